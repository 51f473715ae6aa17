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
to 8 bits after adding Gaussian noise of 0, 1 and 3 grey levels.

Speed: one face of 9 x 9 views x 128 x 128 directions (1.33 M rays): derivatives of a
frame pair + one linear solve of Eq. 5, ours (numba kernels) against a numpy / scipy
implementation of the same computation (``scipy.ndimage.correlate1d`` passes, the
coefficient matrix A formed in numpy and AᵀWA by a matrix product), both measured in
this run; plus the full default estimate per pair. Timings are the best of
``--repeat`` runs after a warm-up; the machine (2 cores) may be shared.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from polycam.derivatives import FILTERS, plenoptic_derivatives  # noqa: E402
from polycam.geometry import R_from_r, T_from_Rt, rt_from_T  # noqa: E402
from polycam.motion import MotionOptions, estimate_motion, ray_motion_coefficients, solve_ray_motion  # noqa: E402
from polycam.synth import LightFieldRenderer, default_lightfield_grid, spheres_scene  # noqa: E402

BASELINE = MotionOptions(filters="central", levels=1, iterations=1, irls_steps=0, robust="none",
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


def accuracy(distances, n_motions: int, supersample: int, directions: int) -> None:
    grid = default_lightfield_grid("all", directions=directions)
    print(f"\n## Accuracy: six faces, f = {grid.faces[0].f:g}, {grid.y.count}x{grid.x.count} views "
          f"{grid.x.step * 100:g} cm apart, {grid.v.count}x{grid.u.count} directions, "
          f"supersample {supersample}; |t| = 1.5 cm, |w| = 0.2 deg; {n_motions} motion(s) per D\n")
    print("| D [m] | method | " + " | ".join(f"{n} est/true" for n in NAMES)
          + " | med err t | med err w | time/pair [s] |")
    print("|---|---|" + "---|" * (len(NAMES) + 3))
    summary = []
    noise_at = distances[len(distances) // 2]
    noise_rows = []
    for D in distances:
        scene = spheres_scene(D, seed=0)
        ren = LightFieldRenderer(scene, grid, supersample)
        L0 = ren.render(np.eye(4))
        rng = np.random.default_rng(int(D * 1000))
        motions = [random_motion(rng, 0.015, np.radians(0.2)) for _ in range(n_motions)]
        frames = [ren.render(M) for M in motions]
        for name, opts in (("baseline", BASELINE), ("polycam", MotionOptions())):
            ratios, errs_t, errs_w, times = [], [], [], []
            for M, L1 in zip(motions, frames):
                t0 = time.perf_counter()
                res = estimate_motion(L0, L1, grid, options=opts)
                times.append(time.perf_counter() - t0)
                est, tru = params(res.T_prev_next), params(M)
                ratios.append(est / tru)
                errs_t.append(np.linalg.norm(est[:3] - tru[:3]) / np.linalg.norm(tru[:3]))
                errs_w.append(np.linalg.norm(est[3:] - tru[3:]) / np.linalg.norm(tru[3:]))
            r = np.median(np.array(ratios), axis=0)
            rel = np.abs(np.array(ratios) - 1)
            med_t, med_w = np.median(rel[:, :3]), np.median(rel[:, 3:])
            summary.append((D, name, med_t, med_w))
            if D == noise_at and name == "polycam":
                noise_rows = noise_table(L0, frames[0], motions[0], grid)
            print(f"| {D:g} | {name} | " + " | ".join(f"{v:.4f}" for v in r)
                  + f" | {100 * med_t:.2f}% | {100 * med_w:.2f}% | {np.mean(times):.2f} |", flush=True)
    print("\nmedian relative error per component (|est/true - 1|, median over the 3 components and"
          " the motions);\nvector errors |est - true| / |true| are in the same range.")
    print(f"\n## 8-bit quantisation and sensor noise (D = {noise_at:g} m, first motion)\n")
    print("| noise [grey levels] | method | med err t | med err w | reported std t / err t |")
    print("|---|---|---|---|---|")
    for row in noise_rows:
        print(row)
    base = {D: (t, w) for D, n, t, w in summary if n == "baseline"}
    ours = {D: (t, w) for D, n, t, w in summary if n == "polycam"}
    print("\n| D [m] | baseline err t / ours | baseline err w / ours |")
    print("|---|---|---|")
    for D in distances:
        bt, bw = base[D]
        ot, ow = ours[D]
        print(f"| {D:g} | {bt / max(ot, 1e-12):.0f}x | {bw / max(ow, 1e-12):.0f}x |")


def noise_table(L0, L1, M, grid) -> list[str]:
    """Rows: both frames quantised to 8 bits after adding Gaussian noise (seeded)."""
    rng = np.random.default_rng(7)
    rows = []
    tru = params(M)
    for sigma in (0.0, 1.0, 3.0):
        def q(L):
            return (np.round(np.clip(L + rng.normal(0, sigma / 255, L.shape), 0, 1) * 255) / 255
                    ).astype(np.float32)
        a, b = q(L0), q(L1)
        for name, opts in (("baseline", BASELINE), ("polycam", MotionOptions())):
            res = estimate_motion(a, b, grid, options=opts)
            rel = np.abs(params(res.T_prev_next) / tru - 1)
            err_t = np.linalg.norm(params(res.T_prev_next)[:3] - tru[:3])
            ratio = np.linalg.norm(res.std[:3]) / max(err_t, 1e-15)
            rows.append(f"| {sigma:g} | {name} | {100 * np.median(rel[:3]):.2f}% | "
                        f"{100 * np.median(rel[3:]):.2f}% | {ratio:.2f} |")
    return rows


# ------------------------------------------------------------------ speed


def numpy_derivatives(L0, L1, grid, name="fs5"):
    """The same separable derivatives with scipy.ndimage.correlate1d (baseline)."""
    from scipy.ndimage import correlate1d

    fp = FILTERS[name]
    p, d = fp.prefilter.astype(np.float32), fp.derivative.astype(np.float32)
    S = 0.5 * (L0 + L1)
    D = L1 - L0
    axes = {"y": 1, "x": 2, "v": 3, "u": 4}
    step = {"x": grid.x.step, "y": grid.y.step, "u": grid.u.step, "v": grid.v.step}

    def filt(a, which):
        for ax_name, taps in which.items():
            a = correlate1d(a, taps, axis=axes[ax_name], mode="nearest")
        return a

    out = {}
    for n in ("x", "y", "u", "v"):
        which = {m: (d if m == n else p) for m in axes}
        out[n] = filt(S, which) / np.float32(step[n])
    Lt = filt(D, {m: p for m in axes})
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

    t_ours = best_time(ours, repeat)
    t_der = best_time(ours_der, repeat)
    t_base = best_time(base, max(1, repeat // 2))
    t_full = best_time(lambda: estimate_motion(L0, L1, grid), max(1, repeat // 2))
    c_ours = cpu_time(ours, repeat)
    c_der = cpu_time(ours_der, repeat)
    c_base = cpu_time(base, max(1, repeat // 2))
    c_full = cpu_time(lambda: estimate_motion(L0, L1, grid), max(1, repeat // 2))
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
          f"{n / t_base / 1e6:.0f} | {1e3 * c_base:.1f} |")
    print(f"| full default estimate (pyramid, warps, IRLS, covariance) | {1e3 * t_full:.0f} | "
          f"{n / t_full / 1e6:.1f} | {1e3 * c_full:.0f} |")
    print(f"\nspeed-up of ours over the baseline: {t_base / t_ours:.1f}x (CPU time {c_base / c_ours:.1f}x); "
          f"target 33 ms (40 M rays/s) {'met' if t_ours <= 0.033 else 'NOT met'} in wall time "
          f"(CPU time / {threads} threads: {1e3 * c_ours / threads:.1f} ms)")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="fewer distances and motions")
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--skip-accuracy", action="store_true")
    ap.add_argument("--skip-speed", action="store_true")
    args = ap.parse_args()
    if not args.skip_speed:
        speed(args.repeat, 128)
    if not args.skip_accuracy:
        if args.quick:
            accuracy([4.0, 8.0, 16.0], 1, 2, 64)
        else:
            accuracy([4.0, 6.0, 8.0, 12.0, 16.0], 3, 3, 64)


if __name__ == "__main__":
    main()
