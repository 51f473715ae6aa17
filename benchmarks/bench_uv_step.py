"""Benchmark: ``polycam motion SESSION``'s direction step, ``--uv-step 1`` / ``2`` / ``auto``
(:func:`polycam.run.choose_uv_step`; docs/motion.md "The direction step").

Data: ``polycam synth session`` of each rig (its ``[mock]`` table: the textured room, smooth
motion of 5 mm and 0.2 deg per frame, its noise), one session per seed, with the true camera
models. Each session is opened as ``polycam motion SESSION`` opens it
(:func:`polycam.depth_cli.open_source`: ``polycam run``'s views, the step given or chosen) and
solved with the default solver.

Prints per session and step: the step used, the disparity per view step the solver measured
(median over the pairs) and the (u, v) level it stopped at, the median per-pair translation and
rotation errors relative to the true motion, the RMS over the pairs and axes of error / reported
std (translation, rotation: 1 when the covariance explains the errors), and the wall time of
opening (with ``auto``: choosing) and solving; then per rig the medians over the seeds and the
ratios of each step's translation error and time to ``--uv-step 1``'s (the same sessions, this run).
Usage::

    .venv/bin/python benchmarks/bench_uv_step.py [--rigs mock5x5 mock1x5 oak_d_lite] [--seeds 21 22]
        [--frames 9] [--steps 1 2 auto] [--keep DIR]
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(REPO / "benchmarks"))

from bench_arrays import add_keep_option, room_sessions, sessions_root  # noqa: E402  (this folder)
from polycam.depth_cli import open_source  # noqa: E402
from polycam.evaluate import pair_errors  # noqa: E402
from polycam.geometry import r_from_R  # noqa: E402
from polycam.motion import estimate_trajectory  # noqa: E402


def solve(session: Path, step: str) -> dict:
    """Errors, error / std, chosen step and level, and time of ``polycam motion SESSION --uv-step step``'s
    solve (``auto`` or a number of pixels)."""
    t0 = time.perf_counter()
    lf = open_source(session, uv_step=None if step == "auto" else float(step))
    traj, results = estimate_trajectory(lf)
    seconds = time.perf_counter() - t0
    truth = lf.groundtruth()
    err = pair_errors(traj, truth)
    z = []
    for r, M in zip(results, truth.relative()):
        e = np.concatenate([r.T_prev_next[:3, 3] - M[:3, 3], r_from_R(r.T_prev_next[:3, :3]) - r_from_R(M[:3, :3])])
        z.append(e / r.std)
    z = np.array(z)
    disp = [r.view_disparity for r in results if math.isfinite(r.view_disparity)]
    return {"t": float(np.median(err.t_rel)), "w": float(np.median(err.w_rel)),
            "z_t": float(np.sqrt(np.mean(z[:, :3] ** 2))), "z_w": float(np.sqrt(np.mean(z[:, 3:] ** 2))),
            "step": lf.uv_step_px, "level": int(np.median([r.uv_level for r in results])),
            "disparity": float(np.median(disp)) if disp else math.nan, "seconds": seconds}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--rigs", nargs="+", default=["mock5x5", "mock1x5", "oak_d_lite"], help="rig names under rigs/")
    ap.add_argument("--seeds", nargs="+", type=int, default=[21, 22])
    ap.add_argument("--frames", type=int, default=9)
    ap.add_argument("--steps", nargs="+", default=["1", "2", "auto"],
                    help="--uv-step values to compare (the first is the ratios' baseline)")
    add_keep_option(ap)
    args = ap.parse_args()
    root, tmp = sessions_root(args.keep, "bench_uv_step_")
    rows = []
    print("| rig | seed | --uv-step | step [px] | disparity [samples / view step] | level | translation | rotation "
          "| error / std t, ω (RMS) | open + solve [s] |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for name, seed, session in room_sessions(root, args.rigs, args.seeds, args.frames):
        for step in args.steps:
            r = solve(session, step)
            rows.append((name, seed, step, r))
            print(f"| {name} | {seed} | {step} | {r['step']:g} | {r['disparity']:.2f} | {r['level']} "
                  f"| {100 * r['t']:.2f} % | {100 * r['w']:.2f} % | {r['z_t']:.2f}, {r['z_w']:.2f} "
                  f"| {r['seconds']:.1f} |", flush=True)
    print(f"\nmedian over the seeds; ratios against --uv-step {args.steps[0]} (the same sessions, this run):\n")
    print("| rig | --uv-step | translation | rotation | error / std t, ω | translation ratio | time ratio |")
    print("|---|---|---|---|---|---|---|")
    for name in args.rigs:
        base = {s: r for n, s, st, r in rows if n == name and st == args.steps[0]}
        for step in args.steps:
            sel = [(s, r) for n, s, st, r in rows if n == name and st == step]
            med = {k: np.median([r[k] for _, r in sel]) for k in ("t", "w", "z_t", "z_w")}
            t_ratio = np.median([r["t"] / base[s]["t"] for s, r in sel])
            time_ratio = np.median([r["seconds"] / base[s]["seconds"] for s, r in sel])
            print(f"| {name} | {step} | {100 * med['t']:.2f} % | {100 * med['w']:.2f} % | {med['z_t']:.2f}, "
                  f"{med['z_w']:.2f} | {t_ratio:.2f} | {time_ratio:.2f} |")
    if tmp is not None:
        tmp.cleanup()


if __name__ == "__main__":
    main()
