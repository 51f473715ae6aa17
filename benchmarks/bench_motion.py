"""Plenoptic motion: accuracy vs scene distance (paper Fig. 5c) and speed, vs a baseline.

Run: ``.venv/bin/python benchmarks/bench_motion.py [--quick] [--repeat N]``

Accuracy: the paper's Sect. 5 set-up rendered by :mod:`polycam.synth` — six faces,
f = 60, 9 x 9 viewpoints 1 cm apart, 64 x 64 directions over 90 deg per face (3 x 3
rays averaged per sample), unit spheres filling the horizon at distance D. For each
D and each of a few seeded motions (|t| = 1.5 cm, |ω| = 0.2 deg in random directions,
NOTES.md) the table gives the per-parameter ratio estimated / true (median over the
motions) and the median relative error of t and ω for

- ``baseline``: one scale, central differences, one linearisation, plain least
  squares (what NOTES.md "a quick check" measured), and
- ``polycam``: the default :class:`polycam.motion.MotionOptions`.

A second table repeats one motion at the middle distance with both frames quantised
to 8 bits after adding Gaussian noise of 0, 1 and 3 grey levels. ``--supersample k``
renders the accuracy table with k x k rays per sample (a finer approximation of a pixel's
area integral; the silhouettes' staircase of k x k point samples is model error the
translation sees at large D: docs/motion_log.md).

Speed: one face of 9 x 9 views x 128 x 128 directions (1.33 M rays): derivatives of a
frame pair + one linear solve of Eq. 5, ours (numba kernels) against a numpy / scipy
implementation of the same computation (``scipy.ndimage.correlate1d`` passes, the
coefficient matrix A formed in numpy and AᵀWA by a matrix product), both measured in
this run; plus the full default estimate per pair against the same algorithm written
in numpy / scipy (:func:`numpy_full_solve`: same pyramid, warp stencils, filters,
weights, IRLS, covariance scores and the same number of solves per level as our run),
the default estimate with confidences W (a resampled session's frames carry them: the
warp then also moves W), and the peak memory of one full estimate in a fresh process
relative to one frame (and over three consecutive estimates, as in a session); and the default
estimate against the noise options (``--preset noisy``) on the frames with 2 grey levels of noise
added. Timings are the best of ``--repeat`` runs after a warm-up, plus process CPU time; the
machine (2 cores) may be shared, which inflates both (numba's threads spin-wait).
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from polycam.derivatives import FILTERS, plenoptic_derivatives  # noqa: E402
from polycam.geometry import R_from_r, T_from_Rt, rt_from_T  # noqa: E402
from polycam.motion import MotionOptions, estimate_motion, ray_motion_coefficients, solve_ray_motion  # noqa: E402
from polycam.motion_options import NOISY  # noqa: E402
from polycam.synth import LightFieldRenderer, default_lightfield_grid, spheres_scene  # noqa: E402

BASELINE = MotionOptions(filters="central", levels=1, iterations=1, irls_steps=0, robust="none", depth_regressors=False,
                         smooth_c=0.0, uv_taps=2, symmetric=False)
NAMES = ("t_x", "t_y", "t_z", "w_x", "w_y", "w_z")


def best_time(fn, repeat: int) -> float:
    fn()
    ts = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        ts.append(time.perf_counter() - t0)
    return min(ts)


def cpu_time(fn, repeat: int) -> float:
    """Median process CPU time [s] of fn over all threads (less sensitive to other load:
    on idle cores the wall time is about this divided by the threads used)."""
    fn()
    ts = []
    for _ in range(repeat):
        t0 = time.process_time()
        fn()
        ts.append(time.process_time() - t0)
    return float(np.median(ts))


def random_motion(rng: np.random.Generator, t_norm: float, r_norm: float) -> np.ndarray:
    """(4, 4) rig motion T_rig0_rig1 with |t| = t_norm [m], |r| = r_norm [rad], random axes
    kept away from the coordinate planes so every component is sizeable."""
    def vec(n):
        while True:
            v = rng.normal(size=3)
            v /= np.linalg.norm(v)
            if np.min(np.abs(v)) > 0.3:
                return v * n
    return T_from_Rt(R_from_r(vec(r_norm)), vec(t_norm))


def params(T: np.ndarray) -> np.ndarray:
    """(t, ω) order of NAMES."""
    rt = rt_from_T(T)
    return np.concatenate([rt[3:], rt[:3]])


def plot_fig5c(path: str, table: dict) -> None:
    """The paper's Fig. 5c, measured: estimated / true per motion parameter against the scene
    distance, one panel per parameter; lines: median over the motions, dots: each motion.
    ``table``: method → list of (D, ratios (n_motions, 6))."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(2, 3, figsize=(12, 6.5), sharex=True)
    styles = {"baseline": dict(color="tab:red", marker="s"), "polycam": dict(color="tab:blue", marker="o"),
              DR_NAME: dict(color="tab:green", marker="^")}
    for j, (ax, name) in enumerate(zip(axes.ravel(), NAMES)):
        for method, rows in table.items():
            D = np.array([d for d, _ in rows])
            med = np.array([np.median(r[:, j]) for _, r in rows])
            ax.plot(D, med, label=method, **styles.get(method, {}))
            for d, r in rows:
                ax.scatter(np.full(len(r), d), r[:, j], s=8, alpha=0.4, color=styles.get(method, {}).get("color"))
        ax.axhline(1.0, color="k", lw=0.8)
        ax.axhspan(0.995, 1.005, color="tab:green", alpha=0.15, lw=0)
        ax.set_title(name.replace("w_", "ω_"))
        ax.grid(alpha=0.3)
        if j >= 3:
            ax.set_xlabel("distance sensor - scene D [m]")
        if j % 3 == 0:
            ax.set_ylabel("estimated / true")
    axes[0, 0].legend(loc="best", fontsize=8)
    fig.suptitle("Six faces, f = 60, unit spheres (paper Sect. 5): estimated / true motion parameter "
                 "(green band: ±0.5 %)", fontsize=10)
    fig.tight_layout()
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)


DR_NAME = "polycam, measured regressors"
"""The accuracy rows of ``MotionOptions(depth_regressors=False)`` (``--measured-regressors``: Eq. 5 with the
measured L_x, L_y; the default replaces them by Eq. 6's ρ̂ L_u, ρ̂ L_v where that is less noisy)."""


def accuracy(distances, n_motions: int, supersample: int, directions: int, plot: str | None = None,
             measured_regressors: bool = False) -> None:
    grid = default_lightfield_grid("all", directions=directions)
    print(f"\n## Accuracy: six faces, f = {grid.faces[0].f:g}, {grid.y.count}x{grid.x.count} views "
          f"{grid.x.step * 100:g} cm apart, {grid.v.count}x{grid.u.count} directions, "
          f"supersample {supersample}; |t| = 1.5 cm, |w| = 0.2 deg; {n_motions} motion(s) per D\n")
    print("| D [m] | method | " + " | ".join(f"{n} est/true" for n in NAMES)
          + " | med err t | med err w | time/pair [s] |")
    print("|---|---|" + "---|" * (len(NAMES) + 3))
    summary = []
    methods = [("baseline", BASELINE), ("polycam", MotionOptions())]
    if measured_regressors:
        methods.append((DR_NAME, MotionOptions(depth_regressors=False)))
    fig5c = {name: [] for name, _ in methods}
    noise_at = distances[len(distances) // 2]
    noise_rows = []
    for D in distances:
        scene = spheres_scene(D, seed=0)
        ren = LightFieldRenderer(scene, grid, supersample)
        L0 = ren.render(np.eye(4))
        rng = np.random.default_rng(int(D * 1000))
        motions = [random_motion(rng, 0.015, np.radians(0.2)) for _ in range(n_motions)]
        frames = [ren.render(M) for M in motions]
        for name, opts in methods:
            ratios, errs_t, errs_w, times = [], [], [], []
            for M, L1 in zip(motions, frames):
                t0 = time.perf_counter()
                res = estimate_motion(L0, L1, grid, options=opts)
                times.append(time.perf_counter() - t0)
                est, tru = params(res.T_prev_next), params(M)
                ratios.append(est / tru)
                errs_t.append(np.linalg.norm(est[:3] - tru[:3]) / np.linalg.norm(tru[:3]))
                errs_w.append(np.linalg.norm(est[3:] - tru[3:]) / np.linalg.norm(tru[3:]))
            fig5c[name].append((D, np.array(ratios)))
            r = np.median(np.array(ratios), axis=0)
            rel = np.abs(np.array(ratios) - 1)
            med_t, med_w = np.median(rel[:, :3]), np.median(rel[:, 3:])
            summary.append((D, name, med_t, med_w))
            if D == noise_at and name == methods[-1][0]:
                noise_rows = noise_table(L0, frames[0], motions[0], grid, methods)
            print(f"| {D:g} | {name} | " + " | ".join(f"{v:.4f}" for v in r)
                  + f" | {100 * med_t:.2f}% | {100 * med_w:.2f}% | {np.mean(times):.2f} |", flush=True)
    print("\nmedian relative error per component (|est/true - 1|, median over the 3 components and"
          " the motions);\nvector errors |est - true| / |true| are in the same range.")
    if plot:
        plot_fig5c(plot, fig5c)
        print(f"\nplot: {plot}")
    print(f"\n## 8-bit quantisation and sensor noise (D = {noise_at:g} m, first motion)\n")
    print("| noise [grey levels] | method | med err t | med err w | reported std t / err t |")
    print("|---|---|---|---|---|")
    for row in noise_rows:
        print(row)
    base = {D: (t, w) for D, n, t, w in summary if n == "baseline"}
    for method, _ in methods[1:]:
        ours = {D: (t, w) for D, n, t, w in summary if n == method}
        print(f"\n| D [m] | baseline err t / {method} | baseline err w / {method} |")
        print("|---|---|---|")
        for D in distances:
            bt, bw = base[D]
            ot, ow = ours[D]
            print(f"| {D:g} | {bt / max(ot, 1e-12):.0f}x | {bw / max(ow, 1e-12):.0f}x |")


def noise_table(L0, L1, M, grid, methods) -> list[str]:
    """Rows: both frames quantised to 8 bits after adding Gaussian noise (seeded); ``methods``:
    (name, MotionOptions) pairs."""
    rng = np.random.default_rng(7)
    rows = []
    tru = params(M)
    for sigma in (0.0, 1.0, 3.0):
        def q(L):
            return (np.round(np.clip(L + rng.normal(0, sigma / 255, L.shape), 0, 1) * 255) / 255
                    ).astype(np.float32)
        a, b = q(L0), q(L1)
        for name, opts in methods:
            res = estimate_motion(a, b, grid, options=opts)
            rel = np.abs(params(res.T_prev_next) / tru - 1)
            err_t = np.linalg.norm(params(res.T_prev_next)[:3] - tru[:3])
            ratio = np.linalg.norm(res.std[:3]) / max(err_t, 1e-15)
            rows.append(f"| {sigma:g} | {name} | {100 * np.median(rel[:3]):.2f}% | "
                        f"{100 * np.median(rel[3:]):.2f}% | {ratio:.2f} |")
    return rows


# ------------------------------------------------------------------ speed


def numpy_derivatives(L0, L1, grid, name="fs5"):
    """The same separable derivatives with scipy.ndimage.correlate1d (baseline); ``name``: one
    FILTERS name for all axes or axis → name."""
    from scipy.ndimage import correlate1d

    names = name if isinstance(name, dict) else {k: name for k in "xyuv"}
    taps = {k: (FILTERS[names.get(k, "fs5")].prefilter.astype(np.float32),
                FILTERS[names.get(k, "fs5")].derivative.astype(np.float32)) for k in "xyuv"}
    S = 0.5 * (L0 + L1)
    D = L1 - L0
    axes = {"y": 1, "x": 2, "v": 3, "u": 4}
    step = {"x": grid.x.step, "y": grid.y.step, "u": grid.u.step, "v": grid.v.step}

    def filt(a, which):
        for ax_name, t in which.items():
            a = correlate1d(a, t, axis=axes[ax_name], mode="nearest")
        return a

    out = {}
    for n in ("x", "y", "u", "v"):
        which = {m: taps[m][1 if m == n else 0] for m in axes}
        out[n] = filt(S, which) / np.float32(step[n])
    Lt = filt(D, {m: taps[m][0] for m in axes})
    return out, Lt


def numpy_solve(der_np, Lt, grid, valid):
    """A formed in numpy (N x 6, float64), AᵀWA and Aᵀb by matrix products (baseline)."""
    class D:
        pass
    dd = D()
    dd.Lx, dd.Ly, dd.Lu, dd.Lv = der_np["x"], der_np["y"], der_np["u"], der_np["v"]
    A = np.concatenate([ray_motion_coefficients(dd, grid, k).reshape(-1, 6) for k in range(len(grid.faces))])
    w = np.broadcast_to(valid, Lt.shape).reshape(-1).astype(np.float64)
    b = -Lt.reshape(-1).astype(np.float64)
    Aw = A * w[:, None]
    return np.linalg.lstsq(Aw.T @ A, Aw.T @ b, rcond=None)[0]


def numpy_full_solve(L0, L1, grid, schedule: list[int], opts: MotionOptions):
    """The default estimate's algorithm in plain numpy / scipy (baseline for the full solve):
    the same (u, v) pyramid; per iteration a warp of frame 2 (numpy gathers with the same
    6 x 6 Lagrange (u, v) stencils, then bilinear across views), scipy derivatives with the
    same filters, weights = warp validity minimised over the filter support x valid x the
    discontinuity weight, the coefficient matrix A (float64), a weighted solve and
    ``irls_steps`` Tukey re-weightings (weighted MAD by sorting a 50 000-ray subsample),
    and the per-tile scores and sandwich covariance. ``schedule``: iterations per level,
    coarse to fine, taken from our run, so both do the same number of solves. One face."""
    from scipy.ndimage import correlate1d, maximum_filter, minimum_filter

    from polycam.geometry import T_inverse
    from polycam.lightfield import Axis
    from polycam.warp import _uv_stencils

    def down(a):
        for ax in (3, 4):
            a = correlate1d(a, np.array([1, 4, 6, 4, 1], np.float32) / 16, axis=ax, mode="nearest")
            a = a[(slice(None),) * ax + (slice(None, None, 2),)]
        return np.ascontiguousarray(a)

    levels = [(grid, L0, L1)]
    for _ in range(len(schedule) - 1):
        g, a, b = levels[-1]
        half = {k: Axis(getattr(g, k).min, getattr(g, k).min + ((getattr(g, k).count - 1) // 2) * 2
                        * getattr(g, k).step, (getattr(g, k).count - 1) // 2 + 1) for k in "uv"}
        levels.append((replace(g, **half), down(a), down(b)))
    fnames = opts.filters
    radius = {k: FILTERS[fnames[k]].radius for k in "xyuv"}
    M = np.eye(4)
    face = grid.faces[0]
    for (g, A0, A1), n_it in zip(levels[::-1], schedule):
        F, Ny, Nx, Nv, Nu = A0.shape
        S = 0.5 * (A0 + A1)
        lap = np.array([1, -2, 1], np.float32)
        e = np.abs(correlate1d(S, lap, axis=3, mode="nearest")) + np.abs(correlate1d(S, lap, axis=4, mode="nearest"))
        e = maximum_filter(e, size=(1, 1, 1, 5, 5), mode="nearest")
        smooth = 1 / (1 + (e / (opts.smooth_c * np.median(e))) ** 2)
        valid = np.zeros((Ny, Nx, Nv, Nu), bool)
        valid[radius["y"]:Ny - radius["y"], radius["x"]:Nx - radius["x"], radius["v"]:Nv - radius["v"],
              radius["u"]:Nu - radius["u"]] = True
        y, x, v, u = np.meshgrid(g.y.values, g.x.values, g.v.values, g.u.values, indexing="ij")
        scale = None
        for _ in range(n_it):
            G = T_inverse(M)
            R, tr = G[:3, :3], G[:3, 3]
            wv, iv, wu, iu, ok_uv, sx, sy = _uv_stencils(g, face, R, opts.uv_taps)
            U = np.zeros(A1.shape[1:], np.float32)
            for q in range(6):
                for r in range(6):
                    U += (wv[..., q] * wu[..., r]).astype(np.float32) * A1[0][:, :, iv[..., q], iu[..., r]]
            o = np.stack([x, y, np.full_like(x, face.z_pi)], -1) @ R.T + tr
            fx = (o[..., 0] + (face.z_pi - o[..., 2]) * sx - g.x.min) / g.x.step
            fy = (o[..., 1] + (face.z_pi - o[..., 2]) * sy - g.y.min) / g.y.step
            ok = ok_uv & (fx > -1e-6) & (fx < Nx - 1 + 1e-6) & (fy > -1e-6) & (fy < Ny - 1 + 1e-6)
            bx = np.clip(np.floor(fx), 0, Nx - 2).astype(int)
            by = np.clip(np.floor(fy), 0, Ny - 2).astype(int)
            ax_, ay_ = np.clip(fx - bx, 0, 1), np.clip(fy - by, 0, 1)
            vi, ui = np.meshgrid(np.arange(Nv), np.arange(Nu), indexing="ij")
            L1w = ((1 - ay_) * ((1 - ax_) * U[by, bx, vi, ui] + ax_ * U[by, bx + 1, vi, ui])
                   + ay_ * ((1 - ax_) * U[by + 1, bx, vi, ui] + ax_ * U[by + 1, bx + 1, vi, ui]))
            L1w = np.where(ok, L1w, 0).astype(np.float32)[None]
            der, Lt = numpy_derivatives(A0, L1w, g, fnames)
            conf = minimum_filter(ok.astype(np.float32), size=tuple(2 * radius[k] + 1 for k in "yxvu"),
                                  mode="nearest")
            base = (conf * valid * smooth[0]).reshape(-1)

            class D:
                pass
            dd = D()
            dd.Lx, dd.Ly, dd.Lu, dd.Lv = der["x"], der["y"], der["u"], der["v"]
            A = ray_motion_coefficients(dd, g, 0).reshape(-1, 6)
            b = -Lt.reshape(-1).astype(np.float64)
            w = base
            p = np.linalg.lstsq((A * w[:, None]).T @ A, (A * w[:, None]).T @ b, rcond=None)[0]
            for _ in range(opts.irls_steps):
                res = A @ p - b
                m = base > 0
                a, ww = np.abs(res[m]), base[m]
                k = max(1, a.size // 50_000)
                a, ww = a[::k], ww[::k]
                order = np.argsort(a)
                cw = np.cumsum(ww[order])
                mad = max(1.4826 * a[order[np.searchsorted(cw, 0.5 * cw[-1])]], 1e-5)
                scale = mad if scale is None else max(scale, mad)
                z = np.abs(res) / (scale * opts.robust_c)
                w = base * np.where(z < 1, (1 - z * z) ** 2, 0)
                p = np.linalg.lstsq((A * w[:, None]).T @ A, (A * w[:, None]).T @ b, rcond=None)[0]
            res = A @ p - b
            t = 16 if Nu >= 128 else max(4, -(-Nu // 8))
            sc = (w * res)[:, None] * A
            scores = sc.reshape(Ny * Nx, Nv // t, t, Nu // t, t, 6).sum(axis=(0, 2, 4)).reshape(-1, 6)
            Np = np.linalg.pinv((A * w[:, None]).T @ A)
            cov = Np @ (scores.T @ scores) @ Np                   # noqa: F841 (the covariance's cost)
            M = T_inverse(T_from_Rt(R_from_r(p[3:]), p[:3])) @ M
    return M


def solve_schedule(L0, L1, grid, opts: MotionOptions) -> list[int]:
    """Linear solves per pyramid level (coarse to fine) of our estimate with ``opts``."""
    import polycam.motion as pm

    counts: dict[int, int] = {}
    orig = pm._Solver.solve

    def counting(self, M):
        counts[self.g.u.count] = counts.get(self.g.u.count, 0) + 1
        return orig(self, M)

    pm._Solver.solve = counting
    try:
        estimate_motion(L0, L1, grid, options=opts)
    finally:
        pm._Solver.solve = orig
    return [counts[k] for k in sorted(counts)]


MEMORY_CHILD = """
import sys
import numpy as np
sys.path.insert(0, {repo!r})
from polycam.motion import MotionOptions, estimate_motion
from polycam.motion_options import NOISY
from polycam.synth import default_lightfield_grid


def status(key):
    for line in open("/proc/self/status"):
        if line.startswith(key + ":"):
            return int(line.split()[1]) * 1024


small = default_lightfield_grid("+z", views=5, directions=32)
a = np.random.default_rng(0).random(small.shape).astype(np.float32)
Ws = np.ones_like(a) if {with_w} else None
opts = NOISY if {noisy} else MotionOptions(depth_regressors={dr})
estimate_motion(a, a * 0.99 + 0.005, small, W0=Ws, W1=Ws, options=opts)   # load the compiled kernels (as a session: with W)
L0, L1 = np.load({f0!r}), np.load({f1!r})
W = np.ones_like(L0) if {with_w} else None
grid = default_lightfield_grid("+z", directions={directions})
with open("/proc/self/clear_refs", "w") as f:            # reset the peak resident set (VmHWM)
    f.write("5")
before = status("VmRSS")
for _ in range({estimates}):
    estimate_motion(L0, L1, grid, W0=W, W1=W, options=opts)
print(status("VmHWM") - before)
"""


def peak_memory(L0, L1, directions: int, depth_regressors: bool = True, with_w: bool = False,
                estimates: int = 1, noisy: bool = False) -> int:
    """Peak growth of the resident set [bytes] during ``estimates`` consecutive full estimates
    of the pair (as the pairs of a session: the work arrays stay between calls), in a fresh process
    (frames loaded and kernels warmed up on a small grid first; Linux: the peak is reset
    through /proc/self/clear_refs, so earlier peaks such as imports do not hide it).
    ``with_w``: with confidences W = 1 for both frames (allocated before the reset; the
    warm-up has them too, as every pair of a session does: the work arrays' dtypes then
    match, which the allocator's reuse of freed memory depends on). ``noisy``: with the noise
    options (``NOISY``) instead of ``MotionOptions(depth_regressors=depth_regressors)``."""
    import subprocess
    import tempfile

    with tempfile.TemporaryDirectory() as tmp:
        f0, f1 = str(Path(tmp) / "L0.npy"), str(Path(tmp) / "L1.npy")
        np.save(f0, L0)
        np.save(f1, L1)
        code = MEMORY_CHILD.format(repo=str(REPO), f0=f0, f1=f1, directions=directions, dr=depth_regressors,
                                   with_w=with_w, estimates=estimates, noisy=noisy)
        out = subprocess.run([sys.executable, "-c", code], check=True, capture_output=True, text=True)
    return int(out.stdout.split()[-1])


def speed(repeat: int, directions: int) -> None:
    grid = default_lightfield_grid("+z", directions=directions)
    scene = spheres_scene(6.0, seed=0)
    ren = LightFieldRenderer(scene, grid, 1)
    L0 = ren.render(np.eye(4))
    L1 = ren.render(random_motion(np.random.default_rng(1), 0.015, np.radians(0.2)))
    n = L0.size
    filters = MotionOptions().filters

    ws = {}

    def ours():
        # as in the solver: the output arrays of the previous call are reused
        ws["der"] = der = plenoptic_derivatives(L0, L1, grid, filters=filters, out=ws.get("der"))
        return solve_ray_motion(der, grid)

    def base():
        der, Lt = numpy_derivatives(L0, L1, grid)
        return numpy_solve(der, Lt, grid, np.ones(Lt.shape[1:], bool))

    def ours_der():
        ws["der"] = plenoptic_derivatives(L0, L1, grid, filters=filters, out=ws.get("der"))

    meas = MotionOptions(depth_regressors=False)        # the algorithm of the numpy version
    schedule = solve_schedule(L0, L1, grid, meas)
    T_np = numpy_full_solve(L0, L1, grid, schedule, meas)
    T_ours = estimate_motion(L0, L1, grid, options=meas).T_prev_next
    t_ours = best_time(ours, repeat)
    t_der = best_time(ours_der, repeat)
    t_base = best_time(base, max(1, repeat // 2))
    t_full = best_time(lambda: estimate_motion(L0, L1, grid), repeat)
    t_full_m = best_time(lambda: estimate_motion(L0, L1, grid, options=meas), repeat)
    t_full = min(t_full, best_time(lambda: estimate_motion(L0, L1, grid), repeat))   # alternate: same load
    t_full_m = min(t_full_m, best_time(lambda: estimate_motion(L0, L1, grid, options=meas), repeat))
    # frames with 2 grey levels of noise: the default options and the noise options (--preset noisy)
    rng = np.random.default_rng(2)
    L0n, L1n = ((L + rng.normal(0.0, 2.0 / 255.0, L.shape)).astype(L.dtype) for L in (L0, L1))
    t_noisy_d = t_noisy_p = math.inf
    for _ in range(2):                                  # alternate: same load
        t_noisy_d = min(t_noisy_d, best_time(lambda: estimate_motion(L0n, L1n, grid), repeat))
        t_noisy_p = min(t_noisy_p, best_time(lambda: estimate_motion(L0n, L1n, grid, options=NOISY), repeat))
    W = np.ones_like(L0)          # confidences of a resampled session's frames (all measured)
    t_full_w = best_time(lambda: estimate_motion(L0, L1, grid, W0=W, W1=W), repeat)
    W_holes = W.copy()
    W_holes[..., :2] = 0.0        # no data in the first two direction columns: the warp's third channel
    t_full_h = best_time(lambda: estimate_motion(L0, L1, grid, W0=W_holes, W1=W_holes), repeat)
    t_full_np = best_time(lambda: numpy_full_solve(L0, L1, grid, schedule, meas), 1)
    c_ours = cpu_time(ours, repeat)
    c_der = cpu_time(ours_der, repeat)
    c_base = cpu_time(base, max(1, repeat // 2))
    c_full = cpu_time(lambda: estimate_motion(L0, L1, grid), repeat)
    c_full_m = cpu_time(lambda: estimate_motion(L0, L1, grid, options=meas), repeat)
    c_full_np = cpu_time(lambda: numpy_full_solve(L0, L1, grid, schedule, meas), 1)
    mem = peak_memory(L0, L1, directions)
    mem_m = peak_memory(L0, L1, directions, False)
    mem_w = peak_memory(L0, L1, directions, with_w=True)
    mem_s = peak_memory(L0, L1, directions, estimates=3)
    mem_sw = peak_memory(L0, L1, directions, with_w=True, estimates=3)
    mem_noisy = peak_memory(L0n, L1n, directions, noisy=True)
    import numba

    threads = numba.get_num_threads()
    print(f"\n## Speed: one face, {grid.y.count}x{grid.x.count} views x {grid.v.count}x{grid.u.count} "
          f"directions = {n / 1e6:.2f} M rays per frame\n")
    print(f"| what | best wall time [ms] | M rays/s | median CPU time [ms], all threads ({threads}) |")
    print("|---|---|---|---|")
    print(f"| derivatives + one linear solve, numba (ours) | {1e3 * t_ours:.1f} | {n / t_ours / 1e6:.0f} "
          f"| {1e3 * c_ours:.1f} |")
    print(f"|   of which derivatives | {1e3 * t_der:.1f} | {n / t_der / 1e6:.0f} | {1e3 * c_der:.1f} |")
    print(f"| derivatives + one linear solve, numpy/scipy baseline | {1e3 * t_base:.1f} | "
          f"{n / t_base / 1e6:.1f} | {1e3 * c_base:.1f} |")
    print(f"| full default estimate (pyramid, warps, Eq. 6 regressors, IRLS, covariance), ours | "
          f"{1e3 * t_full:.0f} | {n / t_full / 1e6:.1f} | {1e3 * c_full:.0f} |")
    print(f"| the same with `depth_regressors=False` (measured L_x, L_y), ours | {1e3 * t_full_m:.0f} | "
          f"{n / t_full_m / 1e6:.1f} | {1e3 * c_full_m:.0f} |")
    print(f"| the default with confidences W0 = W1 = 1 (as a resampled session's frames), ours | "
          f"{1e3 * t_full_w:.0f} | {n / t_full_w / 1e6:.1f} | – |")
    print(f"| the same with samples without data (W = 0 in two direction columns: the warp carries "
          f"a third, \"no data\" channel), ours | {1e3 * t_full_h:.0f} | {n / t_full_h / 1e6:.1f} | – |")
    print(f"| the default on frames with 2 grey levels of noise, ours | {1e3 * t_noisy_d:.0f} | "
          f"{n / t_noisy_d / 1e6:.1f} | – |")
    print(f"| the noise options (`--preset noisy`, `MotionOptions` NOISY) on the same frames, ours | "
          f"{1e3 * t_noisy_p:.0f} | {n / t_noisy_p / 1e6:.1f} | – |")
    print(f"| that algorithm and solve schedule {schedule} in numpy/scipy | {1e3 * t_full_np:.0f} | "
          f"{n / t_full_np / 1e6:.2f} | {1e3 * c_full_np:.0f} |")
    print(f"\nspeed-up of ours over the baselines: derivatives + solve {t_base / t_ours:.1f}x "
          f"(CPU time {c_base / c_ours:.1f}x), full estimate (same algorithm) {t_full_np / t_full_m:.1f}x "
          f"(CPU time {c_full_np / c_full_m:.1f}x; the default with Eq. 6: {t_full_np / t_full:.1f}x); "
          f"targets 33 ms (40 M rays/s) "
          f"{'met' if t_ours <= 0.033 else 'NOT met'} and 133 ms (10 M rays/s) "
          f"{'met' if t_full <= 0.133 else 'NOT met'} in wall time (CPU time / {threads} threads: "
          f"{1e3 * c_ours / threads:.1f} ms and {1e3 * c_full / threads:.0f} ms)")
    d = np.abs(rt_from_T(T_np) - rt_from_T(T_ours))
    print(f"numpy baseline vs ours: max |Δr| = {d[:3].max():.1e} rad, max |Δt| = {d[3:].max():.1e} m")
    print(f"peak memory of one full estimate (growth of the resident set, fresh process): "
          f"{mem / 2**20:.0f} MiB = {mem / L0.nbytes:.1f} x one frame ({L0.nbytes / 2**20:.1f} MiB); "
          f"with depth_regressors=False {mem_m / 2**20:.0f} MiB = {mem_m / L0.nbytes:.1f} frames; "
          f"with confidences W {mem_w / 2**20:.0f} MiB = {mem_w / L0.nbytes:.1f} frames; "
          f"over three consecutive estimates (a session's pairs: the work arrays stay, and the coarse levels' "
          f"frames borrow their idle tails) {mem_s / 2**20:.0f} MiB = {mem_s / L0.nbytes:.1f} frames, "
          f"with W {mem_sw / 2**20:.0f} MiB = {mem_sw / L0.nbytes:.1f} frames; the noise options (NOISY) on the "
          f"frames with 2 grey levels of noise {mem_noisy / 2**20:.0f} MiB = {mem_noisy / L0.nbytes:.1f} frames")
    print(f"depth_regressors (the default) costs +{1e3 * (t_full - t_full_m):.1f} ms wall (best of {2 * repeat}, "
          f"alternating), +{1e3 * (c_full - c_full_m):.0f} ms CPU time")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="fewer distances and motions")
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--skip-accuracy", action="store_true")
    ap.add_argument("--skip-speed", action="store_true")
    ap.add_argument("--measured-regressors", action="store_true",
                    help="also the accuracy rows of MotionOptions(depth_regressors=False) (Eq. 5's measured "
                         "L_x, L_y; the default uses Eq. 6's where less noisy)")
    ap.add_argument("--distances", type=float, nargs="+", default=None,
                    help="scene distances [m] of the accuracy table (default 4 6 8 12 16 24; --quick 4 8 16)")
    ap.add_argument("--supersample", type=int, default=None,
                    help="k x k rays the renderer averages per sample in the accuracy table (default 3; --quick 2)")
    ap.add_argument("--motions", type=int, default=None,
                    help="random motions per distance in the accuracy table (default 3; --quick 1); the "
                         "medians of 3 motions move by ~0.1 %% at 12 m from one set of motions to another")
    ap.add_argument("--plot", metavar="PNG", default=None,
                    help="write the accuracy figure (paper Fig. 5c, measured) to this file")
    args = ap.parse_args()
    if not args.skip_speed:
        speed(args.repeat, 128)
    if not args.skip_accuracy:
        if args.quick:
            accuracy(args.distances or [4.0, 8.0, 16.0], args.motions or 1, args.supersample or 2, 64, plot=args.plot,
                     measured_regressors=args.measured_regressors)
        else:
            accuracy(args.distances or [4.0, 6.0, 8.0, 12.0, 16.0, 24.0], args.motions or 3, args.supersample or 3, 64,
                     plot=args.plot, measured_regressors=args.measured_regressors)


if __name__ == "__main__":
    main()
