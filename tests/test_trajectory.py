"""Trajectories and the TUM format: exact timestamps, pose round trips, parse errors."""

from __future__ import annotations

import numpy as np
import pytest

from polycam.errors import FormatError
from polycam.geometry import T_from_rt, T_inverse
from polycam.trajectory import Trajectory, read_tum, write_tum
from tolerances import GEOMETRY_ATOL, TUM_POSITION_ATOL, TUM_ROTATION_ATOL


def _traj(rng, n=20, t0=1_403_636_579_763_555_584):
    r = rng.normal(size=(n, 3))
    r *= (rng.uniform(0, np.pi * 0.99, n) / np.linalg.norm(r, axis=1))[:, None]
    rt = np.concatenate([r, rng.normal(0, 2.0, (n, 3))], axis=1)
    ts = t0 + np.cumsum(rng.integers(1, 50_000_000, n)).astype(np.int64)
    return Trajectory(ts, T_from_rt(rt))


def test_tum_round_trip(tmp_path, rng):
    traj = _traj(rng)
    write_tum(tmp_path / "t.tum", traj)
    back = read_tum(tmp_path / "t.tum")
    assert back.timestamps_ns.dtype == np.int64
    np.testing.assert_array_equal(back.timestamps_ns, traj.timestamps_ns)  # ns exact
    np.testing.assert_allclose(back.T_world_rig[:, :3, 3], traj.T_world_rig[:, :3, 3], atol=TUM_POSITION_ATOL)
    np.testing.assert_allclose(back.T_world_rig[:, :3, :3], traj.T_world_rig[:, :3, :3], atol=TUM_ROTATION_ATOL)
    np.testing.assert_array_equal(back.T_world_rig[:, 3], np.tile([0, 0, 0, 1], (len(traj), 1)))


def test_tum_line_format(tmp_path):
    traj = Trajectory(np.array([1_500_000_000, 2_000_000_001], np.int64), np.stack([np.eye(4)] * 2))
    write_tum(tmp_path / "t.tum", traj)
    lines = (tmp_path / "t.tum").read_text().splitlines()
    tok = lines[0].split()
    assert len(tok) == 8 and tok[0] == "1.500000000"
    assert [float(v) for v in tok[1:]] == [0, 0, 0, 0, 0, 0, 1]  # tx ty tz qx qy qz qw
    assert lines[1].split()[0] == "2.000000001"


def test_negative_and_zero_timestamps_round_trip(tmp_path):
    ts = np.array([-1_500_000_000, -1, 0, 7], np.int64)
    write_tum(tmp_path / "t.tum", Trajectory(ts, np.stack([np.eye(4)] * 4)))
    np.testing.assert_array_equal(read_tum(tmp_path / "t.tum").timestamps_ns, ts)


def test_tum_reader_accepts_comments_blank_lines_and_short_fractions(tmp_path):
    p = tmp_path / "t.tum"
    p.write_text("# timestamp tx ty tz qx qy qz qw\n\n"
                 "1.5 1 2 3 0 0 0 1\n"
                 "2 1 2 3 0 0 0.7071067811865476 0.7071067811865476\n"
                 "3.25,0,0,0,0,0,0,1\n")
    t = read_tum(p)
    np.testing.assert_array_equal(t.timestamps_ns, [1_500_000_000, 2_000_000_000, 3_250_000_000])
    np.testing.assert_allclose(t.T_world_rig[0, :3, 3], [1, 2, 3])
    np.testing.assert_allclose(t.T_world_rig[1, :3, :3], [[0, -1, 0], [1, 0, 0], [0, 0, 1]], atol=1e-12)


@pytest.mark.parametrize("text, substrings", [
    ("1 0 0 0 0 0 1\n", ["line 1", "expected 8 values"]),
    ("1 0 0 0 0 0 0 1\n2 0 0 x 0 0 0 1\n", ["line 2", "not a number"]),
    ("1 0 0 nan 0 0 0 1\n", ["line 1", "non-finite"]),
    ("1 0 0 0 0 0 0 2\n", ["line 1", "not unit length"]),
    ("1 0 0 0 0 0 0 1\n1 0 0 0 0 0 0 1\n", ["line 2", "not strictly increasing"]),
    ("# only a comment\n", ["no poses"]),
    ("abc 0 0 0 0 0 0 1\n", ["line 1", "not a number"]),
    ("1e400 0 0 0 0 0 0 1\n", ["line 1", "non-finite"]),
    ("99999999999999999999 0 0 0 0 0 0 1\n", ["line 1", "beyond int64"]),
    ("1 1e300 0 0 0 0 0 1\n", ["line 1", "position beyond"]),
])
def test_tum_errors(tmp_path, text, substrings):
    p = tmp_path / "bad.tum"
    p.write_text(text)
    with pytest.raises(FormatError) as e:
        read_tum(p)
    msg = str(e.value)
    assert str(p) in msg
    for s in substrings:
        assert s in msg, msg


def test_missing_tum(tmp_path):
    with pytest.raises(FormatError, match="no such file"):
        read_tum(tmp_path / "nope.tum")


def test_relative_and_from_relative(rng):
    traj = _traj(rng, 8)
    rel = traj.relative()
    assert rel.shape == (7, 4, 4)
    np.testing.assert_allclose(traj.T_world_rig[:-1] @ rel, traj.T_world_rig[1:], atol=GEOMETRY_ATOL)
    back = Trajectory.from_relative(traj.timestamps_ns, rel)
    # integrated from identity: world = rig frame at the first frame
    np.testing.assert_allclose(back.T_world_rig, T_inverse(traj.T_world_rig[0]) @ traj.T_world_rig,
                               atol=1e-9)
    np.testing.assert_allclose(traj.rebased().T_world_rig, back.T_world_rig, atol=1e-9)
    np.testing.assert_allclose(back.T_world_rig[0], np.eye(4))
    assert len(back) == 8


def test_trajectory_checks_shapes():
    with pytest.raises(ValueError):
        Trajectory(np.zeros(3, np.int64), np.zeros((2, 4, 4)))


def test_poses_at_frame_times():
    # the pose nearest each time, within the tolerance (TUM files of other tools round their times)
    from polycam.trajectory import MATCH_TOLERANCE_NS, poses_at_times

    T = np.broadcast_to(np.eye(4), (4, 4, 4)).copy()
    T[:, 0, 3] = np.arange(4)
    tr = Trajectory(np.array([0, 100, 200, 300], np.int64) * 1_000_000, T)
    got = poses_at_times(tr, np.array([0, 300_000_400, 100_999_000, 199_500_000, -900_000]))
    np.testing.assert_array_equal(got[:, 0, 3], [0, 3, 1, 2, 0])
    with pytest.raises(ValueError, match="no pose within 1 ms of frame time 0.150000000 s"):
        poses_at_times(tr, np.array([0, 150_000_000]))
    assert MATCH_TOLERANCE_NS == 1_000_000


def test_step_beyond_extrapolates_a_constant_acceleration():
    # a rig whose velocity and rotation rate (about one axis) change at a constant rate: the step beyond
    # either end is that motion's own, with a lost frame inward (an interval twice as long) as well;
    # holding the end step instead misses it by the change of velocity
    from polycam.trajectory import step_beyond

    axis = np.array([0.3, -0.5, 0.81]) / np.linalg.norm([0.3, -0.5, 0.81])
    v0, a = np.array([0.10, -0.02, 0.05]), np.array([-0.9, 0.4, 0.3])     # m/s, m/s²
    w0, b = 0.06, 0.8                                                        # rad/s, rad/s²

    def step(t0: float, dt: float) -> np.ndarray:     # the (r, t) vectors of the motion over [t0, t0 + dt]
        return T_from_rt(np.r_[(w0 * dt + 0.5 * b * ((t0 + dt) ** 2 - t0 ** 2)) * axis,
                               v0 * dt + 0.5 * a * ((t0 + dt) ** 2 - t0 ** 2)])

    d = 1 / 30
    frames = [0.0, 2 * d, 3 * d]                                             # frame 1 lost
    after = step_beyond(step(frames[1], d), step(frames[0], 2 * d), d * 1e9, 2 * d * 1e9)
    np.testing.assert_allclose(after, step(frames[2], d), atol=GEOMETRY_ATOL)
    before = step_beyond(step(frames[0], 2 * d), step(frames[1], d), 2 * d * 1e9, d * 1e9)
    np.testing.assert_allclose(before, step(frames[0] - 2 * d, 2 * d), atol=GEOMETRY_ATOL)
    assert np.abs(step(frames[1], d) - step(frames[2], d)).max() > 1e3 * GEOMETRY_ATOL
