"""Depth refined by matching the captured views: iterated multi-view differential stereo.

Eq. 6's stereo estimate ``λ = L_u / L_x`` (:mod:`polycam.depth`) is one linearisation of the
light field across the viewpoints its derivative filters span: exact while the disparity between
those views is a small part of a sample, biased beyond. On a resampled camera array the views
with data are the cameras, 2–4 cm apart, and a room at 2–4 m moves by 1–3 (u, v) samples
between neighbouring cameras; the views between them are filled by the resampler (``W ≤ 0.5``)
and carry its plane sweep's depth, not a measurement. So the depth of Eq. 7 is only a start.

This module refines it the way the motion solver refines its first linearisation (Gauss–Newton
with warping): with ``ρ = 1 / λ = f / Z``, the ray ``(x_t, y_t, u, v)`` of a target view sees the
surface point that a source view at viewpoint ``(x_s, y_s)`` sees in direction
``(u − (x_s − x_t) ρ, v − (y_s − y_t) ρ)`` (``L = τ(x + λ u, y + λ v)``, docs/conventions.md).
Per ray, ``ρ`` minimises the spread of the source views' samples there,

    E(ρ) = Σ_window Σ_s w_s (I_s(u − d_sx ρ, v − d_sy ρ) − Ī)²,   Ī = the w-weighted mean over s,

with ``I_s`` a source view's image smoothed by the fs5 prefilter (its gradient by the matched
fs5 derivative), ``w_s`` its confidence ``W`` where ``W > MIN_W`` (0 elsewhere and outside the
directions), and the window the depth fusion's (:func:`polycam.depth.window_sum`). Each
Gauss–Newton step linearises every source sample in ρ, ``dI_s/dρ = −(d_sx ∂_u I_s + d_sy ∂_v I_s)``,
and moves ρ by at most half a sample of the farthest source. Only the sources' samples enter,
so a target view need not hold data itself: a stereo pair's depth is found at the view half-way
between its two cameras.

The confidence keeps :class:`~polycam.depth.DepthMap`'s meaning, ``λ² / var(λ) = ρ² / var(ρ)``:
the energy ρ explains (``ρ² Σ J²``, J the centred ``dI/dρ``) over what it leaves, the residual's
misfit beyond the sensor noise plus the noise of ρ itself, ``σ² ‖w ∗ p‖²`` (the window's weights
convolved with the prefilter: :func:`polycam.depth.window_weight_energy` of a window one prefilter
wider). Measured in docs/depth.md, "Refinement on the captured views". This module does no I/O.
"""

from __future__ import annotations

import logging
from typing import Callable

import numba
import numpy as np

from .depth import CONFIDENCE_FLOOR, MIN_W, DepthMap, window_sum, window_weight_energy
from .derivatives import FILTERS, correlate_axis
from .lightfield import LightFieldGrid

__all__ = ["REFINE_FILTER", "MAX_STEP_SAMPLES", "CONVERGED_SAMPLES", "grid_positions", "refine_depth"]

log = logging.getLogger(__name__)

REFINE_FILTER = "fs5"
"""The matched prefilter / derivative pair that smooths the source images and gives their gradients."""

MAX_STEP_SAMPLES = 0.5
"""The largest change of a ray's disparity per Gauss–Newton step [samples, at the farthest source]."""

CONVERGED_SAMPLES = 0.01
"""The iterations stop once no valid ray's disparity moves more than this [samples]."""


def grid_positions(grid: LightFieldGrid, views: np.ndarray) -> np.ndarray:
    """(F, Ny, Nx, 2) float64 source positions for :func:`refine_depth`: each selected view at
    its own grid index (iy, ix), NaN at the others. ``views``: (F, Ny, Nx) or (Ny, Nx) bool."""
    F, Ny, Nx = grid.shape[:3]
    sel = np.broadcast_to(np.asarray(views, bool), (F, Ny, Nx))
    iy, ix = np.meshgrid(np.arange(Ny, dtype=float), np.arange(Nx, dtype=float), indexing="ij")
    pos = np.stack(np.broadcast_arrays(iy, ix), axis=-1)                      # (Ny, Nx, 2)
    return np.where(sel[..., None], pos[None], np.nan)


@numba.njit(cache=True, inline="always")
def _bilinear(a, s, fv, fu):
    """a[s] at fractional (fv, fu), inside [0, Nv-1] x [0, Nu-1] (the caller checks)."""
    Nv, Nu = a.shape[1], a.shape[2]
    iv = min(int(fv), Nv - 2) if Nv > 1 else 0
    iu = min(int(fu), Nu - 2) if Nu > 1 else 0
    tv = fv - iv
    tu = fu - iu
    dv = 1 if Nv > 1 else 0
    du = 1 if Nu > 1 else 0
    return ((1 - tv) * ((1 - tu) * a[s, iv, iu] + tu * a[s, iv, iu + du])
            + tv * ((1 - tu) * a[s, iv + dv, iu] + tu * a[s, iv + dv, iu + du]))


@numba.njit(parallel=True, cache=True)
def _terms_kernel(img, gu, gv, w, has_w, min_w, su, sv, rho, out):
    """Per target ray (Nv, Nu): the w-weighted centred sums over the sources S at the ray's
    current ρ — out[0] Σ w J², out[1] Σ w J r, out[2] Σ w r², out[3] Σ w, out[4] Σ w² / Σ w
    (J = dI/dρ, r = I − Ī, both centred). ``img``, ``gu``, ``gv``, ``w``: (S, Nv, Nu) float32;
    ``su``, ``sv``: (S,) the source's shift along u and v per unit ρ [samples]."""
    S, Nv, Nu = img.shape
    for jv in numba.prange(Nv):
        for ju in range(Nu):
            p = rho[jv, ju]
            sw = 0.0
            sw2 = 0.0
            sI = 0.0
            sJ = 0.0
            sII = 0.0
            sJJ = 0.0
            sIJ = 0.0
            for s in range(S):
                fu = ju - su[s] * p
                fv = jv - sv[s] * p
                if fu < 0.0 or fv < 0.0 or fu > Nu - 1 or fv > Nv - 1:
                    continue
                ws = 1.0
                if has_w:
                    ws = _bilinear(w, s, fv, fu)
                    if ws <= min_w:
                        continue
                I = _bilinear(img, s, fv, fu)
                J = -(su[s] * _bilinear(gu, s, fv, fu) + sv[s] * _bilinear(gv, s, fv, fu))
                sw += ws
                sw2 += ws * ws
                sI += ws * I
                sJ += ws * J
                sII += ws * I * I
                sJJ += ws * J * J
                sIJ += ws * I * J
            if sw2 <= 0.0 or sw * sw <= sw2 * 1.000001:     # fewer than two sources
                for c in range(5):
                    out[c, jv, ju] = 0.0
                continue
            out[0, jv, ju] = max(sJJ - sJ * sJ / sw, 0.0)
            out[1, jv, ju] = sIJ - sI * sJ / sw
            out[2, jv, ju] = max(sII - sI * sI / sw, 0.0)
            out[3, jv, ju] = sw
            out[4, jv, ju] = sw2 / sw


def _smoothed(a: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(S, Nv, Nu) images → their prefiltered values and (u, v) gradients [per sample]."""
    pair = FILTERS[REFINE_FILTER]
    pv = correlate_axis(a, pair.prefilter, 1)
    pu = correlate_axis(a, pair.prefilter, 2)
    return (correlate_axis(pv, pair.prefilter, 2), correlate_axis(pv, pair.derivative, 2),
            correlate_axis(pu, pair.derivative, 1))


def _window(a: np.ndarray, window: int) -> np.ndarray:
    return window_sum(a[None, None, None], window)[0, 0, 0]


def _rho_of(f: float, Z: np.ndarray) -> np.ndarray:
    """ρ = f / Z where Z is finite and positive, NaN elsewhere."""
    ok = np.isfinite(Z) & (Z > 0)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(ok, f / np.where(ok, Z, 1.0), np.nan)


def _refine_view(img, gu, gv, w, has_w: bool, su: np.ndarray, sv: np.ndarray, rho: np.ndarray, window: int,
                 iterations: int, noise_s: float, noise_rho: float) -> tuple[np.ndarray, ...]:
    """Gauss–Newton on one target view's ρ (Nv, Nu) from its start: (ρ, confidence, consistency,
    valid mask, iterations run). ``su``, ``sv``: (S,) the sources' shifts per unit ρ [samples]."""
    smax = float(np.max(np.hypot(su, sv)))
    out = np.empty((5, *rho.shape), np.float32)
    it = 0
    for it in range(iterations + 1):
        _terms_kernel(img, gu, gv, w, has_w, MIN_W, su, sv, rho, out)
        Sjj, Sjr = _window(out[0], window), _window(out[1], window)
        if it == iterations:
            break
        ok = Sjj > 0
        step = np.clip(np.where(ok, -Sjr / np.where(ok, Sjj, 1.0), 0.0),
                       -MAX_STEP_SAMPLES / smax, MAX_STEP_SAMPLES / smax)
        rho = np.maximum(rho + step, 0.0)
        if float(np.max(np.abs(step[ok]), initial=0.0)) * smax < CONVERGED_SAMPLES:
            _terms_kernel(img, gu, gv, w, has_w, MIN_W, su, sv, rho, out)
            Sjj = _window(out[0], window)
            break
    Srr = _window(out[2], window)
    # the residual's expected noise energy: Σ w (n − n̄)² = σ² (Σ w − Σ w² / Σ w)
    Nr = noise_s * _window(np.maximum(out[3] - out[4], 0.0), window)
    explained = rho * rho * Sjj
    unexplained = np.maximum(Srr - Nr, 0.0) + noise_rho
    valid = (Sjj > 0) & (rho > 0) & (_window((out[3] > 0).astype(np.float32), window) > 0.5)
    with np.errstate(divide="ignore", invalid="ignore"):
        conf = np.where(valid & (explained > 0), explained / np.maximum(unexplained, CONFIDENCE_FLOOR * explained), 0.0)
        cons = np.where(valid, explained / np.maximum(explained + Srr, 1e-30), 0.0)
    return rho, np.nan_to_num(conf), cons, valid, it


def _start(rho: np.ndarray, fallback: float) -> np.ndarray:
    """A target view's starting ρ: NaN → the view's median (``fallback`` without any), and at most
    its 99th percentile (a stray depth near 0 could not come back half a sample per step)."""
    if not np.any(np.isfinite(rho)):
        return np.full(rho.shape, fallback)
    start, top = np.nanpercentile(rho, [50, 99])
    return np.where(np.isfinite(rho), np.minimum(rho, top), start)


def refine_depth(g: np.ndarray, grid: LightFieldGrid, Z0: np.ndarray, *, sources: np.ndarray,
                 targets: np.ndarray, W: np.ndarray | None = None, window: int = 4, iterations: int = 8,
                 noise_var: float = 0.0, progress: Callable[[int, int], None] | None = None) -> DepthMap:
    """Refine the depth ``Z0`` of the ``targets`` views by matching the ``sources`` views' samples.

    ``g``: (F, Ny, Nx, Nv, Nu) one frame's grey light field. ``Z0``: (F, Ny, Nx, Nv, Nu) [m]
    starting depth along each face's z (e.g. :func:`polycam.depth.depth_from_derivatives`'s;
    read at the targets only, NaN where unknown: those rays start from their view's median).
    ``sources``: (F, Ny, Nx, 2) the viewpoint (iy, ix), in fractional grid indices, of the data
    held at each source view, NaN at views that are not sources (:func:`grid_positions`, or the
    positions a resampled store records: a camera's image seen *from its centre*, a little off the
    grid view on a real array, or the grid view once the resampler re-centred it). ``targets``:
    (F, Ny, Nx) bool. ``W``: the light
    field's confidence, dims of ``g`` (None: every sample has data); a source's sample counts with
    weight W where ``W > MIN_W``. ``window``: the (u, v) neighbourhood, as the depth fusion's.
    ``noise_var``: the sensor noise's variance per sample (0: the confidence counts the misfit
    only). ``progress``: called ``progress(done, total)`` after each target view. Returns a
    DepthMap of ``g``'s dims, its values at the targets (NaN / 0 elsewhere).
    """
    g = np.asarray(g, np.float32)
    F, Ny, Nx, Nv, Nu = g.shape
    sources = np.asarray(sources, float)
    targets = np.broadcast_to(np.asarray(targets, bool), (F, Ny, Nx))
    if sources.shape != (F, Ny, Nx, 2):
        raise ValueError(f"sources must be (F, Ny, Nx, 2) = {(F, Ny, Nx, 2)}, got {sources.shape}")
    Z = np.full(g.shape, np.nan, np.float32)
    conf = np.zeros(g.shape, np.float32)
    cons = np.zeros(g.shape, np.float32)
    pair = FILTERS[REFINE_FILTER]
    # the noise variance of one smoothed sample (the 2-D prefilter), and that of ρ times Σ J²: the
    # window's weights convolved with the prefilter (the window over smoothed noise), σ² ‖w ∗ p‖²
    noise_s = float(noise_var) * float(np.sum(np.square(pair.prefilter))) ** 2
    noise_rho = float(noise_var) * window_weight_energy(window + 2)
    Z0 = np.asarray(Z0, float)
    total, done = int(targets.sum()), 0
    for k, face in enumerate(grid.faces):
        src = np.argwhere(np.isfinite(sources[k, :, :, 0]))               # (S, 2) views holding the data
        tgt = np.argwhere(targets[k])
        rho_all = _rho_of(face.f, Z0[k, tgt[:, 0], tgt[:, 1]])               # (T, Nv, Nu)
        if len(src) >= 2 and np.any(np.isfinite(rho_all)):
            img, gu, gv = _smoothed(g[k, src[:, 0], src[:, 1]])
            has_w = W is not None
            w = (np.ascontiguousarray(np.asarray(W, np.float32)[k, src[:, 0], src[:, 1]]) if has_w
                 else np.ones((1, 1, 1), np.float32))
            pos = sources[k, src[:, 0], src[:, 1]]                          # (S, 2) (iy, ix)
            fallback = float(np.nanmedian(rho_all))
            for t, (jy, ix) in enumerate(tgt):
                # the sources' shifts per unit ρ [samples]: their viewpoints' offsets over the (u, v) steps
                su = (pos[:, 1] - ix) * (grid.x.step if Nx > 1 else 0.0) / grid.u.step
                sv = (pos[:, 0] - jy) * (grid.y.step if Ny > 1 else 0.0) / grid.v.step
                if np.any(np.hypot(su, sv) > 0):
                    rho, c, q, valid, it = _refine_view(img, gu, gv, w, has_w, su, sv, _start(rho_all[t], fallback),
                                                        window, iterations, noise_s, noise_rho)
                    with np.errstate(divide="ignore"):
                        Z[k, jy, ix] = np.where(valid, face.f / rho, np.nan)
                    conf[k, jy, ix], cons[k, jy, ix] = c, q
                    log.debug("refine_depth: face %s view (%d, %d): %d sources, %d iterations, %.0f%% valid",
                              face.name, jy, ix, len(src), it, 100 * float(np.mean(valid)))
                done += 1
                if progress is not None:
                    progress(done, total)
        elif len(tgt):
            done += len(tgt)
            if progress is not None:
                progress(done, total)
    return DepthMap(Z=Z, confidence=conf, consistency=cons)
