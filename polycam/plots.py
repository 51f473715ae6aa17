"""Plots a person would rather look at than read (matplotlib, written to PNG files).

Only the CLI and report writers call these; the numerics never plot.
"""

from __future__ import annotations

import os

import numpy as np

from .evaluate import PairErrors, std_norms
from .trajectory import Trajectory

__all__ = ["plot_trajectory", "plot_pair_errors"]


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")  # files only, never a window
    import matplotlib.pyplot as plt

    return plt


def plot_trajectory(path_png: str | os.PathLike, est: Trajectory, true: Trajectory | None = None) -> None:
    """Positions x, y, z [mm] of ``est`` (and ``true``) against time, plus the x–z path seen from above."""
    plt = _pyplot()
    t_s = (est.timestamps_ns - est.timestamps_ns[0]) * 1e-9
    p_est = est.rebased().T_world_rig[:, :3, 3] * 1e3
    p_true = true.rebased().T_world_rig[:, :3, 3] * 1e3 if true is not None else None
    fig, axes = plt.subplots(1, 2, figsize=(11, 4))
    for i, (name, colour) in enumerate(zip("xyz", ("tab:red", "tab:green", "tab:blue"))):
        axes[0].plot(t_s, p_est[:, i], "-o", ms=3, color=colour, label=f"{name} estimated")
        if p_true is not None:
            axes[0].plot(t_s, p_true[:, i], "--", color=colour, alpha=0.6, label=f"{name} true")
    axes[0].set_xlabel("time [s]")
    axes[0].set_ylabel("position of the rig [mm] (world = rig at frame 0)")
    axes[0].legend(fontsize=7, ncol=2)
    axes[0].grid(alpha=0.3)
    axes[1].plot(p_est[:, 0], p_est[:, 2], "-o", ms=3, label="estimated")
    if p_true is not None:
        axes[1].plot(p_true[:, 0], p_true[:, 2], "--", label="ground truth")
    axes[1].set_xlabel("x [mm]")
    axes[1].set_ylabel("z [mm]")
    axes[1].set_aspect("equal", adjustable="datalim")
    axes[1].set_title("path seen from above")
    axes[1].legend(fontsize=8)
    axes[1].grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path_png, dpi=110)
    plt.close(fig)


def plot_pair_errors(path_png: str | os.PathLike, err: PairErrors, std: np.ndarray | None = None,
                     solved: np.ndarray | None = None) -> None:
    """Per frame pair translation and rotation errors, absolute and relative to the true motion.

    ``std``: (P, 6) the solver's standard deviations of each pair's (t [m], r [rad])
    (:attr:`polycam.motion.PairResult.std`; infinite where unobservable: not drawn), drawn
    beside the errors as the error norm they predict (:func:`~polycam.evaluate.std_norms`): where the
    bars stand far above the marks, the covariance does not explain the error (docs/motion.md,
    "How far to trust the covariance"). ``solved``: (P,) bool, False for the failed pairs (their
    motion is the estimate they started from): drawn grey and left out of the titles' medians."""
    from matplotlib.ticker import MaxNLocator

    plt = _pyplot()
    pairs = np.arange(len(err.t_err))
    solved = np.ones(len(pairs), bool) if solved is None else np.asarray(solved, bool)
    fig, axes = plt.subplots(1, 2, figsize=(11, 3.8))
    for ax, e, colour in zip(axes, (err.t_err * 1e3, np.degrees(err.w_err)), ("tab:blue", "tab:orange")):
        if solved.any():
            ax.bar(pairs[solved], e[solved], color=colour, label="error")
        if not solved.all():
            ax.bar(pairs[~solved], e[~solved], color="0.75", label="failed pair (its start estimate)")
    axes[0].set_ylabel("translation error [mm]")
    axes[1].set_ylabel("rotation error [deg]")
    if std is not None:
        norm_t, norm_r = std_norms(std)
        for ax, p in zip(axes, (norm_t * 1e3, np.degrees(norm_r))):
            p = np.where(np.isfinite(p), p, np.nan)       # unobservable: infinite, not drawn
            ax.plot(pairs, p, "_", color="black", ms=22, mew=2, label="reported 1-σ (norm)")
    for ax, rel in zip(axes, (err.t_rel, err.w_rel)):
        ax.set_xlabel("frame pair (i, i+1)")
        ax.xaxis.set_major_locator(MaxNLocator(integer=True))   # pairs are whole numbers
        of = "" if solved.all() else f" ({int(solved.sum())} solved pairs)"
        ax.set_title(f"median {100 * np.median(rel[solved]):.2f}% of the true motion{of}" if solved.any()
                     else "no pair solved")
        ax.grid(alpha=0.3, axis="y")
        if std is not None or not solved.all():
            ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path_png, dpi=110)
    plt.close(fig)
