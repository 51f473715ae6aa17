"""Synthetic board observations straight from known models (no rendering): the
ground-truth generator for solver tests and benchmarks (like mrcal's
``synthesize_board_observations``).

:func:`synthetic_observations` projects the board's corners at given poses
``T_rig_board`` through the true models, keeps corners inside the imager, adds
Gaussian pixel noise, and returns :class:`calib.detect.BoardObservations` in
exactly the form :func:`calib.detect.detect_session` produces.

:func:`truth_problem` builds the mrcal problem of such observations AT the truth
(no solve), and :func:`predicted_extrinsics_sigma` gives mrcal's predicted 1-sigma
camera-pose errors from it: the cheap way to choose a calibration design (board,
poses, resolution) before rendering anything.
"""

from __future__ import annotations

import numpy as np

from polycam.board import Board
from polycam.cameras import T_rig_cam_of
from polycam.geometry import T_inverse

from .detect import BoardObservations

__all__ = ["synthetic_observations", "project_board", "coverage_poses", "truth_problem", "predicted_extrinsics_sigma"]


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


def _intrinsics_as(lensmodel_true: str, intrinsics: np.ndarray, lensmodel: str) -> np.ndarray:
    """The true intrinsics in ``lensmodel``: equal models pass through; a pinhole or a smaller
    OPENCV model becomes a larger OPENCV one with zero extra coefficients (same projection)."""
    import re

    import mrcal

    if lensmodel == lensmodel_true:
        return np.asarray(intrinsics, float)
    ok = re.fullmatch(r"LENSMODEL_(PINHOLE|OPENCV\d+)", lensmodel_true) and re.fullmatch(r"LENSMODEL_OPENCV\d+",
                                                                                         lensmodel)
    n = mrcal.lensmodel_num_params(lensmodel)
    if not ok or n < len(intrinsics):
        raise ValueError(f"cannot express {lensmodel_true} intrinsics in {lensmodel}")
    return np.concatenate([intrinsics, np.zeros(n - len(intrinsics))])


def truth_problem(models: dict, board: Board, T_rig_board: np.ndarray, *, lensmodel: str | None = None,
                  min_corners: int = 8, board_warp: bool = True, regularization: bool = True) -> dict:
    """mrcal ``optimization_inputs`` of a board calibration evaluated AT the truth.

    The exact corner projections (:func:`synthetic_observations`, noise-free, views with at
    least ``min_corners`` corners inside the imager) with every parameter at its true value:
    intrinsics (in ``lensmodel``, a full mrcal name; default the true models' own), camera poses
    relative to camera 0 (the reference, as :func:`calib.calibrate_board` solves), board poses
    (mrcal's board frame: origin at the first inner corner), a flat board. The optimisation
    flags are those of calibrate_board's last stage (all intrinsics, extrinsics, frames, and the
    board warp when ``board_warp``; mrcal's regularisation when ``regularization``), so
    :func:`calib.extrinsics_uncertainty` of it is the predicted 1-sigma of a solve of such
    data at a given corner noise.

    models: camera id → true mrcal model (rt_cam_ref = T_cam_rig), all of one lens model.
    T_rig_board: (F, 4, 4) board poses (OpenCV board frame, :mod:`polycam.board`).
    """
    from polycam.geometry import T_from_Rt, rt_from_T

    obs = synthetic_observations(models, board, T_rig_board, min_corners=min_corners)
    cams = obs.cameras
    if len(obs.indices_frame_camera) == 0:
        raise ValueError("no camera sees the board in any pose")
    true_lens = models[cams[0]].intrinsics()[0]
    lens = lensmodel or true_lens
    frames, iframe = np.unique(obs.indices_frame_camera[:, 0], return_inverse=True)
    ifc = np.stack([iframe, obs.indices_frame_camera[:, 1], obs.indices_frame_camera[:, 1] - 1], axis=1)
    T_cam0_rig = T_inverse(T_rig_cam_of(models[cams[0]]))
    s = float(board.square_length)
    T_cv_mrcal = T_from_Rt(np.eye(3), np.array([s, s, 0.0]))       # mrcal board frame → OpenCV board frame
    rt_ref_frame = np.stack([rt_from_T(T_cam0_rig @ np.asarray(T_rig_board[f], float) @ T_cv_mrcal)
                             for f in frames])
    rt_cam_ref = np.stack([rt_from_T(T_inverse(T_rig_cam_of(models[c])) @ T_inverse(T_cam0_rig))
                           for c in cams[1:]]).reshape(-1, 6)
    intrinsics = np.stack([_intrinsics_as(true_lens, models[c].intrinsics()[1], lens) for c in cams])
    return dict(intrinsics=np.ascontiguousarray(intrinsics), rt_cam_ref=np.ascontiguousarray(rt_cam_ref),
                rt_ref_frame=np.ascontiguousarray(rt_ref_frame), points=None,
                observations_board=np.ascontiguousarray(obs.observations),
                indices_frame_camintrinsics_camextrinsics=np.ascontiguousarray(ifc, dtype=np.int32),
                observations_point=None, indices_point_camintrinsics_camextrinsics=None, lensmodel=lens,
                imagersizes=np.ascontiguousarray(obs.imagersizes), calobject_warp=np.zeros(2) if board_warp else None,
                do_optimize_intrinsics_core=True, do_optimize_intrinsics_distortions=True,
                do_optimize_extrinsics=True, do_optimize_frames=True, do_optimize_calobject_warp=board_warp,
                calibration_object_spacing=s, do_apply_outlier_rejection=False,
                do_apply_regularization=regularization, verbose=False)


def predicted_extrinsics_sigma(models: dict, board: Board, T_rig_board: np.ndarray, noise_px: float,
                               **kwargs) -> np.ndarray:
    """(C, 2) mrcal's predicted 1-sigma [rad, m] of each camera's pose relative to camera 0
    (:func:`calib.extrinsics_uncertainty`) for a solve of these board poses at corner noise
    ``noise_px`` [px per coordinate], from :func:`truth_problem` (kwargs go there)."""
    from .board_solve import extrinsics_uncertainty

    return extrinsics_uncertainty(truth_problem(models, board, T_rig_board, **kwargs), noise_px)
