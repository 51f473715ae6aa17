"""Pull-push hole filling on a 4-D light-field grid, after Gortler et al., "The Lumigraph" (1996).

Input per face: splatted values ``x0`` and splat weights ``w0`` (sum of kernel
weights of the samples that reached a cell, in units of "samples"), dims
``(F, Ny, Nx, Nv, Nu)`` (the face axis is never filtered: faces are separate
4-D pyramids).

- **pull**: level r+1 halves some axes; with ``h̃ = [1/2, 1, 1/2]`` along each
  halved axis, ``w[r+1] = Σ h̃ min(w[r], 1)`` and ``x[r+1] = Σ h̃ min(w[r], 1) x[r] / w[r+1]``
  (weight-normalised averaging with clamped weights);
- **push**: from the coarsest level down, ``tw`` and ``tx`` are the coarse weights
  and weight-normalised values interpolated linearly (tent ``h = [1/2, 1, 1/2]``)
  onto level r, and with ``w = min(w[r], 1)``::

      x[r] = (w x[r] + (1 - w) tw tx) / (w + (1 - w) tw),   w[r] ← w + (1 - w) tw

  so cells with a full weight keep their own value and holes take the coarse one.

Which axes a level halves is the **schedule**: ``"xy-first"`` (default) halves the
viewpoint axes (y, x) until they are single, then the direction axes (v, u);
``"isotropic"`` halves all four together. With a planar array the data are
sparse in (x, y) (a viewpoint per camera) and dense in (u, v), so xy-first fills a
viewpoint between cameras from its neighbours' full-resolution views (a linear
interpolation in (x, y) at fixed (u, v): the depth-free limit) instead of from a
blurred coarse level.

Confidence ``W`` (SPEC.md, in [0, 1]): Gortler's pushed weight would call a hole
filled from a well-covered coarse level fully confident. Here a filled value
counts less the coarser the level it came from::

    W[r] = w + (1 - w) · attenuation · W[r+1]↑,      W[coarsest] = min(w, 1)

so a cell with direct data has ``W = min(w0, 1)``, a hole filled from the next
level at most ``attenuation`` (default 0.5), from two levels up at most its square,
and a cell of a face no sample reached 0.
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np

__all__ = ["SCHEDULES", "pyramid_schedule", "PushPullResult", "push_pull", "push_pull_reference", "PushPull",
           "weighted_views"]

SCHEDULES = ("xy-first", "isotropic")

# array axes of a frame (F, Ny, Nx, Nv, Nu)
_Y, _X, _V, _U = 1, 2, 3, 4


def _half(n: int) -> int:
    return (n + 1) // 2


def pyramid_schedule(shape: tuple[int, ...], schedule: str = "xy-first") -> list[tuple[int, ...]]:
    """Axes halved at each level for a frame of dims ``shape`` (F, Ny, Nx, Nv, Nu).

    Returns one tuple of array axes per level (empty list: a single-cell grid).
    """
    if schedule not in SCHEDULES:
        raise ValueError(f"schedule must be one of {SCHEDULES}, got {schedule!r}")
    dims = list(shape)
    out = []
    groups = [(_Y, _X), (_V, _U)] if schedule == "xy-first" else [(_Y, _X, _V, _U)]
    for group in groups:
        while True:
            axes = tuple(a for a in group if dims[a] > 1)
            if not axes:
                break
            for a in axes:
                dims[a] = _half(dims[a])
            out.append(axes)
    return out


def _pull_axis(a: np.ndarray, axis: int) -> np.ndarray:
    """Decimate along ``axis``: ``out[i] = a[2i] + (a[2i-1] + a[2i+1]) / 2`` (missing terms 0)."""
    n = a.shape[axis]
    m = _half(n)
    sl = [slice(None)] * a.ndim

    def take(s):
        sl[axis] = s
        return a[tuple(sl)]

    out = take(slice(0, n, 2)).copy()                 # a[2i], i < m
    odd = take(slice(1, n, 2))                        # a[2i+1], i < n // 2
    k = odd.shape[axis]
    half = 0.5 * odd
    sl[axis] = slice(0, k)
    out[tuple(sl)] += half                            # right neighbour 2i+1 of coarse i
    k2 = min(k, m - 1)
    sl2 = [slice(None)] * a.ndim
    sl2[axis] = slice(0, k2)
    sl[axis] = slice(1, 1 + k2)
    out[tuple(sl)] += half[tuple(sl2)]                # left neighbour 2i-1 of coarse i
    return out


def _push_axis(c: np.ndarray, axis: int, n: int) -> np.ndarray:
    """Linear (tent) upsampling along ``axis`` to length n: ``out[2k] = c[k]``,
    ``out[2k+1] = (c[k] + c[k+1]) / 2`` (a missing ``c[k+1]`` counts 0)."""
    shape = list(c.shape)
    shape[axis] = n
    out = np.empty(shape, c.dtype)
    m = c.shape[axis]
    sl = [slice(None)] * c.ndim
    src = [slice(None)] * c.ndim
    sl[axis] = slice(0, n, 2)
    src[axis] = slice(0, (n + 1) // 2)
    out[tuple(sl)] = c[tuple(src)]
    k = n // 2                                        # odd positions 1, 3, ..., 2k-1
    if k:
        left = [slice(None)] * c.ndim
        left[axis] = slice(0, k)
        odd = 0.5 * c[tuple(left)]
        k2 = min(k, m - 1)
        if k2 > 0:
            right = [slice(None)] * c.ndim
            right[axis] = slice(1, 1 + k2)
            tgt = [slice(None)] * c.ndim
            tgt[axis] = slice(0, k2)
            odd[tuple(tgt)] += 0.5 * c[tuple(right)]
        sl[axis] = slice(1, n, 2)
        out[tuple(sl)] = odd
    return out


@dataclass(frozen=True)
class PushPullResult:
    """Filled light field and its confidence, both (F, Ny, Nx, Nv, Nu[, C]) / (F, Ny, Nx, Nv, Nu)."""

    L: np.ndarray
    """float32 values (a trailing channel axis if the input had one)."""
    W: np.ndarray
    """float32 confidence in [0, 1] (see the module docstring)."""
    levels: int
    """Number of pyramid levels below the finest."""


def push_pull_reference(x0: np.ndarray, w0: np.ndarray, *, schedule: str = "xy-first",
                        attenuation: float = 0.5) -> PushPullResult:
    """Fill a splatted light field by pull-push: the plain numpy statement of the
    algorithm (separable passes; slow), which :func:`push_pull` must match.

    x0: (F, Ny, Nx, Nv, Nu[, C]) splatted values (where ``w0`` is 0 they are ignored).
    w0: (F, Ny, Nx, Nv, Nu) splat weights >= 0, in samples (1 = fully covered).
    attenuation: factor in (0, 1] applied to the confidence a filled cell inherits per level.
    """
    w0 = np.asarray(w0, np.float32)
    x0 = np.asarray(x0, np.float32)
    colour = x0.ndim == w0.ndim + 1
    if x0.shape[:w0.ndim] != w0.shape or w0.ndim != 5:
        raise ValueError(f"x0 {x0.shape} and w0 {w0.shape} must be (F, Ny, Nx, Nv, Nu[, C]) and "
                         "(F, Ny, Nx, Nv, Nu)")
    sched = pyramid_schedule(w0.shape, schedule)

    def ex(w):  # broadcast weights over the channel axis
        return w[..., None] if colour else w

    # pull: store clamped weights and weight-normalised values per level
    ws = [np.minimum(w0, np.float32(1.0))]
    xs = [np.where(ex(ws[0]) > 0, x0, np.float32(0.0)).astype(np.float32)]
    for axes in sched:
        w = ws[-1]
        wx = ex(w) * xs[-1]
        for a in axes:
            w = _pull_axis(w, a)
            wx = _pull_axis(wx, a)
        with np.errstate(invalid="ignore", divide="ignore"):
            x = np.where(ex(w) > 0, wx / ex(np.maximum(w, np.float32(1e-30))), np.float32(0.0))
        ws.append(np.minimum(w, np.float32(1.0)))
        xs.append(x.astype(np.float32))

    # push: coarsest to finest
    att = np.float32(attenuation)
    conf = ws[-1].copy()                       # confidence W at the current level
    wp = ws[-1]                                # pushed weight at the current level
    xp = xs[-1]
    for r in range(len(sched) - 1, -1, -1):
        axes = sched[r]
        fine_shape = ws[r].shape
        tw, twx, tc = wp, ex(wp) * xp, conf
        for a in reversed(axes):
            n = fine_shape[a]
            tw = _push_axis(tw, a, n)
            twx = _push_axis(twx, a, n)
            tc = _push_axis(tc, a, n)
        w = ws[r]
        with np.errstate(invalid="ignore", divide="ignore"):
            tx = np.where(ex(tw) > 0, twx / ex(np.maximum(tw, np.float32(1e-30))), np.float32(0.0))
        fill = (1.0 - w) * tw
        den = w + fill
        with np.errstate(invalid="ignore", divide="ignore"):
            xp = np.where(ex(den) > 0, (ex(w) * xs[r] + ex(fill) * tx) / ex(np.maximum(den, np.float32(1e-30))),
                          np.float32(0.0)).astype(np.float32)
        wp = den.astype(np.float32)
        conf = (w + (1.0 - w) * att * tc).astype(np.float32)
    return PushPullResult(L=xp, W=np.clip(conf, 0.0, 1.0), levels=len(sched))


# ----------------------------------------------------------------------------- fast version (numba)
#
# Each kernel is compiled twice: a parallel version for the large levels and a serial
# one for the small levels, where starting the thread pool would cost more than the work.


def _pull_any(w, x, hy, hx, hv, hu, wo, xo):
    """One pull step: w (F, Ny, Nx, Nv, Nu) clamped weights, x (..., C) values → wo (clamped),
    xo at the coarse level, halving the axes flagged 1."""
    F, Ny, Nx, Nv, Nu = w.shape
    _, My, Mx, Mv, Mu = wo.shape
    C = x.shape[5]
    for t in numba.prange(F * My * Mx * Mv):
        k = t % Mv
        r = t // Mv
        j = r % Mx
        r //= Mx
        i = r % My
        f = r // My
        acc = np.zeros(C, np.float32)
        for lo in range(Mu):
            ws = np.float32(0.0)
            for c in range(C):
                acc[c] = 0.0
            for dy in range(-hy, hy + 1):
                yy = i * (1 + hy) + dy
                if yy < 0 or yy >= Ny:
                    continue
                wy = np.float32(1.0) if dy == 0 else np.float32(0.5)
                for dx in range(-hx, hx + 1):
                    xx = j * (1 + hx) + dx
                    if xx < 0 or xx >= Nx:
                        continue
                    wx = wy if dx == 0 else wy * np.float32(0.5)
                    for dv in range(-hv, hv + 1):
                        vv = k * (1 + hv) + dv
                        if vv < 0 or vv >= Nv:
                            continue
                        wv = wx if dv == 0 else wx * np.float32(0.5)
                        for du in range(-hu, hu + 1):
                            uu = lo * (1 + hu) + du
                            if uu < 0 or uu >= Nu:
                                continue
                            a = w[f, yy, xx, vv, uu] * (wv if du == 0 else wv * np.float32(0.5))
                            if a > 0.0:
                                ws += a
                                for c in range(C):
                                    acc[c] += a * x[f, yy, xx, vv, uu, c]
            inv = np.float32(1.0) / ws if ws > 0.0 else np.float32(0.0)
            for c in range(C):
                xo[f, i, j, k, lo, c] = acc[c] * inv
            wo[f, i, j, k, lo] = ws if ws < 1.0 else np.float32(1.0)


def _pull_xy_any(w, x, hy, hx, active, wo, xo):
    """Pull halving (y, x) only, plane by plane: w (F, Ny, Nx, P) clamped weights and
    x (F, Ny, Nx, P*C) values with P = Nv * Nu (C channels interleaved) → wo (F, My, Mx, P)
    clamped, xo (F, My, Mx, P*C). Planes are processed in blocks so the accumulators
    stay in cache while the children stream past. Child planes with active[f, y, x] = 0
    (all weights 0, values finite) are skipped: they would add zeros."""
    F, Ny, Nx, P = w.shape
    _, My, Mx, _ = wo.shape
    C = x.shape[3] // P
    B = 4096
    nb = (P + B - 1) // B
    for t in numba.prange(F * My * Mx * nb):
        blk = t % nb
        r = t // nb
        j = r % Mx
        i = (r // Mx) % My
        f = r // (Mx * My)
        p0 = blk * B
        n = min(P, p0 + B) - p0
        wsum = wo[f, i, j, p0:p0 + n]
        acc = xo[f, i, j, C * p0:C * (p0 + n)]
        wsum[:] = 0.0
        acc[:] = 0.0
        for dy in range(-hy, hy + 1):
            yy = i * (1 + hy) + dy
            if yy < 0 or yy >= Ny:
                continue
            for dx in range(-hx, hx + 1):
                xx = j * (1 + hx) + dx
                if xx < 0 or xx >= Nx or not active[f, yy, xx]:
                    continue
                h = np.float32(1.0)
                if dy != 0:
                    h *= np.float32(0.5)
                if dx != 0:
                    h *= np.float32(0.5)
                wc = w[f, yy, xx, p0:p0 + n]
                xc = x[f, yy, xx, C * p0:C * (p0 + n)]
                if C == 1:
                    for p in range(n):
                        a = h * wc[p]
                        wsum[p] += a
                        acc[p] += a * xc[p]
                else:
                    for p in range(n):
                        a = h * wc[p]
                        wsum[p] += a
                        for c in range(C):
                            acc[C * p + c] += a * xc[C * p + c]
        for p in range(n):
            ws = wsum[p]
            inv = np.float32(1.0) / ws if ws > 0.0 else np.float32(0.0)
            for c in range(C):
                acc[C * p + c] *= inv
            wsum[p] = ws if ws < 1.0 else np.float32(1.0)


@numba.njit(cache=True, inline="always")
def _parents(i, h, M):
    """Coarse parents of fine index i along an axis (h = 1 halved): (p0, w0, p1, w1); a
    missing second parent has weight 0."""
    if h == 0:
        return i, np.float32(1.0), i, np.float32(0.0)
    if i % 2 == 0:
        return i // 2, np.float32(1.0), i // 2, np.float32(0.0)
    p = (i - 1) // 2
    if p + 1 < M:
        return p, np.float32(0.5), p + 1, np.float32(0.5)
    return p, np.float32(0.5), p, np.float32(0.0)


def _push_any(wc, xc, cc, hy, hx, hv, hu, att, w, x, wout, conf):
    """One push step at the fine level: wc, xc, cc are the coarse pushed weights, values and
    confidences; w, x the fine clamped weights and values. x is overwritten with the pushed
    values, wout (may be w) receives the pushed weights, conf the confidences."""
    F, Ny, Nx, Nv, Nu = w.shape
    _, My, Mx, Mv, Mu = wc.shape
    C = x.shape[5]
    for t in numba.prange(F * Ny * Nx * Nv):
        k = t % Nv
        r = t // Nv
        j = r % Nx
        r //= Nx
        i = r % Ny
        f = r // Ny
        ya, ywa, yb, ywb = _parents(i, hy, My)
        xa, xwa, xb, xwb = _parents(j, hx, Mx)
        va, vwa, vb, vwb = _parents(k, hv, Mv)
        tx = np.zeros(C, np.float32)
        for lo in range(Nu):
            wf = w[f, i, j, k, lo]
            if wf >= 1.0:                       # fully covered: keeps its own value
                wout[f, i, j, k, lo] = 1.0
                conf[f, i, j, k, lo] = 1.0
                continue
            ua, uwa, ub, uwb = _parents(lo, hu, Mu)
            tw = np.float32(0.0)
            tc = np.float32(0.0)
            for c in range(C):
                tx[c] = 0.0
            for py in range(2):
                yy = ya if py == 0 else yb
                wy = ywa if py == 0 else ywb
                if wy == 0.0:
                    continue
                for px in range(2):
                    xx = xa if px == 0 else xb
                    wx = xwa if px == 0 else xwb
                    if wx == 0.0:
                        continue
                    for pv in range(2):
                        vv = va if pv == 0 else vb
                        wv = vwa if pv == 0 else vwb
                        if wv == 0.0:
                            continue
                        for pu in range(2):
                            uu = ua if pu == 0 else ub
                            wu = uwa if pu == 0 else uwb
                            if wu == 0.0:
                                continue
                            h = wy * wx * wv * wu
                            tc += h * cc[f, yy, xx, vv, uu]
                            a = h * wc[f, yy, xx, vv, uu]
                            if a > 0.0:
                                tw += a
                                for c in range(C):
                                    tx[c] += a * xc[f, yy, xx, vv, uu, c]
            om = np.float32(1.0) - wf
            den = wf + om * tw
            # tx holds Σ h w x, so (1 - wf) tw (tx / tw) = (1 - wf) tx
            inv = np.float32(1.0) / den if den > 0.0 else np.float32(0.0)
            for c in range(C):
                x[f, i, j, k, lo, c] = (wf * x[f, i, j, k, lo, c] + om * tx[c]) * inv
            wout[f, i, j, k, lo] = den
            cf = wf + om * att * tc
            conf[f, i, j, k, lo] = cf if cf < 1.0 else np.float32(1.0)


def _push_xy_any(wc, xc, cc, hy, hx, att, w, x, wout, conf, store_w):
    """Push halving (y, x) only, plane by plane (dims as :func:`_pull_xy_any`, cc and conf
    like the weights); the pushed weights go to wout only if store_w (the finest level
    does not need them)."""
    F, Ny, Nx, P = w.shape
    _, My, Mx, _ = wc.shape
    C = x.shape[3] // P
    B = 4096
    nb = (P + B - 1) // B
    for t in numba.prange(F * Ny * Nx * nb):
        blk = t % nb
        r = t // nb
        j = r % Nx
        i = (r // Nx) % Ny
        f = r // (Nx * Ny)
        p0 = blk * B
        n = min(P, p0 + B) - p0
        q0, q1 = C * p0, C * (p0 + n)
        ya, ywa, yb, ywb = _parents(i, hy, My)
        xa, xwa, xb, xwb = _parents(j, hx, Mx)
        # the four parent planes (y, x) with their tent weights (missing ones weigh 0)
        h0, h1, h2, h3 = ywa * xwa, ywa * xwb, ywb * xwa, ywb * xwb
        w0p, w1p = wc[f, ya, xa, p0:p0 + n], wc[f, ya, xb, p0:p0 + n]
        w2p, w3p = wc[f, yb, xa, p0:p0 + n], wc[f, yb, xb, p0:p0 + n]
        c0p, c1p = cc[f, ya, xa, p0:p0 + n], cc[f, ya, xb, p0:p0 + n]
        c2p, c3p = cc[f, yb, xa, p0:p0 + n], cc[f, yb, xb, p0:p0 + n]
        x0p, x1p, x2p, x3p = xc[f, ya, xa, q0:q1], xc[f, ya, xb, q0:q1], xc[f, yb, xa, q0:q1], xc[f, yb, xb, q0:q1]
        wf_pl = w[f, i, j, p0:p0 + n]
        wo_pl = wout[f, i, j, p0:p0 + n]
        xf_pl = x[f, i, j, q0:q1]
        cf_pl = conf[f, i, j, p0:p0 + n]
        one = np.float32(1.0)
        if C == 1:                              # the common grey case, kept simple to vectorise
            for p in range(n):
                wf = wf_pl[p]
                a0 = h0 * w0p[p]
                a1 = h1 * w1p[p]
                a2 = h2 * w2p[p]
                a3 = h3 * w3p[p]
                tw = a0 + a1 + a2 + a3
                om = one - wf
                den = wf + om * tw
                inv = one / den if den > 0.0 else np.float32(0.0)
                tx = a0 * x0p[p] + a1 * x1p[p] + a2 * x2p[p] + a3 * x3p[p]
                xf_pl[p] = (wf * xf_pl[p] + om * tx) * inv
                cf = wf + om * att * (h0 * c0p[p] + h1 * c1p[p] + h2 * c2p[p] + h3 * c3p[p])
                cf_pl[p] = min(cf, one)
        else:
            for p in range(n):
                wf = wf_pl[p]
                a0 = h0 * w0p[p]
                a1 = h1 * w1p[p]
                a2 = h2 * w2p[p]
                a3 = h3 * w3p[p]
                tw = a0 + a1 + a2 + a3
                om = one - wf
                den = wf + om * tw
                inv = one / den if den > 0.0 else np.float32(0.0)
                for c in range(C):
                    q = C * p + c
                    tx = a0 * x0p[q] + a1 * x1p[q] + a2 * x2p[q] + a3 * x3p[q]
                    xf_pl[q] = (wf * xf_pl[q] + om * tx) * inv
                cf = wf + om * att * (h0 * c0p[p] + h1 * c1p[p] + h2 * c2p[p] + h3 * c3p[p])
                cf_pl[p] = min(cf, one)
        if store_w:
            for p in range(n):
                wf = wf_pl[p]
                tw = h0 * w0p[p] + h1 * w1p[p] + h2 * w2p[p] + h3 * w3p[p]
                wo_pl[p] = wf + (one - wf) * tw


def _jit_pair(fn, fastmath=False):
    return (numba.njit(cache=True, parallel=True, fastmath=fastmath)(fn),
            numba.njit(cache=True, fastmath=fastmath)(fn))


_FAST = {"nnan", "ninf", "nsz", "arcp"}
"""Fast-math flags for the plane kernels: enough for LLVM to vectorise them, but no
reassociation or FMA contraction, so results do not depend on the buffers' alignment."""

_PULL = _jit_pair(_pull_any)
_PUSH = _jit_pair(_push_any)
_PULL_XY = _jit_pair(_pull_xy_any, fastmath=_FAST)
_PUSH_XY = _jit_pair(_push_xy_any, fastmath=_FAST)

_PARALLEL_MIN_CELLS = 1 << 17
"""Levels with fewer cells run the serial kernels."""


class PushPull:
    """Pull-push for a fixed frame shape, with its pyramid buffers kept between frames.

    shape: (F, Ny, Nx, Nv, Nu); channels: C values per cell. Not thread-safe (one per
    worker). :meth:`run` gives the same result as :func:`push_pull_reference`.
    """

    def __init__(self, shape: tuple[int, ...], channels: int = 1, *, schedule: str = "xy-first",
                 attenuation: float = 0.5):
        if not 0.0 < attenuation <= 1.0:
            raise ValueError("attenuation must be in (0, 1]")
        self.shape = tuple(int(n) for n in shape)
        self.channels = int(channels)
        self.schedule = schedule
        self.attenuation = float(attenuation)
        self.levels = pyramid_schedule(self.shape, schedule)
        self._flags = []
        shapes = [self.shape]
        for axes in self.levels:
            s = list(shapes[-1])
            for a in axes:
                s[a] = _half(s[a])
            shapes.append(tuple(s))
            self._flags.append(tuple(int(a in axes) for a in (_Y, _X, _V, _U)))
        self._shapes = shapes
        # level 0 lives in the caller's arrays; coarser levels here
        self._w = [None] + [np.zeros(s, np.float32) for s in shapes[1:]]
        self._x = [None] + [np.zeros((*s, self.channels), np.float32) for s in shapes[1:]]
        self._c = [None] + [np.zeros(s, np.float32) for s in shapes[1:]]
        self._scratch_w0 = None
        self._all_active = [np.ones(s_[:3], np.bool_) for s_ in shapes]

    @staticmethod
    def _plane(a: np.ndarray) -> np.ndarray:
        """(F, Ny, Nx, Nv, Nu[, C]) → (F, Ny, Nx, Nv * Nu [* C]) view."""
        s = a.shape
        return a.reshape(s[0], s[1], s[2], -1)

    def run(self, x0: np.ndarray, w0_clamped: np.ndarray, W_out: np.ndarray | None = None,
            views: np.ndarray | None = None) -> np.ndarray:
        """Fill ``x0`` in place and return the confidence W.

        x0: (F, Ny, Nx, Nv, Nu, C) float32 C-contiguous splatted values, 0 where the weight is 0
            (overwritten with L).
        w0_clamped: (F, Ny, Nx, Nv, Nu) float32 ``min(w0, 1)`` (read only).
        W_out: optional (F, Ny, Nx, Nv, Nu) float32 buffer for W.
        views: optional (F, Ny, Nx) bool, False for views whose weights are all 0
            (:func:`weighted_views`; computed once per geometry): the finest pull skips them.
        """
        if x0.shape != (*self.shape, self.channels) or x0.dtype != np.float32 or not x0.flags.c_contiguous:
            raise ValueError(f"x0: expected C-contiguous float32 {(*self.shape, self.channels)}, "
                             f"got {x0.dtype} {x0.shape}")
        w0 = np.ascontiguousarray(w0_clamped, np.float32)
        if w0.shape != self.shape:
            raise ValueError(f"w0: expected {self.shape}, got {w0.shape}")
        W = np.empty(self.shape, np.float32) if W_out is None else W_out
        if views is None:
            views = self._all_active[0]
        elif views.shape != self.shape[:3] or views.dtype != np.bool_:
            raise ValueError(f"views: expected bool {self.shape[:3]}, got {views.dtype} {views.shape}")
        ws = [w0] + self._w[1:]
        xs = [x0] + self._x[1:]
        pl = self._plane
        for r, (hy, hx, hv, hu) in enumerate(self._flags):
            k = 0 if ws[r].size >= _PARALLEL_MIN_CELLS else 1
            if hv == 0 and hu == 0:
                _PULL_XY[k](pl(ws[r]), pl(xs[r]), hy, hx, views if r == 0 else self._all_active[r],
                            pl(ws[r + 1]), pl(xs[r + 1]))
            else:
                _PULL[k](ws[r], xs[r], hy, hx, hv, hu, ws[r + 1], xs[r + 1])
        top = len(self._flags)
        np.copyto(W if top == 0 else self._c[top], ws[top])
        att = np.float32(self.attenuation)
        for r in range(top - 1, -1, -1):
            hy, hx, hv, hu = self._flags[r]
            conf = W if r == 0 else self._c[r]
            if r == 0 and not (hv == 0 and hu == 0):   # the caller's weights stay untouched
                if self._scratch_w0 is None:
                    self._scratch_w0 = np.zeros(self.shape, np.float32)
                wout = self._scratch_w0
            else:
                wout = ws[r]        # (not written at level 0 by the xy kernel)
            k = 0 if ws[r].size >= _PARALLEL_MIN_CELLS else 1
            if hv == 0 and hu == 0:
                _PUSH_XY[k](pl(ws[r + 1]), pl(xs[r + 1]), pl(self._c[r + 1]), hy, hx, att,
                            pl(ws[r]), pl(xs[r]), pl(wout), pl(conf), r > 0)
            else:
                _PUSH[k](ws[r + 1], xs[r + 1], self._c[r + 1], hy, hx, hv, hu, att, ws[r], xs[r], wout, conf)
        return W


def weighted_views(w0: np.ndarray) -> np.ndarray:
    """(F, Ny, Nx) bool: the views of w0 (F, Ny, Nx, Nv, Nu) with any weight > 0 (for
    :meth:`PushPull.run`)."""
    return np.asarray(w0).reshape(*np.shape(w0)[:3], -1).max(axis=3) > 0


def push_pull(x0: np.ndarray, w0: np.ndarray, *, schedule: str = "xy-first",
              attenuation: float = 0.5) -> PushPullResult:
    """Fill a splatted light field by pull-push (numba; see the module docstring).

    x0: (F, Ny, Nx, Nv, Nu[, C]) splatted values (where ``w0`` is 0 they are ignored).
    w0: (F, Ny, Nx, Nv, Nu) splat weights >= 0, in samples (1 = fully covered).
    attenuation: factor in (0, 1] applied to the confidence a filled cell inherits per level.
    """
    w0 = np.asarray(w0, np.float32)
    colour = np.ndim(x0) == w0.ndim + 1
    if np.shape(x0)[:w0.ndim] != w0.shape or w0.ndim != 5:
        raise ValueError(f"x0 {np.shape(x0)} and w0 {w0.shape} must be (F, Ny, Nx, Nv, Nu[, C]) and "
                         "(F, Ny, Nx, Nv, Nu)")
    x = np.array(x0, np.float32, order="C", copy=True)
    if not colour:
        x = x[..., None]
    x[w0 <= 0] = 0.0
    pp = PushPull(w0.shape, x.shape[-1], schedule=schedule, attenuation=attenuation)
    W = pp.run(x, np.minimum(w0, np.float32(1.0)), views=weighted_views(w0))
    return PushPullResult(L=x if colour else x[..., 0], W=W, levels=len(pp.levels))
