"""The derivative filters' gain across frequencies, and a linear array's ρ̂ corrected for it.

A filter pair (:class:`polycam.derivatives.FilterPair`: prefilter ``p``, derivative ``d``,
correlation taps over ``k = −r..r``) differentiates a sampled sinusoid of frequency ω [rad per
sample] with the relative gain (:func:`derivative_gain`)

    R(ω) = Σ_k d_k sin(k ω) / (ω Σ_k p_k cos(k ω)),

1 as ω → 0 (``d`` has first moment 1). The solver's default pairs differ: ``fs3``, across the
views, overshoots (R = 1.02 at 0.6, 1.07 at 1, 1.30 at 2 rad per sample); ``fs5``, along u and v,
stays within 0.7 % up to 1 rad per sample (0.967 at 2).

A linear array's ρ̂ (:func:`polycam.eq5.depth_rho` with ``linear``) is a ratio of window sums,
S_xu / S_uu, of the view axis's derivative L_x (``fs3`` across the views) and the direction's L_u
(``fs5`` along u). Texture seen ``k = ρ step_x / step_u`` samples apart from one view to the next
has each frequency ω along u at frequency k ω across the views, so that frequency enters the
ratio as ``ρ R_x(k ω) / R_u(ω)``: where the views are a sizeable fraction of a sample apart
(camera arrays: the solver's finest level keeps k up to ``max_view_disparity`` = 0.75 samples)
ρ̂ reads high, by 1–4 % on the rays that carry the gradient energy of the OAK-D Lite's sessions
(k ≈ 0.6). On a 2-D array that only changes how fast the iteration converges (the warp
interpolates the measured views, so the converged estimate does not depend on the derivatives'
gain); on a linear array the warp extrapolates the single-view axis with the views' mean ρ̄
(Eq. 6), so the translation along that axis converged short by the same factor
(docs/motion.md, "Linear arrays").

:func:`linear_rho_gain` measures the view filter's share per ray at the RMS frequency of ρ̂'s own
window, ``Ω² = S(L_uu²) / S(L_u²)`` (the window and mask of S_uu, so weighted as ρ̂ is; L_uu is the
derivative filter applied to L_u, L_u here its prefilter applied once more), as
``R_x(k Ω)``; the solver divides ρ̂ by it. Exact for one sinusoid; for a spectrum the mean of R
over the window's frequencies, to second order in ω the same (R is 1 + a ω² + …). The direction
filter's share (ρ̂ times ``R_u(Ω)``) is left in: it acts alone where k is small, and taking it out
as well made the linear arrays of benchmarks/bench_linear.py (k ≈ 0.05) 3–8 % worse over 6
motions (the warp reads the directions through its own interpolation, not through R_u).

Dims: frames (F, Ny, Nx, Nv, Nu) over faces, views (y, x) and directions (v, u), as the solver
keeps them (docs/conventions.md); ρ̂ in u per unit of x (the solver's), over the views of its
work arrays (origin ``vo``, :func:`polycam.eq5._view_origin`). No I/O.
"""

from __future__ import annotations

import numba
import numpy as np

from .derivatives import FilterPair, correlate_axis
from .eq5 import _QMAX, _RHO_NONE, rho_window_taps

__all__ = ["derivative_gain", "window_rms_frequency", "linear_rho_gain", "divide_rho_by_gain"]

_MAX_FREQUENCY = np.pi / 2
"""[rad per sample] Ω, and the view axis's k Ω, are capped here (R_fs3 = 1.18 there): above, the
window is dominated by texture aliased along the directions or across the views, whose reading no
single frequency describes (R_fs3 peaks at 1.39 near 2.4 rad per sample and falls to 0 at π)."""

_TABLE_SIZE = 1024
"""Samples of R over [0, ``_MAX_FREQUENCY``] in :func:`divide_rho_by_gain`'s table (linear
interpolation between: within 1e-6 of R for the solver's filters)."""


def derivative_gain(pair: FilterPair, omega: np.ndarray) -> np.ndarray:
    """R(ω) of ``pair`` (module docstring) at ``omega`` (any dims) [rad per sample, ≥ 0];
    float64, same dims (1 at ω = 0)."""
    w = np.asarray(omega, float)
    r = len(pair.prefilter) // 2
    num = np.zeros_like(w)
    den = np.zeros_like(w)
    for t in range(len(pair.prefilter)):
        k = t - r
        num += float(pair.derivative[t]) * np.sin(k * w)
        den += float(pair.prefilter[t]) * np.cos(k * w)
    small = w < 1e-6
    return np.where(small, 1.0, num / np.where(small, 1.0, w * den))


def window_rms_frequency(L: np.ndarray, mask: np.ndarray, vo: np.ndarray, views: tuple[int, int],
                         filters: dict, view_axis: str) -> np.ndarray:
    """Ω [rad per sample] along the direction axis matching ``view_axis``, per ray, over ρ̂'s window
    (module docstring): ``Ω² = S(L_uu²) / S(L_u²)``.

    L: (F, Ny, Nx, Nv, Nu) float32 frame (the solver's level frame); mask: (F, ny, nx, Nv, Nu) bool,
    the rays that enter the windows (as ρ̂'s own sums: the solver's base weights > 0), over the views
    ``views`` = (ny, nx) from origin ``vo`` (4,) [y0, x0, Ny, Nx]; ``filters``: axis name → the
    solver's :class:`~polycam.derivatives.FilterPair`; ``view_axis``: "x" (a row of views: Ω along u)
    or "y" (a column: along v). Returns float32 (F, ny, nx, Nv, Nu), NaN where the window holds no
    gradient energy, at most ``_MAX_FREQUENCY``."""
    if view_axis not in ("x", "y"):
        raise ValueError("view_axis must be 'x' or 'y'")
    row = view_axis == "x"
    ax_view, ax_dir, ax_other = (2, 4, 3) if row else (1, 3, 4)
    f_view, f_dir, f_other = filters[view_axis], filters["u" if row else "v"], filters["v" if row else "u"]
    ny, nx = views
    y0, x0 = int(vo[0]), int(vo[1])
    m = np.zeros(L.shape, np.float32)
    m[:, y0:y0 + ny, x0:x0 + nx] = mask
    a = correlate_axis(correlate_axis(np.asarray(L, np.float32), f_other.prefilter, ax_other), f_view.prefilter, ax_view)
    Lu = correlate_axis(a, f_dir.derivative, ax_dir)
    Luu = correlate_axis(Lu, f_dir.derivative, ax_dir, out=a)
    Lu = correlate_axis(Lu, f_dir.prefilter, ax_dir)     # smoothed as L_uu is: their ratio is ω R_u(ω)
    t9, t3 = rho_window_taps()

    def window(p: np.ndarray) -> np.ndarray:
        p *= m
        return correlate_axis(correlate_axis(correlate_axis(p, t9, 3), t9, 4), t3, ax_view)[:, y0:y0 + ny, x0:x0 + nx]

    s_uu = window(Lu * Lu)
    s_uuuu = window(Luu * Luu)
    with np.errstate(divide="ignore", invalid="ignore"):
        omega = np.sqrt(s_uuuu / s_uu)
    return np.where(s_uu > 0, np.minimum(omega, _MAX_FREQUENCY), np.nan).astype(np.float32)


def linear_rho_gain(rho: np.ndarray, omega: np.ndarray, steps: tuple[float, float], view_filter: FilterPair
                    ) -> np.ndarray:
    """The gain ``R_view(k Ω)`` (module docstring) by which a linear array's ρ̂ reads high, per ray.

    rho: ρ̂ [u per unit of x] (any dims), NaN where there is none; omega: the same dims, Ω from
    :func:`window_rms_frequency`; ``steps``: (view step [m], direction step) along the array's view
    axis and the matching direction axis (k = |ρ̂| steps[0] / steps[1] samples per view step; k Ω
    is capped at ``_MAX_FREQUENCY``);
    ``view_filter``: the derivative filter pair across the views. Returns float32 of rho's dims:
    the gain where both are finite, 1 elsewhere."""
    rho = np.asarray(rho)
    out = np.ones(rho.shape, np.float32)
    ok = np.isfinite(rho) & np.isfinite(omega)
    k = np.abs(rho[ok]) * (steps[0] / steps[1])
    out[ok] = derivative_gain(view_filter, np.minimum(k * omega[ok], _MAX_FREQUENCY))
    return out


def divide_rho_by_gain(rho: np.ndarray, scales: np.ndarray, omega: np.ndarray, steps: tuple[float, float],
                       view_filter: FilterPair) -> None:
    """In place on the solver's int16 ρ̂ (:func:`polycam.eq5.depth_rho`: ``rho`` (F, ny, nx, Nv, Nu)
    in units of ``scales`` (F, ny, nx) per view image, ``_RHO_NONE`` where there is none): ρ̂ divided
    by :func:`linear_rho_gain` (``omega``, ``steps``, ``view_filter`` as there; R read from a table),
    each view re-quantised to its new largest value. Rays without a finite Ω keep their ρ̂."""
    x = np.linspace(0.0, _MAX_FREQUENCY, _TABLE_SIZE)
    table = derivative_gain(view_filter, x).astype(np.float32)
    V = int(np.prod(rho.shape[:3]))
    _divide_kernel(rho.reshape((V,) + rho.shape[3:]), scales.reshape(V), omega.reshape((V,) + omega.shape[3:]),
                   np.float32(steps[0] / steps[1]), table, np.float32((_TABLE_SIZE - 1) / _MAX_FREQUENCY))


@numba.njit(cache=True, inline="always")
def _divided(q, s, w, ratio, table, inv_dx):
    """ρ̂ = q s divided by R(|ρ̂| ratio w) (table over [0, _MAX_FREQUENCY], clamped at its end)."""
    r = np.float32(q) * s
    if not (w == w):
        return r
    t = abs(r) * ratio * w * inv_dx
    n = table.size - 1
    if t >= n:
        return r / table[n]
    i = int(t)
    f = t - np.float32(i)
    return r / (table[i] + f * (table[i + 1] - table[i]))


@numba.njit(parallel=True, cache=True)
def _divide_kernel(rho, scales, omega, ratio, table, inv_dx):
    """:func:`divide_rho_by_gain` on (V, Nv, Nu) views: the new largest |ρ̂| per view, then the
    values in its units."""
    V, Nv, Nu = rho.shape
    none = np.int16(_RHO_NONE)
    for k in numba.prange(V):
        s = scales[k]
        q = rho[k]
        w = omega[k]
        m = np.float32(0.0)
        for v in range(Nv):
            for u in range(Nu):
                if q[v, u] != none:
                    m = max(m, abs(_divided(q[v, u], s, w[v, u], ratio, table, inv_dx)))
        if m == 0.0:
            continue
        inv = np.float32(_QMAX) / m
        for v in range(Nv):
            for u in range(Nu):
                if q[v, u] != none:
                    q[v, u] = np.int16(np.rint(_divided(q[v, u], s, w[v, u], ratio, table, inv_dx) * inv))
        scales[k] = m / np.float32(_QMAX)
