"""Benchmark: depth on camera-array sessions, Eq. 7 at the camera views against its refinement
on the cameras' samples (``polycam.depth_refine``; docs/depth.md "Refinement on the captured views").

Data: ``polycam synth session`` of each rig (its ``[mock]`` table: the textured room, smooth motion
of 5 mm and 0.2 deg per frame, its noise), 2 frames per seed, the true cameras perturbed as
``polycam run`` perturbs them (1 mm, 0.3 deg, 0.5 % focal; ``RunOptions``), resampled on the fly
with those true models on ``polycam run``'s grid (``--uv-step 2``; 2 views per camera spacing, 4
when that gives fewer than 5 along x or y). Both methods are ``polycam run``'s depth stage
(``polycam.run._depth``, with the pair's true motion, so only the depth step is measured): without
the store's camera positions (Eq. 7 on the views at the cameras, the rays with captured data) and
with them (Eq. 7's depth refined at the same views on every camera, at their centres).

Prints per rig and seed the median, 90th percentile and share within 5 % of the relative error of
the confident half of the central views' rays against the ray tracer, the rays kept and the stage's
time; then per rig the medians over the seeds and the ratio of the median errors (Eq. 7 / refined,
this run). Usage::

    .venv/bin/python benchmarks/bench_depth_arrays.py [--rigs mock5x5 mock1x5 webcam3x3 mock1x2]
        [--seeds 1 2 3] [--keep DIR]
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from polycam.geometry import T_inverse  # noqa: E402
from polycam.rig import MockSpec, load_rig  # noqa: E402
from polycam.run import RunOptions, _depth, run_grid  # noqa: E402
from polycam.session import open_session  # noqa: E402
from polycam.synth import scene_for_rig, synth_session  # noqa: E402
from resample.pipeline import open_calibration  # noqa: E402
from resample.stream import SessionLightField  # noqa: E402

from bench_arrays import add_keep_option, sessions_root  # noqa: E402  (this folder)


def depth_both(session: Path, rig, report: Path) -> dict:
    """``polycam run``'s depth stage on the session's first pair, without and with the refinement."""
    opts = RunOptions()
    grid, every = run_grid(open_calibration(open_session(session), None), opts)
    lf = SessionLightField(session, grid=grid)
    truth = lf.groundtruth()
    T = T_inverse(truth.T_world_rig[0]) @ truth.T_world_rig[1]
    L0, L1, W0 = lf.frame(0), lf.frame(1), lf.weights(0)
    report.mkdir(parents=True, exist_ok=True)
    scene = (scene_for_rig(rig), truth.T_world_rig[0])
    out = {}
    for name, positions in (("eq7", None), ("refined", lf.camera_positions)):
        t0 = time.perf_counter()
        out[name] = _depth(report, lf.grid, every, L0, L1, W0, T, opts, positions=positions, truth=scene)
        out[name]["seconds"] = time.perf_counter() - t0
    out["grid"] = f"{lf.grid.y.count}x{lf.grid.x.count}x{lf.grid.v.count}x{lf.grid.u.count}"
    return out


def _cells(d: dict) -> str:
    """median | 90th percentile | within 5 % | rays | seconds (includes writing depth.png and points.ply)."""
    if not d.get("truth_rays"):
        return f"no depth | – | – | 0 | {d['seconds']:.1f}"
    return (f"{100 * d['median_rel_error']:.2f} % | {100 * d['p90_rel_error']:.1f} % | {100 * d['within_5pct']:.0f} % "
            f"| {d['points']} | {d['seconds']:.1f}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--rigs", nargs="+", default=["mock5x5", "mock1x5", "webcam3x3", "mock1x2"],
                    help="rig names under rigs/")
    ap.add_argument("--seeds", nargs="+", type=int, default=[1, 2, 3])
    add_keep_option(ap)
    args = ap.parse_args()
    root, tmp = sessions_root(args.keep, "bench_depth_arrays_")
    opts = RunOptions()
    rows = []
    print("| rig | seed | grid (Ny x Nx x Nv x Nu) | Eq. 7: median | 90th pct. | within 5 % | rays | s "
          "| refined: median | 90th pct. | within 5 % | rays | s |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    for name in args.rigs:
        rig = load_rig(REPO / "rigs" / f"{name}.toml")
        for seed in args.seeds:
            rig_s = dataclasses.replace(rig, mock=dataclasses.replace(rig.mock or MockSpec(), seed=seed))
            session = root / f"{name}_seed{seed}"
            if not (session / "groundtruth.tum").exists():
                synth_session(rig_s, session, frames=2, seed=seed, overwrite=True,
                              perturb_position_m=opts.perturb_position_m,
                              perturb_rotation_deg=opts.perturb_rotation_deg,
                              perturb_focal_frac=opts.perturb_focal_frac)
            r = depth_both(session, rig_s, root / f"report_{name}_{seed}")
            rows.append((name, seed, r))
            print(f"| {name} | {seed} | {r['grid']} | {_cells(r['eq7'])} | {_cells(r['refined'])} |", flush=True)
    print("\nmedian over the seeds; ratio = Eq. 7's median error / the refined one's (the same sessions, this run):\n")
    print("| rig | Eq. 7 median | refined median | ratio (per seed) |")
    print("|---|---|---|---|")
    for name in args.rigs:
        sel = [r for n, _, r in rows if n == name]
        e7 = np.array([r["eq7"].get("median_rel_error", np.nan) for r in sel])
        rf = np.array([r["refined"].get("median_rel_error", np.nan) for r in sel])
        ratios = e7 / rf
        med = (lambda a: float(np.nanmedian(a)) if np.isfinite(a).any() else float("nan"))
        e7_txt = "no depth" if not np.isfinite(e7).any() else f"{100 * med(e7):.2f} %"
        print(f"| {name} | {e7_txt} | {100 * med(rf):.2f} % | {med(ratios):.1f} "
              f"({', '.join(f'{q:.1f}' for q in ratios)}) |")
    if tmp is not None:
        tmp.cleanup()


if __name__ == "__main__":
    main()
