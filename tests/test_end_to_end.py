"""End to end (issue 7): motion straight from a session (resampled on the fly) against motion
through a written light-field store, and the errors of sessions without calibration.
`polycam run` (the whole chain) is tested in tests/test_run.py."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest

from polycam.cli import main
from polycam.rig import load_rig
from polycam.synth import synth_session
from polycam.trajectory import read_tum
from conftest import REPO
from conftest import assert_one_line_error as _one_line_error
from conftest import mock_grid_rig_text
from tolerances import (TUM_POSITION_ATOL, E2E_SMALL_RIG_MOTION_REL, E2E_STREAM_VS_STORE_ATOL, MOTION_ARRAY_NOISE_STD_RATIO_MIN,
                        MOTION_ARRAY_STD_RATIO)

RIG_TEXT = mock_grid_rig_text("e2e3x3", 64, 48)


@pytest.fixture(scope="module")
def session(tmp_path_factory) -> Path:
    """A 3-frame session of a 3x3 rig of 64x48 cameras in the room, with true calib/."""
    tmp = tmp_path_factory.mktemp("e2e")
    (tmp / "rig.toml").write_text(RIG_TEXT)
    return synth_session(load_rig(tmp / "rig.toml"), tmp / "session", frames=3, seed=1)


def test_session_lightfield_equals_resampled_store(session, tmp_path):
    from polycam.lfstore import open_lightfield
    from resample import resample_session
    from resample.stream import SessionLightField

    resample_session(session, tmp_path / "lf.zarr", scheduler="sync")
    store = open_lightfield(tmp_path / "lf.zarr")
    lf = SessionLightField(session)
    assert lf.grid == store.grid
    assert np.array_equal(lf.timestamps_ns, store.timestamps_ns)
    for t in (1, 0, 2):
        np.testing.assert_allclose(lf.frame(t), store.frame(t), atol=E2E_STREAM_VS_STORE_ATOL)
        np.testing.assert_allclose(lf.weights(t), store.weights(t), atol=E2E_STREAM_VS_STORE_ATOL)
    assert lf.frames_resampled == 3          # frame(t) then weights(t): one resampling
    assert lf.groundtruth() is not None
    np.testing.assert_array_equal(lf.camera_positions, store.camera_positions)   # the depth refinement's sources
    assert np.isfinite(store.camera_positions[..., 0]).sum() == len(lf.models)


def test_motion_from_session_matches_motion_from_store(session, tmp_path, capsys):
    assert main(["resample", str(session), "--out", str(tmp_path / "lf.zarr"), "--workers", "0"]) == 0
    assert main(["motion", str(tmp_path / "lf.zarr"), "--out", str(tmp_path / "via_store.tum")]) == 0
    out = capsys.readouterr().out               # the cameras' noise, as polycam resample measured it
    assert "grey levels in the cameras' images" in out and "per resampled sample" not in out
    assert main(["info", str(tmp_path / "lf.zarr")]) == 0
    assert "the cameras' sensor noise" in capsys.readouterr().out
    assert main(["motion", str(session), "--out", str(tmp_path / "direct.tum"), "--calib", str(session / "calib"),
                 "--report", str(tmp_path / "rep"), "--uv-step", "1"]) == 0     # polycam resample's step
    out = capsys.readouterr().out
    assert "resampling" in out and "against" in out
    assert "grey levels in the cameras' images" in out and "per resampled sample" in out   # not the solver's estimate
    assert "noise estimate" not in out
    a, b = read_tum(tmp_path / "direct.tum"), read_tum(tmp_path / "via_store.tum")
    np.testing.assert_array_equal(a.timestamps_ns, b.timestamps_ns)
    np.testing.assert_allclose(a.T_world_rig, b.T_world_rig, atol=1e-6)
    assert (tmp_path / "rep" / "pairs.csv").exists() and (tmp_path / "rep" / "errors.png").exists()
    from polycam.evaluate import pair_errors

    err = pair_errors(a, read_tum(session / "groundtruth.tum"))
    assert np.median(err.t_rel) < E2E_SMALL_RIG_MOTION_REL
    assert np.median(err.w_rel) < E2E_SMALL_RIG_MOTION_REL


def test_motion_chooses_the_direction_step(session, tmp_path, capsys):
    """--uv-step auto (polycam motion's default): 2 pixels where a 1-pixel grid's views are more than
    AUTO_UV_MAX_DISPARITY samples apart for the scene (the 2-pixel grid's store, already opened, is
    kept), else 1; the finest step where the disparity cannot be measured (one camera). A 2-D array
    whose views are more than AUTO_XY_MAX_DISPARITY samples apart at 2 pixels gets AUTO_XY_DENSER views
    per camera spacing (unless --xy-oversample says otherwise)."""
    from polycam.depth_cli import open_source
    from polycam.run import (AUTO_UV_MAX_DISPARITY, AUTO_XY_DENSER, AUTO_XY_MAX_DISPARITY, choose_uv_step,
                             session_grid)
    from polycam.session import open_session
    from resample.pipeline import open_calibration

    def choose(path, xy_oversample=None):
        s = open_session(path)
        models = open_calibration(s, None)
        return (*choose_uv_step(s, models, xy_oversample), models)

    step, d, store, models = choose(session)                  # 2 cm apart in a room: far apart
    assert step == 2.0 and AUTO_UV_MAX_DISPARITY / 2 < d <= AUTO_XY_MAX_DISPARITY
    assert store.grid == session_grid(models, 2.0)[0] and store.xy_oversample == 2
    (tmp_path / "far.toml").write_text(mock_grid_rig_text("far", 64, 48, 3, 3, 0.05))   # 5 cm: farther still
    far = synth_session(load_rig(tmp_path / "far.toml"), tmp_path / "far", frames=2, seed=1)
    step, d, store, models = choose(far)
    assert step == 2.0 and d > AUTO_XY_MAX_DISPARITY and store.xy_oversample == AUTO_XY_DENSER == 3
    assert store.grid == session_grid(models, 2.0, 3)[0] and store.grid.x.count == 7 and store.denser_views
    step, d2, store, _ = choose(far, 2)                        # --xy-oversample 2: as asked
    assert step == 2.0 and d2 == d and store.xy_oversample == 2 and store.grid.x.count == 5
    for name, rows, cols, pitch in (("near", 3, 3, 0.005), ("one", 1, 1, 0.02)):
        (tmp_path / f"{name}.toml").write_text(mock_grid_rig_text(name, 64, 48, rows, cols, pitch))
        path = synth_session(load_rig(tmp_path / f"{name}.toml"), tmp_path / name, frames=2, seed=1)
        step, d, store, _ = choose(path)
        assert step == 1.0 and store is None
        assert (0.0 < d <= AUTO_UV_MAX_DISPARITY) if name == "near" else np.isnan(d)
    auto = open_source(session)                                # the library's default stays 1 pixel
    assert auto.uv_step_px == 1.0 and np.isnan(auto.uv_disparity)
    auto = open_source(session, uv_step=None)
    assert auto.uv_step_px == 2.0 and auto.uv_disparity > AUTO_UV_MAX_DISPARITY / 2
    assert main(["motion", str(session), "--out", str(tmp_path / "auto.tum"), "--report", str(tmp_path / "rep")]) == 0
    out = capsys.readouterr().out
    assert "25x33 directions" in out and "directions every 2 camera pixel(s) (--uv-step auto: 0." in out
    assert "views per camera spacing (over" not in out
    import tomllib

    grid = tomllib.loads((tmp_path / "rep" / "options.toml").read_text())["grid"]   # the report says how
    assert grid["uv_step"] == "auto" and grid["uv_step_px"] == 2.0 and grid["shape"] == [1, 5, 5, 25, 33]
    assert grid["uv_disparity"] == pytest.approx(auto.uv_disparity)
    assert main(["motion", str(session), "--out", str(tmp_path / "one.tum"), "--uv-step", "1"]) == 0
    out = capsys.readouterr().out
    assert "49x65 directions" in out and "--uv-step auto" not in out
    with pytest.raises(SystemExit) as e:                       # bad usage: argparse, exit 2
        main(["motion", str(session), "--out", str(tmp_path / "t.tum"), "--uv-step", "fine"])
    assert e.value.code == 2 and "or auto" in capsys.readouterr().err
    assert main(["depth", str(session), "--out", str(tmp_path / "d"), "--uv-step", "auto"]) == 0   # depth: on request
    assert "directions every 2 camera pixel(s) (--uv-step auto" in capsys.readouterr().out
    assert main(["motion", str(far), "--out", str(tmp_path / "far.tum")]) == 0
    out = capsys.readouterr().out
    assert "7x7 views" in out and "; 3 views per camera spacing (over 0.6 samples per view step with 2))" in out, out


def test_covariance_counts_the_camera_arrays_model_error(tmp_path):
    """On a resampled camera array the residuals do not show the model error (aliasing across
    the views, resampling): the errors are several times the noise covariance's std. The
    reported covariance adds the change from the coarser (u, v) level's estimate, and its std
    explains the errors to within 2x."""
    from polycam.evaluate import error_over_std, pair_errors
    from polycam.motion import estimate_trajectory
    from resample.stream import SessionLightField

    (tmp_path / "rig.toml").write_text(RIG_TEXT)
    lf = SessionLightField(synth_session(load_rig(tmp_path / "rig.toml"), tmp_path / "s", frames=9, seed=1))
    traj, results = estimate_trajectory(lf)
    err = pair_errors(traj, lf.groundtruth())
    noise_std = np.stack([np.sqrt(np.diag(r.covariance_noise)) for r in results])
    assert min(error_over_std(err, noise_std)) > MOTION_ARRAY_NOISE_STD_RATIO_MIN
    lo, hi = MOTION_ARRAY_STD_RATIO
    assert all(lo < k < hi for k in error_over_std(err, np.stack([r.std for r in results])))
    for r in results:
        d = r.level_change
        assert np.all(np.isfinite(d)) and np.abs(d).max() > 0
        np.testing.assert_allclose(r.covariance, r.covariance_noise + np.outer(d, d), rtol=1e-12, atol=1e-30)


def test_motion_from_session_with_more_viewpoints(session, tmp_path, capsys):
    # --xy-oversample 3: two views between neighbouring cameras, 7 x 7 for the 3 x 3 rig
    assert main(["motion", str(session), "--out", str(tmp_path / "dense.tum"), "--xy-oversample", "3"]) == 0
    out = capsys.readouterr().out
    assert "7x7 views" in out and "against" in out
    assert len(read_tum(tmp_path / "dense.tum")) == 3
    with pytest.raises(SystemExit) as e:                       # bad usage: argparse, exit 2
        main(["motion", str(session), "--out", str(tmp_path / "t.tum"), "--xy-oversample", "0"])
    assert e.value.code == 2
    assert not (tmp_path / "t.tum").exists()


def test_motion_sampling_check_adds_the_change_on_a_second_view_sampling(session, tmp_path, capsys):
    """--sampling-check: the pairs re-solved with one more view per camera spacing (3: 7 x 7 views for the
    3 x 3 rig), the change from the nominal estimate added to each covariance as d dᵀ (pairs.csv
    std_sampling_t, _r its norms); the estimates themselves unchanged. A light-field store: one line, exit 1."""
    import csv

    def run(name: str, *extra: str):
        assert main(["motion", str(session), "--out", str(tmp_path / f"{name}.tum"), "--report", str(tmp_path / name),
                     "--uv-step", "2", *extra]) == 0
        with open(tmp_path / name / "pairs.csv", newline="") as f:
            rows = list(csv.DictReader(f))
        get = lambda keys: np.array([[float(r[k]) for k in keys] for r in rows])   # noqa: E731
        return (get(("t_x", "t_y", "t_z", "r_x", "r_y", "r_z")),
                get(("std_t_x", "std_t_y", "std_t_z", "std_r_x", "std_r_y", "std_r_z")), rows)

    x, std, rows = run("nominal")
    assert all(r["std_sampling_t"] == "" for r in rows)
    capsys.readouterr()
    y, _, _ = run("dense", "--xy-oversample", "3")
    capsys.readouterr()
    xc, stdc, rows = run("checked", "--sampling-check")
    out = capsys.readouterr().out
    assert "second view sampling (3 views per camera spacing, 7x7 views" in out, out
    np.testing.assert_array_equal(xc, x)
    d = x - y
    assert np.abs(d).max() > 0
    np.testing.assert_allclose(stdc ** 2, std ** 2 + d ** 2, rtol=1e-4)
    np.testing.assert_allclose([float(r["std_sampling_t"]) for r in rows], np.linalg.norm(d[:, :3], axis=1), rtol=1e-4)
    np.testing.assert_allclose([float(r["std_sampling_r"]) for r in rows], np.linalg.norm(d[:, 3:], axis=1), rtol=1e-4)
    assert main(["resample", str(session), "--out", str(tmp_path / "lf.zarr"), "--workers", "0"]) == 0
    capsys.readouterr()
    code = main(["motion", str(tmp_path / "lf.zarr"), "--out", str(tmp_path / "s.tum"), "--sampling-check"])
    _one_line_error(capsys, code, "lf.zarr: --sampling-check needs a session")
    assert not (tmp_path / "s.tum").exists()


def test_motion_on_a_session_without_calibration_names_it(session, tmp_path, capsys):
    bare = tmp_path / "bare"
    shutil.copytree(session, bare)
    shutil.rmtree(bare / "calib")
    code = main(["motion", str(bare), "--out", str(tmp_path / "t.tum")])
    _one_line_error(capsys, code, "no calibration", "--calib")
    code = main(["motion", str(bare), "--out", str(tmp_path / "t.tum"), "--calib", str(tmp_path / "nope")])
    _one_line_error(capsys, code, "nope")
    assert not (tmp_path / "t.tum").exists()


def test_models_at_capture_follow_the_capture_times(tmp_path):
    # each camera moved by its share of the motion around its frame: with the true motion, exactly where
    # the synthetic session rendered it (polycam.trajectory.pose_at) between the frames; before the first
    # frame and after the last, where the rig's motion goes on, the end steps' velocity extrapolated
    # (step_beyond) lands nearer than the end step held; synchronised cameras stay put
    from polycam.cameras import T_rig_cam_of
    from polycam.geometry import T_inverse
    from polycam.session import open_session
    from polycam.synth import trajectory_for_rig
    from polycam.trajectory import pose_at
    from resample.stream import models_at_capture

    (tmp_path / "rig.toml").write_text(RIG_TEXT)
    rig = load_rig(tmp_path / "rig.toml")
    s = open_session(synth_session(rig, tmp_path / "s", frames=4, seed=1, sync_spread_ms=15.0))
    gt = s.groundtruth()
    T = gt.T_world_rig
    rendered = trajectory_for_rig(rig, 4, seed=1, start_ns=15_000_000, margin=1)   # as synth_session moves it
    motion = np.stack([T_inverse(T[i]) @ T[i + 1] for i in range(len(T) - 1)])
    models = s.calibration()
    beyond = []
    for t in range(len(s)):
        moved = models_at_capture(models, s, t, motion)
        for k, cam in enumerate(s.cameras):
            stamp = int(s.cam_timestamps[t, k])
            want = T_inverse(T[t]) @ pose_at(rendered, stamp) @ T_rig_cam_of(models[cam])
            if gt.timestamps_ns[0] <= stamp <= gt.timestamps_ns[-1]:          # (the truth read from TUM)
                np.testing.assert_allclose(T_rig_cam_of(moved[cam]), want, atol=TUM_POSITION_ATOL)
            else:
                held = T_inverse(T[t]) @ pose_at(gt, stamp) @ T_rig_cam_of(models[cam])
                beyond.append([np.linalg.norm(X[:3, 3] - want[:3, 3]) for X in (T_rig_cam_of(moved[cam]), held)])
    beyond = np.array(beyond)
    rms = np.sqrt(np.mean(beyond ** 2, axis=0))                     # measured 6 against 39 µm
    assert len(beyond) >= 2 and rms[0] < 0.3 * rms[1] and np.all(beyond[:, 0] < 0.5 * beyond[:, 1]), beyond
    failed = motion.copy()                                          # a failed pair next to an end (its
    failed[1] = np.eye(4)                                           # identity): the end step held
    moved = models_at_capture(models, s, 0, failed)
    for k, cam in enumerate(s.cameras):
        held = T_inverse(T[0]) @ pose_at(gt, int(s.cam_timestamps[0, k])) @ T_rig_cam_of(models[cam])
        np.testing.assert_allclose(T_rig_cam_of(moved[cam]), held, atol=TUM_POSITION_ATOL)
    # a capture time moved (a draw of --sync-draws): the camera where the rig was at the moved time
    offsets = np.linspace(-3e6, 3e6, len(s.cameras))
    moved = models_at_capture(models, s, 1, motion, offsets)
    for k, cam in enumerate(s.cameras):
        want = T_inverse(T[1]) @ pose_at(gt, int(s.cam_timestamps[1, k] + offsets[k])) @ T_rig_cam_of(models[cam])
        np.testing.assert_allclose(T_rig_cam_of(moved[cam]), want, atol=1e-12)
    s0 = open_session(synth_session(load_rig(tmp_path / "rig.toml"), tmp_path / "s0", frames=2, seed=1))
    same = models_at_capture(s0.calibration(), s0, 1, motion[:1])
    for cam, m in s0.calibration().items():
        np.testing.assert_allclose(T_rig_cam_of(same[cam]), T_rig_cam_of(m), atol=1e-12)


def test_sync_draws_draw_the_first_pass_motion_from_its_covariance():
    """--sync-draws moves the first pass's motion by draws from its covariance: the factors square to
    it (zero for a failed pair's infinite one), and a zero draw leaves the motion as it was."""
    from polycam.geometry import T_from_rt
    from polycam.sync_draws_cli import _motion_factors, _moved_motion

    rng = np.random.default_rng(5)
    B = rng.standard_normal((6, 6)) * 1e-4
    C = np.stack([B @ B.T, np.diag(np.full(6, np.inf))])
    A = _motion_factors(C, 2)
    np.testing.assert_allclose(A[0] @ A[0].T, C[0], rtol=1e-9, atol=1e-20)
    assert not A[1].any() and not _motion_factors(None, 2).any()
    M = T_from_rt(np.array([[0.01, -0.02, 0.03, 0.004, 0.001, -0.002], [0.0, 0.0, 0.0, 0.005, 0.0, 0.0]]))
    np.testing.assert_allclose(_moved_motion(M, np.zeros((2, 6))), M, atol=1e-15)
    dx = np.array([[1e-4, 0, 0, 0, 0, 0], [0, 0, 0, 0, 0, 1e-3]])
    moved = _moved_motion(M, dx)
    np.testing.assert_allclose(moved[0][:3, 3] - M[0][:3, 3], [1e-4, 0, 0], atol=1e-15)
    np.testing.assert_allclose(moved[1][:3, :3], T_from_rt(np.array([0, 0, 1e-3, 0, 0, 0]))[:3, :3], atol=1e-15)


def test_captured_free_running_cameras_are_corrected(tmp_path, capsys, monkeypatch):
    # free-running mock cameras (phases within ±7 ms) whose timestamps jitter (2 ms std), recorded by the
    # capture as from hardware: polycam motion corrects with the capture times (each camera's running
    # median offset, polycam.session.capture_times); moving each camera by its raw timestamp instead
    # errs more than not correcting (measured: 1.81 % corrected, 2.36 % not, 3.73 % with raw timestamps)
    from capture import MockSource, record
    from polycam.evaluate import pair_errors
    from polycam.session import Session

    text = (REPO / "rigs" / "mock1x5.toml").read_text()
    (tmp_path / "rig.toml").write_text(text.replace("jitter_ms = 0.0", "jitter_ms = 2.0\nsync_spread_ms = 7.0")
                                       .replace("seed = 1", "seed = 3"))
    rig = load_rig(tmp_path / "rig.toml")
    src = MockSource(rig, realtime=False, frames=8)
    record(src, rig, tmp_path / "s", frames=8)
    src.write_truth(tmp_path / "s")
    truth = read_tum(tmp_path / "s" / "groundtruth.tum")
    err = {}
    for mode in ("auto", "off", "raw"):
        if mode == "raw":
            monkeypatch.setattr(Session, "capture_times_ns", lambda self: self.cam_timestamps)
        assert main(["motion", str(tmp_path / "s"), "--out", str(tmp_path / f"{mode}.tum"),
                     "--sync-correct", "off" if mode == "off" else "auto"]) == 0
        out = capsys.readouterr().out
        assert "not synchronised" in out and ("which --sync-draws N measures" in out) == (mode != "off")
        e = pair_errors(read_tum(tmp_path / f"{mode}.tum"), truth)
        err[mode] = float(np.median(e.t_err / e.t_true))
    assert err["auto"] < 0.85 * err["off"] and err["raw"] > 1.6 * err["auto"], err
    # --sync-draws: the capture times' uncertainty (their running medians of 8 jittered stamps) re-solved
    # and added to the covariance, as its own part (pairs.csv std_sync_t, _r)
    import csv

    monkeypatch.undo()
    assert main(["motion", str(tmp_path / "s"), "--out", str(tmp_path / "d.tum"), "--sync-draws", "1",
                 "--report", str(tmp_path / "rep")]) == 0
    out = capsys.readouterr().out
    assert "capture times: 1 draws from their uncertainty (" in out and "2 re-solves" in out, out
    assert "which --sync-draws N measures" not in out
    sigma_ms = float(out.split("their uncertainty (")[1].split(" ms RMS per camera")[0])
    assert 0.2 < sigma_ms < 2.0        # one draw of 1.25 x 2 ms / sqrt(8) = 0.89 ms per camera, median of 5
    with open(tmp_path / "rep" / "pairs.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    assert all(float(r["std_sync_t"]) > 0 and float(r["std_sync_r"]) > 0 for r in rows)
    np.testing.assert_allclose(read_tum(tmp_path / "d.tum").T_world_rig, read_tum(tmp_path / "auto.tum").T_world_rig)
    assert main(["motion", str(tmp_path / "s"), "--out", str(tmp_path / "d0.tum"), "--sync-draws", "1",
                 "--sync-correct", "off"]) == 0
    assert "capture-time draws skipped: no second pass (--sync-correct off)" in capsys.readouterr().out


def test_motion_corrects_unsynchronised_cameras(tmp_path, capsys):
    # a row of five cameras, each capturing at its own offset within ±16 ms: polycam motion solves again with every camera where
    # it captured (--sync-correct auto, the default), 3x smaller errors than with the images taken as
    # simultaneous (measured 1.42 against 4.77 %)
    from polycam.evaluate import pair_errors

    session = synth_session(load_rig(REPO / "rigs" / "mock1x5.toml"), tmp_path / "u", frames=4, seed=3,
                            sync_spread_ms=16.0)
    truth = read_tum(session / "groundtruth.tum")
    err = {}
    for mode in ("auto", "off"):
        assert main(["motion", str(session), "--out", str(tmp_path / f"{mode}.tum"), "--sync-correct", mode]) == 0
        out = capsys.readouterr().out
        assert "not synchronised" in out and ("second pass" in out) == (mode == "auto")
        e = pair_errors(read_tum(tmp_path / f"{mode}.tum"), truth)
        err[mode] = float(np.median(e.t_err / e.t_true))
    assert err["auto"] < 0.5 * err["off"], err
    # polycam depth on the same session: its pair resampled again with the cameras where they captured
    # (pair 0: measured 0.72 % against 3.09 % uncorrected)
    import tomllib

    assert main(["depth", str(session), "--out", str(tmp_path / "d")]) == 0
    out = capsys.readouterr().out
    assert "the pair was resampled again with each camera where it captured" in out
    depth = tomllib.loads((tmp_path / "d" / "depth.toml").read_text())["depth"]
    assert depth["cameras_moved_to_capture"] is True
    M_true = truth.relative()[0]
    off = np.linalg.norm(read_tum(tmp_path / "off.tum").relative()[0][:3, 3] - M_true[:3, 3])
    corrected = np.linalg.norm(np.array(depth["T_prev_next"])[:3, 3] - M_true[:3, 3])
    assert corrected < 0.5 * off
    # --sync-correct off: the images as captured together, as polycam motion's off
    assert main(["depth", str(session), "--out", str(tmp_path / "d0"), "--sync-correct", "off"]) == 0
    assert "each is resampled as if taken at the frame's time" in capsys.readouterr().out
    depth0 = tomllib.loads((tmp_path / "d0" / "depth.toml").read_text())["depth"]
    assert "cameras_moved_to_capture" not in depth0
    assert np.linalg.norm(np.array(depth0["T_prev_next"])[:3, 3] - M_true[:3, 3]) > 2 * corrected
