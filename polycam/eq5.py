"""The rows of paper Eq. 5 and their normal sums: the fused ray loops of the motion solver.

Each ray of face k gives one row ``c · (t, ω) = −L_t`` of the linearised brightness
constancy constraint for the ray motion ``G`` (derivation and sign convention: the
docstring of :mod:`polycam.motion`; frames and units: docs/conventions.md). This module
holds

- the row coefficients (:func:`ray_motion_coefficients`, numpy reference; the inline numba
  ``_eq5_coefficients`` used by the kernels) and the rig → face map ``_face_B``;
- the numba kernels that form, per view image and (u, v) tile, the weighted normal sums
  ``Σ w c cᵀ``, ``Σ w c b``, ``Σ w b²``, ``Σ w`` together with the noise energy E of the
  derivatives and the IRLS statistics (``_prepare_kernel``, ``_pass_kernel``), plus the
  residual sampling and weighted median that give the robust scale;
- their drivers ``_accumulate`` / ``_reduce`` (per-face tile sums → rig-frame N, rhs);
- the depth-regularised regressors of paper Eq. 6 (``depth_regularise``, numpy reference;
  ``depth_rho``, the kernel the solver uses;
  :attr:`~polycam.motion_options.MotionOptions.depth_regressors`), with ρ̂ optionally pooled
  over the views (``_pool_rho`` on the solver's int16 ρ̂; the method and its numpy reference:
  :mod:`polycam.rho_pool`; :attr:`~polycam.motion_options.MotionOptions.depth_pool_views`).

Per-ray work arrays (derivatives, base weights, ρ̂) may hold only the views of the
valid box (the solver's: the views whose (x, y) filter support lies inside the grid; the
others would never be read). The kernels take their *view origin* ``vo`` (4,) int64
``[y0, x0, Ny, Nx]``: such an array's view (j − y0, i − x0) is view (j, i) of the Ny x Nx
grid; ``(0, 0, Ny, Nx)`` for arrays over every view (``_view_origin``). Every kernel counts
a base weight <= 0 as weight 0: the solver keeps the discontinuity weight in the magnitude
of negative base weights (``_prepare_kernel``'s smooth mode 2). The kernels take base
weights as float32 or, as the solver keeps them (weights in [−1, 1]: a confidence times
a discontinuity weight), as int16 in units of 1 / 32767 (``_weight_unit``, ``_store_weight``:
a weight > 0 keeps at least one unit), half the memory.

The solver stores its derivatives as int16 with one scale per view image and
derivative (*scaled views*): value = q × ``dsc[f, j, i, c]``, ``dsc`` (F, ny, nx, 5)
float32 over the same views, c = 0..4 for L_x, L_y, L_u, L_v, L_t, the scale =
max |value| over the view image's rays with base weight > 0, / 32767 (``_quantise_plane``;
the others are clipped: they are never used): half the memory of float32,
with a rounding error of at most 1.5e-5 of the view's largest value (docs/motion_log.md,
"Speed"). The kernels that read derivatives take such ``dsc``; float32 derivatives (the
public :func:`~polycam.motion.solve_ray_motion`, the tests' references) pass unit scales
(``_unit_scales``): the products are then exact. The solver keeps ρ̂ of the Eq. 6
regressors the same way, one scale per view image (:func:`depth_rho`).

The ray loops are branch-free with unsigned indices and re-associated sums
(``_FASTMATH``) so that LLVM vectorises them (speed figures: docs/motion.md).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numba
import numpy as np
from numba.extending import overload

from .derivatives import _FASTMATH, FILTERS, Derivatives, _filt_u, _filt_v, correlate_axis, parallel_chunks, xy_view
from .lightfield import LightFieldGrid
from .rho_pool import _CHI2_1_MEDIAN, pool_over_views

__all__ = ["ray_motion_coefficients", "depth_regularise", "depth_rho", "rho_values", "RegressorMix"]


_NACC = 29
"""Sums per (u, v) tile: the 21 unique entries of Σ w c cᵀ, Σ w c b (6), Σ w b², Σ w."""


_NSTAT = 25
"""Statistics per view image: rays with w > 0, rays with base weight > 0, IRLS inliers
(weight > 0.5), Σ w |∇L · h|², and the 21 unique entries of the noise energy E."""


_ROBUST_KIND = {"none": 0, "tukey": 1, "huber": 2}
"""The passes' ``kind`` of each ``MotionOptions.robust`` loss: the IRLS weight ψ(r) / r."""
_ROBUST_SLOPE = {1: 3, 2: 4}
"""The ``kind`` whose weight is the slope ψ'(r) of the loss ``kind`` (ψ(r) = r · its IRLS weight),
which the M-estimator's covariance takes where least squares takes the weight: Tukey's
(1 − z²)(1 − 5z²) for z < 1, Huber's 1 for z <= 1 (z = |r| / (s c)); 0 beyond."""


def _view_origin(Ny: int, Nx: int, box: np.ndarray | None = None) -> np.ndarray:
    """View origin ``vo`` (4,) int64 of work arrays over the views of ``box`` (8,) of an
    Ny x Nx view grid, or over every view (``box`` None); module docstring."""
    y0, x0 = (0, 0) if box is None else (int(box[0]), int(box[2]))
    return np.array([y0, x0, Ny, Nx], np.int64)


def _box_views(shape: tuple, box: np.ndarray) -> tuple:
    """Dims (F, ny, nx, Nv, Nu) of a work array over the views of ``box`` (8,) of a light
    field of dims ``shape`` (F, Ny, Nx, Nv, Nu)."""
    return (shape[0], max(int(box[1] - box[0]), 0), max(int(box[3] - box[2]), 0)) + tuple(shape[3:])


_QMAX = 32767.0
"""The largest stored magnitude of a scaled view (int16)."""


_WEIGHT_UNITS = _QMAX
"""int16 base weights hold w × this (module docstring)."""


def _weight_unit(w: np.ndarray) -> np.float32:
    """The weight one unit of base weights ``w`` stands for (float32): 1 / 32767 for int16
    (module docstring), 1 for float arrays."""
    return np.float32(1.0 / _WEIGHT_UNITS) if np.issubdtype(w.dtype, np.integer) else np.float32(1.0)


@overload(_weight_unit, inline="always")
def _weight_unit_typed(w):
    if isinstance(w.dtype, numba.types.Integer):
        return lambda w: np.float32(1.0 / _WEIGHT_UNITS)
    return lambda w: np.float32(1.0)


def _store_weight(w, idx, x):
    """w[idx] = x, a weight in [−1, 1] (numba): as it is into a float array; into an int16
    array in units of 1 / 32767, rounded to the nearest unit but at least one unit away
    from 0 when x is not 0 (the sign marks validity: every kernel counts a weight <= 0 as 0)."""
    w[idx] = x


@overload(_store_weight, inline="always")
def _store_weight_typed(w, idx, x):
    if isinstance(w.dtype, numba.types.Integer):
        def store_int(w, idx, x):
            y = np.float32(x) * np.float32(_WEIGHT_UNITS)
            q = np.rint(min(max(y, np.float32(-_WEIGHT_UNITS)), np.float32(_WEIGHT_UNITS)))
            one = np.float32(1.0)
            q = q if (q != 0) | (y == 0) else (one if y > 0 else -one)
            w[idx] = np.int16(q)
        return store_int

    def store(w, idx, x):
        w[idx] = x
    return store


_RHO_NONE = -32768
"""int16 ρ̂ (the solver's, :func:`depth_rho`): the measured regressors are kept (NaN in a
float32 ρ̂)."""


@numba.njit(cache=True, fastmath=_FASTMATH)
def _put_rho_view(a, q, v_lo, v_hi, u_lo, u_hi):
    """q (Nv, Nu) int16 ← ρ̂ a (Nv, Nu) float32, NaN where the measured regressors are kept,
    on the samples v_lo:v_hi x u_lo:u_hi (``_RHO_NONE`` elsewhere and for NaN): rounded to
    units of s = max |a| / 32767 over the numbers there, which it returns (float32; 0 when
    there are none)."""
    z = np.float32(0.0)
    n = numba.uint64(u_hi - u_lo)
    m = _abs_max_where(a, v_lo, v_hi, u_lo, u_hi, a, False)     # NaN compares false: skipped
    inv = np.float32(_QMAX) / m if m > z else z
    none = np.int16(_RHO_NONE)
    q[:, :] = none
    for v in range(v_lo, v_hi):
        r = a[v, u_lo:u_hi]
        o = q[v, u_lo:u_hi]
        for u in range(n):
            o[u] = np.int16(np.rint(r[u] * inv)) if r[u] == r[u] else none
    return m / np.float32(_QMAX)


def rho_window_taps() -> tuple[np.ndarray, np.ndarray]:
    """(t9, t3) float32: the taps of ρ̂'s window (:func:`depth_rho`), t9 = fs5 ∗ fs5 along v and u,
    t3 = fs3's prefilter across the views."""
    t5 = FILTERS["fs5"].prefilter
    return np.convolve(t5, t5).astype(np.float32), FILTERS["fs3"].prefilter.astype(np.float32)


def rho_values(rho: np.ndarray, scales: np.ndarray) -> np.ndarray:
    """float32 ρ̂ (NaN where the measured regressors are kept) of the solver's int16 ρ̂
    (F, ny, nx, Nv, Nu) with its scales (F, ny, nx) (:func:`depth_rho`)."""
    out = rho.astype(np.float32) * scales[..., None, None]
    out[rho == _RHO_NONE] = np.nan
    return out


def _rho_store(a: np.ndarray, rho: np.ndarray, scales: np.ndarray, box: np.ndarray) -> None:
    """rho (int16), scales ← float32 ρ̂ a (same dims, NaN: kept) per view image, quantised on
    the (v, u) samples of box (8,) (:func:`_put_rho_view`)."""
    a = np.ascontiguousarray(a, np.float32).reshape((-1,) + a.shape[3:])
    q = rho.reshape((-1,) + rho.shape[3:])
    sc = scales.reshape(-1)
    for k in range(a.shape[0]):
        sc[k] = _put_rho_view(a[k], q[k], box[4], box[5], box[6], box[7])


@numba.njit(parallel=True, cache=True)
def _store_weights(x, w):
    """w ← x (both (n, ...), same dims) by :func:`_store_weight`: float weights into base
    weights of w's type."""
    for k in numba.prange(x.shape[0]):
        a = x[k].reshape(-1)
        o = w[k].reshape(-1)
        for m in range(a.size):
            _store_weight(o, m, a[m])


def _unit_scales(shape: tuple) -> np.ndarray:
    """Scales (F, ny, nx, 5) float32 of 1 for float32 derivatives of dims ``shape`` (F, ny, nx, Nv,
    Nu): the kernels then read the values as they are (module docstring)."""
    return np.ones(tuple(shape[:3]) + (5,), np.float32)


@numba.njit(cache=True, fastmath=_FASTMATH)
def _abs_max_where(a, v_lo, v_hi, u_lo, u_hi, w, has_w):
    """max |a| (float32) over the samples v_lo:v_hi x u_lo:u_hi of a (Nv, Nu) float32; with
    ``has_w`` over those whose w (a's dims either way) is > 0 only."""
    z = np.float32(0.0)
    n = numba.uint64(u_hi - u_lo)
    # column-wise maxima first: a running max over one loop does not vectorise (~7x slower)
    cmax = np.zeros(u_hi - u_lo, np.float32)
    for v in range(v_lo, v_hi):
        r = a[v, u_lo:u_hi]
        wr = w[v if has_w else 0, u_lo:u_hi]                 # (unread without has_w)
        for u in range(n):
            x = abs(r[u]) if (not has_w) or wr[u] > z else z
            cmax[u] = x if x > cmax[u] else cmax[u]
    m = z
    for u in range(n):
        m = max(m, cmax[u])
    return m


@numba.njit(cache=True, fastmath=_FASTMATH)
def _quantise_plane(a, q, v_lo, v_hi, u_lo, u_hi, w, has_w):
    """q (Nv, Nu) int16 ← a (Nv, Nu) float32 / s rounded to the nearest integer on the samples
    v_lo:v_hi x u_lo:u_hi (0 elsewhere: never read), with the scale s = max |a| / 32767 there
    (0 for an all-zero a), which it returns (float32). With ``has_w`` the maximum is taken
    over the samples whose weight w (Nv, Nu) is > 0 only (the others are never used, and
    data without confidence must not change the rest: they are clipped to ±32767 s); w has
    a's dims either way."""
    Nv, Nu = a.shape
    z = np.float32(0.0)
    n = numba.uint64(u_hi - u_lo)
    m = _abs_max_where(a, v_lo, v_hi, u_lo, u_hi, w, has_w)
    inv = np.float32(_QMAX) / m if m > z else z
    hi = np.float32(_QMAX)
    off = np.float32(32768.5)
    for v in range(Nv):
        o = q[v]
        if v < v_lo or v >= v_hi:
            o[:] = 0
            continue
        o[:u_lo] = 0
        o[u_hi:] = 0
        r = a[v, u_lo:u_hi]
        o = o[u_lo:u_hi]
        for u in range(n):
            # + 32768.5 then truncation: rounding to nearest without a call (vectorises)
            o[u] = np.int16(np.int32(min(max(r[u] * inv, -hi), hi) + off) - 32768)
    return m / np.float32(_QMAX)


@numba.njit(parallel=True, cache=True)
def _quantise_views_kernel(a, q, dsc, k, box):
    """:func:`_quantise_plane` of every view image of a (F, ny, nx, Nv, Nu) into q (int16, same
    dims), the scales into dsc[..., k] (F, ny, nx, 5); the box's (v, u) samples (box (8,))."""
    ny, nx = a.shape[1], a.shape[2]
    for idx in numba.prange(a.shape[0] * ny * nx):
        fc = idx // (ny * nx)
        j = (idx // nx) % ny
        i = idx % nx
        dsc[fc, j, i, k] = _quantise_plane(a[fc, j, i], q[fc, j, i], box[4], box[5], box[6], box[7], a[0, 0, 0], False)


def _scaled_views(arrays: list, box: np.ndarray) -> tuple[list, np.ndarray]:
    """The scaled views (module docstring) of float32 derivatives ``arrays`` = [L_x .. L_t], each
    (F, ny, nx, Nv, Nu), on the (v, u) samples of ``box`` (8,): five int16 arrays and their
    scales (F, ny, nx, 5) float32, as the solver's fused kernel stores them."""
    shape = arrays[0].shape
    dsc = np.zeros(shape[:3] + (5,), np.float32)
    q = [np.empty(shape, np.int16) for _ in range(5)]
    for k, a in enumerate(arrays):
        _quantise_views_kernel(np.ascontiguousarray(a, dtype=np.float32), q[k], dsc, k, np.asarray(box, np.int64))
    return q, dsc


def _unscaled(q: np.ndarray, dsc: np.ndarray, k: int) -> np.ndarray:
    """The float32 values (F, ny, nx, Nv, Nu) of scaled view ``q`` (int16, same dims), derivative
    ``k`` (0..4: L_x .. L_t) of the scales ``dsc`` (F, ny, nx, 5)."""
    return q.astype(np.float32) * dsc[..., k, None, None]


@numba.njit(cache=True, inline="always")
def _eq5_coefficients(g0, g1, g2, g3, x, y, u, v, z_pi, f, inv_f):
    """Coefficients of (t_z, ω_x, ω_y, ω_z) in one ray's Eq. 5 row ``[L_x, L_y, L_u, L_v]
    [M_t, M_ω]`` (those of t_x and t_y are L_x = g0 and L_y = g1); inv_f = 1 / f."""
    c2 = -(u * g0 + v * g1) * inv_f
    c3 = -(u * y * inv_f) * g0 - (v * y * inv_f + z_pi) * g1 - (u * v * inv_f) * g2 \
        - (v * v * inv_f + f) * g3
    c4 = (u * x * inv_f + z_pi) * g0 + (v * x * inv_f) * g1 + (u * u * inv_f + f) * g2 \
        + (u * v * inv_f) * g3
    c5 = -y * g0 + x * g1 - v * g2 + u * g3
    return c2, c3, c4, c5


@numba.njit(cache=True, inline="always")
def _row_energy(x, y, v, z_pi, f, S, var, poly, st):
    """Add one (x, y, v) row's Σ_u w Σ_j var_j m_j m_jᵀ to st[4:25] (upper triangle) from the
    row's weight moments S[k] = Σ_u w u^k (k = 0..4). m_j are the Eq. 5 coefficients of a
    unit derivative along axis j (x, y, u, v), quadratic in u: poly[0] + poly[1] u + poly[2] u²."""
    inv_f = 1.0 / f
    for jax in range(4):
        vj = var[jax]
        if vj == 0.0:
            continue
        poly[:, :] = 0.0
        if jax == 0:                   # unit L_x
            poly[0, 0] = 1.0
            poly[0, 4] = z_pi
            poly[0, 5] = -y
            poly[1, 2] = -inv_f
            poly[1, 3] = -y * inv_f
            poly[1, 4] = x * inv_f
        elif jax == 1:                 # unit L_y
            poly[0, 1] = 1.0
            poly[0, 2] = -v * inv_f
            poly[0, 3] = -(v * y * inv_f + z_pi)
            poly[0, 4] = v * x * inv_f
            poly[0, 5] = x
        elif jax == 2:                 # unit L_u
            poly[0, 4] = f
            poly[0, 5] = -v
            poly[1, 3] = -v * inv_f
            poly[2, 4] = inv_f
        else:                          # unit L_v
            poly[0, 3] = -(v * v * inv_f + f)
            poly[1, 4] = v * inv_f
            poly[1, 5] = 1.0
        k = 4
        for a in range(6):
            for b in range(a, 6):
                e = 0.0
                for d1 in range(3):
                    pa = poly[d1, a]
                    if pa == 0.0:
                        continue
                    for d2 in range(3):
                        e += pa * poly[d2, b] * S[d1 + d2]
                st[k] += vj * e
                k += 1




@numba.njit(cache=True, fastmath=_FASTMATH)
def _accumulate_view(gx, gy, gu, gv, lt, sc, wb, x, y, us, vs, z_pi, f, p, kind, inv_sc, tile,
                     v_lo, v_hi, u_lo, u_hi, h, var, final, acc, st, poly, S):
    """Eq. 5 normal-equation sums of one view image's rays (samples v_lo:v_hi, u_lo:u_hi).

    gx .. lt, wb: (Nv, Nu) derivatives (int16 or float32) and base weights of the view, sc
    (5,) float32 the derivatives' scales (module docstring); c = the ray's Eq. 5
    coefficients in face coordinates, b = −L_t. With ``kind`` 1 (Tukey) or 2 (Huber) the
    weight is wb times the IRLS weight of the residual ``r = L_t + c · p`` normalised by
    1 / inv_sc; with 3 or 4 wb times the slope ψ' of Tukey's or Huber's loss there
    (:data:`_ROBUST_SLOPE`: the M-estimator covariance's normal matrix). Adds the sums to acc
    (n_tv, n_tu, 29) per (u, v) tile of ``tile`` samples and counts to st (25,); with ``final``
    also the texture and the noise energy.
    The ray loop has no branches (rays with weight <= 0 add zeros; their derivatives
    are finite) and unsigned indices, so that it vectorises (callers use ``_FASTMATH``).
    """
    # the per-ray arithmetic and the sums over one row of a tile are float32 (16 rays:
    # the rounding is that of the float32 derivatives); they are added to float64 sums
    one = np.float32(1.0)
    z32 = np.float32(0.0)
    wu = _weight_unit(wb)
    inv_f = np.float32(1.0 / f)
    f32 = np.float32(f)
    z32_pi = np.float32(z_pi)
    x32 = np.float32(x)
    y32 = np.float32(y)
    isc = np.float32(inv_sc)
    tx = np.float32(p[0])
    ty = np.float32(p[1])
    tz = np.float32(p[2])
    wx = np.float32(p[3])
    wy = np.float32(p[4])
    wz = np.float32(p[5])
    qx = np.float32(sc[0])
    qy = np.float32(sc[1])
    qu = np.float32(sc[2])
    qv = np.float32(sc[3])
    qt = np.float32(sc[4])
    hx2 = h[0] * h[0]
    hy2 = h[1] * h[1]
    hu2 = h[2] * h[2]
    hv2 = h[3] * h[3]
    n_w = 0.0
    n_base = 0.0
    n_in = 0.0
    tex = 0.0
    for jv in range(v_lo, v_hi):
        v = vs[jv]
        v32 = np.float32(v)
        tv = jv // tile
        rx = gx[jv]
        ry = gy[jv]
        ru = gu[jv]
        rv = gv[jv]
        rt = lt[jv]
        rw = wb[jv]
        s0 = s1 = s2 = s3 = s4 = 0.0
        for tu in range(u_lo // tile, (u_hi - 1) // tile + 1):
            n00 = n01 = n02 = n03 = n04 = n05 = z32
            n11 = n12 = n13 = n14 = n15 = z32
            n22 = n23 = n24 = n25 = z32
            n33 = n34 = n35 = z32
            n44 = n45 = z32
            n55 = z32
            r0 = r1 = r2 = r3 = r4 = r5 = z32
            sbb = z32
            sw = z32
            c_base = z32
            c_in = z32
            c_w = z32
            for iu in range(numba.uint64(max(tu * tile, u_lo)), numba.uint64(min((tu + 1) * tile, u_hi))):
                wraw = rw[iu]
                pos = wraw > z32
                wi = np.float32(wraw) * wu if pos else z32
                c_base += one if pos else z32
                u = np.float32(us[iu])
                g0 = np.float32(rx[iu]) * qx
                g1 = np.float32(ry[iu]) * qy
                g2 = np.float32(ru[iu]) * qu
                g3 = np.float32(rv[iu]) * qv
                b = -(np.float32(rt[iu]) * qt)
                c0 = g0
                c1 = g1
                c2, c3, c4, c5 = _eq5_coefficients(g0, g1, g2, g3, x32, y32, u, v32, z32_pi, f32, inv_f)
                if kind != 0:
                    r = c0 * tx + c1 * ty + c2 * tz + c3 * wx + c4 * wy + c5 * wz - b
                    zz = abs(r) * isc
                    if kind == 1:
                        q = one - zz * zz
                        wr = q * q if zz < one else z32
                    elif kind == 2:
                        wr = one if zz <= one else one / zz
                    elif kind == 3:                 # Tukey's ψ'(r) / ψ'(0) (_ROBUST_SLOPE)
                        q = one - zz * zz
                        wr = q * (one - np.float32(5.0) * zz * zz) if zz < one else z32
                    else:                           # Huber's
                        wr = one if zz <= one else z32
                    c_in += one if (pos and wr > np.float32(0.5)) else z32
                    wi = wi * wr
                c_w += one if wi > z32 else z32
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
                if final:
                    tex += wi * (g0 * g0 * hx2 + g1 * g1 * hy2 + g2 * g2 * hu2 + g3 * g3 * hv2)
                    m = wi
                    s0 += m
                    m *= u
                    s1 += m
                    m *= u
                    s2 += m
                    m *= u
                    s3 += m
                    m *= u
                    s4 += m
            n_base += c_base
            n_in += c_in
            n_w += c_w
            a = acc[tv, tu]
            a[0] += n00
            a[1] += n01
            a[2] += n02
            a[3] += n03
            a[4] += n04
            a[5] += n05
            a[6] += n11
            a[7] += n12
            a[8] += n13
            a[9] += n14
            a[10] += n15
            a[11] += n22
            a[12] += n23
            a[13] += n24
            a[14] += n25
            a[15] += n33
            a[16] += n34
            a[17] += n35
            a[18] += n44
            a[19] += n45
            a[20] += n55
            a[21] += r0
            a[22] += r1
            a[23] += r2
            a[24] += r3
            a[25] += r4
            a[26] += r5
            a[27] += sbb
            a[28] += sw
        if final and s0 > 0.0:
            S[0] = s0
            S[1] = s1
            S[2] = s2
            S[3] = s3
            S[4] = s4
            _row_energy(x, y, v, z_pi, f, S, var, poly, st)
    st[0] += n_w
    st[1] += n_base
    st[2] += n_in
    st[3] += tex


_ACCUMULATE_LOADED: set = set()


def _load_accumulate_view(Lx: np.ndarray, dsc: np.ndarray, base: np.ndarray, vals: list, zs: np.ndarray,
                          fs: np.ndarray, P: np.ndarray, tile: int, box: np.ndarray, h: np.ndarray,
                          var: np.ndarray, final: bool) -> None:
    """Load :func:`_accumulate_view`'s own compiled code for the argument types that
    :func:`_pass_kernel` gives it (Lx and its siblings, dsc, base: the kernel's work arrays;
    vals: the grid's x, y, u, v values; once per process and types), before the kernel
    first runs. numba links a copy of a called function into the
    caller's code and keeps the function's own code too, and a call reaches whichever the
    process loaded first: the function's own when the caller was compiled in this process,
    the caller's copy when the caller came from numba's disk cache. The two were optimised
    apart and can round float32 sums in another order, so a first run after an install or a
    source change gave other last digits than later runs (docs/motion_log.md, sessions 16–17).
    Loaded first, the function's own code is the one every run reaches. The call sums no
    ray (an empty row range). (:func:`_prepare_kernel` calls the function with other
    argument types, constants among them; its estimates were the same fresh and cached.)"""
    key = tuple(str(numba.typeof(a)) for a in (Lx, dsc, base, vals[2], vals[3], zs, P, h, var))
    if key in _ACCUMULATE_LOADED:
        return
    v = int(box[4])
    _accumulate_view(Lx[0, 0, 0], Lx[0, 0, 0], Lx[0, 0, 0], Lx[0, 0, 0], Lx[0, 0, 0], dsc[0, 0, 0], base[0, 0, 0],
                     vals[0][0], vals[1][0], vals[2], vals[3], zs[0], fs[0], P[0], 0, 0.0, int(tile), v, v,
                     int(box[6]), int(box[7]), h, var, bool(final), np.zeros((1, 1, _NACC)), np.zeros(_NSTAT),
                     np.empty((3, 6)), np.empty(5))
    _ACCUMULATE_LOADED.add(key)


@numba.njit(cache=True, inline="always")
def _box_view(idx, box, ny, nx):
    """(face, y, x) of the view with flat index idx over the faces x the box's (ny, nx) views
    (box (8,): [y0, y1, x0, x1, ...])."""
    fc = idx // (ny * nx)
    rem = idx - fc * ny * nx
    return fc, box[0] + rem // nx, box[2] + rem - (rem // nx) * nx


@numba.njit(parallel=True, cache=True, fastmath=_FASTMATH)
def _pass_kernel(Lx, Ly, Lu, Lv, Lt, dsc, base, has_base, xs, ys, us, vs, zs, fs, P, kind, inv_sc, tile,
                 box, vo, h, var, final, acc, st, chunks):
    """One pass over the rays of the view images box[0]:box[1] (y) x box[2]:box[3] (x),
    samples box[4]:box[5] (v) x box[6]:box[7] (u) of every face: :func:`_accumulate_view`
    with the stored derivatives (F, ny, nx, Nv, Nu; view origin ``vo``, module docstring;
    scales ``dsc``) and base weights (unit weights without ``has_base``). P (F, 6): the parameters in each
    face's frame. acc (n_views, n_tv, n_tu, 29), st (n_views, 25), views ordered (face, y, x)."""
    F, Nv, Nu = Lx.shape[0], Lx.shape[3], Lx.shape[4]
    ny = box[1] - box[0]
    nx = box[3] - box[2]
    n = F * ny * nx
    chunks = max(1, min(n, chunks))
    for c in numba.prange(chunks):
        poly = np.empty((3, 6))
        S = np.empty(5)
        ones = np.empty((Nv if not has_base else 1, Nu if not has_base else 1), base.dtype)
        ones.fill(np.rint(np.float32(1.0) / _weight_unit(base)))          # weight 1 in base's units
        for idx in range(c * n // chunks, (c + 1) * n // chunks):
            fc, j, i = _box_view(idx, box, ny, nx)
            ja = j - vo[0]
            ia = i - vo[1]
            a = acc[idx]
            a[:, :, :] = 0.0
            s = st[idx]
            s[:] = 0.0
            wb = base[fc, ja, ia] if has_base else ones
            _accumulate_view(Lx[fc, ja, ia], Ly[fc, ja, ia], Lu[fc, ja, ia], Lv[fc, ja, ia], Lt[fc, ja, ia],
                             dsc[fc, ja, ia], wb, xs[i], ys[j], us, vs, zs[fc], fs[fc], P[fc], kind, inv_sc, tile,
                             box[4], box[5], box[6], box[7], h, var, final, a, s, poly, S)


@numba.njit(parallel=True, cache=True, fastmath=_FASTMATH)
def _prepare_kernel(L0, L1, l0g, conf, conf_unit, need_min, smooth, smooth_mode, py, dy, px, dx, pv, dv, pu, du,
                    sx, sy, su, sv, Lx, Ly, Lu, Lv, Lt, dsc, base, xs, ys, us, vs, zs, fs, P, tile, box, vo, h,
                    var, final, acc, st, chunks, rho, rho_sc, has_rho, sums, drop_rho=False):
    """Per valid view image, in cache: the base weight = confidence ``conf`` (in units of
    ``conf_unit``: 1 / 65535 for uint16) minimised over the filter support (``need_min``)
    × valid × the discontinuity weight (``smooth_mode`` 0: none,
    1: the array ``smooth`` (weights as base: module docstring), 2: |base|, with a 0 / 1 confidence minimum kept in base's sign:
    base = ±weight, and every kernel counts base <= 0 as weight 0), the plenoptic derivatives of the
    (warped) pair (L0, L1; L0 read rounded to multiples of l0g[face] where > 0, l0g (F,)
    float32: :func:`~polycam.derivatives.xy_view`) as scaled views (int16 Lx .. Lt and their scales ``dsc``, module
    docstring), with ``has_rho`` the Eq. 6 regressors L_x, L_y ← ρ̂ L_u, ρ̂ L_v where ``rho``
    (same dims, int16 in units of ``rho_sc`` per view image: :func:`depth_rho`) is given and
    the base weight > 0 (with ``drop_rho``, a linear array's, a ray without ρ̂ is left out:
    :func:`_rho_times`), and with ``sums``
    the unit-IRLS-weight normal sums (:func:`_accumulate_view`; else acc and st are left as
    they are). box as in :func:`_pass_kernel` (the filter radii). L0, L1, conf: every view;
    Lx .. Lt, dsc, base, ``smooth`` (mode 1) and ``rho`` (with ``has_rho``): view
    origin ``vo`` (module docstring)."""
    F, Ny, Nx, Nv, Nu = L0.shape
    ry = box[0]
    rx = box[2]
    rv = box[4]
    ru = box[6]
    ny = box[1] - box[0]
    nx = box[3] - box[2]
    n = F * ny * nx
    chunks = max(1, min(n, chunks))
    for c in numba.prange(chunks):
        buf = np.empty((7, Nv, Nu), np.float32)
        poly = np.empty((3, 6))
        S = np.empty(5)
        for idx in range(c * n // chunks, (c + 1) * n // chunks):
            fc, j, i = _box_view(idx, box, ny, nx)
            ja = j - vo[0]
            ia = i - vo[1]
            gx = Lx[fc, ja, ia]
            gy = Ly[fc, ja, ia]
            gu = Lu[fc, ja, ia]
            gv = Lv[fc, ja, ia]
            lt = Lt[fc, ja, ia]
            sc = dsc[fc, ja, ia]
            xy_view(L0, L1, l0g[fc], fc, j, i, py, dy, px, dx, buf[0], buf[1], buf[2], buf[3])
            cm = buf[5]
            t2 = buf[6]
            cm[:, :] = conf[fc, j, i]
            if need_min:
                # row-wise minima over contiguous rows (vectorise; unsigned indices)
                for jj in range(j - ry, j + ry + 1):
                    for ii in range(i - rx, i + rx + 1):
                        src = conf[fc, jj, ii]
                        for v in range(Nv):
                            cr = cm[v]
                            sr = src[v]
                            for u in range(numba.uint64(Nu)):
                                cr[u] = min(cr[u], sr[u])
                for v in range(rv, Nv - rv):
                    tr = t2[v]
                    tr[:] = cm[v - rv]
                    for d in range(v - rv + 1, v + rv + 1):
                        sr = cm[d]
                        for u in range(numba.uint64(Nu)):
                            tr[u] = min(tr[u], sr[u])
                n_in = numba.uint64(Nu - 2 * ru)
                for v in range(rv, Nv - rv):
                    tr = t2[v]
                    cr = cm[v, ru:Nu - ru]
                    cr[:] = tr[0:Nu - 2 * ru]
                    for d in range(1, 2 * ru + 1):
                        sr = tr[d:d + Nu - 2 * ru]
                        for u in range(n_in):
                            cr[u] = min(cr[u], sr[u])
            b = base[fc, ja, ia]
            if smooth_mode == 2:                 # the samples outside the box are never read
                for v in range(rv, Nv - rv):
                    br = b[v]
                    cr = cm[v]
                    for u in range(numba.uint64(ru), numba.uint64(Nu - ru)):
                        a = abs(br[u])
                        br[u] = a if cr[u] > np.float32(0.0) else -a
            else:
                b[:, :] = 0.0
                for v in range(rv, Nv - rv):
                    br = b[v]
                    cr = cm[v]
                    sr = smooth[fc, ja, ia, v] if smooth_mode == 1 else smooth[0, 0, 0, 0]
                    for u in range(numba.uint64(ru), numba.uint64(Nu - ru)):   # (unsigned: vectorises)
                        c = cr[u] * conf_unit
                        # (the weight first, then the store: with a conditional product as the
                        # inlined store's argument numba 0.68 stored 0s)
                        x = c
                        if smooth_mode == 1:
                            x = c * (np.float32(sr[u]) * _weight_unit(smooth))
                        _store_weight(br, u, x)
            # the (u, v) stage one derivative at a time into o (cm is no longer needed), each
            # quantised into its scaled view: L_u, L_v first (the Eq. 6 regressors use them)
            tmp = buf[4]
            o = buf[5]
            _filt_v(buf[0], pv, tmp)
            _filt_u(tmp, du, su, o)
            sc[2] = _quantise_plane(o, gu, rv, Nv - rv, ru, Nu - ru, b, True)
            _filt_v(buf[0], dv, tmp)
            _filt_u(tmp, pu, sv, o)
            sc[3] = _quantise_plane(o, gv, rv, Nv - rv, ru, Nu - ru, b, True)
            for k in range(2):
                _filt_v(buf[1 + k], pv, tmp)
                _filt_u(tmp, pu, sx if k == 0 else sy, o)
                if has_rho:
                    _rho_times(o, rho[fc, ja, ia], rho_sc[fc, ja, ia], b, gu if k == 0 else gv, sc[2 + k], rv, Nv - rv,
                               ru, Nu - ru, drop_rho)
                sc[k] = _quantise_plane(o, gx if k == 0 else gy, rv, Nv - rv, ru, Nu - ru, b, True)
            _filt_v(buf[3], pv, tmp)
            _filt_u(tmp, pu, np.float32(1.0), o)
            sc[4] = _quantise_plane(o, lt, rv, Nv - rv, ru, Nu - ru, b, True)
            if not sums:
                continue
            a = acc[idx]
            a[:, :, :] = 0.0
            s = st[idx]
            s[:] = 0.0
            _accumulate_view(gx, gy, gu, gv, lt, sc, b, xs[i], ys[j], us, vs, zs[fc], fs[fc], P[fc], 0, 0.0, tile,
                             rv, Nv - rv, ru, Nu - ru, h, var, final, a, s, poly, S)


@numba.njit(cache=True, inline="always")
def _drop_without_rho(b, q, v_lo, v_hi, u_lo, u_hi):
    """A linear array's rays without ρ̂ (q == ``_RHO_NONE``; (Nv, Nu) int16) left out on the samples
    v_lo:v_hi x u_lo:u_hi: their base weight b's sign turns negative (b <= 0 counts as weight 0;
    |b| stays, as smooth mode 2 keeps the discontinuity weight there)."""
    none = np.int16(_RHO_NONE)
    for v in range(v_lo, v_hi):
        br = b[v]
        qr = q[v]
        for u in range(numba.uint64(u_lo), numba.uint64(u_hi)):
            br[u] = -abs(br[u]) if qr[u] == none else br[u]


@numba.njit(cache=True, fastmath=_FASTMATH)
def _rho_times(o, q, qs, b, g, s, v_lo, v_hi, u_lo, u_hi, drop):
    """o[v, u] ← ρ̂ × g[v, u] s (a scaled view's value: module docstring) where ρ̂ = q[v, u] qs
    (int16 ρ̂ in units of qs: :func:`depth_rho`) is given (q ≠ ``_RHO_NONE``) and the base
    weight b > 0, on the samples v_lo:v_hi x u_lo:u_hi; all (Nv, Nu). With ``drop`` (a linear
    array: the measured regressor is not there to keep) a ray without ρ̂ is left out instead
    (:func:`_drop_without_rho`)."""
    s32 = np.float32(s)
    qs32 = np.float32(qs)
    none = np.int16(_RHO_NONE)
    if drop:
        _drop_without_rho(b, q, v_lo, v_hi, u_lo, u_hi)
    for v in range(v_lo, v_hi):
        qr = q[v]
        br = b[v]
        gr = g[v]
        orow = o[v]
        for u in range(numba.uint64(u_lo), numba.uint64(u_hi)):
            ok = (br[u] > np.float32(0.0)) & (qr[u] != none)
            orow[u] = (np.float32(qr[u]) * qs32) * (np.float32(gr[u]) * s32) if ok else orow[u]


@numba.njit(parallel=True, cache=True, fastmath=_FASTMATH)
def _sample_residuals(Lx, Ly, Lu, Lv, Lt, dsc, base, xs, ys, us, vs, zs, fs, P, box, vo, stride, out_a, out_w):
    """|Eq. 5 residual| and base weight of the rays of every ``stride``-th (v) row of the
    box's view images (rows numbered in C order over (face, y, x, v) inside box; whole
    rows keep the memory access contiguous; arrays with view origin ``vo``, derivatives
    with scales ``dsc``, module docstring). out_a, out_w: (n_rows, box u width)."""
    ny = box[1] - box[0]
    nx = box[3] - box[2]
    nv = box[5] - box[4]
    u0 = box[6]
    for k in numba.prange(out_a.shape[0]):
        q = k * stride
        jv = box[4] + q % nv
        q //= nv
        i = box[2] + q % nx
        q //= nx
        j = box[0] + q % ny
        fc = q // ny
        f = fs[fc]
        z_pi = zs[fc]
        inv_f = 1.0 / f
        x = xs[i]
        y = ys[j]
        v = vs[jv]
        p0, p1, p2, p3, p4, p5 = P[fc, 0], P[fc, 1], P[fc, 2], P[fc, 3], P[fc, 4], P[fc, 5]
        ja = j - vo[0]
        ia = i - vo[1]
        rx = Lx[fc, ja, ia, jv]
        ry = Ly[fc, ja, ia, jv]
        ru = Lu[fc, ja, ia, jv]
        rv = Lv[fc, ja, ia, jv]
        rt = Lt[fc, ja, ia, jv]
        rw = base[fc, ja, ia, jv]
        wu = _weight_unit(base)
        sc = dsc[fc, ja, ia]
        qx, qy, qu, qv, qt = sc[0], sc[1], sc[2], sc[3], sc[4]
        oa = out_a[k]
        ow = out_w[k]
        for m in range(numba.uint64(out_a.shape[1])):          # branch-free: vectorises
            iu = numba.uint64(u0) + m
            wb = rw[iu]
            pos = wb > 0.0
            u = us[iu]
            g0 = np.float64(np.float32(rx[iu]) * qx)
            g1 = np.float64(np.float32(ry[iu]) * qy)
            g2 = np.float64(np.float32(ru[iu]) * qu)
            g3 = np.float64(np.float32(rv[iu]) * qv)
            c2, c3, c4, c5 = _eq5_coefficients(g0, g1, g2, g3, x, y, u, v, z_pi, f, inv_f)
            r = np.float64(np.float32(rt[iu]) * qt) + g0 * p0 + g1 * p1 + c2 * p2 + c3 * p3 + c4 * p4 + c5 * p5
            oa[m] = abs(r) if pos else 0.0
            ow[m] = np.float64(wb) * wu if pos else 0.0


_BIN_SORT_MAX = 2048
"""At most this many values of the selected bin are sorted; a fuller bin (heavy tails: most
values in the lowest bins) is re-binned over its own range first."""


@numba.njit(cache=True, inline="always")
def _bin_scale(a, n, nb):
    """(lo, hi, scale) of a[:n]: its range and the factor that maps it onto bins 0 .. nb - 1,
    ``int((a - lo) scale)``; scale 0 (one bin) when the range is empty or subnormal (its
    inverse would overflow)."""
    lo = a[0]
    hi = a[0]
    for k in range(n):
        lo = min(lo, a[k])
        hi = max(hi, a[k])
    scale = (nb - 1) / (np.float64(hi) - np.float64(lo)) if hi > lo else 0.0
    return lo, hi, (scale if scale < 1e300 else 0.0)


@numba.njit(cache=True)
def _bin_select(a, w, has_w, bins, hist, target):
    """The smallest a_k whose cumulative weight Σ_{a_i <= a_k} w_i reaches ``target``, given
    each value's histogram bin ``bins`` (n,) (monotone in the value; bins at or beyond
    hist.size hold values left out) and the bins' summed weights ``hist``: the bin is found
    from hist, then that bin's values are sorted (re-binned over their own range while more
    than ``_BIN_SORT_MAX``). Weights w (n,) with ``has_w``, else 1 each (then target k + 1
    gives the k-th smallest, 0-based). 0 if the bin is empty."""
    nb = hist.shape[0]
    cum = 0.0
    b = 0
    while b < nb - 1 and cum + hist[b] < target:
        cum += hist[b]
        b += 1
    cnt = 0
    for k in range(a.shape[0]):
        cnt += 1 if bins[k] == b else 0
    vals = np.empty(cnt, a.dtype)
    ws = np.empty(cnt)
    cnt = 0
    for k in range(a.shape[0]):
        if bins[k] == b:
            vals[cnt] = a[k]
            ws[cnt] = w[k] if has_w else 1.0
            cnt += 1
    if cnt == 0:
        return np.zeros(1, a.dtype)[0]             # in a's precision, as the values
    while cnt > _BIN_SORT_MAX:
        lo, hi, scale = _bin_scale(vals, cnt, nb)
        if not hi > lo:
            return lo                              # the bin holds one value, repeated
        if scale == 0.0:                           # subnormal spread: sort what is left
            break
        sub = np.empty(cnt, np.int32)
        subhist = np.zeros(nb)
        for k in range(cnt):
            sub[k] = np.int32((np.float64(vals[k]) - lo) * scale)
            subhist[sub[k]] += ws[k]
        b = 0
        while b < nb - 1 and cum + subhist[b] < target:
            cum += subhist[b]
            b += 1
        m = 0
        for k in range(cnt):
            if sub[k] == b:
                vals[m] = vals[k]
                ws[m] = ws[k]
                m += 1
        if m == cnt:                               # no progress (cannot happen: hi > lo)
            break
        cnt = m
    vals = vals[:cnt]
    ws = ws[:cnt]
    order = np.argsort(vals)
    for o in order:
        cum += ws[o]
        if cum >= target:
            return vals[o]
    return vals[order[cnt - 1]]


@numba.njit(cache=True, fastmath=_FASTMATH)
def _weighted_median(a, w):
    """Weighted median of a >= 0 (the smallest a_k with Σ_{a_i <= a_k} w_i >= Σ w / 2) over
    w > 0: a histogram finds the bin, a sort of that bin's values the sample (exact for any
    monotone binning; the loops are branch-free so that they vectorise)."""
    n = numba.uint64(a.shape[0])
    tot = 0.0
    mean = 0.0
    for k in range(n):
        wk = np.float64(w[k]) if w[k] > 0.0 else 0.0
        tot += wk
        mean += wk * a[k]
    if not tot > 0.0:
        return 0.0
    hi = 4.0 * mean / tot
    if not hi > 0.0:
        return 0.0
    nb = 4096
    scale = nb / hi if nb / hi < 1e300 else 0.0     # subnormal values: one bin, sorted
    bins = np.empty(a.shape[0], np.int32)           # nb + 1: w <= 0, out of every bin
    for k in range(n):
        bins[k] = np.int32(min(a[k] * scale, np.float64(nb))) if w[k] > 0.0 else np.int32(nb + 1)
    hist = np.zeros(nb + 2)
    for k in range(n):
        hist[bins[k]] += w[k] if w[k] > 0.0 else 0.0
    return _bin_select(a, w, True, bins, hist[:nb + 1], 0.5 * tot)


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


def _accumulate(der, base: np.ndarray, has_base: bool, grid: LightFieldGrid, P: np.ndarray, kind: int,
                inv_sc: float, tile: int, box: np.ndarray, h: np.ndarray, var: np.ndarray,
                final: bool) -> tuple[np.ndarray, np.ndarray]:
    """Run :func:`_pass_kernel` over ``der`` (anything with Lx .. Lt (F, Ny, Nx, Nv, Nu));
    returns acc (F, n_views_per_face, n_tiles, 29) and st (F, n_views_per_face, 25)."""
    F, Ny, Nx, Nv, Nu = der.Lx.shape
    nv_ = max(int(box[1] - box[0]), 0) * max(int(box[3] - box[2]), 0)
    nt = (-(-Nv // tile), -(-Nu // tile))
    acc = np.empty((F * nv_,) + nt + (_NACC,))
    st = np.empty((F * nv_, _NSTAT))
    vals = [np.ascontiguousarray(a.values, dtype=np.float64) for a in (grid.x, grid.y, grid.u, grid.v)]
    zs = np.array([face.z_pi for face in grid.faces], float)
    fs = np.array([face.f for face in grid.faces], float)
    if nv_ and box[5] > box[4] and box[7] > box[6]:
        P = np.ascontiguousarray(P, dtype=np.float64)
        dsc = _unit_scales(der.Lx.shape)
        _load_accumulate_view(der.Lx, dsc, base, vals, zs, fs, P, int(tile), box, h, var, final)
        _pass_kernel(der.Lx, der.Ly, der.Lu, der.Lv, der.Lt, dsc, base, has_base, *vals, zs, fs, P, kind,
                     float(inv_sc), int(tile), box, _view_origin(Ny, Nx), h, var, final, acc, st, parallel_chunks())
    else:
        acc[:] = 0.0
        st[:] = 0.0
    return acc.reshape(F, nv_, nt[0] * nt[1], _NACC), st.reshape(F, nv_, _NSTAT)


_IU = np.triu_indices(6)


def _unpack_sym(a: np.ndarray) -> np.ndarray:
    """(..., 21) upper-triangle entries → (..., 6, 6) symmetric matrices."""
    N = np.zeros(a.shape[:-1] + (6, 6))
    N[..., _IU[0], _IU[1]] = a
    N[..., _IU[1], _IU[0]] = a
    return N


def _reduce(acc: np.ndarray, B: list) -> tuple:
    """Rig-frame N (6, 6), rhs (6,), Σ w b², Σ w and the per-face tile sums (F, n_tiles, 29)
    of acc (F, n_views, n_tiles, 29); B: per face the (6, 6) rig → face map."""
    tiles = acc.sum(axis=1)
    tot = tiles.sum(axis=1)                              # (F, 29)
    N = np.zeros((6, 6))
    rhs = np.zeros(6)
    for k, Bk in enumerate(B):
        N += Bk.T @ _unpack_sym(tot[k, :21]) @ Bk
        rhs += Bk.T @ tot[k, 21:27]
    return N, rhs, float(tot[:, 27].sum()), float(tot[:, 28].sum()), tiles


def _face_B(face) -> np.ndarray:
    """(6, 6) map from rig-frame (t, ω) to face-frame (t, ω)."""
    R = np.asarray(face.R_rig_face, float)
    B = np.zeros((6, 6))
    B[:3, :3] = R.T
    B[3:, 3:] = R.T
    return B


_DEPTH_KEEP = 3.0
"""Depth-regularised regressors: keep the measured L_x, L_y where the window's residual energy
exceeds this many times their expected noise variance (one depth does not explain it)."""

_LINEAR_MISFIT = 0.5
"""A linear array's ρ̂ (:func:`depth_rho`'s ``linear``): a ray without it has no L_x (or L_y) and
is left out, so a window is also used where its misfit is at most this fraction of the measured
regressor's energy (one depth explains half of it), not only where it is within the noise.
Measured (docs/motion_log.md, session 40): 0.1, 0.5 and 1 equal on the sphere scene with
occluding spheres (six faces, noise-free and σ = 0.01); on sharp frames of ``polycam synth
lightfield`` (aliased across the views) 0.1 left too few rays at the coarsest level and the
pairs failed, 0.5 gave 23 / 14 % (t / ω), 1 (every window) 28 / 17 %."""

_DEPTH_GATE_MISFIT = 1000.0
"""Default of :attr:`MotionOptions.depth_gate_misfit`: the disparity gate (:attr:`MotionOptions.depth_gate`) replaces a ray whose window one depth
does not explain only where the misfit is at least this many times the expected noise of L_x,
L_y: there the mismatch is the aliasing of the measured derivatives (a bias that noise does not
average away; noise-free sphere scene at 8-16 m: 1.1e4-6e5x, 5-95%), while a misfit of a few
dozen to a few hundred times the noise is signal that the measured derivatives carry beyond one
depth (the noisy one-face 5 x 5 room of tests/test_design.py: 28-310x; replacing it there
makes the translation columns nearly collinear with the rotation's, condition 11 → 60, and
the scatter 2.3x). docs/motion_log.md, "Noise"."""

_RHO_DENOISED_MIN = 0.5
"""ρ̂'s denominator is the window's energy ``S_uu = Σ (L_u² + L_v²)`` less the part the sensor
noise of ``L_u, L_v`` adds to it (``n (var_u + var_v)``, n the window's ray weight), which
would otherwise shrink ρ̂ towards 0 by ``var / (signal + var)`` (errors in variables: at 32 grey
levels ~4 % on the sphere scene); it is kept at least this fraction of ``S_uu`` (windows whose
``L_u`` is mostly noise)."""

_DEPTH_RHO_KAPPA = 0.0856
"""Variance of ρ̂'s pooled noise, in units of var(L_x) / Σ_window (L_u² + L_v²): Σ (w ⋆ k)² /
Σ k² over the four axes for the window w (fs3 across x and y, fs5 ∗ fs5 along u and v) and
the filter k of L_x (fs3 derivative along x, prefilters elsewhere), i.e. the noise of L_x
correlated over the filter supports and L_u locally constant (measured on the room test:
0.10 median)."""


@dataclass(frozen=True)
class RegressorMix:
    """The make-up of the Eq. 6 regressors' noise (:func:`depth_rho`, :func:`depth_regularise`):
    on the replaced rays ``ρ̂ L_u`` carries ``ρ̂² var_u`` (L_u's noise) plus ``L_u² var(ρ̂)`` (ρ̂'s
    pooled noise times the signal), elsewhere the measured L_x keeps ``var_x``; likewise for y."""

    frac: float
    """Replaced rays / valid rays."""
    rho2: float
    """Mean ρ̂² over the replaced rays [(u per unit of x)²]."""
    rho_noise: float
    """Mean ``L_u² var(ρ̂)`` per component over the replaced rays (units of var_x): from the
    measured regressors' noise, unwhitened."""

    def variances(self, var: np.ndarray, rho_gain: float = 1.0) -> np.ndarray:
        """(4,) noise variances of the regressors (L_x or ρ̂ L_u, L_y or ρ̂ L_v, L_u, L_v), a
        ray-count mix, from ``var`` (4,): the derivatives' noise in the metric of the sums
        (unwhitened, or whitened: :meth:`polycam.motion._Solver.whitened_derivative_noise`);
        ``rho_gain``: the factor by which that metric scales the signal ``L_u`` (1 unwhitened),
        since ``L_u δρ`` is the signal modulated by ρ̂'s slowly varying error."""
        out = np.asarray(var, float).copy()
        er = self.rho_noise * rho_gain
        out[0] = (1.0 - self.frac) * var[0] + self.frac * (self.rho2 * var[2] + er)
        out[1] = (1.0 - self.frac) * var[1] + self.frac * (self.rho2 * var[3] + er)
        return out


def _depth_rho_noise(var: np.ndarray) -> tuple[float, float]:
    """(a, b) of the noise test of the Eq. 6 regressors: a ray's ρ̂ L_u, ρ̂ L_v replaces the
    measured L_x, L_y only where ``ρ̂² a + (L_u² + L_v²) b / S_uu ≤ 1`` (S_uu the window's
    Σ L_u² + L_v²), i.e. where their expected noise ``ρ̂² (var_u + var_v) + (L_u² + L_v²)
    var(ρ̂)`` (var(ρ̂) = κ (var_x + var_y) / (2 S_uu)) is at most that of the measured pair,
    var_x + var_y. Both 0 without noise."""
    vxy = float(var[0] + var[1])
    if not vxy > 0:
        return 0.0, 0.0
    return float(var[2] + var[3]) / vxy, 0.5 * _DEPTH_RHO_KAPPA


def depth_regularise(der: list, valid: np.ndarray, var: np.ndarray, rho_max: float = 0.0,
                     gate_misfit: float = _DEPTH_GATE_MISFIT, pool_views: bool = False) -> np.ndarray:
    """In place on der = [Lx, Ly, Lu, Lv, Lt] (F, Ny, Nx, Nv, Nu): L_x, L_y ← ρ̂ L_u, ρ̂ L_v
    (:attr:`MotionOptions.depth_regressors`; ρ̂ = Σ (L_x L_u + L_y L_v) / (Σ (L_u² + L_v²) less
    its noise part, ``_RHO_DENOISED_MIN``) over the window) where valid (bool, same dims), their expected
    noise is at most that of the measured pair (:func:`_depth_rho_noise`; ``var`` (4,): noise
    variances of L_x, L_y, L_u, L_v), and either one depth explains the window to within the
    noise (misfit ≤ ``_DEPTH_KEEP`` x the noise) or ``|ρ̂| ≤ rho_max`` (ρ̂ in units of u per
    unit x: the views are nearly parallel there, :attr:`MotionOptions.depth_gate`) with a
    misfit of at least ``gate_misfit`` x the noise (aliasing, not signal); returns (4,)
    ``var`` updated for the replaced rays (ρ̂² var_u + L_u² var(ρ̂) there, a ray-count mix).
    ``pool_views`` (:attr:`MotionOptions.depth_pool_views`; with noise, var_x + var_y > 0): the
    replaced rays' ρ̂ are first pooled over the views (:func:`polycam.rho_pool.pool_over_views`,
    var(ρ̂) = κ (var_x + var_y) / (2 S_uu), ``_DEPTH_RHO_KAPPA``), the mix with the pooled
    noise. The numpy reference of :func:`depth_rho`."""
    Lx, Ly, Lu, Lv, _ = der
    m = valid.astype(np.float32)
    t5 = FILTERS["fs5"].prefilter.astype(np.float32)
    t3 = FILTERS["fs3"].prefilter.astype(np.float32)

    def win(a):
        out = np.ascontiguousarray(a * m, dtype=np.float32)
        for _ in range(2):
            out = correlate_axis(correlate_axis(out, t5, 3), t5, 4)
        return correlate_axis(correlate_axis(out, t3, 1), t3, 2)

    gx = np.where(valid, Lx, 0.0).astype(np.float32)
    gy = np.where(valid, Ly, 0.0).astype(np.float32)
    gu = np.where(valid, Lu, 0.0).astype(np.float32)
    gv = np.where(valid, Lv, 0.0).astype(np.float32)
    suu = win(gu * gu + gv * gv)
    sxu = win(gx * gu + gy * gv)
    sxx = win(gx * gx + gy * gy)
    n = win(np.ones_like(m))
    den = np.maximum(suu - np.float32(var[2] + var[3]) * n, np.float32(_RHO_DENOISED_MIN) * suu)
    rho = np.where(suu > 0, sxu / np.maximum(den, np.float32(1e-30)), np.float32(0.0)).astype(np.float32)
    res = sxx - rho * sxu
    vxy = var[0] + var[1]
    a, b = _depth_rho_noise(var)
    g2 = gu * gu + gv * gv
    e_rho = np.where(suu > 0, g2 * np.float32(b) / np.maximum(suu, np.float32(1e-30)), np.float32(0.0))
    quiet = rho * rho * np.float32(a) + e_rho <= 1.0
    fits = res <= _DEPTH_KEEP * vxy * n
    gated = (np.abs(rho) <= rho_max) & (res >= gate_misfit * vxy * n)
    use = valid & quiet & (fits | gated)
    nv = int(valid.sum())
    if not (nv and use.any()):
        return np.asarray(var, float).copy()
    rho2 = float(np.mean(rho[use].astype(np.float64) ** 2))
    rho_noise = 0.5 * float(np.mean(e_rho[use].astype(np.float64))) * vxy     # per component
    if pool_views and vxy > 0:
        kv = 0.5 * _DEPTH_RHO_KAPPA * vxy
        pooled = pool_over_views(np.where(use, rho, np.nan), np.where(use, kv / np.maximum(suu, 1e-30), np.nan))
        rho = np.where(use, pooled.rho, rho)
        rho2, rho_noise = _pooled_mix(pooled, gu, gv)
    Lx[use] = rho[use] * gu[use]
    Ly[use] = rho[use] * gv[use]
    mix = RegressorMix(frac=float(use.sum()) / nv, rho2=rho2, rho_noise=rho_noise)
    return mix.variances(var)


def _pooled_mix(pooled, Lu: np.ndarray, Lv: np.ndarray) -> tuple[float, float]:
    """(mean ρ̃², mean (L_u² + L_v²) var(ρ̃) / 2) over the rays with a pooled ρ̃ (finite), for
    :class:`RegressorMix` (``rho2``, ``rho_noise``); Lu, Lv float (F, ny, nx, Nv, Nu)."""
    use = np.isfinite(pooled.rho)
    r = pooled.rho[use].astype(np.float64)
    w2 = (Lu[use].astype(np.float64) ** 2 + Lv[use].astype(np.float64) ** 2)
    return float(np.mean(r * r)), 0.5 * float(np.mean(w2 * pooled.var[use]))


@numba.njit(cache=True, inline="always")
def _depth_products(Lx, Ly, Lu, Lv, dsc, base, near, has_near, box, vo, fc, j, i, w, axes, out):
    """out[c] += w × the masked Eq. 6 products of view image (fc, j, i) (indices already
    clamped; arrays with view origin ``vo``, derivatives with scales ``dsc``): c = 0 Σ-terms
    L_u² + L_v², 1 L_x L_u + L_y L_v, 2 L_x² + L_y², 3 the mask, all 0 outside the valid box,
    where base <= 0 and (with ``has_near``) where ``near`` is nonzero (a view outside the box
    adds nothing). ``axes`` (2,) float32: 1 or 0 per view axis (x, y), 0 leaving that axis's
    terms out (a linear array's single-view axis, whose L_x or L_y is not measured)."""
    if j < box[0] or j >= box[1] or i < box[2] or i >= box[3] or w == 0.0:
        return
    ja = j - vo[0]
    ia = i - vo[1]
    sc = dsc[fc, ja, ia]
    qx, qy, qu, qv = sc[0] * axes[0], sc[1] * axes[1], sc[2] * axes[0], sc[3] * axes[1]
    for v in range(box[4], box[5]):
        gx = Lx[fc, ja, ia, v]
        gy = Ly[fc, ja, ia, v]
        gu = Lu[fc, ja, ia, v]
        gv = Lv[fc, ja, ia, v]
        bw = base[fc, ja, ia, v]
        nr = near[fc, ja, ia, v] if has_near else near[0, 0, 0, 0]
        o0 = out[0, v]
        o1 = out[1, v]
        o2 = out[2, v]
        o3 = out[3, v]
        for u in range(numba.uint64(box[6]), numba.uint64(box[7])):
            m = w if (bw[u] > 0.0) & (nr[u] == 0) else np.float32(0.0)
            a = np.float32(gu[u]) * qu
            b = np.float32(gv[u]) * qv
            c = np.float32(gx[u]) * qx
            d = np.float32(gy[u]) * qy
            o0[u] += m * (a * a + b * b)
            o1[u] += m * (c * a + d * b)
            o2[u] += m * (c * c + d * d)
            o3[u] += m


@numba.njit(cache=True, inline="always")
def _window_uv_row(A, Brow, Crow, t9, box, v):
    """Row v of the (u, v) part of the Eq. 6 window on the box's samples: Crow[c, u] =
    Σ t9 ⊗ t9 over A (4, Nv + 8, Nu + 8), the (v, u) samples padded by 4 zeros on each side;
    Brow (4, Nu + 8) holds the row's v pass (zero outside the box's u range). t9 = fs5 ∗ fs5
    (symmetric: folded)."""
    u0, u1 = box[6], box[7]
    w0, w1, w2, w3, w4 = t9[0], t9[1], t9[2], t9[3], t9[4]
    nu = numba.uint64(u1 - u0)
    for c in range(4):
        o = Brow[c, 4 + u0:4 + u1]
        a0 = A[c, v, 4 + u0:4 + u1]
        a1 = A[c, v + 1, 4 + u0:4 + u1]
        a2 = A[c, v + 2, 4 + u0:4 + u1]
        a3 = A[c, v + 3, 4 + u0:4 + u1]
        a4 = A[c, v + 4, 4 + u0:4 + u1]
        a5 = A[c, v + 5, 4 + u0:4 + u1]
        a6 = A[c, v + 6, 4 + u0:4 + u1]
        a7 = A[c, v + 7, 4 + u0:4 + u1]
        a8 = A[c, v + 8, 4 + u0:4 + u1]
        for u in range(nu):
            o[u] = w4 * a4[u] + w0 * (a0[u] + a8[u]) + w1 * (a1[u] + a7[u]) + w2 * (a2[u] + a6[u]) \
                + w3 * (a3[u] + a5[u])
        row = Brow[c]
        o = Crow[c, u0:u1]
        b0 = row[u0:u1]
        b1 = row[u0 + 1:u1 + 1]
        b2 = row[u0 + 2:u1 + 2]
        b3 = row[u0 + 3:u1 + 3]
        b4 = row[u0 + 4:u1 + 4]
        b5 = row[u0 + 5:u1 + 5]
        b6 = row[u0 + 6:u1 + 6]
        b7 = row[u0 + 7:u1 + 7]
        b8 = row[u0 + 8:u1 + 8]
        for u in range(nu):
            o[u] = w4 * b4[u] + w0 * (b0[u] + b8[u]) + w1 * (b1[u] + b7[u]) + w2 * (b2[u] + b6[u]) \
                + w3 * (b3[u] + b5[u])


@numba.njit(cache=True, fastmath=_FASTMATH)
def _depth_rho_unit(Lx, Ly, Lu, Lv, dsc, base, near, has_near, box, vo, t9, t3, thr, thr_gate, na, nb, rho_max,
                    var_uv, axes, linear, rho, rho_sc, rv, kv, st, fc, i, ja, jb, px, A, Brow, Crow, vb):
    """One run of :func:`_depth_rho_kernel`: view rows ja:jb of column (fc, i); adds its
    statistics to st (4,). Scratch (float32): px (3, 4, Nv, Nu) the products of three view
    rows, A (4, Nv + 8, Nu + 8) and Brow (4, Nu + 8) zero outside the box's (v, u) range
    (only its inside is written here), Crow (4, Nu), vb (Nv, Nu) a view's ρ̂ before rounding.
    A function of its own, called from the parallel loop (a body this large inside the
    prange compiled ~2x slower)."""
    Ny, Nx = vo[2], vo[3]
    for r in range(ja - 1, jb + 1):              # rows r = j-1, j, j+1 at slot (r + 3) % 3 of px
        s = px[(r + 3) % 3]
        s[:, :, :] = 0.0
        rc = min(max(r, 0), Ny - 1)
        for dx in range(3):
            ic = min(max(i + dx - 1, 0), Nx - 1)
            _depth_products(Lx, Ly, Lu, Lv, dsc, base, near, has_near, box, vo, fc, rc, ic, t3[dx], axes, s)
        if r < ja + 1:
            continue
        j = r - 1                                   # rows j-1, j, j+1 are ready
        a0 = px[(j + 2) % 3]
        a1 = px[(j + 3) % 3]
        a2 = px[(j + 4) % 3]
        for c in range(4):
            for v in range(box[4], box[5]):
                o = A[c, v + 4, 4 + box[6]:4 + box[7]]
                s0 = a0[c, v, box[6]:box[7]]
                s1 = a1[c, v, box[6]:box[7]]
                s2 = a2[c, v, box[6]:box[7]]
                for u in range(numba.uint64(box[7] - box[6])):
                    o[u] = t3[0] * s0[u] + t3[1] * s1[u] + t3[2] * s2[u]
        jw = j - vo[0]                              # the view in the work arrays
        iw = i - vo[1]
        out = vb
        bw = base[fc, jw, iw]
        su = dsc[fc, jw, iw, 2]
        sv = dsc[fc, jw, iw, 3]
        n_valid = 0.0
        n_use = 0.0
        r2 = 0.0
        er = 0.0
        for v in range(box[4], box[5]):
            _window_uv_row(A, Brow, Crow, t9, box, v)
            suu = Crow[0]
            sxu = Crow[1]
            sxx = Crow[2]
            sn = Crow[3]
            o = out[v]
            b = bw[v]
            nr = near[fc, jw, iw, v] if has_near else near[0, 0, 0, 0]
            gu = Lu[fc, jw, iw, v]
            gv = Lv[fc, jw, iw, v]
            rvr = rv[fc, jw, iw, v] if kv > 0.0 else rv[0, 0, 0, 0]
            for u in range(numba.uint64(box[6]), numba.uint64(box[7])):
                ok = (b[u] > 0.0) & (nr[u] == 0)
                has = suu[u] > 0.0
                inv = np.float32(1.0) / max(suu[u], np.float32(1e-30))
                den = max(suu[u] - np.float32(var_uv) * sn[u], np.float32(_RHO_DENOISED_MIN) * suu[u])
                q = sxu[u] / max(den, np.float32(1e-30)) if has else np.float32(0.0)
                a = np.float32(gu[u]) * su
                c = np.float32(gv[u]) * sv
                e = (a * a + c * c) * np.float32(nb) * inv if has else np.float32(0.0)
                res = np.float64(sxx[u] - q * sxu[u])
                nw = np.float64(sn[u])
                quiet = q * q * np.float32(na) + e <= np.float32(1.0)
                if linear:               # no measured regressor to keep: one depth explains the window
                    use = ok and has and (res <= thr * nw or res <= _LINEAR_MISFIT * np.float64(sxx[u]))
                else:
                    use = ok and quiet and (res <= thr * nw or (abs(q) <= rho_max and res >= thr_gate * nw))
                o[u] = q if use else np.float32(np.nan)
                if kv > 0.0:
                    rvr[u] = np.float32(kv) * inv if use else np.float32(np.nan)
                n_valid += 1.0 if ok else 0.0
                n_use += 1.0 if use else 0.0
                r2 += np.float64(q) * np.float64(q) if use else 0.0
                er += np.float64(e) if use else 0.0
        rho_sc[fc, jw, iw] = _put_rho_view(vb, rho[fc, jw, iw], box[4], box[5], box[6], box[7])
        st[0] += n_valid
        st[1] += n_use
        st[2] += r2
        st[3] += er


@numba.njit(parallel=True, cache=True, fastmath=_FASTMATH)
def _depth_rho_kernel(Lx, Ly, Lu, Lv, dsc, base, near, has_near, box, vo, t9, t3, thr, thr_gate, na, nb, rho_max,
                      var_uv, axes, linear, rho, rho_sc, rv, kv, stats, scratch):
    """ρ̂ of the Eq. 6 regressors per ray (:func:`depth_rho`): rho int16 in units of rho_sc
    per view image (all arrays with view origin ``vo``, derivatives with scales ``dsc``, module
    docstring), ``_RHO_NONE`` where the measured L_x, L_y are kept (inside the box: base <= 0,
    ``near`` nonzero with ``has_near`` (else a (1, 1, 1, 1, Nu) row of zeros), or the window is not
    explained by one depth; the caller fills the views outside the box). The window sums
    are separable: fs3 across x (per view row, rolling over y), fs3 across y, then t9 =
    fs5 ∗ fs5 along v and u with zeros outside the box (= :func:`depth_regularise`'s two fs5
    passes with "nearest" borders on every ray at least 2 samples inside the (u, v) border).
    ρ̂ = S_xu / (S_uu − n var_uv) (``var_uv`` = var_u + var_v, n the window's ray weight;
    at least ``_RHO_DENOISED_MIN`` S_uu in the denominator). A ray is replaced where
    ``ρ̂² na + (L_u² + L_v²) nb / S_uu ≤ 1`` (:func:`_depth_rho_noise`)
    and its window's misfit is at most ``thr`` x the window's ray weight, or ``|ρ̂| ≤ rho_max``
    and the misfit at least ``thr_gate`` x the weight. With ``kv`` > 0 also each used ray's
    var(ρ̂) = kv / S_uu into rv (float32, same dims as rho; else a (1, 1, 1, 1, Nu) dummy).
    Work: the box's view rows, column (face, x) after column, cut into one equal share per
    chunk; a chunk takes its share as runs of one column each (each run recomputes the
    products of the two view rows around it). scratch (chunks, _depth_rho_scratch(Nv, Nu))
    float32: each chunk's work memory. stats (chunks, 4): valid rays, used rays, Σ ρ̂² and
    Σ (L_u² + L_v²) nb / S_uu over the used ones."""
    F, Nv, Nu = Lx.shape[0], Lx.shape[3], Lx.shape[4]
    nx = box[3] - box[2]
    ny = box[1] - box[0]
    rows = F * nx * ny
    chunks = stats.shape[0]
    n_px = 12 * Nv * Nu
    n_a = 4 * (Nv + 8) * (Nu + 8)
    for c in numba.prange(chunks):
        w = scratch[c]
        px = w[:n_px].reshape((3, 4, Nv, Nu))
        A = w[n_px:n_px + n_a].reshape((4, Nv + 8, Nu + 8))
        Brow = w[n_px + n_a:n_px + n_a + 4 * (Nu + 8)].reshape((4, Nu + 8))
        Crow = w[n_px + n_a + 4 * (Nu + 8):n_px + n_a + 8 * Nu + 32].reshape((4, Nu))
        vb = w[n_px + n_a + 8 * Nu + 32:n_px + n_a + 8 * Nu + 32 + Nv * Nu].reshape((Nv, Nu))
        A[:] = 0.0
        Brow[:] = 0.0
        st = stats[c]
        st[:] = 0.0
        r = rows * c // chunks
        r_end = rows * (c + 1) // chunks
        while r < r_end:
            col = r // ny
            jb = min(r_end - col * ny, ny)
            fc = col // nx
            _depth_rho_unit(Lx, Ly, Lu, Lv, dsc, base, near, has_near, box, vo, t9, t3, thr, thr_gate, na, nb,
                            rho_max, var_uv, axes, linear, rho, rho_sc, rv, kv, st, fc, box[2] + col - fc * nx,
                            box[0] + r - col * ny,
                            box[0] + jb, px, A, Brow, Crow, vb)
            r = col * ny + jb


def _depth_rho_scratch(Nv: int, Nu: int) -> int:
    """float32 work memory of one chunk of :func:`_depth_rho_kernel` on (Nv, Nu) view images."""
    return 13 * Nv * Nu + 4 * (Nv + 8) * (Nu + 8) + 8 * Nu + 32


@numba.njit(parallel=True, cache=True, fastmath=_FASTMATH)
def _apply_rho(Lx, Ly, Lu, Lv, dsc, base, rho, rho_sc, box, vo, chunks, drop=False):
    """L_x, L_y ← ρ̂ L_u, ρ̂ L_v in place where ρ̂ is given and base > 0 (inside box (8,), as
    :func:`depth_rho`: rho int16 in units of rho_sc per view image, ``_RHO_NONE`` where the
    measured regressors are kept; arrays with view origin ``vo``): scaled views
    (int16 with scales ``dsc``, module docstring), each view image re-quantised with the
    scale of its new values (``chunks``: :func:`~polycam.derivatives.parallel_chunks`). With
    ``drop`` (a linear array) a ray without ρ̂ is left out (:func:`_rho_times`)."""
    ny = box[1] - box[0]
    nx = box[3] - box[2]
    F, Nv, Nu = Lx.shape[0], Lx.shape[3], Lx.shape[4]
    n = F * ny * nx
    chunks = max(1, min(n, chunks))
    for c in numba.prange(chunks):
        o = np.empty((Nv, Nu), np.float32)
        for idx in range(c * n // chunks, (c + 1) * n // chunks):
            fc, j, i = _box_view(idx, box, ny, nx)
            ja = j - vo[0]
            ia = i - vo[1]
            sc = dsc[fc, ja, ia]
            b = base[fc, ja, ia]
            q = rho[fc, ja, ia]
            qs = np.float32(rho_sc[fc, ja, ia])
            if drop:
                _drop_without_rho(b, q, box[4], box[5], box[6], box[7])
            for k in range(2):
                g = Lx[fc, ja, ia] if k == 0 else Ly[fc, ja, ia]
                d = Lu[fc, ja, ia] if k == 0 else Lv[fc, ja, ia]
                s = np.float32(sc[k])
                sd = np.float32(sc[2 + k])
                for v in range(box[4], box[5]):
                    gr = g[v]
                    dr = d[v]
                    qr = q[v]
                    br = b[v]
                    orow = o[v]
                    for u in range(numba.uint64(box[6]), numba.uint64(box[7])):
                        ok = (br[u] > np.float32(0.0)) & (qr[u] != np.int16(_RHO_NONE))
                        orow[u] = (np.float32(qr[u]) * qs) * (np.float32(dr[u]) * sd) if ok else np.float32(gr[u]) * s
                sc[k] = _quantise_plane(o, g, box[4], box[5], box[6], box[7], b, True)


@numba.njit(parallel=True, cache=True)
def _fill_rho(rho, rho_sc, near, base, rho_bar, box, vo):
    """ρ̂ ← rho_bar[f, v, u] (F, Nv, Nu) where rho_bar is a number, base > 0 and ``near``
    (uint8, same dims as rho) is nonzero (rays whose filter support holds extrapolated
    samples; inside box (8,), as :func:`depth_rho`: int16 in units of rho_sc, each view image
    re-quantised; arrays with view origin ``vo``)."""
    ny = box[1] - box[0]
    nx = box[3] - box[2]
    F, Nv, Nu = rho.shape[0], rho.shape[3], rho.shape[4]
    nan = np.float32(np.nan)
    none = np.int16(_RHO_NONE)
    for idx in numba.prange(F * ny * nx):
        fc, j, i = _box_view(idx, box, ny, nx)
        ja = j - vo[0]
        ia = i - vo[1]
        a = np.empty((Nv, Nu), np.float32)
        qs = np.float32(rho_sc[fc, ja, ia])
        for v in range(box[4], box[5]):
            q = rho[fc, ja, ia, v]
            r = near[fc, ja, ia, v]
            b = base[fc, ja, ia, v]
            rb = rho_bar[fc, v]
            o = a[v]
            for u in range(numba.uint64(box[6]), numba.uint64(box[7])):     # branch-free: vectorises
                fill = (r[u] != 0) & (b[u] > 0.0) & (rb[u] == rb[u])
                o[u] = np.float32(rb[u]) if fill else (np.float32(q[u]) * qs if q[u] != none else nan)
        rho_sc[fc, ja, ia] = _put_rho_view(a, rho[fc, ja, ia], box[4], box[5], box[6], box[7])


@numba.njit(parallel=True, cache=True)
def _pool_stats_kernel(rho, scales, rv, half, mean, tau2, mvar, d, live):
    """Per direction (f, v, u) over the views of the int16 ρ̂ (F, ny, nx, Nv, Nu; units of scales
    (F, ny, nx), ``_RHO_NONE``: none) with their variances rv (float32, same dims): the mean ρ̄,
    τ² = max(spread − mean var, 0) (0 with fewer than 4 rays) and the mean var into mean, tau2,
    mvar (F, Nv, Nu) float64, whether the direction can be pooled (at least 4 rays, mean var
    > 0) into live (F, Nv, Nu) bool, and (ρ̄_a − ρ̄_b)² / (n (1 / n_a + 1 / n_b)) / mean var into d (NaN
    where it is not defined) for view columns with half[i] = 1 (a) or 2 (b)
    (:func:`polycam.rho_pool.pool_over_views`, whose numpy this is)."""
    F, ny, nx, Nv, Nu = rho.shape
    none = np.int16(_RHO_NONE)
    for fv in numba.prange(F * Nv):
        f = fv // Nv
        v = fv - f * Nv
        acc = np.zeros((8, Nu))                 # n, Σρ, Σρ², Σvar, n_a, Σρ_a, n_b, Σρ_b
        for j in range(ny):
            for i in range(nx):
                row = rho[f, j, i, v]
                vr = rv[f, j, i, v]
                sc = np.float64(scales[f, j, i])
                hk = half[i]
                for u in range(Nu):
                    if row[u] != none:
                        r = np.float64(row[u]) * sc
                        acc[0, u] += 1.0
                        acc[1, u] += r
                        acc[2, u] += r * r
                        acc[3, u] += np.float64(vr[u])
                        if hk == 1:
                            acc[4, u] += 1.0
                            acc[5, u] += r
                        elif hk == 2:
                            acc[6, u] += 1.0
                            acc[7, u] += r
        for u in range(Nu):
            n = acc[0, u]
            m = acc[1, u] / n if n > 0 else np.nan
            mv = acc[3, u] / n if n > 0 else np.nan
            spread = (acc[2, u] - n * m * m) / (n - 1.0) if n > 1 else np.nan
            ok4 = n >= 4 and mv > 0
            live[f, v, u] = ok4
            mean[f, v, u] = m
            mvar[f, v, u] = mv
            tau2[f, v, u] = max(spread - mv, 0.0) if ok4 else 0.0
            ok = acc[4, u] > 0 and acc[6, u] > 0 and mv > 0
            dd = acc[5, u] / acc[4, u] - acc[7, u] / acc[6, u] if ok else 0.0
            d[f, v, u] = dd * dd / (n * (1.0 / acc[4, u] + 1.0 / acc[6, u])) / mv if ok else np.nan


@numba.njit(parallel=True, cache=True)
def _pool_apply_kernel(rho, scales, rv, mean, tau2, mvar, live, q, Lu, Lv, dsc, box, vo, stats):
    """ρ̂ ← ρ̄ + g (ρ̂ − ρ̄), g = τ² / (τ² + var), per ray of the box's views where ``live`` (the
    direction's statistics of :func:`_pool_stats_kernel`; else g = 1), each view image
    re-quantised (:func:`_put_rho_view`); stats (F · ny · nx, 3) per view: the rays, Σ ρ̃²,
    Σ (L_u² + L_v²) var(ρ̃) with var(ρ̃) = g² var + (1 − g)² q mean var (L_u, L_v scaled views,
    module docstring; arrays with view origin ``vo``)."""
    ny = box[1] - box[0]
    nx = box[3] - box[2]
    F, Nv, Nu = rho.shape[0], rho.shape[3], rho.shape[4]
    none = np.int16(_RHO_NONE)
    for idx in numba.prange(F * ny * nx):
        fc, j, i = _box_view(idx, box, ny, nx)
        ja = j - vo[0]
        ia = i - vo[1]
        a = np.empty((Nv, Nu), np.float32)
        sc = np.float64(scales[fc, ja, ia])
        su = np.float64(dsc[fc, ja, ia, 2])
        sv = np.float64(dsc[fc, ja, ia, 3])
        n = 0.0
        r2 = 0.0
        e = 0.0
        for v in range(box[4], box[5]):
            row = rho[fc, ja, ia, v]
            vr = rv[fc, ja, ia, v]
            gu = Lu[fc, ja, ia, v]
            gv = Lv[fc, ja, ia, v]
            for u in range(box[6], box[7]):
                if row[u] == none:
                    a[v, u] = np.nan
                    continue
                r = np.float64(row[u]) * sc
                var = np.float64(vr[u])
                if live[fc, v, u]:
                    t = tau2[fc, v, u]
                    g = t / (t + var) if t + var > 0 else 1.0
                    m = mean[fc, v, u]
                    r = m + g * (r - m)
                    var = g * g * var + (1.0 - g) * (1.0 - g) * q * mvar[fc, v, u]
                a[v, u] = np.float32(r)
                x = np.float64(gu[u]) * su
                y = np.float64(gv[u]) * sv
                n += 1.0
                r2 += r * r
                e += (x * x + y * y) * var
        scales[fc, ja, ia] = _put_rho_view(a, rho[fc, ja, ia], box[4], box[5], box[6], box[7])
        stats[idx, 0] = n
        stats[idx, 1] = r2
        stats[idx, 2] = e


def _pool_rho(rho: np.ndarray, scales: np.ndarray, rv: np.ndarray, Lu: np.ndarray, Lv: np.ndarray,
              dsc: np.ndarray, box: np.ndarray, vo: np.ndarray) -> tuple[float, float]:
    """The solver's int16 ρ̂ (F, ny, nx, Nv, Nu, units of scales (F, ny, nx)) pooled over the
    views in place (:func:`polycam.rho_pool.pool_over_views` on :func:`rho_values`, within
    the int16 rounding), with rv its variances (float32, same dims); returns (mean ρ̃²,
    mean (L_u² + L_v²) var(ρ̃) / 2) over the rays with ρ̃, for :class:`RegressorMix`."""
    F, ny, nx, Nv, Nu = rho.shape
    cols = np.flatnonzero((rho != _RHO_NONE).any(axis=(0, 1, 3, 4)))
    h = (len(cols) - 1) // 2
    half = np.zeros(nx, np.int64)
    if h >= 1:
        half[cols[:h]] = 1
        half[cols[-h:]] = 2
    mean, tau2, mvar, d = (np.empty((F, Nv, Nu)) for _ in range(4))
    live = np.empty((F, Nv, Nu), np.bool_)
    _pool_stats_kernel(rho, scales, rv, half, mean, tau2, mvar, d, live)
    d = d[np.isfinite(d)]
    q = float(np.median(d)) / _CHI2_1_MEDIAN if (h >= 1 and d.size) else math.nan
    if not math.isfinite(q):
        live[...] = False
    stats = np.zeros((F * int(box[1] - box[0]) * int(box[3] - box[2]), 3))
    _pool_apply_kernel(rho, scales, rv, mean, tau2, mvar, live, q if math.isfinite(q) else 0.0, Lu, Lv, dsc,
                       box, vo, stats)
    n, r2, e = stats.sum(axis=0)
    return (r2 / n, 0.5 * e / n) if n else (0.0, 0.0)


def depth_rho(der: list, base: np.ndarray, box: np.ndarray, var: np.ndarray, out: np.ndarray,
              rho_max: float = 0.0, gate_misfit: float = _DEPTH_GATE_MISFIT,
              near: np.ndarray | None = None, vo: np.ndarray | None = None,
              dsc: np.ndarray | None = None, scratch: np.ndarray | None = None,
              out_scale: np.ndarray | None = None, return_mix: bool = False, pool_views: bool = False,
              linear: str = ""):
    """ρ̂ of :func:`depth_regularise` per ray, as a kernel: ``out`` (F, Ny, Nx, Nv, Nu) float32
    gets ρ̂ where the regressors are replaced, NaN where the measured ones are kept (rays
    outside ``box`` (8,) [y0, y1, x0, x1, v0, v1, u0, u1] or with base <= 0 are not valid).
    The kernel stores ρ̂ as the solver keeps it, int16 in units of a scale per view image
    (max |ρ̂| / 32767; ``_RHO_NONE`` where kept): with an int16 ``out`` the scales go into
    ``out_scale`` (F, Ny, Nx) float32 (required then), a float32 ``out`` gets those values
    (:func:`rho_values`: within 1.5e-5 of the view's max |ρ̂|).
    der = [Lx, Ly, Lu, Lv, ...] float32, or int16 scaled views with their scales ``dsc``
    (module docstring) (unchanged); var (4,): noise variances of (L_x, L_y,
    L_u, L_v); ``rho_max``, ``gate_misfit``: as :func:`depth_regularise`; ``near`` (same dims
    as out, uint8): rays where it is nonzero count as base <= 0. ``vo``: the arrays' view
    origin (module docstring; None: they hold every view). ``scratch``: optional float32
    memory the kernel may use as its work arrays (about 17 view images per thread:
    the solver lends it the warped frame, dead by then), allocated when None or too small.
    Returns (4,) the variances for the replaced regressors, as depth_regularise; with
    ``return_mix`` also their make-up, a :class:`RegressorMix` (None: no ray replaced).
    ``pool_views``: then ρ̂ pooled over the views (:func:`polycam.rho_pool.pool_over_views`,
    as depth_regularise; needs noise: var_x + var_y > 0).
    ``linear`` ("x" or "y"; "": both measured): a linear array's single-view axis, whose
    regressor is not measured: ρ̂ from the other axis alone (S_uu, S_xu, S_xx and the noise
    without the single axis's terms), every ray whose window one depth explains (misfit within
    the noise or at most ``_LINEAR_MISFIT`` of its energy) gets it, whatever the noise test."""
    Lx, Ly, Lu, Lv = der[:4]
    t9, t3 = rho_window_taps()
    F = Lx.shape[0]
    vo = _view_origin(*Lx.shape[1:3]) if vo is None else np.asarray(vo, np.int64)
    dsc = _unit_scales(Lx.shape) if dsc is None else dsc
    chunks = numba.get_num_threads()                 # one equal share of the rows each
    stats = np.zeros((chunks, 4))
    n = _depth_rho_scratch(*Lx.shape[3:])
    if scratch is None or scratch.dtype != np.float32 or scratch.size < chunks * n:
        scratch = np.empty(chunks * n, np.float32)
    scratch = scratch.reshape(-1)[:chunks * n].reshape(chunks, n)
    box = np.asarray(box, np.int64)
    if out.dtype != np.int16:
        rho, rho_sc = np.empty(out.shape, np.int16), np.empty(out.shape[:3], np.float32)
        res = depth_rho(der, base, box, var, rho, rho_max, gate_misfit, near, vo, dsc, scratch, rho_sc, return_mix,
                        pool_views, linear)
        out[...] = rho_values(rho, rho_sc)
        return res
    axes = np.array([linear != "x", linear != "y"], np.float32)      # 0: the single-view axis
    var_pos = float(axes[0] * var[0] + axes[1] * var[1]) / float(axes.sum())   # per measured axis
    kv = _DEPTH_RHO_KAPPA * var_pos if pool_views else 0.0     # var(ρ̂) = kv / S_uu
    rv = np.full(out.shape, np.nan, np.float32) if kv > 0.0 else np.zeros((1, 1, 1, 1, Lx.shape[4]), np.float32)
    if F * int(box[3] - box[2]) * int(box[1] - box[0]) > 0 and box[5] > box[4] and box[7] > box[6]:
        y0, y1, x0, x1 = box[0] - vo[0], box[1] - vo[0], box[2] - vo[1], box[3] - vo[1]
        for sl in (np.s_[:, :y0], np.s_[:, y1:], np.s_[:, :, :x0], np.s_[:, :, x1:]):
            out[sl] = _RHO_NONE                         # views outside the box (the kernel does the rest)
            out_scale[sl[:3]] = 0.0
        vxy = float(axes[0] * var[0] + axes[1] * var[1])
        na, nb = _depth_rho_noise(var)
        has_near = near is not None
        near = near if has_near else np.zeros((1, 1, 1, 1, Lx.shape[4]), np.uint8)
        _depth_rho_kernel(Lx, Ly, Lu, Lv, dsc, base, near, has_near, box, vo, t9, t3, _DEPTH_KEEP * vxy,
                          float(gate_misfit) * vxy, na, nb, float(rho_max), float(axes[0] * var[2] + axes[1] * var[3]),
                          axes, bool(linear), out, out_scale, rv, kv, stats, scratch)
    else:
        out[...] = _RHO_NONE
        out_scale[...] = 0.0
    n_valid, n_use, r2, er = stats.sum(axis=0) if stats.size else (0.0, 0.0, 0.0, 0.0)
    rho2 = r2 / n_use if n_use else 0.0
    rho_noise = er / n_use * var_pos if n_use else 0.0
    if kv > 0.0 and n_use:
        rho2, rho_noise = _pool_rho(out, out_scale, rv, Lu, Lv, dsc, box, vo)
    mix = RegressorMix(frac=n_use / n_valid, rho2=rho2, rho_noise=rho_noise) if n_valid and n_use else None
    res = mix.variances(var) if mix is not None else np.asarray(var, float).copy()
    return (res, mix) if return_mix else res
