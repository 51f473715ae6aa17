"""Recorded sessions: write/read round trips, crash safety and every validation error."""

from __future__ import annotations

import dataclasses
import os
import shutil
from datetime import timezone
from pathlib import Path

import cv2
import numpy as np
import pytest

from polycam.cameras import nominal_cameramodel
from polycam.errors import FormatError, InputError
from polycam.geometry import T_from_rt
from polycam.rig import load_rig
from polycam.session import Session, SessionWriter, open_session
from polycam.trajectory import Trajectory
from tolerances import CAPTURE_TIME_DRAW_STD_REL, GEOMETRY_ATOL, TUM_POSITION_ATOL

TINY_RIG = """
[rig]
name = "tiny"

[defaults]
driver = "mock"
width = 8
height = 6

[[camera]]
id = "g8"
position = [0.0, 0.0, 0.0]

[[camera]]
id = "g16"
position = [0.01, 0.0, 0.0]
pixel_format = "Y16"

[[camera]]
id = "rgb"
position = [0.02, 0.0, 0.0]
rotation = [0.0, 0.1, 0.0]
pixel_format = "RGB"
width = 10
height = 4
"""

T0 = 1_403_636_579_763_555_584  # a EuRoC-sized timestamp [ns]
DT = 33_333_333


@pytest.fixture
def rig(tmp_path):
    p = tmp_path / "tiny.toml"
    p.write_text(TINY_RIG)
    return load_rig(p)


def test_overwrite_keeps_the_old_session_until_the_new_one_is_complete(tmp_path, rig, rng, caplog):
    """``overwrite`` moves the old session aside and removes it only when the new one closes complete;
    a new session that fails leaves the old one beside it (and says where); ``discard`` puts it back."""
    path = tmp_path / "S"
    _write(path, rig, rng)
    w = SessionWriter(path, rig, overwrite=True)
    old = w.replaced
    assert old == tmp_path / f"S.old-{os.getpid()}" and len(open_session(old)) == 4
    w.add_frame(T0, _images(rng, 0))
    w.close()
    assert not old.exists() and len(open_session(path)) == 1
    # a new session that ends with an error: the old one is kept beside it
    shutil.rmtree(path)
    _write(path, rig, rng, n=3, drop=())
    with pytest.raises(RuntimeError):
        with SessionWriter(path, rig, overwrite=True) as w:
            w.add_frame(T0, _images(rng, 0))
            raise RuntimeError("camera unplugged")
    assert open_session(path).status == "incomplete" and len(open_session(path)) == 1
    assert open_session(old).status == "complete" and len(open_session(old)) == 3
    assert f"the session it was to replace is kept in {old}" in caplog.text
    # nothing recorded: discard puts the old one back
    shutil.rmtree(path)
    os.replace(old, path)
    w = SessionWriter(path, rig, overwrite=True)
    w.discard()
    assert not old.exists() and len(open_session(path)) == 3 and open_session(path).status == "complete"


def _images(rng, i):
    """Frame i's images: 8-bit grey, 16-bit grey, 8-bit RGB."""
    return {"g8": rng.integers(0, 256, (6, 8), dtype=np.uint8),
            "g16": rng.integers(0, 65536, (6, 8), dtype=np.uint16),
            "rgb": rng.integers(0, 256, (4, 10, 3), dtype=np.uint8)}


def _write(path, rig, rng, n=4, drop=((1, "g16"), (3, "rgb")), close=True):
    """A session of n frames; (frame, camera) pairs in ``drop`` have no image."""
    written = []
    w = SessionWriter(path, rig)
    for i in range(n):
        imgs = _images(rng, i)
        for fi, cam in drop:
            if fi == i:
                imgs[cam] = None
        w.add_frame(T0 + i * DT, imgs)
        written.append(imgs)
    w.close("complete" if close else "incomplete")  # "incomplete": as if it had crashed
    return written


@pytest.fixture
def session(tmp_path, rig, rng):
    """A complete 4-frame session on disk; returns (path, the images written)."""
    path = tmp_path / "S"
    return path, _write(path, rig, rng)


def _expect(path, *substrings):
    with pytest.raises(FormatError) as e:
        open_session(path)
    for s in substrings:
        assert s in str(e.value), str(e.value)
    return e.value


# ----------------------------------------------------------------------------- round trips


def test_round_trip_grey8_grey16_rgb(session, rig):
    path, written = session
    s = open_session(path)
    assert isinstance(s, Session)
    assert s.status == "complete"
    assert s.cameras == ["g8", "g16", "rgb"]
    assert s.created.tzinfo is not None and s.created.utcoffset() == timezone.utc.utcoffset(None)
    assert len(s) == 4
    assert s.timestamps_ns.dtype == np.int64
    np.testing.assert_array_equal(s.timestamps_ns, T0 + DT * np.arange(4))
    assert s.cam_timestamps.shape == (4, 3)
    assert s.cam_timestamps[1, 1] == -1 and s.cam_timestamps[3, 2] == -1
    assert s.cam_timestamps[2, 0] == T0 + 2 * DT
    np.testing.assert_array_equal(s.image_timestamps("g16"), T0 + DT * np.array([0, 2, 3]))
    assert s.image_size("rgb") == (10, 4)
    assert s.image_path("g8", T0) == path / "g8" / "data" / f"{T0}.png"
    for i, imgs in enumerate(written):
        frame = s.read_frame(i)
        for cam, img in imgs.items():
            if img is None:
                assert frame[cam] is None
            else:
                assert frame[cam].dtype == img.dtype and frame[cam].shape == img.shape
                np.testing.assert_array_equal(frame[cam], img)
    assert s.calibration() is None
    assert s.groundtruth() is None
    # the rig is a verbatim copy of the rig file
    assert (path / "rig.toml").read_text() == TINY_RIG
    assert s.rig.ids == rig.ids


def test_rgb_is_rgb_on_disk(tmp_path, rig):
    """Colour images are RGB in memory and standard RGB in the PNG (cv2's BGR never leaks)."""
    img = np.zeros((4, 10, 3), np.uint8)
    img[..., 0] = 200  # pure red
    with SessionWriter(tmp_path / "S", rig) as w:
        p = w.write_image("rgb", 5, img)
        w.write_frame(5, {"rgb": 5})
    on_disk = cv2.imread(str(p), cv2.IMREAD_UNCHANGED)
    assert on_disk[0, 0].tolist() == [0, 0, 200]  # cv2 reads BGR: red is last
    np.testing.assert_array_equal(open_session(tmp_path / "S").read_image("rgb", 5), img)


def test_csv_files_follow_euroc_layout(session):
    path, _ = session
    lines = (path / "g16" / "data.csv").read_text().splitlines()
    assert lines[0] == "#timestamp [ns],filename"
    assert lines[1] == f"{T0},{T0}.png"
    assert len(lines) == 4
    frames = (path / "frames.csv").read_text().splitlines()
    assert frames[0] == "frame,timestamp_ns,g8,g16,rgb"
    assert frames[2] == f"1,{T0 + DT},{T0 + DT},,{T0 + DT}"
    toml = (path / "session.toml").read_text()
    assert 'format = "polycam-session"' in toml and 'status = "complete"' in toml


def test_calibration_and_groundtruth_round_trip(tmp_path, rig, rng):
    models = {c.id: nominal_cameramodel(c) for c in rig.cameras}
    traj = Trajectory(T0 + DT * np.arange(4, dtype=np.int64),
                      T_from_rt(np.concatenate([rng.normal(0, 0.1, (4, 3)), rng.normal(0, 1, (4, 3))], axis=1)))
    writer = SessionWriter(tmp_path / "S2", rig)
    for i in range(4):
        writer.add_frame(T0 + i * DT, _images(rng, i))
    for cam, m in models.items():
        writer.write_calibration(cam, m)
    writer.write_groundtruth(traj)
    rep = writer.write_extra("reports/calibration.txt", "rms 0.1 px\n")
    writer.close()
    s = open_session(tmp_path / "S2")
    calib = s.calibration()
    assert set(calib) == set(rig.ids)
    for cam, m in models.items():
        np.testing.assert_allclose(calib[cam].intrinsics()[1], m.intrinsics()[1], atol=GEOMETRY_ATOL)
        np.testing.assert_allclose(calib[cam].rt_cam_ref(), m.rt_cam_ref(), atol=GEOMETRY_ATOL)
    gt = s.groundtruth()
    np.testing.assert_array_equal(gt.timestamps_ns, traj.timestamps_ns)
    np.testing.assert_allclose(gt.T_world_rig, traj.T_world_rig, atol=TUM_POSITION_ATOL)
    assert rep.read_text() == "rms 0.1 px\n"
    assert not list((tmp_path / "S2" / "calib").glob(".tmp*"))


def test_rig_without_file_is_serialised(tmp_path, repo):
    rig = load_rig(repo / "rigs" / "mock5x5.toml")
    w = SessionWriter(tmp_path / "S", dataclasses.replace(rig, path=None))
    w.close()
    back = open_session(tmp_path / "S").rig
    assert back.name == rig.name and back.ids == rig.ids and back.mock == rig.mock
    for a, b in zip(rig.cameras, back.cameras):
        for f in dataclasses.fields(a):
            va, vb = getattr(a, f.name), getattr(b, f.name)
            if isinstance(va, np.ndarray):
                np.testing.assert_allclose(vb, va, atol=GEOMETRY_ATOL)
            else:
                assert va == vb, f.name


def test_rig_with_lens_copies_the_lens(tmp_path, rig):
    lens_dir = tmp_path / "lenses_src"
    lens_dir.mkdir()
    nominal_cameramodel(rig.camera("g8")).write(str(lens_dir / "wide.cameramodel"))
    text = TINY_RIG.replace("[defaults]", '[defaults]\nlens = "lenses_src/wide.cameramodel"')
    (tmp_path / "lens.toml").write_text(text)
    lens_rig = load_rig(tmp_path / "lens.toml")
    SessionWriter(tmp_path / "S", lens_rig).close()
    back = open_session(tmp_path / "S").rig
    assert back.camera("g16").lens == tmp_path / "S" / "lenses" / "wide.cameramodel"
    assert back.camera("g16").lens.is_file()


def test_incomplete_on_exception(tmp_path, rig, rng):
    path = tmp_path / "S"
    with pytest.raises(RuntimeError, match="camera unplugged"):
        with SessionWriter(path, rig) as w:
            w.add_frame(T0, _images(rng, 0))
            w.add_frame(T0 + DT, _images(rng, 1))
            raise RuntimeError("camera unplugged")
    s = open_session(path)
    assert s.status == "incomplete" and len(s) == 2
    np.testing.assert_array_equal(s.image_timestamps("g8"), [T0, T0 + DT])


def test_readable_while_writing(tmp_path, rig, rng):
    path = tmp_path / "S"
    w = SessionWriter(path, rig)
    assert len(open_session(path)) == 0
    w.add_frame(T0, _images(rng, 0))
    s = open_session(path)
    assert s.status == "incomplete" and len(s) == 1
    w.close()
    assert open_session(path).status == "complete"


def test_truncated_last_lines_open_when_incomplete(tmp_path, rig, rng):
    path = tmp_path / "S"
    _write(path, rig, rng, close=False)  # a writer that "crashed": never closed
    with open(path / "g8" / "data.csv", "a") as f:
        f.write(f"{T0 + 9 * DT},{T0 + 9}")  # half a row, no newline
    with open(path / "frames.csv", "a") as f:
        f.write(f"4,{T0 + 9 * DT},{T0 + 9 * DT},")
    s = open_session(path)
    assert s.status == "incomplete" and len(s) == 4
    assert s.image_timestamps("g8").size == 4
    # the same file in a session that claims to be complete is an error
    toml = path / "session.toml"
    toml.write_text(toml.read_text().replace('"incomplete"', '"complete"'))
    _expect(path, "g8/data.csv", "line 6", "truncated")


def test_empty_csv_in_incomplete_session(tmp_path, rig):
    path = tmp_path / "S"
    SessionWriter(path, rig).close("incomplete")  # crashed right away
    (path / "g16" / "data.csv").write_text("")
    (path / "frames.csv").write_text("frame,times")
    s = open_session(path)
    assert len(s) == 0 and s.cam_timestamps.shape == (0, 3)


# ----------------------------------------------------------------------------- writer errors


def test_writer_refuses_non_empty_folder(tmp_path, rig, rng):
    path = tmp_path / "S"
    path.mkdir()
    (path / "notes.txt").write_text("mine")
    with pytest.raises(InputError, match="not empty"):
        SessionWriter(path, rig)
    with pytest.raises(InputError, match="not a polycam session"):
        SessionWriter(path, rig, overwrite=True)
    assert (path / "notes.txt").exists()
    shutil.rmtree(path)
    _write(path, rig, rng)
    SessionWriter(path, rig, overwrite=True).close()
    assert len(open_session(path)) == 0
    # an existing empty folder is fine
    (tmp_path / "E").mkdir()
    SessionWriter(tmp_path / "E", rig).close()


def test_writer_rejects_bad_images_and_timestamps(tmp_path, rig):
    w = SessionWriter(tmp_path / "S", rig)
    ok = np.zeros((6, 8), np.uint8)
    with pytest.raises(InputError, match="uint8 or uint16"):
        w.write_image("g8", 1, ok.astype(np.float32))
    with pytest.raises(InputError, match="but the rig gives 8x6"):
        w.write_image("g8", 1, np.zeros((8, 6), np.uint8))
    with pytest.raises(InputError, match="grey or"):
        w.write_image("g8", 1, np.zeros((6, 8, 2), np.uint8))
    with pytest.raises(InputError, match="unknown camera"):
        w.write_image("nope", 1, ok)
    with pytest.raises(InputError, match="non-negative"):
        w.write_image("g8", -5, ok)
    with pytest.raises(InputError, match="integer"):
        w.write_image("g8", 1.5, ok)
    w.write_image("g8", 10, ok)
    with pytest.raises(InputError, match="not after"):
        w.write_image("g8", 10, ok)
    w.write_frame(10, {"g8": 10})
    with pytest.raises(InputError, match="not after"):
        w.write_frame(9, {})
    with pytest.raises(InputError, match="unknown camera"):
        w.write_frame(11, {"cam99": 11})
    with pytest.raises(ValueError, match="relative path"):
        w.write_extra("../escape.txt", "x")
    with pytest.raises(ValueError, match="relative path"):
        w.write_extra("session.toml", "x")
    w.close()
    with pytest.raises(ValueError, match="closed"):
        w.write_image("g8", 20, ok)
    assert not list((tmp_path / "S" / "g8" / "data").glob(".tmp*"))


# ----------------------------------------------------------------------------- validation


def _edit(p: Path, old: str, new: str) -> None:
    text = p.read_text()
    assert old in text, (old, text)
    p.write_text(text.replace(old, new, 1))


def test_not_a_session(tmp_path):
    _expect(tmp_path / "missing", "missing", "no such session folder")
    (tmp_path / "empty").mkdir()
    _expect(tmp_path / "empty", "session.toml", "no such file")


@pytest.mark.parametrize("old, new, substrings", [
    ('status = "complete"', 'status = "complete"\ncolour = true', ["[session].colour", "unknown key"]),
    ('status = "complete"\n', "", ["[session].status", "missing"]),
    ('format = "polycam-session"', 'format = "euroc"', ["[session].format", "polycam-session"]),
    ("version = 1", "version = 2", ["[session].version", "unsupported version 2"]),
    ("version = 1", 'version = "1"', ["[session].version", "integer"]),
    ('status = "complete"', 'status = "done"', ["[session].status", "complete"]),
    ('rig = "tiny"', 'rig = "other"', ["[session].rig", "rig.toml"]),
    ('created = "', 'created = "yesterday', ["[session].created", "ISO-8601"]),
    ('"g8",', '"g8",\n    "g8",', ["[session].cameras", "twice"]),
    ('"g8",', '"g9",', ["[session].cameras", "'g9' is not in rig.toml"]),
])
def test_session_toml_errors(session, old, new, substrings):
    path, _ = session
    _edit(path / "session.toml", old, new)
    _expect(path, "session.toml", *substrings)


def test_camera_folder_missing(session):
    path, _ = session
    shutil.rmtree(path / "g16")
    _expect(path, "g16", "camera folder missing")


def test_rig_toml_errors_name_the_file(session):
    path, _ = session
    _edit(path / "rig.toml", "[defaults]", "[defaults]\nexposure = 3")
    _expect(path, "rig.toml", "[defaults].exposure", "unknown key")


@pytest.mark.parametrize("old, new, substrings", [
    ("#timestamp [ns],filename", "time,file", ["line 1", "header"]),
    (f"{T0},{T0}.png", f"{T0},{T0}.png,extra", ["line 2", "expected 2 comma-separated values"]),
    (f"{T0},{T0}.png", f"abc,{T0}.png", ["line 2", "'abc' is not an integer"]),
    (f"{T0},{T0}.png", f"-3,{T0}.png", ["line 2", "non-negative"]),
    (f"{T0},{T0}.png", f"{T0},other.png", ["line 2", "does not match the timestamp"]),
])
def test_data_csv_errors(session, old, new, substrings):
    path, _ = session
    _edit(path / "g8" / "data.csv", old, new)
    _expect(path, "g8/data.csv", *substrings)


def test_data_csv_not_increasing(session):
    path, _ = session
    p = path / "rgb" / "data.csv"
    lines = p.read_text().splitlines()
    lines[2], lines[3] = lines[3], lines[2]
    p.write_text("\n".join(lines) + "\n")
    _expect(path, "rgb/data.csv", "line 4", "timestamps are not strictly increasing")


def test_png_listed_but_missing(session):
    path, _ = session
    os.remove(path / "g16" / "data" / f"{T0 + 2 * DT}.png")
    _expect(path, "g16/data.csv", "line 3", f"{T0 + 2 * DT}.png", "missing")


def test_png_unreadable(session):
    path, _ = session
    p = path / "g8" / "data" / f"{T0 + DT}.png"
    p.write_bytes(p.read_bytes()[:40])  # header intact, pixel data cut off
    s = open_session(path)  # only the first image of each camera is checked on open
    with pytest.raises(FormatError) as e:
        s.read_image("g8", T0 + DT)
    assert f"g8/data/{T0 + DT}.png" in str(e.value) and "unreadable" in str(e.value)


def test_png_not_a_png(session):
    path, _ = session
    (path / "g8" / "data" / f"{T0}.png").write_text("hello")
    _expect(path, f"g8/data/{T0}.png", "not a PNG")


def test_png_wrong_size(session, rng):
    path, _ = session
    # on open: the first image of each camera
    ok, buf = cv2.imencode(".png", np.zeros((5, 8), np.uint8))
    (path / "g8" / "data" / f"{T0}.png").write_bytes(buf.tobytes())
    _expect(path, f"g8/data/{T0}.png", "image is 8x5 but rig.toml gives g8 8x6")
    # on read_image: any later image
    ok, good = cv2.imencode(".png", np.zeros((6, 8), np.uint8))
    (path / "g8" / "data" / f"{T0}.png").write_bytes(good.tobytes())
    (path / "g8" / "data" / f"{T0 + 2 * DT}.png").write_bytes(buf.tobytes())
    s = open_session(path)
    with pytest.raises(FormatError, match="image is 8x5 but rig.toml gives g8 8x6"):
        s.read_frame(2)


def test_png_wrong_kind(session):
    path, _ = session
    ok, buf = cv2.imencode(".png", np.zeros((6, 8, 4), np.uint8))  # RGBA
    (path / "g8" / "data" / f"{T0}.png").write_bytes(buf.tobytes())
    _expect(path, f"g8/data/{T0}.png", "colour type 6")


@pytest.mark.parametrize("old, new, substrings", [
    ("frame,timestamp_ns,g8,g16,rgb", "frame,timestamp_ns,g8,rgb,g16", ["line 1", "do not match"]),
    ("frame,timestamp_ns,g8,g16,rgb", "frame,timestamp_ns,g8,g16", ["line 1", "do not match"]),
    (f"1,{T0 + DT},", f"7,{T0 + DT},", ["line 3", "frame indices"]),
    (f"1,{T0 + DT},", f"1,{T0 - 1},", ["line 3", "not strictly increasing"]),
    (f"1,{T0 + DT},{T0 + DT},", f"1,{T0 + DT},{T0 + DT},,", ["line 3", "expected 5"]),
    (f"1,{T0 + DT},{T0 + DT},", f"1,{T0 + DT},{T0 + 5},", ["line 3", "g8: timestamp has no image"]),
    (f"1,{T0 + DT},{T0 + DT},", f"1,{T0 + DT},x,", ["line 3", "g8: 'x' is not an integer"]),
])
def test_frames_csv_errors(session, old, new, substrings):
    path, _ = session
    _edit(path / "frames.csv", old, new)
    _expect(path, "frames.csv", *substrings)


def test_missing_calibration_model(session, rig):
    path, _ = session
    (path / "calib").mkdir()
    for c in rig.cameras[:2]:
        nominal_cameramodel(c).write(str(path / "calib" / f"{c.id}.cameramodel"))
    s = open_session(path)
    with pytest.raises(FormatError, match="calib/rgb.cameramodel"):
        s.calibration()
    bad = dataclasses.replace(rig.camera("g8"), width=16, height=12, id="rgb")
    nominal_cameramodel(bad).write(str(path / "calib" / "rgb.cameramodel"))
    with pytest.raises(FormatError, match="imagersize 16x12 does not match the camera's 10x4"):
        s.calibration()


def test_unknown_image_is_a_key_error(session):
    path, _ = session
    s = open_session(path)
    with pytest.raises(KeyError):
        s.read_image("g8", T0 + 1)
    with pytest.raises(KeyError):
        s.image_timestamps("cam00")


def test_threaded_add_frame(tmp_path, rig, rng):
    path = tmp_path / "S"
    written = []
    with SessionWriter(path, rig, threads=2) as w:
        for i in range(3):
            written.append(_images(rng, i))
            w.add_frame(T0 + i * DT, written[-1])
        with pytest.raises(InputError, match="but the rig gives"):
            w.add_frame(T0 + 5 * DT, {"g8": np.zeros((6, 8), np.uint8), "rgb": np.zeros((4, 4, 3), np.uint8)})
    s = open_session(path)
    assert len(s) == 3
    for i, imgs in enumerate(written):
        for cam, img in s.read_frame(i).items():
            np.testing.assert_array_equal(img, imgs[cam])


def test_calibration_from_another_folder(session, rig, tmp_path):
    path, _ = session
    s = open_session(path)
    with pytest.raises(FormatError, match="no such calibration folder"):
        s.calibration(tmp_path / "nope")
    d = tmp_path / "calib_out"
    d.mkdir()
    for c in rig.cameras:
        nominal_cameramodel(c).write(str(d / f"{c.id}.cameramodel"))
    assert set(s.calibration(d)) == {"g8", "g16", "rgb"}
    assert s.calibration() is None


def test_capture_times_take_out_the_timestamp_jitter():
    # free-running cameras: constant phases, jittered timestamps; the running median of each camera's
    # offset from the frame time recovers the phases to a fraction of the jitter, follows a steady drift,
    # restarts where the grouping moved to the camera's next image, and keeps missing images missing
    from polycam.session import capture_times

    rng = np.random.default_rng(5)
    F, C, period = 120, 6, 33_333_333
    phase = rng.uniform(-8e6, 8e6, C)
    phase[1] = -12e6
    drift = np.zeros((F, C))
    drift[:, 2] = np.linspace(0.0, 3e6, F)                          # 3 ms over 4 s: rates 0.07 % apart
    drift[60:, 1] = period                                           # camera 1's phase past the tolerance
    captured = 1e9 + np.arange(F)[:, None] * period + phase + drift
    stamps = np.round(captured + rng.normal(0.0, 1e6, (F, C))).astype(np.int64)
    stamps[7, 3] = -1
    frames = np.median(stamps, axis=1).astype(np.int64)
    times = capture_times(frames, stamps)
    assert times[7, 3] == -1 and (times[stamps >= 0] >= 0).all()
    have = stamps >= 0

    def relative(t):         # error of each camera's time against the others' in its frame (what the
        e = np.where(have, t - captured, np.nan)                    # correction uses)
        return (e - np.nanmean(e, axis=1, keepdims=True))[have]

    assert np.sqrt(np.mean(relative(times) ** 2)) < 0.35 * np.sqrt(np.mean(relative(stamps) ** 2))
    assert np.abs(relative(times)).max() < 1.5e6                    # no frame near the jump is off by a period
    # synchronised cameras with jittered timestamps read as synchronised
    sync = np.round(1e9 + np.arange(F)[:, None] * period + rng.normal(0.0, 1e6, (F, C))).astype(np.int64)
    t = capture_times(np.median(sync, axis=1).astype(np.int64), sync)
    assert np.median(np.ptp(t, axis=1)) < 1e6 < np.median(np.ptp(sync, axis=1))
    # one frame, or one image per camera: the timestamps as they are
    np.testing.assert_array_equal(capture_times(frames[:1], stamps[:1]), stamps[:1])


def test_capture_time_draws_spread_as_the_estimate_errs():
    # --sync-draws moves the cameras by draws of the capture times' error (a parametric bootstrap): on one
    # session's timestamps their spread is the estimate's over fresh jitter, per image relative to the
    # 30 fps cameras' mean (what the correction sees): nearly one offset for those (a median of the
    # session's 12 offsets), and for two 25 fps cameras (a line through their own ~10 stamps) about 1.8x
    # that at the session's ends and ~1x in its middle, which one std per camera cannot give
    from polycam.session import capture_time_draw, capture_times, frame_times


    rng = np.random.default_rng(11)
    F, fast, period, jitter = 12, 6, 33_333_333, 2e6
    centres = 1e9 + np.arange(F) * period
    truth = np.full((F, fast + 2), -1, np.int64)
    truth[:, :fast] = np.round(centres[:, None] + rng.uniform(-8e6, 8e6, fast))
    for k in (fast, fast + 1):                                  # 25 fps: each frame takes its nearest image
        own = 1e9 + rng.uniform(-20e6, 20e6) + np.arange(-1, 12) * 40e6
        near = np.abs(own[None, :] - centres[:, None]).argmin(axis=1)
        first = np.r_[True, near[1:] != near[:-1]]
        truth[first, k] = np.round(own[near[first]])
    has = truth >= 0
    slow = [False] * fast + [True, True]

    def observe(r):
        stamps = np.where(has, truth + np.round(jitter * r.standard_normal(truth.shape)).astype(np.int64), -1)
        return np.median(stamps[:, :fast], axis=1).astype(np.int64), stamps

    def relative(e):
        e = np.where(has, e, np.nan)
        return e - np.nanmean(e[:, :fast], axis=1, keepdims=True)

    errors = []
    for _ in range(300):
        frames, stamps = observe(rng)
        errors.append(relative(capture_times(frame_times(frames), stamps, other_rate=slow) - truth))
    draws = []                             # 30 sessions' timestamps (each its own jitter estimate), 10 draws each
    for _ in range(30):
        frames, stamps = observe(rng)
        draws += [relative(capture_time_draw(frames, stamps, rng, other_rate=slow)) for _ in range(10)]
    want, got = np.std(errors, axis=0), np.std(draws, axis=0)          # NaN where no image
    ends, middle = np.r_[0:2, F - 2:F], np.r_[4:8]
    for rows, cams in ((slice(None), slice(0, fast)), (ends, slice(fast, None)), (middle, slice(fast, None))):
        assert abs(np.nanmean(got[rows, cams]) / np.nanmean(want[rows, cams]) - 1.0) < CAPTURE_TIME_DRAW_STD_REL
    assert np.nanmean(want[ends, fast:]) > 1.5 * np.nanmean(want[:, :fast])
    clean = np.median(truth[:, :fast], axis=1).astype(np.int64)                  # no jitter: no error
    assert not capture_time_draw(clean, truth, rng, other_rate=slow).any()
    no_images = np.full_like(stamps, -1)
    assert not capture_time_draw(frames, no_images, rng).any()


def test_frame_times_take_out_the_jitter_of_frame_timestamps():
    # a frame's timestamp is the median of its images', so it jitters with them: the frame times follow
    # the frame clock (a rate 0.05 % off the nominal one, a dropped frame) to a fraction of that jitter
    from polycam.session import frame_times

    rng = np.random.default_rng(7)
    ticks = np.delete(np.arange(80), 33)                              # frame 33 lost
    clock = 2e9 + ticks * 33_333_333 * 1.0005
    stamps = np.round(clock + rng.normal(0.0, 2e6, ticks.size)).astype(np.int64)
    got = frame_times(stamps)
    assert np.sqrt(np.mean((got - clock) ** 2)) < 0.4 * np.sqrt(np.mean((stamps - clock) ** 2))   # 0.29
    assert np.all(np.diff(got) > 0)
    np.testing.assert_array_equal(frame_times(stamps[:2]), stamps[:2])
