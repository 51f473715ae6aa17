"""Benchmark: the motion solver on camera-array sessions against how the views between the cameras
are filled (``resample.viewfill``; docs/resample.md, steps 5 and 6): 2 or 4 views per camera spacing,
the plane sweep's disparity refined at full resolution or not (``ViewFillOptions.refine``), the camera
views re-centred onto their grid views or not (``ViewFillOptions.recentre``).

Data: ``polycam synth session`` of each rig (its ``[mock]`` table: the textured room, smooth motion
of 5 mm and 0.2 deg per frame, its noise), one session per seed, the true cameras perturbed as
``polycam run`` perturbs them (1 mm, 0.3 deg, 0.5 % focal; ``RunOptions``) and used as the models.
Each session is resampled on the fly (``resample.stream.SessionLightField``, ``--uv-step``) and
solved with the default options.

Prints per rig and variant, pooled over every frame pair of the seeds: the median (and mean)
translation and rotation errors relative to the true motion, the median ratio of the estimated
translation's component along the true one (1: no scale error), and the resampling time per frame;
then per rig the ratio of each variant's median translation error to the first variant's (this run).
Usage::

    .venv/bin/python benchmarks/bench_view_fill.py [--rigs webcam3x3 mock5x5 oak_array mock1x5 oak_d_lite]
        [--seeds 3 11 12 13] [--frames 6] [--variants 2:off 2:on 4:off 4:on 2:auto:keep] [--uv-step 2] [--keep DIR]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from polycam.evaluate import pair_errors  # noqa: E402
from polycam.geometry import T_inverse  # noqa: E402
from polycam.motion import estimate_trajectory  # noqa: E402
from polycam.rig import load_rig  # noqa: E402
from polycam.run import RunOptions  # noqa: E402
from polycam.synth import synth_session  # noqa: E402
from resample.resampler import ResampleOptions  # noqa: E402
from resample.stream import SessionLightField  # noqa: E402
from resample.viewfill import ViewFillOptions  # noqa: E402

from bench_arrays import add_keep_option, sessions_root  # noqa: E402  (this folder)


def solve(session: Path, xy: int, refine: bool | None, uv_step: float, recentre: bool = True) -> dict:
    """Per-pair errors and along-ratios of the default solver on the session resampled with ``xy``
    views per camera spacing and ``ViewFillOptions(refine=refine, recentre=recentre)``."""
    lf = SessionLightField(session, uv_step_px=uv_step, xy_oversample=xy,
                           options=ResampleOptions(fill=ViewFillOptions(refine=refine, recentre=recentre)))
    traj, _ = estimate_trajectory(lf)
    truth = lf.groundtruth()
    err = pair_errors(traj, truth)
    along = []
    for k in range(len(traj.T_world_rig) - 1):
        te = (T_inverse(traj.T_world_rig[k]) @ traj.T_world_rig[k + 1])[:3, 3]
        tg = (T_inverse(truth.T_world_rig[k]) @ truth.T_world_rig[k + 1])[:3, 3]
        along.append(float(te @ tg / (tg @ tg)))
    return {"t": list(err.t_rel), "w": list(err.w_rel), "along": along,
            "resample_s": lf.seconds_frames / max(1, lf.frames_resampled)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--rigs", nargs="+", default=["webcam3x3", "mock5x5", "oak_array", "mock1x5", "oak_d_lite"],
                    help="rig names under rigs/")
    ap.add_argument("--seeds", nargs="+", type=int, default=[3, 11, 12, 13])
    ap.add_argument("--frames", type=int, default=6)
    ap.add_argument("--variants", nargs="+", default=["2:off", "2:on", "4:off", "4:on"],
                    help="XY:REFINE[:keep] items: views per camera spacing, the fill's refine (on, off, auto), "
                         "and keep: the camera views not re-centred; the first is the ratios' baseline")
    ap.add_argument("--uv-step", type=float, default=2.0, help="direction spacing of the grid in camera pixels")
    add_keep_option(ap)
    args = ap.parse_args()
    root, tmp = sessions_root(args.keep, "bench_view_fill_")
    opts = RunOptions()
    variants = []
    for item in args.variants:
        xy, refine, *keep = item.split(":")
        variants.append((item, int(xy), {"on": True, "off": False, "auto": None}[refine], keep != ["keep"]))
    rows = {}
    print("| rig | views per camera spacing : refine | pairs | translation median (mean) | rotation median (mean) "
          "| along-ratio median | resample s / frame |")
    print("|---|---|---|---|---|---|---|")
    for name in args.rigs:
        rig = load_rig(REPO / "rigs" / f"{name}.toml")
        for label, xy, refine, recentre in variants:
            acc = {"t": [], "w": [], "along": [], "resample_s": []}
            for seed in args.seeds:
                session = root / f"{name}_seed{seed}_f{args.frames}"
                if not (session / "groundtruth.tum").exists():
                    synth_session(rig, session, frames=args.frames, seed=seed, overwrite=True,
                                  perturb_position_m=opts.perturb_position_m,
                                  perturb_rotation_deg=opts.perturb_rotation_deg,
                                  perturb_focal_frac=opts.perturb_focal_frac)
                r = solve(session, xy, refine, args.uv_step, recentre)
                for k in acc:
                    acc[k] += r[k] if isinstance(r[k], list) else [r[k]]
            rows[(name, label)] = acc
            t, w = np.array(acc["t"]), np.array(acc["w"])
            print(f"| {name} | {label} | {len(t)} | {100 * np.median(t):.2f} % ({100 * np.mean(t):.2f}) "
                  f"| {100 * np.median(w):.2f} % ({100 * np.mean(w):.2f}) | {np.median(acc['along']):.3f} "
                  f"| {np.median(acc['resample_s']):.2f} |", flush=True)
    print(f"\nmedian translation error against {variants[0][0]} (the same sessions, this run):\n")
    print("| rig | " + " | ".join(v[0] for v in variants) + " |")
    print("|---|" + "---|" * len(variants))
    for name in args.rigs:
        base = np.median(rows[(name, variants[0][0])]["t"])
        print(f"| {name} | " + " | ".join(f"{np.median(rows[(name, v[0])]['t']) / base:.2f}" for v in variants) + " |")
    if tmp is not None:
        tmp.cleanup()


if __name__ == "__main__":
    main()
