"""Plenoptic egomotion: rig motion between two light-field frames (paper Eq. 5).

Conventions (SPEC.md, docs/conventions.md). A frame is an array ``L`` of dims
``(F, Ny, Nx, Nv, Nu)`` on a :class:`~polycam.lightfield.LightFieldGrid`: sample
``(x, y, u, v)`` of face k is the ray with origin ``o = (x, y, z_pi)`` and direction
``d ∝ (u, v, f)`` in face coordinates, ``R_rig_face`` maps face to rig coordinates.

Sign convention, derived from ray geometry
------------------------------------------
Let ``M = T_rig[i]_rig[i+1]`` be the rig's motion (the pose of frame i+1 in the
rig frame of frame i; :meth:`Trajectory.relative`). The scene is static, so a
ray ``ρ`` expressed in rig frame i+1 sees what the same physical ray, ``M ρ`` in
rig frame i, saw before::

    L_{i+1}(ρ) = L_i(M ρ)        ⇔        L_{i+1}(G ρ) = L_i(ρ),   G = M⁻¹.

The paper's constraint (NOTES.md Eq. 2–5) is written for ``G``: the ray ``ρ`` of
frame i is found at ``G ρ`` in frame i+1, and for ``G ≈ (I + [ω]ₓ, t)`` a ray moves
by ``δo = ω × o + t``, ``δd = ω × d``. Re-intersecting the moved ray with the plane
``z = z_pi`` and the image plane ``z = z_pi + f`` gives, to first order,

    δx = t_x − (u/f) t_z − (uy/f) ω_x + (ux/f + z_pi) ω_y − y ω_z
    δy = t_y − (v/f) t_z − (vy/f + z_pi) ω_x + (vx/f) ω_y + x ω_z
    δu = −(uv/f) ω_x + (u²/f + f) ω_y − v ω_z
    δv = −(v²/f + f) ω_x + (uv/f) ω_y + u ω_z

and ``L_t + L_x δx + L_y δy + L_u δu + L_v δv = 0``: exactly the rows of M_t, M_ω
in paper Eq. 5. Each face sees ``(R_rig_faceᵀ t, R_rig_faceᵀ ω)``; all faces
stack into one system for the rig-frame ``(t, ω)`` of ``G``. The rig motion is
``M = G⁻¹``: to first order a rig moving by ``+t`` along x gives ``G`` with
``t_x < 0`` and the output ``T_prev_next`` has ``+t_x``.

Iterated linearisation (warping)
--------------------------------
With a current estimate ``M_e``, frame 2 is resampled at the moved rays,
``L1w(ρ) = L1(M_e⁻¹ ρ)`` (each grid ray transformed and re-intersected with
its face's two planes; interpolation linear in (x, y), 6-point Lagrange in (u, v)). If
``L1w(Δ ρ) = L0(ρ)`` for the small ray motion ``Δ`` solved from Eq. 5, then
``M = Δ⁻¹ M_e`` exactly. Optionally (``symmetric``) both frames are warped
half-way with ``H = M_e^½``: ``L0w(ρ) = L0(H ρ)``, ``L1w(ρ) = L1(H⁻¹ ρ)`` and
``M = H Δ⁻¹ H``. This runs coarse to fine over a pyramid in (u, v) (and (x, y)
with ``pyramid_xy`` where there are enough viewpoints).

At the converged estimate the increment is zero, so the answer is set by how
well the warped frame matches, not by the derivative filters: linear
interpolation of a signal with k rad/sample shifts it by a relative error of
about k²/6, which made rotations come out ~10% too large; 4-point cubic
interpolation along (u, v) removes most of that (0.05% on a scene without
occlusions), 6-point also the ~1% left at 8-16 m where the directions are
nearly aliased.

Robust weighting
----------------
Per ray weight = confidence ``W`` (minimum over the filter support; 0 outside
the data) × validity (filter support inside the grid, warped sample inside the
grid) × a discontinuity weight × an IRLS weight. Silhouettes, creases and
aliased steps are where both the interpolation of the warp and the first-order
model fail, with errors that do not average out; the discontinuity weight
finds them from the data alone (large second derivatives in (u, v) near the
ray), so it is the same at every iteration of a level. The IRLS weight is
Tukey's biweight of the residual normalised by a robust scale (1.4826 ·
weighted MAD) that may grow but never shrinks within a pyramid level, so the
weights do not tighten as the warp converges. On the paper's sphere scene the two together bring the
bias of the translation from several percent to a few tenths of a percent
(benchmarks/bench_motion.py).

Diagnostics
-----------
Each pair yields a :class:`PairResult` with the 6x6 covariance of the rig
motion's ``(t, r)`` (``T_prev_next = [R_from_r(r) | t]``), the Jacobi-scaled
condition number, the inlier fraction, and the unobservable directions when
the normal matrix is (near-)singular (no texture, one viewpoint, ...). The
covariance is a cluster-robust sandwich over tiles of rays (residuals of
filtered derivatives are correlated over the filter support) around the
noise-corrected normal matrix ``AᵀWA − E`` (E = expected energy of sensor noise in
the derivatives, with the noise level estimated from second differences across
viewpoints); the textbook ``σ² (AᵀWA − E)⁻¹`` is kept as ``covariance_iid``.

Measured (benchmarks/bench_motion.py, paper Sect. 5 set-up: six faces, f = 60,
9 x 9 views 1 cm apart, 64 x 64 directions, 3 x 3 supersampling, |t| = 1.5 cm,
|ω| = 0.2°): median relative error per component 0.01–0.35% (t) and
0.02–0.12% (ω) at 4–8 m; 3–5% (t) and 0.4–0.6% (ω) at 12–16 m, where the
directions are aliased and the translation's signal is weak (the paper sees
the same growth); against 18–49% / 17–33% for one-shot central-difference
least squares. With 8-bit frames and 3 grey levels of noise at 8 m: 0.7% / 0.3%.

Limits: the covariance describes noise, not the systematic errors of aliased
or occluded data (it can be several times too small on
noise-free synthetic frames); under noise it matches the scatter of repeated
estimates to within about 1.5x (tests/test_motion.py). One face alone couples
t and ω (condition numbers of 10²–10³).

This module does no file I/O; :func:`estimate_trajectory` streams frames from
a light-field store (anything with ``grid``, ``timestamps_ns``, ``frame(i)``,
``weights(i)``).
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field, replace
from typing import Callable

import numba
import numpy as np

from .derivatives import FILTERS, Derivatives, correlate_axis, min_filter_axis, plenoptic_derivatives
from .errors import InputError
from .geometry import R_from_r, T_from_Rt, T_inverse, r_from_R, skew
from .lightfield import Axis, LightFieldGrid
from .trajectory import Trajectory

__all__ = [
    "PARAM_NAMES",
    "MotionOptions",
    "PairResult",
    "estimate_motion",
    "estimate_trajectory",
    "discontinuity_weight",
    "ray_motion_coefficients",
    "solve_ray_motion",
    "warp_lightfield",
    "warp_lightfield_reference",
]

log = logging.getLogger(__name__)

_TEXTURE_FLOOR = 1e-5
"""RMS intensity change per sample below which a light field has no usable texture."""

_SCALE_FLOOR = 1e-5
"""Smallest robust residual scale [intensity]: ~1/400 of an 8-bit level, far above float32 rounding."""

PARAM_NAMES = ("t_x", "t_y", "t_z", "w_x", "w_y", "w_z")
"""Order of the six motion parameters: translation [m] then rotation vector [rad]."""


# ============================================================================ options / result


@dataclass(frozen=True)
class MotionOptions:
    """Settings of the plenoptic motion solver (defaults are the tuned ones)."""

    filters: str | dict = field(default_factory=lambda: {"x": "fs3", "y": "fs3", "u": "fs5", "v": "fs5"})
    """Derivative filter pair name for all axes, or axis name (x y u v) → name (see FILTERS)."""
    levels: int = 3
    """Pyramid levels (1 = single scale)."""
    pyramid_xy: bool = False
    """Also halve the (x, y) sampling at coarse levels when there are enough viewpoints."""
    iterations: int = 4
    """Warp / re-solve iterations per level (the last level may stop early on convergence)."""
    irls_steps: int = 2
    """Re-weighted solves per iteration (0 = plain weighted least squares)."""
    robust: str = "tukey"
    """``tukey``, ``huber`` or ``none``: the IRLS loss on normalised residuals."""
    robust_c: float = 4.685
    """Loss constant in units of the robust residual scale (4.685 Tukey, 1.345 Huber)."""
    smooth_c: float = 0.5
    """Discontinuity weight ``1 / (1 + (e / (c · median e))²)``, e = the largest |∂²L/∂u²| +
    |∂²L/∂v²| within ``smooth_radius`` samples (0 disables): silhouettes, creases and
    aliased steps, where interpolation and linearisation fail, get little weight."""
    smooth_radius: int = 2
    """Half-width in (u, v) samples of the neighbourhood searched for discontinuities."""
    eiv: bool = False
    """Take each step with ``AᵀWA − E`` (E = expected sensor-noise energy in the derivatives):
    less bias under heavy noise where t and ω couple, but measured more scatter; off."""
    symmetric: bool = False
    """Warp both frames half-way (else frame 2 by the whole estimate; measured equally
    accurate with cubic interpolation, and half the warping cost)."""
    uv_taps: int = 6
    """Lagrange interpolation points along u and v in the warp: 2 (linear), 4 (cubic), 6
    (quintic; measured: rotation error at 8-16 m from ~1% with 4 to ~0.1-0.2%)."""
    rcond: float = 1e-7
    """Jacobi-scaled eigenvalue ratio below which a direction is unobservable."""
    min_rays: int = 64
    """Fewer usable rays than this is a failed estimate."""
    tol: float = 1e-7
    """Stop iterating when the increment is below this (|t| [m] + |ω| [rad])."""
    tile: int = 16
    """Largest (u, v) tile in samples for the cluster-robust covariance (smaller on small
    grids so that each face has about 8 x 8 tiles)."""

    def __post_init__(self) -> None:
        if self.robust not in ("tukey", "huber", "none"):
            raise ValueError(f"robust must be tukey, huber or none, got {self.robust!r}")
        if self.uv_taps not in (2, 4, 6):
            raise ValueError(f"uv_taps must be 2, 4 or 6, got {self.uv_taps}")
        if self.levels < 1 or self.iterations < 1 or self.irls_steps < 0:
            raise ValueError("levels and iterations must be >= 1, irls_steps >= 0")


@dataclass(frozen=True)
class PairResult:
    """Rig motion between frames ``index`` and ``index + 1`` with diagnostics.

    Falsy when the estimate failed (``reason`` says why, e.g. unobservable
    directions); ``T_prev_next`` is then the best estimate in the observable
    subspace (zero motion along the unobservable directions).
    """

    index: int
    """Frame index i of the pair (i, i+1)."""
    T_prev_next: np.ndarray
    """(4, 4) ``T_rig[i]_rig[i+1]``: pose of frame i+1 in the rig frame of frame i."""
    covariance: np.ndarray
    """(6, 6) covariance of (t [m], r [rad]) of ``T_prev_next`` (cluster-robust sandwich)."""
    covariance_iid: np.ndarray
    """(6, 6) ``σ² (AᵀWA)⁻¹`` mapped like ``covariance`` (assumes independent residuals)."""
    sigma: float
    """Robust residual scale [intensity per frame] at the final solve."""
    condition: float
    """Condition number of the Jacobi-scaled normal matrix (inf when singular)."""
    inlier_fraction: float
    """Fraction of usable rays with IRLS weight > 0.5 at the final solve."""
    num_rays: int
    """Rays with a positive weight at the final solve."""
    iterations: int
    """Total linear solves (over all levels)."""
    unobservable: tuple[str, ...] = ()
    """Names of (near-)unobservable directions, e.g. ``("t_x", "t_y", "t_z")``."""
    unobservable_directions: np.ndarray = field(default_factory=lambda: np.zeros((0, 6)))
    """(k, 6) unit vectors (scaled parameter space) spanning the unobservable subspace."""
    reason: str = ""
    """Why the estimate failed; empty when it succeeded."""

    @property
    def ok(self) -> bool:
        return not self.reason

    def __bool__(self) -> bool:
        return self.ok

    @property
    def t(self) -> np.ndarray:
        """(3,) [m] translation of ``T_prev_next``."""
        return self.T_prev_next[:3, 3]

    @property
    def r(self) -> np.ndarray:
        """(3,) [rad] rotation vector of ``T_prev_next``."""
        return r_from_R(self.T_prev_next[:3, :3])

    @property
    def std(self) -> np.ndarray:
        """(6,) standard deviations of (t, r) from ``covariance``."""
        return np.sqrt(np.clip(np.diag(self.covariance), 0.0, None))


# ============================================================================ numba kernels


@numba.njit(cache=True, inline="always")
def _lagrange(a, n, w):
    """n-point Lagrange weights for samples at 1 - n/2, ..., n/2 and fraction a ∈ [0, 1]
    (n = 2: linear, 4: cubic, 6: quintic)."""
    o = n // 2 - 1
    for q in range(n):
        pq = q - o
        acc = 1.0
        for m in range(n):
            if m != q:
                pm = m - o
                acc *= (a - pm) / (pq - pm)
        w[q] = acc


@numba.njit(parallel=True, cache=True)
def _warp_kernel(src, xs, ys, us, vs, R, tr, z_pi, f, uv_taps, out, ok):
    """Resample ``src`` (K, Ny, Nx, Nv, Nu) of one face at the grid rays moved by (R, tr).

    The ray (x, y, u, v) → origin ``R (x, y, z_pi) + tr``, direction ``R (u, v, f)``,
    re-intersected with the face's two planes. Interpolation is linear in (x, y)
    and ``uv_taps``-point Lagrange in (u, v) (2 = linear, which biases sub-sample
    shifts by ~k²/6 for k rad/sample; 4 = cubic; 6 = quintic), fewer on short axes.
    ``ok`` (Ny, Nx, Nv, Nu) is False where the moved ray leaves the grid.
    """
    K, Ny, Nx, Nv, Nu = src.shape
    x0 = xs[0]
    y0 = ys[0]
    u0 = us[0]
    v0 = vs[0]
    hx = (xs[Nx - 1] - x0) / (Nx - 1) if Nx > 1 else 1.0
    hy = (ys[Ny - 1] - y0) / (Ny - 1) if Ny > 1 else 1.0
    hu = (us[Nu - 1] - u0) / (Nu - 1) if Nu > 1 else 1.0
    hv = (vs[Nv - 1] - v0) / (Nv - 1) if Nv > 1 else 1.0
    eps = 1e-6
    nu_t = min(uv_taps, Nu - Nu % 2) if Nu > 1 else 1
    nv_t = min(uv_taps, Nv - Nv % 2) if Nv > 1 else 1
    nu_t = max(nu_t, 1)
    nv_t = max(nv_t, 1)
    for jy in numba.prange(Ny):
        wu = np.empty(8)
        wv = np.empty(8)
        iu_idx = np.empty(8, np.int64)
        iv_idx = np.empty(8, np.int64)
        for ix in range(Nx):
            ox = xs[ix]
            oy = ys[jy]
            px = R[0, 0] * ox + R[0, 1] * oy + R[0, 2] * z_pi + tr[0]
            py = R[1, 0] * ox + R[1, 1] * oy + R[1, 2] * z_pi + tr[1]
            pz = R[2, 0] * ox + R[2, 1] * oy + R[2, 2] * z_pi + tr[2]
            for jv in range(Nv):
                v = vs[jv]
                for iu in range(Nu):
                    u = us[iu]
                    dx = R[0, 0] * u + R[0, 1] * v + R[0, 2] * f
                    dy = R[1, 0] * u + R[1, 1] * v + R[1, 2] * f
                    dz = R[2, 0] * u + R[2, 1] * v + R[2, 2] * f
                    good = dz > 1e-9 * f
                    fx = fy = fu = fv = 0.0
                    if good:
                        s = (z_pi - pz) / dz
                        if Nx > 1:
                            fx = (px + s * dx - x0) / hx
                        if Ny > 1:
                            fy = (py + s * dy - y0) / hy
                        if Nu > 1:
                            fu = (f * dx / dz - u0) / hu
                        if Nv > 1:
                            fv = (f * dy / dz - v0) / hv
                        good = (fx > -eps and fx < Nx - 1 + eps and fy > -eps and fy < Ny - 1 + eps
                                and fu > -eps and fu < Nu - 1 + eps and fv > -eps and fv < Nv - 1 + eps)
                    if not good:
                        ok[jy, ix, jv, iu] = False
                        for k in range(K):
                            out[k, jy, ix, jv, iu] = 0.0
                        continue
                    ok[jy, ix, jv, iu] = True
                    bx = min(max(int(math.floor(fx)), 0), max(Nx - 2, 0))
                    by = min(max(int(math.floor(fy)), 0), max(Ny - 2, 0))
                    bu = min(max(int(math.floor(fu)), 0), max(Nu - 2, 0))
                    bv = min(max(int(math.floor(fv)), 0), max(Nv - 2, 0))
                    ax = min(max(fx - bx, 0.0), 1.0)
                    ay = min(max(fy - by, 0.0), 1.0)
                    au = min(max(fu - bu, 0.0), 1.0)
                    av = min(max(fv - bv, 0.0), 1.0)
                    sx = 1 if Nx > 1 else 0
                    sy = 1 if Ny > 1 else 0
                    # (u, v) stencils of nu_t x nv_t taps, indices clamped at the borders
                    if nu_t > 1:
                        _lagrange(au, nu_t, wu)
                    else:
                        wu[0] = 1.0
                    for q in range(nu_t):
                        iu_idx[q] = min(max(bu - (nu_t // 2 - 1) + q, 0), Nu - 1)
                    if nv_t > 1:
                        _lagrange(av, nv_t, wv)
                    else:
                        wv[0] = 1.0
                    for q in range(nv_t):
                        iv_idx[q] = min(max(bv - (nv_t // 2 - 1) + q, 0), Nv - 1)
                    for k in range(K):
                        acc = 0.0
                        for cy in range(2):
                            wy = ay if cy else 1.0 - ay
                            if wy == 0.0:
                                continue
                            yy = by + cy * sy
                            for cx in range(2):
                                wx = ax if cx else 1.0 - ax
                                if wx == 0.0:
                                    continue
                                xx = bx + cx * sx
                                wyx = wy * wx
                                for qv in range(nv_t):
                                    row = 0.0
                                    vv = iv_idx[qv]
                                    for qu in range(nu_t):
                                        row += wu[qu] * src[k, yy, xx, vv, iu_idx[qu]]
                                    acc += wyx * wv[qv] * row
                        out[k, jy, ix, jv, iu] = acc


@numba.njit(parallel=True, cache=True)
def _normal_kernel(Lx, Ly, Lu, Lv, Lt, w, xs, ys, us, vs, z_pi, f, acc):
    """Per (y, x, v) row: sums of w c cᵀ (21 unique), w c b (6), w b², w into acc (rows, 29).

    c = the Eq. 5 coefficients of (t, ω) in face coordinates, b = −L_t.
    """
    Ny, Nx, Nv, Nu = Lx.shape
    inv_f = 1.0 / f
    for row in numba.prange(Ny * Nx * Nv):
        jy = row // (Nx * Nv)
        rem = row - jy * Nx * Nv
        ix = rem // Nv
        jv = rem - ix * Nv
        x = xs[ix]
        y = ys[jy]
        v = vs[jv]
        n00 = n01 = n02 = n03 = n04 = n05 = 0.0
        n11 = n12 = n13 = n14 = n15 = 0.0
        n22 = n23 = n24 = n25 = 0.0
        n33 = n34 = n35 = 0.0
        n44 = n45 = 0.0
        n55 = 0.0
        r0 = r1 = r2 = r3 = r4 = r5 = 0.0
        sbb = 0.0
        sw = 0.0
        for iu in range(Nu):
            wi = w[jy, ix, jv, iu]
            if wi <= 0.0:
                continue
            u = us[iu]
            gx = Lx[jy, ix, jv, iu]
            gy = Ly[jy, ix, jv, iu]
            gu = Lu[jy, ix, jv, iu]
            gv = Lv[jy, ix, jv, iu]
            b = -Lt[jy, ix, jv, iu]
            c0 = gx
            c1 = gy
            c2 = -(u * gx + v * gy) * inv_f
            c3 = -(u * y * inv_f) * gx - (v * y * inv_f + z_pi) * gy - (u * v * inv_f) * gu \
                - (v * v * inv_f + f) * gv
            c4 = (u * x * inv_f + z_pi) * gx + (v * x * inv_f) * gy + (u * u * inv_f + f) * gu \
                + (u * v * inv_f) * gv
            c5 = -y * gx + x * gy - v * gu + u * gv
            w0 = wi * c0
            w1 = wi * c1
            w2 = wi * c2
            w3 = wi * c3
            w4 = wi * c4
            w5 = wi * c5
            n00 += w0 * c0
            n01 += w0 * c1
            n02 += w0 * c2
            n03 += w0 * c3
            n04 += w0 * c4
            n05 += w0 * c5
            n11 += w1 * c1
            n12 += w1 * c2
            n13 += w1 * c3
            n14 += w1 * c4
            n15 += w1 * c5
            n22 += w2 * c2
            n23 += w2 * c3
            n24 += w2 * c4
            n25 += w2 * c5
            n33 += w3 * c3
            n34 += w3 * c4
            n35 += w3 * c5
            n44 += w4 * c4
            n45 += w4 * c5
            n55 += w5 * c5
            r0 += w0 * b
            r1 += w1 * b
            r2 += w2 * b
            r3 += w3 * b
            r4 += w4 * b
            r5 += w5 * b
            sbb += wi * b * b
            sw += wi
        a = acc[row]
        a[0] = n00
        a[1] = n01
        a[2] = n02
        a[3] = n03
        a[4] = n04
        a[5] = n05
        a[6] = n11
        a[7] = n12
        a[8] = n13
        a[9] = n14
        a[10] = n15
        a[11] = n22
        a[12] = n23
        a[13] = n24
        a[14] = n25
        a[15] = n33
        a[16] = n34
        a[17] = n35
        a[18] = n44
        a[19] = n45
        a[20] = n55
        a[21] = r0
        a[22] = r1
        a[23] = r2
        a[24] = r3
        a[25] = r4
        a[26] = r5
        a[27] = sbb
        a[28] = sw


@numba.njit(parallel=True, cache=True)
def _residual_kernel(Lx, Ly, Lu, Lv, Lt, xs, ys, us, vs, z_pi, f, p, out):
    """out = L_t + c · p: the Eq. 5 residual for face-frame parameters p (6,)."""
    Ny, Nx, Nv, Nu = Lx.shape
    inv_f = 1.0 / f
    tx, ty, tz, wx, wy, wz = p[0], p[1], p[2], p[3], p[4], p[5]
    for row in numba.prange(Ny * Nx * Nv):
        jy = row // (Nx * Nv)
        rem = row - jy * Nx * Nv
        ix = rem // Nv
        jv = rem - ix * Nv
        x = xs[ix]
        y = ys[jy]
        v = vs[jv]
        # flow of this row: δx = ax0 + ax1 u, etc. (linear / quadratic in u)
        for iu in range(Nu):
            u = us[iu]
            dxp = tx - u * inv_f * tz - u * y * inv_f * wx + (u * x * inv_f + z_pi) * wy - y * wz
            dyp = ty - v * inv_f * tz - (v * y * inv_f + z_pi) * wx + v * x * inv_f * wy + x * wz
            dup = -u * v * inv_f * wx + (u * u * inv_f + f) * wy - v * wz
            dvp = -(v * v * inv_f + f) * wx + u * v * inv_f * wy + u * wz
            out[jy, ix, jv, iu] = (Lt[jy, ix, jv, iu] + Lx[jy, ix, jv, iu] * dxp
                                   + Ly[jy, ix, jv, iu] * dyp + Lu[jy, ix, jv, iu] * dup
                                   + Lv[jy, ix, jv, iu] * dvp)


@numba.njit(parallel=True, cache=True)
def _score_kernel(Lx, Ly, Lu, Lv, w, res, xs, ys, us, vs, z_pi, f, tile, out):
    """Per (y, x, v) row and u tile: sums of w c r (6) into out (Ny, Nx, Nv, n_tiles, 6)."""
    Ny, Nx, Nv, Nu = Lx.shape
    inv_f = 1.0 / f
    for row in numba.prange(Ny * Nx * Nv):
        jy = row // (Nx * Nv)
        rem = row - jy * Nx * Nv
        ix = rem // Nv
        jv = rem - ix * Nv
        x = xs[ix]
        y = ys[jy]
        v = vs[jv]
        for iu in range(Nu):
            wi = w[jy, ix, jv, iu]
            if wi <= 0.0:
                continue
            u = us[iu]
            gx = Lx[jy, ix, jv, iu]
            gy = Ly[jy, ix, jv, iu]
            gu = Lu[jy, ix, jv, iu]
            gv = Lv[jy, ix, jv, iu]
            s = wi * res[jy, ix, jv, iu]
            o = out[jy, ix, jv, iu // tile]
            o[0] += s * gx
            o[1] += s * gy
            o[2] += s * (-(u * gx + v * gy) * inv_f)
            o[3] += s * (-(u * y * inv_f) * gx - (v * y * inv_f + z_pi) * gy - (u * v * inv_f) * gu
                         - (v * v * inv_f + f) * gv)
            o[4] += s * ((u * x * inv_f + z_pi) * gx + (v * x * inv_f) * gy + (u * u * inv_f + f) * gu
                         + (u * v * inv_f) * gv)
            o[5] += s * (-y * gx + x * gy - v * gu + u * gv)


# ============================================================================ building blocks


def ray_motion_coefficients(der: Derivatives, grid: LightFieldGrid, k: int) -> np.ndarray:
    """The Eq. 5 coefficient rows of face ``k`` in *rig* coordinates, dims (Ny, Nx, Nv, Nu, 6).

    Row · (t, ω) of the ray motion G equals −L_t for an exact first-order model.
    Reference implementation (numpy, allocates); the solver uses fused kernels.
    """
    face = grid.faces[k]
    f, Z = face.f, face.z_pi
    y, x, v, u = np.meshgrid(grid.y.values, grid.x.values, grid.v.values, grid.u.values, indexing="ij")
    gx, gy, gu, gv = (np.asarray(a[k], float) for a in (der.Lx, der.Ly, der.Lu, der.Lv))
    c = np.stack([
        gx, gy, -(u * gx + v * gy) / f,
        -(u * y / f) * gx - (v * y / f + Z) * gy - (u * v / f) * gu - (v * v / f + f) * gv,
        (u * x / f + Z) * gx + (v * x / f) * gy + (u * u / f + f) * gu + (u * v / f) * gv,
        -y * gx + x * gy - v * gu + u * gv], axis=-1)
    R = np.asarray(face.R_rig_face, float)
    B = np.zeros((6, 6))
    B[:3, :3] = R.T
    B[3:, 3:] = R.T
    return c @ B


def solve_ray_motion(der: Derivatives, grid: LightFieldGrid, weights: np.ndarray | None = None,
                     rcond: float = 1e-7) -> tuple[np.ndarray, np.ndarray]:
    """One weighted linear solve of Eq. 5 over all faces (no warping, no IRLS).

    ``weights``: (F, Ny, Nx, Nv, Nu) or None (the derivatives' valid mask). Returns
    ``p`` (6,) = (t [m], ω [rad]) of the *ray* motion G in rig coordinates (the rig
    moved by ``G⁻¹``) and the normal matrix N (6, 6).
    """
    w = (np.broadcast_to(der.valid, der.Lx.shape) if weights is None else weights).astype(np.float32)
    vals = [np.ascontiguousarray(a.values, dtype=np.float64) for a in (grid.x, grid.y, grid.u, grid.v)]
    N = np.zeros((6, 6))
    rhs = np.zeros(6)
    for k, face in enumerate(grid.faces):
        Ny, Nx, Nv, Nu = der.Lx.shape[1:]
        acc = np.empty((Ny * Nx * Nv, 29))
        _normal_kernel(der.Lx[k], der.Ly[k], der.Lu[k], der.Lv[k], der.Lt[k], np.ascontiguousarray(w[k]),
                       *vals, float(face.z_pi), float(face.f), acc)
        Nk, rk, _, _ = _unpack_normal(acc.sum(axis=0))
        B = _face_B(face)
        N += B.T @ Nk @ B
        rhs += B.T @ rk
    return _solve_normal(N, rhs, rcond)["p"], N


def _uv_stencils(grid: LightFieldGrid, face, R: np.ndarray, taps: int):
    """Where each target direction (v, u) samples the source: the moved direction
    ``R (u, v, f)`` re-projected on the face's image plane depends on (u, v) only.

    Returns per-(v, u) Lagrange weights and clamped indices along v and u
    (``(Nv, Nu, T)`` float64 / int64 each) and ``ok_uv`` (Nv, Nu) bool.
    """
    f = float(face.f)
    v, u = np.meshgrid(grid.v.values, grid.u.values, indexing="ij")
    d = np.stack([u, v, np.full_like(u, f)], axis=-1) @ R.T
    ok = d[..., 2] > 1e-9 * f
    dz = np.where(ok, d[..., 2], 1.0)
    out = []
    eps = 1e-6
    for axis, comp in ((grid.v, 1), (grid.u, 0)):
        n = axis.count
        if n == 1:
            out += [np.ones(v.shape + (1,)), np.zeros(v.shape + (1,), np.int64)]
            continue
        fi = (f * d[..., comp] / dz - axis.min) / axis.step
        ok &= (fi > -eps) & (fi < n - 1 + eps)
        T = max(1, min(taps, n - n % 2))
        base = np.clip(np.floor(fi), 0, n - 2).astype(np.int64)
        a_ = np.clip(fi - base, 0.0, 1.0)
        o = T // 2 - 1
        w = np.empty(v.shape + (T,))
        for q in range(T):
            wq = np.ones_like(a_)
            for m in range(T):
                if m != q:
                    wq *= (a_ - (m - o)) / ((q - o) - (m - o))
            w[..., q] = wq
        idx = np.clip(base[..., None] - o + np.arange(T), 0, n - 1)
        out += [w, idx]
    wv, iv, wu, iu = out
    return (np.ascontiguousarray(wv), np.ascontiguousarray(iv), np.ascontiguousarray(wu),
            np.ascontiguousarray(iu), ok)


@numba.njit(parallel=True, cache=True)
def _warp_uv_kernel(src, wv, iv, wu, iu, out):
    """out[m, v, u] = Σ_q Σ_r wv[v, u, q] wu[v, u, r] src[m, iv[v, u, q], iu[v, u, r]] for
    every image m of src (M, Nv, Nu): the (u, v) part of the warp, shared by all views."""
    M, Nv, Nu = src.shape
    Tv = wv.shape[2]
    Tu = wu.shape[2]
    for m in numba.prange(M):
        img = src[m]
        o = out[m]
        for v in range(Nv):
            for u in range(Nu):
                acc = 0.0
                for q in range(Tv):
                    row = img[iv[v, u, q]]
                    sacc = 0.0
                    for r in range(Tu):
                        sacc += wu[v, u, r] * row[iu[v, u, r]]
                    acc += wv[v, u, q] * sacc
                o[v, u] = acc


@numba.njit(parallel=True, cache=True)
def _warp_xy_kernel(U, ok_uv, xs, ys, us, vs, R, tr, z_pi, f, out, ok):
    """Bilinear interpolation across viewpoints of the (u, v)-warped images U
    (K, Ny, Nx, Nv, Nu) at each moved ray's focal-plane point (x', y')."""
    K, Ny, Nx, Nv, Nu = U.shape
    x0 = xs[0]
    y0 = ys[0]
    hx = (xs[Nx - 1] - x0) / (Nx - 1) if Nx > 1 else 1.0
    hy = (ys[Ny - 1] - y0) / (Ny - 1) if Ny > 1 else 1.0
    eps = 1e-6
    for jy in numba.prange(Ny):
        for ix in range(Nx):
            ox = xs[ix]
            oy = ys[jy]
            px = R[0, 0] * ox + R[0, 1] * oy + R[0, 2] * z_pi + tr[0]
            py = R[1, 0] * ox + R[1, 1] * oy + R[1, 2] * z_pi + tr[1]
            pz = R[2, 0] * ox + R[2, 1] * oy + R[2, 2] * z_pi + tr[2]
            for jv in range(Nv):
                v = vs[jv]
                for iu in range(Nu):
                    good = ok_uv[jv, iu]
                    fx = 0.0
                    fy = 0.0
                    if good:
                        u = us[iu]
                        dx = R[0, 0] * u + R[0, 1] * v + R[0, 2] * f
                        dy = R[1, 0] * u + R[1, 1] * v + R[1, 2] * f
                        dz = R[2, 0] * u + R[2, 1] * v + R[2, 2] * f
                        s = (z_pi - pz) / dz
                        if Nx > 1:
                            fx = (px + s * dx - x0) / hx
                        if Ny > 1:
                            fy = (py + s * dy - y0) / hy
                        good = fx > -eps and fx < Nx - 1 + eps and fy > -eps and fy < Ny - 1 + eps
                    ok[jy, ix, jv, iu] = good
                    if not good:
                        for k in range(K):
                            out[k, jy, ix, jv, iu] = 0.0
                        continue
                    bx = min(max(int(math.floor(fx)), 0), max(Nx - 2, 0))
                    by = min(max(int(math.floor(fy)), 0), max(Ny - 2, 0))
                    ax = min(max(fx - bx, 0.0), 1.0)
                    ay = min(max(fy - by, 0.0), 1.0)
                    bx1 = bx + 1 if Nx > 1 else bx
                    by1 = by + 1 if Ny > 1 else by
                    w00 = (1.0 - ay) * (1.0 - ax)
                    w01 = (1.0 - ay) * ax
                    w10 = ay * (1.0 - ax)
                    w11 = ay * ax
                    for k in range(K):
                        out[k, jy, ix, jv, iu] = (w00 * U[k, by, bx, jv, iu] + w01 * U[k, by, bx1, jv, iu]
                                                  + w10 * U[k, by1, bx, jv, iu] + w11 * U[k, by1, bx1, jv, iu])


def warp_lightfield(arrays: np.ndarray, grid: LightFieldGrid, T_ray: np.ndarray, *,
                    uv_taps: int = 6) -> tuple[np.ndarray, np.ndarray]:
    """Resample light fields at the grid rays moved by the rigid transform ``T_ray`` (rig frame).

    ``arrays``: (K, F, Ny, Nx, Nv, Nu) stacked fields (e.g. L and W) sharing the
    warp. Returns ``out`` (same dims, float32) with ``out(ρ) = in(T_ray ρ)`` and
    ``ok`` (F, Ny, Nx, Nv, Nu) bool: the moved ray lies inside the grid. Interpolation
    is linear in (x, y) and ``uv_taps``-point Lagrange (2, 4 or 6) in (u, v). The
    moved direction, hence the (u, v) stencil, does not depend on the viewpoint, so
    every view image is first resampled in (u, v), then views are blended.
    """
    arrays = np.ascontiguousarray(arrays, dtype=np.float32)
    K, F, Ny, Nx, Nv, Nu = arrays.shape
    out = np.empty_like(arrays)
    ok = np.empty(arrays.shape[1:], bool)
    vals = [np.ascontiguousarray(a.values, dtype=np.float64) for a in (grid.x, grid.y, grid.u, grid.v)]
    U = np.empty((K, Ny, Nx, Nv, Nu), np.float32)
    o = np.empty_like(U)
    for k, face in enumerate(grid.faces):
        Rk = np.asarray(face.R_rig_face, float)
        Tk = T_from_Rt(Rk, np.zeros(3))
        G = T_inverse(Tk) @ T_ray @ Tk          # the ray motion in face coordinates
        R = np.ascontiguousarray(G[:3, :3])
        wv, iv, wu, iu, ok_uv = _uv_stencils(grid, face, R, int(uv_taps))
        src = np.ascontiguousarray(arrays[:, k])
        _warp_uv_kernel(src.reshape(K * Ny * Nx, Nv, Nu), wv, iv, wu, iu, U.reshape(K * Ny * Nx, Nv, Nu))
        _warp_xy_kernel(U, ok_uv, *vals, R, np.ascontiguousarray(G[:3, 3]), float(face.z_pi),
                        float(face.f), o, ok[k])
        out[:, k] = o
    return out, ok


def warp_lightfield_reference(arrays: np.ndarray, grid: LightFieldGrid, T_ray: np.ndarray, *,
                              uv_taps: int = 6) -> tuple[np.ndarray, np.ndarray]:
    """:func:`warp_lightfield` with all 4 x uv_taps² taps per ray in one kernel (reference)."""
    arrays = np.ascontiguousarray(arrays, dtype=np.float32)
    out = np.empty_like(arrays)
    ok = np.empty(arrays.shape[1:], bool)
    vals = [np.ascontiguousarray(a.values, dtype=np.float64) for a in (grid.x, grid.y, grid.u, grid.v)]
    for k, face in enumerate(grid.faces):
        Rk = np.asarray(face.R_rig_face, float)
        Tk = T_from_Rt(Rk, np.zeros(3))
        G = T_inverse(Tk) @ T_ray @ Tk
        src = np.ascontiguousarray(arrays[:, k])
        o = np.empty_like(src)
        _warp_kernel(src, *vals, np.ascontiguousarray(G[:3, :3]), np.ascontiguousarray(G[:3, 3]),
                     float(face.z_pi), float(face.f), int(uv_taps), o, ok[k])
        out[:, k] = o
    return out, ok


def _T_sqrt(T: np.ndarray) -> np.ndarray:
    """H with H @ H = T for a rigid transform T (4, 4) (rotation angle < π)."""
    r = r_from_R(T[:3, :3])
    Rh = R_from_r(0.5 * r)
    th = np.linalg.solve(Rh + np.eye(3), T[:3, 3])
    return T_from_Rt(Rh, th)


def _adjoint(T: np.ndarray) -> np.ndarray:
    """(6, 6) adjoint of T acting on twists ordered (v, ω)."""
    R, p = T[:3, :3], T[:3, 3]
    A = np.zeros((6, 6))
    A[:3, :3] = R
    A[:3, 3:] = skew(p) @ R
    A[3:, 3:] = R
    return A


def _face_B(face) -> np.ndarray:
    """(6, 6) map from rig-frame (t, ω) to face-frame (t, ω)."""
    R = np.asarray(face.R_rig_face, float)
    B = np.zeros((6, 6))
    B[:3, :3] = R.T
    B[3:, 3:] = R.T
    return B


def _unpack_normal(s: np.ndarray) -> tuple[np.ndarray, np.ndarray, float, float]:
    """(29,) sums → N (6, 6), rhs (6,), Σ w b², Σ w."""
    N = np.zeros((6, 6))
    iu = np.triu_indices(6)
    N[iu] = s[:21]
    N = N + np.triu(N, 1).T
    return N, s[21:27].copy(), float(s[27]), float(s[28])


def _downsample(a: np.ndarray, axes: tuple[int, ...]) -> np.ndarray:
    """Binomial [1 4 6 4 1]/16 smoothing then every second sample along ``axes`` of a (..., Ny, Nx, Nv, Nu) array."""
    taps = np.array([1, 4, 6, 4, 1], np.float32) / 16
    out = np.ascontiguousarray(a, dtype=np.float32)
    for ax in axes:
        out = correlate_axis(out, taps, ax)
        sl = [slice(None)] * out.ndim
        sl[ax] = slice(None, None, 2)
        out = np.ascontiguousarray(out[tuple(sl)])
    return out


def _half_axis(a: Axis) -> Axis:
    n = (a.count - 1) // 2 + 1
    return Axis(a.min, a.min + (n - 1) * 2 * a.step, n)


@dataclass
class _Level:
    grid: LightFieldGrid
    L0: np.ndarray      # (F, Ny, Nx, Nv, Nu) float32
    L1: np.ndarray
    W0: np.ndarray | None
    W1: np.ndarray | None


def _pyramid(L0, L1, W0, W1, grid: LightFieldGrid, opts: MotionOptions, pairs_radius: dict) -> list[_Level]:
    """Levels finest first. (u, v) are halved while ≥ 32 samples remain; (x, y) only with
    ``pyramid_xy`` and while the halved axis still leaves valid derivative samples."""
    levels = [_Level(grid, L0, L1, W0, W1)]
    for _ in range(opts.levels - 1):
        g = levels[-1].grid
        axes, kw = [], {}
        for name, ax_idx in (("v", 3), ("u", 4)):
            a = getattr(g, name)
            if a.count >= 32:
                axes.append(ax_idx)
                kw[name] = _half_axis(a)
        if opts.pyramid_xy:
            for name, ax_idx in (("y", 1), ("x", 2)):
                a = getattr(g, name)
                if (a.count - 1) // 2 + 1 >= 2 * pairs_radius[name] + 3:
                    axes.append(ax_idx)
                    kw[name] = _half_axis(a)
        if not axes:
            break
        ng = replace(g, **kw)
        prev = levels[-1]
        def ds(a, axes=tuple(sorted(axes))):
            return None if a is None else _downsample(a, axes)

        levels.append(_Level(ng, ds(prev.L0), ds(prev.L1), ds(prev.W0), ds(prev.W1)))
    return levels


def _min_filter_support(c: np.ndarray, radius: dict) -> np.ndarray:
    """Separable minimum of c (F, Ny, Nx, Nv, Nu) over ±radius per axis (y x v u)."""
    out = c
    for name, ax in (("y", 1), ("x", 2), ("v", 3), ("u", 4)):
        r = radius[name]
        if r > 0 and out.shape[ax] > 1:
            out = min_filter_axis(out, r, ax)
    return out


def _robust_weights(res: np.ndarray, scale: float, kind: str, c: float) -> np.ndarray:
    """IRLS weights ψ(z)/z for z = res/scale."""
    if kind == "none" or not scale > 0:
        return np.ones_like(res)
    z = np.abs(res) / np.float32(scale * c)
    if kind == "huber":
        return np.where(z <= 1.0, 1.0, 1.0 / np.maximum(z, 1e-12)).astype(np.float32)
    return np.where(z < 1.0, (1.0 - z * z) ** 2, 0.0).astype(np.float32)


def _weighted_mad(res: np.ndarray, w: np.ndarray, max_samples: int = 50_000) -> float:
    """1.4826 × weighted median of |res| over w > 0 (on a regular subsample of at most
    ``max_samples`` rays: the scale needs no more precision)."""
    m = (w > 0).reshape(-1)
    a = res.reshape(-1)[m]
    ww = w.reshape(-1)[m]
    if a.size == 0:
        return 0.0
    step = max(1, a.size // max_samples)
    a = np.abs(a[::step])
    ww = ww[::step]
    order = np.argsort(a)
    cw = np.cumsum(ww[order], dtype=np.float64)
    i = int(np.searchsorted(cw, 0.5 * cw[-1]))
    return 1.4826 * float(a[order[min(i, len(a) - 1)]])


def _noise_variance(lev: _Level) -> float:
    """Sensor-noise variance per sample, from the robust spread of second differences
    across viewpoints (the light field is smooth along x and y; the finest available
    axis is used): σ² = (1.4826 · median |Δ²L|)² / 6."""
    for ax in (2, 1, 4, 3):                             # x, y, then u, v
        if lev.L0.shape[ax] >= 3:
            break
    else:
        return 0.0
    vals = []
    for L, W in ((lev.L0, lev.W0), (lev.L1, lev.W1)):
        d2 = correlate_axis(L, np.array([1.0, -2.0, 1.0], np.float32), ax)
        sl = [slice(None)] * 5
        sl[ax] = slice(1, -1)
        d2 = d2[tuple(sl)]
        if W is not None:
            d2 = d2[(W[tuple(sl)] > 0)]
        v = np.abs(d2.reshape(-1))
        vals.append(v[:: max(1, v.size // 200_000)])
    v = np.concatenate(vals)
    if v.size == 0:
        return 0.0
    return float((1.4826 * np.median(v)) ** 2 / 6.0)


def discontinuity_weight(S: np.ndarray, opts: MotionOptions) -> np.ndarray:
    """(F, Ny, Nx, Nv, Nu) weights in (0, 1] of a light field S of the same dims: small near
    intensity discontinuities.

    e = |∂²S/∂u²| + |∂²S/∂v²|, maximised over ±``smooth_radius`` samples in (u, v);
    w = 1 / (1 + (e / (smooth_c · median e))²). The solver applies it to the mean of a
    frame pair; it depends on the data only (not on the motion), so it is the same in
    every iteration of a level. Public so the design study predicts with the same weights.
    """
    from scipy.ndimage import maximum_filter

    lap = np.array([1.0, -2.0, 1.0], np.float32)
    e = np.zeros_like(S)
    for ax in (3, 4):
        if S.shape[ax] >= 3:
            e += np.abs(correlate_axis(S, lap, ax))
    r = int(opts.smooth_radius)
    if r > 0:
        e = maximum_filter(e, size=(1, 1, 1, 2 * r + 1, 2 * r + 1), mode="nearest")
    sample = e.reshape(-1)[:: max(1, e.size // 200_000)]
    m = float(np.median(sample))
    if not m > 0:
        return np.ones_like(e)
    z = e / np.float32(opts.smooth_c * m)
    return (1.0 / (1.0 + z * z)).astype(np.float32)


def _level_discontinuity_weight(lev: _Level, opts: MotionOptions) -> np.ndarray:
    """:func:`discontinuity_weight` of a level's frame mean (where frame 1 has data)."""
    S = 0.5 * (lev.L0 + lev.L1)
    if lev.W0 is not None:
        S = S * (lev.W0 > 0)
    return discontinuity_weight(S, opts)


# ============================================================================ the solver


class _Solver:
    """One pyramid level: warp, derivatives, weights and (re-)weighted solves."""

    def __init__(self, lev: _Level, opts: MotionOptions, filters: dict):
        self.lev = lev
        self.g = lev.grid
        self.opts = opts
        self.filters = filters
        self.vals = [np.ascontiguousarray(a.values, dtype=np.float64)
                     for a in (self.g.x, self.g.y, self.g.u, self.g.v)]
        self.radius = {k: (fp.radius if getattr(self.g, k).count >= 2 * fp.radius + 1 else 0)
                       for k, fp in filters.items()}
        self.scale: float | None = None
        self.smooth = _level_discontinuity_weight(lev, opts) if opts.smooth_c > 0 else None
        self.noise_var: float | None = None

    def prepare(self, M: np.ndarray) -> None:
        """Warp both frames by the estimate M and compute derivatives and base weights."""
        lev, opts = self.lev, self.opts
        H = _T_sqrt(M) if opts.symmetric else np.eye(4)
        H1 = T_inverse(H) if opts.symmetric else T_inverse(M)
        # channels: L, W and the "no data" indicator (W <= 0), which must not be
        # interpolated into usable samples (any stencil tap on it → unusable)
        stack0 = [lev.L0] + ([lev.W0, (lev.W0 <= 0)] if lev.W0 is not None else [])
        stack1 = [lev.L1] + ([lev.W1, (lev.W1 <= 0)] if lev.W1 is not None else [])
        if opts.symmetric:
            w0, ok0 = warp_lightfield(np.stack(stack0), self.g, H, uv_taps=opts.uv_taps)
        else:
            w0, ok0 = np.stack(stack0).astype(np.float32), np.ones(lev.L0.shape, bool)
        w1, ok1 = warp_lightfield(np.stack(stack1), self.g, H1, uv_taps=opts.uv_taps)
        conf = (ok0 & ok1).astype(np.float32)
        for ww in (w0, w1):
            if len(ww) > 1:
                conf *= np.clip(ww[1], 0, 1) * (np.abs(ww[2]) < 1e-6)
        der = plenoptic_derivatives(w0[0], w1[0], self.g, filters={k: v.name for k, v in self.filters.items()},
                                    out=getattr(self, "der", None))
        if not (lev.W0 is None and lev.W1 is None and conf.min() > 0):
            conf = _min_filter_support(conf, self.radius)
        base = conf * der.valid[None].astype(np.float32)
        if self.smooth is not None:
            base *= self.smooth
        self.der = der
        self.base = base

    def normal(self, w: np.ndarray):
        """Rig-frame N (6, 6), rhs (6,), Σ w b², Σ w for weights w (F, Ny, Nx, Nv, Nu)."""
        d = self.der
        N = np.zeros((6, 6))
        rhs = np.zeros(6)
        sbb = sw = 0.0
        for k, face in enumerate(self.g.faces):
            Ny, Nx, Nv, Nu = d.Lx.shape[1:]
            acc = np.empty((Ny * Nx * Nv, 29))
            _normal_kernel(d.Lx[k], d.Ly[k], d.Lu[k], d.Lv[k], d.Lt[k], w[k], *self.vals,
                           float(face.z_pi), float(face.f), acc)
            Nk, rk, bk, wk = _unpack_normal(acc.sum(axis=0))
            B = _face_B(face)
            N += B.T @ Nk @ B
            rhs += B.T @ rk
            sbb += bk
            sw += wk
        return N, rhs, sbb, sw

    def residuals(self, p_rig: np.ndarray) -> np.ndarray:
        d = self.der
        out = np.empty_like(d.Lt)
        for k, face in enumerate(self.g.faces):
            pk = _face_B(face) @ p_rig
            _residual_kernel(d.Lx[k], d.Ly[k], d.Lu[k], d.Lv[k], d.Lt[k], *self.vals,
                             float(face.z_pi), float(face.f), pk, out[k])
        return out

    def texture(self, w: np.ndarray) -> float:
        """Weighted RMS of the intensity change per sample, sqrt(Σ w |∇L · h|² / Σ w)."""
        d = self.der
        sw = float(np.sum(w, dtype=np.float64))
        if not sw > 0:
            return 0.0
        e = 0.0
        for arr, h in ((d.Lx, self.g.x.step), (d.Ly, self.g.y.step), (d.Lu, self.g.u.step),
                       (d.Lv, self.g.v.step)):
            e += float(np.sum(w * (arr * np.float32(h)) ** 2, dtype=np.float64))
        return math.sqrt(e / sw)

    def noise_energy(self, w: np.ndarray) -> np.ndarray:
        """(6, 6) rig-frame E = Σ w Mᵀ diag(var L_x, var L_y, var L_u, var L_v) M: the
        expected contribution of sensor noise to AᵀWA (M = the Eq. 5 ray matrices)."""
        if self.noise_var is None:
            self.noise_var = _noise_variance(self.lev)
        var_S = 0.5 * self.noise_var                    # noise of the frames' mean
        if not var_S > 0:
            return np.zeros((6, 6))
        shape = self.der.Lx.shape[1:]
        pn = {k: (float(np.sum(fp.prefilter ** 2)) if self.radius[k] > 0 else 1.0)
              for k, fp in self.filters.items()}
        step = {"x": self.g.x.step, "y": self.g.y.step, "u": self.g.u.step, "v": self.g.v.step}
        var = []
        for k in ("x", "y", "u", "v"):
            if self.radius[k] == 0 or not step[k] > 0:
                var.append(0.0)
                continue
            others = math.prod(pn[o] for o in "xyuv" if o != k)
            var.append(var_S * float(np.sum(self.filters[k].derivative ** 2)) * others / step[k] ** 2)
        # E is a smooth (polynomial) function of the ray coordinates weighted by w: sum it
        # over every s-th direction and scale up by the weight ratio (a covariance
        # correction needs no more precision; 16x cheaper on large grids)
        s = 4 if min(shape[2], shape[3]) >= 32 else 1
        xs, ys, us, vs = self.vals
        sub_vals = (xs, ys, np.ascontiguousarray(us[::s]), np.ascontiguousarray(vs[::s]))
        sub = (shape[0], shape[1], len(sub_vals[3]), len(sub_vals[2]))
        one = np.ones(sub, np.float32)
        zero = np.zeros(sub, np.float32)
        E = np.zeros((6, 6))
        for kf, face in enumerate(self.g.faces):
            wk = np.ascontiguousarray(w[kf][:, :, ::s, ::s])
            sw_sub = float(np.sum(wk, dtype=np.float64))
            if not sw_sub > 0:
                continue
            ratio = float(np.sum(w[kf], dtype=np.float64)) / sw_sub
            Ek = np.zeros((6, 6))
            for j in range(4):
                if var[j] == 0.0:
                    continue
                g = [zero, zero, zero, zero]
                g[j] = one
                acc = np.empty((sub[0] * sub[1] * sub[2], 29))
                _normal_kernel(*g, zero, wk, *sub_vals, float(face.z_pi), float(face.f), acc)
                Ek += var[j] * ratio * _unpack_normal(acc.sum(axis=0))[0]
            B = _face_B(face)
            E += B.T @ Ek @ B
        return E

    def scores(self, w: np.ndarray, res: np.ndarray) -> np.ndarray:
        """(n_blocks, 6) per-tile sums of w a r in rig coordinates (tiles of (u, v), whole (x, y))."""
        d = self.der
        Nuv = max(self.g.u.count, self.g.v.count)
        tile = max(1, min(int(self.opts.tile), max(4, -(-Nuv // 8))))   # >= ~8 x 8 tiles per face
        blocks = []
        for k, face in enumerate(self.g.faces):
            Ny, Nx, Nv, Nu = d.Lx.shape[1:]
            nt = (Nu + tile - 1) // tile
            out = np.zeros((Ny, Nx, Nv, nt, 6))
            _score_kernel(d.Lx[k], d.Ly[k], d.Lu[k], d.Lv[k], w[k], res[k], *self.vals,
                          float(face.z_pi), float(face.f), tile, out)
            s = out.sum(axis=(0, 1))                                   # (Nv, nt, 6)
            nv = (Nv + tile - 1) // tile
            pad = np.zeros((nv * tile, nt, 6))
            pad[:Nv] = s
            s = pad.reshape(nv, tile, nt, 6).sum(axis=1).reshape(-1, 6)
            blocks.append(s @ _face_B(face))
        return np.concatenate(blocks)

    def solve(self, final: bool) -> dict:
        """Weighted (IRLS) solve of the increment; returns a dict of the pieces."""
        opts = self.opts
        w = self.base
        N, rhs, sbb, sw = self.normal(w)
        sol = _solve_normal(N, rhs, opts.rcond)
        steps = opts.irls_steps if opts.robust != "none" else 0
        wr = None
        res = None
        for _ in range(steps):
            res = self.residuals(sol["p"])
            mad = max(_weighted_mad(res, self.base), _SCALE_FLOOR)
            # the scale may grow but never shrinks within a level: weights do not
            # tighten as the warp converges
            self.scale = mad if self.scale is None else max(self.scale, mad)
            wr = _robust_weights(res, self.scale, opts.robust, opts.robust_c)
            w = self.base * wr
            N, rhs, sbb, sw = self.normal(w)
            sol = _solve_normal(N, rhs, opts.rcond)
        E = self.noise_energy(w)
        if opts.eiv and np.any(E):
            # step with the noise-free sensitivity N − E (errors in variables): with
            # noisy derivatives N alone under-steps (badly so where t and ω couple)
            sol["p"] = _corrected_pinv(N, E, sol) @ rhs
        sol.update(N=N, E=E, w=w, wr=wr, sw=sw)
        if final:
            res = self.residuals(sol["p"])
            sol["res"] = res
        return sol


def _solve_normal(N: np.ndarray, rhs: np.ndarray, rcond: float) -> dict:
    """Solve N p = rhs with Jacobi scaling; directions with tiny scaled eigenvalues are dropped."""
    d = np.diag(N).copy()
    dmax = float(d.max()) if d.size else 0.0
    live = d > max(dmax, 1e-300) * 1e-14
    s = np.where(live, 1.0 / np.sqrt(np.where(live, d, 1.0)), 0.0)
    Ns = N * s[:, None] * s[None, :]
    evals, evecs = np.linalg.eigh(Ns)
    lmax = float(evals.max()) if evals.size else 0.0
    good = evals > rcond * lmax if lmax > 0 else np.zeros(6, bool)
    # dead columns give zero eigenvalues whose eigenvectors are axis vectors: unobservable
    inv = np.zeros(6)
    inv[good] = 1.0 / evals[good]
    Ns_pinv = (evecs * inv) @ evecs.T
    N_pinv = Ns_pinv * s[:, None] * s[None, :]
    p = N_pinv @ rhs
    bad_dirs = evecs[:, ~good].T
    cond = float(lmax / evals[good].min()) if good.all() and lmax > 0 else math.inf
    return {"p": p, "N_pinv": N_pinv, "unobs": bad_dirs, "cond": cond}


def _name_direction(vec: np.ndarray) -> str:
    """'t_x' for an axis-aligned unit vector, else a short linear combination."""
    a = np.abs(vec)
    i = int(np.argmax(a))
    if a[i] > 0.95:
        return PARAM_NAMES[i]
    terms = [f"{vec[j]:+.2f} {PARAM_NAMES[j]}" for j in np.argsort(-a) if a[j] > 0.1]
    return "(" + " ".join(terms) + ")"


def _check_frame(name: str, L: np.ndarray, grid: LightFieldGrid, W: np.ndarray | None = None) -> np.ndarray:
    """(F, Ny, Nx, Nv, Nu) float32 copy of a frame (colour averaged). Non-finite samples
    are an error unless the confidence ``W`` is 0 there (they are then set to 0)."""
    L = np.asarray(L)
    if L.ndim == 6 and L.shape[:5] == grid.shape:        # colour: average the channels
        L = L.mean(axis=-1)
    if L.shape != grid.shape:
        raise InputError(f"motion: {name} has dims {L.shape}, but the grid is {grid.shape} "
                         "(F, Ny, Nx, Nv, Nu)")
    L = np.array(L, dtype=np.float32, order="C")
    bad = ~np.isfinite(L)
    if np.any(bad):
        if W is None or np.any(bad & (W > 0)):
            raise InputError(f"motion: {name} contains NaN or infinite samples where the "
                             "confidence W is not 0; mask them with W = 0")
        L[bad] = 0.0
    return L


def estimate_motion(L0: np.ndarray, L1: np.ndarray, grid: LightFieldGrid, *,
                    W0: np.ndarray | None = None, W1: np.ndarray | None = None,
                    T_init: np.ndarray | None = None, options: MotionOptions | None = None,
                    index: int = 0) -> PairResult:
    """Rig motion ``T_rig0_rig1`` between light-field frames ``L0`` and ``L1``.

    ``L0``, ``L1``: (F, Ny, Nx, Nv, Nu) intensities on ``grid`` (a trailing colour
    axis is averaged). ``W0``, ``W1``: optional confidences of the same dims in
    [0, 1]. ``T_init``: (4, 4) starting estimate of ``T_rig0_rig1`` (identity).
    Raises :class:`InputError` for unusable input (NaNs, mismatched dims).
    """
    opts = options or MotionOptions()
    W0 = None if W0 is None else _check_frame(f"weights of frame {index}", W0, grid)
    W1 = None if W1 is None else _check_frame(f"weights of frame {index + 1}", W1, grid)
    L0 = _check_frame(f"frame {index}", L0, grid, W0)
    L1 = _check_frame(f"frame {index + 1}", L1, grid, W1)
    fnames = opts.filters if isinstance(opts.filters, dict) else {k: opts.filters for k in "xyuv"}
    try:
        filters = {k: FILTERS[fnames.get(k, "fs5")] for k in "xyuv"}
    except KeyError as e:
        raise InputError(f"motion: unknown derivative filter {e.args[0]!r}; expected one of "
                         f"{sorted(FILTERS)}") from None
    M = np.eye(4) if T_init is None else np.asarray(T_init, float).copy()
    levels = _pyramid(L0, L1, W0, W1, grid, opts, {k: fp.radius for k, fp in filters.items()})
    n_solves = 0
    sol = None
    solver = None
    diag = None
    for li in range(len(levels) - 1, -1, -1):
        solver = _Solver(levels[li], opts, filters)
        finest = li == 0
        for it in range(opts.iterations):
            solver.prepare(M)
            sol = solver.solve(final=True)
            n_solves += 1
            p = sol["p"]
            if not np.all(np.isfinite(p)):        # cannot happen with finite input; be safe
                p = sol["p"] = np.zeros(6)
            H = _T_sqrt(M) if opts.symmetric else M
            D = T_from_Rt(R_from_r(p[3:]), p[:3])
            M = H @ T_inverse(D) @ H if opts.symmetric else T_inverse(D) @ M
            diag = (sol, _increment_covariance(sol, solver), H)
            if finest or it >= 1:
                # Stop once the increment is within the noise: re-warping noisy data
                # only makes the estimate wander (it re-samples the noise). Coarse
                # levels always take two steps.
                C = diag[1][0]
                chi2 = float(p @ np.linalg.pinv(C) @ p) if np.all(np.isfinite(C)) else math.inf
                if chi2 < _CHI2_STOP or np.linalg.norm(p[:3]) + np.linalg.norm(p[3:]) < opts.tol:
                    break
    return _result(index, M, diag, solver, opts, n_solves)


_CHI2_STOP = 12.6
"""95% quantile of χ² with 6 degrees of freedom: an increment below it is noise."""


def _increment_covariance(sol: dict, solver: _Solver) -> tuple[np.ndarray, np.ndarray, float]:
    """Covariances (6, 6) of the converged estimate: cluster-robust sandwich and
    ``σ² (AᵀWA)⁺``, and σ².

    Sensor noise in the derivatives inflates AᵀWA (errors in variables): the iteration
    converges where the noise's pull balances the *noise-free* sensitivity, which is
    AᵀWA minus the expected noise energy E. Both covariances use ``N − E`` (E shrunk
    if needed to keep it well inside positive definite); with one face, where t and ω
    couple, this is a factor of several for the translation.
    """
    w, res = sol["w"], sol["res"]
    sw = float(np.sum(w, dtype=np.float64))
    chi2 = float(np.sum(w.astype(np.float64) * res.astype(np.float64) ** 2))
    sigma2 = chi2 / max(sw - 6.0, 1.0)
    Np = _corrected_pinv(sol["N"], sol["E"], sol)
    S = solver.scores(w, res)
    G = S.shape[0]
    meat = S.T @ S * (G / max(G - 1, 1))
    return Np @ meat @ Np, sigma2 * Np, sigma2


def _corrected_pinv(N: np.ndarray, E: np.ndarray, sol: dict) -> np.ndarray:
    """Pseudo-inverse of N − αE on the observable subspace; α is the largest of 1, 1/2,
    1/4, ... keeping every (Jacobi-scaled) observable eigenvalue above 20% of N's smallest."""
    d = np.diag(N)
    live = d > max(float(d.max()), 1e-300) * 1e-14
    s = np.where(live, 1.0 / np.sqrt(np.where(live, d, 1.0)), 0.0)
    U = sol["unobs"]                                   # (k, 6) in scaled coordinates
    P = np.eye(6) - (U.T @ U if len(U) else 0.0)       # projector on the observable part
    Ns = P @ (N * s[:, None] * s[None, :]) @ P
    Es = P @ (E * s[:, None] * s[None, :]) @ P
    n_obs = 6 - len(U)
    if n_obs == 0:
        return sol["N_pinv"]
    floor = 0.2 * np.linalg.eigvalsh(Ns)[-n_obs:].min()
    alpha = 1.0
    for _ in range(12):
        ev, vec = np.linalg.eigh(Ns - alpha * Es)
        if ev[-n_obs:].min() >= floor:
            break
        alpha *= 0.5
    else:
        return sol["N_pinv"]
    inv = np.zeros(6)
    inv[-n_obs:] = 1.0 / ev[-n_obs:]
    return ((vec * inv) @ vec.T) * s[:, None] * s[None, :]


def _result(index, M, diag, solver: _Solver, opts: MotionOptions, n_solves: int) -> PairResult:
    sol, (C_sand, C_iid, sigma2), H = diag
    w = sol["w"]
    num = int(np.count_nonzero(w > 0))
    base_n = int(np.count_nonzero(solver.base > 0))
    wr = sol["wr"]
    inl = float(np.count_nonzero((wr > 0.5) & (solver.base > 0)) / base_n) if (wr is not None and base_n) \
        else (1.0 if base_n else 0.0)
    # map the increment covariance to the rig's (t, r): M = H exp(−δ) H = M · exp(Ad(H⁻¹)(−δ))
    # (one-sided warping: H = M_e, M = exp(−δ) M_e = M · exp(Ad(M⁻¹)(−δ)))
    J = np.zeros((6, 6))
    J[:3, :3] = M[:3, :3]
    J[3:, 3:] = np.eye(3)
    J = -J @ _adjoint(T_inverse(H) if opts.symmetric else T_inverse(M))
    cov = J @ C_sand @ J.T
    cov_iid = J @ C_iid @ J.T
    unobs_vecs = sol["unobs"]
    texture = solver.texture(w)
    if texture < _TEXTURE_FLOOR:
        unobs_vecs = np.eye(6)
    if len(unobs_vecs):
        # parameters touching the unobservable subspace get infinite variance
        # (J maps parameters one to one up to a rotation within t and within ω)
        touched = np.sum(unobs_vecs ** 2, axis=0) > 0.01
        touched = touched | np.concatenate([[touched[:3].any()] * 3, [touched[3:].any()] * 3])
        for C in (cov, cov_iid):
            C[touched, :] = 0.0
            C[:, touched] = 0.0
            C[touched, touched] = np.inf
    names = tuple(_name_direction(v) for v in unobs_vecs)
    reason = ""
    if num < opts.min_rays:
        reason = f"only {num} usable rays (need {opts.min_rays}): too little texture or valid data"
    elif texture < _TEXTURE_FLOOR:
        reason = (f"unobservable: no texture (RMS gradient {texture:.2g} per sample); "
                  "all of " + ", ".join(names))
    elif names:
        reason = "unobservable: " + ", ".join(names)
    elif not np.all(np.isfinite(M)):
        reason = "the solution diverged"
    if reason:
        log.warning("pair %d: %s", index, reason)
    return PairResult(index=index, T_prev_next=M, covariance=cov, covariance_iid=cov_iid,
                      sigma=math.sqrt(sigma2), condition=sol["cond"], inlier_fraction=inl,
                      num_rays=num, iterations=n_solves, unobservable=names,
                      unobservable_directions=unobs_vecs, reason=reason)


def estimate_trajectory(store, *, progress: Callable[[int, int], None] | None = None,
                        options: MotionOptions | None = None, constant_velocity: bool = True,
                        **option_overrides) -> tuple[Trajectory, list[PairResult]]:
    """Egomotion of every consecutive frame pair of a light-field store, integrated.

    ``store`` provides ``grid``, ``timestamps_ns`` (T,), ``frame(i)`` → (F, Ny, Nx, Nv, Nu)
    (optionally with a colour axis) and ``weights(i)`` → same dims or None. Frames are
    read one at a time (two in memory). ``progress(done, total)`` is called after each
    pair. ``constant_velocity`` starts each pair from the previous pair's estimate.
    Returns the trajectory (``T_world_rig``, world = rig at the first frame) and the
    per-pair results (falsy ones failed; their motion is still integrated).
    """
    opts = options or MotionOptions()
    if option_overrides:
        opts = replace(opts, **option_overrides)
    grid = store.grid
    ts = np.asarray(store.timestamps_ns, dtype=np.int64)
    n = int(ts.shape[0])
    if n < 2:
        raise InputError(f"motion: the light field has {n} frame(s); need at least 2")
    get_w = getattr(store, "weights", None)
    W_prev = get_w(0) if get_w else None
    L_prev = store.frame(0)
    results: list[PairResult] = []
    T_init = None
    for i in range(n - 1):
        L_next = store.frame(i + 1)
        W_next = get_w(i + 1) if get_w else None
        res = estimate_motion(L_prev, L_next, grid, W0=W_prev, W1=W_next, T_init=T_init,
                              options=opts, index=i)
        results.append(res)
        if constant_velocity and res.ok:
            T_init = res.T_prev_next
        L_prev, W_prev = L_next, W_next
        if progress is not None:
            progress(i + 1, n - 1)
    traj = Trajectory.from_relative(ts, np.stack([r.T_prev_next for r in results]))
    return traj, results
