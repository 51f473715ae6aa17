"""ρ̂ of the Eq. 6 regressors pooled over the views: empirical-Bayes shrinkage per direction.

The Eq. 6 regressors (:attr:`~polycam.motion_options.MotionOptions.depth_regressors`)
replace a ray's positional derivatives by ``ρ̂ L_u, ρ̂ L_v``, ρ̂ pooled over a small
window around the ray (:func:`polycam.eq5.depth_rho`). At high noise and far scenes that
window is not enough: ρ̂ is estimated from ``L_x``, whose signal there is a few grey
levels per view step, and one window's ρ̂ carries more noise than ρ itself (at 8 m and 32
grey levels its noise is ~1.5 ρ on the sphere scene of benchmarks/bench_noise.py).

The views of a light-field camera see nearly the same scene point along one direction
(u, v): their parallax is the disparity times the rig's baseline, a fraction of a
sample for the scenes that make ρ̂ noisy. So the rays of one direction share their ρ up
to the occlusion edges, and their mean over the views ρ̄(f, v, u) is a far less noisy
estimate wherever that holds. :func:`pool_over_views` moves each ray's ρ̂ towards that
mean by as much as its own noise warrants (a James–Stein / empirical-Bayes shrinkage):

    ρ̃ = ρ̄ + g (ρ̂ − ρ̄),    g = τ² / (τ² + var ρ̂),

with var ρ̂ the ray's own noise variance (given: :func:`polycam.eq5.depth_rho`'s model) and
τ² the spread of the true ρ over the views at that direction, estimated as the spread of
ρ̂ over the views less its mean noise variance (kept ≥ 0). Where the views see one depth
and the noise dominates, g → 0 and the ray takes the views' mean; where the depth differs
across the views (silhouettes) or the noise is small (τ² ≫ var ρ̂), g → 1 and ρ̂ stays.

The pooled ρ̃'s noise variance, which the errors-in-variables correction of the solver
needs (:class:`polycam.eq5.RegressorMix`), is ``g² var ρ̂ + (1 − g)² var ρ̄``. The mean's
variance is not var ρ̂ / n: neighbouring views share their filters' samples, so their ρ̂
errors correlate. It is measured from the data: two halves of the views (the first and
the last (k − 1) // 2 of the k view columns across x, the middle one or two left out) give
two nearly independent means per direction whose difference has variance ≈ var ρ̄ n (1 /
n_a + 1 / n_b) (n, n_a, n_b their ray counts); its median over the directions, in units of
the directions' mean var ρ̂, is the factor ``q`` (robust to the few directions where the
halves see different depths). The count scaling holds for independent views; where the
noise is shared over more than the gap (tests/test_rho_pool.py: a 3 x 3 box across the
views) q comes out low (there 0.77 of the truth), and so does the variance reported.

This module is the method and its numpy form (used by :func:`polycam.eq5.depth_regularise`);
the solver runs the same on its int16 ρ̂ in numba (``polycam.eq5._pool_rho``, tested equal).

Dims: (F, ny, nx, Nv, Nu) arrays over faces, views (y, x) and directions (v, u), as the
solver keeps them (docs/conventions.md); NaN marks a ray without ρ̂ (measured regressors
kept, or outside the valid views). Units: ρ in u per unit of x (the solver's), its
variance in those units squared. Measurements: docs/motion_log.md, Session 24.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["PooledRho", "pool_over_views"]

_CHI2_1_MEDIAN = 0.454936
"""Median of χ² with one degree of freedom: a squared Gaussian's median / its variance."""


@dataclass(frozen=True)
class PooledRho:
    """The result of :func:`pool_over_views`."""

    rho: np.ndarray
    """(F, ny, nx, Nv, Nu) float32 pooled ρ̃ (NaN where the input was NaN)."""
    var: np.ndarray
    """(F, ny, nx, Nv, Nu) float32 noise variance of ρ̃, ``g² var ρ̂ + (1 − g)² var ρ̄`` (NaN likewise)."""
    gain: np.ndarray
    """(F, ny, nx, Nv, Nu) float32 g ∈ [0, 1]: the share of the ray's own ρ̂ − ρ̄ kept (NaN likewise)."""
    q: float
    """var ρ̄ / mean var ρ̂ over the views, measured from the two halves of the views
    (NaN when they could not be formed: then ρ̂ is returned unchanged, g = 1)."""


def pool_over_views(rho: np.ndarray, var: np.ndarray) -> PooledRho:
    """Shrink each ray's ρ̂ towards the mean over the views at its direction (module docstring).

    rho: (F, ny, nx, Nv, Nu) float ρ̂ per ray, NaN where there is none; var: the same dims,
    the noise variance of each ρ̂ (finite and > 0 where rho is finite). Directions with fewer
    than 4 rays, or views that cannot be split into two halves of columns holding rays,
    keep their ρ̂ (g = 1).
    """
    rho = np.asarray(rho, np.float64)
    var = np.asarray(var, np.float64)
    if rho.ndim != 5 or var.shape != rho.shape:
        raise ValueError(f"rho and var must have the same 5 dims (F, ny, nx, Nv, Nu), got {rho.shape}, {var.shape}")
    ok = np.isfinite(rho) & np.isfinite(var) & (var > 0)
    n = ok.sum(axis=(1, 2))                                      # (F, Nv, Nu) rays per direction
    r0 = np.where(ok, rho, 0.0)
    v0 = np.where(ok, var, 0.0)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = r0.sum(axis=(1, 2)) / n                          # ρ̄ (F, Nv, Nu)
        spread = np.where(ok, (rho - mean[:, None, None]) ** 2, 0.0).sum(axis=(1, 2)) / (n - 1)
        mean_var = v0.sum(axis=(1, 2)) / n                      # mean var ρ̂ over the views
    q = _mean_noise_ratio(r0, ok, mean_var)
    live = (n >= 4) & np.isfinite(mean_var) & (mean_var > 0)
    if not math.isfinite(q):
        live[...] = False
    tau2 = np.where(live, np.maximum(spread - mean_var, 0.0), 0.0)[:, None, None]
    with np.errstate(invalid="ignore", divide="ignore"):
        g = np.where(live[:, None, None] & ok, tau2 / (tau2 + var), 1.0)
    mean_b = np.where(live, mean, 0.0)[:, None, None]
    out = np.where(ok, mean_b + g * (rho - mean_b), np.nan)
    var_mean = (q * mean_var if math.isfinite(q) else np.zeros_like(mean_var))[:, None, None]
    var_out = np.where(ok, g * g * var + (1.0 - g) ** 2 * np.where(live[:, None, None], var_mean, 0.0), np.nan)
    return PooledRho(rho=out.astype(np.float32), var=var_out.astype(np.float32),
                     gain=np.where(ok, g, np.nan).astype(np.float32), q=q)


def _mean_noise_ratio(r0: np.ndarray, ok: np.ndarray, mean_var: np.ndarray) -> float:
    """var ρ̄ / mean var ρ̂ (module docstring): ρ̄_a, ρ̄_b the means over the first and the last
    ``h = (k − 1) // 2`` of the k view columns that hold rays (the middle column left out,
    so that noise shared by neighbouring views does not enter both); the median over the
    directions of (ρ̄_a − ρ̄_b)², in units of the direction's mean var ρ̂ and of
    n (1 / n_a + 1 / n_b) (the means' variance for n, n_a, n_b rays: each ∝ 1 / its count),
    over the χ²₁ median. NaN without two halves (k < 3)."""
    cols = np.flatnonzero(ok.any(axis=(0, 1, 3, 4)))
    h = (len(cols) - 1) // 2
    if h < 1:
        return math.nan
    n = ok.sum(axis=(1, 2)).astype(np.float64)
    means, inv = [], 0.0
    for c in (cols[:h], cols[-h:]):
        k = ok[:, :, c].sum(axis=(1, 2))
        with np.errstate(invalid="ignore", divide="ignore"):
            means.append(r0[:, :, c].sum(axis=(1, 2)) / k)
            inv = inv + 1.0 / k
    with np.errstate(invalid="ignore", divide="ignore"):
        d = (means[0] - means[1]) ** 2 / (n * inv) / mean_var
    d = d[np.isfinite(d)]
    if d.size == 0:
        return math.nan
    return float(np.median(d)) / _CHI2_1_MEDIAN
