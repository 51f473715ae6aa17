"""Plenoptic motion under image noise against the Cramér–Rao bound of the linear model (issue #3, target 2).

Run: ``.venv/bin/python benchmarks/bench_noise.py [--quick] [--draws N] [--sigmas ...] [--before]
[--variants] [--probe] [--antithetic] [--seed N ...]``

Set-up (paper Sect. 5, as benchmarks/bench_motion.py): unit spheres filling the
horizon at D = 8 m, f = 60, 9 x 9 viewpoints 1 cm apart, 64 x 64 directions per face
(8 x 8 rays averaged per sample: :data:`SUPERSAMPLE`), one motion |t| = 1.5 cm, |ω| = 0.2 deg (seeded),
on all six faces and on the ``+z`` face alone. Both frames get independent white
Gaussian noise of σ = 0, 0.5, 1, 2, 4, 8, 16, 32 grey levels (of 255) per light-field
sample (float, not quantised); several seeded draws per level, always the same motion.
The high levels are where the noise-free error (model bias, the σ = 0 row) is small
next to the bound; ``--high-noise`` adds the same table for the noise options measured
best together (``smooth_c=0, eiv=True, whiten="on", model_weight=True, model_weight_gain=8,
uv_taps=14, depth_pool_views=True``: no discontinuity weight, errors-in-variables steps,
whitened re-solves, the model-validity weight with the model error weighed 8x its energy,
14-point Lagrange in the warp's (u, v), the Eq. 6 regressors' ρ̂ pooled over the views),
measured in the same run; ``--option KEY=VALUE`` changes a solver option in both tables.

Table per level: RMS over the draws of the vector error |t̂ − t| and |ω̂ − ω| (nothing
removed; the noise-free error, i.e. the bias, is the σ = 0 row), the bound (sqrt of
the trace of the CRB blocks below: the RMS vector error an efficient unbiased
estimator reaches), and the ratio measured / bound (goal ≤ 1.5). Further columns
give the noise-only ratio (RMS of the deviation from the draws' mean / bound), the draws'
mean error / bound (the bias under noise, which can exceed the σ = 0 row's: model error
that the robust weights discard on noise-free frames, docs/motion_log.md, "Noise" →
Session 19; the mean of n draws also carries noise-only / √n), ``6-D``: the RMS error in
the bound's own metric, sqrt(mean eᵀ CRB⁻¹ e / 6) over the six parameters (:func:`efficiency_6d`;
1 for an efficient unbiased estimator; it weights every direction of (t, ω) by its own bound,
the per-block ratios weight the worst-determined ones most; the goal is judged on the
per-block ratios), and the
σ predicted for the solver's own weighted estimator by :func:`polycam.design.predict_pair`
(which knows the discontinuity and Tukey weights but not the errors-in-variables step,
the noise-aware weight or the whitening); ``GLS`` counts the estimates in which
``whiten="auto"`` took the whitened (generalised least squares) re-solves (``on`` / ``off``: the
option forces them in every estimate / in none).
``--variants`` repeats the measurement for several :class:`MotionOptions` (since session 4
the defaults include ``depth_regressors=True``; the variants other than the explicit
``depth_regressors=False`` row do too); ``--probe`` (``--probe-only``) decomposes the
linearised estimator at the true motion (:func:`linear_probe`): which part of the gap to the
bound an estimator with noise-free regressors (oracle) would still have on the rays the warp
keeps, with plain or whitened least squares, against the measured and the Eq. 6 regressors.
``--frontier`` (``--frontier-only``) fits the bound's own linear model (its rays, its noise-free
regressors, no warp) by least squares whitened with each floor of :data:`FRONTIER_FLOORS`, down to
the exact whitening whose covariance the bound is: the noise and the bias of each, computed exactly
(:func:`gls_frontier`): how close to the bound any fit of the model can come on the frames.
``--oracle-depth`` (a diagnostic) gives the solver the scene's true disparity in place of its
estimate ρ̂ (:class:`OracleDepth`): the same rays get Eq. 6 regressors, ``ρ L_u, ρ L_v`` with
the ray tracer's ρ, so the table shows what any better ρ̂ could still gain.
``--supersample`` sets the rays the renderer averages per sample (k x k; default
:data:`SUPERSAMPLE`); ``--quadrature`` adds the noise-free error with and without the robust and
model-validity weights on the frames of k x k and 2k x 2k rays (:func:`quadrature_table`): model
error of the frames themselves, which the weights remove without noise but let in under it, shows
as an unweighted error that falls with the rays per sample (sharper lenses need more rays:
docs/motion.md, "Noise against the Cramér–Rao bound").
``--antithetic`` draws the noise in pairs n, −n (:func:`errors`): the same kind of draws, but the
draws' mean, the bias under noise, is measured several times more precisely. The ``90 %``
columns give each ratio's percentile bootstrap interval over the draws (antithetic pairs
resampled as units: :func:`ratio_interval`): how far another set of as many draws may put it.
``--seed`` picks the draw set (default 17, that of the documented tables); several seeds pool their
draws (``--draws`` each) and the ``per set`` column gives the smallest and largest ratio of the sets
alone (:func:`set_ratios`): the bootstrap interval of one set knows only the tails that set drew, and
understates the spread between sets (docs/motion.md, "How sure the ratios are").
``--scene room`` replaces the spheres by the mock rig's textured room (far wall at
``--distance``; a diagnostic: at this grid's 64 directions per 90° its near walls put texture
near the directions' Nyquist limit, docs/motion_log.md, "Noise" → Session 19).

The bound (derivation)
----------------------
The linear model is paper Eq. 5 applied to the two frames as given (no warp):
for every ray ρ in the set V of rays whose derivative filters lie inside the grid,

    y(ρ) = −L_t(ρ) = a(ρ)ᵀ p + e(ρ),

p = (t, ω) of the ray motion G = M⁻¹ in rig coordinates (M = T_rig0_rig1), a(ρ) the
Eq. 5 row built from the noise-free derivatives (L_x, L_y, L_u, L_v) of the frame
pair (:func:`polycam.motion.ray_motion_coefficients`; derivatives at the pair's
temporal midpoint, i.e. at the true motion), and e the noise of the data term. The
solver's L_t is the fully prefiltered difference, L_t = K (L1 − L0), with
K = K_y ⊗ K_x ⊗ K_v ⊗ K_u the separable prefilters of the differentiated axes
(fs3 on x, y; fs5 on u, v: MotionOptions().filters). With image noise n0, n1 i.i.d.
N(0, σ²) per sample, e = K (n1 − n0) is Gaussian with covariance

    Σ = 2 σ² K_V K_Vᵀ = 2 σ² ⊗_axes (K_a K_aᵀ),

K_a the (n_a − 2 r_a) x n_a Toeplitz matrix of axis a restricted to its interior rows
(V is a product of per-axis interiors, so no border clamping enters and Σ keeps the
Kronecker form; an axis that is not differentiated is not filtered: identity). For a
linear Gaussian model with known a the Fisher information is

    I = Σ_faces Aᵀ Σ⁻¹ A = (1 / 2σ²) Σ_faces Aᵀ (⊗_a (K_a K_aᵀ)⁻¹) A,

applied axis by axis (the K_a K_aᵀ are at most 64 x 64), and Cov(p̂) ≥ I⁻¹ for any
unbiased estimator from y (Cramér–Rao). I⁻¹ is mapped to the rig motion's (t, r)
(``T_prev_next = [R_from_r(r) | t]``) with the Jacobian of p ↦ (t, r)(exp(p)⁻¹) at the
true p (numerical). Noise in a is not a reason for a larger bound: with the light field
itself an unknown nuisance (observed in both frames, frame 2 its moved copy), the Fisher
information of the motion is, to first order, that of the difference of the frames with
noise-free regressors — per spatial frequency the nuisance direction (1, 1) is projected
out of (0, ∂/∂p), which halves the information whatever the motion size when the motion
maps rays to rays — i.e. exactly the 2σ² above. An estimator that takes its regressors
from the noisy frames loses efficiency (an instrumental-variables estimator with noisy
instruments), but that is the estimator's loss, not the bound's. Left out, deliberately:
noise in a (errors in variables — the
solver's derivatives are noisy, which biases it towards zero at high noise), the
warp (the solver interpolates frame 2 at the moved rays, which smooths its noise and
loses rays that leave the grid) and model error (the first-order model is not exact
for a 1.5-view motion: the solver iterates; the bound is for the linearised model).
Because Σ⁻¹ undoes the prefilters, the bound is that of a *whitened* (generalised)
least-squares fit: an estimator that weights the data by the inverse noise
covariance (``MotionOptions(whiten="on", whiten_floor=0)`` is that estimator; the
default floor regularises it, see docs/motion_log.md, "Noise"). Also shown: ``OLS`` = the exact covariance of plain unweighted least
squares on the same rays, N⁻¹ (Aᵀ Σ A) N⁻¹ with N = AᵀA (what the solver's
normal equations give without robust weights, warps or bias).
"""

from __future__ import annotations

import argparse
import contextlib
import logging
import math
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

import dataclasses  # noqa: E402

from polycam.derivatives import FILTERS, plenoptic_derivatives  # noqa: E402
from polycam.eq5 import depth_regularise  # noqa: E402
from polycam.errors import InputError  # noqa: E402
from polycam.design import RigSampling, Source, predict_pair  # noqa: E402
from polycam.geometry import R_from_r, T_from_Rt, T_inverse, rt_from_T  # noqa: E402
from polycam.motion import MotionOptions, estimate_motion, ray_motion_coefficients, warp_lightfield  # noqa: E402
from polycam.motion_options import NOISY, describe_options, options_from_strings  # noqa: E402
from polycam.synth import LightFieldRenderer, default_lightfield_grid  # noqa: E402
from polycam.synth.scenes import make_scene  # noqa: E402
from polycam.synth.raycast import trace_outer  # noqa: E402
from polycam.synth.render import lightfield_face_rays  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_motion import params, random_motion  # noqa: E402  (the same motions and (t, ω) order)

SIGMAS = (0.0, 0.5, 1.0, 2.0, 4.0, 8.0, 16.0, 32.0)
"""Noise levels [grey levels of 255]."""
SUPERSAMPLE = 8
"""Rays the renderer averages per sample, k x k (the pixel's area integral, by quadrature). A
camera integrates over the pixel exactly; with few rays the quadrature error at the spheres'
silhouettes and in their texture is model error of the frames themselves, which no estimator
removes: warped by the true motion, the 8 m pair's prefiltered difference is 0.27 / 0.14 /
0.074 / 0.052 / 0.045 grey levels RMS near depth jumps with k = 3 / 5 / 8 / 12 / 16 (0.20 /
0.10 / 0.054 / 0.042 / 0.038 elsewhere; the noise's at σ = 1 is 0.18), and plain least
squares with Eq. 6 instruments on it is off by 16 / 3.7 / 1.1 / 0.1 / 0.3 bounds (σ = 1)
along t (docs/motion_log.md, Session 23). k = 8 (19 s to render the pair) brings the
quadrature error below half the noise of one grey level; until session 22 it was 3."""

AXES = ("y", "x", "v", "u")
"""Order of the per-face array axes (F, Ny, Nx, Nv, Nu) after the face."""


# ---------------------------------------------------------------------------- the bound


def _toeplitz_rows(taps: np.ndarray, n: int) -> np.ndarray:
    """(n − 2r, n) correlation matrix of ``taps`` (2r+1,) for the interior outputs r..n−r−1."""
    r = len(taps) // 2
    K = np.zeros((n - 2 * r, n))
    for i in range(n - 2 * r):
        K[i, i:i + 2 * r + 1] = taps
    return K


def _axis_filters(der, grid, filters: dict) -> dict:
    """Axis → (interior slice, K_a K_aᵀ) of the prefilter the solver applies along it."""
    counts = {"x": grid.x.count, "y": grid.y.count, "u": grid.u.count, "v": grid.v.count}
    out = {}
    for a in AXES:
        n = counts[a]
        if der.differentiated[a]:
            fp = FILTERS[filters[a]]
            K = _toeplitz_rows(np.asarray(fp.prefilter, float), n)
            out[a] = (slice(fp.radius, n - fp.radius), K @ K.T)
        else:
            out[a] = (slice(0, n), np.eye(n))
    return out


def _apply_axes(X: np.ndarray, mats: list[np.ndarray], inverse: bool) -> np.ndarray:
    """Apply the per-axis matrices (or their inverses) to axes 0..3 of X (Ny, Nx, Nv, Nu, 6)."""
    out = X
    for ax, M in enumerate(mats):
        out = np.moveaxis(out, ax, 0)
        sh = out.shape
        flat = out.reshape(sh[0], -1)
        flat = np.linalg.solve(M, flat) if inverse else M @ flat
        out = np.moveaxis(flat.reshape(sh), 0, ax)
    return out


def _ray_to_rig(p_true: np.ndarray) -> np.ndarray:
    """(6, 6) Jacobian of p ↦ (t, r) of exp(p)⁻¹ at p_true (p = (t, ω) of the ray motion)."""
    def f(p):
        rt = rt_from_T(T_inverse(T_from_Rt(R_from_r(p[3:]), p[:3])))
        return np.concatenate([rt[3:], rt[:3]])
    J = np.zeros((6, 6))
    h = 1e-7
    for j in range(6):
        e = np.zeros(6)
        e[j] = h
        J[:, j] = (f(p_true + e) - f(p_true - e)) / (2 * h)
    return J


def true_disparity(scene, grid) -> np.ndarray:
    """(F, Ny, Nx, Nv, Nu) float32: the true ρ of Eq. 6 (``L_x = ρ L_u``, u per unit of x) of
    each sample's centre ray at the identity pose: ``ρ = f / Z = |(u, v, f)| / distance``,
    Z the depth along the face's z axis, distance along the unit ray (0 for the sky)."""
    F, Ny, Nx, Nv, Nu = grid.shape
    out = np.empty(grid.shape, np.float32)
    for k in range(F):
        o, d = lightfield_face_rays(grid, k, 1)
        dist = trace_outer(scene, o, d, np.eye(4)).distance.reshape(Ny, Nx, Nv, Nu)
        norm = np.linalg.norm(d[:, 0], axis=-1).reshape(Nv, Nu)
        out[k] = np.where(np.isfinite(dist), norm / dist, 0.0)
    return out


class OracleDepth:
    """Context manager (a diagnostic, ``--oracle-depth``): while active, the solver's Eq. 6
    regressors use the true disparity ``rho_true`` (from :func:`true_disparity`) instead of
    its estimate ρ̂, on the rays where the solver replaces the measured ``L_x, L_y`` (its keep /
    replace decisions and noise bookkeeping are unchanged, so ``eiv=True`` over-corrects
    here). It wraps ``polycam.motion.depth_rho`` at the finest level (the grid's shape)."""

    def __init__(self, rho_true: np.ndarray):
        self.rho_true = rho_true

    def __enter__(self):
        import polycam.motion as pm
        from polycam.eq5 import _rho_store, rho_values

        self._pm, self._orig = pm, pm.depth_rho
        rho_true, orig = self.rho_true, self._orig

        def depth_rho(der, base, box, var, out, *args, **kw):
            res = orig(der, base, box, var, out, *args, **kw)
            # the solver's ρ̂ holds the valid box's views only (view origin vo: polycam.eq5)
            vo = kw.get("vo", args[3] if len(args) > 3 else None)
            truth = rho_true if vo is None else rho_true[:, vo[0]:vo[0] + out.shape[1], vo[1]:vo[1] + out.shape[2]]
            if out.shape == truth.shape:
                # the solver's ρ̂ is int16 in units of a scale per view image (out_scale)
                packed = out.dtype == np.int16
                vals = rho_values(out, kw["out_scale"]) if packed else out
                use = np.isfinite(vals)
                vals[use] = truth[use]
                if packed:
                    _rho_store(vals, out, kw["out_scale"], box)
            return res

        pm.depth_rho = depth_rho
        return self

    def __exit__(self, *exc):
        self._pm.depth_rho = self._orig
        return False


def linear_model_bounds(L0: np.ndarray, L1: np.ndarray, grid, M: np.ndarray,
                        filters: dict) -> tuple[np.ndarray, np.ndarray]:
    """(CRB, OLS) (6, 6) covariances of the rig motion's (t, r) per unit noise variance σ² = 1
    (module docstring). L0, L1: noise-free (F, Ny, Nx, Nv, Nu) frames; M: true T_rig0_rig1."""
    der = plenoptic_derivatives(L0, L1, grid, filters=filters)
    spec = _axis_filters(der, grid, filters)
    sl = tuple(spec[a][0] for a in AXES)
    mats = [spec[a][1] for a in AXES]
    info = np.zeros((6, 6))
    N = np.zeros((6, 6))
    meat = np.zeros((6, 6))
    for k in range(len(grid.faces)):
        A = ray_motion_coefficients(der, grid, k)[sl]                   # (ny, nx, nv, nu, 6) on V
        A2 = A.reshape(-1, 6)
        info += A2.T @ _apply_axes(A, mats, inverse=True).reshape(-1, 6) / 2.0
        N += A2.T @ A2
        meat += 2.0 * A2.T @ _apply_axes(A, mats, inverse=False).reshape(-1, 6)
    G = T_inverse(M)
    rt = rt_from_T(G)
    J = _ray_to_rig(np.concatenate([rt[3:], rt[:3]]))
    crb = J @ np.linalg.inv(info) @ J.T
    Ni = np.linalg.inv(N)
    ols = J @ (Ni @ meat @ Ni) @ J.T
    return 0.5 * (crb + crb.T), 0.5 * (ols + ols.T)


def raw_sample_bounds(faces: str, D: float, supersample: int, directions: int,
                      M: np.ndarray, blur: float = 0.0, scene: str = "spheres") -> tuple[np.ndarray, np.ndarray]:
    """(6, 6) CRBs (over the samples of the filtered model's ray set V, over all samples) of the rig motion's (t, r) per unit σ² from the *raw* samples, no filters:
    ``2 (Jᵀ J)⁻¹`` with J (n_samples, 6) the exact Jacobian of frame 2's samples with respect to
    (t, r) at the true motion (central differences of the renderer: 1 mm, 0.1 mrad steps), the
    factor 2 for the noise of both frames (the first-order bound with the scene unknown: for a
    motion that maps rays to rays the nuisance costs exactly that factor). A reference for how much the filtered
    linear model (:func:`linear_model_bounds`) already leaves to the estimator: the
    high-frequency content of the raw samples that the derivative filters cannot use."""
    grid = default_lightfield_grid(faces, directions=directions)
    ren = LightFieldRenderer(make_scene(scene, D, seed=0), grid, supersample, psf=blur)
    q = np.concatenate([M[:3, 3], rt_from_T(M)[:3]])
    steps = (1e-3,) * 3 + (1e-4,) * 3
    cols = []
    for i, h in enumerate(steps):
        e = np.zeros(6)
        e[i] = h
        a, b = (ren.render(T_from_Rt(R_from_r(qq[3:]), qq[:3])).astype(np.float64) for qq in (q + e, q - e))
        d = (a - b) / (2 * h)
        cols.append(d)
    out = []
    for sl in ((slice(None), slice(1, -1), slice(1, -1), slice(2, -2), slice(2, -2)), (slice(None),) * 5):
        J = np.stack([c[sl].reshape(-1) for c in cols], axis=1)
        out.append(2.0 * np.linalg.inv(J.T @ J))
    return out[0], out[1]


def regressor_snr(L0: np.ndarray, L1: np.ndarray, grid, filters: dict, seed: int = 3) -> dict:
    """Axis → RMS of the noise-free derivative / RMS of the derivative of pure noise of
    σ = 1 grey level (the noise part scales with σ), over the valid rays: the signal-to-noise
    ratio of the regressors of Eq. 5 (the bound treats them as noise-free)."""
    rng = np.random.default_rng(seed)
    der = plenoptic_derivatives(L0, L1, grid, filters=filters)
    n = [rng.normal(0.0, 1.0 / 255.0, L0.shape).astype(np.float32) for _ in range(2)]
    dn = plenoptic_derivatives(n[0], n[1], grid, filters=filters)
    v = np.broadcast_to(der.valid, L0.shape)
    out = {}
    for name in ("Lx", "Ly", "Lu", "Lv"):
        a, b = getattr(der, name)[v], getattr(dn, name)[v]
        out[name] = float(np.sqrt(np.mean(a.astype(np.float64) ** 2) / np.mean(b.astype(np.float64) ** 2)))
    return out


def identity_sampling(grid) -> RigSampling:
    """A :class:`RigSampling` with one source per grid viewpoint (every sample observed directly)."""
    F, Ny, Nx, Nv, Nu = grid.shape
    sources = tuple(Source(camera=f"{k}:{jy}:{ix}", face=k, jy=jy, ix=ix, binning=1.0)
                    for k in range(F) for jy in range(Ny) for ix in range(Nx))
    return RigSampling(grid=grid, sources=sources, P=tuple(np.eye(Ny * Nx) for _ in range(F)),
                       masks=np.ones((len(sources), Nv, Nu), bool), W=np.ones(grid.shape, np.float32),
                       spacing=float(grid.x.step))


# ---------------------------------------------------------------------------- measurement


class _WhitenCount(logging.Handler):
    """Counts the solver's ``whiten="auto"`` decisions (its debug log) per estimate."""

    def __init__(self):
        super().__init__(logging.DEBUG)
        self.on = 0

    def emit(self, record):
        if record.msg.startswith("whiten:") and record.args and record.args[-1] == "on":
            self.on += 1


def errors(L0, L1, grid, M, sigma: float, draws: int, opts: MotionOptions, seed: int,
           counter: _WhitenCount | None = None, antithetic: bool = False) -> np.ndarray:
    """(draws, 6) estimated − true (t, r) for noise σ [0, 1 units]; ``counter`` counts the
    estimates that took the whitened (GLS) re-solves. ``antithetic``: the draws come in
    pairs, noise n then −n (each draw is still white Gaussian noise, so RMS errors keep their
    meaning; the pair's mean cancels every odd order of the noise, so the draws' mean, the
    bias under noise, is known far better than from independent draws: at 4 m, σ = 8, 48
    draws, ±0.07 instead of ±0.22 bounds)."""
    rng = np.random.default_rng([seed, int(round(sigma * 1e6))])
    out = []
    lg = logging.getLogger("polycam.motion")
    if counter is not None:
        lg.addHandler(counter)
        old_level = lg.level
        lg.setLevel(logging.DEBUG)
    try:
        n0 = n1 = None
        for k in range(draws if sigma > 0 else 1):
            if sigma > 0 and not (antithetic and k % 2):
                n0, n1 = rng.normal(0.0, sigma, L0.shape), rng.normal(0.0, sigma, L1.shape)
            elif sigma > 0:
                n0, n1 = -n0, -n1
            a = (L0 + n0).astype(np.float32) if sigma > 0 else L0
            b = (L1 + n1).astype(np.float32) if sigma > 0 else L1
            res = estimate_motion(a, b, grid, options=opts)
            out.append(params(res.T_prev_next) - params(M))
    finally:
        if counter is not None:
            lg.removeHandler(counter)
            lg.setLevel(old_level)
    return np.array(out)


def efficiency_6d(e: np.ndarray, crb: np.ndarray) -> float:
    """sqrt(mean eᵀ CRB⁻¹ e / 6) of the (draws, 6) errors e (t, r) against the (6, 6) bound: the
    RMS error in the bound's own metric, every direction of (t, ω) weighted by its bound (1 for
    an efficient unbiased estimator, whatever the units; unlike the per-block ratios, which
    sqrt(trace) weights towards the worst-determined directions)."""
    q = np.einsum("ni,ij,nj->n", e, np.linalg.inv(crb), e)
    return float(np.sqrt(np.mean(q) / crb.shape[0]))


def rms_norm(e: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.sum(e * e, axis=-1))))


BOOT_RESAMPLES = 2000
"""Resamples of :func:`ratio_interval`'s bootstrap."""


def ratio_interval(e: np.ndarray, bound: float, antithetic: bool, level: float = 0.9,
                   seed: int = 11) -> tuple[float, float]:
    """The ``level`` (two-sided) percentile bootstrap interval of rms_norm(e) / bound, e (draws, 3)
    the errors of one block (t or ω): the spread a ratio from this many draws has from one draw
    set to the next. The draws are resampled whole, antithetic pairs (n, −n) as one unit (their
    errors are not independent)."""
    n = len(e)
    units = e.reshape(n // 2, 2, -1) if antithetic and n % 2 == 0 else e.reshape(n, 1, -1)
    rng = np.random.default_rng(seed)
    idx = rng.integers(0, len(units), size=(BOOT_RESAMPLES, len(units)))
    sq = np.sum(units * units, axis=-1).mean(axis=1)          # (units,) mean squared norm per unit
    r = np.sqrt(sq[idx].mean(axis=1)) / bound
    lo, hi = np.quantile(r, [(1 - level) / 2, (1 + level) / 2])
    return float(lo), float(hi)


def setup(faces: str, D: float, supersample: int, directions: int, blur: float = 0.0,
          motion_scale: float = 1.0, oracle: bool = False, scene: str = "spheres"):
    """(grid, L0, L1, M): the noise-free frame pair of the set-up. ``blur``: std [samples] of a
    Gaussian optics point-spread function along u and v of every view, applied before the pixel
    integration as a lens does (:class:`~polycam.synth.render.LightFieldRenderer`'s ``psf``; 0:
    the renderer's pixel averaging only); ``motion_scale``: multiplies the motion (|t| = 1.5 cm,
    |ω| = 0.2° at 1); ``oracle``: also return the true disparity (:func:`true_disparity`) as a
    fifth item; ``scene``: a :func:`polycam.synth.scenes.make_scene` name (``spheres``: the
    paper's; ``room``: the mock rig's textured room, far wall at D, objects 1–4 m away)."""
    grid = default_lightfield_grid(faces, directions=directions)
    scene = make_scene(scene, D, seed=0)
    ren = LightFieldRenderer(scene, grid, supersample, psf=blur)
    M = random_motion(np.random.default_rng(8000), 0.015 * motion_scale, math.radians(0.2) * motion_scale)
    out = grid, ren.render(np.eye(4)), ren.render(M), M
    return out + (true_disparity(scene, grid),) if oracle else out


def set_ratios(e: np.ndarray, b_t: float, b_w: float, n_sets: int) -> str:
    """'lo–hi, lo–hi': the smallest and largest ratio t, ω over the ``n_sets`` equal draw sets
    that the (draws, 6) errors ``e`` concatenate ('–' for one set): how far one set's ratio
    strays from the pooled one."""
    if n_sets < 2:
        return "–"
    sets = e.reshape(n_sets, -1, 6)
    t = [rms_norm(x[:, :3]) / b_t for x in sets]
    w = [rms_norm(x[:, 3:]) / b_w for x in sets]
    return f"{min(t):.2f}–{max(t):.2f}, {min(w):.2f}–{max(w):.2f}"


def noise_table(name: str, grid, L0, L1, M, sigmas, draws: int, opts: MotionOptions,
                predict: bool, antithetic: bool = False, seed: int | tuple[int, ...] = 17) -> list[dict]:
    """Print and return the table of measured errors against the bound, one row per noise level
    in ``sigmas``; ``seed`` one draw set or several, whose draws are pooled (``draws`` each)."""
    seeds = (seed,) if isinstance(seed, int) else tuple(seed)
    filters = opts.filters if isinstance(opts.filters, dict) else {k: opts.filters for k in "xyuv"}
    crb1, ols1 = linear_model_bounds(L0, L1, grid, M, filters)
    sampling = identity_sampling(grid) if predict else None
    n_src = len(sampling.sources) if predict else 0
    F, Ny, Nx, Nv, Nu = grid.shape
    print(f"\n## {name}: {grid.shape} rays, |t| = {100 * np.linalg.norm(M[:3, 3]):.1f} cm, "
          f"|w| = {np.degrees(np.linalg.norm(rt_from_T(M)[:3])):.2f} deg, {draws} draws per level"
          f"{' (antithetic pairs)' if antithetic else ''}, draw set{'s' if len(seeds) > 1 else ''} "
          f"{', '.join(map(str, seeds))}{' (pooled)' if len(seeds) > 1 else ''}\n")
    print("| σ [grey] | RMS err t [mm] | CRB t [mm] | ratio t | 90 % t | noise-only t | RMS err ω [µrad] | "
          "CRB ω [µrad] | ratio ω | 90 % ω | noise-only ω | per set t, ω | mean / CRB t, ω | 6-D | OLS/CRB t, ω | "
          "solver σ t, ω (design) / CRB | GLS | time/est [s] |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    rows = []
    for s in sigmas:
        sig = s / 255.0
        t0 = time.perf_counter()
        counter = _WhitenCount()
        e = np.concatenate([errors(L0, L1, grid, M, sig, draws, opts, seed=sd, counter=counter, antithetic=antithetic)
                            for sd in (seeds if s > 0 else seeds[:1])])
        dt = (time.perf_counter() - t0) / len(e)
        gls = f"{counter.on}/{len(e)}" if opts.whiten == "auto" else opts.whiten     # "on": every estimate
        crb = crb1 * sig * sig
        ols = ols1 * sig * sig
        b_t = math.sqrt(np.trace(crb[:3, :3]))
        b_w = math.sqrt(np.trace(crb[3:, 3:]))
        m_t, m_w = rms_norm(e[:, :3]), rms_norm(e[:, 3:])
        mean = e.mean(axis=0)                  # the draws' mean error: bias, incl. what the noise brings
        dev = e - mean
        corr = math.sqrt(len(e) / (len(e) - 1)) if len(e) > 1 else math.nan
        n_t, n_w = rms_norm(dev[:, :3]) * corr, rms_norm(dev[:, 3:]) * corr
        a_t, a_w = float(np.linalg.norm(mean[:3])), float(np.linalg.norm(mean[3:]))
        six = efficiency_6d(e, crb) if s > 0 else math.nan
        pred = ""
        if predict and s > 0:
            src0 = L0.reshape(F * Ny * Nx, Nv, Nu)
            src1 = L1.reshape(F * Ny * Nx, Nv, Nu)
            pr = predict_pair(sampling, src0, src1, M, np.full(n_src, sig), options=opts,
                              rng=np.random.default_rng(5))
            pred = f"{pr.std_t / b_t:.2f}, {pr.std_w / b_w:.2f}"
        ci_t, ci_w = ((ratio_interval(e[:, sl], b, antithetic) if s > 0 and len(e) > 1 else (math.nan, math.nan))
                      for sl, b in ((slice(0, 3), b_t), (slice(3, 6), b_w)))
        row = dict(sigma=s, err_t=m_t, err_w=m_w, crb_t=b_t, crb_w=b_w, noise_t=n_t, noise_w=n_w, mean_t=a_t, mean_w=a_w,
                   six=six, ci_t=ci_t, ci_w=ci_w,
                   ols_t=math.sqrt(np.trace(ols[:3, :3])), ols_w=math.sqrt(np.trace(ols[3:, 3:])))
        rows.append(row)
        if s == 0:
            print(f"| 0 (bias) | {1e3 * m_t:.4f} | 0 | – | – | – | {1e6 * m_w:.3f} | 0 | – | – | – | – | – | – | – | – | {gls} | "
                  f"{dt:.1f} |", flush=True)
            continue
        print(f"| {s:g} | {1e3 * m_t:.4f} | {1e3 * b_t:.4f} | {m_t / b_t:.2f} | {ci_t[0]:.2f}–{ci_t[1]:.2f} | "
              f"{n_t / b_t:.2f} | {1e6 * m_w:.3f} | {1e6 * b_w:.3f} | {m_w / b_w:.2f} | {ci_w[0]:.2f}–{ci_w[1]:.2f} | "
              f"{n_w / b_w:.2f} | {set_ratios(e, b_t, b_w, len(seeds))} | {a_t / b_t:.2f}, {a_w / b_w:.2f} | {six:.2f} | "
              f"{row['ols_t'] / b_t:.2f}, {row['ols_w'] / b_w:.2f} | {pred or '–'} | {gls} | {dt:.1f} |", flush=True)
    snr = regressor_snr(L0, L1, grid, filters)
    print("\nregressor signal / noise RMS at σ = 1 grey level (divide by σ for other levels): "
          + ", ".join(f"{k} {v:.0f}" for k, v in snr.items()))
    worst = max((max(r["err_t"] / r["crb_t"], r["err_w"] / r["crb_w"]) for r in rows if r["sigma"] > 0),
                default=math.nan)
    upper = max((max(r["ci_t"][1], r["ci_w"][1]) for r in rows if r["sigma"] > 0), default=math.nan)
    print(f"\nworst measured / CRB ratio over σ > 0: {worst:.2f} (goal ≤ 1.5: {'met' if worst <= 1.5 else 'NOT met'}); "
          f"the largest upper end of the ratios' 90 % intervals (another draw set's spread): {upper:.2f}; "
          f"|t| = {1e3 * np.linalg.norm(M[:3, 3]):.1f} mm, |ω| = {1e6 * np.linalg.norm(rt_from_T(M)[:3]):.0f} µrad"
          + ("" if opts == NOISY else "; target 2 is judged on the noise options (--high-noise; docs/motion.md, "
             "\"Where issue #3's targets stand\")"))
    return rows


HIGH_NOISE = NOISY
"""The noise options (``polycam.motion_options.NOISY``; ``polycam motion --preset noisy``), measured
best together (with the default Eq. 6 positional regressors): no discontinuity weight (computed from
noisy frames it discards rays at random), errors-in-variables steps, whitened re-solves, and the
model-validity weight (docs/motion.md, "Noise"; until session 18 ``eiv=True, smooth_noise=True``,
which the blurred set-up measured worse for t; ``model_weight`` since session 21: the same from σ ≈
4 grey levels on, far less translation error below; ``model_weight_gain=8`` since session 22: the
largest ratio over the 4 m and 8 m scenes 2.31 against 2.53, the translation's at 8 m and 1–2 grey
levels 1.98 / 1.83 against 2.53 / 2.19; ``uv_taps=8`` since session 23: at 8 m the noise-free
rotation bias 1.78 → 0.39 µrad, ω at 1 grey level 1.64 → 1.35x its bound; ``depth_pool_views`` since
session 24: ρ̂ pooled over the views, at 32 grey levels the translation 1.74 → 1.36x at 8 m, 1.67 →
1.32x at 6 m; ``uv_taps=10`` since session 26: at the paper's full motion (8 m) the noise-free
rotation bias 2.6 → 1.1 µrad, ω at 1 grey level 1.62 → 1.23x; ``uv_taps=14`` since session 33: through
sharper lenses on 16 x 16-ray frames at 8 m and 1 grey level, ω 1.45 → 1.29x (PSF 0.5) and 1.79 → 1.42x
(PSF 0.3), PSF 0.8 unchanged)."""

VARIANTS = {
    "default": MotionOptions(),
    "smooth_noise": MotionOptions(smooth_noise=True),
    "eiv": MotionOptions(eiv=True),
    "eiv, smooth_noise": MotionOptions(eiv=True, smooth_noise=True),
    "eiv, smooth_noise, whiten=auto (floor 0.3)": MotionOptions(eiv=True, smooth_noise=True, whiten="auto"),
    "eiv, smooth_noise, whiten=on (floor 0.3)": MotionOptions(eiv=True, smooth_noise=True, whiten="on"),
    "eiv, smooth_noise, whiten=on, floor 0.1": MotionOptions(eiv=True, smooth_noise=True, whiten="on",
                                                             whiten_floor=0.1),
    "depth_regressors=False (the default before session 5)": MotionOptions(depth_regressors=False),
    "whiten=on, floor 0 (exact GLS)": MotionOptions(whiten="on", whiten_floor=0.0),
    "smooth_c=0": MotionOptions(smooth_c=0.0),
    "robust=none": MotionOptions(robust="none", irls_steps=0),
    "smooth_c=0, robust=none": MotionOptions(smooth_c=0.0, robust="none", irls_steps=0, whiten="off"),
    "filters=fs3": MotionOptions(filters="fs3"),
    "filters=fs3, smooth_c=0, robust=none": MotionOptions(filters="fs3", smooth_c=0.0, robust="none", irls_steps=0),
}


def variant_table(name: str, grid, L0, L1, M, sigmas, draws: int) -> None:
    crb1, _ = linear_model_bounds(L0, L1, grid, M, MotionOptions().filters)
    print(f"\n## {name}: MotionOptions variants, measured RMS error / CRB (t, ω) of the default "
          f"filters' linear model (noise-only part in brackets), {draws} draws\n")
    print("| options | " + " | ".join(f"σ = {s:g}" for s in sigmas) + " |")
    print("|---|" + "---|" * len(sigmas))
    for vname, opts in VARIANTS.items():
        cells = []
        for s in sigmas:
            sig = s / 255.0
            e = errors(L0, L1, grid, M, sig, draws, opts, seed=17)
            if s == 0:
                cells.append(f"bias {1e3 * rms_norm(e[:, :3]):.4f} mm, {1e6 * rms_norm(e[:, 3:]):.2f} µrad")
                continue
            crb = crb1 * sig * sig
            b_t, b_w = math.sqrt(np.trace(crb[:3, :3])), math.sqrt(np.trace(crb[3:, 3:]))
            dev = (e - e.mean(axis=0)) * (math.sqrt(len(e) / (len(e) - 1)) if len(e) > 1 else math.nan)
            cells.append(f"{rms_norm(e[:, :3]) / b_t:.2f}, {rms_norm(e[:, 3:]) / b_w:.2f} "
                         f"({rms_norm(dev[:, :3]) / b_t:.2f}, {rms_norm(dev[:, 3:]) / b_w:.2f})")
        print(f"| {vname} | " + " | ".join(cells) + " |", flush=True)


def quadrature_table(name: str, frames: list, opts: MotionOptions) -> None:
    """The frames' own model error against the renderer's quadrature: the noise-free error of the
    solver with ``opts`` and with the same options but no robust or model-validity weights, on the
    frame pairs ``frames`` ((rays per sample k, grid, L0, L1, M) each). Under noise the weights no
    longer single out model error smaller than the noise (docs/motion_log.md, Session 22), so the
    unweighted row is the bias that noise lets in; where it falls as k grows, it is the
    renderer's (k x k rays approximate the pixel's integral), not the solver's, and a camera,
    which integrates exactly, does not have it."""
    bare = dataclasses.replace(opts, robust="none", model_weight=False)
    print(f"\n## {name}: noise-free error against the rays per sample\n")
    print("| rays per sample | options | t [mm] | error t (x, y, z) [mm] | ω [µrad] |")
    print("|---|---|---|---|---|")
    for k, grid, L0, L1, M in frames:
        for label, o in (("as given", opts), ("no robust or model weights", bare)):
            e = errors(L0, L1, grid, M, 0.0, 1, o, 0)[0]
            print(f"| {k} x {k} | {label} | {1e3 * np.linalg.norm(e[:3]):.4f} | "
                  f"{', '.join(f'{1e3 * q:+.4f}' for q in e[:3])} | {1e6 * np.linalg.norm(e[3:]):.2f} |", flush=True)


# ---------------------------------------------------------------------------- linear probe


def _true_motion_mask(grid, ok: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """(F, Ny, Nx, Nv, Nu) float64 0/1: rays whose derivative filters see only samples that the
    warp by the true motion kept inside the grid (``ok``, eroded by the filter radii: 1 in x, y,
    2 in u, v), and that lie in the filters' interior (``valid``): the rays the solver can use."""
    okv = ok.astype(np.float32)
    for ax, r in ((1, 1), (2, 1), (3, 2), (4, 2)):
        okv = np.minimum(okv, np.minimum.reduce([np.roll(okv, d, axis=ax) for d in range(-r, r + 1)]))
    return (okv * valid).astype(np.float64)


FRONTIER_FLOORS = (None, 1.0, 0.3, 0.1, 0.03, 0.0)
"""Weightings of :func:`gls_frontier`: None = plain least squares, else whitened with this ridge; 0 is
the exact generalised least squares whose covariance the bound is."""


def gls_frontier(name: str, grid, L0, L1, M) -> None:
    """The bound's own linear model as an estimator: how far from the bound any fit of it can get.

    On the rays V of the bound, with the bound's noise-free regressors ``a`` (derivatives of the
    noise-free pair, no warp: the midpoint linearisation of :func:`linear_model_bounds`, exact to
    second order in the motion) and its data ``y = −L_t`` of the noise-free pair, the (whitened)
    least-squares estimate ``(Aᵀ W A)⁻¹ Aᵀ W y`` for W = ``(⊗ₐ(K_a K_aᵀ + floor I))⁻¹`` (None: I).
    Its error without noise is the bias (the linear model's error on these frames: silhouettes, the
    aliasing of the directions), its covariance under noise is exact (no draws):
    ``2σ² (AᵀWA)⁻¹ AᵀWΣ̃WA (AᵀWA)⁻¹`` with Σ̃ = ⊗ₐ K_a K_aᵀ; floor 0 is the estimator the bound is the
    covariance of (noise 1.00 by construction). Printed per floor: noise / CRB, bias / CRB at
    σ = 1 (the bias is fixed, so at σ it is bias / σ bounds) and the RMS error / CRB at σ = 1 and 4.
    Where the exact fit's bias is many bounds, the bound counts information the model cannot use
    on those frames (docs/motion.md, "Noise against the Cramér–Rao bound")."""
    filters = MotionOptions().filters
    crb, _ = linear_model_bounds(L0, L1, grid, M, filters)
    bt1, bw1 = math.sqrt(np.trace(crb[:3, :3])), math.sqrt(np.trace(crb[3:, 3:]))     # per unit σ
    der = plenoptic_derivatives(L0, L1, grid, filters=filters)
    spec = _axis_filters(der, grid, filters)
    sl = tuple(spec[a][0] for a in AXES)
    mats = [spec[a][1] for a in AXES]
    A = [ray_motion_coefficients(der, grid, k)[sl] for k in range(len(grid.faces))]
    y = [der.Lt[k][sl] for k in range(len(grid.faces))]
    rt = rt_from_T(T_inverse(M))
    p_true = np.concatenate([rt[3:], rt[:3]])
    J = _ray_to_rig(p_true)
    print(f"\n## {name}: the bound's linear model fitted by (whitened) least squares, no warp, noise-free "
          f"regressors (exact covariance, no draws); / CRB, t, ω\n")
    print("| weighting | noise | bias at σ = 1 | RMS error σ = 1 | σ = 4 |")
    print("|---|---|---|---|---|")
    for floor in FRONTIER_FLOORS:
        N = np.zeros((6, 6))
        rhs = np.zeros(6)
        meat = np.zeros((6, 6))
        for Ak, yk in zip(A, y):
            WA = Ak if floor is None else _apply_axes(Ak, [m + floor * np.eye(len(m)) for m in mats], inverse=True)
            WA2 = WA.reshape(-1, 6)
            N += WA2.T @ Ak.reshape(-1, 6)
            rhs -= WA2.T @ yk.reshape(-1)
            meat += 2.0 * WA2.T @ _apply_axes(WA, mats, inverse=False).reshape(-1, 6)
        Ni = np.linalg.inv(N)
        e = J @ (Ni @ rhs - p_true)
        C = J @ Ni @ meat @ Ni.T @ J.T
        noise = (math.sqrt(np.trace(C[:3, :3])) / bt1, math.sqrt(np.trace(C[3:, 3:])) / bw1)
        bias = (255.0 * np.linalg.norm(e[:3]) / bt1, 255.0 * np.linalg.norm(e[3:]) / bw1)
        tot = [", ".join(f"{math.hypot(b / s, n):.2f}" for b, n in zip(bias, noise)) for s in (1.0, 4.0)]
        label = "least squares" if floor is None else ("whitened exactly (the bound's estimator)" if floor == 0
                                                       else f"whitened, floor {floor:g}")
        print(f"| {label} | {noise[0]:.2f}, {noise[1]:.2f} | {bias[0]:.2f}, {bias[1]:.2f} | {tot[0]} | {tot[1]} |",
              flush=True)


PROBE_FLOORS = (None, 0.3)
"""Weightings of the probe: None = plain least squares, else whitened with this ridge
(``MotionOptions.whiten_floor``)."""


def linear_probe(name: str, grid, L0, L1, M, sigmas, draws: int) -> None:
    """The linearised estimator at its fixed point, decomposed: frame 2 warped by the true
    motion, one linear solve of Eq. 5 restricted to the rays the warp keeps, with the noise-free
    Jacobian ``J`` (derivatives of the noise-free warped pair) as the model, so that the error is
    ``−(Bᵀ W J)⁻¹ Bᵀ W (b₀ + n)``: ``b₀`` the noise-free data term (model error: the bias) and
    ``n`` its noise; ``B`` the instruments (regressors) the estimator multiplies by — the
    noise-free ``J`` itself (oracle), the measured derivatives, or Eq. 6's ``ρ̂ L_u, ρ̂ L_v``
    (:func:`polycam.eq5.depth_regularise` as the solver computes them); ``W`` plain least squares or
    whitened by ``(⊗ₐ K_a K_aᵀ + floor I)⁻¹`` on the interior box (rays outside the warp's set are
    zero rows, so the whitening is approximate there). The oracle row is what an estimator that
    knew the noise-free derivatives would reach on the same rays: how much of the gap to the
    CRB is in the rays and the weighting rather than in the solver's regressors."""
    filters = MotionOptions().filters
    crb1, _ = linear_model_bounds(L0, L1, grid, M, filters)
    Jr = _ray_to_rig(np.zeros(6))
    F = len(grid.faces)
    w1c, ok = warp_lightfield(L1[None], grid, T_inverse(M))
    derc = plenoptic_derivatives(L0, w1c[0], grid, filters=filters)
    spec = _axis_filters(derc, grid, filters)
    sl = tuple(spec[a][0] for a in AXES)
    mats = [spec[a][1] for a in AXES]
    WM = _true_motion_mask(grid, ok, derc.valid)
    frac = float(WM[(slice(None),) + sl].mean())

    def rows(der):
        return [ray_motion_coefficients(der, grid, k)[sl] * WM[k][sl][..., None] for k in range(F)]

    def solve(B, y, floor):
        N = np.zeros((6, 6))
        rhs = np.zeros(6)
        for k in range(F):
            WB = B[k] if floor is None else _apply_axes(
                B[k], [m + floor * np.eye(len(m)) for m in mats], inverse=True)
            WB = WB.reshape(-1, 6)
            N += WB.T @ J[k].reshape(-1, 6)
            rhs -= WB.T @ y[k].reshape(-1)
        return Jr @ np.linalg.solve(N, rhs)

    J = rows(derc)
    b0 = [derc.Lt[k][sl] * WM[k][sl] for k in range(F)]
    kinds = ("noise-free J (oracle)", "measured (solver, depth_regressors=False)",
             "ρ̂ L_u, ρ̂ L_v (Eq. 6, depth_regressors)")

    def instruments(der):
        var = np.full(4, 1e30)                 # the keep rule off: Eq. 6 wherever valid
        reg = [der.Lx.copy(), der.Ly.copy(), der.Lu, der.Lv, der.Lt]
        depth_regularise(reg, np.broadcast_to(der.valid, L0.shape), var)
        return J, rows(der), rows(dataclasses.replace(der, Lx=reg[0], Ly=reg[1]))

    crb = crb1 / 255.0 ** 2
    bt1, bw1 = math.sqrt(np.trace(crb[:3, :3])), math.sqrt(np.trace(crb[3:, 3:]))
    bias = {}
    for kind, B in zip(kinds, instruments(derc)):
        for fl in PROBE_FLOORS:
            e0 = solve(B, b0, fl)
            bias[(kind, fl)] = f"{np.linalg.norm(e0[:3]) / bt1:.1f}, {np.linalg.norm(e0[3:]) / bw1:.1f}"
    print(f"\n## {name}: the linearised estimator at the true motion, RMS error / CRB (t, ω), noise-only "
          f"part in brackets, {draws} draws; the warp keeps {100 * frac:.0f}% of the bound's rays\n")
    print("| instruments | weighting | σ = 0: bias / CRB at σ = 1 | " + " | ".join(f"σ = {s:g}" for s in sigmas) + " |")
    print("|---|---|---|" + "---|" * len(sigmas))
    cells = {(k, fl): [] for k in kinds for fl in PROBE_FLOORS}
    for s in sigmas:
        sig = s / 255.0
        rng = np.random.default_rng([29, int(s * 1000)])
        errs = {key: [] for key in cells}
        for _ in range(draws):
            a = (L0 + rng.normal(0.0, sig, L0.shape)).astype(np.float32)
            b = (L1 + rng.normal(0.0, sig, L1.shape)).astype(np.float32)
            w1, _ = warp_lightfield(b[None], grid, T_inverse(M))
            der = plenoptic_derivatives(a, w1[0], grid, filters=filters)
            n = [der.Lt[k][sl] * WM[k][sl] - b0[k] for k in range(F)]
            for kind, B in zip(kinds, instruments(der)):
                for fl in PROBE_FLOORS:
                    errs[(kind, fl)].append((solve(B, b0, fl), solve(B, n, fl)))
        bt, bw = bt1 * s, bw1 * s
        for key, v in errs.items():
            e0 = np.array([x[0] for x in v])
            en = np.array([x[1] for x in v])
            tot, dev = e0 + en, en - en.mean(axis=0)
            c = math.sqrt(len(v) / (len(v) - 1)) if len(v) > 1 else math.nan
            cells[key].append(f"{rms_norm(tot[:, :3]) / bt:.2f}, {rms_norm(tot[:, 3:]) / bw:.2f} "
                              f"({c * rms_norm(dev[:, :3]) / bt:.2f}, {c * rms_norm(dev[:, 3:]) / bw:.2f})")
    for (kind, fl), c in cells.items():
        print(f"| {kind} | {'least squares' if fl is None else f'whitened, floor {fl:g}'} | {bias[(kind, fl)]} | "
              + " | ".join(c) + " |", flush=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="3 draws, fewer levels, supersample 2")
    ap.add_argument("--draws", type=int, default=None)
    ap.add_argument("--distance", type=float, default=8.0,
                    help="[m] the spheres' distance (spheres) or the far wall's (room)")
    ap.add_argument("--scene", choices=("spheres", "room"), default="spheres",
                    help="spheres: the paper's Sect. 5 scene (default); room: the mock rig's textured room")
    ap.add_argument("--variants", action="store_true", help="also the MotionOptions variants table")
    ap.add_argument("--no-predict", action="store_true", help="skip polycam.design.predict_pair")
    ap.add_argument("--faces", nargs="+", default=["all", "+z"])
    ap.add_argument("--variant-sigmas", type=float, nargs="+", default=[0.0, 1.0, 8.0])
    ap.add_argument("--variants-only", action="store_true", help="skip the main table")
    ap.add_argument("--probe", action="store_true",
                    help="also the linearised estimator at the true motion, decomposed (oracle regressors, whitening)")
    ap.add_argument("--probe-only", action="store_true", help="only the --probe table")
    ap.add_argument("--frontier", action="store_true",
                    help="also the bound's own linear model fitted by (whitened) least squares: noise and bias "
                         "per whitening floor, exact (gls_frontier)")
    ap.add_argument("--frontier-only", action="store_true", help="only the --frontier table")
    ap.add_argument("--raw-bound", action="store_true",
                    help="also the CRB of the raw samples (exact renderer Jacobian, no filters) next to the linear model's")
    ap.add_argument("--blur", type=float, default=0.0,
                    help="Gaussian optics point-spread function along u, v of every view [samples], before "
                         "the pixel integration (default 0: sharp, aliased)")
    ap.add_argument("--motion-scale", type=float, default=1.0, help="multiplies the motion (1: 1.5 cm, 0.2 deg)")
    ap.add_argument("--raw-bound-only", action="store_true", help="only the --raw-bound table")
    ap.add_argument("--probe-sigmas", type=float, nargs="+", default=[4.0, 16.0], help="noise levels of --probe")
    ap.add_argument("--sigmas", type=float, nargs="+", default=None, help="noise levels [grey levels]")
    ap.add_argument("--high-noise", action="store_true",
                    help=f"also the table for the noise options {describe_options(HIGH_NOISE)} (HIGH_NOISE)")
    ap.add_argument("--oracle-depth", action="store_true",
                    help="diagnostic: the main table with the true disparity in the Eq. 6 regressors instead of "
                         "the solver's estimate")
    ap.add_argument("--supersample", type=int, default=None,
                    help=f"k x k rays averaged per sample by the renderer (default {SUPERSAMPLE}; --quick 2)")
    ap.add_argument("--antithetic", action="store_true",
                    help="draws in pairs n, -n (errors()): the draws' mean (bias) far more precise")
    ap.add_argument("--seed", type=int, nargs="+", default=[17],
                    help="the draw set of the main and the --high-noise table (default 17: the documented tables); "
                         "several: their draws pooled (--draws each), with each set's ratio beside")
    ap.add_argument("--depth-regressors", choices=("on", "off"), default=None,
                    help="the main table with MotionOptions(depth_regressors=True / False) (else the defaults)")
    ap.add_argument("--quadrature", action="store_true",
                    help="also the noise-free error with and without the robust and model weights on frames "
                         "rendered with k x k and 2k x 2k rays per sample (the frames' own model error; the "
                         "--high-noise options if given, else the main table's)")
    ap.add_argument("--option", action="append", default=[], metavar="KEY=VALUE",
                    help="a MotionOptions field for the main and the --high-noise table, on top of their own "
                         "options (as polycam motion --option; repeatable)")
    args = ap.parse_args()
    main_opts = MotionOptions() if args.depth_regressors is None else \
        MotionOptions(depth_regressors=args.depth_regressors == "on")
    high_opts = HIGH_NOISE
    if args.option:
        try:
            main_opts = options_from_strings(args.option, main_opts)
            high_opts = options_from_strings(args.option, high_opts)
        except InputError as e:
            ap.error(str(e))
    main_name, high_name = (describe_options(o) or "default options" for o in (main_opts, high_opts))
    draws = args.draws or (3 if args.quick else 6)
    sigmas = tuple(args.sigmas) if args.sigmas else ((0.0, 1.0, 4.0, 16.0) if args.quick else SIGMAS)
    ss = args.supersample or (2 if args.quick else SUPERSAMPLE)
    if args.oracle_depth:
        main_name += ", true disparity in the Eq. 6 regressors (--oracle-depth)"
    for faces in args.faces:
        grid, L0, L1, M, *rho = setup(faces, args.distance, ss, 64, args.blur, args.motion_scale,
                                      args.oracle_depth, args.scene)
        label = ("six faces" if faces == "all" else f"one face {faces}") + (", room" if args.scene == "room" else "")
        if args.raw_bound or args.raw_bound_only:
            crb_f, _ = linear_model_bounds(L0, L1, grid, M, MotionOptions().filters)
            print(f"\n## {label}, D = {args.distance:g} m: bounds at σ = 1 grey level, sqrt(trace) t [mm], ω [µrad]\n")
            print("| bound | t | ω |\n|---|---|---|")
            crb_v, crb_all = raw_sample_bounds(faces, args.distance, ss, 64, M, args.blur, args.scene)
            for bname, C in (("linear model, prefiltered derivatives (the yardstick)", crb_f),
                             ("raw samples, exact Jacobian, rays of V", crb_v),
                             ("raw samples, exact Jacobian, all rays", crb_all)):
                C = C / 255.0 ** 2
                print(f"| {bname} | {1e3 * math.sqrt(np.trace(C[:3, :3])):.5f} | {1e6 * math.sqrt(np.trace(C[3:, 3:])):.4f} |",
                      flush=True)
        if args.raw_bound_only:
            continue
        if not (args.variants_only or args.probe_only or args.frontier_only):
            with OracleDepth(rho[0]) if rho else contextlib.nullcontext():
                noise_table(f"{label}, D = {args.distance:g} m, {main_name}", grid, L0, L1, M, sigmas, draws,
                            main_opts, not args.no_predict, args.antithetic, tuple(args.seed))
            if args.high_noise:
                noise_table(f"{label}, D = {args.distance:g} m, {high_name}", grid, L0, L1, M,
                            sigmas, draws, high_opts, not args.no_predict, args.antithetic, tuple(args.seed))
        if args.quadrature:
            fine = setup(faces, args.distance, 2 * ss, 64, args.blur, args.motion_scale, False, args.scene)[:4]
            quadrature_table(f"{label}, D = {args.distance:g} m, {high_name if args.high_noise else main_name}",
                             [(ss, grid, L0, L1, M), (2 * ss, *fine)], high_opts if args.high_noise else main_opts)
        if args.frontier or args.frontier_only:
            gls_frontier(f"{label}, D = {args.distance:g} m", grid, L0, L1, M)
        if args.probe or args.probe_only:
            linear_probe(f"{label}, D = {args.distance:g} m", grid, L0, L1, M, tuple(args.probe_sigmas), draws)
        if args.variants or args.variants_only:
            variant_table(f"{label}, D = {args.distance:g} m", grid, L0, L1, M, tuple(args.variant_sigmas), draws)


if __name__ == "__main__":
    main()
