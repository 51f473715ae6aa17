"""Depth from plenoptic derivatives: differential stereo and motion (paper Eq. 6–7).

On a Lambertian surface a face's light field is locally
``L(x, y, u, v) = τ(x + λ u, y + λ v)`` with ``λ = Z / f``, where ``Z`` [m] is the
depth of the surface point along the face's z axis measured from the focal plane
Π (``z = z_pi``). Hence (Eq. 6, our derivation; NOTES.md's ``L_u / (f L_x)`` drops a
factor f² — units show it)::

    L_u = λ L_x,   L_v = λ L_y                      (differential stereo)

and, with a known ray motion δ = (δx, δy, δu, δv) of the frame pair (Eq. 5 rows),
substituting Eq. 6 into ``L_t + L_x δx + L_y δy + L_u δu + L_v δv = 0``::

    λ (L_x δu + L_y δv) = −(L_t + L_x δx + L_y δy)    (Eq. 7, last form)

All three are linear in λ: ``a_i λ = b_i``. They are fused per ray by weighted
least squares over a small (u, v) neighbourhood (prefilter-weighted sums of
``a²`` and ``a b``): ``λ = Σ a b / Σ a²``. The confidence is the information
``Σ a²`` times the fraction of the equations' energy explained by one depth
(near 0 at occlusion boundaries, where two depths mix, and in textureless areas).
This is a first implementation (one scale; no scale selection or temporal
integration, paper Sect. 4.1).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .derivatives import FILTERS, Derivatives, correlate_axis
from .geometry import T_inverse, rt_from_T
from .lightfield import LightFieldGrid

__all__ = ["DepthMap", "depth_from_derivatives"]


@dataclass(frozen=True)
class DepthMap:
    """Per-ray depth of a light-field frame pair (arrays of dims (F, Ny, Nx, Nv, Nu))."""

    Z: np.ndarray
    """[m] depth along each face's z axis from its focal plane Π (NaN where unknown)."""
    confidence: np.ndarray
    """Information × consistency, ≥ 0 (0 = no estimate); comparable within one frame pair."""
    consistency: np.ndarray
    """In [0, 1]: fraction of the equations' energy explained by one depth."""

    def range_along_ray(self, grid: LightFieldGrid) -> np.ndarray:
        """[m] distance from each ray's origin on Π to the surface, ``Z |(u, v, f)| / f``."""
        out = np.empty_like(self.Z)
        for k, face in enumerate(grid.faces):
            v, u = np.meshgrid(grid.v.values, grid.u.values, indexing="ij")
            out[k] = self.Z[k] * (np.sqrt(u * u + v * v + face.f ** 2) / face.f)[None, None]
        return out


def _ray_flow(grid: LightFieldGrid, k: int, p_face: np.ndarray):
    """First-order flow (δx, δy, δu, δv) of face k's rays for face-frame (t, ω), each
    broadcastable to (Ny, Nx, Nv, Nu)."""
    face = grid.faces[k]
    f, Z = face.f, face.z_pi
    y = grid.y.values[:, None, None, None]
    x = grid.x.values[None, :, None, None]
    v = grid.v.values[None, None, :, None]
    u = grid.u.values[None, None, None, :]
    tx, ty, tz, wx, wy, wz = p_face
    dx = tx - u / f * tz - u * y / f * wx + (u * x / f + Z) * wy - y * wz
    dy = ty - v / f * tz - (v * y / f + Z) * wx + v * x / f * wy + x * wz
    du = -u * v / f * wx + (u * u / f + f) * wy - v * wz
    dv = -(v * v / f + f) * wx + u * v / f * wy + u * wz
    return dx, dy, du, dv


def _smooth_uv(a: np.ndarray, radius: int) -> np.ndarray:
    """Smooth a (F, Ny, Nx, Nv, Nu) array over (u, v) with the fs5 prefilter applied
    ``radius // 2`` times (0 = none)."""
    taps = FILTERS["fs5"].prefilter
    out = np.ascontiguousarray(a, dtype=np.float32)
    for _ in range(max(0, radius // 2)):
        out = correlate_axis(correlate_axis(out, taps, 3), taps, 4)
    return out


def depth_from_derivatives(der: Derivatives, grid: LightFieldGrid, *,
                           T_prev_next: np.ndarray | None = None, window: int = 4,
                           min_confidence: float = 0.0) -> DepthMap:
    """Per-ray depth from the plenoptic derivatives of a frame pair.

    ``der``: :func:`~polycam.derivatives.plenoptic_derivatives` of frames (L0, L1).
    ``T_prev_next``: (4, 4) rig motion ``T_rig0_rig1`` (e.g. from
    :func:`~polycam.motion.estimate_motion`); with it the temporal equation (Eq. 7)
    joins the two stereo equations, without it only Eq. 6 is used (one frame's
    structure suffices). ``window``: neighbourhood size in (u, v) samples for the
    fusion. Rays with confidence ≤ ``min_confidence`` get ``Z = NaN``.
    """
    # the equations a λ = b, stacked per ray as sums a², a b, b² (float32 arrays)
    Lx, Ly, Lu, Lv, Lt = der.Lx, der.Ly, der.Lu, der.Lv, der.Lt
    aa = Lx * Lx + Ly * Ly
    ab = Lx * Lu + Ly * Lv
    bb = Lu * Lu + Lv * Lv
    if T_prev_next is not None:
        G = T_inverse(np.asarray(T_prev_next, float))          # the rays' motion
        rt = rt_from_T(G)
        p_rig = np.concatenate([rt[3:], rt[:3]])
        for k, face in enumerate(grid.faces):
            R = np.asarray(face.R_rig_face, float)
            p_face = np.concatenate([R.T @ p_rig[:3], R.T @ p_rig[3:]])
            dx, dy, du, dv = _ray_flow(grid, k, p_face)
            a3 = Lx[k] * du + Ly[k] * dv
            b3 = -(Lt[k] + Lx[k] * dx + Ly[k] * dy)
            aa[k] += a3 * a3
            ab[k] += a3 * b3
            bb[k] += b3 * b3
    valid = np.broadcast_to(der.valid, aa.shape).astype(np.float32)
    Saa = _smooth_uv(aa * valid, window)
    Sab = _smooth_uv(ab * valid, window)
    Sbb = _smooth_uv(bb * valid, window)
    with np.errstate(divide="ignore", invalid="ignore"):
        lam = np.where(Saa > 0, Sab / Saa, np.nan)
        # energy explained by the best single depth: (Σab)² / (Σa² Σb²) ∈ [0, 1]
        consistency = np.where((Saa > 0) & (Sbb > 0), (Sab * Sab) / (Saa * Sbb), 0.0)
    consistency = np.clip(np.nan_to_num(consistency), 0.0, 1.0).astype(np.float32)
    confidence = (Saa * consistency * (valid > 0)).astype(np.float32)
    Z = np.empty_like(lam, dtype=np.float32)
    for k, face in enumerate(grid.faces):
        Z[k] = lam[k] * face.f
    Z = np.where(confidence > min_confidence, Z, np.nan).astype(np.float32)
    return DepthMap(Z=Z, confidence=confidence, consistency=consistency)
