"""Per-pair motion diagnostics as a CSV file (the I/O beside :mod:`polycam.motion`).

One row per frame pair ``(i, i+1)``::

    pair,timestamp_ns,t_x,t_y,t_z,r_x,r_y,r_z,std_t_x,std_t_y,std_t_z,std_r_x,std_r_y,std_r_z,
    std_noise_t,std_noise_r,level_change_t,level_change_r,std_calib_t,std_calib_r,sigma,noise_sigma,
    uv_level,view_disparity,condition,inlier_fraction,num_rays,iterations,ok,unobservable,reason,
    std_sync_t,std_sync_r,std_sampling_t,std_sampling_r,parallax

``t`` [m] and ``r`` [rad] (axis-angle) are those of ``T_rig[i]_rig[i+1]``; ``std_*``
the square roots of the covariance diagonal; ``std_noise_t`` [m] and ``std_noise_r`` [rad] the
norms (√Σ of the squares over the three axes) of the part of them the residuals' scatter explains
(``PairResult.covariance_noise``), ``level_change_t`` [m] and ``level_change_r`` [rad] the norms of
the change from the coarser (u, v) level's estimate that the covariance adds as model error
(``PairResult.level_change``; empty with one level), ``std_calib_t`` [m] and ``std_calib_r`` [rad]
the norms of the part the calibration's error explains (``PairResult.covariance_calibration``,
``polycam motion --calib-draws``; empty when not measured), ``std_sync_t`` [m] and ``std_sync_r`` [rad]
those of the part unsynchronised cameras' capture times explain
(``PairResult.covariance_sync``, ``polycam motion --sync-draws``; empty when not measured), and
``std_sampling_t`` [m] and ``std_sampling_r`` [rad] those of the change on a second view sampling
(``PairResult.covariance_sampling``, ``polycam motion --sampling-check``; empty when not measured); ``sigma`` the
robust residual scale and
``noise_sigma`` the frames' sensor noise per sample (both in intensity units, as
:class:`~polycam.motion.PairResult`'s); ``timestamp_ns`` is frame i+1's (empty when not
given); ``uv_level`` the (u, v) pyramid level the estimate comes from and ``view_disparity``
the disparity per view step [samples] that chose it (empty when not measured;
:class:`~polycam.motion_options.MotionOptions` ``max_view_disparity``); ``unobservable`` lists
direction names separated by ``;``; ``parallax`` is the smallest signal fraction of the translation
directions (``PairResult.parallax_fraction``: ~1 parallax well above the noise, below
``MotionOptions.parallax_min`` the translation is unobservable; empty when not measured).
"""

from __future__ import annotations

import csv
import io
import os
from dataclasses import fields
from typing import Sequence

import numpy as np

from .calib_spread import calibration_std, capture_timing_std, view_sampling_std
from .evaluate import std_norms
from .motion import MotionOptions, PairResult
from .tomlio import atomic_write_text

__all__ = ["PAIR_REPORT_COLUMNS", "write_pair_report", "write_motion_report"]

PAIR_REPORT_COLUMNS = (
    "pair", "timestamp_ns", "t_x", "t_y", "t_z", "r_x", "r_y", "r_z",
    "std_t_x", "std_t_y", "std_t_z", "std_r_x", "std_r_y", "std_r_z",
    "std_noise_t", "std_noise_r", "level_change_t", "level_change_r", "std_calib_t", "std_calib_r",
    "sigma", "noise_sigma", "uv_level", "view_disparity", "condition", "inlier_fraction", "num_rays", "iterations",
    "ok", "unobservable", "reason", "std_sync_t", "std_sync_r", "std_sampling_t", "std_sampling_r", "parallax",
)


def write_pair_report(results: Sequence[PairResult], path_csv: str | os.PathLike,
                      timestamps_ns: np.ndarray | None = None) -> None:
    """Write the per-pair results atomically as CSV (columns: :data:`PAIR_REPORT_COLUMNS`).

    ``timestamps_ns``: optional (N,) frame timestamps; pair i gets frame i+1's.
    """
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(PAIR_REPORT_COLUMNS)
    cal_t, cal_r = std_norms(calibration_std(results))
    sync_t, sync_r = std_norms(capture_timing_std(results))
    samp_t, samp_r = std_norms(view_sampling_std(results))
    for k, r in enumerate(results):
        ts = "" if timestamps_ns is None else str(int(timestamps_ns[r.index + 1]))
        std = r.std
        noise = std_norms(np.sqrt(np.clip(np.diag(r.covariance_noise), 0.0, None)))
        d = r.level_change                   # its norms as std_norms takes them: √Σ d² over t and r
        change = [f"{v[0]:.6g}" for v in std_norms(np.abs(d))] if np.all(np.isfinite(d)) else ["", ""]
        w.writerow([r.index, ts, *(f"{v:.9g}" for v in r.t), *(f"{v:.9g}" for v in r.r),
                    *(f"{v:.6g}" for v in std), *(f"{v[0]:.6g}" for v in noise),
                    *change, *(f"{v[k]:.6g}" if np.isfinite(v[k]) else "" for v in (cal_t, cal_r)),
                    f"{r.sigma:.6g}", f"{r.noise_sigma:.6g}", r.uv_level,
                    f"{r.view_disparity:.4g}" if np.isfinite(r.view_disparity) else "", f"{r.condition:.6g}",
                    f"{r.inlier_fraction:.4f}", r.num_rays, r.iterations, int(r.ok),
                    ";".join(r.unobservable), r.reason,
                    *(f"{v[k]:.6g}" if np.isfinite(v[k]) else "" for v in (sync_t, sync_r, samp_t, samp_r)),
                    f"{r.parallax_fraction[0]:.3f}" if np.isfinite(r.parallax_fraction[0]) else ""])
    atomic_write_text(path_csv, buf.getvalue())


def write_motion_report(report_dir: str | os.PathLike, results: Sequence[PairResult], traj,
                        truth=None, timestamps_ns: np.ndarray | None = None,
                        options: MotionOptions | None = None, scale_selection: bool | None = None,
                        preset: str | None = None, grid: dict | None = None) -> list[str]:
    """A report folder: ``pairs.csv``, ``trajectory.png``, with a ground truth
    ``errors.png`` (each pair's error beside the norm of its reported standard
    deviations), and with ``options`` ``options.toml`` (the solver's settings: every
    :class:`~polycam.motion.MotionOptions` field under ``[motion]``, ``scale_selection`` and
    ``preset`` (the ``--preset`` the options started from) too when given, and ``grid`` (how a
    session was resampled on the fly, e.g. its direction step) under ``[grid]``, so that
    a report says how it was made). Returns the names of the
    files written.

    traj, truth: :class:`~polycam.trajectory.Trajectory` (``truth`` optional, same timestamps).
    """
    from pathlib import Path

    from .evaluate import pair_errors
    from .plots import plot_pair_errors, plot_trajectory

    report = Path(report_dir)
    report.mkdir(parents=True, exist_ok=True)
    write_pair_report(results, report / "pairs.csv", timestamps_ns)
    plot_trajectory(report / "trajectory.png", traj, truth)
    written = ["pairs.csv", "trajectory.png"]
    if truth is not None:
        plot_pair_errors(report / "errors.png", pair_errors(traj, truth), np.stack([r.std for r in results]),
                         solved=np.array([bool(r) for r in results]))
        written.append("errors.png")
    if options is not None:
        import tomli_w

        doc = {f.name: getattr(options, f.name) for f in fields(options)}
        if scale_selection is not None:
            doc["scale_selection"] = bool(scale_selection)
        if preset is not None:
            doc["preset"] = preset
        tables = {"motion": doc} if grid is None else {"motion": doc, "grid": dict(grid)}
        atomic_write_text(report / "options.toml", "# polycam motion: the solver's settings (MotionOptions)"
                          + (" and the grid a session was resampled on" if grid is not None else "") + "\n"
                          + tomli_w.dumps(tables))
        written.append("options.toml")
    return written
