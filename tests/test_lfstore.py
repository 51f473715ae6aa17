"""Light-field store (Zarr v3): round trips, lazy reads, crash safety and validation."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest

from polycam.errors import FormatError, InputError
from polycam.geometry import T_from_rt
from polycam.lfstore import (LightFieldStore, LightFieldWriter, open_lightfield,
                             write_lightfield)
from polycam.lightfield import Axis, LightFieldGrid
from polycam.trajectory import Trajectory
from tolerances import LIGHTFIELD_ATOL, TUM_POSITION_ATOL


@pytest.fixture
def grid() -> LightFieldGrid:
    return LightFieldGrid.cube(["+z", "-x"], f=1.0, z_pi=0.1, x=Axis(-0.02, 0.02, 3),
                               y=Axis(-0.01, 0.01, 2), u=Axis(-0.5, 0.5, 5), v=Axis(-0.4, 0.4, 4))


def _frames(rng, grid, T, colour=None):
    shape = (T, *grid.shape) + ((colour,) if colour else ())
    return rng.random(shape, dtype=np.float32)


def _traj(rng, ts):
    rt = np.concatenate([rng.normal(0, 0.05, (len(ts), 3)), rng.normal(0, 0.2, (len(ts), 3))], axis=1)
    return Trajectory(np.asarray(ts, np.int64), T_from_rt(rt))


@pytest.mark.parametrize("colour, weights", [(None, False), (None, True), (3, False), (3, True)])
def test_round_trip(tmp_path, rng, grid, colour, weights):
    T = 3
    L = _frames(rng, grid, T, colour)
    W = rng.random((T, *grid.shape), dtype=np.float32) if weights else None
    ts = np.array([10, 20, 35], np.int64)
    L[1, 0, 0, 0, 0, 0] = np.nan  # NaN marks "no data" and is stored as is
    path = write_lightfield(tmp_path / "lf.zarr", grid, L, ts, weights=W)
    s = open_lightfield(path)
    assert isinstance(s, LightFieldStore)
    assert len(s) == s.num_frames == T
    assert s.colour == colour and s.has_weights == weights
    np.testing.assert_array_equal(s.timestamps_ns, ts)
    assert s.grid.attrs() == grid.attrs()
    assert s.grid.shape == grid.shape
    for k, face in enumerate(grid.faces):
        np.testing.assert_array_equal(s.grid.faces[k].R_rig_face, face.R_rig_face)
        assert (s.grid.faces[k].name, s.grid.faces[k].z_pi, s.grid.faces[k].f) == (face.name, face.z_pi, face.f)
    for t in range(T):
        f = s.frame(t)
        assert f.dtype == np.float32 and f.shape == L.shape[1:]
        np.testing.assert_allclose(f, L[t], atol=LIGHTFIELD_ATOL, equal_nan=True)
        if weights:
            np.testing.assert_allclose(s.weights(t), W[t], atol=LIGHTFIELD_ATOL)
    np.testing.assert_array_equal(s.frame(-1), L[-1])
    np.testing.assert_array_equal(np.stack(list(s)), L)
    if not weights:
        assert s.weights(0) is None
    with pytest.raises(IndexError):
        s.frame(T)
    assert s.groundtruth() is None
    assert s.attrs["format"] == "polycam-lightfield" and s.attrs["version"] == 1


def test_layout_and_chunks(tmp_path, rng, grid):
    """One chunk per (frame, face); the attributes follow SPEC.md."""
    L = _frames(rng, grid, 2)
    write_lightfield(tmp_path / "lf.zarr", grid, L, [1, 2], weights=np.ones((2, *grid.shape)))
    meta = json.loads((tmp_path / "lf.zarr" / "L" / "zarr.json").read_text())
    assert meta["data_type"] == "float32"
    assert meta["chunk_grid"]["configuration"]["chunk_shape"] == [1, 1, *grid.shape[1:]]
    wmeta = json.loads((tmp_path / "lf.zarr" / "W" / "zarr.json").read_text())
    assert wmeta["chunk_grid"]["configuration"]["chunk_shape"] == [1, 1, *grid.shape[1:]]
    attrs = json.loads((tmp_path / "lf.zarr" / "zarr.json").read_text())["attributes"]
    assert set(attrs) >= {"format", "version", "faces", "x", "y", "u", "v", "timestamps_ns"}
    assert attrs["faces"][1]["name"] == "-x"
    assert attrs["timestamps_ns"] == [1, 2]
    assert np.allclose(attrs["u"], np.linspace(-0.5, 0.5, 5))


def test_lazy_frame_read(tmp_path, rng, grid):
    """frame(t) reads only frame t: other frames' chunks can be gone."""
    L = _frames(rng, grid, 3)
    write_lightfield(tmp_path / "lf.zarr", grid, L, [1, 2, 3])
    shutil.rmtree(tmp_path / "lf.zarr" / "L" / "c" / "0")  # frame 0's chunks
    s = open_lightfield(tmp_path / "lf.zarr")
    np.testing.assert_array_equal(s.frame(2), L[2])
    np.testing.assert_array_equal(s.L[2, 1, :, :, 1, 2], L[2, 1, :, :, 1, 2])  # orthographic image


def test_streaming_writer_and_groundtruth(tmp_path, rng, grid):
    ts = [100, 200, 300, 400]
    traj = _traj(rng, ts)
    L = _frames(rng, grid, 4, colour=1)
    with LightFieldWriter(tmp_path / "lf.zarr", grid, colour=1, groundtruth=traj) as w:
        assert w.partial.exists() and not (tmp_path / "lf.zarr").exists()
        for t in range(4):
            assert w.append(L[t], ts[t]) == t
    assert not w.partial.exists()
    s = open_lightfield(tmp_path / "lf.zarr")
    assert s.colour == 1 and len(s) == 4
    gt = s.groundtruth()
    np.testing.assert_array_equal(gt.timestamps_ns, ts)
    np.testing.assert_allclose(gt.T_world_rig, traj.T_world_rig, atol=TUM_POSITION_ATOL)


def test_close_with_groundtruth_checks_it(tmp_path, rng, grid):
    w = LightFieldWriter(tmp_path / "lf.zarr", grid)
    w.append(_frames(rng, grid, 1)[0], 5)
    with pytest.raises(ValueError, match="one pose per frame"):
        w.close(groundtruth=_traj(rng, [5, 6]))
    assert not (tmp_path / "lf.zarr").exists() and not w.partial.exists()


def test_exception_leaves_no_store(tmp_path, rng, grid):
    path = tmp_path / "lf.zarr"
    with pytest.raises(RuntimeError, match="boom"):
        with LightFieldWriter(path, grid) as w:
            w.append(_frames(rng, grid, 1)[0], 1)
            raise RuntimeError("boom")
    assert list(tmp_path.iterdir()) == []


def test_stale_partial_is_replaced(tmp_path, rng, grid):
    (tmp_path / "lf.zarr.partial").mkdir()
    (tmp_path / "lf.zarr.partial" / "junk").write_text("x")
    write_lightfield(tmp_path / "lf.zarr", grid, _frames(rng, grid, 1), [1])
    assert len(open_lightfield(tmp_path / "lf.zarr")) == 1
    assert not (tmp_path / "lf.zarr.partial").exists()


def test_overwrite(tmp_path, rng, grid):
    path = tmp_path / "lf.zarr"
    write_lightfield(path, grid, _frames(rng, grid, 2), [1, 2])
    with pytest.raises(InputError, match="already exists"):
        LightFieldWriter(path, grid)
    write_lightfield(path, grid, _frames(rng, grid, 1), [7], overwrite=True)
    assert open_lightfield(path).timestamps_ns.tolist() == [7]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["lf.zarr"]
    other = tmp_path / "mine"
    other.mkdir()
    (other / "thesis.tex").write_text("x")
    with pytest.raises(InputError, match="not a Zarr store"):
        LightFieldWriter(other, grid, overwrite=True)


def test_writer_rejects_bad_frames(tmp_path, rng, grid):
    with LightFieldWriter(tmp_path / "lf.zarr", grid, with_weights=True) as w:
        L = _frames(rng, grid, 1)[0]
        Wt = np.ones(grid.shape, np.float32)
        with pytest.raises(ValueError, match="expected dims"):
            w.append(L[:1], 1, Wt)
        with pytest.raises(ValueError, match="W_frame is required"):
            w.append(L, 1)
        with pytest.raises(ValueError, match="W_frame: expected dims"):
            w.append(L, 1, Wt[0])
        with pytest.raises(ValueError, match="non-negative integer"):
            w.append(L, 1.5, Wt)
        w.append(L, 1, Wt)
        with pytest.raises(ValueError, match="not after"):
            w.append(L, 1, Wt)
    with pytest.raises(ValueError, match="colour"):
        LightFieldWriter(tmp_path / "b.zarr", grid, colour=0)
    with pytest.raises(ValueError, match="timestamps"):
        write_lightfield(tmp_path / "c.zarr", grid, _frames(rng, grid, 2), [1])
    assert not (tmp_path / "c.zarr").exists()


def test_empty_store(tmp_path, grid):
    write_lightfield(tmp_path / "lf.zarr", grid, [], [])
    s = open_lightfield(tmp_path / "lf.zarr")
    assert len(s) == 0 and list(s) == []


# ----------------------------------------------------------------------------- validation


@pytest.fixture
def store(tmp_path, rng, grid):
    path = tmp_path / "lf.zarr"
    write_lightfield(path, grid, _frames(rng, grid, 2), [1, 2], weights=np.ones((2, *grid.shape)))
    return path


def _set_attr(path, key, value):
    p = path / "zarr.json"
    meta = json.loads(p.read_text())
    if value is _DELETE:
        del meta["attributes"][key]
    else:
        meta["attributes"][key] = value
    p.write_text(json.dumps(meta))


_DELETE = object()


def _expect(path, *substrings):
    with pytest.raises(FormatError) as e:
        open_lightfield(path)
    msg = str(e.value)
    assert str(path) in msg, msg
    for s in substrings:
        assert s in msg, msg


def test_not_a_store(tmp_path):
    _expect(tmp_path / "nope.zarr", "no such light-field store")
    (tmp_path / "dir.zarr").mkdir()
    _expect(tmp_path / "dir.zarr", "not a Zarr group")


def test_array_is_not_a_group(store):
    _expect(store / "L", "not a Zarr group")


_I3 = [[1, 0, 0], [0, 1, 0], [0, 0, 1]]


@pytest.mark.parametrize("key, value, substrings", [
    ("format", "polycam-session", ["attrs.format", "polycam-lightfield"]),
    ("format", _DELETE, ["attrs.format"]),
    ("version", 2, ["attrs.version", "unsupported version 2"]),
    ("faces", [], ["attrs.faces"]),
    ("faces", [{"name": "+z", "R_rig_face": [[1, 0, 0], [0, 1, 0], [0, 0, -1]], "z_pi": 0, "f": 1},
               {"name": "-x", "R_rig_face": [[1, 0, 0], [0, 1, 0], [0, 0, 1]], "z_pi": 0, "f": 1}],
     ["attrs.faces[0]", "rotation"]),
    ("faces", [{"name": 5, "R_rig_face": _I3, "z_pi": 0, "f": 1}], ["attrs.faces[0]", "non-empty string"]),
    ("faces", [{"name": "+z", "R_rig_face": _I3, "z_pi": 0, "f": 1}] * 2, ["attrs.faces[1]", "a second face"]),
    ("faces", [{"name": "-x", "R_rig_face": _I3, "z_pi": 0, "f": 1}], ["attrs.faces[0]", "cube face '-x'"]),
    ("x", [0.0, 1.0, 3.0], ["attrs.x", "regularly spaced"]),
    ("u", [0.5, 0.0, -0.5, -1, -1.5], ["attrs.u", "increasing"]),
    ("v", "0..1", ["attrs.v", "list of numbers"]),
    ("y", [-0.01, 0.0, 0.01], ["L", "do not match"]),
    ("timestamps_ns", [1, 2, 3], ["attrs.timestamps_ns", "3 timestamps for 2 frames"]),
    ("timestamps_ns", [2, 2], ["attrs.timestamps_ns", "not strictly increasing"]),
    ("timestamps_ns", [1.0, 2.0], ["attrs.timestamps_ns", "integers"]),
])
def test_attr_errors(store, key, value, substrings):
    _set_attr(store, key, value)
    _expect(store, *substrings)


def test_camera_positions_attribute(store, grid):
    """Optional; read into (F, Ny, Nx, 2) fractional grid indices at the cameras' views."""
    assert open_lightfield(store).camera_positions is None
    _set_attr(store, "camera_positions", [[0, 0.1, 1.0], [1, 1.0, 0.8]])
    pos = open_lightfield(store).camera_positions
    assert pos.shape == (*grid.shape[:3], 2)
    np.testing.assert_array_equal(pos[0, 0, 1], [0.1, 1.0])
    np.testing.assert_array_equal(pos[1, 1, 1], [1.0, 0.8])
    assert np.isfinite(pos[..., 0]).sum() == 2


@pytest.mark.parametrize("value, substrings", [
    ({"cam0": [0, 1, 1]}, ["attrs.camera_positions", "list of [face, iy, ix]"]),
    ([[0, 1]], ["attrs.camera_positions", "entry 0", "expected [face, iy, ix]"]),
    ([[0, 1, 1], [0.5, 1, 1]], ["entry 1", "an integer and two numbers"]),
    ([[0, "1", 1]], ["entry 0"]),
    ([[0, 1, float("nan")]], ["entry 0"]),
    ([[7, 1, 1]], ["entry 0", "off the grid"]),
    ([[0, 1, 1.2], [0, 0.9, 0.7]], ["entry 1", "a second camera at view (1, 1)"]),
])
def test_camera_positions_errors(store, value, substrings):
    _set_attr(store, "camera_positions", value)
    _expect(store, *substrings)


def test_camera_noise_attribute(store):
    """Optional: the cameras' sensor noise polycam resample measured, and from how many images."""
    lf = open_lightfield(store)
    assert np.isnan(lf.camera_noise_sigma) and lf.camera_noise_images == 0
    _set_attr(store, "camera_noise", {"sigma": 0.008, "images": 9})
    lf = open_lightfield(store)
    assert lf.camera_noise_sigma == 0.008 and lf.camera_noise_images == 9


@pytest.mark.parametrize("value, substrings", [
    (0.008, ["attrs.camera_noise", "keys sigma and images"]),
    ({"sigma": 0.008}, ["attrs.camera_noise", "keys sigma and images"]),
    ({"sigma": -0.1, "images": 3}, ["attrs.camera_noise", "sigma", ">= 0"]),
    ({"sigma": "0.1", "images": 3}, ["sigma", "finite number"]),
    ({"sigma": 0.1, "images": 0}, ["images", "positive integer"]),
    ({"sigma": 0.1, "images": 2.5}, ["images", "positive integer"]),
])
def test_camera_noise_errors(store, value, substrings):
    _set_attr(store, "camera_noise", value)
    _expect(store, *substrings)


def test_faces_count_mismatch(store):
    meta = json.loads((store / "zarr.json").read_text())
    meta["attributes"]["faces"] = meta["attributes"]["faces"][:1]
    (store / "zarr.json").write_text(json.dumps(meta))
    _expect(store, "L", "do not match")


def test_array_errors(store, tmp_path, rng, grid):
    import zarr

    g = zarr.open_group(str(store), mode="r+")
    g.create_array("W2", shape=(2, 1), dtype="float32")
    open_lightfield(store)  # extra arrays are ignored
    del g["W"]
    g.create_array("W", shape=(2, 1, 2, 3, 4, 4), dtype="float32")
    _expect(store, "W", "do not match")
    del g["W"]
    g.create_array("W", shape=(2, *grid.shape), dtype="float64")
    _expect(store, "W", "float32")
    del g["W"]
    open_lightfield(store)  # W is optional
    del g["L"]
    _expect(store, "L", "missing array")
    g.create_array("L", shape=(2, *grid.shape), dtype="uint8")
    _expect(store, "L", "float32")


def test_face_with_a_non_finite_focal_length(store):
    faces = json.loads((store / "zarr.json").read_text())["attributes"]["faces"]
    faces[1]["f"] = float("nan")          # json.dumps writes NaN, which zarr reads back as a float
    _set_attr(store, "faces", faces)
    _expect(store, "attrs.faces[1]", "f must be a finite number")


@pytest.mark.parametrize("array", ["L", "W"])
def test_unreadable_array_metadata(store, array):
    (store / array / "zarr.json").write_text("{not json")
    _expect(store, f": {array}: ", "unreadable array metadata")


@pytest.mark.parametrize("array", ["L", "W"])
def test_unreadable_chunk_is_one_error_naming_the_store_and_frame(store, array):
    """A truncated chunk file (a copy cut short) is read lazily: the frame's read names the store,
    the array and the frame; the other frame still reads."""
    chunks = sorted(p for p in (store / array).rglob("*") if p.is_file() and p.name != "zarr.json"
                    and p.relative_to(store / array).parts[:2] == ("c", "1"))
    assert chunks
    for c in chunks:
        c.write_bytes(c.read_bytes()[:7])
    lf = open_lightfield(store)
    read = lf.frame if array == "L" else lf.weights
    read(0)
    with pytest.raises(FormatError) as e:
        read(1)
    msg = str(e.value)
    assert msg.startswith(f"{store}: {array}: frame 1: unreadable chunk data") and "\n" not in msg, msg


@pytest.mark.parametrize("content, problem", [(b"{not json", "not JSON"), (b"\xff\xfe", "not UTF-8"),
                                              (b"[1, 2]", "expected a JSON object")])
def test_unreadable_group_metadata_names_the_file(store, content, problem):
    (store / "zarr.json").write_bytes(content)
    with pytest.raises(FormatError) as e:
        open_lightfield(store)
    assert str(e.value).startswith(f"{store / 'zarr.json'}: {problem}"), str(e.value)


@pytest.mark.parametrize("value", [1.5, -0.25, float("nan")])
def test_confidences_outside_0_1_are_an_error(tmp_path, rng, grid, value):
    """SPEC.md: W is in [0, 1]; a frame with a confidence outside is one error naming the store, W and
    the frame when it is read."""
    W = np.ones((2, *grid.shape), np.float32)
    W[1, 0, 0, 0, 0, 0] = value
    path = tmp_path / "lf.zarr"
    write_lightfield(path, grid, _frames(rng, grid, 2), [1, 2], weights=W)
    lf = open_lightfield(path)
    lf.weights(0)
    with pytest.raises(FormatError, match=r"lf.zarr: W: frame 1: confidences outside \[0, 1\]"):
        lf.weights(1)


def test_faces_with_other_names_take_any_rotation(store):
    """SPEC.md names the cube's faces only: a face of another name may have any rotation."""
    c, s = np.cos(0.3), np.sin(0.3)
    R = [[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]]
    meta = json.loads((store / "zarr.json").read_text())
    faces = meta["attributes"]["faces"]
    faces[1] = {**faces[1], "name": "tilted", "R_rig_face": R}
    _set_attr(store, "faces", faces)
    g = open_lightfield(store).grid
    assert g.faces[1].name == "tilted"
    np.testing.assert_allclose(g.faces[1].R_rig_face, R)
