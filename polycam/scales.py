"""Scale selection for plenoptic derivatives (paper Sect. 4.1): make the four depth
estimates of Eq. 7 agree.

A scale is a pair of binomial pre-smoothings, one along (x, y) and one along (u, v),
applied to both frames before the solver's matched derivative filters. By linearity
this equals derivative filters ``d ⊛ b`` with prefilters ``p ⊛ b``, i.e. the matched
Farid–Simoncelli pairs of :mod:`polycam.derivatives` moved up a Gaussian-like scale
space (binomial ``b`` of order n has variance n / 4 samples²). The (x, y) and (u, v)
scales are chosen independently per face (or per (u, v) tile, "region"), so their
*relative* scale is what is selected: on a Lambertian surface at depth Z a (u, v)
sample covers ``Z Δu / f`` metres of the scene and an (x, y) sample ``Δx`` metres, so
the derivatives along the two see the same scene patch only for one relative scale.

Selection: with a motion estimate, compute at each candidate scale the four
per-ray depth estimates ``λ_i = Σ a_i b_i / Σ a_i²`` of
:func:`polycam.depth.depth_equations` (two differential-stereo ones, from L_u / L_x
and L_v / L_y, and two motion-based ones) and their disagreement, the
information-weighted mean of ``|log λ_i − log λ_j|`` over pairs (clipped at 1). The
scale with the smallest disagreement in a face / region wins (ties, within
``tie`` relative, go to the least smoothing). :func:`estimate_motion_scale_selected`
closes the loop of the paper: motion → depth → adapt filter scales → re-estimate
motion (from the previous estimate), until the choice stops changing.

The pre-smoothing uses :func:`polycam.derivatives.correlate_axis`; samples whose
smoothing support leaves the grid get weight 0. The solver is
:func:`polycam.motion.estimate_motion`, unchanged (this module only pre-filters its
input and passes the border as the confidence W). Measured effect:
benchmarks/bench_scales.py and docs/depth.md. This module does no I/O.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field

import numpy as np

from .depth import (DEPTH_FILTERS, EQUATIONS, DepthMap, depth_equations, depth_from_derivatives, equation_noise,
                    grey_frame, window_sum)
from .derivatives import correlate_axis, derivative_noise, filter_taps, min_filter_axis, plenoptic_derivatives
from .lightfield import LightFieldGrid
from .motion_weights import frame_noise_variance

__all__ = [
    "Scale",
    "MOTION_SCALES",
    "MOTION_UV_SCALES",
    "SCALE_LADDER",
    "DISPARITY_SIGMA_FACTOR",
    "binomial_taps",
    "smooth_at_scale",
    "smoothing_taps",
    "scale_derivatives",
    "DepthEstimates",
    "depth_estimates",
    "disagreement",
    "ScaleSelection",
    "select_scales",
    "apply_selection",
    "ScaleSelectedMotion",
    "estimate_motion_scale_selected",
    "view_disparity",
    "VIEW_DISPARITY_TEXTURE_GATE",
    "VIEW_DISPARITY_STILL_GATE",
    "VIEW_DISPARITY_AGREE",
    "ScaleTracker",
    "depth_scale_selected",
]

log = logging.getLogger(__name__)

@dataclass(frozen=True)
class Scale:
    """Binomial pre-smoothing orders along (x, y) and (u, v) (0 = none, else even).

    Order n has n + 1 taps (radius n / 2) and a variance of n / 4 samples².
    """

    xy: int = 0
    uv: int = 0

    @property
    def name(self) -> str:
        return f"xy{self.xy}_uv{self.uv}"

    @property
    def sigma_xy(self) -> float:
        """[samples] standard deviation of the (x, y) pre-smoothing."""
        return 0.5 * float(np.sqrt(self.xy))

    @property
    def sigma_uv(self) -> float:
        """[samples] standard deviation of the (u, v) pre-smoothing."""
        return 0.5 * float(np.sqrt(self.uv))


MOTION_SCALES: tuple[Scale, ...] = (Scale(4, 0), Scale(2, 0), Scale(0, 0), Scale(2, 2), Scale(0, 2),
                                    Scale(0, 4), Scale(0, 8))
"""Candidates of the motion feedback loop, from relatively finest (u, v) to coarsest:
σ_xy = 1, 0.71, 0 with no (u, v) smoothing, σ_xy = σ_uv = 0.71, then σ_uv = 0.71, 1, 1.41
samples with no (x, y) smoothing. On 9 x 9 viewpoints with fs3, ``xy4`` leaves the central
3 x 3 valid, ``xy2`` the central 5 x 5."""

MOTION_UV_SCALES: tuple[Scale, ...] = (Scale(0, 0), Scale(0, 2), Scale(0, 4), Scale(0, 8))
"""Candidates of the trajectory loop (:class:`ScaleTracker`): (u, v) smoothing only, σ_uv = 0,
0.71, 1, 1.41 samples, so every viewpoint keeps its derivatives (the translation is measured
across them); which ones a face may use is capped by its disparity (:func:`view_disparity`)."""

DISPARITY_SIGMA_FACTOR: float = 2.5
"""Cap of the (u, v) pre-smoothing: σ_uv ≤ this factor x the face's median disparity per view
step (in (u, v) samples). A scene point moves by the disparity d from one viewpoint to the next,
so the (x, y) derivative filter (±1 view) sees the texture over ±d samples: smoothing (u, v) at
about that scale makes the two derivatives see the same patch (plenoptic sampling; Chai et al.
2000), while more smoothing only removes texture. Measured on the room scene of the 5x5 mock
rig (d ≈ 0.85 samples with one view per camera, 0.41 with two): the depth-agreement choice is
σ_uv ≈ 1.7–2.4 d there, and on the paper's sphere scene (d ≈ 0.05–0.09) the cap keeps the
unsmoothed frames, where (u, v) smoothing costs motion accuracy (docs/depth.md)."""

SCALE_LADDER: tuple[Scale, ...] = MOTION_SCALES + (Scale(6, 0), Scale(6, 2))
"""Candidates for depth: :data:`MOTION_SCALES` plus σ_xy = 1.22 (``xy6``, with σ_uv 0 or 0.71),
which on 9 x 9 viewpoints leaves only the central view with derivatives (what
``polycam depth --views central`` writes). Scales without any valid ray are skipped."""


def binomial_taps(order: int) -> np.ndarray:
    """(order + 1,) normalised binomial coefficients (order 0: ``[1]``)."""
    if order < 0 or order % 2:
        raise ValueError(f"binomial order must be even and >= 0, got {order}")
    t = np.array([1.0])
    for _ in range(order):
        t = np.convolve(t, [0.5, 0.5])
    return t


_AXES = {"xy": (("y", 1), ("x", 2)), "uv": (("v", 3), ("u", 4))}


def _scale_taps(scale: Scale, shape4: tuple) -> dict:
    """Axis name → (axis index 1..4, binomial taps) of the axes that ``scale`` smooths on a
    face of ``shape4`` (Ny, Nx, Nv, Nu): an axis too short for the taps is left alone."""
    out = {}
    for group, order in (("xy", scale.xy), ("uv", scale.uv)):
        if order == 0:
            continue
        for name, ax in _AXES[group]:
            if shape4[ax - 1] >= order + 1:
                out[name] = (ax, binomial_taps(order))
    return out


def _smooth_face(L: np.ndarray, scale: Scale) -> tuple[np.ndarray, np.ndarray]:
    """Pre-smooth one face (Ny, Nx, Nv, Nu) (or stacked (..., Ny, Nx, Nv, Nu)) and its
    (Ny, Nx, Nv, Nu) bool mask of samples whose smoothing support lies inside the grid."""
    out = np.ascontiguousarray(L, dtype=np.float32)
    nd = out.ndim
    shape4 = out.shape[-4:]
    ok = np.ones(shape4, bool)
    for ax, taps in _scale_taps(scale, shape4).values():
        a4 = ax - 1                                       # axis in (Ny, Nx, Nv, Nu)
        n = shape4[a4]
        r = len(taps) // 2
        out = correlate_axis(out, taps, nd - 4 + a4)
        keep = np.zeros(n, bool)
        keep[r:n - r] = True
        sh = [1, 1, 1, 1]
        sh[a4] = n
        ok &= keep.reshape(sh)
    return out, ok


def smoothing_taps(scale: Scale, grid: LightFieldGrid) -> dict:
    """Axis name → the binomial taps :func:`smooth_at_scale` correlates that axis with at
    ``scale`` (axes it leaves alone are absent), e.g. for
    :func:`polycam.derivatives.derivative_noise`."""
    shape4 = (grid.y.count, grid.x.count, grid.v.count, grid.u.count)
    return {name: taps for name, (_, taps) in _scale_taps(scale, shape4).items()}


def smooth_at_scale(L: np.ndarray, scales: Scale | list[Scale] | tuple[Scale, ...]
                    ) -> tuple[np.ndarray, np.ndarray]:
    """Pre-smooth a frame L (F, Ny, Nx, Nv, Nu) at one scale, or one scale per face.

    Returns the smoothed frame (float32, same dims) and ``ok`` (F, Ny, Nx, Nv, Nu) bool:
    the smoothing support lies inside the grid.
    """
    L = np.asarray(L, dtype=np.float32)
    F = L.shape[0]
    per_face = [scales] * F if isinstance(scales, Scale) else list(scales)
    if len(per_face) != F:
        raise ValueError(f"{len(per_face)} scales for {F} faces")
    out = np.empty_like(L)
    ok = np.empty(L.shape, bool)
    for k in range(F):
        out[k], ok[k] = _smooth_face(L[k], per_face[k])
    return out, ok


def scale_derivatives(L0: np.ndarray, L1: np.ndarray, grid: LightFieldGrid, scale, *,
                      filters: str | dict = DEPTH_FILTERS):
    """Plenoptic derivatives of the pair at ``scale`` (one :class:`Scale` or one per face).

    Returns (:class:`~polycam.derivatives.Derivatives`, ``ok`` (F, Ny, Nx, Nv, Nu) bool:
    the derivative filters' support inside the grid, and every smoothed sample it reads
    with its own smoothing support inside the grid).
    """
    S0, ok0 = smooth_at_scale(L0, scale)
    S1, _ = smooth_at_scale(L1, scale)
    der = plenoptic_derivatives(S0, S1, grid, filters=filters)
    if not ok0.all():
        # a derivative reads ±radius smoothed samples along each axis; those near the border were
        # smoothed with clipped taps (on 5 views, xy4 made a plane's depth 6 % too far)
        pairs, _ = filter_taps(grid, filters)
        ok = ok0.astype(np.float32)
        for name, axis in (("y", 1), ("x", 2), ("v", 3), ("u", 4)):
            if pairs[name] is not None and pairs[name].radius > 0:
                ok = min_filter_axis(ok, pairs[name].radius, axis)
        ok0 = ok > 0
    return der, ok0 & der.valid[None]


@dataclass(frozen=True)
class DepthEstimates:
    """The four per-ray depth estimates of Eq. 6–7 at one scale (arrays (F, Ny, Nx, Nv, Nu))."""

    lam: dict
    """Equation name (:data:`polycam.depth.EQUATIONS`) → λ = Z / f (float32; NaN: no information)."""
    info: dict
    """Equation name → windowed information Σ a² (≥ 0)."""
    ok: np.ndarray
    """bool: the filters' support lies inside the grid."""


def depth_estimates(der, grid: LightFieldGrid, T_prev_next: np.ndarray | None, *, ok: np.ndarray | None = None,
                    window: int = 4) -> DepthEstimates:
    """Windowed least-squares λ of each depth equation separately (``window`` as in
    :func:`~polycam.depth.depth_from_derivatives`); without ``T_prev_next`` only the two
    stereo equations; on a linear array not the positional motion equation (it reads the
    unmeasured L_x or L_y as 0: :func:`~polycam.depth.depth_from_derivatives`)."""
    m = np.broadcast_to(der.valid, der.Lx.shape) if ok is None else ok
    valid = m.astype(np.float32)
    lam, info = {}, {}
    for name, (a, b) in depth_equations(der, grid, T_prev_next).items():
        if name == "motion_pos" and grid.single_view_axis:
            continue
        Saa = window_sum(a * a * valid, window)
        Sab = window_sum(a * b * valid, window)
        with np.errstate(divide="ignore", invalid="ignore"):
            lam[name] = np.where((Saa > 0) & m, Sab / Saa, np.nan).astype(np.float32)
        info[name] = np.where(m, Saa, 0.0).astype(np.float32)
    return DepthEstimates(lam=lam, info=info, ok=m)


def _pair_terms(est: DepthEstimates, sel: np.ndarray | tuple = ()):
    """Per pair of equations: (|log λ_i − log λ_j| clipped at 1, weight) on the rays of ``sel``.

    Weights are min over the pair of information / its median on the valid rays, so
    every equation counts about equally whatever its units; rays where either λ is not
    positive count as a full disagreement (1).
    """
    names = [n for n in EQUATIONS if n in est.lam]
    ok = est.ok[sel] if sel != () else est.ok
    norm = {}
    for n in names:
        I = est.info[n][sel] if sel != () else est.info[n]
        pos = I[ok & (I > 0)]
        norm[n] = float(np.median(pos)) if pos.size else 0.0
    terms = []
    for i, a in enumerate(names):
        for b in names[i + 1:]:
            if not (norm[a] > 0 and norm[b] > 0):
                continue
            la = est.lam[a][sel] if sel != () else est.lam[a]
            lb = est.lam[b][sel] if sel != () else est.lam[b]
            Ia = (est.info[a][sel] if sel != () else est.info[a]) / norm[a]
            Ib = (est.info[b][sel] if sel != () else est.info[b]) / norm[b]
            w = np.where(ok, np.minimum(Ia, Ib), 0.0)
            good = (la > 0) & (lb > 0)
            with np.errstate(divide="ignore", invalid="ignore"):
                d = np.where(good, np.abs(np.log(np.where(good, la / lb, 1.0))), 1.0)
            terms.append((np.minimum(np.nan_to_num(d, nan=1.0), 1.0), np.nan_to_num(w)))
    return terms


def disagreement(est: DepthEstimates, sel=()) -> float:
    """Information-weighted mean of ``min(|log λ_i − log λ_j|, 1)`` over the pairs of
    equations and the rays of ``sel`` (an index into (F, Ny, Nx, Nv, Nu) arrays; all
    rays by default); NaN without information."""
    num = den = 0.0
    for d, w in _pair_terms(est, sel):
        num += float(np.sum(d * w, dtype=np.float64))
        den += float(np.sum(w, dtype=np.float64))
    return num / den if den > 0 else float("nan")


@dataclass(frozen=True)
class ScaleSelection:
    """The chosen scale per face (and per (u, v) tile for ``per="region"``)."""

    scales: tuple[Scale, ...]
    """The candidate scales that were compared."""
    face_choice: tuple[int, ...]
    """(F,) index into ``scales`` per face."""
    scores: np.ndarray
    """(F, S) disagreement per face and candidate (NaN: no information)."""
    region_choice: np.ndarray | None = None
    """(F, Tv, Tu) index into ``scales`` per (u, v) tile (``per="region"`` only)."""
    region_scores: np.ndarray | None = None
    """(F, Tv, Tu, S) disagreement per tile and candidate."""
    tile: int = 16
    """(u, v) tile size in samples of the regions."""

    def face_scales(self) -> tuple[Scale, ...]:
        return tuple(self.scales[i] for i in self.face_choice)


def _choose(scores: np.ndarray, tie: float) -> np.ndarray:
    """Index of the least-smoothing candidate within ``tie`` (relative) of the best, per row
    of scores (..., S); candidates are ordered from least to most smoothing except that
    (x, y) smoothing counts after no smoothing (see :data:`SCALE_LADDER`)."""
    s = np.where(np.isfinite(scores), scores, np.inf)
    best = s.min(axis=-1, keepdims=True)
    good = s <= best * (1.0 + tie)
    idx = np.argmax(good, axis=-1)
    return np.where(np.isfinite(best[..., 0]), idx, -1)


def _ladder_order(scales) -> list[int]:
    """Candidate order for tie-breaking: least total smoothing first."""
    return sorted(range(len(scales)), key=lambda i: (scales[i].xy + scales[i].uv, scales[i].xy))


def select_scales(L0: np.ndarray, L1: np.ndarray, grid: LightFieldGrid, T_prev_next: np.ndarray, *,
                  scales: tuple[Scale, ...] = SCALE_LADDER, per: str = "face", tile: int = 16,
                  window: int = 4, tie: float = 0.05, W0: np.ndarray | None = None,
                  max_sigma_uv: np.ndarray | None = None) -> ScaleSelection:
    """Choose per face (``per="face"``) or also per (u, v) tile (``"region"``) the scale at
    which the four depth estimates of the pair (L0, L1) (F, Ny, Nx, Nv, Nu) agree best,
    given the rig motion ``T_prev_next`` (4, 4). ``W0``: optional confidence of L0
    (rays with W0 ≤ 0.5 are ignored). ``max_sigma_uv``: optional (F,) cap [samples] of the
    (u, v) smoothing per face; candidates above it are not compared there (score NaN),
    the unsmoothed scale always is."""
    if per not in ("face", "region"):
        raise ValueError(f"per must be 'face' or 'region', got {per!r}")
    F, Ny, Nx, Nv, Nu = grid.shape
    order = _ladder_order(scales)
    Tv, Tu = -(-Nv // tile), -(-Nu // tile)
    S = len(scales)
    scores = np.full((F, S), np.nan)
    rscores = np.full((F, Tv, Tu, S), np.nan) if per == "region" else None
    cap = np.full(F, np.inf) if max_sigma_uv is None else np.broadcast_to(np.asarray(max_sigma_uv, float), (F,))
    allowed = np.array([[scales[si] == Scale() or scales[si].sigma_uv <= cap[k] for si in range(S)]
                        for k in range(F)])
    for si in range(S):
        if not allowed[:, si].any():
            continue
        der, ok = scale_derivatives(L0, L1, grid, scales[si])
        if W0 is not None:
            ok = ok & (np.asarray(W0) > 0.5)
        est = depth_estimates(der, grid, T_prev_next, ok=ok, window=window)
        for k in range(F):
            if not allowed[k, si]:
                continue
            scores[k, si] = disagreement(est, (slice(k, k + 1),))
            if rscores is not None:
                terms = _pair_terms(est, (slice(k, k + 1),))
                num = np.zeros((Tv, Tu))
                den = np.zeros((Tv, Tu))
                for d, w in terms:
                    dw = _tile_sum((d * w)[0], tile)
                    num += dw
                    den += _tile_sum(w[0], tile)
                with np.errstate(divide="ignore", invalid="ignore"):
                    rscores[k, :, :, si] = np.where(den > 0, num / den, np.nan)
    # choose in the tie-break order, map back to indices into scales
    ordered = scores[:, order]
    face_choice = tuple(int(order[i]) if i >= 0 else scales.index(Scale()) if Scale() in scales else 0
                        for i in _choose(ordered, tie))
    region_choice = None
    if rscores is not None:
        ri = _choose(rscores[..., order], tie)
        fallback = np.array(face_choice)[:, None, None]
        region_choice = np.where(ri >= 0, np.array(order)[np.maximum(ri, 0)], fallback)
    sel = ScaleSelection(scales=tuple(scales), face_choice=face_choice, scores=scores,
                         region_choice=region_choice, region_scores=rscores, tile=tile)
    log.info("scale selection: %s", ", ".join(s.name for s in sel.face_scales()))
    return sel


def _tile_sum(a: np.ndarray, tile: int) -> np.ndarray:
    """Sum of a (Ny, Nx, Nv, Nu) array over viewpoints and (u, v) tiles → (Tv, Tu)."""
    s = np.sum(a, axis=(0, 1), dtype=np.float64)
    Nv, Nu = s.shape
    Tv, Tu = -(-Nv // tile), -(-Nu // tile)
    pad = np.zeros((Tv * tile, Tu * tile))
    pad[:Nv, :Nu] = s
    return pad.reshape(Tv, tile, Tu, tile).sum(axis=(1, 3))


def apply_selection(L0: np.ndarray, L1: np.ndarray, sel: ScaleSelection,
                    W0: np.ndarray | None = None, W1: np.ndarray | None = None):
    """Both frames pre-smoothed at each face's chosen scale, with confidences that are 0
    where the smoothing support leaves the grid: (L0s, L1s, W0s, W1s), all
    (F, Ny, Nx, Nv, Nu) float32 (W None when nothing was smoothed and no W was given)."""
    fs = sel.face_scales()
    L0s, ok = smooth_at_scale(L0, fs)
    L1s, _ = smooth_at_scale(L1, fs)
    if ok.all() and W0 is None and W1 is None:
        return L0s, L1s, None, None
    okf = ok.astype(np.float32)
    W0s = okf if W0 is None else okf * np.asarray(W0, np.float32)
    W1s = okf if W1 is None else okf * np.asarray(W1, np.float32)
    return L0s, L1s, W0s, W1s


@dataclass(frozen=True)
class ScaleSelectedMotion:
    """Result of :func:`estimate_motion_scale_selected`."""

    result: object
    """The final :class:`polycam.motion.PairResult` (on the pre-smoothed frames)."""
    selection: ScaleSelection
    """The last scale selection."""
    history: list = field(default_factory=list)
    """Per round: (T_prev_next (4, 4), face scale names) before re-estimating."""


def estimate_motion_scale_selected(L0: np.ndarray, L1: np.ndarray, grid: LightFieldGrid, *,
                                   W0: np.ndarray | None = None, W1: np.ndarray | None = None,
                                   T_init: np.ndarray | None = None, options=None,
                                   scales: tuple[Scale, ...] = MOTION_SCALES, rounds: int = 2,
                                   tie: float = 0.05, index: int = 0,
                                   max_sigma_uv: np.ndarray | None = None) -> ScaleSelectedMotion:
    """Rig motion ``T_rig0_rig1`` with the scale-selection feedback loop of Sect. 4.1.

    1. ``estimate_motion`` on the frames as given (``options``: a
       :class:`polycam.motion.MotionOptions`);
    2. per face, the scale at which the four depth estimates agree (:func:`select_scales`);
    3. ``estimate_motion`` again on both frames pre-smoothed at those scales, from the
       previous estimate; repeat 2–3 up to ``rounds`` times or until the choice repeats.
    ``L0``, ``L1``, ``W0``, ``W1``: (F, Ny, Nx, Nv, Nu) (a colour axis is averaged).
    ``max_sigma_uv``: optional (F,) cap of the (u, v) smoothing (:func:`select_scales`).
    """
    from .motion import estimate_motion

    L0 = grey_frame(L0)
    L1 = grey_frame(L1)
    res = estimate_motion(L0, L1, grid, W0=W0, W1=W1, T_init=T_init, options=options, index=index)
    history = []
    sel = None
    prev = None
    for _ in range(max(0, int(rounds))):
        if not res:
            break
        sel = select_scales(L0, L1, grid, res.T_prev_next, scales=scales, tie=tie, W0=W0,
                            max_sigma_uv=max_sigma_uv)
        choice = sel.face_choice
        history.append((res.T_prev_next.copy(), tuple(s.name for s in sel.face_scales())))
        if choice == prev:
            break
        prev = choice
        if all(scales[i] == Scale() for i in choice) and not history[:-1]:
            break                                          # the unsmoothed input was already best
        a, b, w0, w1 = apply_selection(L0, L1, sel, W0, W1)
        res = estimate_motion(a, b, grid, W0=w0, W1=w1, T_init=res.T_prev_next, options=options, index=index)
    if sel is None:
        sel = ScaleSelection(scales=tuple(scales), face_choice=(0,) * grid.shape[0],
                             scores=np.full((grid.shape[0], len(scales)), np.nan))
    return ScaleSelectedMotion(result=res, selection=sel, history=history)


VIEW_DISPARITY_TEXTURE_GATE: float = 16.0
""":func:`view_disparity` with a noise variance: a ray's windowed energy of L_u (L_v) must exceed
this many times the energy its noise alone would give (an amplitude 4x the noise's), or the ray
has too little texture to measure and is left out. Without the gates, on frames with 16-32 grey
levels of noise, the noise's own L_x / L_u ratios made the paper's 8 m sphere scene (0.05
samples per view step) measure 1.3-1.9 (session 32)."""

VIEW_DISPARITY_STILL_GATE: float = 4.0
""":func:`view_disparity` with a noise variance: a textured ray (:data:`VIEW_DISPARITY_TEXTURE_GATE`)
whose windowed energy of L_x (L_y) is at most this many times its noise's, i.e. whose views differ
by no more than the noise, counts as disparity 0 (its λ as infinite)."""

VIEW_DISPARITY_AGREE: float = 2.0
""":func:`view_disparity`'s ``agree`` as the motion solver's level rule uses it: a ray's two
stereo estimates of λ = Z / f must have the same sign and lie within this factor of each other.
Session 35: on the paper's 12 m scene with 16 grey levels of noise the still gate let most of
one face's rays through in 3 of 96 draws; their λ had either sign, the median over λ > 0 measured
1.0-1.7 samples per view step instead of ~0 and stopped those solves one or two levels early."""


def view_disparity(L0: np.ndarray, L1: np.ndarray, grid: LightFieldGrid, *, W0: np.ndarray | None = None,
                   window: int = 4, noise_var: float = 0.0, agree: float = 0.0) -> np.ndarray:
    """(F,) median disparity per view step of each face, in (u, v) samples.

    From the differential-stereo depth estimates of Eq. 6 at the finest scale (no motion
    needed): λ = Z / f per ray (windowed least squares of ``L_u = λ L_x``, ``L_v = λ L_y``);
    a point moves by ``Δx / λ`` in u from one viewpoint to the next. The median runs over
    the rays with a positive λ (and W0 > 0.5 when given); NaN for a face without any.
    ``noise_var``: the sensor-noise variance per sample of each frame (independent in L0 and
    L1; :func:`~polycam.motion_weights.frame_noise_variance`); when positive, the rays are
    gated against the noise's energies (:data:`VIEW_DISPARITY_TEXTURE_GATE`,
    :data:`VIEW_DISPARITY_STILL_GATE`).
    ``agree`` > 0 (:data:`VIEW_DISPARITY_AGREE`): a ray whose two stereo equations are both
    measured counts only where they agree — λ of the same sign, within a factor ``agree`` of
    each other, or both still (disparity 0) — and then with its |disparity| (either sign: a
    light field's disparities may have both about its focal plane); one with a single equation
    measured counts as without ``agree``. Noise alone rarely passes (its λ are independent), a
    Lambertian point does (one Z for both). An axis with one viewpoint (a linear array's) has
    no stereo equation.
    """
    L0 = grey_frame(L0)
    L1 = grey_frame(L1)
    der, ok = scale_derivatives(L0, L1, grid, Scale())
    if W0 is not None:
        ok = ok & (np.asarray(W0) > 0.5)
    out = np.full(grid.shape[0], np.nan)
    steps = {"stereo_x": grid.x.step / grid.u.step, "stereo_y": grid.y.step / grid.v.step}
    est = depth_estimates(der, grid, None, ok=ok, window=window)
    if noise_var > 0.0:
        lams = _gated_stereo_lambda(est, der, grid, window, noise_var)
    else:
        lams = {name: np.where(np.isfinite(est.lam[name]), est.lam[name], np.nan) for name in steps}
    for name, axis in (("stereo_x", grid.x), ("stereo_y", grid.y)):
        if axis.count == 1:                  # a linear array's single-view axis: not measured
            lams[name] = np.full_like(lams[name], np.nan)
    if agree > 0.0:
        lams = _agreeing_lambdas(lams["stereo_x"], lams["stereo_y"], agree)
    for k in range(grid.shape[0]):
        d = []
        for name, ratio in steps.items():
            lam = lams[name][k]
            lam = lam[~np.isnan(lam) & (lam > 0)]
            if lam.size:
                d.append(ratio / float(np.median(lam)))
        if d:
            out[k] = max(d)
    return out


def _agreeing_lambdas(lam_x: np.ndarray, lam_y: np.ndarray, factor: float) -> dict:
    """{"stereo_x": .., "stereo_y": ..}: λ of the two stereo equations (same dims; NaN
    unmeasured, inf still) where both are measured and agree (same sign, within ``factor``, or
    both inf), as |λ|; NaN where both are measured and do not; as given where only one is."""
    both = ~np.isnan(lam_x) & ~np.isnan(lam_y)
    ax, ay = np.abs(lam_x), np.abs(lam_y)
    # (both inf: the same sign, and inf <= factor x inf)
    ok = (np.sign(lam_x) == np.sign(lam_y)) & (np.maximum(ax, ay) <= factor * np.minimum(ax, ay))
    return {name: np.where(both, np.where(ok, np.abs(lam), np.nan), lam).astype(lam.dtype)
            for name, lam in (("stereo_x", lam_x), ("stereo_y", lam_y))}


def _gated_stereo_lambda(est: DepthEstimates, der, grid: LightFieldGrid, window: int, noise_var: float) -> dict:
    """Name → the two stereo equations' λ of ``est`` (:func:`depth_estimates` of ``der``)
    gated against the noise: NaN where the window's energy of b (L_u, L_v) is within
    :data:`VIEW_DISPARITY_TEXTURE_GATE` of the noise's, else inf where that of a (L_x, L_y;
    ``est.info``) is within :data:`VIEW_DISPARITY_STILL_GATE`."""
    noise = equation_noise(grid, derivative_noise(noise_var, grid, DEPTH_FILTERS, smoothing_taps(Scale(), grid)),
                           equations=("stereo_x", "stereo_y"))
    valid = est.ok.astype(np.float32)
    n = window_sum(valid, window)
    out = {}
    for name, (_, b) in depth_equations(der, grid, None).items():
        va, _, vb = noise[name]
        textured = est.ok & (window_sum(b * b * valid, window) > VIEW_DISPARITY_TEXTURE_GATE * vb * n)
        still = est.info[name] <= VIEW_DISPARITY_STILL_GATE * va * n
        out[name] = np.where(textured, np.where(still, np.float32(np.inf), est.lam[name]), np.float32(np.nan))
    return out


class ScaleTracker:
    """Sect. 4.1 scale selection along a sequence of frame pairs.

    The first pair (and every ``reselect_every``-th after it) runs the feedback loop of
    :func:`estimate_motion_scale_selected` over ``scales`` (default :data:`MOTION_UV_SCALES`),
    each face's (u, v) smoothing capped at ``factor`` x its disparity (:func:`view_disparity`);
    the pairs in between reuse that choice: both frames pre-smoothed at it and one
    :func:`~polycam.motion.estimate_motion` (the depth range changes slowly along a sequence).
    ``estimate(...)`` takes and returns what ``estimate_motion`` does.
    """

    def __init__(self, grid: LightFieldGrid, *, scales: tuple[Scale, ...] = MOTION_UV_SCALES,
                 factor: float = DISPARITY_SIGMA_FACTOR, reselect_every: int = 8, rounds: int = 2):
        self.grid = grid
        self.scales = tuple(scales)
        self.factor = float(factor)
        self.reselect_every = max(1, int(reselect_every))
        self.rounds = rounds
        self.selection: ScaleSelection | None = None
        """The choice in use (None before the first pair)."""
        self.disparity: np.ndarray | None = None
        """(F,) disparity per view step [samples] measured at the last selection."""
        self._pairs = 0

    def estimate(self, L0: np.ndarray, L1: np.ndarray, *, W0: np.ndarray | None = None,
                 W1: np.ndarray | None = None, T_init: np.ndarray | None = None, options=None,
                 index: int = 0):
        """The :class:`~polycam.motion.PairResult` of one frame pair (F, Ny, Nx, Nv, Nu)."""
        from .motion import estimate_motion

        grid = self.grid
        L0 = grey_frame(L0)
        L1 = grey_frame(L1)
        if self.selection is None or self._pairs % self.reselect_every == 0:
            self.disparity = view_disparity(L0, L1, grid, W0=W0)
            cap = np.nan_to_num(self.factor * self.disparity, nan=0.0)
            out = estimate_motion_scale_selected(L0, L1, grid, W0=W0, W1=W1, T_init=T_init, options=options,
                                                 scales=self.scales, rounds=self.rounds, index=index,
                                                 max_sigma_uv=cap)
            self.selection = out.selection
            res = out.result
            log.info("pair %d: disparity %s samples per view step; scales %s", index,
                     ", ".join(f"{d:.2f}" for d in self.disparity),
                     ", ".join(s.name for s in self.selection.face_scales()))
        elif all(s == Scale() for s in self.selection.face_scales()):
            res = estimate_motion(L0, L1, grid, W0=W0, W1=W1, T_init=T_init, options=options, index=index)
        else:
            a, b, w0, w1 = apply_selection(L0, L1, self.selection, W0, W1)
            res = estimate_motion(a, b, grid, W0=w0, W1=w1, T_init=T_init, options=options, index=index)
        self._pairs += 1
        return res




def depth_scale_selected(L0: np.ndarray, L1: np.ndarray, grid: LightFieldGrid, T_prev_next: np.ndarray, *,
                         selection: ScaleSelection | None = None, scales: tuple[Scale, ...] = SCALE_LADDER,
                         per: str = "region", tile: int = 16, window: int = 4,
                         equations: tuple[str, ...] = ("stereo_x", "stereo_y", "motion_pos"),
                         W0: np.ndarray | None = None, noise_var: float | None = None
                         ) -> tuple[DepthMap, ScaleSelection]:
    """Fused depth (:func:`~polycam.depth.depth_from_derivatives`) where every face / (u, v)
    tile takes the scale its four depth estimates agree best at, corrected for the sensor
    noise of variance ``noise_var`` per sample (None: estimated from the frames; 0: none).

    Returns the :class:`~polycam.depth.DepthMap` (F, Ny, Nx, Nv, Nu) and the selection
    used (computed unless ``selection`` is given; ``per`` as in :func:`select_scales`).
    """
    L0 = grey_frame(L0)
    L1 = grey_frame(L1)
    if selection is None:
        selection = select_scales(L0, L1, grid, T_prev_next, scales=scales, per=per, tile=tile,
                                  window=window, W0=W0)
    F, Ny, Nx, Nv, Nu = grid.shape
    if selection.region_choice is not None:
        t = selection.tile
        choice = np.repeat(np.repeat(selection.region_choice, t, axis=1), t, axis=2)[:, :Nv, :Nu]
    else:
        choice = np.broadcast_to(np.array(selection.face_choice)[:, None, None], (F, Nv, Nu))
    Z = np.full(grid.shape, np.nan, np.float32)
    conf = np.zeros(grid.shape, np.float32)
    cons = np.zeros(grid.shape, np.float32)
    if noise_var is None:                                      # the sensor noise, for each scale's derivatives
        noise_var = frame_noise_variance(L0, L1, grid, W0)
    for si in np.unique(choice):
        scale = selection.scales[int(si)]
        der, ok = scale_derivatives(L0, L1, grid, scale)
        noise = derivative_noise(noise_var, grid, DEPTH_FILTERS, smoothing_taps(scale, grid))
        dm = depth_from_derivatives(der, grid, T_prev_next=T_prev_next, window=window,
                                    equations=equations, valid=ok, noise=noise)
        m = np.broadcast_to((choice == si)[:, None, None], grid.shape)
        Z[m] = dm.Z[m]
        conf[m] = dm.confidence[m]
        cons[m] = dm.consistency[m]
    return DepthMap(Z=Z, confidence=conf, consistency=cons), selection
