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

from ..geometry import R_from_r, T_from_Rt
from ..trajectory import Trajectory

__all__ = ["frame_timestamps", "static_trajectory", "smooth_trajectory", "make_trajectory"]

_SALT_MOTION = 21


def frame_timestamps(frames: int, fps: float = 30.0, start_ns: int = 0) -> np.ndarray:
    """(frames,) int64 [ns]: ``start_ns + round(i * 1e9 / fps)``."""
    if frames < 1 or not fps > 0:
        raise ValueError("need frames >= 1 and fps > 0")
    return start_ns + np.round(np.arange(frames) * (1e9 / fps)).astype(np.int64)


def static_trajectory(frames: int, fps: float = 30.0, start_ns: int = 0) -> Trajectory:
    """The rig at rest: identity poses."""
    return Trajectory(frame_timestamps(frames, fps, start_ns), np.tile(np.eye(4), (frames, 1, 1)))


def _smooth_profile(rng: np.random.Generator, n: int) -> np.ndarray:
    """(n, 3) smooth random vector signal: a drift plus 3 sinusoids with periods of 15-120 frames."""
    i = np.arange(n, dtype=float)[:, None]
    out = rng.normal(size=(1, 3))                                    # drift
    for _ in range(3):
        period = rng.uniform(15.0, 120.0, size=(1, 3))
        phase = rng.uniform(0.0, 2.0 * np.pi, size=(1, 3))
        out = out + rng.normal(size=(1, 3)) * np.sin(2.0 * np.pi * i / period + phase)
    return out


def smooth_trajectory(frames: int, *, step_t: float = 0.005, step_r_deg: float = 0.2, fps: float = 30.0,
                      seed: int = 0, start_ns: int = 0) -> Trajectory:
    """A smooth random trajectory (see the module docstring); reproducible from ``seed``.

    step_t: [m] RMS translation between consecutive frames.
    step_r_deg: [deg] RMS rotation angle between consecutive frames.
    """
    if step_t < 0 or step_r_deg < 0:
        raise ValueError("step sizes must be >= 0")
    ts = frame_timestamps(frames, fps, start_ns)
    n = frames - 1
    T = np.empty((frames, 4, 4))
    T[0] = np.eye(4)
    if n == 0:
        return Trajectory(ts, T)
    rng = np.random.default_rng([seed, _SALT_MOTION])
    v = _smooth_profile(rng, n)
    w = _smooth_profile(rng, n)
    v *= step_t / max(math.sqrt(np.mean(np.sum(v * v, axis=1))), 1e-300)
    w *= math.radians(step_r_deg) / max(math.sqrt(np.mean(np.sum(w * w, axis=1))), 1e-300)
    steps = T_from_Rt(R_from_r(w), v)
    for i in range(n):
        T[i + 1] = T[i] @ steps[i]
    return Trajectory(ts, T)


def make_trajectory(motion: str, frames: int, *, step_t: float = 0.005, step_r_deg: float = 0.2,
                    fps: float = 30.0, seed: int = 0, start_ns: int = 0) -> Trajectory:
    """``static`` or ``smooth`` (the rig file's ``[mock] motion`` values)."""
    if motion == "static":
        return static_trajectory(frames, fps, start_ns)
    if motion == "smooth":
        return smooth_trajectory(frames, step_t=step_t, step_r_deg=step_r_deg, fps=fps, seed=seed,
                                 start_ns=start_ns)
    raise ValueError(f"unknown motion {motion!r}; expected 'static' or 'smooth'")
