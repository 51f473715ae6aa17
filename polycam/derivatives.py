"""Plenoptic derivatives of a light-field frame pair: L_x, L_y, L_u, L_v, L_t.

Arrays of one frame have dims ``(F, Ny, Nx, Nv, Nu)`` (SPEC.md: ``L[t, face, y, x,
v, u]``); filters never cross faces. Derivatives are separable and *matched*: the
derivative along one axis is taken with the derivative taps of a filter pair while
the other three axes are smoothed with that pair's prefilter (Farid & Simoncelli,
"Differentiation of discrete multidimensional signals", IEEE TIP 2004), so all four
partial derivatives describe the same smoothed signal. The time derivative is
symmetric: spatial derivatives are those of the frames' mean ``(L0 + L1) / 2`` (by
linearity the average of the two frames' derivatives) and ``L_t`` is the fully
prefiltered difference ``L1 - L0``; all five refer to the midpoint between frames.

Units: ``L_x, L_y`` per metre (divided by the grid's x / y steps), ``L_u, L_v`` per
unit of f, ``L_t`` per frame interval. Samples whose filter support leaves the grid
are marked invalid. An axis with fewer samples than the filter support is not
differentiated: its derivative is zero and it is not smoothed (the solver then
reports the motion directions that depend on it as unobservable).

The filters run as one fused numba kernel (parallel over view images) on float32
C-contiguous arrays: per output view image an (x, y) stage reads the neighbouring
views of both frames into four view-filtered images held in cache, and a (u, v)
stage filters those into the five outputs (:func:`xy_view`, :func:`uv_view`, which
the motion solver's kernels share). :func:`plenoptic_derivatives_reference` does the same one separable pass at
a time with :func:`correlate_axis` (which matches ``scipy.ndimage.correlate1d``
with ``mode="nearest"``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numba
import numpy as np

from .lightfield import LightFieldGrid

__all__ = [
    "FilterPair",
    "FILTERS",
    "correlate_axis",
    "min_filter_axis",
    "Derivatives",
    "plenoptic_derivatives",
    "plenoptic_derivatives_reference",
    "derivative_noise",
    "smooth_all",
    "filter_taps",
    "parallel_chunks",
    "xy_view",
    "uv_view",
]


@dataclass(frozen=True)
class FilterPair:
    """A matched prefilter / first-derivative pair, as correlation taps (odd length).

    ``prefilter`` sums to 1; ``derivative`` has first moment 1 (``sum_k k d[k] = 1``
    with k centred), so a unit ramp has derivative exactly 1 per sample.
    """

    name: str
    prefilter: np.ndarray
    """(2r+1,) smoothing taps."""
    derivative: np.ndarray
    """(2r+1,) derivative taps (correlation orientation: positive for a rising ramp)."""

    @property
    def radius(self) -> int:
        return len(self.prefilter) // 2


def _pair(name: str, p, d) -> FilterPair:
    p = np.asarray(p, float)
    d = np.asarray(d, float)
    r = len(p) // 2
    k = np.arange(-r, r + 1)
    p = p / p.sum()
    d = d / np.sum(k * d)
    return FilterPair(name, p, d)


FILTERS: dict[str, FilterPair] = {
    # plain central differences, no smoothing (the baseline)
    "central": _pair("central", [0.0, 1.0, 0.0], [-1.0, 0.0, 1.0]),
    # Farid & Simoncelli (2004) 3- and 5-tap pairs
    "fs3": _pair("fs3", [0.229879, 0.540242, 0.229879], [-0.425287, 0.0, 0.425287]),
    "fs5": _pair("fs5", [0.030320, 0.249724, 0.439911, 0.249724, 0.030320],
                 [-0.104550, -0.292315, 0.0, 0.292315, 0.104550]),
}
"""Available filter pairs by name."""


@numba.njit(parallel=True, cache=True, fastmath=False)
def _corr_mid(a, taps, out):
    """out[i, j, k] = sum_t taps[t] a[i, clamp(j + t - r), k] for a (A, n, B) view."""
    A, n, B = a.shape
    T = taps.shape[0]
    r = T // 2
    for ij in numba.prange(A * n):
        i = ij // n
        j = ij - i * n
        for k in range(B):
            out[i, j, k] = 0.0
        for t in range(T):
            w = taps[t]
            if w == 0.0:
                continue
            jj = j + t - r
            if jj < 0:
                jj = 0
            elif jj > n - 1:
                jj = n - 1
            for k in range(B):
                out[i, j, k] += w * a[i, jj, k]


@numba.njit(parallel=True, cache=True, fastmath=False)
def _corr_last(a, taps, out):
    """out[i, j] = sum_t taps[t] a[i, clamp(j + t - r)] for a (A, n) view."""
    A, n = a.shape
    T = taps.shape[0]
    r = T // 2
    m = max(n - 2 * r, 0)
    for i in numba.prange(A):
        row = a[i]
        o = out[i, r:r + m]
        o[:] = 0.0
        for t in range(T):
            w = taps[t]
            src = row[t:t + m]
            for j in range(m):          # contiguous slices: vectorises
                o[j] += w * src[j]
        for jb in range(n - m):         # borders, with clamped indices
            j = jb if jb < r else r + m + jb - r
            if j >= n:
                continue
            acc = 0.0
            for t in range(T):
                jj = min(max(j + t - r, 0), n - 1)
                acc += taps[t] * row[jj]
            out[i, j] = acc


def correlate_axis(a: np.ndarray, taps: np.ndarray, axis: int,
                   out: np.ndarray | None = None) -> np.ndarray:
    """Correlate float32 array ``a`` (any dims) with 1-D ``taps`` along ``axis``.

    Same as ``scipy.ndimage.correlate1d(a, taps, axis, mode="nearest")`` (the
    border values are only placeholders: callers mask them). Returns ``out``
    (float32, dims of ``a``).
    """
    a = np.ascontiguousarray(a, dtype=np.float32)
    axis = axis % a.ndim
    if out is None:
        out = np.empty_like(a)
    taps32 = np.asarray(taps, dtype=np.float32)
    n = a.shape[axis]
    A = int(np.prod(a.shape[:axis], dtype=np.int64))
    B = int(np.prod(a.shape[axis + 1:], dtype=np.int64))
    if B == 1:
        _corr_last(a.reshape(A, n), taps32, out.reshape(A, n))
    else:
        _corr_mid(a.reshape(A, n, B), taps32, out.reshape(A, n, B))
    return out


@numba.njit(parallel=True, cache=True)
def _min_mid(a, r, out):
    """out[i, j, k] = min over |d| <= r of a[i, clamp(j + d), k] for a (A, n, B) view."""
    A, n, B = a.shape
    for ij in numba.prange(A * n):
        i = ij // n
        j = ij - i * n
        lo = max(j - r, 0)
        hi = min(j + r, n - 1)
        for k in range(B):
            out[i, j, k] = a[i, lo, k]
        for jj in range(lo + 1, hi + 1):
            for k in range(B):
                v = a[i, jj, k]
                if v < out[i, j, k]:
                    out[i, j, k] = v


def min_filter_axis(a: np.ndarray, radius: int, axis: int) -> np.ndarray:
    """Minimum of float32 ``a`` over ``±radius`` samples along ``axis`` (window clipped at
    the borders, like ``scipy.ndimage.minimum_filter1d(mode="nearest")``)."""
    a = np.ascontiguousarray(a, dtype=np.float32)
    axis = axis % a.ndim
    out = np.empty_like(a)
    n = a.shape[axis]
    A = int(np.prod(a.shape[:axis], dtype=np.int64))
    B = int(np.prod(a.shape[axis + 1:], dtype=np.int64))
    _min_mid(a.reshape(A, n, B), int(radius), out.reshape(A, n, B))
    return out


# axes of a (F, Ny, Nx, Nv, Nu) array
_AX = {"y": 1, "x": 2, "v": 3, "u": 4}


@dataclass(frozen=True)
class Derivatives:
    """Plenoptic derivatives of a frame pair at the temporal midpoint.

    Every array has dims ``(F, Ny, Nx, Nv, Nu)`` (float32).
    """

    Lx: np.ndarray
    """[1/m] derivative along the focal-plane x axis (fixed direction)."""
    Ly: np.ndarray
    """[1/m] derivative along the focal-plane y axis."""
    Lu: np.ndarray
    """[1/unit of f] derivative along u (fixed position)."""
    Lv: np.ndarray
    """[1/unit of f] derivative along v."""
    Lt: np.ndarray
    """[1/frame] prefiltered ``L1 - L0``."""
    valid: np.ndarray
    """(Ny, Nx, Nv, Nu) bool: the filter support lies inside the grid."""
    differentiated: dict
    """Axis name (``x y u v``) → whether that axis had enough samples to differentiate."""


def _axis_pairs(grid_counts: dict, filters: dict) -> dict:
    """Per axis: the FilterPair, or None when the axis is too short to differentiate."""
    out = {}
    for name, n in grid_counts.items():
        fp = filters[name]
        out[name] = fp if n >= 2 * fp.radius + 1 else None
    return out


def _valid_mask(shape4: tuple, pairs: dict) -> np.ndarray:
    """(Ny, Nx, Nv, Nu) bool: samples at least ``radius`` from every differentiated border."""
    valid = np.ones(shape4, bool)
    for name, fp in pairs.items():
        if fp is None or fp.radius == 0:
            continue
        ax = _AX[name] - 1
        n = shape4[ax]
        keep = np.zeros(n, bool)
        keep[fp.radius:n - fp.radius] = True
        shape = [1, 1, 1, 1]
        shape[ax] = n
        valid &= keep.reshape(shape)
    return valid


def _resolve_filters(filters) -> dict:
    """``filters``: a FILTERS name for all axes, or a dict axis name → name."""
    if isinstance(filters, str):
        filters = {k: filters for k in _AX}
    out = {}
    for k in _AX:
        name = filters.get(k, "fs5") if isinstance(filters, dict) else filters
        if isinstance(name, FilterPair):
            out[k] = name
            continue
        if name not in FILTERS:
            raise ValueError(f"unknown derivative filter {name!r}; expected one of {sorted(FILTERS)}")
        out[k] = FILTERS[name]
    return out


def smooth_all(a: np.ndarray, pairs: dict, skip: str | None = None) -> np.ndarray:
    """Apply the prefilter of every differentiated axis (except ``skip``) to a (F, Ny, Nx, Nv, Nu) array."""
    out = a
    for name in ("y", "x", "v", "u"):
        fp = pairs[name]
        if name == skip or fp is None or fp.radius == 0:
            continue
        out = correlate_axis(out, fp.prefilter, _AX[name])
    return out if out is not a else a.copy()


def plenoptic_derivatives_reference(L0: np.ndarray, L1: np.ndarray, grid: LightFieldGrid, *,
                                    filters: str | dict = "fs5") -> Derivatives:
    """Same as :func:`plenoptic_derivatives`, one separable pass at a time (16 passes over
    the arrays; kept as the reference the fused kernels are tested against)."""
    pairs = _axis_pairs({"x": grid.x.count, "y": grid.y.count, "u": grid.u.count,
                         "v": grid.v.count}, _resolve_filters(filters))
    L0 = np.ascontiguousarray(L0, dtype=np.float32)
    L1 = np.ascontiguousarray(L1, dtype=np.float32)
    S = 0.5 * (L0 + L1)
    D = L1 - L0
    step = {"x": grid.x.step, "y": grid.y.step, "u": grid.u.step, "v": grid.v.step}
    zeros = None

    def deriv(name: str, base: np.ndarray) -> np.ndarray:
        nonlocal zeros
        fp = pairs[name]
        if fp is None:
            if zeros is None:
                zeros = np.zeros_like(S)
            return zeros
        d = correlate_axis(base, fp.derivative, _AX[name])
        d *= np.float32(1.0 / step[name])
        return d

    # share smoothing passes: (x, y) derivatives from S smoothed in (u, v) and vice versa
    S_uv = smooth_all(smooth_all(S, {"u": pairs["u"], "v": None, "x": None, "y": None}),
                      {"v": pairs["v"], "u": None, "x": None, "y": None})
    S_xy = smooth_all(smooth_all(S, {"x": pairs["x"], "u": None, "v": None, "y": None}),
                      {"y": pairs["y"], "u": None, "v": None, "x": None})
    only = {k: None for k in _AX}

    def sm(a, name):
        return smooth_all(a, {**only, name: pairs[name]})

    Lx = deriv("x", sm(S_uv, "y"))
    Ly = deriv("y", sm(S_uv, "x"))
    Lu = deriv("u", sm(S_xy, "v"))
    Lv = deriv("v", sm(S_xy, "u"))
    Lt = smooth_all(D, pairs)
    valid = _valid_mask(S.shape[1:], pairs)
    return Derivatives(Lx, Ly, Lu, Lv, Lt, valid, {k: pairs[k] is not None for k in _AX})


_FASTMATH = {"reassoc", "contract", "nsz", "arcp"}
"""LLVM fast-math flags of the accumulating kernels (here the per-view stages the motion
solver's fused kernels call, and :mod:`polycam.eq5`, :mod:`polycam.warp`): re-associated
sums let the ray loops vectorise (results change by float rounding only); no ``nnan`` /
``ninf``, so the ``not w > 0`` tests keep their meaning."""


# ---------------------------------------------------------------------------- fused kernels


@numba.njit(cache=True, inline="always")
def _units(y):
    """y (float32, in units) rounded to the nearest integer (float32 rint: vectorises),
    clipped to ±32767: an int16 frame's value (polycam.warp._store)."""
    hi = np.float32(32767.0)
    return np.rint(min(max(y, -hi), hi))


@numba.njit(cache=True, inline="always")
def _on_grid(x, inv, unit):
    """x (float32) rounded to the nearest multiple of ``unit`` (``inv`` = 1 / unit, both float32),
    clipped to ±32767 units: the value an int16 frame in those units holds (:func:`_units`)."""
    return _units(x * inv) * unit


@numba.njit(cache=True)
def _on_grid_row(row, inv, unit, out):
    for u in range(row.shape[0]):
        out[u] = _on_grid(row[u], inv, unit)


@numba.njit(cache=True, fastmath=_FASTMATH)
def xy_view(L0, L1, g0, f, j, i, py, dy, px, dx, a1, a2, a3, a4):
    """(x, y) stage of one output view image (f, j, i) from the frames' mean S and
    difference D: a1 = Px Py S, a2 = Dx Py S, a3 = Px Dy S, a4 = Px Py D, each (Nv, Nu)
    (clamped borders). With ``g0`` > 0 (float32) frame 1 is read rounded to multiples of g0
    (:func:`_on_grid`): the motion solver's warp source is int16 in those units
    (polycam.warp._warp_into), so that two frames holding the same values have a difference
    of exactly 0 (rounding only frame 2 would leave a difference that is a function of the
    image: a bias). Shared with the motion solver's fused kernels."""
    if py.shape[0] == 3 and px.shape[0] == 3:
        _xy_view3(L0, L1, g0, f, j, i, py, dy, px, dx, a1, a2, a3, a4)
    else:
        _xy_view_taps(L0, L1, g0, f, j, i, py, dy, px, dx, a1, a2, a3, a4)


@numba.njit(cache=True, fastmath=_FASTMATH)
def _xy_view3(L0, L1, g0, f, j, i, py, dy, px, dx, a1, a2, a3, a4):
    """:func:`xy_view` for 3-tap filters along x and y (fs3, the solver's default), in one
    pass per (v) row: the 18 neighbouring rows of both frames are combined in registers
    (separably: x first), each output row is written once."""
    Ny, Nx, Nv, Nu = L0.shape[1:]
    half = np.float32(0.5)
    n = numba.uint64(Nu)
    j0 = max(j - 1, 0)
    j2 = min(j + 1, Ny - 1)
    i0 = max(i - 1, 0)
    i2 = min(i + 1, Nx - 1)
    p0, p1, p2 = px[0], px[1], px[2]
    d0, d1, d2 = dx[0], dx[1], dx[2]
    q0, q1, q2 = py[0] * half, py[1] * half, py[2] * half
    e0, e1, e2 = dy[0] * half, dy[1] * half, dy[2] * half
    r0, r1, r2 = py[0], py[1], py[2]
    on_grid = g0 > 0.0
    g = np.empty((9 if on_grid else 0, Nu), np.float32)
    inv = np.float32(1.0) / g0 if on_grid else np.float32(0.0)
    for v in range(Nv):
        A0, A1, A2 = L0[f, j0, i0, v], L0[f, j0, i, v], L0[f, j0, i2, v]
        B0, B1, B2 = L0[f, j, i0, v], L0[f, j, i, v], L0[f, j, i2, v]
        C0, C1, C2 = L0[f, j2, i0, v], L0[f, j2, i, v], L0[f, j2, i2, v]
        if on_grid:
            k = 0
            for row in (A0, A1, A2, B0, B1, B2, C0, C1, C2):
                _on_grid_row(row, inv, g0, g[k])
                k += 1
            A0, A1, A2, B0, B1, B2, C0, C1, C2 = g[0], g[1], g[2], g[3], g[4], g[5], g[6], g[7], g[8]
        X0, X1, X2 = L1[f, j0, i0, v], L1[f, j0, i, v], L1[f, j0, i2, v]
        Y0, Y1, Y2 = L1[f, j, i0, v], L1[f, j, i, v], L1[f, j, i2, v]
        Z0, Z1, Z2 = L1[f, j2, i0, v], L1[f, j2, i, v], L1[f, j2, i2, v]
        o1, o2, o3, o4 = a1[v], a2[v], a3[v], a4[v]
        for u in range(n):
            sa0, sa1, sa2 = A0[u] + X0[u], A1[u] + X1[u], A2[u] + X2[u]
            sb0, sb1, sb2 = B0[u] + Y0[u], B1[u] + Y1[u], B2[u] + Y2[u]
            sc0, sc1, sc2 = C0[u] + Z0[u], C1[u] + Z1[u], C2[u] + Z2[u]
            Pa = p0 * sa0 + p1 * sa1 + p2 * sa2
            Pb = p0 * sb0 + p1 * sb1 + p2 * sb2
            Pc = p0 * sc0 + p1 * sc1 + p2 * sc2
            Da = d0 * sa0 + d1 * sa1 + d2 * sa2
            Db = d0 * sb0 + d1 * sb1 + d2 * sb2
            Dc = d0 * sc0 + d1 * sc1 + d2 * sc2
            Ta = p0 * (X0[u] - A0[u]) + p1 * (X1[u] - A1[u]) + p2 * (X2[u] - A2[u])
            Tb = p0 * (Y0[u] - B0[u]) + p1 * (Y1[u] - B1[u]) + p2 * (Y2[u] - B2[u])
            Tc = p0 * (Z0[u] - C0[u]) + p1 * (Z1[u] - C1[u]) + p2 * (Z2[u] - C2[u])
            o1[u] = q0 * Pa + q1 * Pb + q2 * Pc
            o2[u] = q0 * Da + q1 * Db + q2 * Dc
            o3[u] = e0 * Pa + e1 * Pb + e2 * Pc
            o4[u] = r0 * Ta + r1 * Tb + r2 * Tc


@numba.njit(cache=True, fastmath=_FASTMATH)
def _xy_view_taps(L0, L1, g0, f, j, i, py, dy, px, dx, a1, a2, a3, a4):
    """:func:`xy_view` for any tap counts: one accumulating pass per (x, y) tap."""
    Ny, Nx, Nv, Nu = L0.shape[1:]
    ry = py.shape[0] // 2
    rx = px.shape[0] // 2
    a1[:, :] = 0.0
    a2[:, :] = 0.0
    a3[:, :] = 0.0
    a4[:, :] = 0.0
    on_grid = g0 > 0.0
    g = np.empty(Nu if on_grid else 0, np.float32)
    inv = np.float32(1.0) / g0 if on_grid else np.float32(0.0)
    for a in range(py.shape[0]):
        jj = min(max(j + a - ry, 0), Ny - 1)
        for b in range(px.shape[0]):
            ii = min(max(i + b - rx, 0), Nx - 1)
            w1 = py[a] * px[b]
            w2 = py[a] * dx[b]
            w3 = dy[a] * px[b]
            if w1 == 0.0 and w2 == 0.0 and w3 == 0.0:
                continue
            t0 = L0[f, jj, ii]
            t1 = L1[f, jj, ii]
            h1 = np.float32(0.5 * w1)
            h2 = np.float32(0.5 * w2)
            h3 = np.float32(0.5 * w3)
            d1 = np.float32(w1)
            for v in range(Nv):
                r0 = t0[v]
                if on_grid:
                    _on_grid_row(r0, inv, g0, g)
                    r0 = g
                r1 = t1[v]
                o1 = a1[v]
                o2 = a2[v]
                o3 = a3[v]
                o4 = a4[v]
                for u in range(Nu):
                    sm = r0[u] + r1[u]
                    o1[u] += h1 * sm
                    o2[u] += h2 * sm
                    o3[u] += h3 * sm
                    o4[u] += d1 * (r1[u] - r0[u])


@numba.njit(cache=True, fastmath=_FASTMATH)
def _filt_v(src, w, out):
    """out[v, u] = sum_t w[t] src[clamp(v + t - r), u] for 2-D (Nv, Nu) arrays."""
    Nv, Nu = src.shape
    T = w.shape[0]
    r = T // 2
    n = numba.uint64(Nu)
    if T == 5:
        w0, w1, w2, w3, w4 = w[0], w[1], w[2], w[3], w[4]
        for v in range(Nv):
            a = src[min(max(v - 2, 0), Nv - 1)]
            b = src[min(max(v - 1, 0), Nv - 1)]
            c = src[v]
            d = src[min(v + 1, Nv - 1)]
            e = src[min(v + 2, Nv - 1)]
            o = out[v]
            for u in range(n):
                o[u] = w0 * a[u] + w1 * b[u] + w2 * c[u] + w3 * d[u] + w4 * e[u]
    elif T == 3:
        w0, w1, w2 = w[0], w[1], w[2]
        for v in range(Nv):
            a = src[max(v - 1, 0)]
            c = src[v]
            d = src[min(v + 1, Nv - 1)]
            o = out[v]
            for u in range(n):
                o[u] = w0 * a[u] + w1 * c[u] + w2 * d[u]
    else:
        for v in range(Nv):
            o = out[v]
            o[:] = 0.0
            for t in range(T):
                wt = w[t]
                if wt == 0.0:
                    continue
                row = src[min(max(v + t - r, 0), Nv - 1)]
                for u in range(n):
                    o[u] += wt * row[u]


@numba.njit(cache=True, fastmath=_FASTMATH)
def _filt_u(src, w, scale, out):
    """out[v, u] = scale * sum_t w[t] src[v, clamp(u + t - r)] for 2-D (Nv, Nu) arrays."""
    Nv, Nu = src.shape
    T = w.shape[0]
    r = T // 2
    m = max(Nu - 2 * r, 0)
    mu = numba.uint64(m)
    for v in range(Nv):
        row = src[v]
        o = out[v, r:r + m]
        if T == 5:
            w0, w1, w2, w3, w4 = w[0] * scale, w[1] * scale, w[2] * scale, w[3] * scale, w[4] * scale
            for u in range(mu):
                o[u] = w0 * row[u] + w1 * row[u + 1] + w2 * row[u + 2] + w3 * row[u + 3] + w4 * row[u + 4]
        elif T == 3:
            w0, w1, w2 = w[0] * scale, w[1] * scale, w[2] * scale
            for u in range(mu):
                o[u] = w0 * row[u] + w1 * row[u + 1] + w2 * row[u + 2]
        else:
            o[:] = 0.0
            for t in range(T):
                wt = w[t] * scale
                if wt == 0.0:
                    continue
                sl = row[t:t + m]
                for u in range(mu):
                    o[u] += wt * sl[u]
        for jb in range(Nu - m):
            j = jb if jb < r else r + m + jb - r
            if j >= Nu:
                continue
            acc = 0.0
            for t in range(T):
                acc += w[t] * row[min(max(j + t - r, 0), Nu - 1)]
            out[v, j] = acc * scale


@numba.njit(cache=True, fastmath=_FASTMATH)
def uv_view(a1, a2, a3, a4, pv, dv, pu, du, sx, sy, su, sv, tmp, lx, ly, lu, lv, lt):
    """(u, v) stage of one view image: lu = Du Pv a1, lv = Pu Dv a1, lx = Pu Pv a2,
    ly = Pu Pv a3, lt = Pu Pv a4, derivatives scaled by 1/step (s*); all (Nv, Nu)."""
    _filt_v(a1, pv, tmp)
    _filt_u(tmp, du, su, lu)
    _filt_v(a1, dv, tmp)
    _filt_u(tmp, pu, sv, lv)
    _filt_v(a2, pv, tmp)
    _filt_u(tmp, pu, sx, lx)
    _filt_v(a3, pv, tmp)
    _filt_u(tmp, pu, sy, ly)
    _filt_v(a4, pv, tmp)
    _filt_u(tmp, pu, np.float32(1.0), lt)


@numba.njit(parallel=True, cache=True)
def _derivatives_kernel(L0, L1, py, dy, px, dx, pv, dv, pu, du, sx, sy, su, sv, Lx, Ly, Lu, Lv, Lt,
                        chunks):
    """Both stages per view image, with the (x, y)-stage results kept in per-chunk
    (Nv, Nu) buffers (in cache) instead of four frame-sized arrays."""
    F, Ny, Nx, Nv, Nu = L0.shape
    n = F * Ny * Nx
    chunks = max(1, min(n, chunks))
    for c in numba.prange(chunks):
        buf = np.empty((5, Nv, Nu), np.float32)
        for idx in range(c * n // chunks, (c + 1) * n // chunks):
            f = idx // (Ny * Nx)
            rem = idx - f * Ny * Nx
            j = rem // Nx
            i = rem - j * Nx
            xy_view(L0, L1, np.float32(0.0), f, j, i, py, dy, px, dx, buf[0], buf[1], buf[2], buf[3])
            uv_view(buf[0], buf[1], buf[2], buf[3], pv, dv, pu, du, sx, sy, su, sv, buf[4],
                    Lx[f, j, i], Ly[f, j, i], Lu[f, j, i], Lv[f, j, i], Lt[f, j, i])


def parallel_chunks() -> int:
    """Work chunks for a prange over view images: a few per thread (load balance)."""
    return 4 * numba.get_num_threads()


def derivative_noise(noise_var: float, grid: LightFieldGrid, filters: str | dict = "fs5",
                     smoothing: dict | None = None) -> np.ndarray:
    """(5,) variances of L_x, L_y, L_u, L_v, L_t (:func:`plenoptic_derivatives`, units as
    theirs) caused by white sensor noise of variance ``noise_var`` per sample, independent in
    the two frames: the spatial derivatives are of the frames' mean (variance noise_var / 2),
    L_t of their difference (2 noise_var), each through the separable filters of every
    differentiated axis (the sum of the squared taps per axis; an axis too short to
    differentiate is neither smoothed nor differentiated: variance 0 for its derivative).
    ``filters``: as :func:`plenoptic_derivatives` (names, or axis → FilterPair);
    ``smoothing``: optional axis → taps the frames were correlated with before (e.g.
    :func:`polycam.scales.smooth_at_scale`'s binomial pre-smoothing), composed with the filters."""
    pairs = _axis_pairs({"x": grid.x.count, "y": grid.y.count, "u": grid.u.count,
                         "v": grid.v.count}, _resolve_filters(filters))
    var_S = 0.5 * noise_var
    if not var_S > 0:
        return np.zeros(5)
    smoothing = smoothing or {}
    step = {"x": grid.x.step, "y": grid.y.step, "u": grid.u.step, "v": grid.v.step}

    def taps(k: str, t: np.ndarray) -> np.ndarray:
        s = smoothing.get(k)
        return np.asarray(t, float) if s is None else np.convolve(np.asarray(t, float), np.asarray(s, float))

    pn = {}                        # noise gain of each axis's prefilter (or pre-smoothing alone)
    for k in ("x", "y", "u", "v"):
        if pairs[k] is not None:
            pn[k] = float(np.sum(taps(k, pairs[k].prefilter) ** 2))
        else:
            pn[k] = float(np.sum(np.asarray(smoothing[k], float) ** 2)) if k in smoothing else 1.0
    var = []
    for k in ("x", "y", "u", "v"):
        if pairs[k] is None or not step[k] > 0:
            var.append(0.0)
            continue
        others = math.prod(pn[o] for o in "xyuv" if o != k)
        var.append(var_S * float(np.sum(taps(k, pairs[k].derivative) ** 2)) * others / step[k] ** 2)
    var.append(2.0 * noise_var * math.prod(pn.values()))
    return np.array(var)


def filter_taps(grid: LightFieldGrid, filters: str | dict) -> tuple[dict, tuple]:
    """The resolved pairs (axis name → FilterPair or None) and the kernels' float32 taps
    ``(py, dy, px, dx, pv, dv, pu, du, sx, sy, su, sv)``: prefilter and derivative taps
    per axis and 1/step scales; an axis too short to differentiate gets the identity
    prefilter, a zero derivative and scale 0."""
    pairs = _axis_pairs({"x": grid.x.count, "y": grid.y.count, "u": grid.u.count,
                         "v": grid.v.count}, _resolve_filters(filters))
    step = {"x": grid.x.step, "y": grid.y.step, "u": grid.u.step, "v": grid.v.step}
    taps = {}
    for name in ("y", "x", "v", "u"):
        fp = pairs[name]
        if fp is None:                                 # not differentiated, not smoothed
            taps[name] = (np.ones(1, np.float32), np.zeros(1, np.float32), np.float32(0.0))
        else:
            taps[name] = (fp.prefilter.astype(np.float32), fp.derivative.astype(np.float32),
                          np.float32(1.0 / step[name]))
    (py, dy, sy), (px, dx, sx), (pv, dv, sv), (pu, du, su) = (taps[k] for k in ("y", "x", "v", "u"))
    return pairs, (py, dy, px, dx, pv, dv, pu, du, sx, sy, su, sv)


def plenoptic_derivatives(L0: np.ndarray, L1: np.ndarray, grid: LightFieldGrid, *,
                          filters: str | dict = "fs5", out: Derivatives | None = None) -> Derivatives:
    """Derivatives of the frame pair ``L0``, ``L1`` (each (F, Ny, Nx, Nv, Nu)) on ``grid``.

    ``filters`` names a :data:`FILTERS` pair for all axes, or maps axis names
    (``x y u v``) to pair names (unnamed axes use ``fs5``). ``out``: a previous result
    of the same dims whose arrays are overwritten (saves allocating fresh memory).
    One fused kernel, parallel over view images: the (x, y) stage builds the four
    view-smoothed / view-differentiated images from the frames' mean and difference in
    cache, the (u, v) stage filters them into the five outputs.
    """
    pairs, taps = filter_taps(grid, filters)
    L0 = np.ascontiguousarray(L0, dtype=np.float32)
    L1 = np.ascontiguousarray(L1, dtype=np.float32)
    if L0.shape != L1.shape or L0.ndim != 5:
        raise ValueError(f"frames must both be (F, Ny, Nx, Nv, Nu), got {L0.shape} and {L1.shape}")
    if out is not None and out.Lx.shape == L0.shape:
        arrays = [out.Lx, out.Ly, out.Lu, out.Lv, out.Lt]
    else:
        arrays = [np.empty_like(L0) for _ in range(5)]
    Lx, Ly, Lu, Lv, Lt = arrays
    _derivatives_kernel(L0, L1, *taps, Lx, Ly, Lu, Lv, Lt, parallel_chunks())
    valid = _valid_mask(L0.shape[1:], pairs)
    return Derivatives(Lx, Ly, Lu, Lv, Lt, valid, {k: pairs[k] is not None for k in _AX})
