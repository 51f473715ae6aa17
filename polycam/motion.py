"""Plenoptic egomotion: rig motion between two light-field frames (paper Eq. 5).

Conventions (SPEC.md, docs/conventions.md). A frame is an array ``L`` of dims
``(F, Ny, Nx, Nv, Nu)`` on a :class:`~polycam.lightfield.LightFieldGrid`: sample
``(x, y, u, v)`` of face k is the ray with origin ``o = (x, y, z_pi)`` and direction
``d ∝ (u, v, f)`` in face coordinates, ``R_rig_face`` maps face to rig coordinates.

Sign convention, derived from ray geometry
------------------------------------------
Let ``M = T_rig[i]_rig[i+1]`` be the rig's motion (the pose of frame i+1 in the
rig frame of frame i; :meth:`Trajectory.relative`). The scene is static, so a
ray ``ρ`` expressed in rig frame i+1 sees what the same physical ray, ``M ρ`` in
rig frame i, saw before::

    L_{i+1}(ρ) = L_i(M ρ)        ⇔        L_{i+1}(G ρ) = L_i(ρ),   G = M⁻¹.

The paper's constraint (NOTES.md Eq. 2–5) is written for ``G``: the ray ``ρ`` of
frame i is found at ``G ρ`` in frame i+1, and for ``G ≈ (I + [ω]ₓ, t)`` a ray moves
by ``δo = ω × o + t``, ``δd = ω × d``. Re-intersecting the moved ray with the plane
``z = z_pi`` and the image plane ``z = z_pi + f`` gives, to first order,

    δx = t_x − (u/f) t_z − (uy/f) ω_x + (ux/f + z_pi) ω_y − y ω_z
    δy = t_y − (v/f) t_z − (vy/f + z_pi) ω_x + (vx/f) ω_y + x ω_z
    δu = −(uv/f) ω_x + (u²/f + f) ω_y − v ω_z
    δv = −(v²/f + f) ω_x + (uv/f) ω_y + u ω_z

and ``L_t + L_x δx + L_y δy + L_u δu + L_v δv = 0``: exactly the rows of M_t, M_ω
in paper Eq. 5. Each face sees ``(R_rig_faceᵀ t, R_rig_faceᵀ ω)``; all faces
stack into one system for the rig-frame ``(t, ω)`` of ``G``. The rig motion is
``M = G⁻¹``: to first order a rig moving by ``+t`` along x gives ``G`` with
``t_x < 0`` and the output ``T_prev_next`` has ``+t_x``.

Iterated linearisation (warping)
--------------------------------
With a current estimate ``M_e``, frame 2 is resampled at the moved rays,
``L1w(ρ) = L1(M_e⁻¹ ρ)``, or (``symmetric``) both frames half-way, and the small ray
motion ``Δ`` solved from Eq. 5 updates the estimate (``M = Δ⁻¹ M_e``); the resampling
and why its (u, v) interpolation is 6-point Lagrange: :mod:`polycam.warp`. This runs
coarse to fine over a pyramid in (u, v) (and (x, y) with ``pyramid_xy`` where there
are enough viewpoints; :mod:`polycam.pyramid`); a coarse level takes two steps, then
stops once its increment moves no ray by half a sample (``_COARSE_SETTLED``), since the
next level takes up that much in one linearisation. A motion of a view step or more takes
many rays out of the viewpoints' range (1.5 steps on 9 x 9 views: 31% of the samples;
the solver then loses 36% of its rays, whose filter supports need them); at the two
finest levels, once ρ̂ below exists, those up to ``extrapolate_views`` steps out are
extrapolated by Eq. 6 from the edge views instead (``L(x_e + d, u) = L(x_e, u + ρ d)``,
ρ averaged over the views per direction; ρ̂ itself is then taken from the rays whose
filter support holds captured samples only; docs/motion_log.md, "Paper Fig. 5c"). The
level above the finest hands its ρ̄ down (:func:`_finer_rho_bar`), so the finest level
extrapolates from its first warp on and mostly converges in two solves.
Where the views are too far apart for the scene (disparity per view step above
``max_view_disparity`` samples: camera arrays), the light field is aliased across the views
at the fine (u, v) scales, and the finest level used is the first coarse enough
(:func:`_aliasing_start`; docs/motion.md, "Camera arrays"). Where a level's disparity per view
step is above ``depth_views`` (0.25 samples), the warp blends the views around each moved ray
along ρ̄ (Eq. 6: each view read at the direction that sees the same scene point) instead of at
one direction: the plain blend of views a sizeable fraction of a sample apart mixes different
scene points, so at the converged estimate the warped frame lags the motion and the translation
came out 3–10 % long on the camera arrays (:func:`polycam.warp._depth_views_kernel`).

Linear arrays
-------------
A linear array (one viewpoint along x or y, several along the other: a row of cameras, a
stereo pair resampled onto views between its cameras) measures no positional derivative along
its single-view axis. There Eq. 6 stands in at every level: that regressor is ρ̂ L_u (or ρ̂ L_v),
ρ̂ from the other axis alone (:func:`polycam.eq5.depth_rho`'s ``linear``), and a ray whose window
no single depth explains is left out (it has no regressor to keep); the warp extrapolates every
ray the motion moves off the axis from the views by Eq. 6 with the views' mean ρ̄ per direction
(its gaps filled from their neighbours, :func:`polycam.warp._filled_view_mean`), however far (the
first warp of the coarsest level, before any ρ̂, keeps the rays on the axis). The symmetric warp
does not extrapolate so: with it such a pair fails with that reason. ρ̂ is divided by the gain
of the derivative filter across the views at each ray's frequencies
(:func:`polycam.filter_response.linear_rho_gain`): fs3 reads L_x, so ρ̂, up to a few per cent high
where the views are a sizeable fraction of a sample apart, and the warp's extrapolation with that
ρ̄ converged with the translation along the single-view axis short by as much. Measured (docs/motion.md,
"Linear arrays"): the middle row or column of the paper set-up's 9 x 9 array errs 1.7–34x as much
as the whole array without noise (t 0.4–1.1 %), 1.3–7x with 2 grey levels (benchmarks/bench_linear.py);
a row of five mock cameras about as much as the 5 x 5 rig (2.8 / 0.9 % against 2.7 / 0.8 %). The disparity per view step of camera
arrays (:func:`_aliasing_start`) is measured along the other axis.

Robust weighting
----------------
Per ray weight = confidence ``W`` (minimum over the filter support; 0 outside
the data) × validity (filter support inside the grid, warped sample inside the
grid) × a discontinuity weight × an IRLS weight. Silhouettes, creases and
aliased steps are where both the interpolation of the warp and the first-order
model fail, with errors that do not average out; the discontinuity weight
finds them from the data alone (large second derivatives in (u, v) near the
ray), so it is the same at every iteration of a level. The IRLS weight is
Tukey's biweight of the residual normalised by a robust scale (1.4826 ·
weighted MAD) that may grow but never shrinks within a pyramid level, so the
weights do not tighten as the warp converges. On the paper's sphere scene the two together bring the
bias of the translation from several percent to a few tenths of a percent
(benchmarks/bench_motion.py). Both single out model error only where it stands out of the
noise: the IRLS cut-off grows with the noise, so model error of the noise's size passes
once the noise is there. ``MotionOptions.model_weight`` (opt-in) adds a weight that does not
depend on the noise level: the residual energy pooled over 7 x 7 views x 5 x 5 directions,
beyond what the noise explains, is the window's model error ê², and a ray weighs
``s² / (s² + κ ê²)`` (κ: ``model_weight_gain``). The weights: :mod:`polycam.motion_weights`.

Positional regressors (paper Eq. 6)
-----------------------------------
For a Lambertian scene ``L_x = ρ L_u`` and ``L_y = ρ L_v``, ρ (u per unit x) fixed by the
depth of the scene point the ray sees: at the two finest levels the measured ``L_x, L_y`` (differences
across a few views: noisy, and aliased where the views are nearly parallel) are replaced
by ``ρ̂ L_u, ρ̂ L_v`` with ρ̂ pooled over a window, where one depth explains the window and
that is less noisy, or where the views are nearly parallel (the disparity gate: the
measured ones are aliased there), unless the gate costs information (it raises the normal
matrix's condition number more than ``depth_gate_cond`` times; then it acts only where the
misfit is far above the noise) (``MotionOptions.depth_regressors``, default on since
session 5; the rule: :func:`polycam.eq5.depth_rho`; measured: docs/motion_log.md, "Noise").

Diagnostics
-----------
Each pair yields a :class:`PairResult` with the 6x6 covariance of the rig
motion's ``(t, r)`` (``T_prev_next = [R_from_r(r) | t]``), the Jacobi-scaled
condition number, the inlier fraction, and the unobservable directions when
the normal matrix is (near-)singular (no texture, one viewpoint, ...) or when the translation
columns show no parallax above the noise (:func:`polycam.parallax.parallax_signal`: measured from
each frame alone, their share common to both frames is below ``MotionOptions.parallax_min``). The
covariance is a cluster-robust sandwich over tiles of rays (residuals of
filtered derivatives are correlated over the filter support) around the
M-estimate's noise-corrected sensitivity ``Σ base ψ'(r) c cᵀ − E`` (ψ' the slope of the
IRLS loss at each ray's residual, :meth:`_Solver.slope_normal`; without IRLS, and after the
noise options' whitened re-solves, the weighted normal matrix ``AᵀWA``; E = expected energy of
sensor noise in the derivatives, with the noise level estimated from second differences across
viewpoints), over clusters of tiles that span the residuals' correlation (:func:`_clusters`), each
cluster's score scaled by its leverage ``N (N − N_g)⁻¹`` (the cluster jackknife: the fit takes up
part of a cluster's noise, most where it carries much of a direction, :func:`_jackknife_scores`),
kept as ``covariance_noise``; the textbook ``σ² (AᵀWA − E)⁻¹`` is kept as
``covariance_iid``. The reported ``covariance`` adds ``d dᵀ``, ``d`` the change of (t, r) from
the estimate of the (u, v) level above the finest to the final one: model error coherent over
the image (aliasing across the views, resampling) moves the estimate without showing in the
residuals, and the two levels see it differently. A grid too small for a coarser level takes ``d``
from an estimate on its frames blurred along u and v (:func:`_blurred_change`).

Measured (benchmarks/bench_motion.py, paper Sect. 5 set-up: six faces, f = 60,
9 x 9 views 1 cm apart, 64 x 64 directions, 3 x 3 supersampling, |t| = 1.5 cm,
|ω| = 0.2°; default options, i.e. with the Eq. 6 regressors): median relative error per
component 0.03–0.07% (t) and 0.02–0.14% (ω) at 4–8 m; 0.4–2% (t) and 0.3–0.4% (ω) at
12–16 m, where the directions are aliased and the translation's signal is weak (the
paper sees the same growth); against 18–49% / 17–33% for one-shot central-difference
least squares. With 8-bit frames at 12 m: 0.03% / 0.2% (t / ω) quantised only, 0.2% / 0.6% with 3 grey
levels of noise.
Speed (bench_motion.py, one face of 9 x 9 views x 128 x 128 directions = 1.33 M rays;
figures in docs/motion.md, their history in docs/motion_log.md): the full default
estimate (6 solves over 3 levels) takes ~110–115 ms wall on 2 threads (~20 ms more with
confidences W).
Per iteration: one warp (views-innermost, so each of the 6 x 6 (u, v) taps is one
vectorised multiply-add over all view images, then a branch-free blend across views),
one fused kernel (derivatives, stored as int16 with a scale per view image (eq5's
"scaled views"), base weights, normal sums per view image in cache, valid views only)
and ``irls_steps`` passes that compute residual, IRLS weight and sums
together; the covariance's scores and Σ w r² follow from per-tile sums (the residual is
linear in the increment) and the noise energy from per-row weight moments. The ray loops
are branch-free with unsigned indices and re-associated sums (``_FASTMATH``) so that LLVM
vectorises them; work arrays are kept per thread for the next call on the same grid
(:func:`free_work_buffers`). The kernels: :mod:`polycam.eq5` (rows and normal sums),
:mod:`polycam.warp`, :mod:`polycam.whitening` (generalised least squares).

Limits: ``covariance_noise`` describes noise, not the systematic errors of aliased
or occluded data (on resampled camera-array sessions the errors were 3–5x its standard
deviations, RMS per axis, in session 37); with the level change camera-array sessions err
0.7–1.1x the reported std (RMS per axis, session 56) and clean frames 0.1–0.5x (conservative);
under noise on the tests' small grids 1.1–1.5x (docs/motion.md, "How far to trust the covariance";
tests/test_motion.py). One face alone couples t and ω (condition numbers of 10²–10³).

This module does no file I/O; :func:`estimate_trajectory` streams frames from
a light-field store (anything with ``grid``, ``timestamps_ns``, ``frame(i)``,
``weights(i)``).
"""

from __future__ import annotations

import logging
import math
import threading
from dataclasses import dataclass, field, replace
from typing import Callable

import numpy as np

from .derivatives import FILTERS, Derivatives, correlate_axis, derivative_noise, filter_taps, parallel_chunks
from .eq5 import (_NACC, _NSTAT, _QMAX, _ROBUST_KIND, _ROBUST_SLOPE, _accumulate, _apply_rho, _box_views, _face_B,
                  _fill_rho, _load_accumulate_view, _pass_kernel, _prepare_kernel, _reduce, _sample_residuals,
                  _store_weights, _unpack_sym, _view_origin, _weighted_median, RegressorMix, depth_rho,
                  ray_motion_coefficients)
from .errors import InputError
from .filter_response import divide_rho_by_gain, window_rms_frequency
from .geometry import R_from_r, T_from_Rt, T_inverse, adjoint, r_from_R
from .lightfield import Axis, LightFieldGrid, finite_frame
from .motion_options import MotionOptions
from .motion_weights import (_SCALE_SAMPLES, _level_discontinuity_weight, _noise_variance, discontinuity_weight,
                             frame_noise_variance, min_over_support, model_error_weights, robust_scale, robust_slope, robust_weight,
                             solver_filter_pairs)
from .parallax import ParallaxSignal, parallax_signal
from .pyramid import _BINOMIAL, _add_level, _Level, _pyramid
from .trajectory import Trajectory
from .warp import (_T_sqrt, _apply_warped_confidence, _face_abs_max, _face_abs_max_min, _warped_confidence_kernel,
                   _filled_view_mean, _near_marks, _padded, _view_mean, _views_inner_lw_kernel, _warp_into,
                   warp_lightfield, warp_lightfield_reference)
from .whitening import _whitened_noise_gain, _whitened_sums, _whitening_factors

__all__ = [
    "PARAM_NAMES",
    "MotionOptions",
    "PairResult",
    "estimate_motion",
    "estimate_trajectory",
    "frame_view_disparity",
    "free_work_buffers",
    "discontinuity_weight",
    "ScaledEigen",
    "scaled_eigen",
    "ray_motion_coefficients",
    "solve_ray_motion",
    "warp_lightfield",
    "warp_lightfield_reference",
    "solver_filter_pairs",
    "min_over_support",
    "robust_scale",
    "robust_weight",
    "robust_slope",
    "ray_to_rig_jacobian",
]

log = logging.getLogger(__name__)

_TEXTURE_FLOOR = 1e-5
"""RMS intensity change per sample below which a light field has no usable texture."""

_SCALE_FLOOR = 1e-5
"""Smallest robust residual scale [intensity]: ~1/400 of an 8-bit level, far above float32 rounding."""

PARAM_NAMES = ("t_x", "t_y", "t_z", "w_x", "w_y", "w_z")
"""Order of the six motion parameters: translation [m] then rotation vector [rad]."""


# ============================================================================ result


@dataclass(frozen=True)
class PairResult:
    """Rig motion between frames ``index`` and ``index + 1`` with diagnostics.

    Falsy when the estimate failed (``reason`` says why, e.g. unobservable
    directions); ``T_prev_next`` is then the best estimate in the observable
    subspace (zero motion along the unobservable directions; a translation without parallax above
    the noise, ``parallax_fraction``, is kept as least squares found it), or, when the final solve
    had fewer than ``MotionOptions.min_rays`` usable rays or the grid is a linear array,
    the estimate the solve started from (``T_init``: in a trajectory with
    ``constant_velocity`` the previous pair's motion).
    """

    index: int
    """Frame index i of the pair (i, i+1)."""
    T_prev_next: np.ndarray
    """(4, 4) ``T_rig[i]_rig[i+1]``: pose of frame i+1 in the rig frame of frame i."""
    covariance: np.ndarray
    """(6, 6) covariance of (t [m], r [rad]) of ``T_prev_next``: ``covariance_noise`` plus
    ``level_change level_changeᵀ`` (the model error the residuals do not show, estimated by how
    far the finest level moved the estimate of the level above it, or on one level the estimate on
    blurred frames; docs/motion.md, "How far to trust the covariance"), plus ``covariance_calibration``, ``covariance_sync`` and
    ``covariance_sampling`` where they were measured."""
    covariance_noise: np.ndarray
    """(6, 6) the part of ``covariance`` the residuals' scatter explains: a cluster-robust
    sandwich over tiles of rays around the M-estimate's sensitivity (each ray's slope ψ' of the
    IRLS loss, not its weight), each cluster's score scaled by its leverage (the cluster jackknife;
    module docstring)."""
    covariance_iid: np.ndarray
    """(6, 6) ``σ² (AᵀWA)⁻¹`` mapped like ``covariance`` (assumes independent residuals)."""
    sigma: float
    """Robust residual scale [intensity per frame] at the final solve."""
    condition: float
    """Condition number of the Jacobi-scaled normal matrix (inf when singular)."""
    inlier_fraction: float
    """Fraction of usable rays with IRLS weight > 0.5 at the final solve."""
    num_rays: int
    """Rays with a positive weight at the final solve."""
    iterations: int
    """Total linear solves (over all levels)."""
    unobservable: tuple[str, ...] = ()
    """Names of (near-)unobservable directions, e.g. ``("t_x", "t_y", "t_z")``."""
    unobservable_directions: np.ndarray = field(default_factory=lambda: np.zeros((0, 6)))
    """(k, 6) unit vectors (scaled parameter space) spanning the unobservable subspace (a translation
    direction without parallax above the noise: its rig-frame unit vector, rotation part 0)."""
    reason: str = ""
    """Why the estimate failed; empty when it succeeded."""
    noise_sigma: float = math.nan
    """Sensor noise σ per sample [intensity] of the pair's frames as given, estimated from their
    second differences across the cameras' views (:func:`polycam.motion_weights.frame_noise_variance`;
    8-bit rounding included). ``MotionOptions`` presets: docs/motion.md, "Noise"."""
    uv_level: int = 0
    """(u, v) pyramid level the estimate comes from: 0 the frames' own sampling, k the k-th
    halving (``MotionOptions.max_view_disparity``: the views are too far apart for finer scales)."""
    view_disparity: float = math.nan
    """Disparity per view step [(u, v) samples of the frames] that chose ``uv_level`` (the
    largest over the faces; NaN when not measured: ``max_view_disparity`` inf, fewer than 3
    views along x or y, no texture)."""
    level_change: np.ndarray = field(default_factory=lambda: np.full(6, np.nan))
    """(6,) (t [m], r [rad]) of ``T_prev_next`` minus those of the estimate the level above the
    finest (u, v) level handed down to it; on a grid whose directions allow no coarser level (fewer
    than 32 along u and v) while the options ask for more, minus those of the estimate on the
    frames blurred along u and v (:func:`_blurred_change`). NaN with ``MotionOptions.levels`` 1 or
    when the blurred estimate failed: ``covariance`` is then ``covariance_noise``."""
    parallax_fraction: np.ndarray = field(default_factory=lambda: np.full(3, np.nan))
    """(3,) signal fractions of the translation directions, ascending: how much of the
    translation columns' energy is parallax common to both frames rather than noise
    (:func:`polycam.parallax.parallax_signal`; ~1: parallax well above the noise, ~0: none);
    directions below ``MotionOptions.parallax_min`` are unobservable. NaN when not measured."""
    covariance_calibration: np.ndarray | None = None
    """(6, 6) the part of ``covariance`` the camera models' calibration error explains (the spread of
    the estimate over models drawn from the calibration's uncertainty:
    :func:`polycam.calib_spread.with_calibration`); None when not measured (the solver alone)."""
    covariance_sync: np.ndarray | None = None
    """(6, 6) the part of ``covariance`` the uncertainty of unsynchronised cameras' capture times
    explains (the spread of the corrected estimate over capture times drawn from it:
    :func:`polycam.calib_spread.with_capture_timing`); None when not measured."""
    covariance_sampling: np.ndarray | None = None
    """(6, 6) the part of ``covariance`` added for the change of the estimate on a second view
    sampling of the same frames (``d dᵀ``: :func:`polycam.calib_spread.with_view_sampling`,
    ``polycam motion --sampling-check``); None when not measured."""

    @property
    def ok(self) -> bool:
        return not self.reason

    def __bool__(self) -> bool:
        return self.ok

    @property
    def t(self) -> np.ndarray:
        """(3,) [m] translation of ``T_prev_next``."""
        return self.T_prev_next[:3, 3]

    @property
    def r(self) -> np.ndarray:
        """(3,) [rad] rotation vector of ``T_prev_next``."""
        return r_from_R(self.T_prev_next[:3, :3])

    @property
    def std(self) -> np.ndarray:
        """(6,) standard deviations of (t, r) from ``covariance``."""
        return np.sqrt(np.clip(np.diag(self.covariance), 0.0, None))


# ============================================================================ building blocks


def solve_ray_motion(der: Derivatives, grid: LightFieldGrid, weights: np.ndarray | None = None,
                     rcond: float = 1e-7) -> tuple[np.ndarray, np.ndarray]:
    """One weighted linear solve of Eq. 5 over all faces (no warping, no IRLS).

    ``weights``: (F, Ny, Nx, Nv, Nu) or None (the derivatives' valid mask). Returns
    ``p`` (6,) = (t [m], ω [rad]) of the *ray* motion G in rig coordinates (the rig
    moved by ``G⁻¹``) and the normal matrix N (6, 6).
    """
    F, Ny, Nx, Nv, Nu = der.Lx.shape
    if weights is None:                     # unit weights on the valid box only
        box, base, has_base = _valid_box(der.valid), np.zeros((1,) * 5, np.float32), False
    else:
        box = np.array([0, Ny, 0, Nx, 0, Nv, 0, Nu], np.int64)
        base, has_base = np.ascontiguousarray(np.broadcast_to(weights, der.Lx.shape), dtype=np.float32), True
    acc, _ = _accumulate(der, base, has_base, grid, np.zeros((F, 6)), 0, 0.0, max(Nv, Nu), box,
                         np.zeros(4), np.zeros(4), False)
    N, rhs, _, _, _ = _reduce(acc, [_face_B(face) for face in grid.faces])
    return _solve_normal(N, rhs, rcond)["p"], N


def _valid_box(valid: np.ndarray) -> np.ndarray:
    """(8,) int64 [y0, y1, x0, x1, v0, v1, u0, u1]: the box of a (Ny, Nx, Nv, Nu) valid mask."""
    box = []
    for ax in range(4):
        idx = np.flatnonzero(valid.any(axis=tuple(a for a in range(4) if a != ax)))
        box += [int(idx[0]), int(idx[-1]) + 1] if idx.size else [0, 0]
    return np.array(box, np.int64)


# ============================================================================ solver rules (public)


def ray_to_rig_jacobian(M: np.ndarray, H: np.ndarray | None = None) -> np.ndarray:
    """(6, 6) d(t, r of the rig motion M) / d(ray-motion increment δ) at the estimate M:
    M = exp(−δ) M (one-sided warping), or M = H exp(−δ) H with ``H`` (symmetric warping)."""
    J = np.zeros((6, 6))
    J[:3, :3] = M[:3, :3]
    J[3:, 3:] = np.eye(3)
    return -J @ adjoint(T_inverse(M if H is None else H))


# ============================================================================ the solver


def _warp_source(L: np.ndarray, W: np.ndarray | None, name: str | None = None, L_other: np.ndarray | None = None,
                 W_other: np.ndarray | None = None) -> tuple[np.ndarray, int, np.ndarray, np.ndarray | None]:
    """Channels warped together, (F, Nv, Nu, M) int16 (:func:`~polycam.warp._views_inner`
    layout; scaled warp, :func:`~polycam.warp._warp_into`): L, and with a confidence W also W
    and, where W has samples without data (W <= 0), the "no data" indicator W <= 0, which
    must not be interpolated into usable samples (any stencil tap on it makes the sample
    unusable; without such samples it would warp to 0 everywhere, so it is left out: a third
    less warping). ``name``: into that per-thread work array (:func:`_work_array`). Returns
    the source, its channel count K (1, 2 or 3) and the units (F, K) float64 of its channels
    per face: max |channel| / 32767 (1 for an all-zero channel; for L the maximum over L and
    ``L_other`` too, the other frame of the pair, which the derivatives read rounded to the
    same units), 1 / 32767 for the indicator. L's maxima leave out the samples whose confidence
    (W, ``W_other``) is <= 0: they are never used and must not change the rest (they are clipped).
    Last, with K = 3 the directions with samples without data in some view, (F, Nv, Nu) uint8
    (:func:`~polycam.warp._warp_into`'s ``nodata``), else None."""
    F, Ny, Nx, Nv, Nu = L.shape
    flat = (F, Ny * Nx, Nv, Nu)
    L = np.ascontiguousarray(L, dtype=np.float32).reshape(flat)
    W = L if W is None else np.ascontiguousarray(W, dtype=np.float32).reshape(flat)
    if W is L:
        channels = 1
    else:
        w_max, w_min = _face_abs_max_min(W)              # one pass over W
        channels = 3 if w_min.min() <= 0.0 else 2
    units = np.full((F, 3), 1.0 / _QMAX)
    units[:, 0] = _face_abs_max(L, None if W is L else W) / _QMAX
    if L_other is not None:
        w = None if W_other is None else np.ascontiguousarray(W_other, dtype=np.float32)
        units[:, 0] = np.maximum(units[:, 0], _face_abs_max(np.ascontiguousarray(L_other, dtype=np.float32), w) / _QMAX)
    if channels > 1:
        units[:, 1] = w_max / _QMAX
    units[units <= 0] = 1.0
    units = units.astype(np.float32).astype(np.float64)     # float32 values: the same in every kernel
    shape = (F, Nv, Nu, _padded(channels * Ny * Nx))
    out = np.empty(shape, np.int16) if name is None else _work_array(name, shape, np.int16)
    inv = np.float32(1.0) / units.astype(np.float32)      # as derivatives._on_grid's (float32 division)
    nodata = np.empty((F, Nv, Nu) if channels == 3 else (1, 1, 1), np.uint8)
    _views_inner_lw_kernel(L, W, channels, inv, out, nodata)
    return out, channels, units[:, :channels], nodata if channels == 3 else None


_RHO_SETTLED = 0.05
"""ρ̂ of the Eq. 6 regressors is reused while the warp has moved no ray by more than this
many samples (of any axis) since it was computed (:meth:`_Solver.warp_change`). Measured
(bench_noise.py, six faces, σ = 8 / 16 grey levels, 4 draws, t error): ρ̂ fresh at every
preparation 0.437 / 0.582 mm; computed at a level's first two preparations and reused
after 0.443 / 0.598, but on tests/test_motion.py's one-face pair (large motion, one level)
the covariance then under-predicts the scatter by 2.4x; at the first only 0.560 / 1.526.
Between solves the warp typically moves rays by 0.2-1 samples, so ρ̂ is mostly fresh.
Session 7, with the extrapolation: 0.15 (ρ̂ reused at the finest level's last warp, which
moved 0.1 samples; ~11 ms faster) doubled the six-face noise-free bias of t."""

_DR_LEVELS = 2
"""depth_regressors applies at this many of the finest pyramid levels. The coarsest levels
need none (bench_noise.py as above, ρ̂ at the first two preparations: t 0.443 / 0.598 mm at
all levels, 0.447 / 0.605 at the finest only). At the level above the finest they hand the
finest its extrapolation's ρ̄ (:func:`_finer_rho_bar`) and their disparity-gate decision:
its first solve then already extrapolates the rays moved beyond the viewpoints, and the
finest level mostly converges in two solves instead of three (session 34: bench_motion's
speed pair 131–139 -> 111–113 ms, with W 156–164 -> 133–135 ms; the accuracy benchmarks as
before: docs/motion_log.md)."""

_NO_NODATA = np.zeros(1, np.float32)
"""Placeholder "no data" channel for :func:`~polycam.warp._warped_confidence_kernel` (never read)."""

_VIEWS_RHO_FILL = 16
"""Rounds of :func:`~polycam.warp._filled_view_mean` that fill the unknown directions of ρ̄ for the
warp's blend along the disparity (``MotionOptions.depth_views``; the rest get the face's median)."""

_W_SETTLED = 0.25
"""With confidences W whose W1 is warped (``MotionOptions.warp_confidence``, or W1 with zeros; else
W1 is taken at each ray's own sample and only W0 is folded), a re-warp keeps the warped W of each
ray inside from an earlier warp
while the warp has moved no ray by more than this many samples (of any axis) since
(:meth:`_Solver.warp_change`; :func:`~polycam.warp._warp_into`'s ``lag_confidence``): W is a
weight, and blending and extrapolating it again cost ~8 ms of the finest level's second warp
(bench_motion's speed pair: that warp moves the rays 0.1 samples, the coarse levels' re-warps more
than 1). Estimates within 7e-7 of fresh confidences (session 35, docs/motion_log.md)."""

_NO_RHO = np.zeros((1,) * 5, np.int16)
"""Placeholder ρ̂ for :func:`~polycam.eq5._prepare_kernel` without depth_regressors (never read)."""
_NO_RHO_SC = np.zeros((1,) * 3, np.float32)
"""Its scales."""
_NO_SMOOTH = np.ones((1,) * 5, np.int16)
"""Placeholder discontinuity weight for :func:`~polycam.eq5._prepare_kernel` (smooth modes 0, 2: never read)."""

_WORK = threading.local()
"""Per-thread flat work arrays of the last estimate, by name: see :func:`free_work_buffers`."""


def _work_array(name: str, shape: tuple, dtype=np.float32) -> np.ndarray:
    """An uninitialised work array of the given dims, a view of a flat per-thread buffer that
    the next use of ``name`` reuses (fresh memory costs page faults: ~5% of an estimate).
    Pyramid levels run one after the other, so all levels share one buffer per name: the
    peak memory is that of the finest level, as without the cache."""
    cache = _WORK.__dict__.setdefault("arrays", {})
    lent = _WORK.__dict__.setdefault("lent", {})
    n = math.prod(shape)
    a = cache.get(name)
    if a is None or a.size < n or a.dtype != np.dtype(dtype) or n > lent.get(name, n):
        # (a request reaching into a lent tail gets a buffer of its own: the arrays in the
        # tail keep the old one alive)
        cache[name] = None                      # release the old one before allocating
        lent.pop(name, None)
        a = cache[name] = np.empty(n, dtype)
    return a[:n].reshape(shape)


_TAIL_NAMES = ("derivatives", "out1")
"""The float32 work arrays whose tails :func:`_tail_array` lends (the largest two)."""
_TAIL_HEAD = 0.3
"""The share of a work array :func:`_tail_array` never lends: what the next coarser pyramid
level uses of it (a quarter, halved (u, v): (65 / 128)² of it at 128 directions) and a margin."""


def _tail_array(shape: tuple) -> np.ndarray | None:
    """A float32 array of the given dims in the idle tail of one of this thread's cached
    finest-level work arrays (:func:`_work_array`), or None when none has room: the coarse
    pyramid levels' frames of the next estimate (``polycam.pyramid._pyramid``'s ``alloc``),
    which live only while the coarse levels, which use those arrays' heads, are solved.
    Lent from the end down until :func:`_return_tails`; :func:`_work_array` never hands
    out lent memory."""
    cache = _WORK.__dict__.get("arrays", {})
    lent = _WORK.__dict__.setdefault("lent", {})
    n = math.prod(shape)
    for name in _TAIL_NAMES:
        a = cache.get(name)
        if a is None or a.dtype != np.float32:
            continue
        end = lent.get(name, a.size)
        if end - n >= math.ceil(_TAIL_HEAD * a.size):
            lent[name] = end - n
            return a[end - n:end].reshape(shape)
    return None


def _return_tails() -> None:
    """End the loans of :func:`_tail_array` (their arrays must be dead: the finest level
    reuses the memory)."""
    _WORK.__dict__.pop("lent", None)


def free_work_buffers() -> None:
    """Release the work arrays that :func:`estimate_motion` keeps on the calling thread for
    its next call (about four frames' worth: those of the finest pyramid level, docs/motion.md "Speed")."""
    _WORK.__dict__.pop("arrays", None)
    _return_tails()


class _Solver:
    """One pyramid level: warp, fused derivatives / weights / normal sums, IRLS passes."""

    def __init__(self, lev: _Level, opts: MotionOptions, filters: dict, level: int = 0,
                 view_disparity: float = math.nan):
        self.lev = lev
        self.level = level                   # 0: the finest
        # the warp blends the views along ρ̄ (MotionOptions.depth_views) where this level's
        # disparity per view step (its own samples; NaN: not measured) is above the threshold
        self.depth_views = bool(view_disparity > opts.depth_views)
        self.g = g = lev.grid
        self.opts = opts
        self.filters = filters
        self.pairs, self.taps = filter_taps(g, {k: fp.name for k, fp in filters.items()})
        # a linear array's single-view axis ("x" or "y"; "": none): its regressor is always ρ̂ L_u
        # (or ρ̂ L_v), at every level (LightFieldGrid.single_view_axis)
        self.linear = g.single_view_axis
        self.omega: np.ndarray | None = None     # its rays' frequencies (_linear_rho_gain), per level
        self.radius = {k: (fp.radius if self.pairs[k] is not None else 0) for k, fp in filters.items()}
        self.vals = [np.ascontiguousarray(a.values, dtype=np.float64) for a in (g.x, g.y, g.u, g.v)]
        self.zs = np.array([face.z_pi for face in g.faces], float)
        self.fs = np.array([face.f for face in g.faces], float)
        self.B = [_face_B(face) for face in g.faces]
        self.h = np.array([g.x.step, g.y.step, g.u.step, g.v.step], float)
        F, Ny, Nx, Nv, Nu = self.shape = lev.L0.shape
        r = self.radius
        self.box = np.array([r["y"], Ny - r["y"], r["x"], Nx - r["x"], r["v"], Nv - r["v"], r["u"], Nu - r["u"]],
                            np.int64)
        self.tile = max(1, min(int(opts.tile), max(4, -(-max(Nu, Nv) // 8))))   # >= ~8 x 8 tiles per face
        self.kind = _ROBUST_KIND[opts.robust]
        self.scale: float | None = None
        # per-ray work arrays hold the views of the box only (eq5's view origin): the others
        # are never read (their (x, y) filter support leaves the grid)
        self.vo = _view_origin(Ny, Nx, self.box)
        self.cshape = _box_views(self.shape, self.box)
        self.var: np.ndarray | None = None
        # the warp sources are int16 in units (F, K) per face and channel (warp._warp_into's
        # scaled warp: the warped frames are float32), L's common to both frames: the fused
        # kernel reads frame 1 rounded to them (l0g), so equal samples give L_t = 0 exactly
        # W1 without zeros is not warped (MotionOptions.warp_confidence): each ray's confidence gets
        # frame 2's W1 at its own sample after the warp (_Solver._warp), the source holds L alone
        self.own_w1 = (lev.W1 is not None and not opts.warp_confidence and not opts.symmetric
                       and float(lev.W1.min()) > 0.0)
        self.src1, self.K1, self.units1, self.nodata1 = _warp_source(lev.L1, None if self.own_w1 else lev.W1, "src1",
                                                                     lev.L0, lev.W0)
        self.l0g = self.units1[:, 0].astype(np.float32)
        self.src0, self.K0, self.units0, _ = _warp_source(lev.L0, lev.W0, None, lev.L1, lev.W1) if opts.symmetric \
            else (None, 0, None, None)
        # the derivatives are int16 scaled views (polycam.eq5's docstring: a scale per view
        # image and derivative in self.dsc), five in one block of float32 slots. The warp
        # stores only L of frame 2: it folds the warped W and "no data" channels into the
        # confidence (warp._warp_into's confidence_channels). With ``symmetric`` (both frames
        # warped) they are stored: the warped frame 2 comes first in one buffer with the
        # derivatives, warped[0] is L, and the other channels share the derivatives' memory —
        # they are read (folded into conf) before the fused kernel writes the derivatives.
        # (Otherwise separate arrays: one block measured ~1 frame more resident for the same
        # live arrays, session 8: the allocator's heap keeps freed temporaries then.)
        S, C = math.prod(self.shape), math.prod(self.cshape)
        nd = -(-5 * C // 2)                            # float32 slots of 5 C int16
        K = self.K1
        if lev.W1 is None or not opts.symmetric:
            self.out1 = _work_array("out1", (1,) + self.shape)
            dmem = _work_array("derivatives", (nd,))
            free = 0                                    # dmem[free:] is free during a warp
        else:
            block = _work_array("warped_derivatives", (S + max((K - 1) * S, nd),))
            self.out1 = block[:K * S].reshape((K,) + self.shape)
            dmem = block[S:]
            free = (K - 1) * S
        q = dmem.view(np.int16)
        self.der = [q[n * C:(n + 1) * C].reshape(self.cshape) for n in range(5)]   # L_x .. L_t
        self.dsc = _work_array("dsc", self.cshape[:3] + (5,))
        # the warp's scratch (its copy of the edge views, warp._warp_into) and the marks of
        # its extrapolated samples lie in the derivatives' memory past the warped channels
        # (the marks at the end): the fused kernel rewrites it after each warp
        tail = dmem.size - (S + 3) // 4                # the marks: S bytes at the end
        self.warp_scratch = dmem[free:tail] if tail >= free else dmem[free:]
        self.marks_memory = dmem[tail:] if tail >= free else None
        # the warp's confidence: 0 / 1 without W (uint8: a quarter of the memory), else
        # multiplied by the (warped) confidences, in units of 1 / 65535 (uint16: half;
        # warp._folded_confidence); float32 when both frames are warped (symmetric)
        binary = lev.W0 is None and lev.W1 is None and not opts.symmetric
        dtype = np.uint8 if binary else (np.float32 if opts.symmetric else np.uint16)
        self.conf = _work_array("conf", self.shape, dtype)
        self.conf_unit = np.float32(1.0 / 65535.0) if dtype == np.uint16 else np.float32(1.0)
        self.base = _work_array("base", self.cshape, np.int16)     # int16 units (polycam.eq5's docstring)
        # the discontinuity weight (fixed per level; int16 weights as base): with a 0 / 1
        # confidence it lives in the base weights' memory, as |base| with base's sign the
        # confidence (eq5._prepare_kernel, smooth mode 2: 0.3 frames less); else an array of
        # its own (mode 1). Computed in the warped frame's memory, free now
        self.smooth: np.ndarray | None = None
        self.smooth_mode = 0 if opts.smooth_c <= 0 else (2 if binary else 1)
        if self.smooth_mode:
            w = _level_discontinuity_weight(lev, opts, self.box,
                                            out=self.out1[0].reshape(-1)[:C].reshape(self.cshape))
            if self.smooth_mode == 1:
                self.smooth = _work_array("smooth", self.cshape, np.int16)
            _store_weights(w, self.base if self.smooth_mode == 2 else self.smooth)
        nviews = F * (self.box[1] - self.box[0]) * (self.box[3] - self.box[2])
        nt = (-(-Nv // self.tile), -(-Nu // self.tile))
        self.acc = _work_array("acc", (nviews,) + nt + (_NACC,), np.float64)
        self.st = _work_array("st", (nviews, _NSTAT), np.float64)
        self.rho: np.ndarray | None = None   # ρ̂ of the Eq. 6 regressors (depth_regressors): int16
        self.rho_sc: np.ndarray | None = None  # in units of these per view image (polycam.eq5.depth_rho)
        self.var_dr: np.ndarray | None = None
        self.mix: RegressorMix | None = None   # the make-up of var_dr (None: measured regressors only)
        self.rho_gain = 1.0                    # whitened / plain energy of the signal L_u (whitened re-solves)
        self.N_plain: np.ndarray | None = None  # the last solve's normal matrix before whitening
        self.M_rho: np.ndarray | None = None   # the estimate at which rho was computed
        self.rho_extrapolated = False          # rho was computed from a warp extrapolated with this level's rho_bar
        self.rho_bar_handed = False            # rho_bar is the coarser level's (_finer_rho_bar) until the first rho
        self.rho_bar: np.ndarray | None = None  # (F, Nv, Nu) ρ̂ averaged over the views (extrapolate_views)
        self.gate_misfit: float | None = None  # the disparity gate's misfit floor (decided at the first rho)
        self.views_rho: np.ndarray | None = None   # rho_bar filled, for depth_views (_views_rho)
        self.views_rho_of: np.ndarray | None = None  # the rho_bar it was made from
        self.M_conf: np.ndarray | None = None  # the estimate whose warp made conf's warped W (fold)
        self.n_base = 0
        self.whitened: bool | None = None    # GLS re-solves (None: not decided yet)
        self.p_w: np.ndarray | None = None   # the residuals' p of the last solve's IRLS weights
        # the kernels' summing function loaded before they run: the same code fresh or cached
        _load_accumulate_view(self.der[0], self.dsc, self.base, self.vals, self.zs, self.fs, np.zeros((F, 6)),
                              self.tile, self.box, self.h, np.zeros(4), False)

    # --------------------------------------------------------------- passes

    def _face_params(self, p_rig: np.ndarray) -> np.ndarray:
        return np.stack([Bk @ p_rig for Bk in self.B])

    def _tile(self, final: bool) -> int:
        """Tile of a pass's sums: the covariance's (u, v) tiles in the final pass of a solve
        (the scores need per-tile sums), else whole view rows (one tile per view image: the
        totals are the same, and the ray loop then adds its vector partial sums once per
        row instead of once per 16 rays, ~2x faster)."""
        return self.tile if final else max(self.shape[3], self.shape[4])

    def _marks(self) -> np.ndarray:
        """The warp's marks of extrapolated samples, (F, Ny, Nx, Nv, Nu) uint8 zeroed: in the
        derivatives' memory (free from the warp to the fused kernel) when it holds them."""
        S = math.prod(self.shape)
        mem = self.marks_memory
        marks = mem.reshape(-1).view(np.uint8)[:S].reshape(self.shape) if mem is not None and mem.nbytes >= S \
            else _work_array("marks", self.shape, np.uint8)
        marks.fill(0)
        return marks

    def _sums(self):
        F = self.shape[0]
        acc = self.acc.reshape(F, -1, self.acc.shape[1] * self.acc.shape[2], _NACC)
        return _reduce(acc, self.B), self.st.reshape(F, -1, _NSTAT)

    def prepare(self, M: np.ndarray, final: bool):
        """Warp frame 2 (both frames with ``symmetric``) by the estimate M, then the fused
        kernel: derivatives, base weights, normal sums with unit IRLS weights."""
        lev, opts = self.lev, self.opts
        H = _T_sqrt(M) if opts.symmetric else np.eye(4)
        H1 = T_inverse(H) if opts.symmetric else T_inverse(M)
        # Eq. 6 regressors (finest _DR_LEVELS levels): ρ̂ from the measured regressors, then the
        # sums again; reused (the fused kernel replaces L_x, L_y) only while the warp has not
        # moved since (ρ̂ of a warp a step before the converged one costs accuracy)
        dr = bool(self.linear) or (opts.depth_regressors and self.level < _DR_LEVELS)
        moved = self.warp_change(self.M_rho, M) if dr and self.M_rho is not None else math.inf
        rho_bar = self.rho_bar if not opts.symmetric else None     # the extrapolation's (None: none)
        extrapolate = rho_bar is not None
        # a fresh ρ̂ also when the extrapolation starts: ρ̂ of a warp without it has none for
        # the rays whose support then holds extrapolated samples, which would keep their
        # measured L_x, L_y (the copies' noise) instead of the view mean. Likewise when it starts
        # with the level's own ρ̄: ρ̂ of a warp extrapolated with the coarser level's, reused at
        # the next warp, biased the translation under noise (full motion, σ = 4: 1.07 bounds)
        first_dr = dr and (moved > _RHO_SETTLED or (extrapolate and not self.rho_extrapolated))
        if dr:
            log.debug("depth regressors: warp moved %.3g samples since rho: %s", moved,
                      "fresh" if first_dr else "reused")
        if first_dr:
            self.M_rho = np.array(M, float)
            self.rho_extrapolated = extrapolate and not self.rho_bar_handed
        # a fresh ρ̂ needs them (not on a linear array, whose moved rays are all extrapolated)
        marks = self._marks() if extrapolate and first_dr and not self.linear else None
        L0 = self._warp(M, H, H1, rho_bar, marks)
        # ρ̂ from the captured samples only: a window holding extrapolated samples (made with an
        # earlier ρ̂) would pull the new ρ̂ back towards it. Taken now: the marks lie in the
        # derivatives' memory, which the fused kernel rewrites
        near = None if marks is None else _near_marks(marks, self.radius["y"], self.radius["x"],
                                                      _work_array("near", self.cshape, np.uint8), *self.vo[:2])
        conf = self.conf
        need_min = not (lev.W0 is None and lev.W1 is None and conf.min() > 0)
        smooth = self.smooth if self.smooth is not None else _NO_SMOOTH
        Lx, Ly, Lu, Lv, Lt = self.der
        has_rho = dr and not first_dr
        if has_rho:
            self.var = self._regressor_noise()
        g = self.lev.grid
        a, b = (g.v, g.y) if self.linear == "x" else (g.u, g.x)      # the axis with views
        rho_max = opts.depth_gate * abs(a.step) / max(abs(b.step), 1e-300)
        # the gate's misfit floor, decided at the level's first ρ̂: none unless the gate costs
        # conditioning (then opts.depth_gate_misfit)
        if self.gate_misfit is not None:
            floors = (self.gate_misfit,)
        elif self.linear:                         # no measured regressors to fall back to
            floors = (opts.depth_gate_misfit,)
        elif rho_max > 0 and opts.depth_gate_misfit > 0:
            floors = (0.0, opts.depth_gate_misfit)
        else:
            floors = (opts.depth_gate_misfit,)
        check = first_dr and len(floors) > 1
        tile = self.tile if check else self._tile(final)     # the check's covariance needs the tiles
        derivatives = (L0, self.out1[0], self.l0g, conf, self.conf_unit, need_min, smooth, self.smooth_mode, *self.taps,
                       Lx, Ly, Lu, Lv, Lt, self.dsc, self.base, *self.vals, self.zs, self.fs,
                       np.zeros((self.shape[0], 6)), tile, self.box, self.vo, self.h)
        _prepare_kernel(*derivatives, self.var, final, self.acc, self.st, parallel_chunks(),
                        self.rho if has_rho else _NO_RHO, self.rho_sc if has_rho else _NO_RHO_SC, has_rho,
                        not first_dr or check, bool(self.linear))
        if first_dr:
            var = self.var if self.var is not None else self.derivative_noise()
            if check:
                p_measured, sigma_measured, cond_measured = self._increment_and_sigma()
            self.rho = _work_array("rho", self.cshape, np.int16)      # in units of rho_sc per view image
            self.rho_sc = _work_array("rho_sc", self.cshape[:3])
            for n, floor in enumerate(floors):
                if n:                                     # back to the measured regressors
                    self._warp(M, H, H1, rho_bar, None)   # ρ̂'s windows used the warped frame's memory
                    _prepare_kernel(*derivatives, self.var, final, self.acc, self.st, parallel_chunks(),
                                    _NO_RHO, _NO_RHO_SC, False, False)
                self.var_dr = self._depth_rho(var, rho_max, floor, near)
                self.var = self._regressor_noise()
                _apply_rho(Lx, Ly, Lu, Lv, self.dsc, self.base, self.rho, self.rho_sc, self.box, self.vo,
                           parallel_chunks(), bool(self.linear))
                _pass_kernel(Lx, Ly, Lu, Lv, Lt, self.dsc, self.base, True, *self.vals, self.zs, self.fs,
                             np.zeros((self.shape[0], 6)), 0, 0.0, tile if n + 1 < len(floors) else self._tile(final),
                             self.box, self.vo, self.h, self.var, final, self.acc, self.st, parallel_chunks())
                self.gate_misfit = floor
                if n + 1 < len(floors):
                    p_gate, _, cond = self._increment_and_sigma()
                    z = np.array([np.linalg.norm(p_gate[:3] - p_measured[:3]),
                                  np.linalg.norm(p_gate[3:] - p_measured[3:])]) / np.maximum(sigma_measured, 1e-300)
                    log.debug("depth regressors: condition %.3g with the gate, %.3g measured; the estimates "
                              "differ by %.3g, %.3g sigma (t, w)", cond, cond_measured, z[0], z[1])
                    # the gate loses information (conditioning) and the measured regressors show
                    # no bias the gate would remove (the two agree within the noise): fall back
                    if cond <= opts.depth_gate_cond * cond_measured or z.max() > opts.depth_gate_z:
                        break
        # (a linear array's from each fresh ρ̂: its warp extrapolates every ray moved off the axis)
        if first_dr and (self.linear or ((opts.extrapolate_views > 0 or self.depth_views) and not extrapolate)):
            self.rho_bar = _view_mean(self.rho, self.rho_sc)
            if self.linear:
                self.rho_bar = _filled_view_mean(self.rho_bar)
            self.rho_bar_handed = False
        sums = self._sums()
        self.n_base = int(sums[1][..., 1].sum())
        return sums

    def _warp(self, M: np.ndarray, H: np.ndarray, H1: np.ndarray, rho_bar: np.ndarray | None,
              marks: np.ndarray | None) -> np.ndarray:
        """Frame 2 warped by H1 into self.out1 (frame 1 by H too with ``symmetric``), the
        warp's confidence times the confidences W into self.conf; M (4, 4) the estimate
        whose warp this is; ``rho_bar`` (the views' extrapolation; None: none) and ``marks``
        as :func:`~polycam.warp._warp_into`. Returns frame 1 as the fused kernel reads it."""
        lev, opts = self.lev, self.opts
        # with confidences (not symmetric) the warp folds them into conf: the warped W and
        # frame 1's (unwarped) W0 in the same pass (warp._folded_confidence); while the warp
        # has moved no ray by more than _W_SETTLED samples since they were made, the rays
        # inside keep them (warp._warp_into's lag_confidence)
        fold = not opts.symmetric and (lev.W0 is not None or lev.W1 is not None)
        lag = bool(fold and self.K1 == 2 and self.M_conf is not None and self.warp_change(self.M_conf, M) <= _W_SETTLED)
        _warp_into(self.src1, self.g, H1, opts.uv_taps, self.out1, self.conf,
                   rho_bar, opts.extrapolate_views, marks=marks,
                   scratch=self.warp_scratch, ratio=self.units1,
                   confidence_channels=self.K1 if fold else 0, W0=lev.W0 if fold else None,
                   nodata=self.nodata1 if fold else None, lag_confidence=lag,
                   depth_views=self._views_rho(rho_bar))
        if fold and not lag:
            self.M_conf = np.array(M, float)
        if self.own_w1:                           # × W1 at each ray's own sample, in conf's units
            _warped_confidence_kernel(self.conf.reshape(-1), lev.W1.reshape(-1), _NO_NODATA, False, 1.0, 0.5)
        if not opts.symmetric:
            return lev.L0
        conf = self.conf
        if lev.W1 is not None:
            _apply_warped_confidence(conf, self.out1)
        out0 = np.empty((self.K0,) + self.shape, np.float32)
        ok0 = np.empty(self.shape, np.float32)
        _warp_into(self.src0, self.g, H, opts.uv_taps, out0, ok0, ratio=self.units0)
        conf *= ok0
        if lev.W0 is not None:
            _apply_warped_confidence(conf, out0)
        return out0[0]

    def _views_rho(self, rho_bar: np.ndarray | None) -> np.ndarray | None:
        """The warp's ρ for blending the views along the disparity (``depth_views``; None: off, or no
        ρ̄ yet): ``rho_bar`` with its unknown directions filled from their neighbours
        (:func:`~polycam.warp._filled_view_mean`: ρ̂ leaves out the windows no single depth explains,
        half or more of a room's directions), kept while ``rho_bar`` is the same array."""
        if not self.depth_views or rho_bar is None:
            return None
        if self.views_rho_of is not rho_bar:
            self.views_rho = _filled_view_mean(rho_bar, _VIEWS_RHO_FILL)
            self.views_rho_of = rho_bar
        return self.views_rho

    def _depth_rho(self, var: np.ndarray, rho_max: float, floor: float, near: np.ndarray | None) -> np.ndarray:
        """:func:`polycam.eq5.depth_rho` into ``self.rho`` from the measured regressors; with
        ``near`` (F, Ny, Nx, Nv, Nu uint8: 1 where an extrapolated sample lies within the
        (x, y) support of a ray's filters) only the other rays enter ρ̂'s windows, ``rho_bar``
        becomes their view mean and the near rays get it (their measured L_x, L_y mix the
        extrapolated copies' noise). Returns the regressors' noise variances (4,)."""
        var_dr, self.mix = depth_rho(self.der, self.base, self.box, self._var_measured(var), self.rho, rho_max, floor,
                                     near, self.vo, self.dsc, scratch=self.out1[0], out_scale=self.rho_sc,
                                     return_mix=True, pool_views=self.opts.depth_pool_views,   # out1: read by now
                                     linear=self.linear)
        if self.linear and self.opts.linear_gain:
            self._linear_rho_gain()
        if near is not None:
            self.rho_bar = _view_mean(self.rho, self.rho_sc)
            self.rho_bar_handed = False
            _fill_rho(self.rho, self.rho_sc, near, self.base, self.rho_bar, self.box, self.vo)
        return var_dr

    def _linear_rho_gain(self) -> None:
        """A linear array's ρ̂ divided by the view filter's gain at each ray's frequencies
        (:mod:`polycam.filter_response`): fs3 across views a sizeable fraction of a sample apart
        reads L_x, so ρ̂, high, and the warp's extrapolation with that ρ̄ converged with the
        translation along the single-view axis short by as much. The frequencies are the level
        frame's, measured once per level over the rays with base weights (ρ̂'s windows)."""
        g = self.lev.grid
        view = "x" if self.linear == "y" else "y"
        if self.omega is None:
            self.omega = window_rms_frequency(self.lev.L0, self.base > 0, self.vo, self.cshape[1:3], self.filters, view)
        steps = (g.x.step, g.u.step) if view == "x" else (g.y.step, g.v.step)
        divide_rho_by_gain(self.rho, self.rho_sc, self.omega, steps, self.filters[view])

    def warp_change(self, M_a: np.ndarray, M_b: np.ndarray) -> float:
        """Largest first-order displacement of a ray of this level's grid between the warps of
        estimates M_a and M_b (both (4, 4)), in samples of its axis (x, y, u or v), over the
        corners of each face's (x, y, u, v) box (the displacement is at most quadratic there)."""
        D = T_inverse(M_a) @ M_b
        p = np.concatenate([D[:3, 3], r_from_R(D[:3, :3])])
        g = self.g
        best = 0.0
        for k, face in enumerate(g.faces):
            tx, ty, tz, wx, wy, wz = self.B[k] @ p
            f, z = face.f, face.z_pi
            for x in (g.x.values[0], g.x.values[-1]):
                for y in (g.y.values[0], g.y.values[-1]):
                    for u in (g.u.values[0], g.u.values[-1]):
                        for v in (g.v.values[0], g.v.values[-1]):
                            d = (tx - u / f * tz - u * y / f * wx + (u * x / f + z) * wy - y * wz,
                                 ty - v / f * tz - (v * y / f + z) * wx + v * x / f * wy + x * wz,
                                 -u * v / f * wx + (u * u / f + f) * wy - v * wz,
                                 -(v * v / f + f) * wx + u * v / f * wy + u * wz)
                            for dk, hk in zip(d, self.h):
                                if hk > 0:
                                    best = max(best, abs(dk) / hk)
        return best

    def _var_measured(self, var: np.ndarray) -> np.ndarray:
        """The derivative noise of the measured regressors (kept across re-preparations)."""
        if getattr(self, "_var0", None) is None:
            self._var0 = np.asarray(var, float).copy()
        return self._var0

    def reweighted(self, p_rig: np.ndarray, final: bool, kind: int | None = None):
        """Normal sums with IRLS weights of the residuals at p_rig (robust scale self.scale); ``kind``:
        the pass's weight instead of the IRLS loss's (:mod:`polycam.eq5`, e.g. its slope)."""
        Lx, Ly, Lu, Lv, Lt = self.der
        _pass_kernel(Lx, Ly, Lu, Lv, Lt, self.dsc, self.base, True, *self.vals, self.zs, self.fs,
                     self._face_params(p_rig), self.kind if kind is None else kind,
                     1.0 / (self.scale * self.opts.robust_c), self._tile(final),
                     self.box, self.vo, self.h, self.var, final, self.acc, self.st, parallel_chunks())
        return self._sums()

    def slope_normal(self) -> tuple[np.ndarray, float] | None:
        """(N_ψ', Σ base ψ'): the rig-frame normal matrix (6, 6) of the last solve's rays with each
        weight the base weight times the slope ψ' of the robust loss at the residual the last IRLS
        pass weighted by (at ``p_w``, scale ``scale``; :data:`polycam.eq5._ROBUST_SLOPE`), and the sum
        of those weights; for :func:`_increment_covariance`. None without IRLS weights (no robust
        loss or no reweighted pass) and after the whitened re-solves (their rows carry √w). One more
        pass over the rays; it overwrites the pass sums (call it after the last solve)."""
        if not self.kind or self.p_w is None or self.whitened or self.scale is None:
            return None
        (N, _, _, sw, _), _ = self.reweighted(self.p_w, False, _ROBUST_SLOPE[self.kind])
        return N, sw

    def mad(self, p_rig: np.ndarray, max_samples: int = _SCALE_SAMPLES) -> float:
        """1.4826 × weighted median of |residual| over base weight > 0 (weights = base), on
        every k-th (v) row of the valid views, at least ``max_samples`` rays (the scale
        needs no more precision)."""
        if self.n_base == 0:
            return 0.0
        box = self.box
        nv = int(box[5] - box[4])
        n_rows = self.shape[0] * int(box[1] - box[0]) * int(box[3] - box[2]) * nv
        stride = max(1, self.n_base // max_samples)
        while stride > 1 and math.gcd(stride, nv) != 1:      # visit every v
            stride -= 1
        n = -(-n_rows // stride)
        a = np.empty((n, int(box[7] - box[6])), np.float32)
        w = np.empty_like(a)
        _sample_residuals(*self.der, self.dsc, self.base, *self.vals, self.zs, self.fs, self._face_params(p_rig),
                          box, self.vo, stride, a, w)
        return 1.4826 * float(_weighted_median(a.reshape(-1), w.reshape(-1)))

    def model_weight(self, p_rig: np.ndarray) -> None:
        """``model_weight``: scale the base weights by the model-validity weight of the
        residuals at p_rig (:func:`~polycam.motion_weights.model_error_weights`, robust scale
        self.scale); the next :meth:`prepare` rewrites the base weights."""
        box = self.box
        dims = (self.shape[0],) + tuple(int(box[2 * k + 1] - box[2 * k]) for k in range(4))
        n = math.prod(dims[:4])
        res = _work_array("model_res", (n, dims[4]))
        w = _work_array("model_w", (n, dims[4]))
        _sample_residuals(*self.der, self.dsc, self.base, *self.vals, self.zs, self.fs, self._face_params(p_rig),
                          box, self.vo, 1, res, w)
        model_error_weights(res.reshape(dims), w.reshape(dims), self.base, box, self.scale,
                            gain=self.opts.model_weight_gain)

    def derivative_noise(self) -> np.ndarray:
        """(4,) expected variance of sensor noise in L_x, L_y, L_u, L_v (the frames' mean)."""
        return derivative_noise(_noise_variance(self.lev), self.g, self.filters)[:4]

    # --------------------------------------------------------------- whitening

    def whitened_sums(self, p_rig: np.ndarray | None) -> tuple:
        """:func:`~polycam.eq5._reduce` of the whitened rows (:func:`~polycam.whitening._whitened_sums`)
        with the current derivatives and base weights, IRLS weights of the residuals at p_rig
        (None: unit)."""
        kind = self.kind if p_rig is not None else 0
        P = self._face_params(p_rig) if p_rig is not None else np.zeros((self.shape[0], 6))
        inv_sc = 1.0 / (self.scale * self.opts.robust_c) if kind else 0.0
        factors = _whitening_factors(self.filters, self.radius, self.box, self.opts.whiten_floor)
        acc = _whitened_sums(tuple(self.der), self.base, self.vals, self.zs, self.fs, P, kind, inv_sc,
                             self.box, factors, self.tile, self.vo, self.dsc)
        return _reduce(acc, self.B)

    def decide_whiten(self) -> bool:
        """Switch the GLS re-solves on (``whiten="on"``, or ``auto`` when the whitened misfit at
        the last solve is within ``whiten_ratio`` of the expected whitened noise 2σ²); from then
        on the noise energy E is that of the whitened metric."""
        opts = self.opts
        var_n = _noise_variance(self.lev)
        on = opts.whiten == "on"
        Nw = None
        if opts.whiten == "auto" and var_n > 0 and self.n_base > 0:
            N, rhs, sbb, sw, _ = self.whitened_sums(self.p_w)
            Nw = N
            p = _solve_normal(N, rhs, opts.rcond)["p"]
            s2 = max(sbb - 2.0 * float(p @ rhs) + float(p @ N @ p), 0.0) / max(sw - 6.0, 1.0)
            noise = 2.0 * var_n * math.prod(self._prefilter_gains().values())
            on = s2 <= opts.whiten_ratio * noise
            log.debug("whiten: whitened misfit %.3g = %.2f x the expected noise %.3g: %s",
                      s2, s2 / noise, noise, "on" if on else "off")
        self.whitened = on
        if on:
            if self.mix is not None:              # the signal's whitening gain for the mix's ρ̂ part
                Nw = self.whitened_sums(self.p_w)[0] if Nw is None else Nw
                self.rho_gain = _signal_gain(self.N_plain, Nw)
            self.var = self._regressor_noise()
        return on

    def _regressor_noise(self) -> np.ndarray:
        """(4,) noise variances of the current regressors in the metric of the sums: the
        measured derivatives', or with the Eq. 6 regressors their mix (:class:`~polycam.eq5.RegressorMix`);
        whitened once the GLS re-solves are on."""
        if not self.whitened:
            return self.var_dr if self.var_dr is not None else self.derivative_noise()
        var_w = self.whitened_derivative_noise(_noise_variance(self.lev))
        return self.mix.variances(var_w, self.rho_gain) if self.mix is not None else var_w

    def whitened_derivative_noise(self, var_n: float) -> np.ndarray:
        """(4,) :meth:`derivative_noise` in the whitened metric: along the differentiated
        axis the whitened gain of the derivative taps (:func:`~polycam.whitening._whitened_noise_gain`), along
        the others 1 (whitening undoes their prefilters)."""
        var_S = 0.5 * var_n
        step = {"x": self.g.x.step, "y": self.g.y.step, "u": self.g.u.step, "v": self.g.v.step}
        gains = self._prefilter_gains()
        var = []
        for k in ("x", "y", "u", "v"):
            if self.radius[k] == 0 or not step[k] > 0 or not var_S > 0 or self._box_len(k) <= 0:
                var.append(0.0)
                continue
            others = math.prod(gains[o] for o in "xyuv" if o != k)
            var.append(var_S * _whitened_noise_gain(self.filters[k], self._box_len(k), self.opts.whiten_floor)
                       * others / step[k] ** 2)
        return np.array(var)

    def _box_len(self, axis: str) -> int:
        a = {"y": 0, "x": 1, "v": 2, "u": 3}[axis]
        return int(self.box[2 * a + 1] - self.box[2 * a])

    def _prefilter_gains(self) -> dict:
        """Axis → whitened variance of prefiltered unit white noise (1 without whiten_floor;
        1 on axes that are not filtered)."""
        return {k: (_whitened_noise_gain(self.filters[k], self._box_len(k), self.opts.whiten_floor, False)
                    if self.radius[k] > 0 and self._box_len(k) > 0 else 1.0) for k in "xyuv"}

    # --------------------------------------------------------------- solve

    def _misfit(self, p, N, rhs, sbb, tiles) -> tuple[float, np.ndarray]:
        """Σ w r² and the per-tile scores Σ w c r (G, 6) of the increment p (6,): residuals are
        linear in p, so both follow from the sums (N, rhs, Σ w b², per-tile sums)."""
        chi2 = max(sbb - 2.0 * float(p @ rhs) + float(p @ N @ p), 0.0)
        scores = []
        for k, Bk in enumerate(self.B):
            Nt = _unpack_sym(tiles[k, :, :21])
            scores.append((Nt @ (Bk @ p) - tiles[k, :, 21:27]) @ Bk)
        return chi2, np.concatenate(scores)

    def _increment_and_sigma(self) -> tuple[np.ndarray, np.ndarray, float]:
        """The unit-weight increment (6,) of the current sums (tiled: ``self.tile``), its
        (t, ω) standard deviations (2,) from the cluster-robust covariance, and the normal
        matrix's condition number."""
        (N, rhs, sbb, sw, tiles), _ = self._sums()
        sol = _solve_normal(N, rhs, self.opts.rcond)
        chi2, scores = self._misfit(sol["p"], N, rhs, sbb, tiles)
        sol.update(N=N, E=np.zeros((6, 6)), sw=sw, chi2=chi2, scores=scores)
        C = _increment_covariance(sol)[0]
        return sol["p"], np.sqrt([max(np.trace(C[:3, :3]), 0.0), max(np.trace(C[3:, 3:]), 0.0)]), sol["cond"]

    def solve(self, M: np.ndarray) -> dict:
        """Warp by M, then the weighted (IRLS) solve of the increment; returns a dict of the
        pieces (solution, normal matrix, noise energy, scores, counts)."""
        opts = self.opts
        if self.var is None:
            self.var = self.derivative_noise()
        steps = opts.irls_steps if self.kind else 0
        (N, rhs, sbb, sw, tiles), st = self.prepare(M, final=steps == 0)
        sol = _solve_normal(N, rhs, opts.rcond)
        self.p_w = None
        for i in range(steps):
            mad = max(self.mad(sol["p"]), _SCALE_FLOOR)
            # the scale may grow but never shrinks within a level: weights do not
            # tighten as the warp converges
            self.scale = mad if self.scale is None else max(self.scale, mad)
            if i == 0 and opts.model_weight and self.level == 0:
                self.model_weight(sol["p"])
            self.p_w = sol["p"]
            (N, rhs, sbb, sw, tiles), st = self.reweighted(sol["p"], final=i == steps - 1)
            sol = _solve_normal(N, rhs, opts.rcond)
        self.N_plain = N
        if self.whitened:
            # generalised least squares with the same weights (the kernel's sums give counts and E)
            N, rhs, sbb, sw, tiles = self.whitened_sums(self.p_w)
            if self.mix is not None:
                self.rho_gain = _signal_gain(self.N_plain, N)
            sol = _solve_normal(N, rhs, opts.rcond)
        stats = st.sum(axis=1)                                  # (F, 25)
        E = np.zeros((6, 6))
        for k, Bk in enumerate(self.B):
            E += Bk.T @ _unpack_sym(stats[k, 4:25]) @ Bk
        if opts.eiv and np.any(E):
            # step with the noise-free sensitivity N − E (errors in variables): with
            # noisy derivatives N alone under-steps (badly so where t and ω couple)
            sol["p"] = _corrected_pinv(N, E, sol) @ rhs
        p = sol["p"]
        chi2, scores = self._misfit(p, N, rhs, sbb, tiles)
        tot = stats.sum(axis=0)
        sol.update(N=N, E=E, sw=sw, chi2=chi2, scores=scores, tiles=tiles, B=self.B,
                   tile_grid=(self.shape[0], *self.acc.shape[1:3], self.tile), num=int(tot[0]),
                   base_n=int(tot[1]), inliers=int(tot[2]) if steps else None,
                   texture=math.sqrt(tot[3] / sw) if sw > 0 else 0.0)
        return sol


def _signal_gain(N_plain: np.ndarray, N_white: np.ndarray) -> float:
    """How much the whitening scales the energy of the signal ``L_u, L_v`` (the factor of the
    ``L_u² var(ρ̂)`` part of the Eq. 6 regressors' noise, :class:`~polycam.eq5.RegressorMix`):
    the mean ratio of the rotation columns' diagonals of the whitened and plain normal
    matrices N_white, N_plain (6, 6) with the same weights (those columns are L_u, L_v with
    smooth coefficients, and carry little noise: ~0.2 % of N at 8 grey levels); 1 when
    they are empty."""
    d0, d1 = np.diag(N_plain)[3:], np.diag(N_white)[3:]
    ok = (d0 > 0) & (d1 > 0)
    return float(np.mean(d1[ok] / d0[ok])) if ok.any() else 1.0


@dataclass(frozen=True)
class ScaledEigen:
    """Jacobi-scaled eigen-analysis of a 6x6 normal matrix N: what the solver can observe."""

    N_pinv: np.ndarray
    """(6, 6) pseudo-inverse of N on the observable subspace."""
    evals: np.ndarray
    """(6,) eigenvalues of the scaled matrix ``S N S`` (ascending)."""
    evecs: np.ndarray
    """(6, 6) its unit eigenvectors (columns), in scaled parameters."""
    scale: np.ndarray
    """(6,) the Jacobi scaling ``S = diag(1 / sqrt(N_ii))`` (0 for dead columns)."""
    live: np.ndarray
    """(6,) bool: columns of N that are not (numerically) zero."""
    good: np.ndarray
    """(6,) bool: eigenvalues above ``rcond`` times the largest (observable directions)."""


def scaled_eigen(N: np.ndarray, rcond: float) -> ScaledEigen:
    """Jacobi-scaled eigen-analysis of N (6, 6): directions whose scaled eigenvalue is below
    ``rcond`` times the largest are unobservable (dead columns give zero eigenvalues whose
    eigenvectors are axis vectors)."""
    d = np.diag(N).copy()
    dmax = float(d.max()) if d.size else 0.0
    live = d > max(dmax, 1e-300) * 1e-14
    s = np.where(live, 1.0 / np.sqrt(np.where(live, d, 1.0)), 0.0)
    Ns = N * s[:, None] * s[None, :]
    evals, evecs = np.linalg.eigh(Ns)
    lmax = float(evals.max()) if evals.size else 0.0
    good = evals > rcond * lmax if lmax > 0 else np.zeros(6, bool)
    inv = np.zeros(6)
    inv[good] = 1.0 / evals[good]
    N_pinv = ((evecs * inv) @ evecs.T) * s[:, None] * s[None, :]
    return ScaledEigen(N_pinv=N_pinv, evals=evals, evecs=evecs, scale=s, live=live, good=good)


def _solve_normal(N: np.ndarray, rhs: np.ndarray, rcond: float) -> dict:
    """Solve N p = rhs with Jacobi scaling; directions with tiny scaled eigenvalues are dropped."""
    eig = scaled_eigen(N, rcond)
    evals, evecs, good, N_pinv = eig.evals, eig.evecs, eig.good, eig.N_pinv
    lmax = float(evals.max()) if evals.size else 0.0
    p = N_pinv @ rhs
    bad_dirs = evecs[:, ~good].T
    cond = float(lmax / evals[good].min()) if good.all() and lmax > 0 else math.inf
    return {"p": p, "N_pinv": N_pinv, "unobs": bad_dirs, "cond": cond, "scale": eig.scale}


def _name_direction(vec: np.ndarray) -> str:
    """'t_x' for an axis-aligned unit vector, else a short linear combination."""
    a = np.abs(vec)
    i = int(np.argmax(a))
    if a[i] > 0.95:
        return PARAM_NAMES[i]
    terms = [f"{vec[j]:+.2f} {PARAM_NAMES[j]}" for j in np.argsort(-a) if a[j] > 0.1]
    return "(" + " ".join(terms) + ")"


def _check_frame(name: str, L: np.ndarray, grid: LightFieldGrid, W: np.ndarray | None = None,
                 intensities: bool = True) -> np.ndarray:
    """(F, Ny, Nx, Nv, Nu) float32 C-contiguous frame (colour averaged; the input itself when
    it already is one: never written). Non-finite samples are an error unless the
    confidence ``W`` is 0 there (they are then set to 0); so are non-numeric dtypes and, with
    ``intensities``, values beyond :data:`MAX_INTENSITY`."""
    L = np.asarray(L)
    if L.dtype.kind not in "biuf":
        raise InputError(f"motion: {name} has dtype {L.dtype}; expected numbers (float32 in [0, 1])")
    if L.ndim == 6 and L.shape[:5] == grid.shape:        # colour: average the channels
        L = L.mean(axis=-1)
    if L.shape != grid.shape:
        raise InputError(f"motion: {name} has dims {L.shape}, but the grid is {grid.shape} "
                         "(F, Ny, Nx, Nv, Nu)")
    L = np.ascontiguousarray(L, dtype=np.float32)     # no copy when it already is (never written)
    L = finite_frame(name, L, W, who="motion")
    big = max(float(L.max()), -float(L.min())) if intensities and L.size else 0.0     # no |L| temporary
    if big > MAX_INTENSITY:
        raise InputError(f"motion: {name} has intensities up to {big:.3g}; expected [0, 1] (8-bit / 255, "
                         "16-bit / 65535: SPEC.md)")
    return L


MAX_INTENSITY = 1e4
"""The largest |intensity| :func:`estimate_motion` takes: SPEC.md's frames are in [0, 1]; frames in 8- or
16-bit units (255, 65535) pass, a few orders of magnitude more are a scaling mistake (values of 1e20
overflowed the robust scale's histogram)."""


def _check_confidence(name: str, W: np.ndarray, grid: LightFieldGrid) -> np.ndarray:
    """(F, Ny, Nx, Nv, Nu) float32 confidences in [0, 1] (SPEC.md)."""
    W = _check_frame(name, W, grid, intensities=False)
    lo, hi = (float(W.min()), float(W.max())) if W.size else (0.0, 0.0)
    if not (lo >= 0.0 and hi <= 1.0):
        raise InputError(f"motion: {name} outside [0, 1] (from {lo:g} to {hi:g})")
    return W


def _check_grid(grid: LightFieldGrid) -> None:
    """:class:`InputError` for a grid no frame can be solved on (a grid made in code: GRID.toml and
    stores are checked when read)."""
    if not grid.faces:
        raise InputError("motion: the grid has no faces")
    for face in grid.faces:
        if not (math.isfinite(face.f) and face.f > 0 and math.isfinite(face.z_pi)):
            raise InputError(f"motion: face {face.name}: f must be finite and > 0 and z_pi finite, got "
                             f"f = {face.f}, z_pi = {face.z_pi}")
    for name in ("u", "v"):
        if getattr(grid, name).count < 3:
            raise InputError(f"motion: the grid has {getattr(grid, name).count} direction(s) along {name}; "
                             "the derivatives need at least 3")
    for name in ("x", "y", "u", "v"):
        a = getattr(grid, name)
        if a.count < 1 or not (math.isfinite(a.min) and math.isfinite(a.max)):
            raise InputError(f"motion: the grid's {name} axis is empty or not finite ({a})")


def _options_filters(opts: MotionOptions) -> dict:
    """Axis ("x", "y", "u", "v") → the derivative filter ``opts.filters`` names for it."""
    fnames = opts.filters if isinstance(opts.filters, dict) else {k: opts.filters for k in "xyuv"}
    try:
        return {k: FILTERS[fnames.get(k, "fs5")] for k in "xyuv"}
    except KeyError as e:
        raise InputError(f"motion: unknown derivative filter {e.args[0]!r}; expected one of "
                         f"{sorted(FILTERS)}") from None


def estimate_motion(L0: np.ndarray, L1: np.ndarray, grid: LightFieldGrid, *,
                    W0: np.ndarray | None = None, W1: np.ndarray | None = None,
                    T_init: np.ndarray | None = None, options: MotionOptions | None = None,
                    index: int = 0) -> PairResult:
    """Rig motion ``T_rig0_rig1`` between light-field frames ``L0`` and ``L1``.

    ``L0``, ``L1``: (F, Ny, Nx, Nv, Nu) intensities on ``grid`` (a trailing colour
    axis is averaged). ``W0``, ``W1``: optional confidences of the same dims in
    [0, 1]. ``T_init``: (4, 4) starting estimate of ``T_rig0_rig1`` (identity).
    Raises :class:`InputError` for unusable input: NaNs where W is not 0, dims that do not match
    the grid or each other's colour channels, non-numeric dtypes, intensities beyond
    :data:`MAX_INTENSITY`, W outside [0, 1], a ``T_init`` that is not a finite (4, 4) transform,
    a grid without faces, with a face whose f is not finite and > 0, or with fewer than 3
    directions along u or v.
    """
    opts = (options or MotionOptions()).for_frames(W0 is not None or W1 is not None)
    _check_grid(grid)
    W0 = None if W0 is None else _check_confidence(f"weights of frame {index}", W0, grid)
    W1 = None if W1 is None else _check_confidence(f"weights of frame {index + 1}", W1, grid)
    if np.ndim(L0) == 6 and np.ndim(L1) == 6 and np.shape(L0)[-1] != np.shape(L1)[-1]:
        raise InputError(f"motion: frames {index} and {index + 1} have {np.shape(L0)[-1]} and "
                         f"{np.shape(L1)[-1]} colour channels")
    L0 = _check_frame(f"frame {index}", L0, grid, W0)
    L1 = _check_frame(f"frame {index + 1}", L1, grid, W1)
    filters = _options_filters(opts)
    M = np.eye(4) if T_init is None else np.asarray(T_init, float).copy()
    if M.shape != (4, 4) or not np.all(np.isfinite(M)):
        raise InputError(f"motion: T_init must be a finite (4, 4) transform, got dims {M.shape}")
    linear = _linear_unsupported(grid, opts)
    if linear:
        log.warning("pair %d: %s", index, linear)
        C = np.diag(np.full(6, np.inf))
        return PairResult(index=index, T_prev_next=M, covariance=C, covariance_noise=C.copy(), covariance_iid=C.copy(),
                          sigma=math.nan, condition=math.inf, inlier_fraction=0.0, num_rays=0, iterations=0,
                          reason=linear, noise_sigma=math.sqrt(frame_noise_variance(L0, L1, grid, W0, W1)))
    # the coarse levels' frames borrow the idle tails of the finest level's work arrays
    # (kept from the previous estimate; a session's peak memory is then one estimate's)
    _return_tails()
    try:
        radius = {k: fp.radius for k, fp in filters.items()}
        levels = _pyramid(L0, L1, W0, W1, grid, opts, radius, alloc=_tail_array)
        start, disparity = _aliasing_start(levels, opts, radius)
        if start == 0:
            one_level = len(levels) == 1
            res = _estimate_levels(levels, M, opts, filters, index, disparity=disparity)
            if one_level and opts.levels > 1 and res.ok:
                res = _blurred_change(res, L0, L1, W0, W1, grid, opts, filters, index)
            return replace(res, view_disparity=disparity)
        work = levels[start:]
        d_start = disparity * _per_view(work[0].grid, levels[0].grid)     # (finite: start > 0)
        del levels[1:]                            # the finer levels' frames are not needed
        res = _estimate_levels(work, M, opts, filters, index, own_finest=False, disparity=d_start)
        return replace(res, uv_level=start, view_disparity=disparity,
                       noise_sigma=math.sqrt(_noise_variance(levels[0])))
    finally:
        _return_tails()


def _aliasing_start(levels: list, opts: MotionOptions, radius: dict) -> tuple[int, float]:
    """(k, d): the finest pyramid level k whose disparity per view step is at most
    ``opts.max_view_disparity`` of its (u, v) samples, and that disparity d measured in the
    finest level's samples (NaN: not measured, k = 0). Extends ``levels`` (finest first) so
    that ``opts.levels`` levels remain from k where the (u, v) sampling allows.

    d is :func:`polycam.scales.view_disparity` (the median over the rays of the differential-
    stereo depth, the largest over the faces) on the central 3 x 3 views of the coarsest level
    up to the third (cheap: ~1 ms on 9 x 9 x 32 x 32, and coarse levels alias least), scaled by
    that level's (u, v) step over the (x, y) step relative to the finest's, its rays gated
    against that level's sensor noise (``noise_var``: rays without texture left out, rays whose
    views differ by no more than the noise counted as disparity 0) and counted only where the
    two stereo equations agree (``agree``: :data:`~polycam.scales.VIEW_DISPARITY_AGREE`), with
    confidences W0 only on rays with at least half the best W0 of those views. Needs
    3 views along x and y, or along one of them on a linear array (one viewpoint along the other).
    A level that halves (x, y) with (u, v) (``pyramid_xy``) keeps the disparity per
    view step: the search stops before it."""
    thr = opts.max_view_disparity
    if not math.isfinite(thr):
        return 0, math.nan
    d = _measured_disparity(levels)
    if not math.isfinite(d):
        return 0, math.nan
    g0 = levels[0].grid
    k = 0
    while d * _per_view(levels[k].grid, g0) > thr:
        if k + 1 >= len(levels) and not _add_level(levels, opts, radius, _tail_array):
            break
        if _per_view(levels[k + 1].grid, g0) >= _per_view(levels[k].grid, g0):
            break                 # (x, y) halved with (u, v) (pyramid_xy): no nearer the threshold
        k += 1
    while len(levels) < k + opts.levels and _add_level(levels, opts, radius, _tail_array):
        pass
    if k:
        log.debug("disparity %.2f samples per view step: the solve stops at (u, v) level %d", d, k)
    return k, d


def _measured_disparity(levels: list) -> float:
    """Disparity per view step of ``levels`` (finest first) in the finest level's (u, v) samples, as
    :func:`_aliasing_start` describes (NaN: not measured: too few views, no usable rays)."""
    g0 = levels[0].grid
    single = g0.single_view_axis
    if any(n < 3 and not (single and n == 1) for n in (g0.x.count, g0.y.count)):
        return math.nan
    from .scales import VIEW_DISPARITY_AGREE, view_disparity

    m = min(2, len(levels) - 1)
    lev = levels[m]
    g = lev.grid
    cy, cx = g.y.count // 2, g.x.count // 2
    ys = slice(cy - 1, cy + 2) if g.y.count > 1 else slice(0, 1)
    xs = slice(cx - 1, cx + 2) if g.x.count > 1 else slice(0, 1)
    sub = replace(g, y=Axis.from_values(g.y.values[ys]), x=Axis.from_values(g.x.values[xs]))
    views = (slice(None), ys, xs)
    L = lev.L0[views]
    W = None if lev.W0 is None else lev.W0[views]
    if W is not None and 0.0 < float(W.max()) < 1.0:
        # the gate (W0 > 0.5) relative to the best of these views: a stereo pair resampled with
        # 4 views per camera spacing has no camera among its central views (W 0.25-0.375), whose
        # disparity was then never measured (docs/motion.md, "Blending the views along the disparity")
        W = W / float(W.max())
    # (one frame as both: their mean carries its whole noise, twice that of two frames' mean)
    d_faces = view_disparity(L, L, sub, W0=W, noise_var=2.0 * _noise_variance(lev), agree=VIEW_DISPARITY_AGREE)
    if not np.any(np.isfinite(d_faces)):
        return math.nan
    return float(np.nanmax(d_faces)) / _per_view(g, g0)          # finest level's samples per its view step


def _per_view(g: LightFieldGrid, g0: LightFieldGrid) -> float:
    """Samples of level grid g per sample of the finest level's g0, per view step of g per g0's
    (along y on a linear array with one viewpoint along x): a disparity per view step measured in
    g0's samples times this is g's."""
    if g0.single_view_axis == "x":
        return (g.y.step / g0.y.step) / (g.v.step / g0.v.step)
    return (g.x.step / g0.x.step) / (g.u.step / g0.u.step)


def frame_view_disparity(L: np.ndarray, grid: LightFieldGrid, W: np.ndarray | None = None,
                         options: MotionOptions | None = None) -> float:
    """Disparity per view step of one light-field frame, in ``grid``'s (u, v) samples: what the
    solver measures to choose its finest (u, v) level (``MotionOptions.max_view_disparity``; the
    pair's ``PairResult.view_disparity``), here for a frame alone, e.g. to choose how finely to
    resample a session (:func:`polycam.run.choose_uv_step`).

    ``L``: (F, Ny, Nx, Nv, Nu) intensities (a trailing colour axis is averaged); ``W``: optional
    confidences of the same dims. NaN when it cannot be measured (fewer than 3 views along x or
    y, no texture). Raises :class:`InputError` for unusable input (NaNs, mismatched dims).
    """
    opts = options or MotionOptions()
    W = None if W is None else _check_frame("weights", W, grid)
    L = _check_frame("frame", L, grid, W)
    radius = {k: fp.radius for k, fp in _options_filters(opts).items()}
    levels = _pyramid(L, L, W, W, grid, replace(opts, levels=3), radius)
    return _measured_disparity(levels)


def _estimate_levels(levels: list, M: np.ndarray, opts: MotionOptions, filters: dict, index: int,
                     own_finest: bool = True, disparity: float = math.nan) -> PairResult:
    """:func:`estimate_motion` on the pyramid ``levels`` (finest first) from ``M``.
    ``own_finest``: ``levels[0]``'s frames are not borrowed work memory (:func:`_tail_array`),
    so the loans end once it is reached. ``disparity``: per view step in ``levels[0]``'s
    samples (:func:`_aliasing_start`; NaN: not measured), which turns on each level's
    ``depth_views``."""
    g0 = levels[0].grid
    n_solves = 0
    sol = None
    solver = None
    diag = None
    coarse = None
    M_start = np.array(M, float)
    for li in range(len(levels) - 1, -1, -1):
        if li == 0 and diag is not None:
            coarse = M.copy()                     # the estimate the level above hands down
        # the coarser level's extrapolation disparity ρ̄ (it has one only with depth_regressors at
        # a level < _DR_LEVELS), its grid and disparity-gate decision, handed down (None: no ρ̄)
        coarse_rho = None if solver is None or solver.rho_bar is None else (solver.rho_bar, solver.lev.grid,
                                                                            solver.gate_misfit)
        solver = None                             # free the previous level's buffers first
        levels[li + 1:] = [None] * (len(levels) - li - 1)      # and its frames
        if li == 0 and own_finest:
            _return_tails()                       # the coarse frames are dead now
        solver = _Solver(levels[li], opts, filters, li,
                         disparity * _per_view(levels[li].grid, g0) if math.isfinite(disparity) else math.nan)
        if coarse_rho is not None:
            rho_bar, coarse_grid, gate_misfit = coarse_rho
            solver.rho_bar = _finer_rho_bar(rho_bar, coarse_grid, levels[li].grid)
            solver.rho_bar_handed = True
            # the gate's floor too (decided where that level's ρ̂ began, :meth:`_Solver.prepare`):
            # decided again at a start already near the answer, the measured and gated estimates
            # differ less and the z test flipped to the measured regressors on sharp noisy frames
            # (1.5 view steps, 2 grey levels: t 4.6 mm off instead of 0.8; docs/motion_log.md)
            solver.gate_misfit = gate_misfit
        finest = li == 0
        whiten = finest and opts.whiten != "off"
        for it in range(opts.iterations + (_WHITEN_ITERATIONS if whiten else 0)):
            sol = solver.solve(M)
            n_solves += 1
            p = sol["p"]
            if not np.all(np.isfinite(p)):        # cannot happen with finite input; be safe
                p = sol["p"] = np.zeros(6)
            H = _T_sqrt(M) if opts.symmetric else M
            D = T_from_Rt(R_from_r(p[3:]), p[:3])
            M = H @ T_inverse(D) @ H if opts.symmetric else T_inverse(D) @ M
            diag = (sol, _increment_covariance(sol), H)
            if finest or it >= 1:
                # Stop once the increment is within the noise: re-warping noisy data
                # only makes the estimate wander (it re-samples the noise). Coarse
                # levels take two steps, then stop also once within the next level's reach.
                C = diag[1][0]
                chi2 = float(p @ np.linalg.pinv(C) @ p) if np.all(np.isfinite(C)) else math.inf
                done = chi2 < _CHI2_STOP or np.linalg.norm(p[:3]) + np.linalg.norm(p[3:]) < opts.tol
                done = done or (not finest and solver.warp_change(np.eye(4), D) < _COARSE_SETTLED)
                if whiten and solver.whitened is None and (done or it >= opts.iterations - 1) \
                        and solver.decide_whiten():
                    continue                      # converged: now the whitened (GLS) re-solves
                if done or (finest and not solver.whitened and it >= opts.iterations - 1):
                    break
    if diag is not None:
        # the reported covariance with the M-estimate's sensitivity (one more pass; the
        # convergence tests above took the IRLS weights')
        diag = (diag[0], _increment_covariance(diag[0], solver.slope_normal(), jackknife=True), diag[2])
    parallax = None
    if opts.parallax_min > 0:
        lev = levels[0]
        parallax = parallax_signal(lev.L0, lev.L1, lev.grid, M, filters=filters, W0=lev.W0, W1=lev.W1)
    change = None
    if coarse is not None:
        change = np.concatenate([M[:3, 3] - coarse[:3, 3], r_from_R(M[:3, :3]) - r_from_R(coarse[:3, :3])])
    return _result(index, M, diag, opts, n_solves, _few_views(levels[0].grid, filters),
                   math.sqrt(_noise_variance(levels[0])), change, M_start, parallax)


def _blur_uv(L: np.ndarray, W: np.ndarray | None) -> tuple[np.ndarray, np.ndarray | None]:
    """(L, W) (F, Ny, Nx, Nv, Nu) blurred along u and v by the pyramid's binomial filter (not
    decimated); with confidences a normalised convolution (samples without data do not darken their
    neighbours; the blurred W is the blurred confidences)."""
    def blur(a):
        return correlate_axis(correlate_axis(np.ascontiguousarray(a, np.float32), _BINOMIAL, 4), _BINOMIAL, 3)

    if W is None:
        return blur(L), None
    Wb = blur(W)
    Lb = blur(L * W)
    return np.where(Wb > 0, Lb / np.where(Wb > 0, Wb, 1.0), 0.0).astype(np.float32), np.clip(Wb, 0.0, 1.0)


def _blurred_change(res: PairResult, L0, L1, W0, W1, grid: LightFieldGrid, opts: MotionOptions, filters: dict,
                    index: int) -> PairResult:
    """``res`` (an estimate on one (u, v) level: the grid's directions allow no coarser one) with the
    model-error term a coarser level would give: the change ``d`` from the estimate on the frames
    blurred along u and v (:func:`_blur_uv`), which see the scene through other filters as a coarser
    level does, started from ``res``; ``covariance`` gains ``d dᵀ`` and ``level_change`` is ``d``.
    Measured on the tests' one-face and six-face rooms and spheres (docs/motion.md, "How far to trust
    the covariance"): clean frames' error / std 0.9–4.8 (RMS over the axes) → 0.1–0.4, noisy frames'
    1.2–1.9 → 0.9–1.6. When the blurred estimate fails, its first step alone (one linearisation at
    ``res``, which cannot warp the rays off the grid) stands in: one face rotated by 8–10° between
    frames, whose second step along the weak t–ω direction left no ray on the grid (session 56).
    ``res`` unchanged when that fails too."""
    (A, WA), (B, WB) = _blur_uv(L0, W0), _blur_uv(L1, W1)
    radius = {k: fp.radius for k, fp in filters.items()}
    one = replace(opts, levels=1, parallax_min=0.0)
    for o in (one, replace(one, iterations=1)):         # then the first step alone
        other = _estimate_levels(_pyramid(A, B, WA, WB, grid, o, radius), res.T_prev_next, o, filters, index)
        if other:
            break
    else:
        return res
    M, C = res.T_prev_next, other.T_prev_next
    d = np.concatenate([M[:3, 3] - C[:3, 3], r_from_R(M[:3, :3]) - r_from_R(C[:3, :3])])
    if not np.all(np.isfinite(d)):
        return res
    return replace(res, covariance=res.covariance_noise + np.outer(d, d), level_change=d)


def _finer_rho_bar(rho_bar: np.ndarray, coarse: LightFieldGrid, fine: LightFieldGrid) -> np.ndarray:
    """A coarser pyramid level's extrapolation disparity ρ̄ (F, Nv_c, Nu_c) on its grid
    ``coarse``, resampled onto the (u, v) samples of the finer level's grid ``fine``: (F, Nv,
    Nu) float64, each direction taking the nearest coarse direction's value (NaN stays NaN).
    ρ = f / Z is in u per unit x (:func:`polycam.warp.warp_lightfield`), the same physical
    quantity at every level, so only the sampling changes. The finer level's first
    preparation extrapolates with it and then replaces it by its own (:meth:`_Solver.prepare`)."""
    iu = np.abs(fine.u.values[:, None] - coarse.u.values[None, :]).argmin(axis=1)
    iv = np.abs(fine.v.values[:, None] - coarse.v.values[None, :]).argmin(axis=1)
    return np.ascontiguousarray(rho_bar[:, iv][:, :, iu])


def _few_views(grid: LightFieldGrid, filters: dict) -> str:
    """Why a grid may leave no usable rays: the view axes whose every viewpoint lies inside one
    ray's filter support (3 views under fs3), where any motion moves part of the support out of
    the grid ('' when there are none)."""
    tight = [(k, n) for k, n in (("x", grid.x.count), ("y", grid.y.count))
             if 0 < filters[k].radius and n == 2 * filters[k].radius + 1]
    if not tight:
        return ""
    return (" and ".join(f"{n} viewpoints along {k}" for k, n in tight) + " are all inside one ray's filter "
            "support, so a moved frame leaves no usable ray: resample onto more viewpoints (e.g. views "
            "between the cameras)")


def _linear_unsupported(grid: LightFieldGrid, opts: MotionOptions) -> str:
    """Why the solver cannot take a linear array with these options ('' when it can). A linear
    array's warp extrapolates every ray moved off its single-view axis by Eq. 6 (the views' ρ̄),
    which the symmetric warp (both frames half-way) does not do."""
    k = grid.single_view_axis
    if not k or not opts.symmetric:
        return ""
    other = "y" if k == "x" else "x"
    n = grid.y.count if k == "x" else grid.x.count
    return (f"one viewpoint along {k} and {n} along {other} (a linear array) needs the one-sided warp: "
            "the symmetric warp (MotionOptions.symmetric) does not extrapolate along the single-view axis")


_COARSE_SETTLED = 0.5
"""After its two steps a coarse level stops once its increment moves no ray by this many of
its samples (of any axis): the next level, with twice the sampling, takes up a one-sample
error in its first linearisation. Stopping a coarse level after one such step instead
(faster) left the finest level of an ill-conditioned one-face design (t~ω correlation
-0.89) stopping on the noise test short of convergence: its scatter rose 36 % above the
prediction (tests/test_design.py)."""
_CHI2_STOP = 12.6
"""95% quantile of χ² with 6 degrees of freedom: an increment below it is noise."""
_WHITEN_ITERATIONS = 3
"""Most whitened (GLS) re-solves after the plain solve converged at the finest level."""


def _increment_covariance(sol: dict, slope: tuple[np.ndarray, float] | None = None,
                          jackknife: bool = False) -> tuple[np.ndarray, np.ndarray, float]:
    """Covariances (6, 6) of the converged estimate: cluster-robust sandwich and
    ``σ² (AᵀWA)⁺``, and σ².

    Sensor noise in the derivatives inflates AᵀWA (errors in variables): the iteration
    converges where the noise's pull balances the *noise-free* sensitivity, which is
    AᵀWA minus the expected noise energy E. Both covariances use ``N − E`` (E shrunk
    if needed to keep it well inside positive definite); with one face, where t and ω
    couple, this is a factor of several for the translation. The scores are the
    per-tile sums of w c r over (u, v) tiles of all views (``_Solver.solve``).

    ``slope``: (N_ψ', Σ base ψ') of :meth:`_Solver.slope_normal`, the normal matrix with each ray's
    weight the slope ψ' of the robust loss at its residual instead of the IRLS weight ψ(r) / r.
    IRLS converges to the M-estimate ``Σ base c ψ(r) = 0``, which noise moves through ψ', not
    through the weight: for Tukey's loss ψ' is below the weight everywhere (negative beyond 45 %
    of the cut-off), so the sandwich's sensitivity is ``N_ψ' − κE`` (κ = Σ base ψ' / Σ w, E's
    share), as :mod:`polycam.design` predicts it. Taken only where it is well inside positive
    definite (its Jacobi-scaled eigenvalues above 5 % of N's smallest); ``σ² (AᵀWA)⁺`` keeps N.
    The solver's convergence tests take the IRLS weights' N (the estimate is as before session
    56); the reported covariance takes the slope (:func:`_estimate_levels`).

    ``jackknife``: the tiles summed into clusters that span the residuals' correlation
    (:func:`_clusters`) and each cluster's score scaled by its leverage (:func:`_jackknife_scores`, the
    cluster jackknife), for the reported covariance; without it (the convergence tests, the depth
    gate's test) the tiles' scores as they are, times G / (G − 1).
    """
    sigma2 = sol["chi2"] / max(sol["sw"] - 6.0, 1.0)
    Np = _corrected_pinv(sol["N"], sol["E"], sol)
    Nb = Np
    if slope is not None:
        N_s, sw_s = slope
        sc = sol["scale"]                                 # N's Jacobi scaling (_solve_normal)
        live = sc > 0
        ev_s = np.linalg.eigvalsh((N_s * sc[:, None] * sc[None, :])[np.ix_(live, live)])
        ev = np.linalg.eigvalsh((sol["N"] * sc[:, None] * sc[None, :])[np.ix_(live, live)])
        if len(ev) and ev_s.min() > 0.05 * ev.min() and sol["sw"] > 0:
            Nb = _corrected_pinv(N_s, sol["E"] * (sw_s / sol["sw"]), sol, N_scale=sol["N"])
    S = sol["scores"]
    G = S.shape[0]
    if jackknife:
        S, tile_N = _clusters(S, _tile_normals(sol["tiles"], sol["B"]), sol["tile_grid"])
        S = _jackknife_scores(S, tile_N, sol)
        meat = S.T @ S
    else:
        meat = S.T @ S * (G / max(G - 1, 1))
    return Nb @ meat @ Nb, sigma2 * Np, sigma2


_CLUSTER_SAMPLES = 8
"""Smallest (u, v) extent [samples] of the reported covariance's clusters: the residuals are
correlated over the derivative filters' support (5 samples along u, v) widened by the warp's
interpolation, and a sandwich over clusters smaller than that misses the correlation between
neighbours (:func:`_clusters`)."""
_CLUSTER_MIN = 24
"""Fewest clusters (tiles with rays) :func:`_clusters` merges the tiles into: the jackknife of six
parameters over fewer turns erratic (one face of 24 x 24 directions in 9 clusters: leverages at the
clip, the std up to 1.7x conservative)."""


def _tile_normals(tiles: np.ndarray, B: list) -> np.ndarray:
    """(G, 6, 6) each tile's rig-frame normal matrix Σ w c cᵀ from the per-face tile sums ``tiles``
    (F, n_tiles, 29) and the faces' rig → face maps B, in the order of :meth:`_Solver._misfit`'s
    scores."""
    return np.concatenate([Bk.T @ _unpack_sym(tiles[k, :, :21]) @ Bk for k, Bk in enumerate(B)])


def _clusters(S: np.ndarray, tile_N: np.ndarray, grid: tuple[int, int, int, int]
              ) -> tuple[np.ndarray, np.ndarray]:
    """The reported covariance's clusters: the tiles' scores S (G, 6) and normal matrices tile_N (G, 6,
    6), G = F n_tv n_tu (``grid`` = (F, n_tv, n_tu, tile): faces, tiles along v and u, the tile's
    size in samples), summed over blocks of b x b tiles, b the fewest tiles that span
    :data:`_CLUSTER_SAMPLES`; as they are (b = 1) where that leaves fewer than :data:`_CLUSTER_MIN`
    clusters with rays. Only small grids have tiles under 8 samples (``_Solver``'s tiles are an
    eighth of the directions, at least 4): on six faces of 16 x 16 directions the 96 tiles of 4
    samples become 24 of 8, and the noisy sets' errors 1.05–1.33x their std become 0.87–1.12x."""
    F, n_tv, n_tu, tile = grid
    b = -(-_CLUSTER_SAMPLES // max(int(tile), 1))
    if b <= 1 or len(S) != F * n_tv * n_tu:
        return S, tile_N

    def blocks(X):                                        # (G, ...) → (F nbv nbu, ...) block sums
        X = X.reshape((F, n_tv, n_tu) + X.shape[1:])
        X = np.pad(X, [(0, 0), (0, -n_tv % b), (0, -n_tu % b)] + [(0, 0)] * (X.ndim - 3))
        X = X.reshape((F, X.shape[1] // b, b, X.shape[2] // b, b) + X.shape[3:]).sum(axis=(2, 4))
        return X.reshape((-1,) + X.shape[3:])

    S_c, N_c = blocks(S), blocks(tile_N)
    live = np.trace(N_c, axis1=1, axis2=2) > 0
    if live.sum() < _CLUSTER_MIN:
        return S, tile_N
    return S_c[live], N_c[live]


_JACKKNIFE_LEVERAGE_MAX = 0.9
"""Largest leverage eigenvalue of one cluster that :func:`_jackknife_scores` takes as it is: its
score then grows at most 10x. Near 1 (a direction that one cluster nearly alone determines) the
factor is unbounded while the score along it goes to 0 (the fit takes up that cluster's noise
there); the clusters of the tests' grids reach 0.3–0.7."""


def _jackknife_scores(S: np.ndarray, tile_N: np.ndarray, sol: dict) -> np.ndarray:
    """(G, 6) the clusters' scores S (G, 6) each scaled by its leverage: ``N (N − N_g)⁻¹ s_g``, N
    the solve's normal matrix ``sol["N"]`` (6, 6) and N_g (``tile_N``, (G, 6, 6)) the cluster's
    share (:func:`_clusters`).

    At the fit the residuals are orthogonal to the regressors, so a cluster's score shows its noise
    less the part the fit took up, and most so where the cluster carries much of a direction's
    information (a textured patch, an occluding edge: on the tests' six faces of 16 x 16 directions
    the one with the most of 96 tiles carries a third to a half of one direction, of 24 clusters
    about a half). Leaving cluster g out moves the solution by ``(N − N_g)⁻¹ s_g``, so with these
    scores the sandwich ``N⁻¹ (Σ s̃ s̃ᵀ) N⁻¹`` is the variance of the leave-one-cluster-out
    estimates about the estimate (the cluster jackknife, "CR3" of the cluster-robust literature;
    MacKinnon & White 1985 for single rays). Computed in N's Jacobi scaling (``sol["scale"]``) on
    its observable subspace (``sol["unobs"]`` its complement): with ``R`` the subspace's
    eigenvectors over the square roots of their eigenvalues, ``N R Rᵀ`` is the identity there and
    ``N (N − N_g)⁻¹ = N R (I − Rᵀ N_g R)⁻¹ Rᵀ``; the cluster's leverages (the eigenvalues of
    ``Rᵀ N_g R``, in [0, 1]) are clipped at :data:`_JACKKNIFE_LEVERAGE_MAX`."""
    n_obs = 6 - len(sol["unobs"])
    if n_obs <= 0 or not len(S):
        return S
    sc = sol["scale"]
    ev, V = np.linalg.eigh(sol["N"] * sc[:, None] * sc[None, :])
    ev, V = np.maximum(ev[-n_obs:], 1e-300), V[:, -n_obs:]
    R = V / np.sqrt(ev)                                   # (6, n_obs)
    lev, U = np.linalg.eigh(R.T @ (tile_N * sc[:, None] * sc[None, :]) @ R)
    f = 1.0 / (1.0 - np.clip(lev, 0.0, _JACKKNIFE_LEVERAGE_MAX))
    z = (S * sc) @ R                                      # (G, n_obs): the scaled scores in R's basis
    z = np.einsum("gij,gj->gi", U, f * np.einsum("gji,gj->gi", U, z))
    out = z @ (V * np.sqrt(ev)).T                         # N's scaled form times R, applied to z
    return np.where(sc > 0, out / np.where(sc > 0, sc, 1.0), 0.0)


def _corrected_pinv(N: np.ndarray, E: np.ndarray, sol: dict, N_scale: np.ndarray | None = None) -> np.ndarray:
    """Pseudo-inverse of N − αE on the observable subspace; α is the largest of 1, 1/2,
    1/4, ... keeping every (Jacobi-scaled) observable eigenvalue above 20% of N's smallest.
    ``N_scale``: the normal matrix whose diagonal scales the parameters (``sol["unobs"]`` is in
    its scaled coordinates; None: N's own)."""
    d = np.diag(N if N_scale is None else N_scale)
    live = d > max(float(d.max()), 1e-300) * 1e-14
    s = np.where(live, 1.0 / np.sqrt(np.where(live, d, 1.0)), 0.0)
    U = sol["unobs"]                                   # (k, 6) in scaled coordinates
    P = np.eye(6) - (U.T @ U if len(U) else 0.0)       # projector on the observable part
    Ns = P @ (N * s[:, None] * s[None, :]) @ P
    Es = P @ (E * s[:, None] * s[None, :]) @ P
    n_obs = 6 - len(U)
    if n_obs == 0:
        return sol["N_pinv"]
    floor = 0.2 * np.linalg.eigvalsh(Ns)[-n_obs:].min()
    alpha = 1.0
    for _ in range(12):
        ev, vec = np.linalg.eigh(Ns - alpha * Es)
        if ev[-n_obs:].min() >= floor:
            break
        alpha *= 0.5
    else:
        return sol["N_pinv"]
    inv = np.zeros(6)
    inv[-n_obs:] = 1.0 / ev[-n_obs:]
    return ((vec * inv) @ vec.T) * s[:, None] * s[None, :]


def _result(index, M, diag, opts: MotionOptions, n_solves: int, few_views: str = "",
            noise_sigma: float = math.nan, level_change: np.ndarray | None = None,
            M_start: np.ndarray | None = None, parallax: ParallaxSignal | None = None) -> PairResult:
    """The :class:`PairResult` of the final solve ``diag`` at estimate ``M``; ``level_change``:
    (6,) its (t, r) minus the coarser level's (None: one level). When the final solve had
    fewer than ``opts.min_rays`` usable rays, the estimate carries no information (the warp
    by the coarser levels' estimate may have moved every ray off the grid): the result's
    motion is then ``M_start``, the estimate the solve started from (``T_init``), if given."""
    sol, (C_sand, C_iid, sigma2), H = diag
    num = sol["num"]
    if num < opts.min_rays and M_start is not None:
        M = M_start
    base_n = sol["base_n"]
    inl = sol["inliers"] / base_n if (sol["inliers"] is not None and base_n) else (1.0 if base_n else 0.0)
    # map the increment covariance to the rig's (t, r): M = H exp(−δ) H = M · exp(Ad(H⁻¹)(−δ))
    # (one-sided warping: H = M_e, M = exp(−δ) M_e = M · exp(Ad(M⁻¹)(−δ)))
    J = ray_to_rig_jacobian(M, H if opts.symmetric else None)
    cov_noise = J @ C_sand @ J.T
    cov_iid = J @ C_iid @ J.T
    # the model error the residuals cannot show (at the fixed point they are orthogonal to the
    # regressors, so a regressor error coherent over the image moves the estimate unseen): the
    # coarser level sees the scene through other filters and aliasing, and how far the finest level
    # moved its estimate measures that error's size (and includes the coarser level's own noise)
    change = np.full(6, np.nan) if level_change is None else np.asarray(level_change, float)
    cov = cov_noise + (np.outer(change, change) if np.all(np.isfinite(change)) else 0.0)
    unobs_vecs = sol["unobs"]
    texture = sol["texture"]
    flat = np.zeros((0, 3)) if parallax is None else parallax.below(opts.parallax_min)
    if len(flat):
        # translation directions without parallax above the noise (the rig's t and the ray motion's
        # differ by a rotation and a sign: any such direction makes the whole t block infinite below);
        # the estimate is kept as least squares gave it (a fit of the noise where there is no parallax
        # at all, still near the truth where a weak one drowns in strong noise)
        unobs_vecs = np.concatenate([unobs_vecs, np.hstack([flat, np.zeros((len(flat), 3))])])
    if texture < _TEXTURE_FLOOR:
        unobs_vecs = np.eye(6)
    if len(unobs_vecs):
        # parameters touching the unobservable subspace get infinite variance
        # (J maps parameters one to one up to a rotation within t and within ω)
        touched = np.sum(unobs_vecs ** 2, axis=0) > 0.01
        touched = touched | np.concatenate([[touched[:3].any()] * 3, [touched[3:].any()] * 3])
        for C in (cov, cov_noise, cov_iid):
            C[touched, :] = 0.0
            C[:, touched] = 0.0
            C[touched, touched] = np.inf
    names = tuple(_name_direction(v) for v in unobs_vecs)
    if len(flat) == 3 and len(flat) == len(names):
        names = PARAM_NAMES[:3]                # the whole translation (the three span it)
    reason = ""
    if num < opts.min_rays:
        reason = (f"only {num} usable rays (need {opts.min_rays}): "
                  + (few_views if few_views else "too little texture or valid data"))
    elif texture < _TEXTURE_FLOOR:
        reason = (f"unobservable: no texture (RMS gradient {texture:.2g} per sample); "
                  "all of " + ", ".join(names))
    elif len(flat) and len(flat) == len(names):
        reason = (f"unobservable: {', '.join(names)}: no parallax above the noise (signal fraction "
                  f"{float(np.nanmin(parallax.fraction)):.2f} < {opts.parallax_min:g}: the translation columns are "
                  "mostly noise)")
    elif names:
        reason = "unobservable: " + ", ".join(names)
    elif not np.all(np.isfinite(M)):
        reason = "the solution diverged"
    if reason:
        log.warning("pair %d: %s", index, reason)
    return PairResult(index=index, T_prev_next=M, covariance=cov, covariance_noise=cov_noise, covariance_iid=cov_iid,
                      sigma=math.sqrt(sigma2), condition=sol["cond"], inlier_fraction=inl,
                      num_rays=num, iterations=n_solves, unobservable=names,
                      unobservable_directions=unobs_vecs, reason=reason, noise_sigma=noise_sigma,
                      level_change=change,
                      parallax_fraction=np.full(3, np.nan) if parallax is None else parallax.fraction)


def estimate_trajectory(store, *, progress: Callable[[int, int], None] | None = None,
                        options: MotionOptions | None = None, constant_velocity: bool = True,
                        scale_selection: bool = False,
                        **option_overrides) -> tuple[Trajectory, list[PairResult]]:
    """Egomotion of every consecutive frame pair of a light-field store, integrated.

    ``store`` provides ``grid``, ``timestamps_ns`` (T,), ``frame(i)`` → (F, Ny, Nx, Nv, Nu)
    (optionally with a colour axis) and ``weights(i)`` → same dims or None. Frames are
    read one at a time (two in memory). ``progress(done, total)`` is called after each
    pair. ``constant_velocity`` starts each pair from the previous pair's estimate.
    ``scale_selection``: pre-smooth (u, v) at the scale of paper Sect. 4.1
    (:class:`polycam.scales.ScaleTracker`: chosen where the four depth estimates agree,
    capped by the disparity per view step; for grids whose views are far apart for the
    scene, e.g. one view per camera of a 2 cm array in a room).
    Returns the trajectory (``T_world_rig``, world = rig at the first frame) and the
    per-pair results (falsy ones failed; their motion, :class:`PairResult`'s ``T_prev_next``, is
    still integrated).
    """
    opts = options or MotionOptions()
    if option_overrides:
        opts = replace(opts, **option_overrides)
    grid = store.grid
    ts = np.asarray(store.timestamps_ns, dtype=np.int64)
    n = int(ts.shape[0])
    if n < 2:
        raise InputError(f"motion: the light field has {n} frame(s); need at least 2")
    get_w = getattr(store, "weights", None)
    W_prev = get_w(0) if get_w else None
    L_prev = store.frame(0)
    results: list[PairResult] = []
    T_init = None
    estimate = estimate_motion
    if scale_selection:
        from .scales import ScaleTracker

        tracker = ScaleTracker(grid)

        def estimate(L0, L1, grid, **kw):
            return tracker.estimate(L0, L1, **kw)
    for i in range(n - 1):
        L_next = store.frame(i + 1)
        W_next = get_w(i + 1) if get_w else None
        res = estimate(L_prev, L_next, grid, W0=W_prev, W1=W_next, T_init=T_init, options=opts, index=i)
        results.append(res)
        if constant_velocity and res.ok:
            T_init = res.T_prev_next
        L_prev, W_prev = L_next, W_next
        if progress is not None:
            progress(i + 1, n - 1)
    traj = Trajectory.from_relative(ts, np.stack([r.T_prev_next for r in results]))
    return traj, results
