"""Per-ray data weights of the motion solver: noise, discontinuities, confidence, IRLS.

The weight of a ray in the Eq. 5 system (:mod:`polycam.motion`, section "Robust
weighting" of its docstring; docs/motion.md) is its confidence minimised over the filter
support (:func:`solver_filter_pairs`, :func:`min_over_support`) × validity × a
discontinuity weight (:func:`discontinuity_weight`: large second derivatives in (u, v)
near the ray, optionally above the level sensor noise alone reaches, with the noise
variance estimated from second differences across viewpoints) × an IRLS weight
(:func:`robust_weight` of the residual over :func:`robust_scale`), and with
``MotionOptions.model_weight`` × a model-validity weight (:func:`model_error_weights`: the
residual energy pooled over a window, beyond the noise's).
"""

from __future__ import annotations

import functools
import math

import numba
import numpy as np

from .derivatives import FILTERS, min_filter_axis
from .eq5 import _bin_scale, _bin_select
from .lightfield import LightFieldGrid
from .motion_options import MotionOptions
from .pyramid import _Level

__all__ = [
    "frame_noise_variance",
    "discontinuity_weight",
    "solver_filter_pairs",
    "min_over_support",
    "robust_scale",
    "robust_weight",
    "robust_slope",
    "model_error_weights",
]


@numba.njit(parallel=True, cache=True)
def _second_differences(L, W, has_w, ax, stride, out, hy=1, oy=0, hx=1, ox=0):
    """|L[a-h] − 2 L[a] + L[a+h]| along axis ``ax`` (1..4) of L (F, Ny, Nx, Nv, Nu) on
    every ``stride``-th (v) row (C order over the rows used; whole rows for contiguous
    access; along u only the interior samples); NaN where the confidence W is not positive
    (``has_w``). Along y only the views oy, oy + hy, ... are used, along x ox, ox + hx, ...
    (the cameras' views, :func:`_camera_stride`); along the differenced view axis h is its
    step and the centres are the used views with both neighbours inside. out: (n_rows, n_u)."""
    F, Ny, Nx, Nv, Nu = L.shape
    n1, s1, d1 = _axis_rows(Ny, hy, oy, ax == 1)
    n2, s2, d2 = _axis_rows(Nx, hx, ox, ax == 2)
    n3 = Nv - 2 if ax == 3 else Nv
    dv = 1 if ax == 3 else 0
    du = 1 if ax == 4 else 0
    dj = hy if d1 else 0
    di = hx if d2 else 0
    two = np.float32(2.0)
    for k in numba.prange(out.shape[0]):
        q = k * stride
        v = q % n3 + dv
        q //= n3
        i = s2 + (q % n2) * hx
        q //= n2
        j = s1 + (q % n1) * hy
        f = q // n1
        for m in range(out.shape[1]):
            u = m + du
            if has_w and not W[f, j, i, v, u] > 0:
                out[k, m] = np.nan
                continue
            out[k, m] = abs(L[f, j - dj, i - di, v - dv, u - du] - two * L[f, j, i, v, u]
                            + L[f, j + dj, i + di, v + dv, u + du])


@numba.njit(cache=True)
def _axis_rows(n, h, o, differenced):
    """(count, first, differenced) of the views o, o + h, ... of an axis of n views; on the
    differenced axis only those with both neighbours (± h) inside."""
    if differenced:
        return max((n - 1 - o) // h - 1, 0), o + h, True
    return (n - 1 - o) // h + 1, o, False


@numba.njit(cache=True)
def _median_kernel(a):
    n = a.shape[0]
    nb = 4096
    lo, hi, scale = _bin_scale(a, n, nb)                # scale 0 (subnormal spread): one bin, sorted
    if not hi > lo:
        return lo
    bins = np.empty(n, np.int32)
    hist = np.zeros(nb)
    for i in range(n):
        bins[i] = np.int32((np.float64(a[i]) - lo) * scale)
    for i in range(n):
        hist[bins[i]] += 1.0
    # the middle order statistics (0-based (n - 1) // 2 and n // 2): cumulative counts k + 1
    m1 = _bin_select(a, a, False, bins, hist, (n - 1) // 2 + 1.0)
    if n % 2:
        return m1
    m2 = _bin_select(a, a, False, bins, hist, n // 2 + 1.0)
    return (m1 + m2) / 2       # in a's precision, as numpy's median


def _median(a: np.ndarray) -> float:
    """``np.median`` of finite values a (any dims; the same result to the last bit, ~7x
    faster on 50 000 float32 values: a histogram finds the middle values' bins,
    :func:`~polycam.eq5._bin_select` the values)."""
    a = np.ascontiguousarray(a).reshape(-1)
    if a.size == 0:
        return math.nan
    return float(_median_kernel(a))


def _camera_stride(L: np.ndarray, ax: int) -> tuple[int, int]:
    """(h, o): the spacing and offset along view axis ``ax`` (1: y, 2: x) of L
    (F, Ny, Nx, Nv, Nu) of the views that are not linear interpolations of their
    neighbours. A grid with viewpoints interpolated between the cameras (design's
    ``xy_oversample``: one view in h is a camera) has second differences that vanish at
    the interpolated views: their median per view position is below 1e-4 of the largest.
    (1, 0) when every interior view is measured (or the axis has fewer than 3 views)."""
    n = L.shape[ax]
    if n < 3:
        return 1, 0
    sub = L[:, :, :, ::max(1, L.shape[3] // 8), ::max(1, L.shape[4] // 32)]   # a few (v, u) samples suffice
    d2 = np.abs(np.diff(sub, n=2, axis=ax))                   # centres 1 .. n − 2
    med = np.median(np.moveaxis(d2, ax, 0).reshape(n - 2, -1), axis=1)
    if not med.max() > 0:
        return 1, 0
    live = np.flatnonzero(med > 1e-4 * med.max()) + 1
    if live.size == 0 or live.size == n - 2:
        return 1, 0
    if live.size >= 2:
        h = int(np.diff(live).min())
    else:                        # one camera centre: h − 1 interpolated views up to the end
        a = int(live[0])
        h = min(n - 1 - a, a)
    return (h, int(live[0]) % h) if h > 1 else (1, 0)


def _noise_variance(lev: _Level) -> float:
    """Sensor-noise variance per sample of the level's frames (:func:`_second_difference_variance`),
    estimated once per level (``lev.noise_var``)."""
    if lev.noise_var is None:
        lev.noise_var = _second_difference_variance(lev)
    return lev.noise_var


def _second_difference_variance(lev: _Level, samples: int = 25_000) -> float:
    """Sensor-noise variance per sample, from the robust spread of second differences
    across viewpoints (the light field is smooth along x and y; the finest available
    axis is used) on regularly spaced rows, about ``samples`` per frame:
    σ² = (1.4826 · median |Δ²L|)² / 6 (:func:`_robust_variance`; on 8-bit frames the grouped
    median). On a grid with viewpoints interpolated between the cameras, over the cameras'
    views only (:func:`_camera_stride`)."""
    for ax in (2, 1, 4, 3):                             # x, y, then u, v
        if lev.L0.shape[ax] >= 3:
            break
    else:
        return 0.0
    if "camera_stride" not in lev.views:          # the same at every level with these views
        lev.views["camera_stride"] = (_camera_stride(lev.L0, 1), _camera_stride(lev.L0, 2))
    (hy, oy), (hx, ox) = lev.views["camera_stride"]
    F, Ny, Nx, Nv, Nu = lev.L0.shape
    shape = [F, _axis_rows(Ny, hy, oy, ax == 1)[0], _axis_rows(Nx, hx, ox, ax == 2)[0],
             Nv - 2 if ax == 3 else Nv, Nu - 2 if ax == 4 else Nu]
    n_u = shape[4]
    n_rows = int(np.prod(shape[:4]))
    if n_rows * n_u == 0:
        return 0.0
    stride = max(1, n_rows * n_u // samples)
    vals = []
    for L, W in ((lev.L0, lev.W0), (lev.L1, lev.W1)):
        out = np.empty((-(-n_rows // stride), n_u), np.float32)
        _second_differences(L, L if W is None else W, W is not None, ax, stride, out, hy, oy, hx, ox)
        out = out.reshape(-1)
        vals.append(out[np.isfinite(out)])
    v = np.concatenate(vals)
    if v.size == 0:
        return 0.0
    q = 0.0 if lev.W0 is not None or lev.W1 is not None else min(_lattice_step(lev.L0), _lattice_step(lev.L1))
    return _robust_variance(v, q) / 6.0


def _lattice_step(L: np.ndarray, samples: int = 4096) -> float:
    """The step q of the lattice k·q (k integer) that the frame values L lie on, in L's units:
    1/255 for 8-bit frames scaled to [0, 1] (1 for frames in grey levels, values up to 255), or
    1/(255 m²) for their m x m block means (m = 2, 3, 4: :func:`polycam.hci.load_hci_lightfield`'s
    ``downsample``); 0 when a spread of ``samples`` values is not within 1e-3 steps of one (float
    frames, resampled ones). Their second differences are multiples of q too."""
    flat = L.reshape(-1)
    x = np.asarray(flat[::max(1, flat.size // samples)], np.float64)
    x = x[np.isfinite(x)]
    if x.size == 0:
        return 0.0
    unit = 1.0 if float(np.max(np.abs(x))) > 1.0 + 1e-6 else 1.0 / 255.0
    for m in (1, 2, 3, 4):
        q = unit / (m * m)
        k = x / q
        if np.all(np.abs(k - np.rint(k)) <= 1e-3):
            return q
    return 0.0


def _robust_variance(a: np.ndarray, q: float = 0.0) -> float:
    """Variance of zero-mean Gaussian values from their absolute values a (n,) ≥ 0:
    (1.4826 · median a)². Values on a lattice of step q > 0 (integer frames, e.g. 8-bit:
    :func:`_lattice_step`) have a median that jumps from step to step (σ estimates of 0, 0.61,
    1.21 ... grey levels from second differences); there the median is that of the values spread
    uniformly over their rounding cells ([0, q/2) for 0, [k − ½, k + ½) q else: the grouped
    median), less the spread's own variance q²/12 (Sheppard's correction)."""
    if q == 0.0:
        return float((1.4826 * _median(a)) ** 2)
    counts = np.bincount(np.rint(a / q).astype(np.int64))
    cum = np.cumsum(counts)
    half = 0.5 * cum[-1]
    k = int(np.searchsorted(cum, half))                  # first cell with cum ≥ half
    below = float(cum[k - 1]) if k > 0 else 0.0
    lo, width = (0.0, 0.5) if k == 0 else (k - 0.5, 1.0)
    m = (lo + (half - below) / float(counts[k]) * width) * q
    return max(float((1.4826 * m) ** 2) - q * q / 12.0, 0.0)


def frame_noise_variance(L0: np.ndarray, L1: np.ndarray, grid: LightFieldGrid, W0: np.ndarray | None = None,
                         W1: np.ndarray | None = None) -> float:
    """Sensor-noise variance per sample of a frame pair (F, Ny, Nx, Nv, Nu) float32 (with
    confidences W0, W1 of the same dims, or None), as the motion solver estimates it
    (:func:`_noise_variance`: the robust spread of second differences across viewpoints);
    :func:`polycam.derivatives.derivative_noise` turns it into the derivatives' noise."""
    return _noise_variance(_Level(grid, L0, L1, W0, W1))


@numba.njit(parallel=True, cache=True)
def _discontinuity_energy(L0, L1, W0, has_w, r, out, y0, x0, stride, samples):
    """out = |∂²S/∂u²| + |∂²S/∂v²| (second differences, clamped borders) of the mean
    S = (L0 + L1) / 2 (times W0 > 0 with ``has_w``) maximised over ±r samples in (u, v)
    (windows clipped at the borders), per view image of (F, Ny, Nx, Nv, Nu) arrays; out
    (F, ny, nx, Nv, Nu) holds the views y0:y0 + ny, x0:x0 + nx only. With ``stride`` > 0,
    samples[k] (k = 0, 1, ...; (n, Nu)) gets row k x stride of the energy of *every* view
    (rows in C order over (F, Ny, Nx, Nv)), as if out held them all."""
    F, Ny, Nx, Nv, Nu = L0.shape
    ny, nx = out.shape[1], out.shape[2]
    two = np.float32(2.0)
    half = np.float32(0.5)
    zero = np.float32(0.0)
    n = F * Ny * Nx
    chunks = max(1, min(n, 64))
    # row-wise loops over contiguous u with unsigned indices (they vectorise)
    un = numba.uint64(Nu)
    for c in numba.prange(chunks):
        img = np.empty((Nv, Nu), np.float32)
        e = np.empty((Nv, Nu), np.float32)
        for idx in range(c * n // chunks, (c + 1) * n // chunks):
            fc = idx // (Ny * Nx)
            rem = idx - fc * Ny * Nx
            j = rem // Nx
            i = rem - j * Nx
            a0 = L0[fc, j, i]
            a1 = L1[fc, j, i]
            wv = W0[fc, j, i]
            kept = y0 <= j < y0 + ny and x0 <= i < x0 + nx
            o = out[fc, j - y0, i - x0] if kept else e     # e is free after the row maxima
            for v in range(Nv):
                ir = img[v]
                r0 = a0[v]
                r1 = a1[v]
                rw = wv[v]
                for u in range(un):
                    sv = (r0[u] + r1[u]) * half
                    ir[u] = zero if (has_w and not rw[u] > 0) else sv
            for v in range(Nv):
                er = e[v]
                ir = img[v]
                if Nv >= 3:
                    im = img[max(v - 1, 0)]
                    ip = img[min(v + 1, Nv - 1)]
                    for u in range(un):
                        er[u] = zero + abs(im[u] - two * ir[u] + ip[u])
                else:
                    er[:] = zero
                if Nu >= 3:
                    er[0] += abs(ir[0] - two * ir[0] + ir[1])
                    for u in range(numba.uint64(1), numba.uint64(Nu - 1)):
                        er[u] += abs(ir[u - 1] - two * ir[u] + ir[u + 1])
                    er[Nu - 1] += abs(ir[Nu - 2] - two * ir[Nu - 1] + ir[Nu - 1])
            for v in range(Nv):                          # max over ±r rows
                ir = img[v]
                ir[:] = e[max(v - r, 0)]
                for d in range(max(v - r, 0) + 1, min(v + r, Nv - 1) + 1):
                    er = e[d]
                    for u in range(un):
                        ir[u] = max(ir[u], er[u])
            for v in range(Nv):                          # max over ±r samples along u
                ir = img[v]
                orow = o[v]
                for u in range(min(r, Nu)):              # left border (clipped windows)
                    m = ir[max(u - r, 0)]
                    for d in range(max(u - r, 0) + 1, min(u + r, Nu - 1) + 1):
                        m = max(m, ir[d])
                    orow[u] = m
                if Nu > 2 * r:
                    m_in = numba.uint64(Nu - 2 * r)
                    oi = orow[r:Nu - r]
                    oi[:] = ir[0:Nu - 2 * r]
                    for d in range(1, 2 * r + 1):
                        sr = ir[d:d + Nu - 2 * r]
                        for u in range(m_in):
                            oi[u] = max(oi[u], sr[u])
                for u in range(max(Nu - r, r), Nu):      # right border
                    m = ir[max(u - r, 0)]
                    for d in range(max(u - r, 0) + 1, min(u + r, Nu - 1) + 1):
                        m = max(m, ir[d])
                    orow[u] = m
            if stride > 0:
                g0 = idx * Nv                            # the view's first row (C order)
                for v in range(-(-g0 // stride) * stride - g0, Nv, stride):
                    samples[(g0 + v) // stride] = o[v]


_NOISE_ENERGY_Q = 0.99
"""Quantile of the discontinuity energy of pure noise subtracted by the noise-aware weight."""


@functools.lru_cache(maxsize=8)
def _noise_energy_quantile(radius: int) -> float:
    """The ``_NOISE_ENERGY_Q`` quantile of the discontinuity energy e (:func:`_discontinuity_energy`,
    window ±radius) of white noise of unit variance: e of noise of variance s² is s times this.
    Computed once per radius from a seeded 128 x 128 noise image."""
    n = np.random.default_rng(1234).standard_normal((1, 1, 1, 128, 128)).astype(np.float32)
    e = np.empty_like(n)
    _discontinuity_energy(n, n, n, False, radius, e, 0, 0, 0, n[0, 0, 0])
    return float(np.quantile(e, _NOISE_ENERGY_Q))


def _discontinuity_weight(L0: np.ndarray, L1: np.ndarray, W0: np.ndarray | None, opts: MotionOptions,
                          samples: int = 50_000, noise_var: float = 0.0, box: np.ndarray | None = None,
                          out: np.ndarray | None = None) -> np.ndarray:
    """:func:`discontinuity_weight` of S = (L0 + L1) / 2 (zero where W0 <= 0); the median
    from about ``samples`` values in whole rows. ``noise_var``: sensor-noise variance of S
    per sample (``smooth_noise``: the energy noise alone reaches is subtracted from e).
    ``box`` (8,): return only the weights of its views (F, box y, box x, Nv, Nu), as the
    solver keeps them (the median is still that of every view). ``out``: into this float32
    C array of the returned dims."""
    F, Ny, Nx, Nv, Nu = L0.shape
    y0, y1, x0, x1 = (0, Ny, 0, Nx) if box is None else (int(b) for b in box[:4])
    e = np.empty((F, y1 - y0, x1 - x0, Nv, Nu), np.float32) if out is None else out   # the kept views only
    stride = max(1, L0.size // samples)
    rows = np.empty((-(-(F * Ny * Nx * Nv) // stride), Nu), np.float32)   # every stride-th row of all views
    _discontinuity_energy(L0, L1, L0 if W0 is None else W0, W0 is not None, max(int(opts.smooth_radius), 0), e,
                          y0, x0, stride, rows)
    m = _median(rows)
    if not m > 0:
        e.fill(1.0)
        return e
    if opts.smooth_noise and noise_var > 0:
        # noise-aware: only energy above what noise alone reaches counts as a discontinuity
        e -= np.float32(_noise_energy_quantile(max(int(opts.smooth_radius), 0)) * math.sqrt(noise_var))
        np.maximum(e, np.float32(0.0), out=e)
    e *= np.float32(1.0 / (opts.smooth_c * m))
    np.multiply(e, e, out=e)
    e += np.float32(1.0)
    return np.reciprocal(e, out=e)


def discontinuity_weight(S: np.ndarray, opts: MotionOptions, noise_var: float = 0.0) -> np.ndarray:
    """(F, Ny, Nx, Nv, Nu) weights in (0, 1] of a light field S of the same dims: small near
    intensity discontinuities.

    e = |∂²S/∂u²| + |∂²S/∂v²|, maximised over ±``smooth_radius`` samples in (u, v);
    w = 1 / (1 + (e / (smooth_c · median e))²). The solver applies it to the mean of a
    frame pair; it depends on the data only (not on the motion), so it is the same in
    every iteration of a level. Public so the design study predicts with the same weights.
    With ``opts.smooth_noise`` and ``noise_var`` > 0 (the sensor-noise variance of S per
    sample), e is first reduced by the level pure noise of that variance stays below with
    99% probability (clipped at 0), so noise alone leaves the weights at 1.
    """
    S = np.ascontiguousarray(S, dtype=np.float32)
    return _discontinuity_weight(S, S, None, opts, noise_var=noise_var)


def _level_discontinuity_weight(lev: _Level, opts: MotionOptions, box: np.ndarray | None = None,
                                out: np.ndarray | None = None) -> np.ndarray:
    """:func:`discontinuity_weight` of a level's frame mean (where frame 1 has data); the
    mean of two frames has half the per-frame noise variance (:func:`_noise_variance`).
    ``box``: only its views, ``out``: into that array (:func:`_discontinuity_weight`)."""
    var_S = 0.5 * _noise_variance(lev) if opts.smooth_noise else 0.0
    return _discontinuity_weight(lev.L0, lev.L1, lev.W0, opts, noise_var=var_S, box=box, out=out)


def solver_filter_pairs(grid: LightFieldGrid, opts: MotionOptions) -> dict:
    """Axis name (x y u v) → the FilterPair the solver uses on this grid (None: the axis is
    too short to differentiate)."""
    names = opts.filters if isinstance(opts.filters, dict) else {k: opts.filters for k in "xyuv"}
    counts = {"x": grid.x.count, "y": grid.y.count, "u": grid.u.count, "v": grid.v.count}
    out = {}
    for k in "xyuv":
        fp = FILTERS[names.get(k, "fs5")]
        out[k] = fp if counts[k] >= 2 * fp.radius + 1 else None
    return out


def min_over_support(c: np.ndarray, pairs: dict) -> np.ndarray:
    """Minimum of a (F, Ny, Nx, Nv, Nu) confidence over each ray's filter support
    (``pairs`` from :func:`solver_filter_pairs`): the solver's confidence rule."""
    out = c
    for name, ax in (("y", 1), ("x", 2), ("v", 3), ("u", 4)):
        fp = pairs[name]
        if fp is not None and fp.radius > 0 and out.shape[ax] > 1:
            out = min_filter_axis(out, fp.radius, ax)
    return out


_SCALE_SAMPLES = 20_000
"""Rays the robust residual scale (a weighted median) is taken from, at least: its relative
precision ~1 % (the scale only sets the IRLS cut-off)."""


def robust_scale(res: np.ndarray, w: np.ndarray) -> float:
    """The solver's robust residual scale: 1.4826 x the w-weighted median of |res| over
    w > 0 (from at least ``_SCALE_SAMPLES`` regularly spaced samples)."""
    m = w.reshape(-1) > 0
    a = np.abs(res.reshape(-1)[m]).astype(np.float64)
    ww = w.reshape(-1)[m].astype(np.float64)
    if a.size == 0:
        return 0.0
    step = max(1, a.size // _SCALE_SAMPLES)
    a, ww = a[::step], ww[::step]
    order = np.argsort(a)
    cw = np.cumsum(ww[order])
    i = int(np.searchsorted(cw, 0.5 * cw[-1]))
    return 1.4826 * float(a[order[min(i, a.size - 1)]])


def robust_weight(res: np.ndarray, scale: float, opts: MotionOptions) -> np.ndarray:
    """The solver's IRLS weight w(r) of residuals ``res`` (any dims) at robust ``scale``
    (Tukey or Huber with ``opts.robust_c``; ones without robust weighting)."""
    if opts.robust == "none" or opts.irls_steps == 0 or not scale > 0:
        return np.ones_like(res)
    z = np.abs(res) / np.float32(scale * opts.robust_c)
    if opts.robust == "huber":
        return np.where(z <= 1.0, 1.0, 1.0 / np.maximum(z, 1e-12)).astype(np.float32)
    return np.where(z < 1.0, (1.0 - z * z) ** 2, 0.0).astype(np.float32)


def robust_slope(res: np.ndarray, scale: float, opts: MotionOptions) -> np.ndarray:
    """ψ'(res) of the IRLS loss (ψ(r) = w(r) r; 1 where the loss is quadratic): how much a
    small change of a ray's residual moves the robust (M-)estimate that IRLS converges to."""
    if opts.robust == "none" or opts.irls_steps == 0 or not scale > 0:
        return np.ones_like(res)
    z = np.abs(res) / np.float32(scale * opts.robust_c)
    if opts.robust == "huber":
        return (z <= 1.0).astype(np.float32)
    return np.where(z < 1.0, (1.0 - z * z) * (1.0 - 5.0 * z * z), 0.0).astype(np.float32)


_MODEL_HALF = (3, 3, 2, 2)
"""Half-widths (y, x, v, u) of the window :func:`model_error_weights` pools residual energy
over: 7 x 7 views x 5 x 5 directions (session 21, docs/motion_log.md: pooling across more
views tells the model error apart better, for the rotation most: 3 x 3 views gave ω 1.2–1.9x
the error of 7 x 7 at 1–2 grey levels; more directions than 5 x 5 lose the translation's
gain)."""

_MODEL_MARGIN = 0.5
"""The pooled residual energy counts as model error only above ``(1 + margin) s²``, so that
where noise dominates the weights stay near 1 (the prefilters correlate the residuals, so the
window's mean of pure noise scatters more than its ray count suggests). On bench_noise's 4 m
scene with the noise options (gain 1) the mean weight is 0.43 / 0.90 / 0.98 / 1.00 at 0 / 1 /
2 / 4–16 grey levels (with a 3 x 3 x 5 x 5 window: 0.99 at 8, 0.92 there with no margin, at
the same gains at 1–2)."""


@numba.njit(cache=True, inline="always")
def _window_sums(src, h, dst):
    """dst[j] ← Σ src[j − h .. j + h] (clipped at the ends), a float64 running sum; src and
    dst 1-D of one length, not overlapping."""
    n = src.shape[0]
    s = 0.0
    for j in range(min(h, n)):
        s += src[j]
    for j in range(n):
        if j + h < n:
            s += src[j + h]
        if j - h - 1 >= 0:
            s -= src[j - h - 1]
        dst[j] = s


@numba.njit(parallel=True, cache=True)
def _box_sum_axis(a, h):
    """In place: a (pre, n, post) float32 ← its sums over ±h along the middle axis (clipped
    at the ends); a task per block of ≤ 512 columns of a pre line, whose running sums (float64,
    each column's in :func:`_window_sums`'s order) advance a row at a time over contiguous columns."""
    pre, n, post = a.shape
    cb = 512
    nb = (post + cb - 1) // cb
    for k in numba.prange(pre * nb):
        p = k // nb
        c0 = (k % nb) * cb
        w = min(post, c0 + cb) - c0
        buf = a[p, :, c0:c0 + w].copy()        # the source rows (n, w): a is overwritten row by row
        s = np.zeros(w)
        for j in range(min(h, n)):
            for c in range(w):
                s[c] += buf[j, c]
        for j in range(n):
            if j + h < n:
                for c in range(w):
                    s[c] += buf[j + h, c]
            if j - h - 1 >= 0:
                for c in range(w):
                    s[c] -= buf[j - h - 1, c]
            for c in range(w):
                a[p, j, c0 + c] = s[c]


@numba.njit(parallel=True, cache=True)
def _box_sum_last(a, h):
    """In place: a (lines, n) float32 ← its sums over ±h along each (contiguous) line; a task
    per 256 lines, one buffer each."""
    lines, n = a.shape
    chunk = 256
    for c in numba.prange((lines + chunk - 1) // chunk):
        buf = np.empty(n)
        for ln in range(c * chunk, min(lines, (c + 1) * chunk)):
            buf[:] = a[ln]
            _window_sums(buf, h, a[ln])


def _box_sums(a: np.ndarray, half: tuple) -> None:
    """In place: a (F, ny, nx, nv, nu) float32 ← its sums over the window ±half (y, x, v, u)
    (clipped at the array's ends)."""
    F = a.shape[0]
    for k, h in enumerate(half):
        ax = k + 1
        if h > 0 and a.shape[ax] > 1:
            if ax == a.ndim - 1:
                _box_sum_last(a.reshape(-1, a.shape[ax]), h)
            else:
                _box_sum_axis(a.reshape(F * math.prod(a.shape[1:ax]), a.shape[ax], -1), h)


@numba.njit(parallel=True, cache=True)
def _square_mask(r, w):
    """In place: r ← r² where w > 0 (else 0), w ← 1 where w > 0 (else 0); flat float32 arrays."""
    for i in numba.prange(r.size):
        ok = w[i] > 0.0
        r[i] = r[i] * r[i] if ok else np.float32(0.0)
        w[i] = np.float32(1.0) if ok else np.float32(0.0)


@numba.njit(parallel=True, cache=True)
def _scale_base(base, e, n, s2, margin, gain, v0, u0):
    """base[f, j, i, v0 + v, u0 + u] (int16 weights) ×= s2 / (s2 + gain ê²), ê² = max(e / n −
    (1 + margin) s2, 0) of the pooled sums e (F, ny, nx, nv, nu) of r² over n rays."""
    F, ny, nx, nv, nu = e.shape
    for k in numba.prange(F * ny * nx):
        f = k // (ny * nx)
        j = (k // nx) % ny
        i = k % nx
        for v in range(nv):
            b = base[f, j, i, v0 + v]
            ev = e[f, j, i, v]
            nvv = n[f, j, i, v]
            for u in range(nu):
                if b[u0 + u] > 0 and nvv[u] > 0.0:
                    e2 = gain * max(np.float64(ev[u]) / nvv[u] - (1.0 + margin) * s2, 0.0)
                    b[u0 + u] = np.int16(np.float64(b[u0 + u]) * s2 / (s2 + e2) + 0.5)


def model_error_weights(res: np.ndarray, w: np.ndarray, base: np.ndarray, box: np.ndarray, scale: float,
                        half: tuple = _MODEL_HALF, margin: float = _MODEL_MARGIN, gain: float = 1.0) -> None:
    """Scale the solver's int16 base weights ``base`` (F, ny, nx, Nv, Nu: the views of
    ``box``) by a model-validity weight that does not depend on the noise level: where the
    Eq. 5 residuals ``res`` (F, ny, nx, nv, nu, the rays of ``box`` (8,) y0 y1 x0 x1 v0 v1 u0
    u1; weights ``w`` of the same dims, > 0 where used) are larger, on average over a window
    (``half``: 7 x 7 views x 5 x 5 directions), than noise of the robust residual ``scale``
    explains, a ray's weight becomes ``s² / (s² + ê²)`` with ``ê² = max(mean r² − (1 +
    margin) s², 0)`` the window's model-error energy: the weight of a ray whose variance is
    noise plus that model error. A ray's own residual is mostly noise; the window's mean
    energy minus the noise's is the model error (silhouettes, aliasing, the warp's
    interpolation), which is systematic and so does not average out, whatever the noise
    level. ``gain`` κ > 0 weighs the model error against the noise: ``s² / (s² + κ ê²)``
    (:attr:`~polycam.motion_options.MotionOptions.model_weight_gain`: model error is
    systematic, so over many rays it adds up as a bias where noise averages out; κ = 1 is the
    variance weight). ``res`` and ``w`` are overwritten (work arrays)."""
    if not scale > 0:
        return
    r = res.reshape(-1)
    m = w.reshape(-1)
    _square_mask(r, m)
    _box_sums(res, half)
    _box_sums(w, half)
    _scale_base(base, res, w, float(scale) ** 2, float(margin), float(gain), int(box[4]), int(box[6]))
