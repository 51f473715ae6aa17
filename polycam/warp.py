"""Ray-space warping: a light field resampled at the grid rays moved by a rigid transform.

Conventions (SPEC.md, docs/conventions.md): a frame ``L`` of dims ``(F, Ny, Nx, Nv, Nu)``
on a :class:`~polycam.lightfield.LightFieldGrid`; sample ``(x, y, u, v)`` of face k is the
ray with origin ``(x, y, z_pi)`` and direction ``∝ (u, v, f)`` in face coordinates.

Iterated linearisation (warping)
--------------------------------
The motion solver (:mod:`polycam.motion`) linearises paper Eq. 5 about its current
estimate ``M_e``: frame 2 is resampled at the moved rays, ``L1w(ρ) = L1(M_e⁻¹ ρ)`` (each
grid ray transformed and re-intersected with its face's two planes; interpolation linear
in (x, y), 6-point Lagrange in (u, v)). If ``L1w(Δ ρ) = L0(ρ)`` for the small ray motion
``Δ`` solved from Eq. 5, then ``M = Δ⁻¹ M_e`` exactly. Optionally (``symmetric``) both
frames are warped half-way with ``H = M_e^½`` (``_T_sqrt``): ``L0w(ρ) = L0(H ρ)``,
``L1w(ρ) = L1(H⁻¹ ρ)`` and ``M = H Δ⁻¹ H``.

At the converged estimate the increment is zero, so the answer is set by how
well the warped frame matches, not by the derivative filters: linear
interpolation of a signal with k rad/sample shifts it by a relative error of
about k²/6, which made rotations come out ~10% too large; 4-point cubic
interpolation along (u, v) removes most of that (0.05% on a scene without
occlusions), 6-point also the ~1% left at 8-16 m where the directions are
nearly aliased.

Rays moved beyond the viewpoints (a motion of 1.5 view steps takes 31% of a 9 x 9
array's rays out) can be extrapolated by paper Eq. 6 when the scene's disparity ρ = f / Z
is known per direction: from the nearest edge view at the direction shifted by ρ times
the overshoot (:func:`_extrapolate_xy_kernel`, cubic in (u, v): the shift is a small
fraction of a sample, which linear interpolation gets wrong by a large part of itself
on sharp images).

Across the views the blend is linear at one direction, exact where the scene's disparity per
view step is a small fraction of a sample. Where it is not (camera arrays: a sample or more at
the frames' own sampling, still 0.4–0.9 at the level the solver stops at), neighbouring views
see different scene points at one direction and the blend lags the motion; there the motion
solver (``MotionOptions.depth_views``) has L blended along the disparity ρ̄ per direction
instead: each of the four views around the moved ray read at ``u + ρ (x' − x_n)``, the direction
at which view ``x_n`` sees the scene point that the moved ray ``(x', u)`` sees
(:func:`_depth_views_kernel`, vectorised over the views; :func:`_depth_views_exact_kernel`, every
ray's own stencils, its reference).

The fast path (:func:`warp_lightfield`) is views-innermost: the (u, v) part of the
stencil depends only on the direction, so each of the 6 x 6 (u, v) taps is one
vectorised multiply-add over all view images, followed by a branch-free blend across
views, one direction row at a time (:func:`_warp_rows_kernel`: the row's (u, v)-warped
images stay in a per-thread scratch); :func:`warp_lightfield_reference` does all taps per ray in one kernel (speed
figures: docs/motion.md).

The motion solver's source is int16 (half the memory; :func:`_warp_into`, ``ratio``): each
channel of each face in units of its largest magnitude / 32767 (for L over both frames of
the pair), rounded by :func:`_store`; the warped frame is float32 in the frames' own units.
The solver's derivative kernel reads the other frame rounded to the same units
(:func:`polycam.derivatives.xy_view`), so that equal samples still give L_t = 0 exactly.
"""

from __future__ import annotations

import math

import numba
import numpy as np
from llvmlite import ir as llvm_ir
from numba.extending import intrinsic, overload

from .derivatives import _units
from .eq5 import _FASTMATH, _RHO_NONE, _abs_max_where
from .geometry import R_from_r, T_from_Rt, T_inverse, r_from_R
from .lightfield import LightFieldGrid

__all__ = ["warp_lightfield", "warp_lightfield_reference"]

_UV_TAPS_MAX = 16
"""Most Lagrange points along u and v (``MotionOptions.uv_taps``): the stencils' length (fewer
taps are padded with zero weights, which the blends skip)."""


def _store(a, idx, val):
    """a[idx] = val: as it is into a float array; rounded to the nearest integer and clipped
    to ±32767 into an int16 array (val float32: :func:`~polycam.derivatives._units`; the
    motion solver's int16 warp source, :func:`_warp_into`)."""
    a[idx] = val


@overload(_store, inline="always")
def _store_typed(a, idx, val):
    if isinstance(a.dtype, numba.types.Integer):
        def store_int(a, idx, val):
            a[idx] = np.int16(_units(val))
        return store_int

    def store(a, idx, val):
        a[idx] = val
    return store


_CHUNK = 64                                       # directions per stack buffer (_xy_row)

_OUTSIDE = -np.inf
"""A float warp's mark of a ray outside the grid that a lagged warp leaves to the
extrapolation (:func:`_xy_row`'s ``lag`` 2; warped values are finite)."""


def _stack_buffer(dtype):
    """An intrinsic ``f(n)`` returning a pointer to ``n`` (an integer literal) elements of
    ``dtype`` (a numba type) on the stack of the function it is inlined into, allocated once
    at its entry (wrap it with ``numba.carray``). Nothing else can point there, so a loop
    that reads arrays at computed offsets (gathers) and writes only such a buffer
    vectorises; writing an array instead, LLVM would need a runtime check that the write
    does not overwrite what the loop reads, which it cannot form for computed offsets, and
    keeps the loop scalar (:func:`_xy_row`)."""
    @intrinsic
    def stack(typingctx, n):
        if not isinstance(n, numba.types.IntegerLiteral):
            return None

        def codegen(context, builder, signature, args):
            with builder.goto_entry_block():
                return builder.alloca(context.get_value_type(dtype), size=llvm_ir.Constant(llvm_ir.IntType(64),
                                                                                      n.literal_value))
        return numba.types.CPointer(dtype)(n), codegen
    return stack


_stack_i32 = _stack_buffer(numba.types.int32)
_stack_f64 = _stack_buffer(numba.types.float64)


@numba.njit(cache=True, inline="always")
def _lagrange(a, n, w):
    """n-point Lagrange weights for samples at 1 - n/2, ..., n/2 and fraction a ∈ [0, 1]
    (n = 2: linear, 4: cubic, 6: quintic, 8, 10)."""
    o = n // 2 - 1
    for q in range(n):
        pq = q - o
        acc = 1.0
        for m in range(n):
            if m != q:
                pm = m - o
                acc *= (a - pm) / (pq - pm)
        w[q] = acc


@numba.njit(cache=True, inline="always")
def _cubic(a, w):
    """4-point Lagrange weights for samples at -1, 0, 1, 2 and fraction a ∈ [0, 1] (the
    closed form of ``_lagrange(a, 4, w)``)."""
    b = a - 1.0
    c = a - 2.0
    d = a + 1.0
    w[0] = -a * b * c * (1.0 / 6.0)
    w[1] = d * b * c * 0.5
    w[2] = -d * a * c * 0.5
    w[3] = d * a * b * (1.0 / 6.0)


@numba.njit(cache=True, inline="always")
def _shift_stencil(i, d, n, w):
    """Taps along a direction axis of n samples that read sample i shifted by d samples into
    w (4,): (count, first index); count 1 (no shift, or a single sample: w[0] = 1), 4 (cubic),
    0 (the nodes leave the axis)."""
    if d == 0.0 or n == 1:
        w[0] = 1.0
        return 1, np.int64(i)
    s = i + d
    b = math.floor(s)
    if n < 4 or b < 1 or b > n - 3:
        return 0, np.int64(i)
    _cubic(s - b, w)
    return 4, np.int64(b) - 1


@numba.njit(cache=True, inline="always")
def _stencil_scratch():
    """(wv, wu, iv, iu): one ray's Lagrange weights (float64) and indices (int64) along v and u,
    _UV_TAPS_MAX each (:func:`_lagrange_stencil`), per thread."""
    return (np.empty(_UV_TAPS_MAX), np.empty(_UV_TAPS_MAX), np.empty(_UV_TAPS_MAX, np.int64),
            np.empty(_UV_TAPS_MAX, np.int64))


@numba.njit(cache=True, inline="always")
def _face_direction(R, u, v, f):
    """``R (u, v, f)``: a face sample's direction (u, v, f) moved by the rotation R (3, 3)."""
    return (R[0, 0] * u + R[0, 1] * v + R[0, 2] * f,
            R[1, 0] * u + R[1, 1] * v + R[1, 2] * f,
            R[2, 0] * u + R[2, 1] * v + R[2, 2] * f)


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
    nu_t = _taps_used(uv_taps, Nu)
    nv_t = _taps_used(uv_taps, Nv)
    for jy in numba.prange(Ny):
        wv, wu, iv_idx, iu_idx = _stencil_scratch()
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
                    dx, dy, dz = _face_direction(R, u, v, f)
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


@numba.njit(cache=True, inline="always")
def _lagrange_stencil(fi, n, taps, den, w, idx):
    """Lagrange weights and clamped indices (``taps`` points, padded to _UV_TAPS_MAX with zero weights)
    at the fractional sample position fi of an n-sample axis into w (_UV_TAPS_MAX,), idx (_UV_TAPS_MAX,);
    den[q] = Π_{m≠q} (q − m) for the number of points used (:func:`_lagrange_dens`)."""
    T = _taps_used(taps, n)
    if n == 1:
        for q in range(_UV_TAPS_MAX):
            w[q] = 1.0 if q == 0 else 0.0
            idx[q] = 0
        return
    b = min(max(math.floor(fi), 0.0), n - 2.0)
    a = min(max(fi - b, 0.0), 1.0)
    o = T // 2 - 1
    ib = int(b)
    pre = 1.0                                      # prefix x suffix products of (a − node)
    for q in range(T):
        w[q] = pre
        pre *= a - (q - o)
        idx[q] = min(max(ib - o + q, 0), n - 1)
    suf = 1.0
    for q in range(T - 1, -1, -1):
        w[q] *= suf / den[q]
        suf *= a - (q - o)
    for q in range(T, _UV_TAPS_MAX):
        w[q] = 0.0
        idx[q] = idx[0]


@numba.njit(cache=True, inline="always")
def _taps_used(taps, n):
    """Lagrange points of a ``taps``-point stencil on an n-sample axis (an even number that
    fits; 1 on a single sample): the stencils' leading entries, the rest are zero."""
    return max(1, min(taps, n - n % 2))


@numba.njit(cache=True)
def _lagrange_dens(Nv, Nu, taps):
    """(2, _UV_TAPS_MAX): the Lagrange denominators Π_{m≠q} (q − m) of :func:`_lagrange_stencil` for
    the v and u axes (Nv, Nu samples; ``taps`` points at most)."""
    dens = np.ones((2, _UV_TAPS_MAX))
    for k, n in enumerate((Nv, Nu)):
        T = _taps_used(taps, n)
        for q in range(T):
            for m in range(T):
                if m != q:
                    dens[k, q] *= q - m
    return dens


@numba.njit(cache=True, inline="always")
def _moved_uv(us, vs, R, f, jv, ju):
    """Where the direction (vs[jv], us[ju]) moved by R samples its face: (fv, fu) in
    samples of the v and u axes, whether it lies inside them (and ahead), and its slopes
    d_x / d_z, d_y / d_z (0 when outside)."""
    Nv = vs.shape[0]
    Nu = us.shape[0]
    eps = 1e-6
    hv = (vs[Nv - 1] - vs[0]) / (Nv - 1) if Nv > 1 else 1.0
    hu = (us[Nu - 1] - us[0]) / (Nu - 1) if Nu > 1 else 1.0
    d0, d1, d2 = _face_direction(R, us[ju], vs[jv], f)
    good = d2 > 1e-9 * f
    dz = d2 if good else 1.0
    fv = (f * d1 / dz - vs[0]) / hv
    fu = (f * d0 / dz - us[0]) / hu
    if Nv > 1:
        good = good and fv > -eps and fv < Nv - 1 + eps
    if Nu > 1:
        good = good and fu > -eps and fu < Nu - 1 + eps
    return fv, fu, good, (d0 / dz if good else 0.0), (d1 / dz if good else 0.0)


@numba.njit(cache=True)
def _uv_stencil_row(us, vs, R, f, taps, dens, jv, wv, iv, wu, iu):
    """The Lagrange stencils of direction row jv (:func:`_uv_stencils`) into wv, wu (Nu, _UV_TAPS_MAX)
    float64 and iv, iu (Nu, _UV_TAPS_MAX) int64. Not inlined, and compiled without fast-math flags,
    so the weights are those of :func:`_uv_stencils` to the last bit wherever it is called."""
    for ju in range(us.shape[0]):
        fv, fu, _, _, _ = _moved_uv(us, vs, R, f, jv, ju)
        _lagrange_stencil(fv, vs.shape[0], taps, dens[0], wv[ju], iv[ju])
        _lagrange_stencil(fu, us.shape[0], taps, dens[1], wu[ju], iu[ju])


@numba.njit(parallel=True, cache=True)
def _uv_stencil_kernel(us, vs, R, f, taps, wv, iv, wu, iu, ok, sx, sy, weights):
    """:func:`_uv_stencils` into given arrays (us (Nu,), vs (Nv,) the sample values);
    without ``weights`` only ok, sx, sy (wv .. iu are not touched)."""
    Nv = vs.shape[0]
    Nu = us.shape[0]
    dens = _lagrange_dens(Nv, Nu, taps)
    for jv in numba.prange(Nv):
        if weights:
            _uv_stencil_row(us, vs, R, f, taps, dens, jv, wv[jv], iv[jv], wu[jv], iu[jv])
        for ju in range(Nu):
            _, _, good, slx, sly = _moved_uv(us, vs, R, f, jv, ju)
            ok[jv, ju] = good
            sx[jv, ju] = slx
            sy[jv, ju] = sly


def _uv_stencils(grid: LightFieldGrid, face, R: np.ndarray, taps: int, weights: bool = True):
    """Where each target direction (v, u) samples the source: the moved direction
    ``R (u, v, f)`` re-projected on the face's image plane depends on (u, v) only.

    Returns per-(v, u) Lagrange weights and clamped indices along v and u
    (``(Nv, Nu, _UV_TAPS_MAX)`` float64 / int64 each; fewer taps are padded with zero weights),
    ``ok_uv`` (Nv, Nu) bool and the moved direction's slopes d_x / d_z, d_y / d_z (Nv, Nu).
    Without ``weights`` the first four are None (:func:`_warp_rows_kernel` computes each
    row's stencils itself: 0.6 frames less memory at 128 x 128 directions).
    """
    us = np.ascontiguousarray(grid.u.values, dtype=np.float64)
    vs = np.ascontiguousarray(grid.v.values, dtype=np.float64)
    shape = (vs.size, us.size)
    st = shape + (_UV_TAPS_MAX,) if weights else (1, 1, _UV_TAPS_MAX)
    wv, wu = np.empty(st), np.empty(st)
    iv, iu = np.empty(st, np.int64), np.empty(st, np.int64)
    ok = np.empty(shape, bool)
    sx, sy = np.empty(shape), np.empty(shape)
    _uv_stencil_kernel(us, vs, np.ascontiguousarray(R, dtype=np.float64), float(face.f), int(taps),
                       wv, iv, wu, iu, ok, sx, sy, weights)
    return (wv, iv, wu, iu, ok, sx, sy) if weights else (None, None, None, None, ok, sx, sy)


@numba.njit(cache=True, inline="always")
def _uv_row(srcT, wv, iv, wu, iu, Ur, lanes, has_lanes, tv, tu):
    """Ur[u, m] = Σ_q Σ_r wv[u, q] wu[u, r] srcT[iv[u, q], iu[u, r], m] (srcT float32, or int16
    in its channels' units: :func:`_warp_into`): one direction row of
    the (u, v) part of the warp (up to 16 x 16 taps; stencils (Nu, _UV_TAPS_MAX) of :func:`_uv_stencil_row`),
    shared by all views. Views (and channels) are the innermost axis m of srcT (Nv, Nu, M)
    and Ur (Nu, M), so each tap is one vectorised multiply-add over all view images (M a
    multiple of 16: no scalar remainder). With ``has_lanes`` only the first lanes[u] (Nu,)
    lanes of direction u are computed (a multiple of 16 too), the others are 0. tv, tu: the
    taps in use along v and u (:func:`_taps_used`; the stencils' other entries are zero)."""
    Nu, M = Ur.shape
    for u in range(Nu):
        o = Ur[u]
        o[:] = 0.0
        mu = lanes[u] if has_lanes else M
        for q in range(tv):
            wq = wv[u, q]
            if wq == 0.0:
                continue
            row = srcT[iv[u, q]]
            for r in range(tu):
                w = np.float32(wq * wu[u, r])
                if w == 0.0:
                    continue
                s = row[iu[u, r]]
                for m in range(mu):
                    o[m] += w * np.float32(s[m])


@numba.njit(cache=True, inline="always")
def _xy_row(Uv, ok_uv, slope_x, slope_y, ax_, bx_, ay_, by_, face, jv, M, ratio, out, ok, fold, W0, has_w0, cq, crnd,
            nd_row, lag):
    """Row jv of every view of ``out`` (K, F, Ny, Nx, Nv, Nu): bilinear interpolation across
    viewpoints of the row's (u, v)-warped images Uv (Nu M,) ((Nu, M) flattened, M >= K Ny Nx:
    (K, Ny, Nx) flattened, then padding) at each moved ray's focal-plane point in grid units,
    fx = ax_ + bx_ slope_x, fy = ay_ + by_ slope_y (ax_ .. by_: (Ny, Nx) per view from its
    moved origin; slopes (Nv, Nu) per direction), times ``ratio[k]`` (K,) for channel k
    (:func:`_warp_into`; out float32 or int16: :func:`_store`); ok[face] (F, Ny, Nx, Nv, Nu;
    float32 or uint8) is 1 where the moved ray lies inside the grid, else 0 (and out 0).
    K = len(ratio) channels; with ``fold`` out holds channel 0 only and the others (a
    confidence W, and a "no data" indicator with K = 3) are folded into ok[face] (uint16)
    with the unwarped frame's ``W0`` (F, Ny, Nx, Nv, Nu, if ``has_w0``) by
    :func:`_folded_confidence` (``cq``, ``crnd``: its q, rnd, :func:`_confidence_units`);
    ``nd_row`` (Nu,) uint8 with K = 3: :func:`_nodata_runs` of the row (0: the indicator is 0
    in every view, so those directions blend as with K = 2). With ``lag`` 1 or 2 (``fold``, K = 2,
    out float32), ok[face] holds the folded confidences of an earlier warp, and a ray inside keeps
    its confidence when it is not 0: only L is blended, and W only for the rays inside without
    one (scalar, as K = 1) (:func:`_warp_into`'s ``lag_confidence``). The rays outside get 0
    with ``lag`` 1; with 2 they keep their confidence and get L = _OUTSIDE, for
    :func:`_extrapolate_xy_kernel`, which fills or clears each of them.

    The blend loops are scalar: their stores to ``out`` keep LLVM from vectorising them
    (:func:`_stack_buffer`), and scalar loads are faster than gathers here for one channel
    (measured: vectorised through a stack buffer, the one-channel warp took 6.4 ms against
    5.6 ms, 9 x 9 views x 128 x 128 directions, 2 cores). With two or three folded channels
    the position, weights and confidence arithmetic per ray outweighs that: those blend a
    run of at most _CHUNK directions (of one ``nd_row`` value) into stack buffers
    (vectorised, gathers), then store it
    (10.0 -> 7.5 ms the warp with W and W0; the same values, bit for bit)."""
    K = ratio.shape[0]
    _, _, Ny, Nx = out.shape[:4]
    Nu = out.shape[5]
    eps = 1e-6
    bx_max = numba.uint64(max(Nx - 2, 0))
    by_max = numba.uint64(max(Ny - 2, 0))
    dx1 = numba.uint64(1 if Nx > 1 else 0)
    dy1 = numba.uint64(Nx if Ny > 1 else 0)
    hi_x = Nx - 1 + eps
    hi_y = Ny - 1 + eps
    cx = np.float64(Nx - 1)
    cy = np.float64(Ny - 1)
    nxy = numba.uint64(Ny * Nx)
    nm = numba.uint64(M)
    unx = numba.uint64(Nx)
    sxr = slope_x[jv]
    syr = slope_y[jv]
    okr = ok_uv[jv]
    lim = (eps, hi_x, hi_y, cx, cy)
    ib_max = (bx_max, by_max)
    b0 = numba.carray(_stack_f64(_CHUNK), _CHUNK)      # a chunk's L (folded channels)
    bc = numba.carray(_stack_i32(_CHUNK), _CHUNK)      # and its confidences
    for jy in range(Ny):
        for ix in range(Nx):
            a_x = ax_[jy, ix]
            b_x = bx_[jy, ix]
            a_y = ay_[jy, ix]
            b_y = by_[jy, ix]
            okrow = ok[face, jy, ix, jv]
            if fold:
                # the confidence channels share each ray's position and weights with L in one
                # pass (one loop per channel count: a branch inside would stop the vectorisation
                # of the chunked loops; each value is computed before the _store call: numba
                # 0.68 stored zeros for a second channel when the conditional expression was
                # _store's argument)
                w0row = W0[face, jy, ix, jv] if has_w0 else W0[0, 0, 0, 0]
                o0 = out[0, face, jy, ix, jv]
                r0 = ratio[0]
                r1 = ratio[min(1, K - 1)]
                r2 = ratio[min(2, K - 1)]
                c1 = nxy
                c2 = nxy + nxy
                if K == 1:
                    for iu in range(numba.uint64(Nu)):
                        o, wx, wy, good = _xy_position(a_x, b_x, a_y, b_y, sxr, syr, okr, iu, lim, ib_max, unx, nm)
                        x0 = _bilinear(Uv, o, dx1, dy1, wx, wy) * r0 if good else 0.0
                        _store(o0, iu, x0)
                        okrow[iu] = _folded_confidence(good, np.float32(1.0), np.float32(0.0), w0row[iu], cq, crnd)
                elif lag:
                    for iu in range(numba.uint64(Nu)):
                        o, wx, wy, good = _xy_position(a_x, b_x, a_y, b_y, sxr, syr, okr, iu, lim, ib_max, unx, nm)
                        x0 = _bilinear(Uv, o, dx1, dy1, wx, wy) * r0 if good else 0.0
                        _store(o0, iu, x0)
                        if not good:
                            if lag == 2:
                                o0[iu] = _OUTSIDE
                            else:
                                okrow[iu] = 0
                        elif okrow[iu] == 0:
                            x1 = np.float32(_bilinear(Uv, o + c1, dx1, dy1, wx, wy) * r1)
                            okrow[iu] = _folded_confidence(True, x1, np.float32(0.0), w0row[iu], cq, crnd)
                else:
                    # two or three channels: a chunk of directions at a time, blended into the
                    # stack buffers (vectorised), then stored
                    s = 0
                    while s < Nu:
                        # a run of at most _CHUNK directions whose "no data" channel is all zero
                        # (nd_row 0: blended as K = 2, the same values) or not
                        z = nd_row[s] if K == 3 else 0
                        e = s + 1
                        e_max = min(s + _CHUNK, Nu)
                        while e < e_max and (K == 2 or nd_row[e] == z):
                            e += 1
                        n = numba.uint64(e - s)
                        us = numba.uint64(s)
                        s = e
                        if z == 0:
                            for i in range(n):
                                o, wx, wy, good = _xy_position(a_x, b_x, a_y, b_y, sxr, syr, okr, us + i, lim, ib_max,
                                                               unx, nm)
                                b0[i] = _bilinear(Uv, o, dx1, dy1, wx, wy) * r0 if good else 0.0
                                x1 = np.float32(_bilinear(Uv, o + c1, dx1, dy1, wx, wy) * r1 if good else 0.0)
                                bc[i] = _folded_confidence(good, x1, np.float32(0.0), w0row[us + i], cq, crnd)
                        else:
                            for i in range(n):
                                o, wx, wy, good = _xy_position(a_x, b_x, a_y, b_y, sxr, syr, okr, us + i, lim, ib_max,
                                                               unx, nm)
                                b0[i] = _bilinear(Uv, o, dx1, dy1, wx, wy) * r0 if good else 0.0
                                x1 = np.float32(_bilinear(Uv, o + c1, dx1, dy1, wx, wy) * r1 if good else 0.0)
                                x2 = np.float32(_bilinear(Uv, o + c2, dx1, dy1, wx, wy) * r2 if good else 0.0)
                                bc[i] = _folded_confidence(good, x1, x2, w0row[us + i], cq, crnd)
                        for i in range(n):
                            v = b0[i]
                            _store(o0, us + i, v)
                        for i in range(n):
                            okrow[us + i] = bc[i]
                continue
            for k in range(K):
                orow = out[k, face, jy, ix, jv]
                rk = ratio[k]
                c = numba.uint64(k) * nxy
                for iu in range(numba.uint64(Nu)):
                    o, wx, wy, good = _xy_position(a_x, b_x, a_y, b_y, sxr, syr, okr, iu, lim, ib_max, unx, nm)
                    x = _bilinear(Uv, o + c, dx1, dy1, wx, wy) * rk if good else 0.0
                    _store(orow, iu, x)
                    okrow[iu] = 1.0 if good else 0.0


_ND_RUN = 16
"""Zero runs of the "no data" flags shorter than this are marked as data (:func:`_nodata_runs`)."""


@numba.njit(cache=True, inline="always")
def _nodata_runs(Ur, m0, n, lanes, nd):
    """nd (Nu,) uint8: 0 where the (u, v)-warped "no data" channel Ur[u, m0:m0 + n] (Ur (Nu, M))
    is 0 in every view (the folded warp blends those directions as with K = 2, the same
    values: :func:`_xy_row`, :func:`_extrapolate_xy_kernel`), else 1; a run of zeros shorter
    than _ND_RUN between ones is set to 1 too, so that the blend's runs of either kind
    are not too short to vectorise. Directions whose (u, v) warp left the channel out
    (lanes[u] < M, :func:`_uv_row`) are 0 without a look."""
    Nu, M = Ur.shape
    for u in range(Nu):
        if lanes[u] < M:
            nd[u] = 0
            continue
        r = Ur[u]
        f = False
        for m in range(m0, m0 + n):
            f |= r[m] != 0.0
        nd[u] = f
    u = 0
    while u < Nu:
        if nd[u] != 0:
            u += 1
            continue
        e = u
        while e < Nu and nd[e] == 0:
            e += 1
        if e - u < _ND_RUN and (u > 0 or e < Nu):
            for i in range(u, e):
                nd[i] = 1
        u = e


@numba.njit(cache=True, inline="always")
def _xy_position(a_x, b_x, a_y, b_y, sxr, syr, okr, iu, lim, ib_max, unx, nm):
    """Where the moved ray of direction iu of a view falls among the viewpoints
    (:func:`_xy_row`): its offset in the (u, v)-warped row Uv of channel 0 (lower-left view
    by, bx), the bilinear weights wx, wy and whether it lies inside (and ``okr[iu]``).
    ``lim`` = (eps, hi_x, hi_y, cx, cy); ``ib_max`` = (bx_max, by_max). Branch-free with
    unsigned indices, so that a loop of the caller's can vectorise (gathers)."""
    eps, hi_x, hi_y, cx, cy = lim
    fx = a_x + b_x * sxr[iu]
    fy = a_y + b_y * syr[iu]
    good = okr[iu] & (fx > -eps) & (fx < hi_x) & (fy > -eps) & (fy < hi_y)
    fx = min(max(fx, 0.0), cx)
    fy = min(max(fy, 0.0), cy)
    bx = min(numba.uint64(fx), ib_max[0])
    by = min(numba.uint64(fy), ib_max[1])
    wx = min(fx - bx, 1.0)
    wy = min(fy - by, 1.0)
    return iu * nm + by * unx + bx, wx, wy, good


@numba.njit(cache=True, inline="always")
def _folded_confidence(good, w, nodata, w0, c_unit, c_rnd):
    """The motion solver's confidence c of a warped ray as stored in its uint16 ``conf``:
    c c_unit + c_rnd (q, rnd of :func:`_confidence_units`) truncated, as int32 (a signed
    conversion vectorises; the store truncates it to uint16): 0 outside the grid (not
    ``good``), else the warped W clipped to [0, 1], 0 where the warped "no data" indicator
    is not 0, times frame 1's confidence w0 (:func:`_weight_confidence`). What
    :func:`_apply_warped_confidence` does after the warp, folded into it (``_warp_into``'s
    ``confidence_channels``)."""
    wf = min(max(w, np.float32(0.0)), np.float32(1.0))
    c = (np.float32(1.0) if good else np.float32(0.0)) * (wf * (np.float32(1.0) if abs(nodata) < 1e-6
                                                                   else np.float32(0.0)))
    return np.int32(c * _weight_confidence(w0) * c_unit + c_rnd)


@numba.njit(cache=True, inline="always")
def _bilinear(Uv, o, dx1, dy1, wx, wy):
    """The bilinear blend of Uv at o, o + dx1, o + dy1, o + dy1 + dx1 (weights wx along dx1, wy along dy1)."""
    return ((1.0 - wy) * ((1.0 - wx) * Uv[o] + wx * Uv[o + dx1])
            + wy * ((1.0 - wx) * Uv[o + dy1] + wx * Uv[o + dy1 + dx1]))


@numba.njit(parallel=True, cache=True, fastmath=_FASTMATH)
def _warp_rows_kernel(srcT, us, vs, R, f, taps, ok_uv, slope_x, slope_y, ax_, bx_, ay_, by_, face, ratio, out, ok,
                      slot, E, edges, fold, W0, has_w0, cq, crnd, ND, S, lag):
    """The warp of face ``face`` of ``out`` (K, F, Ny, Nx, Nv, Nu), one direction row v at a
    time: the row's (u, v) stencils (:func:`_uv_stencil_row`; us (Nu,), vs (Nv,) the sample
    values, R (3, 3) the ray rotation in face coordinates, f the focal length) and its
    (u, v)-warped images of all views (:func:`_uv_row`, from srcT (Nv, Nu, M), views
    innermost) stay in a per-thread scratch (Nu, M) while :func:`_xy_row` blends them
    across viewpoints (no (Nv, Nu, M) intermediate: 1.2 frames less memory, and read from
    cache). With ``edges`` the edge views' rows are copied to E (Nv, K, P, Nu), directions
    innermost, at their ``slot`` (Ny Nx,) (:func:`_perimeter`), for
    :func:`_extrapolate_xy_kernel` (in srcT's units: ``ratio`` (K,) as :func:`_xy_row`).
    ``fold`` .. ``crnd``: as :func:`_xy_row`. With ``fold`` and K = 3, ND (Nv, Nu) uint8 gets
    :func:`_nodata_runs` of each row (else a dummy (1, Nu)), and the (u, v) warp leaves the
    "no data" channel out (it is 0) where no tap of a direction's stencil lies on a
    direction with samples without data in some view: S (Nv + 1, Nu + 1) int32 counts them
    (a summed-area table: S[v, u] = their number in rows < v, columns < u). ``lag``: as
    :func:`_xy_row`."""
    K = ratio.shape[0]
    _, _, Ny, Nx = out.shape[:4]
    Nv, Nu, M = srcT.shape
    nxy = Ny * Nx
    has_nd = fold and K == 3
    m2 = min(-(-2 * nxy // 16) * 16, M)           # the lanes of L and W (padded as _padded)
    dens = _lagrange_dens(Nv, Nu, taps)
    chunks = min(Nv, 32)
    for c in numba.prange(chunks):
        # (the int64 cast: one specialisation of the worker, not an int64 and a uint64 one)
        _warp_rows_chunk(np.int64(c), chunks, srcT, us, vs, R, f, taps, ok_uv, slope_x, slope_y, ax_, bx_, ay_, by_,
                         face, ratio, out, ok, slot, E, edges, fold, W0, has_w0, cq, crnd, ND, S, dens, m2, has_nd,
                         lag)


@numba.njit(cache=True, fastmath=_FASTMATH)
def _warp_rows_chunk(c, chunks, srcT, us, vs, R, f, taps, ok_uv, slope_x, slope_y, ax_, bx_, ay_, by_, face, ratio, out,
                     ok, slot, E, edges, fold, W0, has_w0, cq, crnd, ND, S, dens, m2, has_nd, lag):
    """Chunk c of ``chunks`` of :func:`_warp_rows_kernel`'s direction rows (serial: the
    parallel kernel only distributes the chunks, which keeps its compilation short)."""
    K = ratio.shape[0]
    _, _, Ny, Nx = out.shape[:4]
    Nv, Nu, M = srcT.shape
    nxy = Ny * Nx
    Ur = np.empty((Nu, M), np.float32)
    Uv = Ur.reshape(Nu * M)
    wv = np.empty((Nu, _UV_TAPS_MAX))
    wu = np.empty((Nu, _UV_TAPS_MAX))
    iv = np.empty((Nu, _UV_TAPS_MAX), np.int64)
    iu = np.empty((Nu, _UV_TAPS_MAX), np.int64)
    lanes = np.full(Nu if has_nd else 1, M, np.int64)     # (one allocation less without)
    tv = _taps_used(taps, Nv)
    tu = _taps_used(taps, Nu)
    for jv in range(c * Nv // chunks, (c + 1) * Nv // chunks):
        _uv_stencil_row(us, vs, R, f, taps, dens, jv, wv, iv, wu, iu)
        if has_nd:
            for u in range(Nu):                  # the stencil's box of taps
                v0 = v1 = iv[u, 0]
                u0 = u1 = iu[u, 0]
                for q in range(1, max(tv, tu)):     # (unused entries repeat entry 0)
                    v0 = min(v0, iv[u, q])
                    v1 = max(v1, iv[u, q])
                    u0 = min(u0, iu[u, q])
                    u1 = max(u1, iu[u, q])
                n_nd = S[v1 + 1, u1 + 1] - S[v0, u1 + 1] - S[v1 + 1, u0] + S[v0, u0]
                lanes[u] = M if n_nd > 0 else m2
        _uv_row(srcT, wv, iv, wu, iu, Ur, lanes, has_nd, tv, tu)
        if edges:
            for k in range(K):
                for view in range(nxy):
                    p = slot[view]
                    if p < 0:
                        continue
                    row = E[jv, k, p]
                    for u in range(Nu):
                        row[u] = Ur[u, k * nxy + view]
        if has_nd:
            _nodata_runs(Ur, 2 * nxy, nxy, lanes, ND[jv])
        _xy_row(Uv, ok_uv, slope_x, slope_y, ax_, bx_, ay_, by_, face, jv, M, ratio, out, ok, fold, W0, has_w0,
                cq, crnd, ND[jv if has_nd else 0], lag)


def _perimeter(Ny: int, Nx: int) -> np.ndarray:
    """(Ny Nx,) int64: each view's slot among the views on the array's edge (row 0 or
    Ny - 1, column 0 or Nx - 1), in view order; -1 inside. Eq. 6 extrapolation reads only
    these (:func:`_extrapolate_xy_kernel`)."""
    jy, ix = np.divmod(np.arange(Ny * Nx), Nx)
    edge = (jy == 0) | (jy == Ny - 1) | (ix == 0) | (ix == Nx - 1)
    slot = np.full(Ny * Nx, -1, np.int64)
    slot[edge] = np.arange(int(edge.sum()))
    return slot


@numba.njit(cache=True, inline="always")
def _edge_sample(Ef, K, P, Nu, Nv, p, jv, iu, su, sv, ok_uv, wu, wv):
    """(value, ok): channel 0 of edge view ``p``'s (u, v)-warped image in Ef (the flat E of
    :func:`_extrapolate_xy_kernel`) at direction (jv, iu) shifted by (sv, su) samples (4-point
    Lagrange along an axis with a shift, :func:`_shift_stencil`); not ok where a node leaves the
    directions or is not ``ok_uv``. wu, wv: (4,) scratch."""
    tu, ou = _shift_stencil(iu, su, Nu, wu)
    tv, ov = _shift_stencil(jv, sv, Nv, wv)
    if tu == 0 or tv == 0:
        return 0.0, False
    val = 0.0
    for q in range(tv):
        acc = 0.0
        for t in range(tu):
            if not ok_uv[ov + q, ou + t]:
                return 0.0, False
            acc += wu[t] * Ef[(((ov + q) * K) * P + p) * Nu + ou + t]
        val += wv[q] * acc
    return val, True


@numba.njit(parallel=True, cache=True, fastmath=_FASTMATH)
def _extrapolate_xy_kernel(E, slot, ok_uv, slope_x, slope_y, ax_, bx_, ay_, by_, face, rho, kx, ky,
                           e_max_x, e_max_y, ratio, out, ok, marks, has_marks, fold, W0, has_w0, cq, crnd, ND, lag,
                           along=False):
    """Fill the rays :func:`_warp_rows_kernel` left empty because their moved focal-plane point
    lies outside the viewpoints' range, by at most ``e_max_x``, ``e_max_y`` view steps along x and y
    (inf: the single-view axis of a linear array), from the nearest edge viewpoint(s) by paper Eq. 6:
    on a Lambertian surface the ray from
    ``x_e + d`` along u is the ray from ``x_e`` along ``u + ρ d`` (ρ = f / Z, u per unit x),
    so the value is the edge view's (u, v)-warped image read at the direction shifted by
    ``(e_x kx ρ, e_y ky ρ)`` samples (e in view steps beyond the edge, kx = step_x / step_u,
    ky = step_y / step_v), 4-point Lagrange along the axis (or axes) that extrapolate (rays
    whose nodes leave the directions stay empty), linear along the array's edge between
    the two nearest edge views (one view at a corner).
    ``E`` (Nv, K, P, Nu): the edge views' (u, v)-warped images (:func:`_warp_rows_kernel`),
    ``slot`` (Ny Nx,) each view's index in E (:func:`_perimeter`). ``rho`` (Nv, Nu): the
    disparity per direction of face ``face`` (NaN: unknown, the ray stays empty). Other
    arguments (``ratio`` and ``fold`` .. ``crnd`` included) as :func:`_xy_row`; ``ok`` gets 1
    where filled (the folded confidence with ``fold``; a ray inside the grid whose folded
    confidence is 0 is then not skipped by its ``ok``, but its moved point lies inside, so
    it is not filled — unless it lies within the inside test's 1e-6 of the edge, where the
    edge view refills it with the same value), and with ``has_marks`` so does ``marks``
    (F, Ny, Nx, Nv, Nu) (else a dummy). With ``fold`` and K = 3, the "no data" channel is
    left at 0 where ND (Nv, Nu) (:func:`_warp_rows_kernel`) is 0 at every node: it is 0
    there. With ``lag`` (:func:`_xy_row`'s ``lag`` 2) the rays to fill are those whose L is
    _OUTSIDE: each is filled, keeping its confidence in ok when that is not 0 (only L is
    extrapolated for it), or else cleared (L and ok 0). With ``along`` (the warp's blend along the
    disparity, :func:`_depth_views_kernel`) L's blend between the two edge views is along the
    disparity too: each read at its own shift along the edge, ``ρ k (c − b)`` for the view at b and
    the point at c (where a node of that leaves the directions, the plain blend stays)."""
    K = ratio.shape[0]
    has_nd = fold and K == 3
    _, _, Ny, Nx = out.shape[:4]
    Nv, _, P, Nu = E.shape
    Ef = E.reshape(E.size)
    KPN = K * P * Nu
    for jv in numba.prange(Nv):
        wu = np.empty(4)
        wv = np.empty(4)
        wa = np.empty(4)                              # (along: _edge_sample's stencils)
        wb = np.empty(4)
        vals = np.zeros(3, np.float32)                # fold: the confidence channels' values
        vals[1] = 1.0                                 # (W = 1 when there is none: K = 1)
        for jy in range(Ny):
            for ix in range(Nx):
                okrow = ok[face, jy, ix, jv]
                orow = out[0, face, jy, ix, jv]
                w0row = W0[face, jy, ix, jv] if has_w0 else W0[0, 0, 0, 0]
                for iu in range(Nu):
                    keep = 0
                    if lag:
                        if orow[iu] != _OUTSIDE:
                            continue
                        keep = okrow[iu]            # the earlier warp's confidence (0: none)
                        orow[iu] = 0                # cleared unless filled below
                        okrow[iu] = 0
                    elif okrow[iu] > 0.0:
                        continue
                    r = rho[jv, iu]
                    if not ok_uv[jv, iu] or not r == r:
                        continue
                    fx = ax_[jy, ix] + bx_[jy, ix] * slope_x[jv, iu]
                    fy = ay_[jy, ix] + by_[jy, ix] * slope_y[jv, iu]
                    cx = min(max(fx, 0.0), Nx - 1.0)
                    cy = min(max(fy, 0.0), Ny - 1.0)
                    ex = fx - cx
                    ey = fy - cy
                    if abs(ex) > e_max_x or abs(ey) > e_max_y or (ex == 0.0 and ey == 0.0):
                        continue
                    # 4-point Lagrange along an axis that extrapolates (linear interpolation of a
                    # sub-sample shift errs by a large fraction of it on sharp images), nodes
                    # inside the grid; the axis that does not keeps its own sample
                    tu, ou = _shift_stencil(iu, ex * kx * r, Nu, wu)
                    tv, ov = _shift_stencil(jv, ey * ky * r, Nv, wv)
                    if tu == 0 or tv == 0:
                        continue
                    # the two edge views the clamped point lies between (one at a corner:
                    # ex, ey both nonzero put it on a view)
                    if ex != 0.0:
                        b0 = min(int(cy), max(Ny - 2, 0))
                        w1 = cy - b0 if Ny > 1 else 0.0
                        p0 = slot[b0 * Nx + int(cx)]
                        p1 = slot[min(b0 + 1, Ny - 1) * Nx + int(cx)]
                    else:
                        b0 = min(int(cx), max(Nx - 2, 0))
                        w1 = cx - b0 if Nx > 1 else 0.0
                        p0 = slot[int(cy) * Nx + b0]
                        p1 = slot[int(cy) * Nx + min(b0 + 1, Nx - 1)]
                    w0 = 1.0 - w1
                    if tv == 1:                          # along u only (the common case) or no shift
                        okr = ok_uv[ov]
                        if tu == 4:
                            if not (okr[ou] and okr[ou + 1] and okr[ou + 2] and okr[ou + 3]):
                                continue
                        elif not okr[ou]:
                            continue
                        for k in range(1 if keep > 0 else _channels(K, has_nd, ND, vals, ov, ou, 1, tu)):
                            o0 = ((ov * K + k) * P + p0) * Nu + ou
                            o1 = ((ov * K + k) * P + p1) * Nu + ou
                            if tu == 4:
                                val = (wu[0] * (w0 * Ef[o0] + w1 * Ef[o1])
                                       + wu[1] * (w0 * Ef[o0 + 1] + w1 * Ef[o1 + 1])
                                       + wu[2] * (w0 * Ef[o0 + 2] + w1 * Ef[o1 + 2])
                                       + wu[3] * (w0 * Ef[o0 + 3] + w1 * Ef[o1 + 3]))
                            else:
                                val = w0 * Ef[o0] + w1 * Ef[o1]
                            _put_channel(out, vals, fold, k, (face, jy, ix, jv, iu), val * ratio[k])
                    elif tu == 1:                        # along v only
                        if not (ok_uv[ov, ou] and ok_uv[ov + 1, ou] and ok_uv[ov + 2, ou] and ok_uv[ov + 3, ou]):
                            continue
                        for k in range(1 if keep > 0 else _channels(K, has_nd, ND, vals, ov, ou, 4, 1)):
                            o0 = ((ov * K + k) * P + p0) * Nu + ou
                            o1 = ((ov * K + k) * P + p1) * Nu + ou
                            _put_channel(out, vals, fold, k, (face, jy, ix, jv, iu), ratio[k] * (
                                wv[0] * (w0 * Ef[o0] + w1 * Ef[o1])
                                + wv[1] * (w0 * Ef[o0 + KPN] + w1 * Ef[o1 + KPN])
                                + wv[2] * (w0 * Ef[o0 + 2 * KPN] + w1 * Ef[o1 + 2 * KPN])
                                + wv[3] * (w0 * Ef[o0 + 3 * KPN] + w1 * Ef[o1 + 3 * KPN])))
                    else:                                # both axes (a corner's diagonal)
                        good = True
                        for q in range(4):
                            for t in range(4):
                                good = good and ok_uv[ov + q, ou + t]
                        if not good:
                            continue
                        for k in range(1 if keep > 0 else _channels(K, has_nd, ND, vals, ov, ou, 4, 4)):
                            o0 = ((ov * K + k) * P + p0) * Nu + ou
                            o1 = ((ov * K + k) * P + p1) * Nu + ou
                            val = 0.0
                            for q in range(4):
                                acc = 0.0
                                for t in range(4):
                                    acc += wu[t] * (w0 * Ef[o0 + q * KPN + t] + w1 * Ef[o1 + q * KPN + t])
                                val += wv[q] * acc
                            _put_channel(out, vals, fold, k, (face, jy, ix, jv, iu), val * ratio[k])
                    if along and w0 != 0.0 and w1 != 0.0:
                        # L along the disparity: the edge views at their own shifts along the edge
                        if ex != 0.0:
                            su0 = su1 = ex * kx * r
                            sv0, sv1 = w1 * ky * r, -w0 * ky * r
                        else:
                            su0, su1 = w1 * kx * r, -w0 * kx * r
                            sv0 = sv1 = ey * ky * r
                        v0, g0 = _edge_sample(Ef, K, P, Nu, Nv, p0, jv, iu, su0, sv0, ok_uv, wa, wb)
                        v1, g1 = _edge_sample(Ef, K, P, Nu, Nv, p1, jv, iu, su1, sv1, ok_uv, wa, wb)
                        if g0 and g1:
                            _put_channel(out, vals, fold, 0, (face, jy, ix, jv, iu), (w0 * v0 + w1 * v1) * ratio[0])
                    if keep > 0:
                        okrow[iu] = keep
                    elif fold:
                        okrow[iu] = _folded_confidence(True, vals[1], vals[2], w0row[iu], cq, crnd)
                    else:
                        okrow[iu] = 1.0
                    if has_marks:
                        marks[face, jy, ix, jv, iu] = 1


@numba.njit(cache=True, inline="always")
def _depth_views_dims(out, srcT, taps):
    """(Ny, Nx, Nv, Nu, M, dens, tv, tu) of :func:`_depth_views_kernel`'s arguments: the grid's and
    srcT's dims, the Lagrange denominators (:func:`_lagrange_dens`) and the taps used along v, u."""
    _, _, Ny, Nx = out.shape[:4]
    Nv, Nu, M = srcT.shape
    return Ny, Nx, Nv, Nu, M, _lagrange_dens(Nv, Nu, taps), _taps_used(taps, Nv), _taps_used(taps, Nu)


@numba.njit(parallel=True, cache=True, fastmath=_FASTMATH)
def _depth_views_exact_kernel(srcT, us, vs, R, f, taps, ok_uv, slope_x, slope_y, ax_, bx_, ay_, by_, face, rho, kx,
                              ky, r0, out):
    """Channel 0 (L) of face ``face`` of ``out`` (K, F, Ny, Nx, Nv, Nu) again at every ray whose moved
    focal-plane point lies inside the viewpoints, blended across the (up to) four viewpoints around
    that point *along the direction's disparity* instead of at one direction: by paper Eq. 6 the ray
    from ``x'`` along ``u'`` is, on a Lambertian surface, the ray from the neighbouring view ``x_n``
    along ``u' + ρ (x' − x_n)`` (ρ = f / Z, u per unit x), so each neighbour is read at its own
    direction (``uv_taps``-point Lagrange from srcT (Nv, Nu, M), views innermost, channel 0 at
    m = view) and the bilinear weights blend four samples of one scene point. Linear interpolation
    across views a sample or more of disparity apart blends different scene points: at the
    converged estimate the warped frame then lags the true motion, which the solve makes up by a
    long translation (docs/motion.md, "Camera arrays"). ``rho`` (Nv, Nu): ρ per direction of this
    face (NaN: unknown, the ray keeps the plain blend); ``kx``, ``ky``: view step over (u, v) step;
    ``r0``: channel 0's ``ratio``; positions and arguments otherwise as :func:`_xy_row`. A ray whose
    shifted direction leaves the (u, v) samples keeps the plain blend too. Every ray's own
    stencils, one view sample at a time: the reference of :func:`_depth_views_kernel`."""
    Ny, Nx, Nv, Nu, M, dens, tv, tu = _depth_views_dims(out, srcT, taps)
    eps = 1e-6
    for jv in numba.prange(Nv):
        wv, wu, iv, iu = _stencil_scratch()
        for ju in range(Nu):
            r = rho[jv, ju]
            if not ok_uv[jv, ju] or not r == r:
                continue
            fv, fu, _, _, _ = _moved_uv(us, vs, R, f, jv, ju)
            for jy in range(Ny):
                for ix in range(Nx):
                    fx = ax_[jy, ix] + bx_[jy, ix] * slope_x[jv, ju]
                    fy = ay_[jy, ix] + by_[jy, ix] * slope_y[jv, ju]
                    if not (fx > -eps and fx < Nx - 1 + eps and fy > -eps and fy < Ny - 1 + eps):
                        continue
                    fx = min(max(fx, 0.0), Nx - 1.0)
                    fy = min(max(fy, 0.0), Ny - 1.0)
                    bx = min(int(fx), max(Nx - 2, 0))
                    by = min(int(fy), max(Ny - 2, 0))
                    wx = fx - bx if Nx > 1 else 0.0
                    wy = fy - by if Ny > 1 else 0.0
                    acc = 0.0
                    inside = True
                    for cy in range(2 if Ny > 1 else 1):
                        for cx in range(2 if Nx > 1 else 1):
                            w = (wx if cx else 1.0 - wx) * (wy if cy else 1.0 - wy)
                            if w == 0.0:
                                continue
                            su = fu + r * kx * (fx - (bx + cx)) if Nu > 1 else 0.0
                            sv = fv + r * ky * (fy - (by + cy)) if Nv > 1 else 0.0
                            if su < -eps or su > Nu - 1 + eps or sv < -eps or sv > Nv - 1 + eps:
                                inside = False
                                break
                            _lagrange_stencil(sv, Nv, taps, dens[0], wv, iv)
                            _lagrange_stencil(su, Nu, taps, dens[1], wu, iu)
                            m = (by + cy) * Nx + bx + cx
                            val = 0.0
                            for q in range(tv):
                                row = srcT[iv[q]]
                                a = 0.0
                                for t in range(tu):
                                    a += wu[t] * np.float32(row[iu[t], m])
                                val += wv[q] * a
                            acc += w * val
                        if not inside:
                            break
                    if inside:
                        _store(out[0, face, jy, ix, jv], ju, acc * r0)


@numba.njit(parallel=True, cache=True, fastmath=_FASTMATH)
def _depth_views_kernel(srcT, us, vs, R, f, taps, ok_uv, slope_x, slope_y, ax_, bx_, ay_, by_, face, rho, kx, ky,
                        r0, out):
    """:func:`_depth_views_exact_kernel` (same arguments and result up to the shift below) with the
    (u, v) interpolation vectorised over the views, as :func:`_uv_row`: the moved ray of view
    (jy, ix) along direction (v, u) falls at ``(ix + δx, jy + δy)`` among the viewpoints, and its
    four neighbours are the views at offsets ``(ox + c, oy + r)``, c, r ∈ {0, 1}, each read at the
    moved direction shifted by ``ρ (kx (δx − ox − c), ky (δy − oy − r))`` samples. δ changes from
    view to view only through the rotation's moved origins (by ~ω times the array's extent in view
    steps: 0.01 view steps for 0.2 deg over 4 cm), so the shifts are taken at the central view's
    δ for every view of a direction, ``(ox, oy)`` = its floor: then a neighbour role's stencil is one
    per direction and each of the four roles is one vectorised multiply-add per tap over all view
    images (the shift's error: ρ times that change, ~0.01 samples at a disparity of one sample per
    view step). Each view keeps its own bilinear weights (from its own δ, which may pass 0 or 1 by
    that change: a tiny linear extrapolation); a ray whose neighbours leave the views, or whose
    shifted directions leave the (u, v) samples, keeps the plain blend."""
    Ny, Nx, Nv, Nu, M, dens, tv, tu = _depth_views_dims(out, srcT, taps)
    eps = 1e-6
    nr_x = 2 if Nx > 1 else 1
    nr_y = 2 if Ny > 1 else 1
    cy0, cx0 = Ny // 2, Nx // 2
    m1 = min(-(-Ny * Nx // 16) * 16, M)            # L's lanes (padded as _padded): the other channels are not read
    chunks = min(Nv, 32)
    for c in numba.prange(chunks):
        U = np.empty((4, Nu, M), np.float32)        # the four roles' (u, v)-shifted view images of a row
        wv = np.empty((4, Nu, _UV_TAPS_MAX))
        wu = np.empty((4, Nu, _UV_TAPS_MAX))
        iv = np.empty((4, Nu, _UV_TAPS_MAX), np.int64)
        iu = np.empty((4, Nu, _UV_TAPS_MAX), np.int64)
        lanes = np.zeros(Nu, np.int64)
        ox = np.zeros(Nu, np.int64)
        oy = np.zeros(Nu, np.int64)
        for jv in range(c * Nv // chunks, (c + 1) * Nv // chunks):
            any_valid = False
            for ju in range(Nu):
                r = rho[jv, ju]
                lanes[ju] = 0
                if not ok_uv[jv, ju] or not r == r:
                    continue
                fv, fu, _, _, _ = _moved_uv(us, vs, R, f, jv, ju)
                dx = ax_[cy0, cx0] + bx_[cy0, cx0] * slope_x[jv, ju] - cx0 if Nx > 1 else 0.0
                dy = ay_[cy0, cx0] + by_[cy0, cx0] * slope_y[jv, ju] - cy0 if Ny > 1 else 0.0
                ox[ju] = math.floor(dx)
                oy[ju] = math.floor(dy)
                good = True
                for rr in range(nr_y):
                    for cc in range(nr_x):
                        q = rr * 2 + cc
                        su = fu + r * kx * (dx - ox[ju] - cc) if Nu > 1 else 0.0
                        sv = fv + r * ky * (dy - oy[ju] - rr) if Nv > 1 else 0.0
                        good = good and su > -eps and su < Nu - 1 + eps and sv > -eps and sv < Nv - 1 + eps
                        _lagrange_stencil(sv, Nv, taps, dens[0], wv[q, ju], iv[q, ju])
                        _lagrange_stencil(su, Nu, taps, dens[1], wu[q, ju], iu[q, ju])
                if good:
                    lanes[ju] = m1
                    any_valid = True
            if not any_valid:
                continue
            for rr in range(nr_y):
                for cc in range(nr_x):
                    q = rr * 2 + cc
                    _uv_row(srcT, wv[q], iv[q], wu[q], iu[q], U[q], lanes, True, tv, tu)
            for jy in range(Ny):
                for ix in range(Nx):
                    orow = out[0, face, jy, ix, jv]
                    a_x = ax_[jy, ix]
                    b_x = bx_[jy, ix]
                    a_y = ay_[jy, ix]
                    b_y = by_[jy, ix]
                    for ju in range(Nu):
                        if lanes[ju] == 0:
                            continue
                        fx = a_x + b_x * slope_x[jv, ju]
                        fy = a_y + b_y * slope_y[jv, ju]
                        if not (fx > -eps and fx < Nx - 1 + eps and fy > -eps and fy < Ny - 1 + eps):
                            continue
                        vx = ix + ox[ju]                    # the lower neighbour's view
                        vy = jy + oy[ju]
                        if vx < 0 or vx + nr_x - 1 > Nx - 1 or vy < 0 or vy + nr_y - 1 > Ny - 1:
                            continue
                        wx = fx - vx if Nx > 1 else 0.0
                        wy = fy - vy if Ny > 1 else 0.0
                        m = vy * Nx + vx
                        acc = (1.0 - wy) * ((1.0 - wx) * U[0, ju, m] + (wx * U[1, ju, m + 1] if nr_x > 1 else 0.0))
                        if nr_y > 1:
                            acc += wy * ((1.0 - wx) * U[2, ju, m + Nx] + (wx * U[3, ju, m + Nx + 1] if nr_x > 1
                                                                          else 0.0))
                        _store(orow, ju, acc * r0)


@numba.njit(cache=True, inline="always")
def _channels(K, has_nd, ND, cvals, ov, ou, nv, nu):
    """How many of the K channels :func:`_extrapolate_xy_kernel` computes for a ray whose
    nodes are ND[ov:ov + nv, ou:ou + nu]: K - 1 with ``has_nd`` (the folded "no data"
    channel, K = 3) when ND is 0 at all of them, and then that channel's cvals[2] = 0 (its
    value), else K."""
    if not has_nd:
        return K
    for q in range(nv):
        for t in range(nu):
            if ND[ov + q, ou + t] != 0:
                return K
    cvals[2] = 0.0
    return K - 1


@numba.njit(cache=True, inline="always")
def _put_channel(dst, cvals, folding, ch, ray, value):
    """Channel ch of a ray (ray = (face, jy, ix, jv, iu)) into dst (:func:`_store`), or with
    ``folding`` the confidence channels (ch > 0) into cvals (3,) float32 instead. (Argument
    names differ from the caller's: inlined, ``out = out`` made numba's parfor pass recurse.)"""
    if folding and ch > 0:
        cvals[ch] = np.float32(value)
    else:
        _store(dst, (ch,) + ray, value)


@numba.njit(parallel=True, cache=True)
def _near_marks_kernel(marks, ry, rx, oy, ox, out):
    F, Ny, Nx, Nv, Nu = marks.shape
    ny, nx = out.shape[1], out.shape[2]
    for idx in numba.prange(F * ny * nx):
        f = idx // (ny * nx)
        j = (idx // nx) % ny
        i = idx % nx
        o = out[f, j, i]
        o[:, :] = 0
        j += oy
        i += ox
        for jj in range(max(j - ry, 0), min(j + ry + 1, Ny)):
            for ii in range(max(i - rx, 0), min(i + rx + 1, Nx)):
                m = marks[f, jj, ii]
                for v in range(Nv):
                    orow = o[v]
                    mrow = m[v]
                    for u in range(numba.uint64(Nu)):
                        orow[u] |= mrow[u]


def _near_marks(marks: np.ndarray, ry: int, rx: int, out: np.ndarray, oy: int = 0, ox: int = 0) -> np.ndarray:
    """``out`` (F, ny, nx, Nv, Nu) uint8: 1 where a sample of ``marks`` (F, Ny, Nx, Nv, Nu,
    uint8 0 / 1) lies within ``ry``, ``rx`` views at the same direction, else 0 (the (x, y)
    part of a ray's filter support; the marked samples of :func:`_warp_into` change slowly
    with the direction, so the (u, v) part is left out); out's view (j, i) is view
    (j + oy, i + ox) of marks."""
    _near_marks_kernel(marks, int(ry), int(rx), int(oy), int(ox), out)
    return out


@numba.njit(parallel=True, cache=True)
def _view_mean_kernel(rho, scales, out):
    F, Ny, Nx, Nv, Nu = rho.shape
    none = np.int16(_RHO_NONE)
    for fv in numba.prange(F * Nv):
        f = fv // Nv
        v = fv - f * Nv
        o = out[f, v]
        n = np.zeros(Nu)
        o[:] = 0.0
        for j in range(Ny):
            for i in range(Nx):
                row = rho[f, j, i, v]
                s = np.float32(scales[f, j, i])
                for u in range(Nu):
                    if row[u] != none:
                        o[u] += np.float32(row[u]) * s
                        n[u] += 1.0
        for u in range(Nu):
            o[u] = o[u] / n[u] if n[u] > 0 else np.nan


def _view_mean(rho: np.ndarray, scales: np.ndarray) -> np.ndarray:
    """(F, Nv, Nu) float64: the mean over the views of the solver's int16 ρ̂ (F, Ny, Nx, Nv, Nu)
    in units of scales (F, Ny, Nx) (:func:`~polycam.eq5.depth_rho`), ignoring the rays that keep
    the measured regressors (NaN where every view's does)."""
    F, Ny, Nx, Nv, Nu = rho.shape
    out = np.empty((F, Nv, Nu))
    _view_mean_kernel(rho, scales, out)
    return out


def _filled_view_mean(rho_bar: np.ndarray, steps: int = 8) -> np.ndarray:
    """``rho_bar`` (F, Nv, Nu) (:func:`_view_mean`) with its NaN directions filled from their
    neighbours: up to ``steps`` rounds of the mean of the known values among the 3 x 3 around
    each unknown one, then the face's median (a face without any stays NaN). A linear array's
    warp extrapolates every ray moved off its single-view axis with it, so a direction without
    ρ̄ (no view's window explained by one depth, or the (u, v) border the filters leave out)
    would lose its rays and, through the filters' support, their neighbours'."""
    out = np.array(rho_bar, np.float64)
    for _ in range(steps):
        known = np.isfinite(out)
        if known.all():
            break
        val = np.pad(np.where(known, out, 0.0), ((0, 0), (1, 1), (1, 1)))
        cnt = np.pad(known.astype(np.float64), ((0, 0), (1, 1), (1, 1)))
        Nv, Nu = out.shape[1:]
        sv = sum(val[:, a:a + Nv, b:b + Nu] for a in range(3) for b in range(3))
        sc = sum(cnt[:, a:a + Nv, b:b + Nu] for a in range(3) for b in range(3))
        grow = ~known & (sc > 0)
        out[grow] = sv[grow] / sc[grow]
    for f in range(out.shape[0]):
        known = np.isfinite(out[f])
        if known.any() and not known.all():
            out[f][~known] = np.median(out[f][known])
    return out


@numba.njit(cache=True, inline="always")
def _put_views(o, a, f, v, m0, s):
    """o[u, m0 + m] = a[f, m, v, u] s (:func:`_store`) for every m of a (F, M, Nv, Nu) and u."""
    for m in range(a.shape[1]):
        row = a[f, m, v]
        for u in range(a.shape[3]):
            _store(o, (u, m0 + m), row[u] * s)


@numba.njit(parallel=True, cache=True)
def _views_inner_kernel(a, out):
    """out[f, v, u, m] = a[f, m, v, u] (m = the flattened (K, Ny, Nx)), zero for m beyond
    a's (the padding); per (f, v) the output block (Nu, M) stays in cache while rows of a
    are read contiguously."""
    F, M, Nv, Nu = a.shape
    Mp = out.shape[3]
    for fv in numba.prange(F * Nv):
        f = fv // Nv
        v = fv - f * Nv
        o = out[f, v]
        _put_views(o, a, f, v, 0, np.float32(1.0))
        for u in range(Nu):
            o[u, M:Mp] = 0.0


@numba.njit(parallel=True, cache=True)
def _views_inner_lw_kernel(L, W, channels, inv, out, nodata):
    """:func:`_views_inner_kernel` of the first ``channels`` (1, 2 or 3) of L, W and the "no
    data" indicator W <= 0 (1 / 0) from L, W (F, Ny Nx, Nv, Nu): no stacked copy. Channel k
    of face f is multiplied by inv[f, k] (F, 3) float32 and stored by :func:`_store` (out
    float32 or int16). With 3 channels ``nodata`` (F, Nv, Nu) uint8 gets 1 where some view
    has a sample without data, else 0 (:func:`_warp_into`'s ``nodata``)."""
    F, V, Nv, Nu = L.shape
    M = channels * V
    Mp = out.shape[3]
    for fv in numba.prange(F * Nv):
        f = fv // Nv
        v = fv - f * Nv
        o = out[f, v]
        _put_views(o, L, f, v, 0, inv[f, 0])
        if channels > 1:
            _put_views(o, W, f, v, V, inv[f, 1])
        if channels > 2:
            # the indicator: a direction without such samples in any view gets a contiguous
            # row of zeros, the others their views one by one
            one = inv[f, 2]
            nd = nodata[f, v]
            nd[:] = 0
            for m in range(V):
                row = W[f, m, v]
                for u in range(Nu):
                    nd[u] |= row[u] <= 0.0
            for u in range(Nu):
                ou = o[u]
                if nd[u] == 0:
                    for m in range(2 * V, 3 * V):
                        ou[m] = 0
                else:
                    for m in range(V):
                        _store(ou, 2 * V + m, one if W[f, m, v, u] <= 0.0 else np.float32(0.0))
        for u in range(Nu):
            o[u, M:Mp] = 0


@numba.njit(parallel=True, cache=True)
def _view_abs_max_kernel(a, w, has_w, out):
    """out[n] = max |a[n]| over each view image of a (N, Nv, Nu), with ``has_w`` over the
    samples whose w (a's dims; a itself otherwise) is > 0 only (:func:`~polycam.eq5._abs_max_where`)."""
    N, Nv, Nu = a.shape
    for n in numba.prange(N):
        out[n] = _abs_max_where(a[n], 0, Nv, 0, Nu, w[n], has_w)


def _face_abs_max(a: np.ndarray, w: np.ndarray | None = None) -> np.ndarray:
    """(F,) float64: max |a| over each face of a (F, Ny, Nx, Nv, Nu) or (F, Ny Nx, Nv, Nu)
    float32 C, over the samples where ``w`` (a's dims, float32 C) is > 0 if given (no
    frame-sized temporary)."""
    F, Nv, Nu = a.shape[0], a.shape[-2], a.shape[-1]
    flat = a.reshape(-1, Nv, Nu)
    m = np.empty(flat.shape[0], np.float32)
    _view_abs_max_kernel(flat, flat if w is None else w.reshape(-1, Nv, Nu), w is not None, m)
    return m.reshape(F, -1).max(axis=1).astype(np.float64)


@numba.njit(parallel=True, cache=True, fastmath=_FASTMATH)
def _view_abs_max_min_kernel(a, out_max, out_min):
    """out_max[n] = max |a[n]|, out_min[n] = min a[n] over each view image of a (N, Nv, Nu)
    (column-wise extremes first, as :func:`~polycam.eq5._abs_max_where`: they vectorise)."""
    N, Nv, Nu = a.shape
    for n in numba.prange(N):
        hi = np.zeros(Nu, np.float32)
        lo = np.full(Nu, np.inf, np.float32)
        for v in range(Nv):
            row = a[n, v]
            for u in range(Nu):
                x = row[u]
                y = abs(x)
                hi[u] = y if y > hi[u] else hi[u]
                lo[u] = x if x < lo[u] else lo[u]
        out_max[n] = hi.max()
        out_min[n] = lo.min()


def _face_abs_max_min(a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """((F,), (F,)) float64: max |a| and min a over each face of a (F, Ny, Nx, Nv, Nu) or
    (F, Ny Nx, Nv, Nu) float32 C (finite), in one pass."""
    F, Nv, Nu = a.shape[0], a.shape[-2], a.shape[-1]
    flat = a.reshape(-1, Nv, Nu)
    hi = np.empty(flat.shape[0], np.float32)
    lo = np.empty(flat.shape[0], np.float32)
    _view_abs_max_min_kernel(flat, hi, lo)
    return hi.reshape(F, -1).max(axis=1).astype(np.float64), lo.reshape(F, -1).min(axis=1).astype(np.float64)


def _padded(m: int) -> int:
    """The warp's view axis length for m = K Ny Nx values: the next multiple of 16 (the
    (u, v) warp's vector loops then have no scalar remainder: 81 → 96 is ~25 % faster)."""
    return -(-m // 16) * 16


def _views_inner(arrays: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
    """(F, K, Ny, Nx, Nv, Nu) → (F, Nv, Nu, M) float32 C, M = :func:`_padded` (K Ny Nx): the
    warp's source layout, (K, Ny, Nx) flattened then zeros (into ``out`` when given)."""
    a = np.ascontiguousarray(arrays, dtype=np.float32)
    F, K, Ny, Nx, Nv, Nu = a.shape
    if out is None:
        out = np.empty((F, Nv, Nu, _padded(K * Ny * Nx)), np.float32)
    _views_inner_kernel(a.reshape(F, K * Ny * Nx, Nv, Nu), out)
    return out


@numba.njit(cache=True, inline="always")
def _weight_confidence(w):
    """The confidence of a weight w: w clipped to [0, 1], zero where w <= 0."""
    return min(max(w, np.float32(0.0)), np.float32(1.0)) * (np.float32(1.0) if w > 0.0 else np.float32(0.0))


@numba.njit(parallel=True, cache=True)
def _warped_confidence_kernel(conf, W, nodata, has_nodata, q, rnd):
    n = conf.shape[0]
    rows = max(1, n // 16384)
    for r in numba.prange(rows):
        for k in range(r * n // rows, (r + 1) * n // rows):
            w = min(max(W[k], np.float32(0.0)), np.float32(1.0))
            c = conf[k] * (w * (np.float32(1.0) if not has_nodata or abs(nodata[k]) < 1e-6 else np.float32(0.0)))
            conf[k] = c * q + rnd


def _confidence_units(conf: np.ndarray) -> tuple[float, float]:
    """(q, rnd): a confidence c is stored in ``conf`` as c q + rnd (truncated): float32 as it
    is, uint16 as round(c x 65535) (:func:`_apply_warped_confidence`, :func:`_folded_confidence`)."""
    return (65535.0, 0.5) if conf.dtype == np.uint16 else (1.0, 0.0)


def _apply_warped_confidence(conf: np.ndarray, out: np.ndarray) -> None:
    """conf (F, Ny, Nx, Nv, Nu) *= the confidence of the warped channels out (K, F, Ny, Nx, Nv,
    Nu) of the motion solver's source with W (``polycam.motion._warp_source``: L, W and, K = 3,
    the "no data" indicator W <= 0): the warped W clipped to [0, 1], zero where the warped
    indicator is not 0 (in place, no frame-sized temporaries). conf float32, or uint16
    holding the warp's 0 / 1 and then the product in units of 1 / 65535
    (:func:`_confidence_units`). The motion solver's ``symmetric`` warps (both frames
    warped); otherwise the warp folds this into its pass (:func:`_folded_confidence`)."""
    flat = conf.reshape(-1)
    _warped_confidence_kernel(flat, out[1].reshape(-1), out[-1].reshape(-1), out.shape[0] > 2,
                              *_confidence_units(conf))


_NO_MARKS = np.zeros((1, 1, 1, 1, 1), np.uint8)


def _warp_into(srcT: np.ndarray, grid: LightFieldGrid, T_ray: np.ndarray, uv_taps: int,
               out: np.ndarray, ok: np.ndarray, rho: np.ndarray | None = None,
               extrapolate_views: float = 0.0,
               marks: np.ndarray | None = None, scratch: np.ndarray | None = None,
               ratio: np.ndarray | None = None, confidence_channels: int = 0,
               W0: np.ndarray | None = None, nodata: np.ndarray | None = None,
               lag_confidence: bool = False, depth_views: np.ndarray | None = None) -> None:
    """:func:`warp_lightfield` into given buffers. srcT (F, Nv, Nu, M) float32 C
    (:func:`_views_inner`); out (K, F, Ny, Nx, Nv, Nu) float32; ok (F, Ny, Nx, Nv, Nu)
    float32 or uint8 (1 inside, 0 outside; the solver uses uint8 without confidences).
    Scaled warp (the motion solver's, half the memory): srcT and out may also be int16,
    each channel k of face f in units of its own scale (s_src, s_out), and ``ratio`` (F, K)
    = s_src / s_out (float out: s_out = 1; None: all 1): out gets the interpolated srcT
    times ratio, rounded and clipped to ±32767 when int16 (:func:`_store`).
    With ``rho`` (F, Nv, Nu) (the disparity ρ = f / Z per direction, u per unit x; NaN
    unknown) and ``extrapolate_views`` > 0, rays up to that many view steps outside the
    viewpoints are filled by Eq. 6 (:func:`_extrapolate_xy_kernel`); ``marks`` (F, Ny, Nx,
    Nv, Nu) uint8, if given, gets 1 at the filled samples (the caller zeroes it). On a linear
    array (one viewpoint along x or y, several along the other) ``rho`` alone extrapolates every
    ray that the motion moves off the single-view axis, however far (without ``rho`` that axis
    keeps each ray's position).
    ``scratch``: float32 C memory that is free during the call (the solver passes its
    derivatives', which each warp precedes): the extrapolation's copy of the edge views
    (K P Nv Nu floats, P the edge views) goes there when it fits.
    ``confidence_channels`` K > 0 (the motion solver's source with W: L, W and with K = 3 the
    "no data" indicator, :func:`~polycam.motion._warp_source`): out holds only L (its first
    channel), and ok (uint16 only) gets the confidence of each warped ray instead of 1, times that of
    the unwarped frame's ``W0`` (F, Ny, Nx, Nv, Nu) if given (:func:`_folded_confidence`: what
    :func:`_apply_warped_confidence` does, in the same pass, without storing the warped W).
    With K = 3, ``nodata`` (F, Nv, Nu) uint8 (:func:`~polycam.motion._warp_source`; None:
    from srcT) is nonzero where some view has a sample without data: the (u, v) warp
    leaves the indicator out where no stencil tap touches one (it is 0 there).
    ``lag_confidence`` (K = 2, out float32): ok holds the folded confidences of an earlier warp
    of the same source, W0 and ok dims, by a motion that moved no ray far from this one; a ray
    that is inside the grid or filled by the extrapolation keeps its confidence unless it is 0
    (then it gets a fresh one), so the warped W is not blended again for it (:func:`_xy_row`,
    :func:`_extrapolate_xy_kernel`); L is warped as always. The motion solver's re-warps
    (``polycam.motion._W_SETTLED``).
    ``depth_views`` (F, Nv, Nu), ρ per direction as ``rho`` (NaN: unknown): L (channel 0) of the
    rays inside the viewpoints is blended across the views along it (:func:`_depth_views_kernel`)
    instead of at one direction; the other channels and ``ok`` are those of the plain blend."""
    _, F, Ny, Nx, Nv, Nu = out.shape
    fold = confidence_channels > 0
    if fold and ok.dtype != np.uint16:
        raise ValueError("_warp_into: folded confidences need a uint16 ok")
    if lag_confidence and (confidence_channels != 2 or out.dtype != np.float32):
        raise ValueError("_warp_into: lag_confidence needs confidence_channels 2 and a float32 out")
    K = confidence_channels if fold else out.shape[0]
    cq, crnd = _confidence_units(ok) if fold else (1.0, 0.0)
    has_w0 = W0 is not None
    W0 = np.ascontiguousarray(W0, dtype=np.float32) if has_w0 else np.ones((1, 1, 1, 1, Nu), np.float32)
    xs, ys = grid.x.values, grid.y.values
    us = np.ascontiguousarray(grid.u.values, dtype=np.float64)
    vs = np.ascontiguousarray(grid.v.values, dtype=np.float64)
    # a linear array (one viewpoint along one axis) moves its rays off that axis with any motion
    # along it: with rho they are all extrapolated from the views (no limit along that axis), in
    # grid units of the other axis's view step; without, that axis keeps each ray's position
    single = bool(grid.single_view_axis)
    extrapolate = rho is not None and (Nx > 1 or Ny > 1) and (extrapolate_views > 0 or single)
    hx = (xs[-1] - xs[0]) / (Nx - 1) if Nx > 1 else 1.0
    hy = (ys[-1] - ys[0]) / (Ny - 1) if Ny > 1 else 1.0
    if single and extrapolate:
        hx, hy = (hy, hy) if Nx == 1 else (hx, hx)
    e_max = [math.inf if n == 1 else float(extrapolate_views) for n in (Nx, Ny)]
    y, x = np.meshgrid(ys, xs, indexing="ij")
    lag = (2 if extrapolate else 1) if lag_confidence else 0     # (_xy_row)
    slot = _perimeter(Ny, Nx)
    e_shape = (Nv, K, int(slot.max()) + 1, Nu) if extrapolate else (1, 1, 1, 1)
    n_e = math.prod(e_shape)
    flat = None if scratch is None else scratch.reshape(-1)
    E = flat[:n_e].reshape(e_shape) if flat is not None and flat.dtype == np.float32 and flat.size >= n_e \
        else np.empty(e_shape, np.float32)
    ratio = np.ones((F, K)) if ratio is None else np.ascontiguousarray(ratio, dtype=np.float64)
    has_nd = fold and K == 3                     # the folded "no data" channel
    ND = np.empty((Nv if has_nd else 1, Nu), np.uint8)      # _nodata_runs per face
    S = np.zeros((Nv + 1, Nu + 1) if has_nd else (1, 1), np.int32)
    if has_nd and nodata is None:
        nxy = Ny * Nx
        nodata = (srcT[..., 2 * nxy:3 * nxy] != 0).any(axis=-1)
    for k, face in enumerate(grid.faces):
        if has_nd:                               # the summed-area table of face k's nodata
            np.cumsum(np.cumsum(nodata[k] != 0, axis=0, dtype=np.int32), axis=1, out=S[1:, 1:])
        Rk = np.asarray(face.R_rig_face, float)
        Tk = T_from_Rt(Rk, np.zeros(3))
        G = T_inverse(Tk) @ T_ray @ Tk          # the ray motion in face coordinates
        R = np.ascontiguousarray(G[:3, :3])
        _, _, _, _, ok_uv, slope_x, slope_y = _uv_stencils(grid, face, R, int(uv_taps), weights=False)
        o = np.stack([x, y, np.full_like(x, face.z_pi)], axis=-1) @ R.T + G[:3, 3]     # moved origins
        sz = face.z_pi - o[..., 2]
        # grid units (x' = o_x + sz slope_x): zero coefficients on a single-sample axis (unless a
        # linear array extrapolates along it)
        cx = (np.ascontiguousarray((o[..., 0] - xs[0]) / hx), np.ascontiguousarray(sz / hx)) \
            if Nx > 1 or (single and extrapolate) else (np.zeros((Ny, Nx)), np.zeros((Ny, Nx)))
        cy = (np.ascontiguousarray((o[..., 1] - ys[0]) / hy), np.ascontiguousarray(sz / hy)) \
            if Ny > 1 or (single and extrapolate) else (np.zeros((Ny, Nx)), np.zeros((Ny, Nx)))
        _warp_rows_kernel(srcT[k], us, vs, R, float(face.f), int(uv_taps), ok_uv, slope_x, slope_y, *cx, *cy, k,
                          ratio[k], out, ok, slot, E, extrapolate, fold, W0, has_w0, cq, crnd, ND, S, lag)
        if extrapolate:
            ku = abs(hx / grid.u.step) if Nu > 1 else 0.0
            kv = abs(hy / grid.v.step) if Nv > 1 else 0.0
            _extrapolate_xy_kernel(E, slot, ok_uv, slope_x, slope_y, *cx, *cy, k, rho[k], ku, kv,
                                   *e_max, ratio[k], out, ok,
                                   _NO_MARKS if marks is None else marks, marks is not None, fold, W0, has_w0, cq, crnd,
                                   ND, lag, depth_views is not None)
        if depth_views is not None and (Nx > 1 or Ny > 1):
            kx = hx / grid.u.step if Nu > 1 else 0.0
            ky = hy / grid.v.step if Nv > 1 else 0.0
            _depth_views_kernel(srcT[k], us, vs, R, float(face.f), int(uv_taps), ok_uv, slope_x, slope_y, *cx, *cy, k,
                                np.ascontiguousarray(depth_views[k], dtype=np.float64), kx, ky, float(ratio[k, 0]), out)


def warp_lightfield(arrays: np.ndarray, grid: LightFieldGrid, T_ray: np.ndarray, *,
                    uv_taps: int = 6, rho: np.ndarray | None = None,
                    extrapolate_views: float = 0.0, depth_views: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Resample light fields at the grid rays moved by the rigid transform ``T_ray`` (rig frame).

    ``arrays``: (K, F, Ny, Nx, Nv, Nu) stacked fields (e.g. L and W) sharing the
    warp. Returns ``out`` (same dims, float32) with ``out(ρ) = in(T_ray ρ)`` and
    ``ok`` (F, Ny, Nx, Nv, Nu) bool: the moved ray lies inside the grid. Interpolation
    is linear in (x, y) and ``uv_taps``-point Lagrange (an even number, 2 to 16) in (u, v). The
    moved direction, hence the (u, v) stencil, does not depend on the viewpoint, so
    every view image is first resampled in (u, v), then views are blended.
    ``rho`` (F, Nv, Nu): the disparity ρ = f / Z per direction (u per unit of x; NaN:
    unknown); with it, rays that leave the viewpoints by at most ``extrapolate_views``
    view steps are extrapolated by paper Eq. 6 from the nearest edge viewpoint(s)
    (``L(x_e + d, u) = L(x_e, u + ρ d)``) and count as inside; with ``depth_views`` too, the
    first array (L) of the rays inside is blended across the views along ρ as well (each of the
    four views around the moved point read at the direction that sees the same scene point; the
    other arrays keep the plain blend): where the views are a sample or more of disparity apart,
    the plain blend mixes different scene points (:func:`_depth_views_kernel`).
    """
    arrays = np.asarray(arrays, dtype=np.float32)
    K, F, Ny, Nx, Nv, Nu = arrays.shape
    out = np.empty(arrays.shape, np.float32)
    ok = np.empty(arrays.shape[1:], np.float32)
    srcT = _views_inner(np.moveaxis(arrays, 0, 1))
    rho = None if rho is None else np.asarray(rho, np.float64)
    _warp_into(srcT, grid, T_ray, uv_taps, out, ok, rho, extrapolate_views,
               depth_views=rho if depth_views else None)
    return out, ok > 0


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
