"""Resampling sessions into light-field stores: against a direct render, in-process and
through dask, missing images, and the ``polycam resample`` command."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from polycam.errors import InputError
from polycam.lfstore import open_lightfield
from polycam.lightfield import LightFieldGrid
from polycam.rig import load_rig
from polycam.session import SessionWriter, open_session
from polycam.synth import render_lightfield, room_scene, synth_session, true_cameramodels
from resample import ResampleOptions, Resampler, auto_grid, resample_session
from tolerances import RESAMPLE_DIRECT_PSNR_DB, RESAMPLE_MIDVIEW_PSNR_DB

REPO = Path(__file__).resolve().parents[1]


def _rig(tmp: Path) -> Path:
    import mrcal

    lens = tmp / "lens.cameramodel"
    mrcal.cameramodel(intrinsics=("LENSMODEL_OPENCV4", np.array([100.0, 100.0, 79.5, 59.5, -0.12, 0.02, 0.001, -0.001])),
                      imagersize=np.array([160, 120])).write(str(lens))
    p = tmp / "rig.toml"
    p.write_text(f"""[rig]
name = "irregular3x3"
[defaults]
driver = "mock"
width = 64
height = 48
fps = 30
fov_deg = 60
lens = "{lens}"
[grid]
rows = 3
cols = 3
pitch = 0.02
[mock]
scene = "room"
motion = "smooth"
seed = 2
noise = 0.0
""")
    return p


@pytest.fixture(scope="module")
def session(tmp_path_factory):
    """A 3-frame session of an irregular 3x3 rig (rotations of ~2 deg, a distorting lens,
    focal perturbations; true models in calib/), and its scene."""
    tmp = tmp_path_factory.mktemp("resample_session")
    rig = load_rig(_rig(tmp))
    scene = room_scene(4.0, seed=2)
    synth_session(rig, tmp / "session", scene=scene, frames=3, seed=2, supersample=2,
                  perturb_rotation_deg=2.0, perturb_focal_frac=0.01)
    return tmp / "session", scene


def _psnr(a, b, mask):
    return float(10 * np.log10(1.0 / np.mean((a[mask] - b[mask]) ** 2)))


def test_irregular_rig_against_a_direct_render(session):
    """At viewpoints where cameras sit the resampled light field matches the grid rendered
    directly. Half-way between two cameras the pull-push alone gives the linear
    interpolation of their resampled views at full (u, v) resolution (the depth-free
    limit); the default fills those views along the disparity instead (camera views
    unchanged). Both flag them as not covered. (At 64x48 pixels the resampling error at
    the cameras dominates; benchmarks/bench_resample.py compares the views between
    cameras with interpolated direct views at full size.)"""
    path, scene = session
    s = open_session(path)
    models = s.calibration()
    grid = auto_grid(models)
    assert (grid.y.count, grid.x.count) == (5, 5)
    r = Resampler(models, grid).resample(s.read_frame(1))
    r_pp = Resampler(models, grid, options=ResampleOptions(view_fill="pushpull")).resample(s.read_frame(1))
    ref = render_lightfield(scene, grid, s.groundtruth().T_world_rig[1], supersample=4)
    at_cam = np.zeros(grid.shape, bool)
    at_cam[:, ::2, ::2] = True
    good = at_cam & (r.W > 0.5)
    assert good.sum() > 0.5 * at_cam.sum()
    psnr_cam = _psnr(r.L, ref, good)
    assert psnr_cam >= RESAMPLE_DIRECT_PSNR_DB
    np.testing.assert_array_equal(r.L[at_cam], r_pp.L[at_cam])
    # half-way between two cameras along x, where both neighbours are covered
    both = (r.W[:, ::2, 0:-1:2] > 0.5) & (r.W[:, ::2, 2::2] > 0.5)
    lin = 0.5 * (r_pp.L[:, ::2, 0:-1:2] + r_pp.L[:, ::2, 2::2])
    assert _psnr(r_pp.L[:, ::2, 1::2], lin, both) >= RESAMPLE_MIDVIEW_PSNR_DB
    assert _psnr(r.L[:, ::2, 1::2], ref[:, ::2, 1::2], both) >= RESAMPLE_DIRECT_PSNR_DB
    for x in (r, r_pp):
        assert np.all(x.W[:, ::2, 1::2] <= 0.5 + 1e-6)       # interpolated views are not "covered"


def test_session_to_store_in_process(session, tmp_path):
    path, _ = session
    out = tmp_path / "lf.zarr"
    seen = []
    summ = resample_session(path, out, scheduler="sync", progress=lambda d, n: seen.append((d, n)))
    assert seen == [(1, 3), (2, 3), (3, 3)]
    assert summ.frames == 3 and summ.cameras == 9 and summ.scheduler == "sync" and summ.channels == 1
    lf = open_lightfield(out)
    s = open_session(path)
    np.testing.assert_array_equal(lf.timestamps_ns, s.timestamps_ns)
    assert lf.has_weights and lf.grid == summ.grid
    np.testing.assert_array_equal(lf.groundtruth().T_world_rig, s.groundtruth().T_world_rig)
    rs = Resampler(s.calibration(), lf.grid)
    for t in (0, 2):
        r = rs.resample(s.read_frame(t))
        np.testing.assert_array_equal(lf.frame(t), r.L)
        np.testing.assert_array_equal(lf.weights(t), r.W)
    assert not (tmp_path / "lf.zarr.partial").exists()
    # the camera centres, for the depth refinement: one per camera, at its view, ~on it
    pos = lf.camera_positions
    np.testing.assert_array_equal(pos, rs.camera_positions())
    at = np.isfinite(pos[..., 0])
    assert at.sum() == 9 and at[0, ::2, ::2].all()
    iy, ix = np.nonzero(at[0])
    assert np.max(np.abs(pos[0, iy, ix] - np.stack([iy, ix], -1))) < 0.5
    # the cameras' sensor noise in the first frame's images, as the session resampled on the fly has it
    from resample.resampler import images_noise_sigma

    est = images_noise_sigma(s.read_frame(0), rs.cameras)
    assert lf.camera_noise_images == 9 and lf.camera_noise_sigma == pytest.approx(np.median(list(est.values())))
    with pytest.raises(InputError, match="already exists"):
        resample_session(path, out, scheduler="sync")


def test_a_grid_the_cameras_do_not_see(session, tmp_path, caplog):
    """A grid on the face behind the cameras is refused before the store is made (it would be
    W = 0 everywhere); a grid with that face beside the one they look through is resampled,
    with a warning naming the empty face."""
    import logging

    path, _ = session
    front = auto_grid(open_session(path).calibration())
    back = LightFieldGrid.cube(["-z"], f=front.faces[0].f, z_pi=front.faces[0].z_pi, x=front.x, y=front.y,
                               u=front.u, v=front.v)
    with pytest.raises(InputError, match="no camera ray reaches the grid's face"):
        resample_session(path, tmp_path / "back.zarr", grid=back, scheduler="sync")
    assert not (tmp_path / "back.zarr").exists() and not (tmp_path / "back.zarr.partial").exists()
    both = LightFieldGrid.cube(["+z", "-z"], f=front.faces[0].f, z_pi=front.faces[0].z_pi, x=front.x,
                               y=front.y, u=front.u, v=front.v)
    assert [f.name for f in front.faces] == ["+z"]
    with caplog.at_level(logging.WARNING, logger="resample.pipeline"):
        resample_session(path, tmp_path / "both.zarr", grid=both, scheduler="sync")
    assert any("face(s) -z" in r.getMessage() for r in caplog.records)
    assert np.all(open_lightfield(tmp_path / "both.zarr").weights(0)[1] == 0)


def test_dask_workers_write_the_same_store(session, tmp_path):
    """A local dask cluster of two worker processes (frames out of order, written straight
    into their chunks) gives the store of the in-process run, byte for byte."""
    path, _ = session
    a = resample_session(path, tmp_path / "sync.zarr", scheduler="sync")
    b = resample_session(path, tmp_path / "dask.zarr", workers=2)
    assert b.scheduler == "local:2"
    la, lb = open_lightfield(a.path), open_lightfield(b.path)
    for t in range(3):
        np.testing.assert_array_equal(la.frame(t), lb.frame(t))
        np.testing.assert_array_equal(la.weights(t), lb.weights(t))


def test_an_existing_dask_scheduler(session, tmp_path):
    from distributed import LocalCluster

    path, _ = session
    with LocalCluster(n_workers=1, threads_per_worker=2, processes=True, dashboard_address=":0") as cluster:
        summ = resample_session(path, tmp_path / "lf.zarr", scheduler=cluster.scheduler_address)
    assert summ.scheduler == cluster.scheduler_address
    ref = resample_session(path, tmp_path / "ref.zarr", scheduler="sync")
    np.testing.assert_array_equal(open_lightfield(summ.path).frame(1), open_lightfield(ref.path).frame(1))


def test_frames_with_missing_images(tmp_path):
    """A camera that dropped a frame: that frame is resampled from the others; a frame with
    no image at all is written as zeros."""
    rig = load_rig(_rig(tmp_path))
    models = true_cameramodels(rig, seed=1, perturb_rotation_deg=1.0)
    rng = np.random.default_rng(0)
    with SessionWriter(tmp_path / "s", rig) as w:
        for cam, m in models.items():
            w.write_calibration(cam, m)
        imgs = {c.id: rng.integers(0, 256, (48, 64), dtype=np.uint8) for c in rig.cameras}
        w.add_frame(1000, imgs)
        w.add_frame(2000, {**imgs, "cam04": None})
        w.add_frame(3000, {c: None for c in imgs})
    summ = resample_session(tmp_path / "s", tmp_path / "lf.zarr", scheduler="sync")
    assert summ.missing_images == 1 + 9 and summ.empty_frames == 1
    lf = open_lightfield(summ.path)
    sub = {c: m for c, m in open_session(tmp_path / "s").calibration().items() if c != "cam04"}
    r = Resampler(sub, lf.grid).resample({c: imgs[c] for c in sub})
    np.testing.assert_array_equal(lf.frame(1), r.L)
    assert np.all(lf.frame(2) == 0) and np.all(lf.weights(2) == 0)


def test_rgb_session_gives_a_colour_store(tmp_path):
    p = _rig(tmp_path)
    p.write_text(p.read_text().replace('fov_deg = 60', 'fov_deg = 60\npixel_format = "RGB"'))
    rig = load_rig(p)
    models = true_cameramodels(rig, seed=1, perturb_rotation_deg=1.0)
    rng = np.random.default_rng(1)
    with SessionWriter(tmp_path / "s", rig) as w:
        for cam, m in models.items():
            w.write_calibration(cam, m)
        imgs = {c.id: rng.integers(0, 256, (48, 64, 3), dtype=np.uint8) for c in rig.cameras}
        w.add_frame(1000, imgs)
        w.add_frame(2000, imgs)
    summ = resample_session(tmp_path / "s", tmp_path / "lf.zarr", scheduler="sync")
    lf = open_lightfield(summ.path)
    assert summ.channels == 3 and lf.colour == 3 and lf.frame(1).shape == (*lf.grid.shape, 3)
    r = Resampler(open_session(tmp_path / "s").calibration(), lf.grid, channels=3).resample(imgs)
    np.testing.assert_array_equal(lf.frame(1), r.L)
    rs_grey = Resampler(open_session(tmp_path / "s").calibration(), lf.grid)
    grey = rs_grey.resample({c: img[..., 1] for c, img in imgs.items()})
    # channels are independent, except for the disparities of the views filled between
    # cameras (found on the mean of the channels)
    measured = np.ones(lf.grid.shape, bool)
    for f, j, i in rs_grey.fill_plan().targets:
        measured[f, j, i] = False
    assert 0 < measured.mean() < 1
    np.testing.assert_allclose(lf.frame(0)[..., 1][measured], grey.L[measured], atol=1e-6)
    np.testing.assert_array_equal(lf.weights(0), grey.W)


def _polycam(*args):
    return subprocess.run([sys.executable, "-m", "polycam.cli", *map(str, args)], capture_output=True,
                          text=True, cwd=REPO, timeout=300)


def test_cli(session, tmp_path):
    path, _ = session
    grid_toml = tmp_path / "grid.toml"
    grid_toml.write_text("[grid]\nf = 40.0\nz_pi = 0.0\nfaces = [\"+z\"]\n"
                         "x = [-0.02, 0.02, 3]\ny = [-0.02, 0.02, 3]\nu = [-20.0, 20.0, 21]\nv = [-15.0, 15.0, 16]\n")
    out = tmp_path / "lf.zarr"
    p = _polycam("resample", path, "--out", out, "--grid", grid_toml, "--workers", "0")
    assert p.returncode == 0, p.stderr
    assert "wrote" in p.stdout and "3 frames" in p.stdout
    lf = open_lightfield(out)
    assert lf.grid.shape == (1, 3, 3, 16, 21) and lf.grid.faces[0].f == 40.0
    out2 = tmp_path / "lf-pp.zarr"
    p = _polycam("resample", path, "--out", out2, "--grid", grid_toml, "--workers", "0", "--view-fill", "pushpull")
    assert p.returncode == 0, p.stderr
    assert open_lightfield(out2).grid.shape == lf.grid.shape
    p = _polycam("resample", path, "--out", out, "--workers", "0")
    assert p.returncode == 1 and p.stderr.count("\n") == 1 and "already exists" in p.stderr
    out3 = tmp_path / "lf-x4.zarr"        # the automatic grid at 4 views per camera spacing, 2 pixels a step
    p = _polycam("resample", path, "--out", out3, "--workers", "0", "--xy-oversample", "4", "--uv-step", "2")
    assert p.returncode == 0, p.stderr
    la = open_lightfield(out3)
    auto = auto_grid(open_session(path).calibration(), uv_step_px=2.0, xy_oversample=4)
    assert la.grid.shape == auto.shape and (la.grid.y.count, la.grid.x.count) == (9, 9)
    assert la.attrs["resample"]["xy_oversample"] == 4 and la.attrs["resample"]["uv_step_px"] == 2.0
    assert "xy_oversample" not in lf.attrs["resample"]          # a given grid records no automatic choice
    p = _polycam("resample", path, "--out", tmp_path / "x.zarr", "--grid", grid_toml, "--xy-oversample", "4")
    assert p.returncode == 1 and p.stderr.count("\n") == 1 and "not with --grid" in p.stderr
    p = _polycam("resample", path, "--calib", tmp_path / "nope", "--out", tmp_path / "x.zarr")
    assert p.returncode == 1 and "no such calibration folder" in p.stderr
    p = _polycam("resample", tmp_path, "--out", tmp_path / "x.zarr")
    assert p.returncode == 1 and "not a session folder" in p.stderr
    assert not (tmp_path / "x.zarr").exists()
    bad = tmp_path / "bad.toml"
    bad.write_text("[grid]\nf = 40.0\n")
    p = _polycam("resample", path, "--out", tmp_path / "x.zarr", "--grid", bad)
    assert p.returncode == 1 and "bad.toml" in p.stderr


def test_cli_truncated_image_is_one_line(session, tmp_path):
    """A truncated PNG: polycam's one line naming it, without OpenCV's own warning about the same file
    (the CLI quietens OpenCV's log below errors), status 1, no store."""
    import shutil

    path, _ = session
    copy = tmp_path / "s"
    shutil.copytree(path, copy)
    png = sorted((copy / "cam04" / "data").glob("*.png"))[0]
    png.write_bytes(png.read_bytes()[:200])
    p = _polycam("resample", copy, "--out", tmp_path / "lf.zarr", "--workers", "0")
    assert p.returncode == 1 and p.stderr == f"polycam: error: {png}: unreadable PNG (corrupt or truncated)\n", p.stderr
    assert not (tmp_path / "lf.zarr").exists()


def test_session_without_calibration(tmp_path):
    rig = load_rig(_rig(tmp_path))
    with SessionWriter(tmp_path / "s", rig) as w:
        w.add_frame(1000, {c.id: np.zeros((48, 64), np.uint8) for c in rig.cameras})
    with pytest.raises(InputError, match="no calibration"):
        resample_session(tmp_path / "s", tmp_path / "lf.zarr")


def test_grid_from_a_grid_file_is_used_as_given(session, tmp_path):
    path, _ = session
    s = open_session(path)
    g = auto_grid(s.calibration(), uv_step_px=2.0)
    grid = LightFieldGrid.cube(["+z"], f=g.faces[0].f, z_pi=0.01, x=g.x, y=g.y, u=g.u, v=g.v)
    summ = resample_session(path, tmp_path / "lf.zarr", grid=grid, scheduler="sync")
    assert open_lightfield(summ.path).grid == grid


def test_unsynchronised_cameras_moved_to_their_capture(tmp_path, capsys):
    """capture_motion (polycam resample --sync-motion TRAJ.tum): every frame resampled with each camera
    where it captured its image: the frames of resample.stream.SessionLightField(capture_motion=...), in
    process and through dask alike; the store says so, and a trajectory without the frame times is one
    line naming it."""
    from polycam.cli import main
    from polycam.trajectory import read_tum
    from resample.stream import SessionLightField

    rig = load_rig(_rig(tmp_path))
    path = synth_session(rig, tmp_path / "u", frames=3, seed=2, supersample=1, sync_spread_ms=16.0)
    truth = read_tum(path / "groundtruth.tum")
    motion = truth.relative()
    a = resample_session(path, tmp_path / "sync.zarr", scheduler="sync", capture_motion=motion)
    b = resample_session(path, tmp_path / "dask.zarr", workers=2, capture_motion=motion)
    plain = resample_session(path, tmp_path / "plain.zarr", scheduler="sync")
    assert a.cameras_moved_to_capture and b.cameras_moved_to_capture and not plain.cameras_moved_to_capture
    la, lb, lp = (open_lightfield(s.path) for s in (a, b, plain))
    stream = SessionLightField(path, grid=a.grid, capture_motion=motion, camera_noise=False)
    for t in range(3):
        np.testing.assert_array_equal(la.frame(t), stream.frame(t))
        np.testing.assert_array_equal(la.weights(t), stream.weights(t))
        np.testing.assert_array_equal(lb.frame(t), la.frame(t))
    assert not np.array_equal(la.frame(1), lp.frame(1))
    assert la.attrs["resample"]["cameras_moved_to_capture"] is True
    assert "cameras_moved_to_capture" not in lp.attrs["resample"]
    # the command, with the ground truth as the trajectory; and one without the frames' times
    assert main(["resample", str(path), "--out", str(tmp_path / "cli.zarr"), "--workers", "0",
                 "--sync-motion", str(path / "groundtruth.tum")]) == 0
    assert "each frame resampled with every camera where it captured its image" in capsys.readouterr().out
    np.testing.assert_array_equal(open_lightfield(tmp_path / "cli.zarr").frame(2), la.frame(2))
    (tmp_path / "short.tum").write_text((path / "groundtruth.tum").read_text().splitlines()[0] + "\n")
    assert main(["resample", str(path), "--out", str(tmp_path / "bad.zarr"), "--workers", "0",
                 "--sync-motion", str(tmp_path / "short.tum")]) == 1
    err = [l for l in capsys.readouterr().err.splitlines() if l.strip()]
    assert len(err) == 1 and "short.tum" in err[0] and "no pose within 1 ms" in err[0], err
    assert not (tmp_path / "bad.zarr").exists()
