"""COLMAP interop and rays: text-model import/export round trips (the real kettle model),
rig configs pycolmap reads, OpenCV / Kalibr exports, per-pixel rig-frame rays and ray
tables, and the target-free COLMAP calibration on a small synthetic session (slow)."""

from __future__ import annotations

import json
import logging
import math
from pathlib import Path

import numpy as np
import pytest

from polycam.cameras import T_rig_cam_of
from polycam.errors import FormatError
from polycam.geometry import T_from_rt
from polycam.rig import load_rig

from conftest import shared_data
from tolerances import (CALIB_COLMAP_FOCAL_REL, CALIB_COLMAP_POSITION_M, CALIB_COLMAP_TEXT_ATOL,
                        CALIB_MODEL_ROUNDTRIP_ATOL, CALIB_RAY_REPROJ_PX)


def _models(rng, lenses=("LENSMODEL_OPENCV8", "LENSMODEL_OPENCV4", "LENSMODEL_PINHOLE", "LENSMODEL_OPENCV5")):
    """Camera id → random plausible mrcal model (rt_cam_ref = T_cam_rig)."""
    import mrcal

    out = {}
    for k, lens in enumerate(lenses):
        n = mrcal.lensmodel_num_params(lens)
        intr = np.concatenate([[300 + 10 * k, 301 + 10 * k, 159.5 + k, 119.5 - k], rng.normal(size=n - 4) * 0.01])
        rt = np.concatenate([rng.normal(size=3) * 0.05, rng.normal(size=3) * 0.1])
        out[f"cam{k:02d}"] = mrcal.cameramodel(intrinsics=(lens, intr), imagersize=np.array([320, 240]), rt_cam_ref=rt)
    return out


def _same(a: dict, b: dict, atol: float) -> None:
    assert list(a) == list(b)
    for k in a:
        la, ia = a[k].intrinsics()
        lb, ib = b[k].intrinsics()
        if la == "LENSMODEL_OPENCV5" and lb == "LENSMODEL_OPENCV8":   # OPENCV5 is exported as FULL_OPENCV
            ib = ib[:9]
        else:
            assert la == lb
        np.testing.assert_allclose(ib, ia, atol=atol * max(1.0, np.abs(ia).max()))
        np.testing.assert_allclose(T_from_rt(b[k].rt_cam_ref()), T_from_rt(a[k].rt_cam_ref()), atol=atol)
        assert list(a[k].imagersize()) == list(b[k].imagersize())


def test_kettle_import_export_round_trip(tmp_path):
    """The real kettle COLMAP model: import → write → import is lossless, and pycolmap reads
    our files to the same cameras and poses (pixel convention included)."""
    import pycolmap

    from calib import import_colmap_text, read_colmap_text, write_colmap_text

    kettle = shared_data("lumigraph-kettle")
    models = import_colmap_text(kettle)
    assert len(models) == 28
    cams, images = read_colmap_text(kettle)
    first = images[0]
    m = models[first.name]
    c = cams[first.camera_id]
    assert m.intrinsics()[0] == "LENSMODEL_OPENCV4"
    assert m.intrinsics()[1][2] == pytest.approx(c.params[1] - 0.5)       # COLMAP centres at +0.5
    write_colmap_text(models, tmp_path / "out")
    back = import_colmap_text(tmp_path / "out")
    _same(models, back, CALIB_COLMAP_TEXT_ATOL)
    rec = pycolmap.Reconstruction()
    rec.read_text(str(tmp_path / "out"))
    # the kettle's own rows, converted by pycolmap (not by our code)
    raw_cams = {int(f[0]): np.array(f[4:], float) for f in
                (ln.split() for ln in (kettle / "cameras.txt").read_text().splitlines() if ln and ln[0] != "#")}
    rows = [ln.split(maxsplit=9) for ln in (kettle / "images.txt").read_text().splitlines() if ln and ln[0] != "#"]
    raw = {f[9]: f for f in rows[0::2]}
    names = list(models)                # our image ids are 1, 2, ... in this order
    for im in rec.images.values():
        # COLMAP's text reader stops a NAME at the first space (the kettle's names have one)
        assert names[im.image_id - 1].startswith(im.name)
        f = raw[names[im.image_id - 1]]
        qw, qx, qy, qz, tx, ty, tz = (float(v) for v in f[1:8])
        want = pycolmap.Rigid3d(pycolmap.Rotation3d(np.array([qx, qy, qz, qw])), np.array([tx, ty, tz]))
        np.testing.assert_allclose(np.asarray(im.cam_from_world().matrix()), np.asarray(want.matrix()), atol=1e-6)
        p_new = np.asarray(rec.camera(im.camera_id).params)       # OPENCV (fx fy cx cy k1 k2 p1 p2)
        np.testing.assert_allclose(p_new[[0, 2, 3, 4]], raw_cams[int(f[8])], rtol=1e-6)


def test_model_conversions_round_trip(tmp_path, rng):
    """mrcal → COLMAP text → mrcal and mrcal → OpenCV YAML → mrcal for every supported lens."""
    from calib import import_colmap_text, read_opencv_yaml, write_colmap_text, write_opencv_yaml

    models = _models(rng)
    write_colmap_text(models, tmp_path / "c")
    _same(models, import_colmap_text(tmp_path / "c"), CALIB_COLMAP_TEXT_ATOL)
    write_opencv_yaml(models, tmp_path / "o.yaml")
    _same(models, read_opencv_yaml(tmp_path / "o.yaml"), CALIB_MODEL_ROUNDTRIP_ATOL)


def test_unsupported_models_are_refused(rng):
    import mrcal

    from calib import mrcal_to_colmap
    from polycam.errors import InputError

    lens = "LENSMODEL_SPLINED_STEREOGRAPHIC_order=3_Nx=8_Ny=6_fov_x_deg=80"
    intr = np.zeros(mrcal.lensmodel_num_params(lens))
    with pytest.raises(InputError, match="no COLMAP equivalent"):
        mrcal_to_colmap(lens, intr)


def test_rig_config_is_read_by_pycolmap(tmp_path, rng):
    """Our rig_config.json parses with pycolmap.read_rig_config with the right cam_from_rig."""
    import pycolmap

    from calib import write_rig_config

    models = _models(rng, ("LENSMODEL_OPENCV4",) * 3)
    p = write_rig_config(models, tmp_path / "rig_config.json")
    doc = json.loads(p.read_text())
    configs = pycolmap.read_rig_config(str(p))
    assert len(configs) == 1 and len(configs[0].cameras) == 3
    T0 = T_from_rt(models["cam00"].rt_cam_ref())
    for cam, c, entry in zip(models, configs[0].cameras, doc[0]["cameras"]):
        assert c.image_prefix == f"{cam}/"
        if cam == "cam00":
            assert c.ref_sensor
            continue
        want = T_from_rt(models[cam].rt_cam_ref()) @ np.linalg.inv(T0)
        got = np.asarray(c.cam_from_rig.matrix())
        np.testing.assert_allclose(got, want[:3], atol=1e-9)
        assert entry["camera_model_name"] == "OPENCV"


def test_kalibr_camchain(tmp_path, rng):
    from calib import write_kalibr_camchain
    from polycam.errors import InputError

    models = _models(rng, ("LENSMODEL_OPENCV4", "LENSMODEL_PINHOLE"))
    text = write_kalibr_camchain(models, tmp_path / "camchain.yaml").read_text()
    assert "cam0:" in text and "cam1:" in text and "T_cn_cnm1:" in text and "distortion_model: radtan" in text
    with pytest.raises(InputError, match="Kalibr"):
        write_kalibr_camchain(_models(rng, ("LENSMODEL_OPENCV8",)), tmp_path / "x.yaml")


def test_pixel_rays_reproject(rng):
    """o + s d of every pixel's rig-frame ray projects back onto that pixel."""
    import mrcal

    from calib import pixel_rays

    for model in _models(rng).values():
        rays, valid = pixel_rays(model, supersample=2)
        W, H = model.imagersize()
        assert rays.shape == (H, W, 4) and valid.all()
        np.testing.assert_allclose(np.linalg.norm(rays.directions, axis=-1), 1.0, atol=1e-12)
        p_rig = rays.points_at(np.full(rays.shape, 2.5))
        T = np.linalg.inv(T_rig_cam_of(model))
        p_cam = p_rig @ T[:3, :3].T + T[:3, 3]
        q = mrcal.project(np.ascontiguousarray(p_cam), *model.intrinsics())
        from polycam.cameras import pixel_grid

        assert np.abs(q - pixel_grid(int(W), int(H), 2)).max() <= CALIB_RAY_REPROJ_PX


def test_ray_table_round_trip(tmp_path, rng):
    from calib import pixel_rays, read_ray_table, write_ray_table

    models = _models(rng, ("LENSMODEL_OPENCV8",))
    (p,) = write_ray_table(models, tmp_path / "rays")
    rays, valid, q = read_ray_table(p)
    ref, ref_valid = pixel_rays(models["cam00"])
    assert rays.shape == ref.shape and (valid == ref_valid).all()
    np.testing.assert_allclose(rays.directions, ref.directions, atol=1e-6)     # float32 table
    np.testing.assert_allclose(rays.origins, ref.origins, atol=1e-6)


def test_cli_from_colmap(tmp_path):
    """`polycam calibrate --from-colmap` turns the kettle model into cameramodels and exports."""
    from polycam.cli import main

    kettle = shared_data("lumigraph-kettle")
    assert main(["calibrate", "--from-colmap", str(kettle), "--out", str(tmp_path / "k"), "--export", "colmap"]) == 0
    files = sorted((tmp_path / "k").glob("*.cameramodel"))
    assert len(files) == 28
    assert (tmp_path / "k" / "colmap" / "rig_config.json").is_file()


def _moving_rig_session(tmp_path):
    """A rendered 2x2 rig (cameras 6 cm apart, perturbed) moving through a room, 8 frames
    (3 cm and 1 degree per frame: with 5 cm and 2 degrees COLMAP's incremental mapping was
    marginal here, 2 of 8 frames registered with one seed in 18 runs on a loaded machine, and
    with all three seeds of the retry test in one CI run; 18 of 18 mapped whole now)."""
    from polycam.session import open_session
    from polycam.synth import synth_session

    p = tmp_path / "rig.toml"
    p.write_text("""[rig]
name = "colmaptest"
[defaults]
width = 320
height = 240
fov_deg = 70
[grid]
rows = 2
cols = 2
pitch = 0.06
[mock]
scene = "room"
motion = "smooth"
seed = 3
distance = 3.0
step_t = 0.03
step_r_deg = 1.0
""")
    rig = load_rig(p)
    out = synth_session(rig, tmp_path / "s", frames=8, perturb_position_m=0.001, perturb_rotation_deg=0.3,
                        perturb_focal_frac=0.01)
    return open_session(out)


@pytest.mark.slow
def test_colmap_target_free_on_a_moving_rig(tmp_path):
    """SIFT + mapping + rig bundle adjustment on a rendered 2x2 rig moving through a room:
    camera centres (metric from the rig file) and focal lengths near the truth; a second run
    with the same seed gives the same cameras to the last bit (seeded RANSACs, one-thread
    extraction, mapping and final bundle adjustment: calib.colmap.reconstruct_images)."""
    from calib import calibrate_colmap

    s = _moving_rig_session(tmp_path)
    cal = calibrate_colmap(s)
    again = calibrate_colmap(s)
    for c in cal.models:
        for a, b in ((cal.models[c].intrinsics()[1], again.models[c].intrinsics()[1]),
                     (cal.models[c].extrinsics_rt_fromref(), again.models[c].extrinsics_rt_fromref())):
            assert np.array_equal(a, b), c
    true = s.calibration()
    assert cal.frames_registered == 8 and cal.rms_px < 0.5
    from calib.align import fit_rig_frame

    cams = list(true)
    fit = fit_rig_frame(np.stack([T_rig_cam_of(cal.models[c]) for c in cams]),
                        np.stack([T_rig_cam_of(true[c]) for c in cams]), position_sigma_m=1.0,
                        rotation_sigma_deg=1e-3)
    assert fit.position_residuals_m.max() <= CALIB_COLMAP_POSITION_M
    for c in cams:
        f_est, f_true = cal.models[c].intrinsics()[1][0], true[c].intrinsics()[1][0]
        assert abs(f_est / f_true - 1) <= CALIB_COLMAP_FOCAL_REL
    assert math.isfinite(cal.scale) and cal.scale_source == "rig"


@pytest.mark.slow
def test_colmap_retries_a_poor_mapping_with_the_next_seed(tmp_path, monkeypatch, caplog):
    """A mapping that registers too few frames (here: the first attempt sees only frames 0
    and 1) is retried with the next seed, which maps the whole session."""
    import calib.colmap as cc

    s = _moving_rig_session(tmp_path)
    real = cc.reconstruct_images
    seeds = []

    def first_poor(img_dir, workdir, **kw):
        seeds.append(kw["seed"])
        if len(seeds) == 1:
            kw["image_names"] = sorted(str(q.relative_to(img_dir)) for q in Path(img_dir).rglob("*.png")
                                       if int(q.stem) in (0, 1))
        return real(img_dir, workdir, **kw)

    monkeypatch.setattr(cc, "reconstruct_images", first_poor)
    with caplog.at_level(logging.WARNING, logger="calib.colmap"):
        cal = cc.calibrate_colmap(s, seed=5)
    # the retry takes the next seeds in order; the second attempt itself may, rarely, map
    # too little (COLMAP's mapper is not bit-reproducible across machines: a fresh-clone CI
    # run needed the third seed), which the third attempt then covers
    assert seeds[:2] == [5, 6] and len(seeds) <= cc._MAPPING_ATTEMPTS and cal.frames_registered == 8
    assert "retrying with the next seed" in caplog.text


def test_board_scale_from_triangulated_corners(tmp_path):
    """The COLMAP path's metric scale from a board: true geometry shrunk by k gives back k."""
    from calib.colmap import _board_scale
    from polycam.board import load_board
    from polycam.geometry import T_inverse
    from polycam.session import open_session
    from polycam.synth import synth_board_session

    (tmp_path / "board.toml").write_text('[board]\ntype = "charuco"\nsquares = [5, 7]\nsquare_length = 0.04\n'
                                         'marker_length = 0.03\ndictionary = "DICT_5X5_100"\n')
    board = load_board(tmp_path / "board.toml")
    (tmp_path / "rig.toml").write_text('[rig]\nname = "pair"\n[defaults]\nwidth = 320\nheight = 240\nfov_deg = 60\n'
                                       '[grid]\nrows = 1\ncols = 2\npitch = 0.08\n')
    s = open_session(synth_board_session(load_rig(tmp_path / "rig.toml"), tmp_path / "s", board=board, frames=3,
                                         seed=1))
    true = s.calibration()
    k = 3.7
    T_rig_cam0 = T_rig_cam_of(true["cam00"])
    models_ref = {}
    for cam, m in true.items():
        T_cam_ref = T_inverse(T_rig_cam_of(m)) @ T_rig_cam0
        T_cam_ref[:3, 3] /= k
        models_ref[cam] = (m.intrinsics(), T_cam_ref)
    T_ref_world = T_inverse(T_rig_cam0)            # world = rig (static rig)
    T_ref_world[:3, 3] /= k
    scale = _board_scale(s, board, list(true), models_ref, {i: T_ref_world for i in range(len(s))})
    assert scale == pytest.approx(k, rel=0.01)


@pytest.mark.slow
def test_colmap_with_board_scale_end_to_end(tmp_path):
    """`polycam calibrate SESSION --board B --method colmap`: a 2x2 rig moving through a room
    with a ChArUco board on a stand; scale from the triangulated board, cameras near the truth."""
    import tomllib

    from polycam.board import load_board
    from polycam.cli import main
    from polycam.geometry import T_from_Rt
    from polycam.session import open_session
    from polycam.synth import make_trajectory, room_scene, synth_session

    (tmp_path / "board.toml").write_text('[board]\ntype = "charuco"\nsquares = [5, 7]\nsquare_length = 0.08\n'
                                         'marker_length = 0.06\ndictionary = "DICT_5X5_100"\n')
    board = load_board(tmp_path / "board.toml")
    (tmp_path / "rig.toml").write_text('[rig]\nname = "colmapboard"\n[defaults]\nwidth = 320\nheight = 240\n'
                                       'fov_deg = 70\n[grid]\nrows = 2\ncols = 2\npitch = 0.06\n')
    rig = load_rig(tmp_path / "rig.toml")
    bw, bh = board.size_m
    pps = 60
    image, H_image_board = board.render(pps, 0.5)
    margin = (image.shape[1] - board.cols * pps) / 2.0 * board.square_length / pps
    T_world_board = T_from_Rt(np.eye(3), np.array([-bw / 2, -bh / 2 + 0.1, 1.2]))      # 1.2 m ahead, facing the rig
    scene, _ = room_scene(3.0, seed=3).with_image_rect(image, T_world_board, (-margin, bw + margin, -margin,
                                                                               bh + margin), H_image_board[:2])
    out = synth_session(rig, tmp_path / "s", scene=scene, perturb_position_m=0.001, perturb_rotation_deg=0.3,
                        perturb_focal_frac=0.01,
                        trajectory=make_trajectory("smooth", 8, step_t=0.04, step_r_deg=2.0, seed=3))
    rc = main(["calibrate", str(out), "--board", str(tmp_path / "board.toml"), "--method", "colmap",
               "--out", str(tmp_path / "calib")])
    assert rc == 0
    report = tomllib.loads((tmp_path / "calib" / "report.toml").read_text())
    assert report["calibration"]["scale_source"] == "board"
    s = open_session(out)
    true, est = s.calibration(), s.calibration(tmp_path / "calib")
    from calib.align import fit_rig_frame

    cams = list(true)
    fit = fit_rig_frame(np.stack([T_rig_cam_of(est[c]) for c in cams]), np.stack([T_rig_cam_of(true[c]) for c in cams]),
                        position_sigma_m=1.0, rotation_sigma_deg=1e-3)
    assert fit.position_residuals_m.max() <= CALIB_COLMAP_POSITION_M
    for c in cams:
        assert abs(est[c].intrinsics()[1][0] / true[c].intrinsics()[1][0] - 1) <= CALIB_COLMAP_FOCAL_REL


_CAMERAS = "# CAMERA_ID MODEL WIDTH HEIGHT PARAMS\n1 PINHOLE 48 36 41 41 24 18\n"
_IMAGES = "1 1 0 0 0 0 0 0 1 cam00\n\n2 1 0 0 0 0.1 0 0 1 cam01\n\n"


@pytest.mark.parametrize("which, old, new, fragments", [
    ("cameras", "PINHOLE 48 36", "PINHOLE 0 36", ["cameras.txt", "line 2", "WIDTH and HEIGHT", "0 x 36"]),
    ("cameras", "PINHOLE 48 36", "PINHOLE 99999999999 36", ["line 2", "WIDTH and HEIGHT"]),
    ("cameras", "41 41 24", "nan nan 24", ["line 2", "non-finite parameter"]),
    ("cameras", "41 41 24", "0 41 24", ["line 2", "focal length must be > 0"]),
    ("cameras", "24 18", "inf 18", ["line 2", "non-finite parameter"]),
    ("cameras", "PINHOLE", "FOO", ["cameras.txt", "line 2", "model FOO has no mrcal equivalent"]),
    ("cameras", "18\n", "18\n1 PINHOLE 48 36 41 41 24 18\n", ["line 3", "camera 1 is listed twice"]),
    ("images", "0 0 0 0.1", "0 0 0 nan", ["images.txt", "line 3", "non-finite"]),
    ("images", "2 1 0 0 0 0.1 0 0 1 cam01", "2 1 0 0 0 0.1 0 0 1 cam00", ["line 3", "'cam00' is listed twice"]),
    ("images", "2 1 0 0 0 0.1 0 0 1 cam01", "1 1 0 0 0 0.1 0 0 1 cam01", ["line 3", "image 1 is listed twice"]),
])
def test_colmap_text_values_are_checked(tmp_path, which, old, new, fragments):
    """A COLMAP text model's values, not only its layout: sizes, finite parameters and poses, positive focal
    lengths, known models, ids and names once each; one line naming the file and the line."""
    from calib import read_colmap_text

    text = {"cameras": _CAMERAS, "images": _IMAGES}
    read_colmap_text(_write_model(tmp_path / "ok", text))
    assert old in text[which]
    text[which] = text[which].replace(old, new, 1)
    with pytest.raises(FormatError) as e:
        read_colmap_text(_write_model(tmp_path / "bad", text))
    msg = str(e.value)
    assert "\n" not in msg and str(tmp_path / "bad") in msg, msg
    for f in fragments:
        assert f in msg, msg


def _write_model(d, text):
    d.mkdir()
    (d / "cameras.txt").write_text(text["cameras"])
    (d / "images.txt").write_text(text["images"])
    return d
