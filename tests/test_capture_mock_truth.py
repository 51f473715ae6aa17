"""The mock driver's ground truth (issue 7): a mock session carries its true trajectory and
camera models like a synthetic one, and the mock can show a calibration board."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from capture import CaptureError, MockSource, record
from polycam.board import load_board
from polycam.cameras import T_rig_cam_of
from polycam.rig import load_rig
from polycam.session import open_session
from polycam.synth import board_poses, trajectory_for_rig, true_cameramodels
from polycam.trajectory import read_tum
from conftest import mock_grid_rig_text

REPO = Path(__file__).resolve().parents[1]
BOARD = REPO / "rigs" / "boards" / "charuco_5x7.toml"


def make_rig(tmp_path: Path, *, w=32, h=24, scene="room", motion="smooth", mock: str = ""):
    """A 1x2 mock rig (conftest's rig text, seed 1) with this scene, motion and extra [mock] lines."""
    text = mock_grid_rig_text("truth1x2", w, h, rows=1, cols=2)
    text = text.replace('scene = "room"', f'scene = "{scene}"').replace('motion = "smooth"', f'motion = "{motion}"')
    p = tmp_path / "rig.toml"
    p.write_text(text + mock + "\n")
    return load_rig(p)


def test_mock_session_carries_its_trajectory_and_models(tmp_path):
    """Frames lost to drops and jittered timestamps still get the pose each frame showed."""
    rig = make_rig(tmp_path, mock="jitter_ms = 3.0\ndrop_rate = 0.2")
    models = true_cameramodels(rig, seed=2, perturb_position_m=0.002, perturb_rotation_deg=0.5)
    src = MockSource(rig, realtime=False, frames=8, models=models)
    record(src, rig, tmp_path / "s", frames=8)
    assert src.write_truth(tmp_path / "s") == ["groundtruth.tum", "calib/ (2 models)"]
    s = open_session(tmp_path / "s")
    gt = s.groundtruth()
    np.testing.assert_array_equal(gt.timestamps_ns, s.timestamps_ns)
    traj = trajectory_for_rig(rig, 8, seed=1)
    period = 1e9 / 30
    for f in range(len(s)):
        ts = s.cam_timestamps[f][s.cam_timestamps[f] >= 0]
        i = int(round(float(np.median(ts)) / period))            # jitter (3 ms) << half a period
        np.testing.assert_allclose(gt.T_world_rig[f], traj.T_world_rig[i], atol=1e-6)
    calib = s.calibration()
    for c in rig.ids:
        np.testing.assert_allclose(T_rig_cam_of(calib[c]), T_rig_cam_of(models[c]), atol=1e-9)
        np.testing.assert_allclose(calib[c].intrinsics()[1], models[c].intrinsics()[1])


def test_mock_unsynchronised_cameras(tmp_path):
    """[mock] sync_spread_ms: free-running cameras, each at its own constant phase within the spread,
    their images the scene at those moments; the capture groups them into frames as it would real
    cameras, and the truth is the rig at the (lower) median of a frame's moments, as its timestamp."""
    from polycam.session import sync_warning
    from polycam.synth import CameraArrayRenderer, quantize, scene_for_rig
    from polycam.trajectory import pose_at

    path = make_rig(tmp_path, mock="sync_spread_ms = 10.0\nstep_t = 0.02").path
    path.write_text(path.read_text().replace("noise = 0.004", "noise = 0.0"))    # images to compare exactly
    rig = load_rig(path)
    src = MockSource(rig, realtime=False, frames=5)
    record(src, rig, tmp_path / "s", frames=5)
    src.write_truth(tmp_path / "s")
    s = open_session(tmp_path / "s")
    assert len(s) == 5 and (s.cam_timestamps >= 0).all()
    start = 10_000_000                                             # the spread: no timestamp before 0
    phase = (s.cam_timestamps - start) - np.round(np.arange(5) * 1e9 / 30).astype(np.int64)[:, None]
    assert np.all(phase == phase[0]) and np.all(np.abs(phase) <= 10_000_000) and np.ptp(phase[0]) > 1_000_000
    assert "not synchronised" in sync_warning(s)
    traj = trajectory_for_rig(rig, 5, seed=1)
    motion = trajectory_for_rig(rig, 5, seed=1, margin=1)          # the rig moves on beyond the frames
    renderer = CameraArrayRenderer(rig, s.calibration(), scene_for_rig(rig, seed=1), supersample=1)
    assert phase[0].min() < 0 or phase[-1].max() > 0          # a camera beyond the trajectory's first or last pose
    for f in (0, 3, 4):
        for k, cam in enumerate(s.cameras):
            moment = int(s.cam_timestamps[f, k]) - start       # beyond the ends: the motion going on
            want = quantize(renderer.render_camera(cam, pose_at(motion, moment)), 8)
            np.testing.assert_array_equal(s.read_frame(f)[cam], want)
            if not 0 <= moment <= traj.timestamps_ns[-1]:      # not its first or last step held
                assert not np.allclose(pose_at(motion, moment), pose_at(traj, moment), atol=1e-7)
    gt = s.groundtruth()
    for f in range(5):
        moment = float(np.sort(s.cam_timestamps[f])[0]) - start      # the lower median, as the frame's stamp
        np.testing.assert_allclose(gt.T_world_rig[f], pose_at(motion, moment), atol=1e-9)
    assert not np.allclose(gt.T_world_rig[2], traj.T_world_rig[2])


def test_mock_cameras_at_their_own_clocks_and_rates(tmp_path):
    """[mock] clock_ppm and a camera at 25 fps among 30 ([[camera]] fps): each image shows the scene at
    its camera's own moment (its clock's period, its rate); recorded free-running, a frame's timestamp is
    the (lower) median of the 30 fps cameras' and the truth the rig at that moment, so that a slower
    camera's sawing offset moves neither."""
    from polycam.synth import CameraArrayRenderer, quantize, scene_for_rig
    from polycam.trajectory import pose_at

    text = mock_grid_rig_text("rates1x3", 32, 24, rows=1, cols=3).replace("noise = 0.004", "noise = 0.0")
    grid = text[text.index("[grid]"):text.index("[mock]")]
    cams = "".join(f"""[[camera]]
id = "cam{k}"
position = [{0.02 * (k - 1)}, 0.0, 0.0]
fps = {25 if k == 2 else 30}
""" for k in range(3))
    path = tmp_path / "rig.toml"
    path.write_text(text.replace(grid, cams) + "sync_spread_ms = 10.0\nclock_ppm = 3000.0\nstep_t = 0.02\n")
    rig = load_rig(path)
    src = MockSource(rig, realtime=False, frames=8)
    record(src, rig, tmp_path / "s", frames=6, free_running=True)
    src.write_truth(tmp_path / "s")
    s = open_session(tmp_path / "s")
    start = src._t0
    period = [src._nominal(k, 1) - src._nominal(k, 0) for k in range(3)]
    assert abs(period[2] - 40e6) < 0.2e6 and abs(period[0] - period[1]) > 10_000       # rate; clocks apart
    traj = trajectory_for_rig(rig, 8, seed=1)
    renderer = CameraArrayRenderer(rig, s.calibration(), scene_for_rig(rig, seed=1), supersample=1)
    for f in (1, 4):
        for k, cam in enumerate(s.cameras):
            if s.cam_timestamps[f, k] >= 0:
                want = quantize(renderer.render_camera(cam, pose_at(traj, int(s.cam_timestamps[f, k]) - start)), 8)
                np.testing.assert_array_equal(s.read_frame(f)[cam], want)
    gt = s.groundtruth()
    for f in range(len(s)):
        fast = s.cam_timestamps[f, :2][s.cam_timestamps[f, :2] >= 0]
        assert s.timestamps_ns[f] == np.sort(fast)[(len(fast) - 1) // 2]
        np.testing.assert_allclose(gt.T_world_rig[f], pose_at(traj, float(s.timestamps_ns[f]) - start), atol=1e-9)


def test_mock_renders_with_the_given_models(tmp_path):
    """A camera rendered with a perturbed model sees a different image than the nominal one."""
    rig = make_rig(tmp_path, motion="static")
    models = true_cameramodels(rig, seed=2, perturb_rotation_deg=2.0)
    record(MockSource(rig, realtime=False, frames=1), rig, tmp_path / "a", frames=1)
    record(MockSource(rig, realtime=False, frames=1, models=models), rig, tmp_path / "b", frames=1)
    a, b = (open_session(tmp_path / n).read_frame(0)["cam00"].astype(float) for n in "ab")
    assert np.mean(np.abs(a - b)) > 2.0


def test_mock_board_session(tmp_path):
    """With a board the rig stands still and the board moves through the seeded poses."""
    rig = make_rig(tmp_path, w=160, h=120)
    board = load_board(BOARD)
    src = MockSource(rig, realtime=False, frames=3, board=board)
    record(src, rig, tmp_path / "s", frames=3)
    assert src.write_truth(tmp_path / "s") == ["groundtruth.tum", "calib/ (2 models)", "board_poses.tum",
                                               "board.toml"]
    s = open_session(tmp_path / "s")
    np.testing.assert_allclose(s.groundtruth().T_world_rig, np.broadcast_to(np.eye(4), (3, 4, 4)), atol=1e-12)
    poses = read_tum(tmp_path / "s" / "board_poses.tum")
    np.testing.assert_array_equal(poses.timestamps_ns, s.timestamps_ns)
    np.testing.assert_allclose(poses.T_world_rig, board_poses(board, s.calibration(), 3, seed=1, cam_ids=rig.ids),
                               atol=1e-6)
    assert (tmp_path / "s" / "board.toml").read_text() == BOARD.read_text()
    img = s.read_frame(0)["cam00"]
    assert (img < 40).mean() > 0.05 and (img > 215).mean() > 0.05     # black squares and white paper


def test_pattern_scene_has_no_truth(tmp_path):
    rig = make_rig(tmp_path, scene="pattern")
    with pytest.raises(CaptureError, match="pattern"):
        MockSource(rig, realtime=False, board=load_board(BOARD))
    src = MockSource(rig, realtime=False, frames=2)
    record(src, rig, tmp_path / "s", frames=2)
    assert not src.has_truth
    with pytest.raises(CaptureError, match="pattern"):
        src.write_truth(tmp_path / "s")


def test_capture_verb_writes_the_mock_truth(tmp_path):
    rig = make_rig(tmp_path, w=64, h=48)
    res = subprocess.run([sys.executable, "-m", "polycam.cli", "capture", "--rig", str(rig.path), "--out",
                          str(tmp_path / "s"), "--frames", "2", "--fast", "--no-display", "--mock-board", str(BOARD)],
                         capture_output=True, text=True, cwd=REPO, timeout=300)
    assert res.returncode == 0, res.stderr
    assert "ground truth (mock): groundtruth.tum" in res.stdout
    for rel in ("groundtruth.tum", "board_poses.tum", "board.toml", "calib/cam01.cameramodel"):
        assert (tmp_path / "s" / rel).is_file(), rel
