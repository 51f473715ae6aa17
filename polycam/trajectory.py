"""Trajectories of rig poses and the TUM text format (SPEC.md).

A :class:`Trajectory` holds ``T_world_rig`` per frame; world is the rig frame at
the first frame for estimated trajectories. TUM lines are
``timestamp tx ty tz qx qy qz qw`` with the timestamp in seconds.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .errors import FormatError
from .geometry import R_from_quat, R_from_r, T_from_Rt, T_inverse, quat_from_R, r_from_R
from .tomlio import atomic_write_text

__all__ = ["Trajectory", "pose_at", "step_beyond", "poses_at_times", "read_tum", "write_tum", "tum_text",
           "MATCH_TOLERANCE_NS", "MAX_TUM_POSITION"]

MATCH_TOLERANCE_NS = 1_000_000
"""[ns] how far a trajectory's pose may be from a frame's timestamp and still be that frame's
(:func:`poses_at_times`; TUM files written by other tools round their times)."""


@dataclass(frozen=True)
class Trajectory:
    """Poses ``T_world_rig`` at increasing timestamps."""

    timestamps_ns: np.ndarray
    """(N,) int64 [ns], strictly increasing."""
    T_world_rig: np.ndarray
    """(N, 4, 4) rigid transforms, rig frame → world frame."""

    def __post_init__(self) -> None:
        ts = np.asarray(self.timestamps_ns)
        T = np.asarray(self.T_world_rig)
        if ts.ndim != 1 or T.shape != (ts.shape[0], 4, 4):
            raise ValueError("Trajectory: need timestamps (N,) and T_world_rig (N, 4, 4)")

    def __len__(self) -> int:
        return int(self.timestamps_ns.shape[0])

    def relative(self) -> np.ndarray:
        """(N-1, 4, 4) motions between consecutive frames, ``T_rig[i]_rig[i+1]``."""
        return T_inverse(self.T_world_rig[:-1]) @ self.T_world_rig[1:]

    def rebased(self) -> "Trajectory":
        """The same trajectory with world = rig frame at the first frame."""
        return Trajectory(self.timestamps_ns, T_inverse(self.T_world_rig[0]) @ self.T_world_rig)

    @classmethod
    def from_relative(cls, timestamps_ns: np.ndarray, T_prev_next: np.ndarray) -> "Trajectory":
        """Integrate (N-1, 4, 4) frame-to-frame motions ``T_rig[i]_rig[i+1]`` from identity."""
        T = [np.eye(4)]
        for M in T_prev_next:
            T.append(T[-1] @ M)
        return cls(np.asarray(timestamps_ns, dtype=np.int64), np.stack(T))


def poses_at_times(trajectory: Trajectory, timestamps_ns: np.ndarray,
                   tolerance_ns: int = MATCH_TOLERANCE_NS) -> np.ndarray:
    """(N, 4, 4) ``T_world_rig`` of the trajectory's poses at the given (N,) times [ns], each the pose
    nearest in time; ValueError naming the first time without a pose within ``tolerance_ns``."""
    ts = np.asarray(trajectory.timestamps_ns, np.int64)
    want = np.asarray(timestamps_ns, np.int64)
    if ts.size == 0:
        raise ValueError("the trajectory has no poses")
    after = np.clip(np.searchsorted(ts, want), 0, ts.size - 1)          # the nearest pose: this one or
    before = np.maximum(after - 1, 0)                                    # the one before it
    i = np.where(np.abs(ts[before] - want) <= np.abs(ts[after] - want), before, after)
    far = np.flatnonzero(np.abs(ts[i] - want) > tolerance_ns)
    if far.size:
        raise ValueError(f"no pose within {tolerance_ns / 1e6:g} ms of frame time {want[far[0]] * 1e-9:.9f} s")
    return trajectory.T_world_rig[i]


def pose_at(trajectory: Trajectory, t_ns: float) -> np.ndarray:
    """(4, 4) ``T_world_rig`` at time ``t_ns`` [ns]: between two frames the step from the earlier to
    the later one (``T[i]⁻¹ T[i+1]``) taken in the fraction elapsed, split linearly in its rotation
    vector and its translation (as :func:`polycam.synth.smooth_trajectory` builds the frames' steps);
    before the first frame and after the last, that end's step extrapolated. Where an unsynchronised
    camera was when it captured: :func:`polycam.synth.synth_session`'s ``sync_spread_ms`` renders it
    there, :func:`resample.stream.models_at_capture` puts it there."""
    ts = np.asarray(trajectory.timestamps_ns, np.float64)
    T = trajectory.T_world_rig
    if len(ts) < 2:
        return T[0].copy()
    i = int(np.clip(np.searchsorted(ts, t_ns, side="right") - 1, 0, len(ts) - 2))
    a = (float(t_ns) - ts[i]) / (ts[i + 1] - ts[i])
    step = T_inverse(T[i]) @ T[i + 1]
    part = T_from_Rt(R_from_r(a * r_from_R(step[:3, :3])), a * step[:3, 3])
    return T[i] @ part


def step_beyond(T_near: np.ndarray, T_far: np.ndarray, dt_near_ns: float, dt_far_ns: float) -> np.ndarray:
    """(4, 4) the rig's step over ``dt_near_ns`` beyond the first or last frame of a sequence, its velocity
    extrapolated linearly (a constant acceleration) from the two steps nearest that end: ``T_near``,
    the step between the end frame and its neighbour, and ``T_far``, the next one inward ((4, 4) each,
    ``T_prev_next`` of the frames in time order, over ``dt_near_ns`` and ``dt_far_ns`` [ns]). The
    velocity of a step is its translation and rotation vector over its interval, taken at its middle
    (small steps: the vectors of neighbouring steps compare as they are). At the last frame it is the
    step from it to the frame after; at the first, from the frame before to it (the same formula: the
    velocity's change goes on the other way). Where the motion changes from step to step (a hand-held
    rig), holding the end step instead errs by about that change times the share of a step beyond."""
    def velocity(T: np.ndarray, dt: float) -> np.ndarray:
        return np.r_[T[:3, 3], r_from_R(T[:3, :3])] / dt

    v_near = velocity(np.asarray(T_near, np.float64), float(dt_near_ns))
    v_far = velocity(np.asarray(T_far, np.float64), float(dt_far_ns))
    v = v_near + (v_near - v_far) * float(dt_near_ns) / (0.5 * (float(dt_near_ns) + float(dt_far_ns)))
    return T_from_Rt(R_from_r(v[3:] * dt_near_ns), v[:3] * dt_near_ns)


def tum_text(timestamps_ns: np.ndarray, T: np.ndarray) -> str:
    """TUM lines ``timestamp tx ty tz qx qy qz qw`` for poses T (N, 4, 4) at (N,) int64 ns
    (seconds written with ns precision, negative timestamps included)."""
    T = np.asarray(T, dtype=float)
    q = quat_from_R(T[:, :3, :3])
    lines = []
    for ns, Ti, qi in zip(np.asarray(timestamps_ns, dtype=np.int64), T, q):
        sign, a = ("-", -int(ns)) if ns < 0 else ("", int(ns))
        sec = f"{sign}{a // 1_000_000_000}.{a % 1_000_000_000:09d}"
        lines.append(sec + " " + " ".join(f"{v:.9f}" for v in (*Ti[:3, 3], *qi)))
    return "\n".join(lines) + "\n"


def write_tum(path: str | os.PathLike, traj: Trajectory) -> None:
    """Write a TUM file atomically (:func:`tum_text` of ``T_world_rig``)."""
    atomic_write_text(path, tum_text(traj.timestamps_ns, traj.T_world_rig))


def _parse_ns(token: str) -> int:
    """Seconds as text → int ns without going through a float (keeps ns exact)."""
    neg = token.startswith("-")
    body = token.lstrip("+-")
    if "e" in body.lower():
        return int(round(float(token) * 1e9))
    whole, _, frac = body.partition(".")
    if not (whole or frac) or not (whole.isdigit() or whole == "") or not (frac.isdigit() or frac == ""):
        raise ValueError(token)
    ns = int(whole or 0) * 1_000_000_000 + int((frac + "000000000")[:9] or 0)
    return -ns if neg else ns


MAX_TUM_POSITION = 1e9
"""[m] The largest |coordinate| :func:`read_tum` takes (UTM northings are ~1e7 m; beyond 1e9 m a
position is a unit mistake, and 1e300 overflowed when poses were composed)."""
_NS_LIMIT = 2 ** 63
"""Timestamps are int64 nanoseconds (SPEC.md): about ±292 years."""


def read_tum(path: str | os.PathLike) -> Trajectory:
    """Read a TUM file; comments (#) and blank lines are skipped. Positions beyond
    :data:`MAX_TUM_POSITION` and timestamps outside int64 nanoseconds are a :class:`FormatError`."""
    path = Path(path)
    try:
        text = path.read_text()
    except FileNotFoundError:
        raise FormatError(path, "no such file") from None
    except (OSError, UnicodeDecodeError) as e:
        raise FormatError(path, f"cannot read ({e})") from None
    ts, poses = [], []
    for lineno, line in enumerate(text.splitlines(), 1):
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        tok = line.replace(",", " ").split()
        if len(tok) != 8:
            raise FormatError(path, f"expected 8 values 'timestamp tx ty tz qx qy qz qw', got {len(tok)}",
                              f"line {lineno}")
        try:
            ns = _parse_ns(tok[0])
            vals = np.array([float(v) for v in tok[1:]])
        except ValueError:
            raise FormatError(path, "not a number", f"line {lineno}") from None
        except OverflowError:            # an infinite timestamp
            raise FormatError(path, "non-finite value", f"line {lineno}") from None
        if not np.all(np.isfinite(vals)):
            raise FormatError(path, "non-finite value", f"line {lineno}")
        if not -_NS_LIMIT < ns < _NS_LIMIT:
            raise FormatError(path, f"timestamp {tok[0]} s is beyond int64 nanoseconds", f"line {lineno}")
        if np.abs(vals[:3]).max() > MAX_TUM_POSITION:
            raise FormatError(path, f"position beyond {MAX_TUM_POSITION:.0e} m (|t| up to "
                              f"{np.abs(vals[:3]).max():.3g})", f"line {lineno}")
        qn = np.linalg.norm(vals[3:])
        if abs(qn - 1.0) > 1e-3:
            raise FormatError(path, f"quaternion is not unit length (|q| = {qn:.6g})", f"line {lineno}")
        if ts and ns <= ts[-1]:
            raise FormatError(path, "timestamps are not strictly increasing", f"line {lineno}")
        ts.append(ns)
        poses.append(T_from_Rt(R_from_quat(vals[3:]), vals[:3]))
    if not ts:
        raise FormatError(path, "no poses")
    return Trajectory(np.array(ts, dtype=np.int64), np.stack(poses))
