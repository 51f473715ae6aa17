"""Settings of the plenoptic motion solver (:func:`polycam.motion.estimate_motion`).

:class:`MotionOptions` lives here, apart from the solver, so that the modules the solver is
built from (:mod:`polycam.motion_weights`, :mod:`polycam.pyramid`) can take it without
importing :mod:`polycam.motion`; it is re-exported there. What the options do:
docs/motion.md and the docstring of :mod:`polycam.motion`. :func:`options_from_strings`
reads them from ``KEY=VALUE`` strings (``polycam motion --option``), :func:`changed_options`
lists the ones that differ from the defaults. :data:`PRESETS` names the two measured sets
(``default``, and ``noisy`` for frames with a grey level of noise or more: ``polycam motion
--preset noisy``).
"""

from __future__ import annotations

import math

from collections.abc import Sequence
from dataclasses import dataclass, field, fields, replace

from .errors import InputError

__all__ = ["MotionOptions", "NOISY", "PRESETS", "options_from_strings", "changed_options", "describe_options"]


@dataclass(frozen=True)
class MotionOptions:
    """Settings of the plenoptic motion solver (defaults are the tuned ones)."""

    filters: str | dict = field(default_factory=lambda: {"x": "fs3", "y": "fs3", "u": "fs5", "v": "fs5"})
    """Derivative filter pair name for all axes, or axis name (x y u v) → name (see FILTERS)."""
    levels: int = 3
    """Pyramid levels (1 = single scale)."""
    max_view_disparity: float = 0.75
    """Plenoptic sampling: the finest (u, v) level the solver goes down to is the first whose
    disparity per view step is at most this many of its (u, v) samples (``inf``: always the
    frames' own sampling). Where the views are farther apart than that for the scene (camera
    arrays: a 3 x 3 webcam rig at 4 cm sees the room at ~2.5 pixels per 2 cm view step), the
    light field is aliased across the views at the fine (u, v) scales: the interpolation across
    the views and the derivatives along x, y fail there and bias the estimate (20 % translation
    error on the rendered light field of that rig at its own sampling, 2–6 % two levels up;
    docs/motion.md, "Camera arrays"). The disparity is measured per pair
    (:func:`polycam.scales.view_disparity`, on the central 3 x 3 views of the coarsest level up
    to the third, its rays gated against that level's sensor noise) and the pyramid is
    extended so that ``levels`` levels remain from there. On the paper's set-up (0.15 samples
    per view step) and HCI *antinous* (0.3–0.6) it changes nothing. Levels that halve (x, y)
    too (``pyramid_xy``) do not lower the disparity per view step, so the search stops before
    them. ``PairResult.uv_level`` says which level the
    estimate comes from."""
    depth_views: float = 0.25
    """The warp blends the (up to) four viewpoints around each moved ray along the direction's
    disparity ρ̄ (paper Eq. 6: each view read at the direction that sees the same scene point;
    :func:`polycam.warp._depth_views_kernel`) instead of at one direction, at every level whose
    disparity per view step (measured as for ``max_view_disparity``, in the level's own samples)
    is above this many samples, from the warp after the level's first ρ̂ on (or the coarser
    level's ρ̄). Linear interpolation across views that far apart blends different scene points,
    so the warped frame lags the true motion at the converged estimate and the translation comes
    out long (camera arrays: per-pair translation error 5–8 % → 1.2–2.5 %; docs/motion.md, "Camera
    arrays"). Below ~0.2 the plain blend is already exact and ρ̄'s own error costs a little (the
    paper's spheres at 8 m, 0.1 samples per view step: t 0.07 → 0.15 % with 0; at 12 m, 0.21: 0.44 →
    0.49 %), hence the threshold; a row of five cameras at 0.28 gains (1.4 → 1.0 %). Not with
    ``symmetric`` (whose warps have no ρ̄). ``inf``: never. Not measured (fewer than 3 views along x or y, ``max_view_disparity`` inf):
    never."""
    linear_gain: bool = True
    """On a linear array (one viewpoint along x or y), divide each ray's ρ̂ by the gain of the
    derivative filter across the views at its window's frequencies
    (:mod:`polycam.filter_response`): fs3 reads L_x, so ρ̂, up to a few per cent high where the
    views are a sizeable fraction of a sample apart, and the warp's Eq. 6 extrapolation with that
    ρ̄ converged with the translation along the single-view axis short by as much (OAK-D Lite
    sessions 2.3 → 1.2 % per pair; docs/motion.md, "The view filter's gain"). False: the solver
    before session 46."""
    pyramid_xy: bool = False
    """Also halve the (x, y) sampling at coarse levels when there are enough viewpoints."""
    iterations: int = 4
    """Warp / re-solve iterations per level (the last level may stop early on convergence)."""
    irls_steps: int = 2
    """Re-weighted solves per iteration (0 = plain weighted least squares)."""
    robust: str = "tukey"
    """``tukey``, ``huber`` or ``none``: the IRLS loss on normalised residuals."""
    robust_c: float = 4.685
    """Loss constant in units of the robust residual scale (4.685 Tukey, 1.345 Huber)."""
    smooth_c: float = 0.5
    """Discontinuity weight ``1 / (1 + (e / (c · median e))²)``, e = the largest |∂²L/∂u²| +
    |∂²L/∂v²| within ``smooth_radius`` samples (0 disables): silhouettes, creases and
    aliased steps, where interpolation and linearisation fail, get little weight. On frames
    without confidences W (rendered light fields, plenoptic cameras' decoded ones); with them
    the solver takes ``smooth_c_resampled``."""
    smooth_c_resampled: float = 0.0
    """``smooth_c`` on frames with confidences W (a resampled camera-array session, or a store
    ``polycam resample`` wrote; :meth:`for_frames`); 0: no discontinuity weight there. The
    weight normalises e by its median, so a ray of median e gets 0.2: on a textured room that
    is most rays (mean weight 0.27–0.36 on the example rigs' sessions), and the weight then
    mostly ranks texture rather than flagging silhouettes; where noise dominates e it ranks
    the noise. Measured against 0.5 (docs/motion.md, "The discontinuity weight on resampled
    sessions", session 44; median per-pair translation error): benchmarks/bench_arrays.py
    webcam3x3 2.57 → 1.92 %, oak_array 2.22 → 1.78, webcam5x5 1.87 → 1.45, oak_d_lite 3.56 →
    3.26, mock5x5 0.77 → 0.79, mock1x5 2.13 → 2.24; the nested cube's spheres with its 2.55
    grey levels of camera noise 1.94 → 0.94 % (noise-free cameras: 0.17 → 0.33 %). ``polycam
    run`` had used 0 since session 2 (``RunOptions.smooth_c``, now this default)."""
    smooth_radius: int = 2
    """Half-width in (u, v) samples of the neighbourhood searched for discontinuities."""
    eiv: bool = False
    """Take each step with ``AᵀWA − E`` (E = expected sensor-noise energy in the derivatives,
    errors in variables): with noisy derivatives AᵀWA alone under-steps, so the iteration
    stops short of the answer (benchmarks/bench_noise.py: ~3x less translation error at 16
    grey levels, unchanged noise-free). Off: the covariance then under-predicts the scatter
    of repeated estimates by up to ~2x where t and ω couple (docs/motion.md)."""
    model_weight: bool = False
    """Model-validity weight at the finest level (:func:`~polycam.motion_weights.model_error_weights`):
    before the IRLS passes of each warp, a ray's weight becomes ``s² / (s² + ê²)`` with ê² the
    Eq. 5 residual energy pooled over 7 x 7 views x 5 x 5 directions beyond what noise of the
    robust scale s explains: the model error (silhouettes, aliasing) that the IRLS weights
    stop singling out once the noise is as large as it (their cut-off grows with the noise).
    With the noise options (benchmarks/bench_noise.py, blurred set-up, 48 draws;
    ``model_weight_gain=1``) at 1 / 2 grey levels: at 4 m the translation error / CRB drops
    from 3.65 / 2.39 to 1.79 / 1.90 and the rotation's from 1.95 / 1.50 to 1.44 / 1.31; at 8 m
    the translation's from 11.1 / 5.68 to 5.69 / 4.21; from 4 grey levels on it changes
    nothing (to ±0.02: where noise dominates the weights stay near 1; docs/motion.md,
    "Noise"). With the default options it does not help on Fig. 5c (their discontinuity weight
    already discards most model error; at 12 m the translation error doubles), nor on the camera-array
    sessions (better on one seed, worse on another), but on one face of sharp (aliased) synthetic
    frames it cut the errors 3-7x (docs/motion_log.md, session 40). ~+35 % time per estimate
    and two float32 work arrays of the finest level's rays (about one frame more memory).
    It needs the IRLS passes (``robust`` not ``none``, ``irls_steps`` ≥ 1): it acts in the
    first and takes their robust scale s; without them it does nothing."""
    model_weight_gain: float = 1.0
    """κ > 0 of ``model_weight``: a ray's weight is ``s² / (s² + κ ê²)``. κ = 1 treats the
    window's model error as noise of its energy (the variance weight); but model error is
    systematic, so over the many rays of a silhouette or an aliased texture it adds up as a
    bias, where noise averages out, and a larger κ discounts it more. Measured with the noise
    options (benchmarks/bench_noise.py, blurred set-up, 48 antithetic draws; docs/motion.md,
    "Noise"), κ = 8 against 1: at 8 m the translation error / CRB at 1 / 2 grey levels drops
    from 2.53 / 2.19 to 1.98 / 1.83, at 4 m it rises at 1 grey level (2.04 → 2.27), the
    rotation's by up to 0.2 below 4 grey levels; from 4 grey levels on it changes nothing to
    within ±0.05 (the weights stay near 1 where noise dominates). Only with ``model_weight``."""
    smooth_noise: bool = False
    """Noise-aware discontinuity weight: subtract from e the level that sensor noise alone
    reaches (its 99th percentile for the noise variance estimated from the frames), so that
    noise is not read as discontinuities (:func:`~polycam.motion.discontinuity_weight`). Helps with ``eiv``
    at 16-32 grey levels; off because at 1-3 grey levels it lets more model error in
    (bench_motion.py's 8-bit rows: translation error 3.8% → 4.4% at 3 grey levels)."""
    depth_regressors: bool = True
    """Replace the positional derivatives by ``ρ̂ L_u, ρ̂ L_v`` (paper Eq. 6, Lambertian:
    ``L_x = ρ L_u``), ρ̂ = Σ (L_x L_u + L_y L_v) / Σ (L_u² + L_v²) pooled over a window (fs5
    twice in (u, v), fs3 once across the views; the denominator less the energy the noise of
    L_u, L_v adds to it, which would shrink ρ̂ at high noise), except where one ρ does not explain the
    window (its residual energy above 3x the expected noise of L_x, L_y: occlusions, and
    noise-free data, where that noise is ~0; but see ``depth_gate``) and where ρ̂ L_u, ρ̂ L_v
    would be noisier than the measured pair (ρ̂² var_u + L_u² var(ρ̂) above var_x, e.g. a ray
    whose edge dominates its window): less noise in the regressors of the
    translation (benchmarks/bench_noise.py: translation error / CRB 18.7 → 6.6 at 8 grey
    levels, 29.5 → 4.6 at 16). At the two finest pyramid levels (the one above the finest
    hands its ρ̄ down, so that the finest extrapolates from its first warp: one solve less
    there, session 34); costs +30–36 ms wall per estimate on 1.33 M rays with the
    ``extrapolate_views`` it enables at the finest level alone (session 33: ρ̂ ~12, the
    extrapolation ~11, the regressors ~6 ms), less with the solve it saves. On by
    default since session 5 (at least as accurate as the measured regressors in every
    benchmark and test, 4x less translation error on the paper's Fig. 5c scene at 8-16 m);
    ``False``: Eq. 5 with the measured L_x, L_y everywhere. A linear array (one viewpoint along
    x or y) has no measured regressor along that axis: there ρ̂ (from the other axis alone)
    replaces it at every level whatever this option, and rays without ρ̂ are left out
    (docs/motion.md, "Linear arrays")."""
    depth_pool_views: bool = False
    """``depth_regressors``: pool each ray's ρ̂ with the other views' at its direction (they see
    nearly the same scene point): shrink it towards their mean by as much as its own noise
    warrants, an empirical-Bayes estimate that keeps ρ̂ where the depth differs across the
    views (:mod:`polycam.rho_pool`). Helps where ρ̂'s window alone is noisy (far scenes, high
    noise: benchmarks/bench_noise.py's noise options at 32 grey levels, translation error / CRB
    1.74 → 1.36 at 8 m, 1.67 → 1.32 at 6 m; unchanged below 8 grey levels); needs the frames'
    noise estimate (does nothing without noise). Costs one float32 array of the light field's
    size while ρ̂ is computed and 4–6 % time. Part of the noise options
    (:data:`NOISY`, ``--preset noisy``); off by default, which is tuned for low noise and has not
    been measured with it (docs/motion_log.md, Session 24)."""
    depth_gate: float = 0.25
    """``depth_regressors``: also replace where the window's disparity is at most this many
    (u, v) samples per view step and its misfit is far above the noise (at least 1000x the
    expected noise of L_x, L_y, ``depth_gate_misfit``: aliasing, not signal).
    There the views are nearly parallel, the measured L_x, L_y are tiny and carry the
    aliasing of the directions (a view's samples shift by a fraction of a sample), while
    ρ̂ L_u does not: on the sphere scene (0.04-0.15 samples per view at 4-16 m) the
    noise-free translation error drops 4x at 8-16 m (benchmarks/bench_motion.py). A misfit
    of a few dozen to a few hundred times the noise is signal the measured derivatives carry
    beyond one depth: replacing it there (session 4, without the misfit floor) gave a noisy
    near room seen by one face of views 1 cm apart 2.3x the translation scatter (docs/motion_log.md).
    0: only where one depth explains the window to within the noise."""
    depth_gate_misfit: float = 1000.0
    """``depth_gate``: where the gate falls back (``depth_gate_cond``, ``depth_gate_z``), it
    replaces only windows whose misfit is at least this many times the expected noise of
    L_x, L_y (noise-free data: always). 1000 keeps the measured regressors on the noisy
    one-face room (misfit 28-310x the noise) and replaces on the noise-free spheres
    (1e4-6e5x). inf: never replace there."""
    depth_gate_cond: float = 2.0
    """``depth_gate``: the gate acts wherever it holds unless, at the first ρ̂ of the finest
    level, the Jacobi-scaled condition number of the normal matrix with it exceeds this
    factor times that of the measured regressors (information lost: the noisy one-face room,
    10 → 60; the spheres at 12 m, 1.3 → 1.3) *and* the two increments agree to within
    ``depth_gate_z`` of their standard deviations (no aliasing bias in the measured
    regressors for the gate to remove); then ``depth_gate_misfit`` applies."""
    depth_gate_z: float = 3.0
    """``depth_gate_cond``: the disagreement, in standard deviations of the measured
    regressors' estimate (cluster-robust, t and ω separately), above which the gate is kept
    although it costs conditioning (measured: the noisy room ≤ 2, one aliased face 12-17)."""
    extrapolate_views: float = 2.0
    """Rays whose warped position leaves the viewpoints by at most this many view steps are
    filled from the nearest edge viewpoint(s) by Eq. 6 (the direction shifted by the
    disparity: ``L(x_e + d, u) = L(x_e, u + ρ d)``, ρ averaged over the views per direction
    from the ``depth_regressors`` estimate; the two finest levels, from the first warp with a
    ρ̂ (the finest: its first, with the ρ̄ of the level above); not with ``symmetric``) instead
    of being dropped; ρ̂ is then computed from the rays whose filter
    support holds no extrapolated sample, and the others get the view average. 0: dropped
    (also without ``depth_regressors``). A linear array's rays moved off its single-view axis
    are always extrapolated, with no limit along that axis (this limit applies to the other)."""
    whiten: str = "off"
    """Generalised least squares at the finest level: ``on`` whitens the Eq. 5 rows by the
    inverse of the prefilters' noise covariance ⊗ₐ K_a K_aᵀ (banded Cholesky per axis) once
    the plain solve has converged, then re-solves; ``auto`` does so only when the whitened
    residual is within ``whiten_ratio`` of the expected sensor noise (noise dominates the
    misfit; whitening amplifies the high frequencies where aliasing lives); ``off`` never."""
    whiten_floor: float = 0.3
    """Ridge added to each axis' K_a K_aᵀ before whitening (its largest eigenvalue is about 1):
    caps the amplification of the frequencies the prefilter removes (0: exact GLS, whose
    whitened misfit on the noise-free sphere scene is ~10⁵ times the noise: aliasing and the
    weights' edges; 0.3 measured best of 0.03, 0.1, 0.3 at 16-32 grey levels)."""
    whiten_ratio: float = 2.0
    """``whiten="auto"``: largest whitened residual variance, in units of the expected
    whitened noise variance 2 σ², at which the whitened re-solve is taken."""
    symmetric: bool = False
    """Warp both frames half-way (else frame 2 by the whole estimate; measured equally
    accurate with cubic interpolation, and half the warping cost). Not on a linear array (its
    warp extrapolates off the single-view axis, which the symmetric warp does not): its pairs
    fail with that reason."""
    warp_confidence: bool = False
    """With confidences W0, W1: warp frame 2's W1 along with the frame (True), or, when W1 has
    no zeros, weight each ray by W0 W1 at its own sample (False; ``polycam.motion._Solver._warp``).
    The warp moves rays by a sample or two, over which a resampled session's W changes little:
    measured on the example rigs' `polycam run` sessions (demo, webcam3x3, webcam5x5, oak_array,
    the cube) median per-pair errors equal or lower (1.45 / 4.86 / 7.08 / 6.63 / 6.05 % against
    1.50 / 4.89 / 7.07 / 6.70 / 6.14 %), and on bench_motion's frame pair the cost of W halved
    (129 against 119 ms without W; 5.0 frames of peak memory instead of 5.4; session 39). A level
    whose W1 has zeros (samples without data) warps it: the warp's "no data" channel keeps the rays
    that read such a sample out."""
    uv_taps: int = 6
    """Lagrange interpolation points along u and v in the warp: 2 (linear), 4 (cubic), 6
    (quintic; measured: rotation error at 8-16 m from ~1% with 4 to ~0.1-0.2%), 8 (the noise
    options of session 23: on the blurred 8 m sphere scene the noise-free rotation bias 1.78 →
    0.39 µrad, and ω at 1 grey level 1.64 → 1.35x its bound; 64 taps per sample instead of 36)
    10 (the noise options since session 26: at the paper's full motion, 8 m, the noise-free
    rotation bias 2.6 → 1.1 µrad and ω at 1 grey level 1.62 → 1.23x; 100 taps, 2–3 % more time),
    or any even number up to 16 (session 32: PSF 0.5 at 8 m on 16 x 16-ray frames, unweighted,
    noise-free rotation bias 1.68 / 0.82 / 0.40 / 0.22 µrad at 10 / 12 / 14 / 16 taps)."""
    rcond: float = 1e-7
    """Jacobi-scaled eigenvalue ratio below which a direction is unobservable."""
    min_rays: int = 64
    """Fewer usable rays than this is a failed estimate."""
    parallax_min: float = 0.2
    """Translation directions whose *signal fraction* is below this are unobservable (no parallax
    above the noise): the fraction of the translation columns' energy that the two frames have in
    common (:func:`polycam.parallax.parallax_signal`, measured after the finest level's solve on its
    central 5 x 5 views and a textured (u, v) window per face, ~3.5 ms). The smallest fraction
    of sets with honest estimates measured 0.45–1.0, of noise-fitted ones (a room 10³–10⁶ m away
    with noise, frames of pure noise) −0.12 and less (docs/motion.md, "No parallax above the
    noise"); 0 turns the test off. A flagged pair keeps its estimate; its translation std is infinite."""
    tol: float = 1e-7
    """Stop iterating when the increment is below this (|t| [m] + |ω| [rad])."""
    tile: int = 16
    """Largest (u, v) tile in samples for the cluster-robust covariance (smaller on small
    grids so that each face has about 8 x 8 tiles, at least 4 samples; the reported covariance
    sums tiles under 8 samples into blocks of 8 where 24 such clusters remain:
    ``polycam.motion._clusters``)."""

    def __post_init__(self) -> None:
        if self.robust not in ("tukey", "huber", "none"):
            raise ValueError(f"robust must be tukey, huber or none, got {self.robust!r}")
        if self.uv_taps not in range(2, 17, 2):
            raise ValueError(f"uv_taps must be an even number from 2 to 16, got {self.uv_taps}")
        if self.whiten not in ("auto", "on", "off"):
            raise ValueError(f"whiten must be auto, on or off, got {self.whiten!r}")
        if not self.depth_gate >= 0.0:
            raise ValueError(f"depth_gate must be >= 0, got {self.depth_gate}")
        if not self.depth_gate_misfit >= 0.0:
            raise ValueError(f"depth_gate_misfit must be >= 0, got {self.depth_gate_misfit}")
        if not self.depth_gate_cond >= 1.0:
            raise ValueError(f"depth_gate_cond must be >= 1, got {self.depth_gate_cond}")
        if not self.depth_gate_z > 0.0:
            raise ValueError(f"depth_gate_z must be > 0, got {self.depth_gate_z}")
        if not 0.0 <= self.smooth_c_resampled < math.inf:
            raise ValueError(f"smooth_c_resampled must be >= 0 and finite, got {self.smooth_c_resampled}")
        if not 0.0 < self.model_weight_gain < math.inf:
            raise ValueError(f"model_weight_gain must be > 0 and finite, got {self.model_weight_gain}")
        if not 0.0 <= self.extrapolate_views < math.inf:
            raise ValueError(f"extrapolate_views must be >= 0 and finite, got {self.extrapolate_views}")
        if not self.depth_views >= 0.0:
            raise ValueError(f"depth_views must be >= 0 (inf: never), got {self.depth_views}")
        if not self.max_view_disparity > 0.0:
            raise ValueError(f"max_view_disparity must be > 0 (inf: no limit), got {self.max_view_disparity}")
        if not 0.0 < self.robust_c < math.inf:
            raise ValueError(f"robust_c must be > 0 and finite, got {self.robust_c}")
        if not 0.0 <= self.smooth_c < math.inf:
            raise ValueError(f"smooth_c must be >= 0 and finite, got {self.smooth_c}")
        if not 0.0 <= self.parallax_min <= 1.0:
            raise ValueError(f"parallax_min must be in [0, 1], got {self.parallax_min}")
        if self.levels < 1 or self.iterations < 1 or self.irls_steps < 0:
            raise ValueError("levels and iterations must be >= 1, irls_steps >= 0")

    def for_frames(self, confidences: bool) -> "MotionOptions":
        """The options as the solver applies them to a frame pair with (``confidences``: W0 or
        W1 given) or without confidences W: with them ``smooth_c`` is ``smooth_c_resampled``."""
        if confidences and self.smooth_c != self.smooth_c_resampled:
            return replace(self, smooth_c=self.smooth_c_resampled)
        return self


NOISY = MotionOptions(smooth_c=0.0, eiv=True, whiten="on", model_weight=True, model_weight_gain=8.0, uv_taps=14,
                      depth_pool_views=True)
"""The noise options: the set measured best together on frames with noise of a grey level or more
(benchmarks/bench_noise.py's ``--high-noise`` table, docs/motion.md, "Noise"). No discontinuity weight
(computed from noisy frames it discards rays at random), errors-in-variables steps, whitened
re-solves, the model-validity weight with gain 8, 14-point (u, v) interpolation and ρ̂ pooled over the
views: on the paper's sphere scene through a blurring lens (``bench_noise.py --blur 0.8``), at 4–12 m
and for the paper's full motion at 8 m, within 1.5x of the Cramér–Rao bound from 1 to 32 grey levels,
where the defaults are 1.3–2.3x; through sharper lenses (PSF 0.5 and 0.3 samples, 8 m, frames
integrated over 16 x 16 rays per sample, 1 and 4 grey levels) 1.23–1.42x, where 10 points left the
rotation at up to 1.79x (14 since session 33; 8 from session 23, 10 from session 26); on unblurred,
aliased frames 1.5–2.0x. They cost about 2.2x the defaults' time per estimate (the whitened re-solves,
the model weight, the pooling, the longer warp: 307 against 137 ms on benchmarks/bench_motion.py's one
face at 2 grey levels; with 10 points 271 ms) and a peak of 6.4 frames of memory instead of 4.4
(docs/motion.md, "Speed and memory"). The defaults stay tuned for 8-bit cameras in good light (under a
grey level of noise), where the model bias matters more: on the noise-free Fig. 5c frames their errors
are 0.44 / 0.29 % (t / ω) at 12 m against these options' 1.15 / 0.66 % (with 10 points). They model
noise independent from sample to sample: on resampled camera-array sessions (viewpoints interpolated
between the cameras, push-pull) they measured no better than the defaults, on the 3 x 3 webcam rig
worse (docs/motion.md, "Which preset"). ``polycam motion`` prints the frames' noise
(:attr:`polycam.motion.PairResult.noise_sigma`) and points to this preset from a grey level on, for
frames without confidences."""

PRESETS: dict[str, MotionOptions] = {"default": MotionOptions(), "noisy": NOISY}
"""The named option sets (the CLI's ``--preset``); ``--option`` items apply on top."""


_TRUE = ("true", "on", "yes", "1")
_FALSE = ("false", "off", "no", "0")


def _default(f) -> object:
    return f.default_factory() if callable(f.default_factory) else f.default


def _parse_value(name: str, default: object, text: str) -> object:
    """``text`` as the type of the field's ``default`` (ValueError: it is not one)."""
    if isinstance(default, bool):
        t = text.strip().lower()
        if t in _TRUE or t in _FALSE:
            return t in _TRUE
        raise ValueError(f"expected true or false, got {text!r}")
    try:
        if isinstance(default, int):
            return int(text)
        v = float(text) if isinstance(default, float) else None
    except ValueError:
        raise ValueError(f"expected {'an integer' if isinstance(default, int) else 'a number'}, got {text!r}") from None
    if v is not None:
        if math.isnan(v):
            raise ValueError("expected a number, got nan")
        return v
    if name == "filters":        # a name for all axes, or axis:name pairs
        if ":" not in text:
            return text.strip()
        pairs = [item.split(":", 1) for item in text.split(",")]
        if any(len(p) != 2 or p[0].strip() not in ("x", "y", "u", "v") for p in pairs):
            raise ValueError(f"expected a filter name or axis:name pairs (x, y, u, v), got {text!r}")
        return {k.strip(): v.strip() for k, v in pairs}
    return text


def options_from_strings(items: Sequence[str], base: MotionOptions | None = None) -> MotionOptions:
    """:class:`MotionOptions` from ``KEY=VALUE`` strings (the CLI's ``--option``), each
    value read as its field's type: bool ``true``/``false`` (also on/off, yes/no, 1/0),
    int, float (``inf`` allowed, not ``nan``), str; ``filters`` takes a filter name for all
    axes (``fs5``) or ``axis:name`` pairs (``x:fs3,y:fs3,u:fs5,v:fs5``). Later items win;
    the others keep ``base``'s values (default: the defaults).
    Raises :class:`~polycam.errors.InputError` (one line naming the item) for an unknown
    key, a value of the wrong type, or options :class:`MotionOptions` rejects."""
    known = {f.name: f for f in fields(MotionOptions)}
    kw: dict[str, object] = {}
    for item in items:
        key, sep, text = item.partition("=")
        key = key.strip()
        if not sep:
            raise InputError(f"--option {item!r}: expected KEY=VALUE")
        if key not in known:
            raise InputError(f"--option {key}: not a solver option (one of: {', '.join(known)})")
        try:
            kw[key] = _parse_value(key, _default(known[key]), text)
        except ValueError as e:
            raise InputError(f"--option {key}: {e}") from None
    try:
        opts = replace(base, **kw) if base is not None else MotionOptions(**kw)
    except ValueError as e:
        raise InputError(f"--option: {e}") from None
    if "filters" in kw:                 # the names exist (the filter table's module imports numba)
        from .derivatives import FILTERS

        f = opts.filters
        for name in (f.values() if isinstance(f, dict) else (f,)):
            if name not in FILTERS:
                raise InputError(f"--option filters: unknown filter {name!r} (one of: {', '.join(FILTERS)})")
    return opts


def changed_options(opts: MotionOptions) -> dict[str, object]:
    """The fields of ``opts`` that differ from the defaults, by name (for reports)."""
    return {f.name: getattr(opts, f.name) for f in fields(MotionOptions)
            if getattr(opts, f.name) != _default(f)}


def describe_options(opts: MotionOptions) -> str:
    """``KEY=VALUE, ...`` of the fields of ``opts`` that differ from the defaults, in field
    order ("" when none do): how the CLI and the benchmarks name a set of options."""
    return ", ".join(f"{k}={v}" for k, v in changed_options(opts).items())
