"""Rigid-transform helpers on plain numpy arrays.

Conventions (docs/conventions.md): a transform ``T_a_b`` is a (..., 4, 4)
homogeneous matrix mapping points from frame b into frame a
(``p_a = T_a_b @ p_b``). Rotations ``R_a_b`` are (..., 3, 3). Axis-angle
vectors ``r`` are (..., 3) [rad] (mrcal's ``r``). Quaternions are
``(qx, qy, qz, qw)`` as in the TUM format, unit norm, ``qw >= 0``.
"""

from __future__ import annotations

import numpy as np

__all__ = [
    "skew",
    "adjoint",
    "R_from_r",
    "r_from_R",
    "quat_from_R",
    "R_from_quat",
    "T_from_Rt",
    "T_inverse",
    "T_from_rt",
    "rt_from_T",
    "transform_points",
    "rotate_vectors",
]


def skew(w: np.ndarray) -> np.ndarray:
    """Cross-product matrices ``[w]_x`` of dims (..., 3, 3) from w of dims (..., 3)."""
    w = np.asarray(w, dtype=float)
    S = np.zeros(w.shape[:-1] + (3, 3))
    S[..., 0, 1], S[..., 0, 2] = -w[..., 2], w[..., 1]
    S[..., 1, 0], S[..., 1, 2] = w[..., 2], -w[..., 0]
    S[..., 2, 0], S[..., 2, 1] = -w[..., 1], w[..., 0]
    return S


def adjoint(T: np.ndarray) -> np.ndarray:
    """(6, 6) adjoint of a rigid transform T (4, 4) acting on twists ordered (v, ω):
    ``[[R, [p]ₓ R], [0, R]]``."""
    R, p = T[:3, :3], T[:3, 3]
    A = np.zeros((6, 6))
    A[:3, :3] = R
    A[:3, 3:] = skew(p) @ R
    A[3:, 3:] = R
    return A


def R_from_r(r: np.ndarray) -> np.ndarray:
    """Rotation matrices (..., 3, 3) from axis-angle vectors r (..., 3) [rad] (Rodrigues)."""
    r = np.asarray(r, dtype=float)
    theta = np.linalg.norm(r, axis=-1)[..., None, None]
    K = skew(r)
    small = theta < 1e-8
    th = np.where(small, 1.0, theta)
    a = np.where(small, 1.0 - theta**2 / 6.0, np.sin(th) / th)
    b = np.where(small, 0.5 - theta**2 / 24.0, (1.0 - np.cos(th)) / th**2)
    return np.eye(3) + a * K + b * (K @ K)


def r_from_R(R: np.ndarray) -> np.ndarray:
    """Axis-angle vectors (..., 3) [rad] from rotation matrices R (..., 3, 3)."""
    q = quat_from_R(R)
    v, w = q[..., :3], q[..., 3]
    s = np.linalg.norm(v, axis=-1)
    angle = 2.0 * np.arctan2(s, w)
    scale = np.where(s < 1e-12, 2.0, angle / np.where(s < 1e-12, 1.0, s))
    return v * scale[..., None]


def quat_from_R(R: np.ndarray) -> np.ndarray:
    """Unit quaternions (..., 4) as (qx, qy, qz, qw), qw >= 0, from R (..., 3, 3)."""
    R = np.asarray(R, dtype=float)
    m = R.reshape(-1, 3, 3)
    q = np.empty((m.shape[0], 4))
    tr = np.trace(m, axis1=1, axis2=2)
    # Choose the numerically largest of w, x, y, z per matrix (Shepperd's method).
    cand = np.stack([tr, m[:, 0, 0], m[:, 1, 1], m[:, 2, 2]], axis=1)
    k = np.argmax(cand, axis=1)
    for i in range(m.shape[0]):
        a = m[i]
        if k[i] == 0:
            s = 2.0 * np.sqrt(max(1.0 + tr[i], 1e-300))
            q[i] = [(a[2, 1] - a[1, 2]) / s, (a[0, 2] - a[2, 0]) / s, (a[1, 0] - a[0, 1]) / s, 0.25 * s]
        elif k[i] == 1:
            s = 2.0 * np.sqrt(max(1.0 + a[0, 0] - a[1, 1] - a[2, 2], 1e-300))
            q[i] = [0.25 * s, (a[0, 1] + a[1, 0]) / s, (a[0, 2] + a[2, 0]) / s, (a[2, 1] - a[1, 2]) / s]
        elif k[i] == 2:
            s = 2.0 * np.sqrt(max(1.0 - a[0, 0] + a[1, 1] - a[2, 2], 1e-300))
            q[i] = [(a[0, 1] + a[1, 0]) / s, 0.25 * s, (a[1, 2] + a[2, 1]) / s, (a[0, 2] - a[2, 0]) / s]
        else:
            s = 2.0 * np.sqrt(max(1.0 - a[0, 0] - a[1, 1] + a[2, 2], 1e-300))
            q[i] = [(a[0, 2] + a[2, 0]) / s, (a[1, 2] + a[2, 1]) / s, 0.25 * s, (a[1, 0] - a[0, 1]) / s]
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    q[q[:, 3] < 0] *= -1.0
    return q.reshape(R.shape[:-2] + (4,))


def R_from_quat(q: np.ndarray) -> np.ndarray:
    """Rotation matrices (..., 3, 3) from quaternions q (..., 4) as (qx, qy, qz, qw)."""
    q = np.asarray(q, dtype=float)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    x, y, z, w = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    R = np.empty(q.shape[:-1] + (3, 3))
    R[..., 0, 0] = 1 - 2 * (y * y + z * z)
    R[..., 0, 1] = 2 * (x * y - z * w)
    R[..., 0, 2] = 2 * (x * z + y * w)
    R[..., 1, 0] = 2 * (x * y + z * w)
    R[..., 1, 1] = 1 - 2 * (x * x + z * z)
    R[..., 1, 2] = 2 * (y * z - x * w)
    R[..., 2, 0] = 2 * (x * z - y * w)
    R[..., 2, 1] = 2 * (y * z + x * w)
    R[..., 2, 2] = 1 - 2 * (x * x + y * y)
    return R


def T_from_Rt(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Homogeneous transforms (..., 4, 4) from R (..., 3, 3) and t (..., 3)."""
    R = np.asarray(R, dtype=float)
    t = np.asarray(t, dtype=float)
    shape = np.broadcast_shapes(R.shape[:-2], t.shape[:-1])
    T = np.zeros(shape + (4, 4))
    T[..., :3, :3] = R
    T[..., :3, 3] = t
    T[..., 3, 3] = 1.0
    return T


def T_inverse(T: np.ndarray) -> np.ndarray:
    """Inverse of rigid transforms T (..., 4, 4): ``T_b_a`` from ``T_a_b``."""
    T = np.asarray(T, dtype=float)
    R = np.swapaxes(T[..., :3, :3], -1, -2)
    return T_from_Rt(R, -(R @ T[..., :3, 3:4])[..., 0])


def T_from_rt(rt: np.ndarray) -> np.ndarray:
    """Transforms (..., 4, 4) from mrcal ``rt`` vectors (..., 6): axis-angle r then t."""
    rt = np.asarray(rt, dtype=float)
    return T_from_Rt(R_from_r(rt[..., :3]), rt[..., 3:])


def rt_from_T(T: np.ndarray) -> np.ndarray:
    """mrcal ``rt`` vectors (..., 6) from transforms T (..., 4, 4)."""
    T = np.asarray(T, dtype=float)
    return np.concatenate([r_from_R(T[..., :3, :3]), T[..., :3, 3]], axis=-1)


def transform_points(T_a_b: np.ndarray, p_b: np.ndarray) -> np.ndarray:
    """Points p_a (..., 3) from points p_b (..., 3) and one transform T_a_b (4, 4)."""
    T_a_b = np.asarray(T_a_b, dtype=float)
    return p_b @ T_a_b[:3, :3].T + T_a_b[:3, 3]


def rotate_vectors(R_a_b: np.ndarray, v_b: np.ndarray) -> np.ndarray:
    """Vectors v_a (..., 3) from v_b (..., 3) and one rotation R_a_b (3, 3)."""
    return v_b @ np.asarray(R_a_b, dtype=float).T
