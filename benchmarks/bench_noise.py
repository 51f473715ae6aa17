"""Plenoptic motion under image noise against the Cramér–Rao bound of the linear model (issue #3, target 2).

Run: ``.venv/bin/python benchmarks/bench_noise.py [--quick] [--draws N] [--sigmas ...] [--before]
[--variants] [--probe]``

Set-up (paper Sect. 5, as benchmarks/bench_motion.py): unit spheres filling the
horizon at D = 8 m, f = 60, 9 x 9 viewpoints 1 cm apart, 64 x 64 directions per face
(3 x 3 rays averaged per sample), one motion |t| = 1.5 cm, |ω| = 0.2 deg (seeded),
on all six faces and on the ``+z`` face alone. Both frames get independent white
Gaussian noise of σ = 0, 0.5, 1, 2, 4, 8, 16, 32 grey levels (of 255) per light-field
sample (float, not quantised); several seeded draws per level, always the same motion.
The high levels are where the noise-free error (model bias, the σ = 0 row) is small
next to the bound; ``--high-noise`` adds the same table for the noise options measured
best together (``depth_regressors=True, eiv=True, smooth_noise=True``: Eq. 6 positional
regressors, errors-in-variables steps, noise-aware discontinuity weight), measured in
the same run.

Table per level: RMS over the draws of the vector error |t̂ − t| and |ω̂ − ω| (nothing
removed; the noise-free error, i.e. the bias, is the σ = 0 row), the bound (sqrt of
the trace of the CRB blocks below: the RMS vector error an efficient unbiased
estimator reaches), and the ratio measured / bound (goal ≤ 1.5). Two further columns
give the noise-only ratio (RMS of the deviation from the draws' mean / bound) and the
σ predicted for the solver's own weighted estimator by :func:`polycam.design.predict_pair`
(which knows the discontinuity and Tukey weights but not the errors-in-variables step,
the noise-aware weight or the whitening); ``GLS`` counts the estimates in which
``whiten="auto"`` took the whitened (generalised least squares) re-solves.
``--variants`` repeats the measurement for several :class:`MotionOptions`; ``--probe``
makes one unweighted linear solve at the true motion with the solver's regressors and
with depth-regularised positional regressors (Eq. 6; a possible solver change).

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
true p (numerical). Left out, deliberately: noise in a (errors in variables — the
solver's derivatives are noisy, which biases it towards zero at high noise), the
warp (the solver interpolates frame 2 at the moved rays, which smooths its noise and
loses rays that leave the grid) and model error (the first-order model is not exact
for a 1.5-view motion: the solver iterates; the bound is for the linearised model).
Because Σ⁻¹ undoes the prefilters, the bound is that of a *whitened* (generalised)
least-squares fit: an estimator that weights the data by the inverse noise
covariance (``MotionOptions(whiten="on", whiten_floor=0)`` is that estimator; the
default floor regularises it, see docs/motion.md). Also shown: ``OLS`` = the exact covariance of plain unweighted least
squares on the same rays, N⁻¹ (Aᵀ Σ A) N⁻¹ with N = AᵀA (what the solver's
normal equations give without robust weights, warps or bias).
"""

from __future__ import annotations

import argparse
import logging
import math
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

import dataclasses  # noqa: E402

from polycam.derivatives import FILTERS, correlate_axis, plenoptic_derivatives  # noqa: E402
from polycam.design import RigSampling, Source, predict_pair  # noqa: E402
from polycam.geometry import R_from_r, T_from_Rt, T_inverse, rt_from_T  # noqa: E402
from polycam.motion import MotionOptions, estimate_motion, ray_motion_coefficients, warp_lightfield  # noqa: E402
from polycam.synth import LightFieldRenderer, default_lightfield_grid, spheres_scene  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_motion import params, random_motion  # noqa: E402  (the same motions and (t, ω) order)

SIGMAS = (0.0, 0.5, 1.0, 2.0, 4.0, 8.0, 16.0, 32.0)
"""Noise levels [grey levels of 255]."""
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
           counter: _WhitenCount | None = None) -> np.ndarray:
    """(draws, 6) estimated − true (t, r) for noise σ [0, 1 units]; ``counter`` counts the
    estimates that took the whitened (GLS) re-solves."""
    rng = np.random.default_rng([seed, int(round(sigma * 1e6))])
    out = []
    lg = logging.getLogger("polycam.motion")
    if counter is not None:
        lg.addHandler(counter)
        old_level = lg.level
        lg.setLevel(logging.DEBUG)
    try:
        for _ in range(draws if sigma > 0 else 1):
            a = (L0 + rng.normal(0.0, sigma, L0.shape)).astype(np.float32) if sigma > 0 else L0
            b = (L1 + rng.normal(0.0, sigma, L1.shape)).astype(np.float32) if sigma > 0 else L1
            res = estimate_motion(a, b, grid, options=opts)
            out.append(params(res.T_prev_next) - params(M))
    finally:
        if counter is not None:
            lg.removeHandler(counter)
            lg.setLevel(old_level)
    return np.array(out)


def rms_norm(e: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.sum(e * e, axis=-1))))


def setup(faces: str, D: float, supersample: int, directions: int):
    grid = default_lightfield_grid(faces, directions=directions)
    ren = LightFieldRenderer(spheres_scene(D, seed=0), grid, supersample)
    M = random_motion(np.random.default_rng(8000), 0.015, math.radians(0.2))
    return grid, ren.render(np.eye(4)), ren.render(M), M


def noise_table(name: str, grid, L0, L1, M, sigmas, draws: int, opts: MotionOptions,
                predict: bool) -> list[dict]:
    filters = opts.filters if isinstance(opts.filters, dict) else {k: opts.filters for k in "xyuv"}
    crb1, ols1 = linear_model_bounds(L0, L1, grid, M, filters)
    sampling = identity_sampling(grid) if predict else None
    n_src = len(sampling.sources) if predict else 0
    F, Ny, Nx, Nv, Nu = grid.shape
    print(f"\n## {name}: {grid.shape} rays, |t| = {100 * np.linalg.norm(M[:3, 3]):.1f} cm, "
          f"|w| = {np.degrees(np.linalg.norm(rt_from_T(M)[:3])):.2f} deg, {draws} draws per level\n")
    print("| σ [grey] | RMS err t [mm] | CRB t [mm] | ratio t | noise-only t | RMS err ω [µrad] | "
          "CRB ω [µrad] | ratio ω | noise-only ω | OLS/CRB t, ω | solver σ t, ω (design) / CRB | "
          "GLS | time/est [s] |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    rows = []
    for s in sigmas:
        sig = s / 255.0
        t0 = time.perf_counter()
        counter = _WhitenCount()
        e = errors(L0, L1, grid, M, sig, draws, opts, seed=17, counter=counter)
        dt = (time.perf_counter() - t0) / len(e)
        gls = f"{counter.on}/{len(e)}"
        crb = crb1 * sig * sig
        ols = ols1 * sig * sig
        b_t = math.sqrt(np.trace(crb[:3, :3]))
        b_w = math.sqrt(np.trace(crb[3:, 3:]))
        m_t, m_w = rms_norm(e[:, :3]), rms_norm(e[:, 3:])
        dev = e - e.mean(axis=0)
        corr = math.sqrt(len(e) / (len(e) - 1)) if len(e) > 1 else math.nan
        n_t, n_w = rms_norm(dev[:, :3]) * corr, rms_norm(dev[:, 3:]) * corr
        pred = ""
        if predict and s > 0:
            src0 = L0.reshape(F * Ny * Nx, Nv, Nu)
            src1 = L1.reshape(F * Ny * Nx, Nv, Nu)
            pr = predict_pair(sampling, src0, src1, M, np.full(n_src, sig), options=opts,
                              rng=np.random.default_rng(5))
            pred = f"{pr.std_t / b_t:.2f}, {pr.std_w / b_w:.2f}"
        row = dict(sigma=s, err_t=m_t, err_w=m_w, crb_t=b_t, crb_w=b_w, noise_t=n_t, noise_w=n_w,
                   ols_t=math.sqrt(np.trace(ols[:3, :3])), ols_w=math.sqrt(np.trace(ols[3:, 3:])))
        rows.append(row)
        if s == 0:
            print(f"| 0 (bias) | {1e3 * m_t:.4f} | 0 | – | – | {1e6 * m_w:.3f} | 0 | – | – | – | – | {gls} | "
                  f"{dt:.1f} |", flush=True)
            continue
        print(f"| {s:g} | {1e3 * m_t:.4f} | {1e3 * b_t:.4f} | {m_t / b_t:.2f} | {n_t / b_t:.2f} | "
              f"{1e6 * m_w:.3f} | {1e6 * b_w:.3f} | {m_w / b_w:.2f} | {n_w / b_w:.2f} | "
              f"{row['ols_t'] / b_t:.2f}, {row['ols_w'] / b_w:.2f} | {pred or '–'} | {gls} | {dt:.1f} |", flush=True)
    snr = regressor_snr(L0, L1, grid, filters)
    print("\nregressor signal / noise RMS at σ = 1 grey level (divide by σ for other levels): "
          + ", ".join(f"{k} {v:.0f}" for k, v in snr.items()))
    worst = max(max(r["err_t"] / r["crb_t"], r["err_w"] / r["crb_w"]) for r in rows if r["sigma"] > 0)
    print(f"\nworst measured / CRB ratio over σ > 0: {worst:.2f} (goal ≤ 1.5: {'met' if worst <= 1.5 else 'NOT met'}); "
          f"|t| = {1e3 * np.linalg.norm(M[:3, 3]):.1f} mm, |ω| = {1e6 * np.linalg.norm(rt_from_T(M)[:3]):.0f} µrad")
    return rows


HIGH_NOISE = MotionOptions(depth_regressors=True, eiv=True, smooth_noise=True)
"""The noise options measured best together: depth-regularised positional regressors (Eq. 6),
errors-in-variables steps, noise-aware discontinuity weight (whitening: see docs/motion.md)."""

VARIANTS = {
    "default": MotionOptions(),
    "smooth_noise": MotionOptions(smooth_noise=True),
    "eiv": MotionOptions(eiv=True),
    "eiv, smooth_noise": MotionOptions(eiv=True, smooth_noise=True),
    "eiv, smooth_noise, whiten=auto (floor 0.3)": MotionOptions(eiv=True, smooth_noise=True, whiten="auto"),
    "eiv, smooth_noise, whiten=on (floor 0.3)": MotionOptions(eiv=True, smooth_noise=True, whiten="on"),
    "eiv, smooth_noise, whiten=on, floor 0.1": MotionOptions(eiv=True, smooth_noise=True, whiten="on",
                                                             whiten_floor=0.1),
    "depth_regressors": MotionOptions(depth_regressors=True),
    "depth_regressors, eiv, smooth_noise": HIGH_NOISE,
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


# ---------------------------------------------------------------------------- linear probe


def depth_regularised(der, passes: int = 2):
    """The derivatives with L_x, L_y replaced by ρ̂ L_u, ρ̂ L_v (Lambertian, paper Eq. 6:
    L_x = ρ L_u with ρ = f / Z), ρ̂ = Σ L_x L_u / Σ L_u² (L_x regressed on the clean L_u) over a
    (u, v) window (the fs5 prefilter applied ``passes`` times) — the proposed solver change."""
    taps = FILTERS["fs5"].prefilter

    def win(a):
        out = np.ascontiguousarray(a, dtype=np.float32)
        for _ in range(passes):
            out = correlate_axis(correlate_axis(out, taps, 3), taps, 4)
        return out

    suu = win(der.Lu * der.Lu + der.Lv * der.Lv)
    sxu = win(der.Lx * der.Lu + der.Ly * der.Lv)
    rho = np.where(suu > 0, sxu / np.maximum(suu, 1e-30), 0.0).astype(np.float32)
    return dataclasses.replace(der, Lx=rho * der.Lu, Ly=rho * der.Lv)


def linear_probe(name: str, grid, L0, L1, M, sigmas, draws: int) -> None:
    """One unweighted linear solve of Eq. 5 at the true motion (frame 2 warped by it, as the
    solver sees it at convergence): RMS of the increment over draws / CRB, with the solver's
    regressors and with depth-regularised positional regressors."""
    filters = MotionOptions().filters
    crb1, _ = linear_model_bounds(L0, L1, grid, M, filters)
    J = _ray_to_rig(np.zeros(6))
    print(f"\n## {name}: one linear solve at the true motion, RMS increment / CRB (t, ω), {draws} draws\n")
    print("| regressors | " + " | ".join(f"σ = {s:g}" for s in sigmas) + " |")
    print("|---|" + "---|" * len(sigmas))
    cells = {"L_x, L_y as measured (solver)": [], "ρ̂ L_u, ρ̂ L_v (Eq. 6, proposed)": []}
    for s in sigmas:
        sig = s / 255.0
        rng = np.random.default_rng([29, int(s * 1000)])
        errs = {k: [] for k in cells}
        for _ in range(draws if s > 0 else 1):
            a = (L0 + rng.normal(0.0, sig, L0.shape)).astype(np.float32) if s > 0 else L0
            b = (L1 + rng.normal(0.0, sig, L1.shape)).astype(np.float32) if s > 0 else L1
            w1, ok = warp_lightfield(b[None], grid, T_inverse(M))
            der = plenoptic_derivatives(a, w1[0], grid, filters=filters)
            okv = ok.astype(np.float32)
            for ax, r in ((1, 1), (2, 1), (3, 2), (4, 2)):
                okv = np.minimum(okv, np.minimum.reduce([np.roll(okv, d, axis=ax) for d in range(-r, r + 1)]))
            w = okv * der.valid[None]
            for key, d in (("L_x, L_y as measured (solver)", der),
                           ("ρ̂ L_u, ρ̂ L_v (Eq. 6, proposed)", depth_regularised(der))):
                N = np.zeros((6, 6))
                rhs = np.zeros(6)
                for k in range(len(grid.faces)):
                    A = ray_motion_coefficients(d, grid, k).reshape(-1, 6)
                    wk = w[k].reshape(-1).astype(np.float64)
                    N += (A * wk[:, None]).T @ A
                    rhs -= (A * wk[:, None]).T @ d.Lt[k].reshape(-1)
                errs[key].append(J @ np.linalg.solve(N, rhs))
        for key in cells:
            e = np.array(errs[key])
            if s == 0:
                cells[key].append(f"bias {1e3 * rms_norm(e[:, :3]):.4f} mm, {1e6 * rms_norm(e[:, 3:]):.2f} µrad")
            else:
                crb = crb1 * sig * sig
                cells[key].append(f"{rms_norm(e[:, :3]) / math.sqrt(np.trace(crb[:3, :3])):.2f}, "
                                  f"{rms_norm(e[:, 3:]) / math.sqrt(np.trace(crb[3:, 3:])):.2f}")
    for key, c in cells.items():
        print(f"| {key} | " + " | ".join(c) + " |", flush=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="3 draws, fewer levels, supersample 2")
    ap.add_argument("--draws", type=int, default=None)
    ap.add_argument("--distance", type=float, default=8.0)
    ap.add_argument("--variants", action="store_true", help="also the MotionOptions variants table")
    ap.add_argument("--no-predict", action="store_true", help="skip polycam.design.predict_pair")
    ap.add_argument("--faces", nargs="+", default=["all", "+z"])
    ap.add_argument("--variant-sigmas", type=float, nargs="+", default=[0.0, 1.0, 8.0])
    ap.add_argument("--variants-only", action="store_true", help="skip the main table")
    ap.add_argument("--probe", action="store_true", help="also the one-linear-solve regressor probe")
    ap.add_argument("--sigmas", type=float, nargs="+", default=None, help="noise levels [grey levels]")
    ap.add_argument("--high-noise", action="store_true",
                    help="also the table for depth_regressors=True, eiv=True, smooth_noise=True")
    args = ap.parse_args()
    draws = args.draws or (3 if args.quick else 6)
    sigmas = tuple(args.sigmas) if args.sigmas else ((0.0, 1.0, 4.0, 16.0) if args.quick else SIGMAS)
    ss = 2 if args.quick else 3
    for faces in args.faces:
        grid, L0, L1, M = setup(faces, args.distance, ss, 64)
        label = "six faces" if faces == "all" else f"one face {faces}"
        if not args.variants_only:
            noise_table(f"{label}, D = {args.distance:g} m, default options", grid, L0, L1, M, sigmas, draws,
                        MotionOptions(), not args.no_predict)
            if args.high_noise:
                noise_table(f"{label}, D = {args.distance:g} m, depth_regressors, eiv, smooth_noise", grid, L0, L1, M,
                            sigmas, draws, HIGH_NOISE, not args.no_predict)
        if args.probe:
            linear_probe(f"{label}, D = {args.distance:g} m", grid, L0, L1, M, (0.0, 1.0, 8.0), draws)
        if args.variants or args.variants_only:
            variant_table(f"{label}, D = {args.distance:g} m", grid, L0, L1, M, tuple(args.variant_sigmas), draws)


if __name__ == "__main__":
    main()
