"""Benchmark: how far the reported covariance explains the motion errors with and without the
calibration's share (``polycam run --calib-draws``; docs/motion.md, "How far to trust the covariance").

Per rig: ``polycam run`` (its mock sessions, an mrcal board calibration, the default 4 draws from that
calibration's uncertainty, each solved at +δ and −δ), then from its report the median over the pairs
of the error norm over the reported std norm (translation, rotation) without the calibration's share
(``√(std² − std_calib²)``) and with it, the calibration's std per pair and its share of the reported
std, and the draws' time against the nominal solve's (this run). Last, why a ratio above 1 may
remain: the calibration's actual pose errors relative to its reference camera (against the true
models) beside what its covariance predicts (``calib.draws.calibration_covariance``).

Usage::

    .venv/bin/python benchmarks/bench_calib_draws.py [--rigs mock5x5 cube6x3x3] [--draws 4] [--keep DIR]

(the nested cube takes ~10 minutes: 144 board frames, 54 cameras)
"""

from __future__ import annotations

import argparse
import csv
import math
import sys
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from polycam.evaluate import pair_errors  # noqa: E402
from polycam.run import RunOptions, run_chain  # noqa: E402
from polycam.trajectory import read_tum  # noqa: E402

from bench_arrays import add_keep_option, sessions_root  # noqa: E402  (this folder)


def ratios(out: Path) -> dict:
    """Errors over the reported std (medians over the pairs) with and without the calibration's share."""
    rows = list(csv.DictReader((out / "report" / "pairs.csv").read_text().splitlines()))
    err = pair_errors(read_tum(out / "trajectory.tum"), read_tum(out / "session" / "groundtruth.tum"))
    res = {"t_with": [], "t_without": [], "w_with": [], "w_without": [], "cal_t": [], "cal_w": [], "share_t": [],
           "share_w": []}
    for k, r in enumerate(rows):
        if r["ok"] != "1" or not r["std_calib_t"]:
            continue
        for axis, name, e in (("t", "t", err.t_err[k]), ("r", "w", err.w_err[k])):
            std = math.sqrt(sum(float(r[f"std_{axis}_{a}"]) ** 2 for a in "xyz"))
            cal = float(r[f"std_calib_{axis}"])
            res[f"{name}_with"].append(e / std)
            res[f"{name}_without"].append(e / math.sqrt(max(std**2 - cal**2, 1e-300)))
            res[f"cal_{name}"].append(cal)
            res[f"share_{name}"].append(cal / std)
    return {k: float(np.median(v)) if v else math.nan for k, v in res.items()}


def calibration_check(out: Path) -> tuple[float, float]:
    """[m] RMS of the calibrated cameras' position errors relative to the solve's reference camera
    (against the true models) and the RMS its covariance predicts."""
    import mrcal

    from calib.draws import calibration_covariance
    from calib.io import load_models

    est, true = load_models(out / "calib"), load_models(out / "session" / "calib")
    cov = calibration_covariance(est)
    ref = cov.cameras[[k for k, e in enumerate(cov.extrinsics) if e is None][0]]
    actual, predicted = [], []
    for k, c in enumerate(cov.cameras):
        if cov.extrinsics[k] is None:
            continue
        # camera centres in the reference camera's frame
        pe = mrcal.transform_point_Rt(est[ref].extrinsics_Rt_fromref(), est[c].extrinsics_Rt_toref()[3])
        pt = mrcal.transform_point_Rt(true[ref].extrinsics_Rt_fromref(), true[c].extrinsics_Rt_toref()[3])
        actual.append(np.linalg.norm(pe - pt))
        b = cov.covariance[cov.extrinsics[k], cov.extrinsics[k]]
        predicted.append(math.sqrt(np.trace(b[3:, 3:])))
    return math.sqrt(np.mean(np.square(actual))), math.sqrt(np.mean(np.square(predicted)))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--rigs", nargs="+", default=["mock5x5", "cube6x3x3"], help="rig names under rigs/")
    ap.add_argument("--draws", type=int, default=RunOptions.calib_draws)
    add_keep_option(ap)
    args = ap.parse_args()
    root, tmp = sessions_root(args.keep, "bench_calib_draws_")
    print("| rig | calibration's std per pair, t / ω (median) | its share of the std, t / ω | errors / std, t: "
          "without → with | ω: without → with | draws' time / nominal solve's | centres vs the reference "
          "camera: actual / predicted RMS |")
    print("|---|---|---|---|---|---|---|")
    for name in args.rigs:
        out = root / name
        summary = run_chain(REPO / "rigs" / f"{name}.toml", out, options=RunOptions(calib_draws=args.draws))
        m = summary["motion"]
        r = ratios(out)
        actual, predicted = calibration_check(out)
        solve_s = m["seconds_per_pair"] * m["pairs"]
        print(f"| {name} | {1e3 * r['cal_t']:.3f} mm / {1e3 * math.degrees(r['cal_w']):.2f} mdeg "
              f"| {100 * r['share_t']:.0f} % / {100 * r['share_w']:.0f} % "
              f"| {r['t_without']:.2f}x → {r['t_with']:.2f}x | {r['w_without']:.2f}x → {r['w_with']:.2f}x "
              f"| {m['seconds_calibration_draws']:.0f} s / {solve_s:.1f} s "
              f"| {1e3 * actual:.2f} / {1e3 * predicted:.2f} mm |", flush=True)
    if tmp is not None:
        tmp.cleanup()


if __name__ == "__main__":
    main()
