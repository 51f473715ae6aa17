"""Synthetic board observations straight from known models (no rendering): the
ground-truth generator for solver tests and benchmarks (like mrcal's
``synthesize_board_observations``).

:func:`synthetic_observations` projects the board's corners at given poses
``T_rig_board`` through the true models, keeps corners inside the imager, adds
Gaussian pixel noise, and returns :class:`calib.detect.BoardObservations` in
exactly the form :func:`calib.detect.detect_session` produces.
"""

from __future__ import annotations

import numpy as np

from polycam.board import Board
from polycam.cameras import T_rig_cam_of
from polycam.geometry import T_inverse

from .detect import BoardObservations

__all__ = ["synthetic_observations", "project_board", "coverage_poses"]


def project_board(model, board: Board, T_rig_board: np.ndarray) -> np.ndarray:
    """(H, W, 2) [px] projections of the board's inner corners (mrcal grid order); NaN behind."""
    import mrcal

    P = board.object_points()                                   # (N, 3) OpenCV board frame
    T_cam_board = T_inverse(T_rig_cam_of(model)) @ np.asarray(T_rig_board, float)
    p = P @ T_cam_board[:3, :3].T + T_cam_board[:3, 3]
    q = mrcal.project(np.ascontiguousarray(p), *model.intrinsics())
    q[p[:, 2] <= 0] = np.nan
    return q.reshape(board.rows - 1, board.cols - 1, 2)


def synthetic_observations(models: dict, board: Board, T_rig_board: np.ndarray, *, noise_px: float = 0.0,
                           rng: np.random.Generator | None = None, min_corners: int = 8,
                           margin_px: float = 0.0) -> BoardObservations:
    """Board observations of every camera at every pose (see the module docstring).

    models: camera id → true mrcal model (rt_cam_ref = T_cam_rig).
    T_rig_board: (F, 4, 4) board poses (OpenCV board frame, :mod:`polycam.board`).
    noise_px: std [px] of the Gaussian noise added to each corner coordinate.
    min_corners: views with fewer visible corners are left out (as detection would).
    """
    rng = rng if rng is not None else np.random.default_rng(0)
    cams = list(models)
    H, W = board.rows - 1, board.cols - 1
    obs, idx, paths = [], [], []
    counts = {c: {"images": 0, "used": 0} for c in cams}
    for i, T in enumerate(np.asarray(T_rig_board, float)):
        for ci, cam in enumerate(cams):
            m = models[cam]
            Wi, Hi = (float(v) for v in m.imagersize())
            q = project_board(m, board, T)
            counts[cam]["images"] += 1
            inside = np.all(np.isfinite(q), axis=-1) & (q[..., 0] >= margin_px - 0.5) & \
                (q[..., 1] >= margin_px - 0.5) & (q[..., 0] <= Wi - 0.5 - margin_px) & \
                (q[..., 1] <= Hi - 0.5 - margin_px)
            if inside.sum() < min_corners:
                continue
            o = np.full((H, W, 3), -1.0)
            o[..., :2] = np.where(inside[..., None], q + rng.normal(size=q.shape) * noise_px, -1.0)
            o[..., 2] = np.where(inside, 1.0, -1.0)
            obs.append(o)
            idx.append((i, ci))
            paths.append(f"{cam}/frame{i:04d}")
            counts[cam]["used"] += 1
    return BoardObservations(board=board, cameras=cams,
                             imagersizes=np.array([[int(v) for v in models[c].imagersize()] for c in cams], np.int32),
                             observations=np.ascontiguousarray(np.array(obs).reshape(-1, H, W, 3)),
                             indices_frame_camera=np.array(idx, np.int32).reshape(-1, 2), paths=paths, counts=counts,
                             skipped={c: {} for c in cams}, found_markers=True)


def coverage_poses(board: Board, models: dict, frames: int, *, seed: int = 0, fill: tuple[float, float] = (0.3, 0.6),
                   tilt_deg: float = 45.0, roll_deg: float = 30.0, spread: float = 0.9) -> np.ndarray:
    """(frames, 4, 4) seeded board poses ``T_rig_board`` that cover whole imagers.

    Frame i aims at camera ``i % N`` (models' order): seen square-on, the board would
    span a fraction ``fill`` of that camera's image; its centre is a uniform random
    pixel of the central ``spread`` fraction of the image (so corners of the imager
    are covered and some views are partial, as mrcal's calibration guide asks);
    tilted by up to ``tilt_deg`` about a random in-plane axis and rolled by up to
    ``roll_deg``. Unlike :func:`polycam.synth.board_poses` the board may leave the
    image partly (ChArUco keeps partial views).
    """
    import math

    import mrcal

    from polycam.geometry import R_from_r, T_from_Rt

    ids = list(models)
    rng = np.random.default_rng([seed, 77])
    bw, bh = board.size_m
    centre_b = np.array([bw / 2.0, bh / 2.0, 0.0])
    out = np.empty((frames, 4, 4))
    for i in range(frames):
        model = models[ids[i % len(ids)]]
        lens, intr = model.intrinsics()
        W, H = (float(v) for v in model.imagersize())
        scale = rng.uniform(*fill) * min(W / bw, H / bh)
        z = intr[0] / scale
        lo, hi = (1.0 - spread) / 2.0, (1.0 + spread) / 2.0
        q = np.array([rng.uniform(lo, hi) * (W - 1), rng.uniform(lo, hi) * (H - 1)])
        d = mrcal.unproject(q, lens, intr, normalize=True)
        p_c = d * (z / d[2])
        phi = rng.uniform(0.0, 2.0 * np.pi)
        tilt = math.radians(rng.uniform(-tilt_deg, tilt_deg))
        az = math.radians(rng.uniform(-roll_deg, roll_deg))
        R = R_from_r(np.array([0.0, 0.0, az])) @ R_from_r(tilt * np.array([math.cos(phi), math.sin(phi), 0.0]))
        out[i] = T_rig_cam_of(model) @ T_from_Rt(R, p_c - R @ centre_b)
    return out
