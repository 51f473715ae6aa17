"""Putting a solved rig into the rig frame (SPEC.md): a rigid fit of solved camera
poses to the rig file's nominal ones, and similarity alignment for comparisons.

A joint solve is expressed in an arbitrary reference (camera 0 for mrcal, the
first image for COLMAP). :func:`fit_rig_frame` finds the rigid transform
``T_rig_ref`` (rotation and translation, **no scale**: the board or the rig
file already fixes metric scale) that best maps the solved cameras onto their
nominal poses, using both camera centres and orientations::

    minimise  sum_i |R c_i + t - p_i|^2  +  w sum_i |R R_ref_cam_i - R_rig_cam_i|_F^2

with ``c_i`` the solved centres, ``p_i`` the nominal ones, and ``w = (σ_p / σ_r)^2``
from the expected mounting tolerances of a camera's position ``σ_p`` (default 1 mm)
and orientation ``σ_r`` (default 0.5 deg), i.e. both terms weighted by their
inverse variances (with a single camera or collinear centres the orientation term
alone fixes the rotation). The closed form is a weighted Kabsch/polar
decomposition. To compare a solve with the truth, use a large ``σ_p`` (the
rotation then comes from the orientations only, as in the benchmarks).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from polycam.geometry import T_from_Rt, r_from_R

__all__ = ["RigFit", "fit_rig_frame", "fit_similarity", "rotation_angle"]


def _polar(M: np.ndarray) -> np.ndarray:
    """The rotation closest to M (3, 3) (det = +1)."""
    U, _, Vt = np.linalg.svd(M)
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))])
    return U @ D @ Vt


def rotation_angle(R: np.ndarray) -> np.ndarray:
    """Rotation angle [rad] of rotation matrices R (..., 3, 3)."""
    return np.linalg.norm(r_from_R(np.asarray(R, float)), axis=-1)


@dataclass(frozen=True)
class RigFit:
    """Result of :func:`fit_rig_frame`."""

    T_rig_ref: np.ndarray
    """(4, 4) solve reference frame → rig frame."""
    position_residuals_m: np.ndarray
    """(N,) [m] distance of each aligned camera centre from its nominal one."""
    rotation_residuals_rad: np.ndarray
    """(N,) [rad] angle between each aligned camera orientation and its nominal one."""


def fit_rig_frame(T_ref_cam: np.ndarray, T_rig_cam_nominal: np.ndarray, *, position_sigma_m: float = 1e-3,
                  rotation_sigma_deg: float = 0.5) -> RigFit:
    """Rigid ``T_rig_ref`` that best maps solved camera poses onto nominal ones.

    T_ref_cam: (N, 4, 4) solved camera poses in the solve's reference frame.
    T_rig_cam_nominal: (N, 4, 4) nominal poses from the rig file.
    position_sigma_m, rotation_sigma_deg: expected deviations from nominal (the weights).
    """
    A = np.asarray(T_ref_cam, float)
    B = np.asarray(T_rig_cam_nominal, float)
    c, p = A[:, :3, 3], B[:, :3, 3]
    c0, p0 = c.mean(axis=0), p.mean(axis=0)
    a, b = c - c0, p - p0
    w = (float(position_sigma_m) / np.radians(float(rotation_sigma_deg))) ** 2
    M = b.T @ a + w * np.einsum("nij,nkj->ik", B[:, :3, :3], A[:, :3, :3])
    R = _polar(M)
    t = p0 - R @ c0
    T = T_from_Rt(R, t)
    aligned = np.einsum("ij,njk->nik", T, A)
    pos = np.linalg.norm(aligned[:, :3, 3] - p, axis=1)
    rot = rotation_angle(np.einsum("nji,njk->nik", aligned[:, :3, :3], B[:, :3, :3]))
    return RigFit(T, pos, rot)


def fit_similarity(src: np.ndarray, dst: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
    """Umeyama similarity ``dst ≈ s R src + t`` for points (N, 3); returns (s, R (3, 3), t (3,))."""
    src = np.asarray(src, float)
    dst = np.asarray(dst, float)
    ms, md = src.mean(axis=0), dst.mean(axis=0)
    a, b = src - ms, dst - md
    U, S, Vt = np.linalg.svd(b.T @ a / len(src))
    d = np.sign(np.linalg.det(U @ Vt))
    D = np.diag([1.0, 1.0, d])
    R = U @ D @ Vt
    var = float(np.mean(np.sum(a**2, axis=1)))
    s = float(np.trace(np.diag(S) @ D) / var) if var > 0 else 1.0
    t = md - s * R @ ms
    return s, R, t
