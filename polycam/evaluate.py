"""Trajectory errors against ground truth (numerics only, no I/O).

Relative pose error per frame pair (RPE) and absolute trajectory error (ATE)
on ``T_world_rig`` trajectories with the same timestamps; both are in the rig
frame of the first frame (docs/conventions.md), so no alignment is needed.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .errors import InputError
from .geometry import T_inverse, r_from_R
from .trajectory import Trajectory

__all__ = ["PairErrors", "pair_errors", "solved_pairs", "ate_rmse", "std_norms", "error_over_std"]


@dataclass(frozen=True)
class PairErrors:
    """Per frame pair errors of an estimated against a true trajectory."""

    t_true: np.ndarray
    """(N-1,) [m] true translation length per pair."""
    w_true: np.ndarray
    """(N-1,) [rad] true rotation angle per pair."""
    t_err: np.ndarray
    """(N-1,) [m] norm of the translation error per pair."""
    w_err: np.ndarray
    """(N-1,) [rad] angle of the rotation error per pair."""

    @property
    def t_rel(self) -> np.ndarray:
        """(N-1,) translation error relative to the true translation."""
        return self.t_err / np.maximum(self.t_true, 1e-300)

    @property
    def w_rel(self) -> np.ndarray:
        """(N-1,) rotation error relative to the true rotation angle."""
        return self.w_err / np.maximum(self.w_true, 1e-300)

    def subset(self, keep: np.ndarray) -> "PairErrors":
        """The errors of the pairs where ``keep`` (N-1,) bool is true (e.g. the solved ones)."""
        keep = np.asarray(keep, bool)
        return PairErrors(t_true=self.t_true[keep], w_true=self.w_true[keep], t_err=self.t_err[keep],
                          w_err=self.w_err[keep])


def solved_pairs(err: PairErrors, std: np.ndarray, solved: np.ndarray) -> tuple[PairErrors, np.ndarray]:
    """The errors and reported standard deviations ``std`` (P, 6) of the solved pairs (``solved``
    (P,) bool; a failed pair's motion is the estimate it started from, not an estimate), or of
    every pair when none was solved."""
    keep = np.asarray(solved, bool)
    if not keep.any():
        keep = np.ones_like(keep)
    return err.subset(keep), np.asarray(std)[keep]


def _check_same_frames(est: Trajectory, true: Trajectory) -> None:
    if len(est) != len(true) or not np.array_equal(est.timestamps_ns, true.timestamps_ns):
        raise InputError(f"the estimated trajectory ({len(est)} poses) and the ground truth "
                         f"({len(true)} poses) do not have the same timestamps")


def pair_errors(est: Trajectory, true: Trajectory) -> PairErrors:
    """Relative pose errors of consecutive pairs (``T_rig[i]_rig[i+1]``)."""
    _check_same_frames(est, true)
    M_est, M_true = est.relative(), true.relative()
    E = T_inverse(M_true) @ M_est
    return PairErrors(
        t_true=np.linalg.norm(M_true[:, :3, 3], axis=1),
        w_true=np.linalg.norm(r_from_R(M_true[:, :3, :3]), axis=1),
        t_err=np.linalg.norm(M_est[:, :3, 3] - M_true[:, :3, 3], axis=1),
        w_err=np.linalg.norm(r_from_R(E[:, :3, :3]), axis=1),
    )


def ate_rmse(est: Trajectory, true: Trajectory) -> float:
    """[m] RMS of position differences, both trajectories rebased to their first pose."""
    _check_same_frames(est, true)
    a, b = est.rebased().T_world_rig[:, :3, 3], true.rebased().T_world_rig[:, :3, 3]
    return float(np.sqrt(np.mean(np.sum((a - b) ** 2, axis=1))))


def std_norms(std: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(P,) [m] and (P,) [rad]: √(Σ std²) over t and over r of ``std`` (P, 6), the pairs'
    standard deviations of (t, r) (:attr:`polycam.motion.PairResult.std`): the RMS error
    norm the covariance predicts (infinite where unobservable)."""
    std = np.asarray(std, float).reshape(-1, 6)
    return np.sqrt(np.sum(std[:, :3] ** 2, axis=1)), np.sqrt(np.sum(std[:, 3:] ** 2, axis=1))


def error_over_std(err: PairErrors, std: np.ndarray) -> tuple[float, float]:
    """How many times the reported uncertainty the errors are: the median over the pairs of
    ``t_err`` and ``w_err`` over :func:`std_norms` of ``std`` (P, 6), the RMS error norms the
    covariance predicts, so 1 means it explains the errors. Pairs with an
    infinite or zero std (unobservable, failed) are left out; NaN without any."""
    out = []
    for e, norm in zip((err.t_err, err.w_err), std_norms(std)):
        ok = np.isfinite(norm) & (norm > 0)
        out.append(float(np.median(e[ok] / norm[ok])) if ok.any() else float("nan"))
    return out[0], out[1]

