"""Tables and plots of a rig design study (:mod:`polycam.design`): the output of ``polycam design``.

``DIR/`` receives (docs/design.md describes every column):

- ``summary.csv``: one row per rig, SPEC.md's columns ``rig, cameras, faces, std_t,
  std_w, err_t, err_w, unobservable`` first (metres and radians; ``inf`` where a
  direction is unobservable, empty where nothing was measured), then the extras;
- ``directions.csv``: the weakly determined motion combinations of every rig;
- ``errors.csv``: every measured estimate error (rig, pair, draw);
- ``sweep.csv``: predicted errors against scene distance;
- ``error_vs_cameras.png``, ``error_vs_baseline.png``, ``error_vs_fov.png``,
  ``error_vs_distance.png``, ``hierarchy.png`` (the paper's Fig. 3, measured);
- ``report.md``: the summary as text, with the verdicts and warnings.

Every file is written atomically (temporary name, then rename).
"""

from __future__ import annotations

import io
import math
import os
from pathlib import Path
from typing import Sequence

import numpy as np

from .design import DesignOptions, DesignResult
from .motion import PARAM_NAMES
from .tomlio import atomic_write_bytes, atomic_write_text

__all__ = [
    "SUMMARY_COLUMNS",
    "HIERARCHY_CLASSES",
    "summary_csv",
    "directions_csv",
    "errors_csv",
    "sweep_csv",
    "report_markdown",
    "plot_error_vs",
    "plot_distance",
    "plot_hierarchy",
    "write_design_report",
]

SUMMARY_COLUMNS = ("rig", "cameras", "faces", "std_t", "std_w", "err_t", "err_w", "unobservable",
                   "class", "model", "baseline", "spacing", "fov_deg", "coverage_deg", "viewpoints", "rays",
                   "std_t_dir", "condition", "weakest", "ambiguity", "solver_unobservable",
                   "bias_t", "bias_w", "scatter_t", "scatter_w", "misfit")
"""Columns of ``summary.csv``: SPEC.md's eight first, then polycam's extras."""

HIERARCHY_CLASSES = ("pinhole, small FOV", "pinhole, spherical", "polydioptric, small FOV",
                     "polydioptric, spherical")
"""The paper's hierarchy of cameras (Fig. 3), in order of increasing stability."""


# ----------------------------------------------------------------------------- CSV


def _fmt(v) -> str:
    """CSV cell: numbers with 6 significant digits, ``inf`` for infinity, empty for NaN."""
    if isinstance(v, (bool, np.bool_)):
        return "true" if v else "false"
    if isinstance(v, (int, np.integer)):
        return str(int(v))
    if isinstance(v, (float, np.floating)):
        if math.isnan(v):
            return ""
        if math.isinf(v):
            return "inf" if v > 0 else "-inf"
        return f"{float(v):.6g}"
    s = str(v)
    if any(c in s for c in ',"\n'):
        s = '"' + s.replace('"', '""') + '"'
    return s


def _csv(header: Sequence[str], rows: Sequence[Sequence]) -> str:
    lines = [",".join(header)]
    lines += [",".join(_fmt(v) for v in row) for row in rows]
    return "\n".join(lines) + "\n"


def summary_csv(results: Sequence[DesignResult]) -> str:
    """``summary.csv`` text: one row per rig (columns :data:`SUMMARY_COLUMNS`)."""
    rows = []
    for r in results:
        d = r.summary_row()
        rows.append([d[c] for c in SUMMARY_COLUMNS])
    return _csv(SUMMARY_COLUMNS, rows)


def directions_csv(results: Sequence[DesignResult]) -> str:
    """``directions.csv``: per rig the motion combinations, weakest first (rank 1), and the
    unobservable ones (rank 0)."""
    header = ["rig", "model", "rank", "kind", "inflation", "name"] + [f"v_{n}" for n in PARAM_NAMES]
    rows = []
    for r in results:
        p = r.prediction
        for name in p.unobservable:
            rows.append([r.name, p.model, 0, "unobservable", math.inf, name] + [math.nan] * 6)
        for i, d in enumerate(p.directions):
            rows.append([r.name, p.model, i + 1, d.kind, d.inflation, d.name] + list(d.vector))
    return _csv(header, rows)


def errors_csv(results: Sequence[DesignResult]) -> str:
    """``errors.csv``: every measured estimate error of (t [m], r [rad]) of ``T_prev_next``."""
    header = ["rig", "pair", "draw", "ok"] + [f"e_{n}" for n in PARAM_NAMES]
    rows = []
    for r in results:
        m = r.measurement
        if m is None:
            continue
        for i in range(m.errors.shape[0]):
            for j in range(m.errors.shape[1]):
                rows.append([r.name, i, j, bool(m.ok[i, j])] + list(m.errors[i, j]))
    return _csv(header, rows)


def sweep_csv(results: Sequence[DesignResult]) -> str:
    """``sweep.csv``: predicted std_t [m] and std_w [rad] against scene distance [m]."""
    rows = [[r.name, D, st, sw] for r in results for (D, st, sw) in r.sweep]
    return _csv(["rig", "distance", "std_t", "std_w"], rows)


# ----------------------------------------------------------------------------- text


def _num(v: float, scale: float, unit: str) -> str:
    if v is None or (isinstance(v, float) and math.isnan(v)):
        return "–"
    if math.isinf(v):
        return "∞"
    return f"{v * scale:.3g} {unit}"


def report_markdown(results: Sequence[DesignResult], options: DesignOptions) -> str:
    """A human summary of the study (the content of ``report.md``)."""
    o = options
    lines = ["# Rig design study", "",
             f"Scene `{o.scene}` at {o.distance:g} m; image noise σ = {o.noise:g} per camera pixel; "
             f"{o.pairs} frame pair(s) of |t| = {o.step_t * 1000:g} mm, |ω| = {o.step_r_deg:g} deg"
             + (f", {o.draws} noise draw(s) each" if o.measure else " (predictions only)")
             + f"; directions every {o.uv_step_deg:g} deg. Errors are per frame pair: predicted 1-σ "
             "(`std`, from the linear model) and measured RMS of the real solver (`err`).", "",
             "| rig | class | cameras | faces | std t | err t | std ω | err ω | unobservable | ambiguity |",
             "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |"]
    for r in results:
        p, m = r.prediction, r.measurement
        lines.append(f"| {r.name} | {r.features['class']} | {r.features['cameras']} | {r.features['faces']} | "
                     f"{_num(p.std_t, 1000, 'mm')} | {_num(m.err_t if m else math.nan, 1000, 'mm')} | "
                     f"{_num(p.std_w, 1000, 'mrad')} | {_num(m.err_w if m else math.nan, 1000, 'mrad')} | "
                     f"{' '.join(p.unobservable) or '–'} | {p.ambiguity or '–'} |")
    lines += ["", "## Verdicts", ""]
    for r in results:
        p, m = r.prediction, r.measurement
        v = [f"**{r.name}** ({r.features['class']}, {p.model} model):"]
        if "t_scale" in p.unobservable:
            v.append("the scale of translation is unobservable (one viewpoint per face: translation enters only "
                     f"through unknown depth); translation direction ±{p.std_t_dir:.3g} rad.")
        elif p.unobservable:
            v.append(f"unobservable: {', '.join(p.unobservable)}.")
        else:
            v.append("all six motion parameters are observable.")
        if p.solver_unobservable:
            v.append(f"The plenoptic solver cannot estimate {' '.join(p.solver_unobservable)} with this rig.")
        if p.ambiguity:
            v.append(f"Rotation–translation ambiguity (classical, small field of view): {p.ambiguity}.")
        if p.directions:
            d = p.directions[0]
            v.append(f"Weakest combination: {d.name} ({d.kind}, variance x{d.inflation:.2f} from coupling).")
        if m is not None and not math.isnan(m.scatter_w):
            v.append(f"Measured: systematic error (solver on the noise-free pairs) {_num(m.bias_t, 1000, 'mm')} / "
                     f"{_num(m.bias_w, 1000, 'mrad')}; noise scatter {_num(m.scatter_t, 1000, 'mm')} / "
                     f"{_num(m.scatter_w, 1000, 'mrad')} against the predicted {_num(p.std_t, 1000, 'mm')} / "
                     f"{_num(p.std_w, 1000, 'mrad')}.")
            if m.bias_w > 2 * max(m.scatter_w, p.std_w):
                v.append("The error is mostly systematic: model error of the sampled light field (parallax of near "
                         "surfaces across viewpoints, interpolated viewpoints, occlusions) amplified along the "
                         "weakest direction; the noise prediction does not cover it (docs/design.md).")
        lines.append(" ".join(v))
        for w in r.warnings:
            lines.append(f"  - warning: {w}")
        lines.append("")
    lines += ["Columns and method: docs/design.md.", ""]
    return "\n".join(lines)


# ----------------------------------------------------------------------------- plots


def _figure_bytes(fig) -> bytes:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110, bbox_inches="tight")
    import matplotlib.pyplot as plt

    plt.close(fig)
    return buf.getvalue()


def _pyplot():
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    return plt


_FEATURES = {"cameras": ("number of cameras", 1.0), "baseline": ("baseline (largest camera distance) [cm]", 100.0),
             "coverage_deg": ("field of view (cone of equal solid angle) [deg]", 1.0),
             "fov_deg": ("camera horizontal field of view [deg]", 1.0)}


def _values(results, key: str):
    """(predicted, measured) arrays of one error (t or w) in mm / mrad; inf where unobservable."""
    p = np.array([getattr(r.prediction, f"std_{key}") for r in results], float) * 1000
    m = np.array([(getattr(r.measurement, f"err_{key}") if r.measurement else math.nan) for r in results],
                 float) * 1000
    return p, m


def _legend(ax) -> None:
    if ax.get_legend_handles_labels()[0]:
        ax.legend(fontsize=7)


def _plot_panel(ax, x, results, key, label_points: bool):
    p, m = _values(results, key)
    finite = p[np.isfinite(p)]
    finite_m = m[np.isfinite(m)]
    allv = np.concatenate([finite, finite_m]) if (finite.size or finite_m.size) else np.array([1.0])
    top = float(allv.max()) * 3 if allv.size else 1.0
    ok = np.isfinite(p)
    ax.scatter(x[ok], p[ok], marker="o", color="C0", label="predicted 1-σ", zorder=3)
    okm = np.isfinite(m)
    ax.scatter(x[okm], m[okm], marker="s", facecolors="none", edgecolors="C3", label="measured RMS", zorder=3)
    if (~ok).any():
        ax.scatter(x[~ok], np.full((~ok).sum(), top), marker="x", color="k", label="unobservable", zorder=3)
    if label_points:
        for xi, pi, r in zip(x, p, results):
            ax.annotate(r.name, (xi, pi if math.isfinite(pi) else top), textcoords="offset points",
                        xytext=(4, 4), fontsize=7)
    ax.set_yscale("log")
    ax.grid(True, which="both", alpha=0.3)


def plot_error_vs(results: Sequence[DesignResult], feature: str) -> bytes:
    """PNG: predicted and measured translation and rotation errors against a rig feature
    (``cameras``, ``baseline``, ``coverage_deg`` or ``fov_deg``)."""
    plt = _pyplot()
    label, scale = _FEATURES[feature]
    x = np.array([r.features[feature] for r in results], float) * scale
    fig, axes = plt.subplots(1, 2, figsize=(10, 4))
    for ax, key, unit, what in ((axes[0], "t", "mm", "translation"), (axes[1], "w", "mrad", "rotation")):
        _plot_panel(ax, x, results, key, label_points=True)
        ax.set_xlabel(label)
        ax.set_ylabel(f"{what} error per frame pair [{unit}]")
        if feature == "cameras" and len(x) and x.max() / max(x.min(), 1) > 8:
            ax.set_xscale("log")
    _legend(axes[0])
    fig.suptitle(f"error against {label}")
    return _figure_bytes(fig)


def plot_distance(results: Sequence[DesignResult], options: DesignOptions) -> bytes:
    """PNG: predicted errors against scene distance (the sweep) with the measured error at
    the study distance."""
    plt = _pyplot()
    fig, axes = plt.subplots(1, 2, figsize=(10, 4))
    for i, r in enumerate(results):
        col = f"C{i % 10}"
        if r.sweep:
            D = np.array([s[0] for s in r.sweep])
            for ax, j in ((axes[0], 1), (axes[1], 2)):
                y = np.array([s[j] for s in r.sweep]) * 1000
                ok = np.isfinite(y)
                if ok.any():
                    ax.plot(D[ok], y[ok], "o-", color=col, label=r.name)
        if r.measurement is not None:
            for ax, v in ((axes[0], r.measurement.err_t), (axes[1], r.measurement.err_w)):
                if math.isfinite(v):
                    ax.plot([options.distance], [v * 1000], "s", mfc="none", color=col)
    for ax, unit, what in ((axes[0], "mm", "translation"), (axes[1], "mrad", "rotation")):
        ax.set_xlabel("scene distance [m]")
        ax.set_ylabel(f"{what} error per frame pair [{unit}]")
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.grid(True, which="both", alpha=0.3)
    _legend(axes[0])
    fig.suptitle("predicted 1-σ (lines) and measured RMS (squares) against scene distance")
    return _figure_bytes(fig)


def plot_hierarchy(results: Sequence[DesignResult]) -> bytes:
    """PNG: the paper's Fig. 3 hierarchy measured — rigs grouped by class (pinhole /
    polydioptric x small FOV / spherical), predicted and measured errors as bars."""
    plt = _pyplot()
    order = sorted(range(len(results)), key=lambda i: (HIERARCHY_CLASSES.index(results[i].features["class"])
                                                       if results[i].features["class"] in HIERARCHY_CLASSES
                                                       else 99, i))
    res = [results[i] for i in order]
    fig, axes = plt.subplots(1, 2, figsize=(max(8, 1.6 * len(res) + 3), 4.5))
    x = np.arange(len(res))
    for ax, key, unit, what in ((axes[0], "t", "mm", "translation"), (axes[1], "w", "mrad", "rotation")):
        p, m = _values(res, key)
        finite = np.concatenate([p[np.isfinite(p)], m[np.isfinite(m)]])
        top = float(finite.max()) * 2 if finite.size else 1.0
        bottom = float(finite.min()) / 3 if finite.size else 0.1
        ax.bar(x - 0.2, np.where(np.isfinite(p), p, np.nan), 0.4, color="C0", label="predicted 1-σ")
        ax.bar(x + 0.2, np.where(np.isfinite(m), m, np.nan), 0.4, color="C3", alpha=0.7, label="measured RMS")
        for xi, pi, r in zip(x, p, res):
            if not math.isfinite(pi):
                txt = "scale\nunobservable" if "t_scale" in r.prediction.unobservable else "unobservable"
                ax.text(xi, bottom * 1.5, txt, ha="center", va="bottom", fontsize=7, rotation=90)
        ax.set_yscale("log")
        ax.set_ylim(bottom, top)
        ax.set_xticks(x)
        ax.set_xticklabels([f"{r.name}\n({r.features['class']})" for r in res], fontsize=7, rotation=20,
                           ha="right")
        ax.set_ylabel(f"{what} error per frame pair [{unit}]")
        ax.grid(True, axis="y", which="both", alpha=0.3)
    _legend(axes[0])
    fig.suptitle("hierarchy of cameras (paper Fig. 3): small-FOV pinhole → spherical pinhole → "
                 "small-FOV polydioptric → spherical polydioptric")
    return _figure_bytes(fig)


# ----------------------------------------------------------------------------- all of it


def write_design_report(results: Sequence[DesignResult], out: str | os.PathLike, options: DesignOptions,
                        *, plots: bool = True) -> list[Path]:
    """Write every table (and the plots) of a study into folder ``out`` (created); returns the paths."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    written = []

    def text(name, s):
        atomic_write_text(out / name, s)
        written.append(out / name)

    def png(name, b):
        atomic_write_bytes(out / name, b)
        written.append(out / name)

    text("summary.csv", summary_csv(results))
    text("directions.csv", directions_csv(results))
    if any(r.measurement is not None for r in results):
        text("errors.csv", errors_csv(results))
    if any(r.sweep for r in results):
        text("sweep.csv", sweep_csv(results))
    text("report.md", report_markdown(results, options))
    if plots and results:
        png("error_vs_cameras.png", plot_error_vs(results, "cameras"))
        png("error_vs_baseline.png", plot_error_vs(results, "baseline"))
        png("error_vs_fov.png", plot_error_vs(results, "coverage_deg"))
        png("error_vs_distance.png", plot_distance(results, options))
        png("hierarchy.png", plot_hierarchy(results))
    return written
