"""Light-field grids: GRID.toml, sample axes, ray generation and store attributes."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

from polycam.errors import FormatError, InputError
from polycam.lightfield import (FACE_NAMES, Axis, LightFieldGrid, R_rig_face_for, _check_faces_attr,
                                finite_frame, load_grid)
from tolerances import GEOMETRY_ATOL, GRID_RAY_ATOL

GRID = """
[grid]
f = 1.0
z_pi = 0.05
faces = ["+z", "-x"]
x = [-0.04, 0.04, 5]
y = [-0.02, 0.02, 3]
u = [-0.5, 0.5, 11]
v = [-0.3, 0.3, 7]
"""


def _grid_file(tmp_path, text):
    p = tmp_path / "grid.toml"
    p.write_text(text)
    return p


def test_load_grid(tmp_path):
    g = load_grid(_grid_file(tmp_path, GRID))
    assert g.shape == (2, 3, 5, 7, 11)
    assert g.num_rays == 2 * 3 * 5 * 7 * 11
    assert [f.name for f in g.faces] == ["+z", "-x"]
    assert all(f.f == 1.0 and f.z_pi == 0.05 for f in g.faces)
    np.testing.assert_allclose(g.faces[1].R_rig_face, R_rig_face_for("-x"))
    np.testing.assert_allclose(g.x.values, np.linspace(-0.04, 0.04, 5))
    assert g.u.step == pytest.approx(0.1)
    assert Axis(2.0, 2.0, 1).step == 0.0


def test_face_rays_closed_form(tmp_path):
    g = load_grid(_grid_file(tmp_path, GRID))
    for k, face in enumerate(g.faces):
        rays = g.face_rays(k)
        assert rays.shape == (3, 5, 7, 11) and rays.frame == "rig"
        R = face.R_rig_face
        j, i, m, n = 2, 1, 4, 9  # L[t, k, j, i, m, n] is sample (x[i], y[j], u[n], v[m])
        x, y, u, v = g.x.values[i], g.y.values[j], g.u.values[n], g.v.values[m]
        np.testing.assert_allclose(rays.origins[j, i, m, n], R @ [x, y, face.z_pi], atol=GRID_RAY_ATOL)
        d = np.array([u, v, face.f]) / np.linalg.norm([u, v, face.f])
        np.testing.assert_allclose(rays.directions[j, i, m, n], R @ d, atol=GRID_RAY_ATOL)
        np.testing.assert_allclose(np.linalg.norm(rays.directions, axis=-1), 1.0, atol=GRID_RAY_ATOL)
    # the +z face of a planar forward array: R = I, origins on the plane z = z_pi
    r0 = g.face_rays(0)
    np.testing.assert_allclose(r0.origins[..., 2], 0.05, atol=GRID_RAY_ATOL)
    assert np.all(r0.directions[..., 2] > 0)
    # the -x face looks along rig -x
    assert np.all(g.face_rays(1).directions[..., 0] < 0)


def test_all_rays_stack_faces(tmp_path):
    g = load_grid(_grid_file(tmp_path, GRID))
    r = g.rays()
    assert r.origins.shape == (2, 3, 5, 7, 11, 3) and r.directions.shape == (2, 3, 5, 7, 11, 3)
    np.testing.assert_array_equal(r.directions[1], g.face_rays(1).directions)


def test_cube_grid_and_attrs_round_trip():
    g = LightFieldGrid.cube(list(FACE_NAMES), f=0.5, z_pi=-0.1, x=Axis(-1, 1, 3), y=Axis(-1, 1, 3),
                            u=Axis(-1, 1, 4), v=Axis(-1, 1, 4))
    a = g.attrs()
    assert set(a) == {"faces", "x", "y", "u", "v"}
    faces = _check_faces_attr("store.zarr", a["faces"])
    assert [f.name for f in faces] == list(FACE_NAMES)
    for f0, f1 in zip(g.faces, faces):
        np.testing.assert_allclose(f1.R_rig_face, f0.R_rig_face, atol=GEOMETRY_ATOL)
        assert (f1.z_pi, f1.f) == (f0.z_pi, f0.f)
    for key in "xyuv":
        ax = Axis.from_values(a[key])
        assert ax == getattr(g, key)


def test_axis_from_values_rejects_irregular():
    with pytest.raises(ValueError, match="regularly spaced"):
        Axis.from_values([0, 1, 3])
    with pytest.raises(ValueError, match="regularly spaced"):
        Axis.from_values([3, 2, 1])
    with pytest.raises(ValueError, match="non-empty"):
        Axis.from_values([])
    assert Axis.from_values([0.25]) == Axis(0.25, 0.25, 1)


@pytest.mark.parametrize("old, new, substrings", [
    ('faces = ["+z", "-x"]', 'faces = ["+z", "+w"]', ["[grid].faces", "unknown face '+w'"]),
    ('faces = ["+z", "-x"]', 'faces = ["+z", "+z"]', ["[grid].faces", "twice"]),
    ('faces = ["+z", "-x"]', "faces = []", ["[grid].faces", "non-empty"]),
    ("f = 1.0", "f = 0", ["[grid].f", "> 0"]),
    ("z_pi = 0.05\n", "", ["[grid].z_pi", "missing"]),
    ("x = [-0.04, 0.04, 5]", "x = [-0.04, 0.04]", ["[grid].x", "list of 3 finite numbers"]),
    ("x = [-0.04, 0.04, 5]", "x = [-0.04, inf, 5]", ["[grid].x", "list of 3 finite numbers"]),
    ("x = [-0.04, 0.04, 5]", "x = [-0.04, 0.04, 100000000]", ["[grid]", "samples per frame", "at most 1073741824"]),
    ("x = [-0.04, 0.04, 5]", "x = [0.04, -0.04, 5]", ["[grid].x", "max > min"]),
    ("x = [-0.04, 0.04, 5]", "x = [-0.04, 0.04, 2.5]", ["[grid].x", "count"]),
    ("x = [-0.04, 0.04, 5]", "x = [-0.04, 0.04, 0]", ["[grid].x", "count"]),
    ("x = [-0.04, 0.04, 5]", "x = [-0.04, 0.04, 1]", ["[grid].x", "count 1) needs min = max"]),
    ("u = [-0.5, 0.5, 11]", "u = [-0.5, 0.5, 11]\nw = 3", ["[grid].w", "unknown key"]),
    ("[grid]", "[other]\nk = 1\n[grid]", ["other", "unknown key"]),
])
def test_grid_errors(tmp_path, old, new, substrings):
    assert old in GRID
    p = _grid_file(tmp_path, GRID.replace(old, new, 1))
    with pytest.raises(FormatError) as e:
        load_grid(p)
    msg = str(e.value)
    assert str(p) in msg, msg
    for s in substrings:
        assert s in msg, msg


@pytest.mark.parametrize("faces, where", [
    ("not a list", "attrs.faces"),
    ([{"name": "+z"}], "attrs.faces[0]"),
    ([{"name": "+z", "R_rig_face": [[1, 0], [0, 1]], "z_pi": 0, "f": 1}], "attrs.faces[0]"),
    ([{"name": "+z", "R_rig_face": np.eye(3).tolist(), "z_pi": "0", "f": 1}], "attrs.faces[0]"),
    ([{"name": "+z", "R_rig_face": np.eye(3).tolist(), "z_pi": 0, "f": -1}], "attrs.faces[0]"),
])
def test_faces_attr_errors(faces, where):
    with pytest.raises(FormatError, match=re.escape(f"store.zarr: {where}: ")):
        _check_faces_attr("store.zarr", faces)


def test_grid_rules_shared_by_resample_and_design():
    """polycam.gridrules is the one copy of the automatic-grid rules: resample's auto_grid
    and the design study's design_grid both give its grid for the same cameras."""
    from polycam import gridrules
    from polycam.cameras import T_rig_cam_of, camera_rays, nominal_cameramodel
    from polycam.design import design_grid, planar_array_rig
    from polycam.rig import CameraSpec
    from resample import grid as rgrid

    assert rgrid.face_of_direction is gridrules.face_of_direction
    assert rgrid.camera_spacing is gridrules.camera_spacing
    cam = CameraSpec(id="c", driver="mock", device=None, width=64, height=48, fps=30.0, pixel_format="GREY",
                     position=np.zeros(3), rotation=np.zeros(3), fov_deg=60.0)
    rig = planar_array_rig(2, 3, 0.02, cam)
    models = {c.id: nominal_cameramodel(c) for c in rig.cameras}
    T = np.stack([T_rig_cam_of(m) for m in models.values()])
    q = np.stack(np.meshgrid(np.arange(0.0, 64.0), np.arange(0.0, 48.0), indexing="xy"), axis=-1)
    dirs = [camera_rays(m, q).directions for m in models.values()]
    f = float(np.median([m.intrinsics()[1][0] for m in models.values()]))
    choice = gridrules.choose_grid(T[:, :3, 3], T[:, :3, 2], dirs, f)
    assert choice.grid == rgrid.auto_grid(models, rays_stride=1)
    assert choice.spacing == pytest.approx(0.02) and choice.own.tolist() == [0] * 6
    g = choice.grid
    assert (g.y.count, g.x.count) == (3, 5) and g.x.step == pytest.approx(0.01)
    d = design_grid(rig, models, uv_step_deg=2.0).grid
    assert (d.x, d.y, d.faces[0].z_pi) == (g.x, g.y, g.faces[0].z_pi)
    assert gridrules.axis_from_range(0.0, 0.004, 0.01, 2) == Axis(0.002, 0.002, 1)
    assert gridrules.max_side_tan(1) > gridrules.max_side_tan(2) == 1.0


def test_perturbed_array_keeps_cameras_on_viewpoints(rng):
    """Position errors of a few mm bias the nearest-neighbour spacing low (the minimum over
    several neighbours); the column spacing keeps a perturbed 5x5 array at 5 x 5 views
    (one per camera), each camera within a fraction of a step of its viewpoint."""
    from polycam import gridrules

    pitch = 0.02
    j, i = np.mgrid[0:5, 0:5]
    c = np.stack([(i - 2) * pitch, (j - 2) * pitch, np.zeros_like(i, float)], axis=-1).reshape(-1, 3)
    c = c + rng.normal(scale=0.0015, size=c.shape)
    nn = gridrules.camera_spacing(c[:, :2])
    assert nn < 0.95 * pitch   # the bias this rule is for
    for axis in (0, 1):
        s = gridrules.column_spacing(c[:, axis], nn)
        assert s == pytest.approx(pitch, rel=0.1)
        a = gridrules.axis_through_columns(c[:, axis], nn, 1)
        assert a.count == 5
        off = np.abs((c[:, axis] - a.min) / a.step - np.round((c[:, axis] - a.min) / a.step))
        assert off.max() < 0.3
    assert gridrules.column_spacing(np.array([0.0]), 0.02) == 0.02


def test_axis_through_columns_is_not_stretched_by_the_extreme_cameras(rng):
    """Many cameras per column (the nested cube pools 18 per outer column over its faces): the
    range of the extreme cameras stretches the axis by their position errors, each view then
    holding a camera that sits nearer the centre than the view (on `polycam run`'s cube the motion's
    translation came out 2 % long); the least-squares fit through the columns does not. A regular
    array's axis stays its exact range, and a single column one view at its middle."""
    from polycam import gridrules

    pitch, sigma = 0.03, 0.001
    x = np.repeat(np.array([-pitch, 0.0, pitch]), 18) + rng.normal(scale=sigma, size=54)
    nn = 0.5 * pitch
    fit = gridrules.axis_through_columns(x, nn, 2)
    old = gridrules.axis_from_range(x.min(), x.max(), gridrules.column_spacing(x, nn), 2)
    assert fit.count == old.count == 5
    assert old.step > 1.04 * pitch / 2                        # the stretch this rule is for
    assert fit.step == pytest.approx(pitch / 2, rel=0.01)
    node = fit.min + 2 * fit.step * np.repeat([0, 1, 2], 18)   # each camera's viewpoint
    assert abs(np.mean(x - node)) < 0.2 * sigma
    for col in range(3):                                      # no column is pulled off its cameras
        assert abs(np.mean((x - node)[18 * col:18 * col + 18])) < 0.8 * sigma
    exact = np.repeat(np.array([-0.02, 0.0, 0.02, 0.04]), 3)
    assert gridrules.axis_through_columns(exact, 0.02, 2) == Axis(-0.02, 0.04, 7)
    assert gridrules.axis_through_columns(np.array([0.001, 0.003]), 0.02, 2) == Axis(0.002, 0.002, 1)


def test_finite_frame_masks_only_samples_without_data():
    L = np.arange(2 * 3 * 4, dtype=np.float32).reshape(2, 3, 4)
    assert finite_frame("frame 0", L) is L                      # finite: the input itself
    bad = L.copy()
    bad[1, 2, 3] = np.nan
    bad[0, 0, 1] = np.inf
    W = np.ones_like(L)
    with pytest.raises(InputError, match=r"^a\.zarr: frame 4 contains NaN"):
        finite_frame("frame 4", bad, None, who="a.zarr")        # no confidences
    W[1, 2, 3] = 0.0
    with pytest.raises(InputError, match="frame 4 contains NaN"):
        finite_frame("frame 4", bad, W)                         # the inf has W = 1
    W[0, 0, 1] = 0.0
    out = finite_frame("frame 4", bad, W)
    assert np.isnan(bad[1, 2, 3]) and out[1, 2, 3] == 0 and out[0, 0, 1] == 0   # a copy
    np.testing.assert_array_equal(out[W > 0], L[W > 0])
    colour = np.repeat(bad[..., None], 3, axis=-1)              # one W for a colour sample
    out = finite_frame("frame 4", colour, W)
    assert out.shape == colour.shape and np.isfinite(out).all()



def test_cameras_grazing_a_face_edge_do_not_widen_its_directions():
    """The nested cube's cameras see 90 deg across and 74 deg down: their side edges lie on the
    faces' 45-deg edges, so mounting errors of 0.3 deg tip a strip of rays onto the next face.
    That strip must not stretch every face's v to ±45 deg (a third more directions, none with
    data); a camera that really looks across an edge (turned by 10 deg) still widens it."""
    from polycam.cameras import nominal_cameramodel
    from polycam.geometry import R_from_r
    from polycam.rig import load_rig
    from polycam.synth import true_cameramodels
    from resample import grid as rgrid

    rig = load_rig(Path(__file__).resolve().parents[1] / "rigs" / "cube6x3x3.toml")
    exact = rgrid.auto_grid(true_cameramodels(rig), uv_step_px=4, rays_stride=8)
    tilted = rgrid.auto_grid(true_cameramodels(rig, seed=6, perturb_rotation_deg=0.3), uv_step_px=4,
                             rays_stride=8)
    f = exact.faces[0].f
    assert exact.v.max == pytest.approx(0.75 * f, abs=1) and exact.u.max == pytest.approx(f, abs=1)
    assert tilted.v.max < 0.8 * f and tilted.v.min > -0.8 * f          # not ±f
    cam = rig.cameras[0]                                               # +z, turned 10 deg about x
    T = cam.T_rig_cam.copy()
    T[:3, :3] = T[:3, :3] @ R_from_r(np.array([np.radians(10.0), 0.0, 0.0]))
    models = true_cameramodels(rig)
    models[cam.id] = nominal_cameramodel(cam, T)
    wide = rgrid.auto_grid(models, uv_step_px=4, rays_stride=8)
    assert max(wide.v.max, -wide.v.min) > 0.95 * f
