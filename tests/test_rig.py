"""Rig files: grid generation, defaults and overrides, and every validation error."""

from __future__ import annotations

import numpy as np
import pytest

from polycam.errors import FormatError
from polycam.geometry import R_from_r
from polycam.rig import load_rig
from tolerances import GEOMETRY_ATOL

CAMERAS = """
[rig]
name = "pair"

[defaults]
driver = "v4l2"
width = 640
height = 480
fps = 30
pixel_format = "GREY"

[[camera]]
id = "left"
device = "/dev/video0"
position = [-0.05, 0.0, 0.0]

[[camera]]
id = "right"
device = "/dev/video2"
position = [0.05, 0.0, 0.0]
rotation = [0.0, 0.2, 0.0]
width = 1280
height = 720
pixel_format = "Y16"
"""

GRID = """
[rig]
name = "g"

[defaults]
width = 32
height = 24

[grid]
rows = 2
cols = 3
pitch = 0.1
"""


def _rig(tmp_path, text, name="rig.toml"):
    p = tmp_path / name
    p.write_text(text)
    return p


def _expect(path, *substrings):
    with pytest.raises(FormatError) as e:
        load_rig(path)
    msg = str(e.value)
    assert str(path) in msg, msg
    for s in substrings:
        assert s in msg, msg


def test_default_rig(repo):
    rig = load_rig(repo / "rigs" / "mock5x5.toml")
    assert rig.name == "mock5x5" and len(rig.cameras) == 25
    assert rig.ids == [f"cam{i:02d}" for i in range(25)]
    c = rig.camera("cam07")
    assert (c.width, c.height, c.pixel_format, c.driver, c.fov_deg) == (320, 240, "GREY", "mock", 60.0)
    assert rig.mock.scene == "room" and rig.mock.motion == "smooth" and rig.mock.seed == 1
    assert rig.mock.noise == pytest.approx(0.004)
    assert rig.path == repo / "rigs" / "mock5x5.toml"


def test_grid_is_row_major_from_top_left(tmp_path):
    rig = load_rig(_rig(tmp_path, GRID))
    assert rig.ids == ["cam00", "cam01", "cam02", "cam03", "cam04", "cam05"]
    # y points down in the rig frame: the top row has the smallest y; x grows along a row
    np.testing.assert_allclose(rig.positions, [[-0.1, -0.05, 0], [0, -0.05, 0], [0.1, -0.05, 0],
                                               [-0.1, 0.05, 0], [0, 0.05, 0], [0.1, 0.05, 0]],
                               atol=GEOMETRY_ATOL)
    np.testing.assert_allclose(rig.positions.mean(axis=0), 0, atol=GEOMETRY_ATOL)  # centred
    for c in rig.cameras:
        np.testing.assert_allclose(c.T_rig_cam[:3, :3], np.eye(3))  # all look along rig +z
        assert (c.width, c.height, c.device, c.lens) == (32, 24, None, None)
    assert rig.mock is None


def test_grid_ids_grow_a_digit_from_100_cameras(tmp_path):
    rig = load_rig(_rig(tmp_path, GRID.replace("rows = 2", "rows = 10").replace("cols = 3", "cols = 11")))
    assert rig.ids[0] == "cam000" and rig.ids[-1] == "cam109" and len(set(rig.ids)) == 110
    rig = load_rig(_rig(tmp_path, GRID.replace("rows = 2", "rows = 1").replace("cols = 3", "cols = 1")))
    assert rig.ids == ["cam00"]
    np.testing.assert_allclose(rig.positions, [[0, 0, 0]])


def test_cameras_defaults_and_overrides(tmp_path):
    rig = load_rig(_rig(tmp_path, CAMERAS))
    left, right = rig.cameras
    assert (left.id, left.device, left.width, left.height, left.fps, left.pixel_format) == \
        ("left", "/dev/video0", 640, 480, 30.0, "GREY")
    assert (right.width, right.height, right.pixel_format, right.driver) == (1280, 720, "Y16", "v4l2")
    np.testing.assert_allclose(right.T_rig_cam[:3, :3], R_from_r(np.array([0, 0.2, 0])), atol=GEOMETRY_ATOL)
    np.testing.assert_allclose(right.T_rig_cam[:3, 3], [0.05, 0, 0])
    np.testing.assert_allclose(left.rotation, 0)


def test_lens_path_is_relative_to_the_rig_file(tmp_path):
    (tmp_path / "lenses").mkdir()
    (tmp_path / "lenses" / "a.cameramodel").write_text("{}")
    sub = tmp_path / "rigs"
    sub.mkdir()
    p = _rig(sub, CAMERAS.replace("[defaults]", '[defaults]\nlens = "../lenses/a.cameramodel"'))
    assert load_rig(p).camera("left").lens == sub / "../lenses/a.cameramodel"


def test_mock_table(tmp_path):
    text = GRID + """
[mock]
scene = "spheres"
motion = "static"
seed = 7
noise = 0.01
jitter_ms = 0.5
sync_spread_ms = 6.5
drop_rate = 0.1
distance = 2.5
mjpg_quality = 75

[mock.disconnect_after]
cam04 = 10
"""
    m = load_rig(_rig(tmp_path, text)).mock
    assert (m.scene, m.motion, m.seed, m.noise, m.jitter_ms, m.sync_spread_ms, m.drop_rate, m.distance,
            m.mjpg_quality) == ("spheres", "static", 7, 0.01, 0.5, 6.5, 0.1, 2.5, 75)
    assert m.disconnect_after == {"cam04": 10}
    assert m.free_running and m.clock_ppm == 0.0


def test_mock_clock_ppm_makes_the_cameras_free_running(tmp_path):
    m = load_rig(_rig(tmp_path, GRID + "[mock]\nclock_ppm = 150.0\n")).mock
    assert m.clock_ppm == 150.0 and m.sync_spread_ms == 0.0 and m.free_running
    assert not load_rig(_rig(tmp_path, GRID + "[mock]\nseed = 2\n")).mock.free_running


@pytest.mark.parametrize("base, old, new, substrings", [
    # unknown keys, at every level
    (GRID, "[grid]", "colour = true\n[grid]", ["[defaults].colour", "unknown key"]),
    (GRID, 'name = "g"', 'name = "g"\nowner = "me"', ["[rig].owner", "unknown key"]),
    (GRID, "pitch = 0.1", "pitch = 0.1\nspacing = 2", ["[grid].spacing", "unknown key"]),
    (CAMERAS, 'id = "left"', 'id = "left"\nexposure = 3', ["[[camera]] #1.exposure", "unknown key"]),
    (GRID, "[grid]", "[lights]\non = true\n[grid]", ["lights", "unknown key"]),
    (GRID + "[mock]\nsceen = 'room'\n", "", "", ["[mock].sceen", "unknown key"]),
    # wrong types and values
    (GRID, "width = 32", 'width = "32"', ["[defaults].width", "expected an integer"]),
    (GRID, "width = 32", "width = 32.5", ["[defaults].width", "expected an integer"]),
    (GRID, "width = 32", "width = 0", ["[defaults].width", ">= 1"]),
    (GRID, "width = 32", "width = 1410065408", ["[defaults].width", "<= 32768"]),
    (GRID, "rows = 2", "rows = 100000000", ["[grid].rows", "<= 4096"]),
    (GRID, "rows = 2", "rows = 2000", ["[grid].rows", "rows x cols = 6000 cameras; at most 4096"]),
    (GRID + "[mock]\nseed = -1\n", "", "", ["[mock].seed", ">= 0"]),
    (CAMERAS, "position = [-0.05, 0.0, 0.0]", "position = [-0.05, nan, 0.0]", ["[[camera]] #1.position",
                                                                              "finite numbers"]),
    (GRID, "rows = 2", "rows = true", ["[grid].rows", "boolean"]),
    (GRID, "pitch = 0.1", "pitch = 0", ["[grid].pitch", "> 0"]),
    (GRID, "pitch = 0.1", "pitch = inf", ["[grid].pitch", "finite"]),
    (GRID + "[mock]\njitter_ms = nan\n", "", "", ["[mock].jitter_ms", "finite"]),
    (GRID + "[mock]\nsync_spread_ms = -1.0\n", "", "", ["[mock].sync_spread_ms", ">= 0"]),
    (GRID + "[mock]\nclock_ppm = -5.0\n", "", "", ["[mock].clock_ppm", ">= 0"]),
    (GRID + "[mock]\nclock_ppm = 2e5\n", "", "", ["[mock].clock_ppm", "<= 100000"]),
    (CAMERAS, "position = [-0.05, 0.0, 0.0]", "position = [-0.05, 0.0]", ["[[camera]] #1.position", "3"]),
    (CAMERAS, 'id = "left"', "id = 3", ["[[camera]] #1.id", "expected a string"]),
    (CAMERAS, 'id = "left"', 'id = "a/b"', ["[[camera]] #1.id", "folder name"]),
    (CAMERAS, 'driver = "v4l2"', 'driver = "gstreamer"', ["[defaults].driver", "v4l2"]),
    (CAMERAS, 'pixel_format = "Y16"', 'pixel_format = "NV12"', ["[[camera]] #2.pixel_format", "GREY"]),
    (GRID + "[mock]\nscene = 'forest'\n", "", "", ["[mock].scene", "room"]),
    (GRID + "[mock]\ndrop_rate = 1.5\n", "", "", ["[mock].drop_rate", "<= 1"]),
    (GRID + "[mock]\nmjpg_quality = 0\n", "", "", ["[mock].mjpg_quality", ">= 1"]),
    (GRID + "[mock]\nmjpg_quality = 95.5\n", "", "", ["[mock].mjpg_quality", "expected an integer"]),
    (GRID, 'name = "g"\n', "", ["[rig].name", "missing"]),
    (GRID, "[rig]", "[rig]\n[rig]", ["invalid TOML"]),
    # structure
    (GRID, "[grid]", '[[camera]]\nid = "x"\nposition = [0, 0, 0]\n[grid]', ["exactly one"]),
    (GRID, "[grid]\nrows = 2\ncols = 3\npitch = 0.1", "", ["exactly one"]),
    (CAMERAS, 'id = "right"', 'id = "left"', ["duplicate camera id 'left'"]),
    (GRID + "[mock.disconnect_after]\ncam99 = 3\n", "", "", ["[mock].disconnect_after.cam99", "no camera"]),
    (GRID, "[grid]", 'lens = "missing.cameramodel"\n[grid]', ["[defaults].lens", "missing.cameramodel"]),
    (CAMERAS, 'id = "left"', 'id = "left"\nlens = "nope/x.cameramodel"', ["[[camera]] #1.lens", "no such"]),
])
def test_rig_errors(tmp_path, base, old, new, substrings):
    assert old in base
    p = _rig(tmp_path, base.replace(old, new, 1))
    _expect(p, *substrings)


def test_missing_rig_file(tmp_path):
    _expect(tmp_path / "nope.toml", "no such file")


@pytest.mark.parametrize("old, new, substrings", [
    ("'intrinsics': [ 55.42562584,", "'intrinsics': [ 0.0,", ["intrinsics", "focal lengths (fx, fy) must be > 0"]),
    ("'intrinsics': [ 55.42562584,", "'intrinsics': [ -55.4,", ["intrinsics", "must be > 0"]),
    ("31.5, 23.5,]", "31.5, 1e999,]", ["intrinsics: non-finite value"]),
    ("'rt_cam_ref': [ 0, 0, 0, 0.05, -0, -0,],\n    'extrinsics': [ 0, 0, 0, 0.05, -0, -0,],",
     "'rt_cam_ref': [ 0, 0, 0, 1e999, -0, -0,],\n    #", ["extrinsics: non-finite value"]),
])
def test_cameramodel_values_no_camera_has(tmp_path, old, new, substrings):
    """mrcal's parser takes any numbers; a model that no camera can have (a focal length of 0, a NaN)
    is one error naming the file before any ray is computed from it."""
    from polycam.cameras import load_cameramodel, nominal_cameramodel, write_cameramodel

    rig_file = tmp_path / "r.toml"
    rig_file.write_text('[rig]\nname = "r"\n[defaults]\nwidth = 64\nheight = 48\n'
                        '[grid]\nrows = 1\ncols = 3\npitch = 0.05\n')
    path = write_cameramodel(nominal_cameramodel(load_rig(rig_file).cameras[0]), tmp_path / "c.cameramodel")
    load_cameramodel(path)
    text = path.read_text()
    assert old in text
    path.write_text(text.replace(old, new, 1))
    with pytest.raises(FormatError) as e:
        load_cameramodel(path)
    msg = str(e.value)
    assert msg.startswith(f"{path}: ") and "\n" not in msg, msg
    for s in substrings:
        assert s in msg, msg
