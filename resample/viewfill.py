"""Depth-aware filling of the views between cameras (a plane sweep per view, lumigraph style).

Pull-push fills a view that no camera measured by interpolating its neighbours'
views at fixed (u, v): the depth-free limit, which ghosts wherever the scene is
not at infinity and breaks the plenoptic constraint the motion solver relies on.
This module replaces those views by interpolation *along the disparity*.

Geometry (face coordinates, SPEC.md). A scene point at depth ``Z`` in front of the
focal plane seen from viewpoint ``(x, y)`` has ``u = f (P_x - x) / Z``, so between two
viewpoints its direction moves by ``Δu = -f Δx / Z``. In grid indices, with the
*disparity* ``δ = f · step_x / (step_u · Z)`` (u-steps per x-step),

    L(target)(iv, iu) ≈ L(source s)(iv - δ r_y Δiy_s, iu - δ Δix_s),
    r_y = (step_y / step_x) (step_u / step_v),   Δi_s = source index − target index.

**Which views.** A *source* is a view the cameras measured (a share of at least
``source_coverage`` of its cells have a full splat weight); a *target* is a view
with (almost) no measured cell (``target_coverage``). Each target takes the source
views within the smallest square ring (Chebyshev radius 1, 2, ... up to
``max_radius``) that holds at least two of them, weighted by ``1 / distance²``.
For an auto grid (a view at every camera and one half-way) that is the two
cameras either side of a half-way view and the four around a centre view.

**Sweep.** For each candidate ``δ`` (``disparities``) every target sample gets the
source samples at the shifted positions (bilinear) and the cost is their weighted
variance, box-averaged over a ``(2 window + 1)²`` patch in (u, v). The disparity
with the smallest cost wins, refined to a fraction of a step by a parabola through
its neighbours. A candidate that sends a source off its view leaves that sample's
cost undefined (the box average uses the defined ones).

**Blend.** The target sample is the weighted mean of the source samples at its
disparity, each source weighted by ``1 / distance²`` times its confidence there.
The confidence ``W`` of filled samples stays the pull-push one (interpolated, not
measured: ``≤ attenuation``).

Grey and colour frames are matched on the mean over channels and blended per channel.
No file I/O.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass

import numba
import numpy as np

from polycam.lightfield import LightFieldGrid

__all__ = ["ViewFillOptions", "ViewFillPlan", "plan_view_fill", "fill_views"]

log = logging.getLogger(__name__)


_MAX_CANDIDATES = 64
"""Most disparity candidates swept at full resolution (a larger range gets a coarser step)."""


@dataclass(frozen=True)
class ViewFillOptions:
    """Settings of the depth-aware view filling (see the module docstring)."""

    min_depth: float = 0.5
    """[m] nearest depth in front of the focal plane the sweep considers; sets the largest
    disparity ``f step_x / (step_u min_depth)``."""
    disparity_step: float = 0.25
    """Candidate spacing [u-steps of motion per x-step of viewpoint] before the sub-step refinement."""
    window: int = 3
    """Half-width [samples] of the (u, v) box over which the matching cost is averaged."""
    source_coverage: float = 0.25
    """A view is a source when at least this share of its cells have a full splat weight."""
    target_coverage: float = 0.02
    """A view is filled when less than this share of its cells have a full splat weight."""
    max_radius: int = 3
    """Largest Chebyshev distance [views] at which sources are looked for."""
    downsample: int = 2
    """The sweep runs on ``downsample x downsample`` averages of the views (and their disparity
    step is ``downsample`` times ``disparity_step``): much faster, and the box is wider."""
    refine: bool = False
    """After the sweep, try ``±disparity_step`` around it at full resolution."""
    holes: bool = False
    """Also re-fill the holes (``W <= 0.5``) of the measured views, from the measured views
    around them (the pull-push fills them depth-free from the neighbouring views)."""

    def __post_init__(self) -> None:
        if not (self.min_depth > 0 and self.disparity_step > 0 and self.window >= 0 and self.max_radius >= 1):
            raise ValueError("min_depth and disparity_step must be > 0, window >= 0, max_radius >= 1")
        if not 0 <= self.target_coverage < self.source_coverage <= 1:
            raise ValueError("need 0 <= target_coverage < source_coverage <= 1")


@dataclass(frozen=True)
class ViewFillPlan:
    """Which views are filled from which, for one grid and one splat geometry."""

    targets: tuple[tuple[int, int, int], ...]
    """(face, iy, ix) of every view to fill."""
    sources: tuple[np.ndarray, ...]
    """Per target: (S, 2) int64 source view indices (iy, ix) on the same face."""
    offsets: tuple[np.ndarray, ...]
    """Per target: (S, 2) float64 source minus target index (Δiy, Δix)."""
    weights: tuple[np.ndarray, ...]
    """Per target: (S,) float32 source weights ``1 / distance²`` (distance in metres), summing to 1."""
    disparities: np.ndarray
    """(K,) float64 candidate disparities [u-steps per x-step], ascending."""
    r_y: tuple[float, ...]
    """Per face: v-steps per y-step for one u-step per x-step (``(step_y / step_x)(step_u / step_v)``)."""
    holes_only: tuple[bool, ...] = ()
    """Per target: a measured view of which only the holes (``W <= 0.5``) are re-filled."""

    def __len__(self) -> int:
        return len(self.targets)


def plan_view_fill(grid: LightFieldGrid, w_clamped: np.ndarray,
                   options: ViewFillOptions | None = None) -> ViewFillPlan:
    """The fill plan for ``grid`` given the clamped splat weights ``w_clamped``
    (F, Ny, Nx, Nv, Nu) in [0, 1] (1 = measured)."""
    opts = options or ViewFillOptions()
    F, Ny, Nx, Nv, Nu = grid.shape
    cov = np.mean(np.asarray(w_clamped) >= 1.0, axis=(3, 4))             # (F, Ny, Nx)
    sx = grid.x.step if grid.x.count > 1 else 0.0
    sy = grid.y.step if grid.y.count > 1 else 0.0
    targets, sources, offsets, weights, holes_only = [], [], [], [], []
    for f in range(F):
        src = cov[f] >= opts.source_coverage
        if src.sum() < 2:
            continue
        for j in range(Ny):
            for i in range(Nx):
                own = bool(src[j, i])
                if cov[f, j, i] >= opts.target_coverage and not (opts.holes and own):
                    continue
                others = src.copy()
                others[j, i] = False
                for r in range(1, opts.max_radius + 1):
                    jj, ii = np.nonzero(others[max(0, j - r):j + r + 1, max(0, i - r):i + r + 1])
                    if jj.size >= 2:
                        break
                if jj.size < 2:
                    continue
                jj = jj + max(0, j - r)
                ii = ii + max(0, i - r)
                d2 = ((jj - j) * sy) ** 2 + ((ii - i) * sx) ** 2
                w = 1.0 / np.maximum(d2, 1e-30)
                targets.append((f, j, i))
                holes_only.append(own)
                sources.append(np.stack([jj, ii], axis=1).astype(np.int64))
                offsets.append(np.stack([jj - j, ii - i], axis=1).astype(np.float64))
                weights.append((w / w.sum()).astype(np.float32))
    # candidate disparities: 0 (infinity) up to the nearest depth, on the face with the largest f
    r_y = []
    dmax = 0.0
    for fc in grid.faces:
        su = grid.u.step if grid.u.count > 1 else 1.0
        sv = grid.v.step if grid.v.count > 1 else 1.0
        step_x = sx if sx > 0 else sy
        step_y = sy if sy > 0 else sx
        r_y.append((step_y / step_x) * (su / sv) if step_x > 0 else 1.0)
        if step_x > 0:
            dmax = max(dmax, fc.f * step_x / (su * opts.min_depth))
    step = opts.disparity_step
    if dmax / step > _MAX_CANDIDATES:
        (log.warning if targets else log.debug)("view fill: disparities up to %.3g u-steps per x-step (min_depth %.3g m) would need %d "
                    "candidates; using %d, %.3g apart", dmax, opts.min_depth, int(dmax / step), _MAX_CANDIDATES,
                    dmax / _MAX_CANDIDATES)
        step = dmax / _MAX_CANDIDATES
    n = int(math.ceil(dmax / step)) + 1
    disp = np.arange(-1, n + 1) * step                          # one step beyond each end for the refinement
    plan = ViewFillPlan(tuple(targets), tuple(sources), tuple(offsets), tuple(weights), disp, tuple(r_y),
                        tuple(holes_only))
    log.info("view fill: %d views filled from their neighbours over %d disparities (0..%.2f u-steps per x-step)",
             len(plan), disp.size, dmax)
    return plan


# ----------------------------------------------------------------------------- numba kernels
#
# One parallel loop over the target views; everything inside is serial (the views are
# many and equal in size, and a parallel region per small step costs more than it
# saves on a loaded machine).


@numba.njit(cache=True, inline="always")
def _corners(y, x, Nv, Nu):
    """Bilinear corners of (y, x) inside an Nv x Nu image (y, x >= 0 and within the image):
    (y0, x0, y1, x1, fy, fx)."""
    y0 = min(int(y), Nv - 2) if Nv > 1 else 0
    x0 = min(int(x), Nu - 2) if Nu > 1 else 0
    y1 = y0 + 1 if Nv > 1 else 0
    x1 = x0 + 1 if Nu > 1 else 0
    return y0, x0, y1, x1, np.float32(y - y0), np.float32(x - x0)


@numba.njit(cache=True, inline="always")
def _bilinear(img, y, x):
    """Bilinear sample of img (Nv, Nu) at (y, x); (value, inside)."""
    Nv, Nu = img.shape
    if not (y >= 0.0 and x >= 0.0 and y <= Nv - 1 and x <= Nu - 1):
        return np.float32(0.0), False
    y0, x0, y1, x1, fy, fx = _corners(y, x, Nv, Nu)
    a = img[y0, x0] + fx * (img[y0, x1] - img[y0, x0])
    if fy == 0.0:
        return a, True
    b = img[y1, x0] + fx * (img[y1, x1] - img[y1, x0])
    return a + fy * (b - a), True


@numba.njit(cache=True)
def _cost(G, S, dy, dx, sw, base, off, scale, r_y, cost, valid):
    """Per target sample (v, u): weighted variance of the S source samples (G: (≥S, Nv, Nu))
    at disparity ``base[v, u] + off`` [full-resolution units; ``scale`` converts to this
    level]; valid = 1 where every source sample is inside its view."""
    Nv, Nu = cost.shape
    for v in range(Nv):
        for u in range(Nu):
            d = (base[v, u] + off) * scale
            s0 = np.float32(0.0)
            s1 = np.float32(0.0)
            s2 = np.float32(0.0)
            ok = True
            for s in range(S):
                p, inside = _bilinear(G[s], v - d * r_y * dy[s], u - d * dx[s])
                if not inside:
                    ok = False
                    break
                s0 += sw[s]
                s1 += sw[s] * p
                s2 += sw[s] * p * p
            if ok:
                m = s1 / s0
                c = s2 / s0 - m * m
                cost[v, u] = c if c > 0.0 else np.float32(0.0)
                valid[v, u] = 1.0
            else:
                cost[v, u] = 0.0
                valid[v, u] = 0.0


@numba.njit(cache=True, fastmath=True)
def _cost_const(G, S, dy, dx, sw, d, r_y, cost, valid):
    """:func:`_cost` for one disparity ``d`` [this level's units] at every sample: the
    shifts and interpolation weights are the same everywhere."""
    Nv, Nu = cost.shape
    oy = np.empty(S)
    ox = np.empty(S)
    iy = np.empty(S, np.int64)
    ix = np.empty(S, np.int64)
    fy = np.empty(S, np.float32)
    fx = np.empty(S, np.float32)
    u_lo, u_hi = 0, Nu - 1
    for s in range(S):
        oy[s] = -d * r_y * dy[s]
        ox[s] = -d * dx[s]
        iy[s] = int(math.floor(oy[s]))
        ix[s] = int(math.floor(ox[s]))
        fy[s] = oy[s] - iy[s]
        fx[s] = ox[s] - ix[s]
        u_lo = max(u_lo, int(math.ceil(-ox[s])))
        u_hi = min(u_hi, int(math.floor(Nu - 1 - ox[s])))
    for v in range(Nv):
        row_ok = u_lo <= u_hi
        for s in range(S):
            y = v + oy[s]
            if y < 0.0 or y > Nv - 1:
                row_ok = False
        if not row_ok:
            for u in range(Nu):
                cost[v, u] = 0.0
                valid[v, u] = 0.0
            continue
        for u in range(u_lo):
            cost[v, u] = 0.0
            valid[v, u] = 0.0
        for u in range(u_hi + 1, Nu):
            cost[v, u] = 0.0
            valid[v, u] = 0.0
        for u in range(u_lo, u_hi + 1):
            s0 = np.float32(0.0)
            s1 = np.float32(0.0)
            s2 = np.float32(0.0)
            for s in range(S):
                y0 = v + iy[s]
                x0 = u + ix[s]
                y1 = min(y0 + 1, Nv - 1)
                x1 = min(x0 + 1, Nu - 1)
                a = G[s, y0, x0] + fx[s] * (G[s, y0, x1] - G[s, y0, x0])
                b = G[s, y1, x0] + fx[s] * (G[s, y1, x1] - G[s, y1, x0])
                p = a + fy[s] * (b - a)
                s0 += sw[s]
                s1 += sw[s] * p
                s2 += sw[s] * p * p
            m = s1 / s0
            c = s2 / s0 - m * m
            cost[v, u] = c if c > 0.0 else np.float32(0.0)
            valid[v, u] = 1.0


@numba.njit(cache=True, fastmath=True)
def _box(a, r, tmp, out):
    """out = the (2r+1)² box sum of a (clipped at the borders); tmp: scratch of a's shape."""
    Nv, Nu = a.shape
    for v in range(Nv):
        acc = np.float32(0.0)
        for u in range(min(r, Nu - 1) + 1):
            acc += a[v, u]
        for u in range(Nu):
            tmp[v, u] = acc
            if u + r + 1 < Nu:
                acc += a[v, u + r + 1]
            if u - r >= 0:
                acc -= a[v, u - r]
    acc2 = np.zeros(Nu, np.float32)
    for v in range(min(r, Nv - 1) + 1):
        for u in range(Nu):
            acc2[u] += tmp[v, u]
    for v in range(Nv):
        for u in range(Nu):
            out[v, u] = acc2[u]
        if v + r + 1 < Nv:
            for u in range(Nu):
                acc2[u] += tmp[v + r + 1, u]
        if v - r >= 0:
            for u in range(Nu):
                acc2[u] -= tmp[v - r, u]


@numba.njit(cache=True)
def _sweep(G, S, dy, dx, sw, base, offs, scale, r_y, window, out, const):
    """out[v, u] = base + the offset (of ``offs``, ascending, equally spaced) with the smallest
    box-averaged cost, refined by a parabola through its neighbours (``const``: base is 0)."""
    Nv, Nu = out.shape
    cost = np.empty((Nv, Nu), np.float32)
    valid = np.empty((Nv, Nu), np.float32)
    tmp = np.empty((Nv, Nu), np.float32)
    agg_c = np.empty((Nv, Nu), np.float32)
    agg_n = np.empty((Nv, Nu), np.float32)
    best = np.full((Nv, Nu), np.inf, np.float32)
    best_k = np.full((Nv, Nu), -1, np.int64)
    c_left = np.full((Nv, Nu), np.inf, np.float32)
    c_right = np.full((Nv, Nu), np.inf, np.float32)
    prev = np.full((Nv, Nu), np.inf, np.float32)
    K = offs.shape[0]
    for k in range(K):
        if const:
            _cost_const(G, S, dy, dx, sw, offs[k] * scale, r_y, cost, valid)
        else:
            _cost(G, S, dy, dx, sw, base, offs[k], scale, r_y, cost, valid)
        _box(cost, window, tmp, agg_c)
        _box(valid, window, tmp, agg_n)
        for v in range(Nv):
            for u in range(Nu):
                n = agg_n[v, u]
                c = agg_c[v, u] / n if n > 0.5 else np.float32(np.inf)
                if best_k[v, u] == k - 1:
                    c_right[v, u] = c
                if c < best[v, u]:
                    best[v, u] = c
                    best_k[v, u] = k
                    c_left[v, u] = prev[v, u]
                    c_right[v, u] = np.inf
                prev[v, u] = c
    step = offs[1] - offs[0] if K > 1 else 0.0
    for v in range(Nv):
        for u in range(Nu):
            k = best_k[v, u]
            if k < 0:
                out[v, u] = base[v, u]
                continue
            d = base[v, u] + offs[k]
            cl, c0, cr = c_left[v, u], best[v, u], c_right[v, u]
            if np.isfinite(cl) and np.isfinite(cr):
                den = cl - 2.0 * c0 + cr
                if den > 0.0:
                    d += step * max(-0.5, min(0.5, 0.5 * (cl - cr) / den))
            out[v, u] = d


@numba.njit(cache=True)
def _shrink(G, S, k, out):
    """k x k box average of the first S views of G (S, Nv, Nu) into out (S, ceil(Nv/k), ceil(Nu/k))."""
    _, Nv, Nu = G.shape
    _, Mv, Mu = out.shape
    for s in range(S):
        for i in range(Mv):
            for j in range(Mu):
                acc = np.float32(0.0)
                n = 0
                for a in range(k):
                    for b in range(k):
                        y = k * i + a
                        x = k * j + b
                        if y < Nv and x < Nu:
                            acc += G[s, y, x]
                            n += 1
                out[s, i, j] = acc / n


@numba.njit(cache=True)
def _upsample(c, k, out):
    """Bilinear upsampling of a map of k x k averages to out's dims."""
    Mv, Mu = c.shape
    Nv, Nu = out.shape
    h = 0.5 * (k - 1)
    for v in range(Nv):
        y = min(max((v - h) / k, 0.0), Mv - 1.0)
        for u in range(Nu):
            x = min(max((u - h) / k, 0.0), Mu - 1.0)
            out[v, u], _ = _bilinear(c, y, x)


@numba.njit(cache=True, fastmath=True)
def _blend(X, A, S, dy, dx, sw, r_y, d, out):
    """out[v, u, :] = Σ_s a_s X_s(v − d r_y dy_s, u − d dx_s) / Σ_s a_s (bilinear) with
    a_s = sw_s · A_s (nearest sample) at the per-sample disparity d (Nv, Nu); X: (S, Nv, Nu, C),
    A: (S, Nv, Nu). Samples no source reaches keep out."""
    _, Nv, Nu, C = X.shape
    acc = np.zeros(C, np.float32)
    ky = np.empty(S)
    for s in range(S):
        ky[s] = r_y * dy[s]
    for v in range(Nv):
        for u in range(Nu):
            dd = d[v, u]
            tw = np.float32(0.0)
            for c in range(C):
                acc[c] = 0.0
            for s in range(S):
                yy = v - dd * ky[s]
                xx = u - dd * dx[s]
                if not (yy >= 0.0 and xx >= 0.0 and yy <= Nv - 1 and xx <= Nu - 1):
                    continue
                y0, x0, y1, x1, fy, fx = _corners(yy, xx, Nv, Nu)
                a = sw[s] * max(A[s, y0 + (fy > 0.5), x0 + (fx > 0.5)], np.float32(1e-3))
                tw += a
                for c in range(C):
                    p0 = X[s, y0, x0, c] + fx * (X[s, y0, x1, c] - X[s, y0, x0, c])
                    p1 = X[s, y1, x0, c] + fx * (X[s, y1, x1, c] - X[s, y1, x0, c])
                    acc[c] += a * (p0 + fy * (p1 - p0))
            if tw > 0.0:
                for c in range(C):
                    out[v, u, c] = acc[c] / tw


@numba.njit(cache=True, parallel=True)
def _fill_all(grey, Lsrc, L, W, targets, holes, srcs, offs, sws, nsrc, r_y, coarse, k_down, fine, window,
              disp_out):
    """Fill every target view of L (F, Ny, Nx, Nv, Nu, C) in place from the source views of
    Lsrc (L itself when no target is a source); disp_out (T, Nv, Nu). A target with holes[t]
    keeps its samples with W > 0.5."""
    F, Ny, Nx, Nv, Nu, C = L.shape
    Mv, Mu = (Nv + k_down - 1) // k_down, (Nu + k_down - 1) // k_down
    T = targets.shape[0]
    Smax = srcs.shape[1]
    for t in numba.prange(T):
        f, j, i = targets[t, 0], targets[t, 1], targets[t, 2]
        S = nsrc[t]
        G = np.empty((Smax, Nv, Nu), np.float32)
        A = np.empty((Smax, Nv, Nu), np.float32)
        X = np.empty((Smax, Nv, Nu, C), np.float32)
        for s in range(S):
            G[s] = grey[f, srcs[t, s, 0], srcs[t, s, 1]]
            A[s] = W[f, srcs[t, s, 0], srcs[t, s, 1]]
            X[s] = Lsrc[f, srcs[t, s, 0], srcs[t, s, 1]]
        dy = offs[t, :, 0].copy()
        dx = offs[t, :, 1].copy()
        sw = sws[t]
        ry = r_y[f]
        d = disp_out[t]
        # coarse: the whole disparity range at 1/k_down resolution
        Gc = np.empty((Smax, Mv, Mu), np.float32)
        _shrink(G, S, k_down, Gc)
        dc = np.empty((Mv, Mu), np.float32)
        _sweep(Gc, S, dy, dx, sw, np.zeros((Mv, Mu), np.float32), coarse, 1.0 / k_down, ry, window, dc, True)
        _upsample(dc, k_down, d)
        if fine.shape[0] > 1:       # a few steps around it at full resolution
            base = d.copy()
            _sweep(G, S, dy, dx, sw, base, fine, 1.0, ry, window, d, False)
        if holes[t]:
            tmp = Lsrc[f, j, i].copy()
            _blend(X, A, S, dy, dx, sw, ry, d, tmp)
            for v in range(Nv):
                for u in range(Nu):
                    if W[f, j, i, v, u] <= 0.5:
                        L[f, j, i, v, u] = tmp[v, u]
        else:
            _blend(X, A, S, dy, dx, sw, ry, d, L[f, j, i])


# ----------------------------------------------------------------------------- driver


def fill_views(L: np.ndarray, W: np.ndarray, plan: ViewFillPlan, options: ViewFillOptions | None = None,
               disparity_out: np.ndarray | None = None) -> None:
    """Fill the target views of ``plan`` in ``L`` in place (see the module docstring).

    L: (F, Ny, Nx, Nv, Nu, C) float32 pulled-pushed values (C-contiguous).
    W: (F, Ny, Nx, Nv, Nu) float32 confidences (read: source confidences).
    disparity_out: optional (F, Ny, Nx, Nv, Nu) float32 array receiving the disparity chosen
        at each filled sample [u-steps per x-step] (for diagnostics).
    """
    opts = options or ViewFillOptions()
    T = len(plan)
    if not T:
        return
    if L.ndim != 6 or L.dtype != np.float32 or not L.flags.c_contiguous or L.shape[:5] != W.shape:
        raise ValueError("L must be C-contiguous float32 (F, Ny, Nx, Nv, Nu, C) and W (F, Ny, Nx, Nv, Nu)")
    Nv, Nu = L.shape[3:5]
    grey = np.ascontiguousarray(L.mean(axis=5) if L.shape[5] > 1 else L[..., 0])
    Smax = max(s.shape[0] for s in plan.sources)
    srcs = np.zeros((T, Smax, 2), np.int64)
    offs = np.zeros((T, Smax, 2), np.float64)
    sws = np.zeros((T, Smax), np.float32)
    nsrc = np.zeros(T, np.int64)
    for t in range(T):
        n = plan.sources[t].shape[0]
        srcs[t, :n] = plan.sources[t]
        offs[t, :n] = plan.offsets[t]
        sws[t, :n] = plan.weights[t]
        nsrc[t] = n
    disp = np.empty((T, Nv, Nu), np.float32)
    step = float(plan.disparities[1] - plan.disparities[0])
    k = int(opts.downsample)
    d_max = plan.disparities[-1]
    coarse = np.arange(-1, int(math.ceil(d_max / (k * step))) + 1) * (k * step)   # same step at 1/k resolution
    fine = np.array([-step, 0.0, step]) if opts.refine else np.zeros(1)
    holes = np.array(plan.holes_only if plan.holes_only else [False] * T, np.bool_)
    Lsrc = L.copy() if holes.any() else L          # sources are re-filled too: read a snapshot
    _fill_all(grey, Lsrc, L, np.ascontiguousarray(W, np.float32), np.array(plan.targets, np.int64), holes, srcs,
              offs, sws, nsrc, np.array(plan.r_y, np.float64), coarse, k, fine, int(opts.window), disp)
    if disparity_out is not None:
        for t, (f, j, i) in enumerate(plan.targets):
            disparity_out[f, j, i] = disp[t]
