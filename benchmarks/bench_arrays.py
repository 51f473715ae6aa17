"""Benchmark: the motion solver on camera-array sessions with and without the plenoptic
sampling rule (``MotionOptions.max_view_disparity``), the warp's blend of the views along the
disparity (``MotionOptions.depth_views``; docs/motion.md "Camera arrays"), the discontinuity
weight on resampled frames (``MotionOptions.smooth_c_resampled``; docs/motion.md "The
discontinuity weight on resampled sessions") and, on linear arrays, the view filter's gain
(``MotionOptions.linear_gain``; docs/motion.md "The view filter's gain").

Data: ``polycam synth session`` of each rig (its ``[mock]`` table: the textured room, smooth
motion of 5 mm and 0.2 deg per frame, its noise), one session per seed, with the true
camera models. Each session is resampled on the fly (``resample.stream.SessionLightField``,
the automatic grid with ``--uv-step``, as ``polycam motion SESSION`` did until session 44; with
``--run-grid`` on ``polycam run``'s grid, :func:`polycam.run.session_grid`, as it does since: 2 views
per camera spacing, or 4 where 2 give fewer than 5 along x or y) and solved with the
default :class:`~polycam.motion_options.MotionOptions` once per threshold (``inf``: always the
frames' own (u, v) sampling, the solver before session 30), ``depth_views`` value (``inf``: the
plain blend, the solver before session 43), ``smooth_c_resampled`` value (0.5: the solver before
session 44) and ``linear_gain`` (off: the solver before session 46; no effect on 2-D arrays).

Prints per session and setting: the disparity per view step the solver measured (median over
the pairs), the (u, v) level it stopped at, the median per-pair translation and rotation errors
relative to the true motion, the ATE and the solve time per pair; then per rig the medians over
the seeds and the ratio of each setting's ATE to the last one's (measured in the same run).
Usage::

    .venv/bin/python benchmarks/bench_arrays.py [--rigs webcam3x3 mock5x5] [--seeds 3 11 12 13]
        [--frames 9] [--thresholds 0.75 inf] [--depth-views 0.25] [--smooth-c-resampled 0 0.5]
        [--linear-gain on off] [--uv-step 1] [--run-grid] [--keep DIR]
"""

from __future__ import annotations

import argparse
import math
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from polycam.evaluate import ate_rmse, pair_errors  # noqa: E402
from polycam.motion import estimate_trajectory  # noqa: E402
from polycam.motion_options import MotionOptions  # noqa: E402
from polycam.rig import load_rig  # noqa: E402
from polycam.run import session_grid  # noqa: E402
from polycam.synth import synth_session  # noqa: E402
from resample.stream import SessionLightField  # noqa: E402


def solve(session: Path, threshold: float, uv_step: float, depth_views: float = MotionOptions.depth_views,
          smooth_c_resampled: float = MotionOptions.smooth_c_resampled,
          linear_gain: bool = MotionOptions.linear_gain, run_grid: bool = False) -> dict:
    """Errors, chosen level and time of the default solver with ``max_view_disparity=threshold``,
    ``depth_views``, ``smooth_c_resampled`` and ``linear_gain``, on the automatic grid or (``run_grid``)
    ``polycam run``'s."""
    lf = SessionLightField(session, uv_step_px=uv_step)
    if run_grid:
        lf = SessionLightField(session, grid=session_grid(lf.models, uv_step)[0])
    t0 = time.perf_counter()
    traj, results = estimate_trajectory(lf, options=MotionOptions(max_view_disparity=threshold,
                                                                  depth_views=depth_views,
                                                                  smooth_c_resampled=smooth_c_resampled,
                                                                  linear_gain=linear_gain))
    seconds = time.perf_counter() - t0 - lf.seconds_frames
    truth = lf.groundtruth()
    err = pair_errors(traj, truth)
    disp = [r.view_disparity for r in results if math.isfinite(r.view_disparity)]
    return {"t": float(np.median(err.t_rel)), "w": float(np.median(err.w_rel)), "ate": ate_rmse(traj, truth),
            "level": int(np.median([r.uv_level for r in results])),
            "disparity": float(np.median(disp)) if disp else math.nan,
            "failed": sum(1 for r in results if not r), "seconds": seconds / max(1, len(results))}


def setting_text(setting: tuple) -> str:
    """``0.75 / 0.25 / 0 / on``: a setting's values as the tables print them."""
    return " / ".join(q if isinstance(q, str) else f"{q:g}" for q in setting)


def add_keep_option(ap: argparse.ArgumentParser) -> None:
    """``--keep DIR``: the sessions' folder, kept and reused (see :func:`sessions_root`)."""
    ap.add_argument("--keep", type=Path, help="render the sessions into this folder and keep them (reused "
                                               "when already there)")


def room_sessions(root: Path, rigs, seeds, frames: int):
    """(rig name, seed, session folder) of a ``polycam synth session`` of the room per rig under rigs/
    and seed, in ``root`` (rendered once: a folder already there is reused)."""
    for name in rigs:
        rig = load_rig(REPO / "rigs" / f"{name}.toml")
        for seed in seeds:
            session = root / f"{name}_seed{seed}_f{frames}"
            if not (session / "groundtruth.tum").exists():
                synth_session(rig, session, frames=frames, seed=seed, scene="room", overwrite=True)
            yield name, seed, session


def sessions_root(keep: Path | None, prefix: str):
    """(root, tmp): ``keep``, or a temporary folder named ``prefix...`` and its handle to clean up."""
    if keep is not None:
        return keep, None
    tmp = tempfile.TemporaryDirectory(prefix=prefix)
    return Path(tmp.name), tmp


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--rigs", nargs="+", default=["webcam3x3", "mock5x5"], help="rig names under rigs/")
    ap.add_argument("--seeds", nargs="+", type=int, default=[3, 11, 12, 13])
    ap.add_argument("--frames", type=int, default=9)
    ap.add_argument("--thresholds", nargs="+", type=float, default=[0.75, math.inf],
                    help="max_view_disparity values to compare")
    ap.add_argument("--depth-views", nargs="+", type=float, default=[MotionOptions.depth_views],
                    help="depth_views values to compare (with each threshold; the last pair is the ratios' "
                         "baseline)")
    ap.add_argument("--smooth-c-resampled", nargs="+", type=float, default=[MotionOptions.smooth_c_resampled],
                    help="smooth_c_resampled values to compare (with each threshold and depth_views)")
    ap.add_argument("--linear-gain", nargs="+", choices=["on", "off"], default=["on"],
                    help="linear_gain values to compare (with each of the above; linear arrays only)")
    ap.add_argument("--uv-step", type=float, default=1.0, help="direction spacing of the grid in camera pixels")
    ap.add_argument("--run-grid", action="store_true", help="resample on polycam run's grid (2 or 4 views per "
                                                            "camera spacing) instead of the automatic one")
    add_keep_option(ap)
    args = ap.parse_args()
    root, tmp = sessions_root(args.keep, "bench_arrays_")
    rows = []
    settings = [(thr, dv, sc, lg) for thr in args.thresholds for dv in args.depth_views
                for sc in args.smooth_c_resampled for lg in args.linear_gain]
    label = "max_view_disparity / depth_views / smooth_c_resampled / linear_gain"
    print(f"| rig | seed | {label} | disparity [samples / view step] | level | translation "
          "| rotation | ATE [mm] | solve s / pair | failed |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for name, seed, session in room_sessions(root, args.rigs, args.seeds, args.frames):
        for thr, dv, sc, lg in settings:
            r = solve(session, thr, args.uv_step, dv, sc, lg == "on", args.run_grid)
            rows.append((name, seed, (thr, dv, sc, lg), r))
            print(f"| {name} | {seed} | {setting_text((thr, dv, sc, lg))} | {r['disparity']:.2f} | {r['level']} "
                  f"| {100 * r['t']:.2f} % | {100 * r['w']:.2f} % | {1e3 * r['ate']:.3f} | {r['seconds']:.2f} "
                  f"| {r['failed']} |", flush=True)
    print(f"\nmedian over the seeds; ATE ratio against {label} = "
          f"{setting_text(settings[-1])} (the same sessions, this run):\n")
    print(f"| rig | {label} | translation | rotation | ATE [mm] | ATE ratio (per seed) |")
    print("|---|---|---|---|---|---|")
    for name in args.rigs:
        base = {s: r["ate"] for n, s, t, r in rows if n == name and t == settings[-1]}
        for setting in settings:
            sel = [(s, r) for n, s, t, r in rows if n == name and t == setting]
            ratios = [r["ate"] / base[s] for s, r in sel if base.get(s)]
            print(f"| {name} | {setting_text(setting)} | {100 * np.median([r['t'] for _, r in sel]):.2f} % "
                  f"| {100 * np.median([r['w'] for _, r in sel]):.2f} % | {1e3 * np.median([r['ate'] for _, r in sel]):.3f} "
                  f"| {np.median(ratios):.2f} ({', '.join(f'{q:.2f}' for q in ratios)}) |")
    if tmp is not None:
        tmp.cleanup()


if __name__ == "__main__":
    main()
