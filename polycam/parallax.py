"""Is there parallax above the noise? The translation's signal, measured from each frame alone.

The rig's translation is seen only through parallax: a ray's positional derivatives
``L_x, L_y`` (paper Eq. 5's translation columns hold nothing else). For a scene far away
(no parallax) they are noise, and a least-squares solve still finds a translation in it
and a small standard deviation for it: the rows' noise looks like information, and the
estimate is a fit of the noise (errors in variables) whatever the true motion.

This module measures how much of the translation columns' energy is signal, without a
noise model: it computes the columns from each frame alone (frame 1 warped onto frame 0
by the estimated motion), ``a0`` and ``a1`` per ray. Sensor noise is independent between
the frames, the scene's parallax is common to both, so over the rays
``S = Σ w sym(a0 a1ᵀ) = Σ w (ā āᵀ − δ δᵀ)`` (ā, δ the half sum and half difference)
has the noise-free columns' energy as its expectation, while ``A = Σ w ā āᵀ`` is what
the solver sees. The generalised eigenvalues of (S, A) are the *signal fractions* of
the translation directions: ~1 where the parallax is well above the noise, ~0 (either
sign) where the columns are noise alone.

The columns are paper Eq. 6's, as the solver's default (``MotionOptions.depth_regressors``):
``L_x ≈ ρ̂ L_u``, ``L_y ≈ ρ̂ L_v`` with the disparity ρ̂ pooled over a window of rays
(the window of :func:`polycam.eq5.rho_window_taps`), here from each frame's own
derivatives: the pooling is what lifts a weak parallax above the noise (raw ``L_x`` of a
room 6 m away under 3 grey levels of noise is mostly noise; its pooled ρ̂ is not).

Measured (docs/motion.md, "No parallax above the noise"; the tests' rendered rooms and spheres, one or
six faces, the benchmarks' frames, HCI's real light field): the smallest fraction 0.41–1.0 on every
set whose estimate is within a few of its standard deviations and whose noise is below 32 grey
levels; −3.8 to −0.12 on a room 10³–10⁶ m away with noise, frames of pure noise and a room at 6 m
under 32 grey levels of noise; 0.09–0.17 on target 2's set at 12 m under 32 grey levels (estimates
within their std but 40–70 % of the motion off); 0.58 on the room at 100 m on six faces (its
translation 4–5 standard deviations off). The motion solver draws its line at
``MotionOptions.parallax_min``.

Frames, units and axis order: docs/conventions.md.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from .derivatives import _valid_mask, correlate_axis, min_filter_axis, plenoptic_derivatives
from .eq5 import rho_window_taps
from .geometry import T_inverse
from .lightfield import Axis, LightFieldGrid
from .warp import warp_lightfield

__all__ = ["ParallaxSignal", "parallax_signal"]


@dataclass(frozen=True)
class ParallaxSignal:
    """How much of the translation columns' energy is the scene's parallax."""

    fraction: np.ndarray
    """(3,) signal fractions of the translation directions, ascending (see the module docstring;
    NaN: not measured)."""
    directions: np.ndarray
    """(3, 3) their unit directions in the rig frame, one per row (``directions[i]`` goes with
    ``fraction[i]``)."""
    num_rays: int
    """Rays the sums ran over."""

    def below(self, threshold: float) -> np.ndarray:
        """(k, 3) the directions whose signal fraction is below ``threshold`` (none when not measured)."""
        keep = np.isfinite(self.fraction) & (self.fraction < threshold)
        return self.directions[keep]


_EXTRAPOLATE_VIEWS = 2.0
"""View steps a linear array's warp extrapolates across its single-view axis (the solver's
``MotionOptions.extrapolate_views`` default)."""
_MIN_WINDOW = 24
"""The smallest (u, v) window :func:`parallax_signal` crops a face to: its filters and ρ̂'s
9-sample window leave 16 x 16 rays inside."""


def _central(n: int, keep: int) -> slice:
    """The central ``keep`` of ``n`` indices (all of them when n <= keep)."""
    lo = max((n - keep) // 2, 0)
    return slice(lo, lo + min(n, keep))


def _not_measured(n: int = 0) -> ParallaxSignal:
    """The result when the fractions cannot be measured (``n`` rays were left)."""
    return ParallaxSignal(np.full(3, np.nan), np.eye(3), n)


def _pooled_rho(L: np.ndarray, grid: LightFieldGrid, filters: dict, w: np.ndarray):
    """(ρ̂, derivatives) of the frame ``L`` (F, Ny, Nx, Nv, Nu) alone: ρ̂ (L's dims, float32; 0 where
    undetermined) of Eq. 6 ``L_x = ρ L_u``, ``L_y = ρ L_v``, least squares pooled over the window of
    :func:`polycam.eq5.rho_window_taps` with the weights ``w`` (L's dims), from the axes with
    several viewpoints only (a linear array's single-view axis has no L_x or L_y)."""
    der = plenoptic_derivatives(L, L, grid, filters=filters)
    t9, t3 = rho_window_taps()

    def pool(a: np.ndarray) -> np.ndarray:
        for axis, taps in ((1, t3), (2, t3), (3, t9), (4, t9)):
            if a.shape[axis] >= len(taps):
                a = correlate_axis(a, taps, axis)
        return a

    num = np.zeros_like(L)
    den = np.zeros_like(L)
    for axis, Lpos, Ldir in (("x", der.Lx, der.Lu), ("y", der.Ly, der.Lv)):
        if getattr(grid, axis).count > 1:
            num += Lpos * Ldir
            den += Ldir * Ldir
    num, den = pool(w * num), pool(w * den)
    rho = np.where(den > 0, num / np.where(den > 0, den, 1.0), 0.0).astype(np.float32)
    return rho, der


def _translation_columns(L: np.ndarray, grid: LightFieldGrid, filters: dict, w: np.ndarray,
                         rays: tuple) -> np.ndarray:
    """(n, 3) float64 paper Eq. 5's translation columns in the rig frame of the frame ``L`` (F, Ny,
    Nx, Nv, Nu) alone at the n rays ``rays`` (index arrays of ``w > 0``), with Eq. 6's ``ρ̂ L_u,
    ρ̂ L_v`` for ``L_x, L_y`` (:func:`_pooled_rho` with the weights ``w``, L's dims)."""
    rho, der = _pooled_rho(L, grid, filters, w)
    rho = rho[rays].astype(np.float64)
    gx, gy = rho * der.Lu[rays], rho * der.Lv[rays]
    k, v, u = rays[0], grid.v.values[rays[3]], grid.u.values[rays[4]]
    f = np.array([face.f for face in grid.faces])[k]
    c = np.stack([gx, gy, -(u * gx + v * gy) / f], axis=-1)                  # (n, 3) face frame
    R = np.stack([np.asarray(face.R_rig_face, float) for face in grid.faces])[k]    # (n, 3, 3)
    return np.einsum("nij,nj->ni", R, c)                                       # rig frame


def _textured_window(image: np.ndarray, conf: np.ndarray | None, side: int) -> tuple[slice, slice]:
    """(v, u) slices of the ``side`` x ``side`` window of ``image`` (Nv, Nu) with the most gradient
    energy among 3 x 3 candidate positions (the corners, edge centres and centre): where the
    parallax, if any, shows best. ``conf``: the image's confidences (same dims) or None; a gradient
    counts with the smaller confidence of its two samples (the edge of a region without data is
    not texture)."""
    Nv, Nu = image.shape
    sv, su = min(side, Nv), min(side, Nu)
    c = np.ones_like(image) if conf is None else np.asarray(conf, np.float64)
    g = np.zeros((Nv + 1, Nu + 1))
    e = np.zeros((Nv, Nu))
    e[:, 1:] += np.diff(image, axis=1) ** 2 * np.minimum(c[:, 1:], c[:, :-1])
    e[1:, :] += np.diff(image, axis=0) ** 2 * np.minimum(c[1:, :], c[:-1, :])
    g[1:, 1:] = e.cumsum(0).cumsum(1)
    best, where = -1.0, (0, 0)
    for v0 in sorted({0, (Nv - sv) // 2, Nv - sv}):
        for u0 in sorted({0, (Nu - su) // 2, Nu - su}):
            energy = g[v0 + sv, u0 + su] - g[v0, u0 + su] - g[v0 + sv, u0] + g[v0, u0]
            if energy > best:
                best, where = energy, (v0, u0)
    return slice(where[0], where[0] + sv), slice(where[1], where[1] + su)


def _face_sums(L0, L1, W0, W1, grid: LightFieldGrid, T_ray: np.ndarray, filters: dict,
               radius: dict) -> tuple[np.ndarray, np.ndarray, int]:
    """(A, S, n): the 3 x 3 sums of the module docstring over the rays of a one-face ``grid``. On a
    linear array the warp extrapolates the rays it moves off the single-view axis by Eq. 6 (as the
    solver's does), with frame 0's ρ̂ averaged over the views."""
    stack = [L1] if W1 is None else [L1, W1]
    rho = None
    if grid.single_view_axis:
        r0, _ = _pooled_rho(np.ascontiguousarray(L0, np.float32), grid, filters,
                            np.ones_like(L0, np.float32) if W0 is None else np.asarray(W0, np.float32))
        rho = r0.mean(axis=(1, 2)).astype(np.float64)                   # (1, Nv, Nu)
    warped, ok = warp_lightfield(np.stack(stack), grid, T_ray, rho=rho,
                                 extrapolate_views=_EXTRAPOLATE_VIEWS if rho is not None else 0.0)
    w = ok.astype(np.float32)
    if W0 is not None:
        w *= np.asarray(W0, np.float32)
    if W1 is not None:
        w *= np.clip(warped[1], 0.0, 1.0)
    # a ray counts where its derivatives' support is inside the grid and the warp's data
    for axis, k in ((1, "y"), (2, "x"), (3, "v"), (4, "u")):
        if radius[k]:
            w = min_filter_axis(w, radius[k], axis)
    w *= _valid_mask(w.shape[1:], {k: filters[k] if radius[k] else None for k in "xyuv"})
    rays = np.nonzero(w > 0)
    n = int(rays[0].size)
    if n == 0:
        return np.zeros((3, 3)), np.zeros((3, 3)), 0
    a0 = _translation_columns(np.ascontiguousarray(L0, np.float32), grid, filters, w, rays)
    a1 = _translation_columns(np.ascontiguousarray(warped[0]), grid, filters, w, rays)
    wm = w[rays].astype(np.float64)[:, None]
    mean, half = 0.5 * (a0 + a1), 0.5 * (a1 - a0)
    A = (mean * wm).T @ mean
    return A, A - (half * wm).T @ half, n


def parallax_signal(L0: np.ndarray, L1: np.ndarray, grid: LightFieldGrid, T_rig0_rig1: np.ndarray, *,
                    filters: dict, W0: np.ndarray | None = None, W1: np.ndarray | None = None,
                    views: int = 5, samples: int = 32768) -> ParallaxSignal:
    """Signal fractions of the translation directions of a frame pair (module docstring).

    ``L0``, ``L1``: (F, Ny, Nx, Nv, Nu) float32 frames on ``grid``; ``T_rig0_rig1`` (4, 4): the
    estimated rig motion (frame 1 is warped onto frame 0 by it); ``filters``: axis name → the
    :class:`~polycam.derivatives.FilterPair` of the derivatives; ``W0``, ``W1``: optional
    confidences (same dims as the frames) weighting the rays. The sums run over the central
    ``views`` x ``views`` viewpoints at most and, per face, a (u, v) window small enough for about
    ``samples`` samples per frame (at least 24 x 24 directions), the most textured of nine
    (:func:`_textured_window`); ~3 ms at 32768. Frame 1's rays that the warp moves outside the
    window are left out. A linear array (one viewpoint along x or y: ``grid.single_view_axis``) is
    measured along its other axis. Not measured (NaN fractions) with fewer than 3 viewpoints along
    an axis that has several, one viewpoint in all, or too few rays left once the warp's and the
    filters' borders are removed.
    """
    F, Ny, Nx, Nv, Nu = grid.shape
    single = grid.single_view_axis
    radius = {k: 0 if k == single else filters[k].radius for k in "xyuv"}
    views_ok = [n >= max(2 * radius[k] + 1, 3) for k, n in (("x", Nx), ("y", Ny)) if k != single]
    if not all(views_ok) or Nx * Ny == 1:
        return _not_measured()
    ys, xs = _central(Ny, views), _central(Nx, views)
    sub = replace(grid, y=Axis.from_values(grid.y.values[ys]), x=Axis.from_values(grid.x.values[xs]))
    ny, nx = sub.y.count, sub.x.count
    side = max(_MIN_WINDOW, math.isqrt(max(samples // (F * ny * nx), 1)))
    T_ray = T_inverse(T_rig0_rig1)
    A, S, n = np.zeros((3, 3)), np.zeros((3, 3)), 0
    for k, face in enumerate(grid.faces):
        centre = (k, Ny // 2, Nx // 2)
        vs, us = _textured_window(np.asarray(L0[centre], np.float64), None if W0 is None else W0[centre], side)
        g = replace(sub, faces=(face,), v=Axis.from_values(grid.v.values[vs]), u=Axis.from_values(grid.u.values[us]))
        part = (k, ys, xs, vs, us)

        def cut(a):
            return None if a is None else np.asarray(a)[part][None]

        Ak, Sk, nk = _face_sums(cut(L0), cut(L1), cut(W0), cut(W1), g, T_ray, filters, radius)
        A, S, n = A + Ak, S + Sk, n + nk
    if n < 64:
        return _not_measured(n)
    d = np.sqrt(np.diag(A))
    if not np.all(d > 0):
        return _not_measured(n)
    As, Ss = A / np.outer(d, d), S / np.outer(d, d)
    try:
        C = np.linalg.cholesky(As)
    except np.linalg.LinAlgError:
        return _not_measured(n)
    X = np.linalg.solve(C, np.linalg.solve(C, Ss).T).T          # C⁻¹ Ss C⁻ᵀ
    frac, V = np.linalg.eigh(0.5 * (X + X.T))
    dirs = np.linalg.solve(C.T, V) / d[:, None]                   # A-orthonormal, in parameters
    dirs = (dirs / np.linalg.norm(dirs, axis=0)).T
    return ParallaxSignal(frac, dirs, n)
