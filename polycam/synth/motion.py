"""Seeded rig trajectories for synthetic data.

A trajectory is a :class:`~polycam.trajectory.Trajectory` of ``T_world_rig``
with world = the rig frame at frame 0 (so ``T_world_rig[0]`` is the identity),
timestamps ``start_ns + round(i * 1e9 / fps)``.

:func:`smooth_trajectory` integrates a smooth random body velocity: each of the
six components (translation [m/frame], rotation [rad/frame], in the rig frame)
is a constant drift plus a few random low-frequency sinusoids, and the whole
velocity is scaled so the RMS per-frame step is ``step_t`` [m] and
``step_r_deg`` [deg]. Frame i+1 is ``T[i] @ T_from_rt(w_i, v_i)``.
"""

from __future__ import annotations

import math

import numpy as np

from ..geometry import R_from_r, T_from_Rt, T_inverse
from ..trajectory import Trajectory

__all__ = ["frame_timestamps", "static_trajectory", "smooth_trajectory", "make_trajectory", "frames_of"]

_SALT_MOTION = 21


def frame_timestamps(frames: int, fps: float = 30.0, start_ns: int = 0) -> np.ndarray:
    """(frames,) int64 [ns]: ``start_ns + round(i * 1e9 / fps)``."""
    if frames < 1 or not fps > 0:
        raise ValueError("need frames >= 1 and fps > 0")
    return start_ns + np.round(np.arange(frames) * (1e9 / fps)).astype(np.int64)


def static_trajectory(frames: int, fps: float = 30.0, start_ns: int = 0) -> Trajectory:
    """The rig at rest: identity poses."""
    return Trajectory(frame_timestamps(frames, fps, start_ns), np.tile(np.eye(4), (frames, 1, 1)))


def _timestamps_with_margin(frames: int, fps: float, start_ns: int, margin: int) -> np.ndarray:
    """(frames + 2 margin,) int64 [ns]: :func:`frame_timestamps` with ``margin`` more before and after."""
    if margin < 0:
        raise ValueError(f"margin must be >= 0, got {margin}")
    frame_timestamps(frames, fps, start_ns)                       # (checks frames and fps)
    return start_ns + np.round(np.arange(-margin, frames + margin) * (1e9 / fps)).astype(np.int64)


def _smooth_profile(rng: np.random.Generator, steps: np.ndarray) -> np.ndarray:
    """(S, 3) smooth random vector signal at the (S,) step indices ``steps``: a drift plus 3 sinusoids
    with periods of 15-120 frames (the same draws whatever the indices)."""
    i = np.asarray(steps, dtype=float)[:, None]
    out = rng.normal(size=(1, 3))                                    # drift
    for _ in range(3):
        period = rng.uniform(15.0, 120.0, size=(1, 3))
        phase = rng.uniform(0.0, 2.0 * np.pi, size=(1, 3))
        out = out + rng.normal(size=(1, 3)) * np.sin(2.0 * np.pi * i / period + phase)
    return out


def smooth_trajectory(frames: int, *, step_t: float = 0.005, step_r_deg: float = 0.2, fps: float = 30.0,
                      seed: int = 0, start_ns: int = 0, margin: int = 0) -> Trajectory:
    """A smooth random trajectory (see the module docstring); reproducible from ``seed``.

    step_t: [m] RMS translation between consecutive frames.
    step_r_deg: [deg] RMS rotation angle between consecutive frames.
    margin: poses added before the first frame and after the last, the same motion going on (a rig
        moves before a capture starts and after it stops; free-running cameras capture up to a period
        beyond the frames' times): ``frames + 2 margin`` poses, whose ``margin``-th is the first
        frame's (the identity, at ``start_ns``) and the ``frames`` from it the same as without one.
    """
    if step_t < 0 or step_r_deg < 0:
        raise ValueError("step sizes must be >= 0")
    ts = _timestamps_with_margin(frames, fps, start_ns, margin)
    n = frames - 1
    T = np.empty((frames + 2 * margin, 4, 4))
    T[margin] = np.eye(4)
    if n + 2 * margin == 0:
        return Trajectory(ts, T)
    rng = np.random.default_rng([seed, _SALT_MOTION])
    idx = np.arange(-margin, n + margin)                          # step j: pose j to j + 1 (frame 0: j = 0)
    v = _smooth_profile(rng, idx)
    w = _smooth_profile(rng, idx)
    core = slice(margin, margin + n) if n > 0 else slice(None)    # scaled by the frames' own steps
    v *= step_t / max(math.sqrt(np.mean(np.sum(v[core] ** 2, axis=1))), 1e-300)
    w *= math.radians(step_r_deg) / max(math.sqrt(np.mean(np.sum(w[core] ** 2, axis=1))), 1e-300)
    steps = T_from_Rt(R_from_r(w), v)
    for i in range(margin, n + 2 * margin):
        T[i + 1] = T[i] @ steps[i]
    for i in range(margin - 1, -1, -1):
        T[i] = T[i + 1] @ T_inverse(steps[i])
    return Trajectory(ts, T)


def make_trajectory(motion: str, frames: int, *, step_t: float = 0.005, step_r_deg: float = 0.2,
                    fps: float = 30.0, seed: int = 0, start_ns: int = 0, margin: int = 0) -> Trajectory:
    """``static`` or ``smooth`` (the rig file's ``[mock] motion`` values); ``margin``: as
    :func:`smooth_trajectory`'s."""
    if motion == "static":
        ts = _timestamps_with_margin(frames, fps, start_ns, margin)
        return Trajectory(ts, np.tile(np.eye(4), (len(ts), 1, 1)))
    if motion == "smooth":
        return smooth_trajectory(frames, step_t=step_t, step_r_deg=step_r_deg, fps=fps, seed=seed,
                                 start_ns=start_ns, margin=margin)
    raise ValueError(f"unknown motion {motion!r}; expected 'static' or 'smooth'")


def frames_of(trajectory: Trajectory, margin: int) -> Trajectory:
    """The frames of a trajectory made with ``margin`` (:func:`smooth_trajectory`): without the poses
    before and after them."""
    frames = slice(margin, len(trajectory) - margin)
    return Trajectory(trajectory.timestamps_ns[frames].copy(), trajectory.T_world_rig[frames].copy())
