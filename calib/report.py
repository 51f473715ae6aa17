"""The calibration report: per-camera residual statistics, skipped images, projection
uncertainty, the camera graph, and plots (files written by :func:`write_report`).

``CALIB_DIR/report.toml`` (machine-readable) and ``CALIB_DIR/report.md`` (for people)
hold the same numbers; ``CALIB_DIR/plots/`` has ``residuals_<cam>.png`` (residual
vectors over the imager and their histogram), ``uncertainty.png`` (worst-direction
projection uncertainty per camera at the median board distance) and
``camera_graph.png`` (frames each pair of cameras saw the board in together, drawn
on the solved camera layout). Residual RMS values use mrcal's convention: per
coordinate, ``sqrt(mean(ex^2 + ey^2) / 2)``.
"""

from __future__ import annotations

import logging
import math
import os
from pathlib import Path

import numpy as np

from polycam.geometry import r_from_R
from polycam.tomlio import atomic_write_bytes, atomic_write_text

from .board_solve import (BoardCalibration, board_distance, extrinsics_uncertainty, observation_residuals,
                          uncertainty_grid)

__all__ = ["report_dict", "write_report"]

log = logging.getLogger(__name__)


def _f(x: float, nd: int = 4) -> float:
    return float(round(float(x), nd)) if np.isfinite(x) else float("nan")


def report_dict(cal: BoardCalibration, *, uncertainty: dict | None = None) -> dict:
    """The report as a TOML-ready dict (see docs/calibration.md for the keys)."""
    obs = cal.observations
    fit = cal.rig_fit
    inputs = cal.optimization_inputs
    doc: dict = {
        "calibration": {
            "method": "mrcal",
            "lensmodel": cal.lensmodel,
            "board": str(obs.board.path) if obs.board.path is not None else obs.board.type,
            "cameras": list(cal.cameras),
            "frames": int(len(cal.frames)),
            "views": int(len(obs.indices_frame_camera)),
            "rms_px": _f(cal.rms_px),
            "outliers": int(sum(s.outliers for s in cal.stats.values())),
            "board_distance_m": _f(board_distance(inputs)),
            "calobject_warp_m": [float(v) for v in (inputs.get("calobject_warp")
                                                     if inputs.get("calobject_warp") is not None else [0.0, 0.0])],
            "stages": [{"stage": n, "rms_px": _f(r)} for n, r in cal.stages],
            "rig_fit": {
                "kind": "rigid (rotation + translation, no scale) to the rig file's nominal poses",
                "position_rms_m": _f(float(np.sqrt(np.mean(fit.position_residuals_m**2))), 6),
                "position_max_m": _f(float(fit.position_residuals_m.max()), 6),
                "rotation_rms_deg": _f(math.degrees(float(np.sqrt(np.mean(fit.rotation_residuals_rad**2))))),
                "rotation_max_deg": _f(math.degrees(float(fit.rotation_residuals_rad.max()))),
            },
        },
        "camera": {},
        "graph": {"cameras": list(cal.cameras), "shared_frames": cal.shared_frames.astype(int).tolist()},
    }
    T = cal.T_rig_cam
    sigma = None
    if uncertainty is not None:
        try:        # predicted pose errors relative to camera 0 at the solve's residual noise level
            sigma = extrinsics_uncertainty(inputs, cal.rms_px)
        except Exception as e:  # degenerate solves: leave the keys out rather than fail the report
            log.warning("pose uncertainty not computed: %s", str(e).strip().splitlines()[0] if str(e) else e)
    for ci, cam in enumerate(cal.cameras):
        st = cal.stats[cam]
        lens, intr = cal.models[cam].intrinsics()
        entry = {
            "images": int(obs.counts.get(cam, {}).get("images", 0)),
            "views": st.views,
            "corners": st.corners,
            "outliers": st.outliers,
            "rms_px": _f(st.rms_px),
            "worst_px": _f(st.worst_px),
            "worst_image": st.worst_path,
            "skipped": {k: int(v) for k, v in obs.counts.get(cam, {}).items() if k not in ("images", "used")},
            "intrinsics": [float(v) for v in intr],
            "position_m": [_f(v, 6) for v in T[cam][:3, 3]],
            "rotation_rad": [_f(v, 6) for v in r_from_R(T[cam][:3, :3])],
            "rig_fit_position_m": _f(fit.position_residuals_m[ci], 6),
            "rig_fit_rotation_deg": _f(math.degrees(fit.rotation_residuals_rad[ci])),
        }
        if uncertainty is not None and cam in uncertainty:
            u = uncertainty[cam]
            ny, nx = u.shape
            entry["uncertainty_px"] = {"centre": _f(u[ny // 2, nx // 2]), "median": _f(np.nanmedian(u)),
                                       "worst": _f(np.nanmax(u))}
        if sigma is not None:
            entry["pose_sigma_vs_first_camera"] = {"position_m": _f(sigma[ci, 1], 7),
                                                   "rotation_deg": _f(math.degrees(sigma[ci, 0]), 5)}
        doc["camera"][cam] = entry
    return doc


def _markdown(doc: dict, cal: BoardCalibration, plots: list[str]) -> str:
    c = doc["calibration"]
    fit = c["rig_fit"]
    lines = [
        "# Calibration report",
        "",
        f"- method: mrcal, lens model `{c['lensmodel']}`, board `{c['board']}`",
        f"- {len(c['cameras'])} cameras, {c['frames']} board poses, {c['views']} views; "
        f"RMS reprojection error {c['rms_px']:.3f} px (per coordinate), {c['outliers']} outlier corners",
        f"- median board distance {c['board_distance_m']:.3f} m; board flex {c['calobject_warp_m']} m",
        f"- rig frame: {fit['kind']}; camera centres within {1e3 * fit['position_max_m']:.2f} mm "
        f"(RMS {1e3 * fit['position_rms_m']:.2f} mm) and orientations within {fit['rotation_max_deg']:.3f} deg "
        "of nominal",
        "- stages: " + ", ".join(f"{s['stage']} {s['rms_px']:.3f} px" for s in c["stages"]),
        "",
        "## Cameras",
        "",
        "| camera | images | views | corners | outliers | RMS px | worst px | uncertainty px (centre / median / worst) | skipped |",
        "| --- | --- | --- | --- | --- | --- | --- | --- | --- |",
    ]
    for cam, e in doc["camera"].items():
        u = e.get("uncertainty_px")
        us = f"{u['centre']:.3f} / {u['median']:.3f} / {u['worst']:.3f}" if u else "-"
        sk = ", ".join(f"{v} {k}" for k, v in e["skipped"].items() if v) or "-"
        lines.append(f"| {cam} | {e['images']} | {e['views']} | {e['corners']} | {e['outliers']} | "
                     f"{e['rms_px']:.3f} | {e['worst_px']:.3f} | {us} | {sk} |")
    lines += ["", "Worst residual per camera:", ""]
    for cam, e in doc["camera"].items():
        lines.append(f"- {cam}: {e['worst_px']:.3f} px in `{e['worst_image']}`")
    skipped = cal.observations.skipped
    if any(files for per in skipped.values() for files in per.values()):
        lines += ["", "## Skipped images", ""]
        for cam, per in skipped.items():
            for reason, files in per.items():
                if files:
                    lines.append(f"- {cam}, {reason} ({len(files)}): " + ", ".join(f"`{f}`" for f in files))
    lines += ["", "## Camera graph (frames in which both cameras saw the board)", "",
              "| | " + " | ".join(cal.cameras) + " |", "| --- " * (len(cal.cameras) + 1) + "|"]
    for cam, row in zip(cal.cameras, cal.shared_frames):
        lines.append(f"| {cam} | " + " | ".join(str(int(v)) if v else "." for v in row) + " |")
    if plots:
        lines += ["", "## Plots", ""] + [f"![{Path(p).stem}]({p})" for p in plots]
    return "\n".join(lines) + "\n"


def _savefig(fig, path: Path) -> None:
    import io

    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=90)
    atomic_write_bytes(path, buf.getvalue())


def _plots(cal: BoardCalibration, out: Path, uncertainty: dict | None) -> list[str]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    d = out / "plots"
    d.mkdir(parents=True, exist_ok=True)
    written = []
    inputs = cal.optimization_inputs
    err, w = observation_residuals(inputs)
    obs = inputs["observations_board"]
    ci_of = inputs["indices_frame_camintrinsics_camextrinsics"][:, 1]
    for ci, cam in enumerate(cal.cameras):
        sel = ci_of == ci
        inl = w[sel] > 0
        q, e = obs[sel][..., :2][inl], err[sel][inl]
        W, H = cal.models[cam].imagersize()
        fig, (a0, a1) = plt.subplots(1, 2, figsize=(10, 4))
        scale = 0.05 * W / max(float(np.sqrt(np.mean(e**2))) if e.size else 1.0, 1e-6)
        a0.quiver(q[:, 0], q[:, 1], e[:, 0] * scale, e[:, 1] * scale, np.linalg.norm(e, axis=1),
                  angles="xy", scale_units="xy", scale=1, cmap="viridis", width=0.003)
        a0.set_xlim(-0.5, W - 0.5)
        a0.set_ylim(H - 0.5, -0.5)
        a0.set_aspect("equal")
        a0.set_title(f"{cam}: residuals (x{scale:.0f})")
        a1.hist(e.ravel(), bins=60, color="0.3")
        a1.set_xlabel("residual [px] (x and y)")
        a1.set_title(f"RMS {cal.stats[cam].rms_px:.3f} px, worst {cal.stats[cam].worst_px:.3f} px")
        fig.tight_layout()
        name = f"plots/residuals_{cam}.png"
        _savefig(fig, out / name)
        plt.close(fig)
        written.append(name)
    if uncertainty:
        n = len(cal.cameras)
        cols = int(math.ceil(math.sqrt(n)))
        rows = int(math.ceil(n / cols))
        fig, axes = plt.subplots(rows, cols, figsize=(3 * cols, 2.4 * rows), squeeze=False)
        vmax = float(np.nanmax([np.nanmax(u) for u in uncertainty.values()] + [1e-9]))
        for k, ax in enumerate(axes.ravel()):
            ax.axis("off")
            if k < n:
                cam = cal.cameras[k]
                im = ax.imshow(uncertainty[cam], vmin=0, vmax=vmax, cmap="magma")
                ax.set_title(cam, fontsize=8)
        fig.colorbar(im, ax=axes.ravel().tolist(), label="worst-direction stdev [px]")
        name = "plots/uncertainty.png"
        _savefig(fig, out / name)
        plt.close(fig)
        written.append(name)
    # camera graph on the solved layout (x, y of the rig frame)
    T = cal.T_rig_cam
    p = np.stack([T[c][:3, 3] for c in cal.cameras])
    fig, ax = plt.subplots(figsize=(5, 5))
    mx = max(int(cal.shared_frames.max()), 1)
    for i in range(len(cal.cameras)):
        for j in range(i + 1, len(cal.cameras)):
            s = int(cal.shared_frames[i, j])
            if s:
                ax.plot(p[[i, j], 0], p[[i, j], 1], "-", color="tab:blue", lw=0.5 + 3.0 * s / mx, alpha=0.5)
    ax.plot(p[:, 0], p[:, 1], "o", color="k")
    for c, pi in zip(cal.cameras, p):
        ax.annotate(c, pi[:2], fontsize=7, xytext=(3, 3), textcoords="offset points")
    ax.set_aspect("equal")
    ax.invert_yaxis()
    ax.set_xlabel("rig x [m]")
    ax.set_ylabel("rig y [m]")
    ax.set_title("camera graph (line width: shared board frames)")
    name = "plots/camera_graph.png"
    _savefig(fig, out / name)
    plt.close(fig)
    written.append(name)
    return written


def write_report(cal: BoardCalibration, out: str | os.PathLike, *, plots: bool = True,
                 uncertainty: bool = True) -> dict:
    """Write ``report.toml``, ``report.md`` and (optionally) ``plots/`` into ``out``; returns the dict."""
    import tomli_w

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    unc = None
    if uncertainty:
        unc = dict(cal.uncertainty)
        missing = [c for c in cal.cameras if c not in unc]
        if missing:
            dist = board_distance(cal.optimization_inputs)
            unc.update({cam: uncertainty_grid(cal.models[cam], dist) for cam in missing})
    doc = report_dict(cal, uncertainty=unc)
    written = _plots(cal, out, unc) if plots else []

    def clean(x):
        if isinstance(x, dict):
            return {k: clean(v) for k, v in x.items()}
        if isinstance(x, list):
            return [clean(v) for v in x]
        if isinstance(x, float) and not math.isfinite(x):
            return "nan"
        return x

    atomic_write_text(out / "report.toml", "# polycam calibration report (docs/calibration.md)\n"
                      + tomli_w.dumps(clean(doc)))
    atomic_write_text(out / "report.md", _markdown(doc, cal, written))
    return doc
