"""The calibration's share of a frame pair's motion covariance, from re-solves with drawn models
(and, the same way, the share of unsynchronised cameras' capture times: :func:`with_capture_timing`;
and the change on a second view sampling: :func:`sampling_change_covariance`).

The camera models' error is the same in every pair of a session, so the solver's residuals cannot
show it. Re-solving the pairs with models drawn from the calibration's uncertainty
(:func:`calib.draws.drawn_models`; the driver is :mod:`polycam.calib_draws_cli`) measures it: for
antithetic draws ``±δ_k`` the half-difference ``d_k = (x(+δ_k) − x(−δ_k)) / 2`` of a pair's
estimate ``x = (t [m], r [rad])`` of ``T_prev_next`` is its first-order response ``J δ_k`` with the
second-order terms cancelled, and ``Σ_k d_k d_kᵀ / K`` estimates ``J C Jᵀ`` (C the calibration's
covariance) with K degrees of freedom. :func:`with_calibration` adds it to each pair's
``covariance`` (kept apart as ``covariance_calibration``). Numerics only, no I/O.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Sequence

import numpy as np

from .geometry import r_from_R
from .motion import PairResult

__all__ = ["pair_vectors", "antithetic_covariance", "with_calibration", "calibration_std", "with_capture_timing",
           "capture_timing_std", "sampling_change_covariance", "with_view_sampling", "view_sampling_std"]


def pair_vectors(results: Sequence[PairResult]) -> np.ndarray:
    """(P, 6) (t [m], r [rad]) of each pair's ``T_prev_next``; NaN rows for failed pairs."""
    out = np.full((len(results), 6), np.nan)
    for k, r in enumerate(results):
        if r:
            out[k, :3] = r.T_prev_next[:3, 3]
            out[k, 3:] = r_from_R(r.T_prev_next[:3, :3])
    return out


def antithetic_covariance(plus: np.ndarray, minus: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per pair, the covariance of the estimate over calibration draws, from antithetic re-solves.

    plus, minus: (K, P, 6) :func:`pair_vectors` of the K draws ``+δ_k`` and ``−δ_k`` (NaN rows
    where a re-solve failed: that draw is left out of that pair's sum). Returns ((P, 6, 6) the
    covariances ``Σ_k d_k d_kᵀ / K_p`` with ``d_k = (plus_k − minus_k) / 2``, NaN where no draw
    counted; (P,) int the draws ``K_p`` that did).
    """
    plus, minus = np.asarray(plus, float), np.asarray(minus, float)
    if plus.shape != minus.shape or plus.ndim != 3 or plus.shape[2] != 6:
        raise ValueError(f"plus and minus must both be (K, P, 6), got {plus.shape} and {minus.shape}")
    d = 0.5 * (plus - minus)
    ok = np.all(np.isfinite(d), axis=2)                          # (K, P)
    d = np.where(ok[..., None], d, 0.0)
    n = ok.sum(axis=0)
    with np.errstate(invalid="ignore", divide="ignore"):
        C = np.einsum("kpi,kpj->pij", d, d) / n[:, None, None]
    C[n == 0] = np.nan
    return C, n


def sampling_change_covariance(nominal: np.ndarray, other: np.ndarray) -> np.ndarray:
    """Per pair, ``d dᵀ`` with ``d = nominal − other`` the change of the estimate between two view
    samplings of the same frames (as the solver adds its level change, ``PairResult.level_change``).

    nominal, other: (P, 6) :func:`pair_vectors` of the two solves (NaN rows where one failed).
    Returns (P, 6, 6), NaN where either row is not finite. The change measures how far the two
    samplings' estimates differ, not which is right: where both err independently by as much it is
    twice one's variance (docs/motion.md, "A second view sampling").
    """
    nominal, other = np.asarray(nominal, float), np.asarray(other, float)
    if nominal.shape != other.shape or nominal.ndim != 2 or nominal.shape[1] != 6:
        raise ValueError(f"nominal and other must both be (P, 6), got {nominal.shape} and {other.shape}")
    d = nominal - other
    C = np.einsum("pi,pj->pij", d, d)
    C[~np.all(np.isfinite(d), axis=1)] = np.nan
    return C


def _with_part(results: Sequence[PairResult], C: np.ndarray, part: str) -> list[PairResult]:
    """The results with ``C`` (P, 6, 6) added to their ``covariance`` and kept as the field ``part``
    (pairs whose ``C`` is not finite are returned unchanged)."""
    C = np.asarray(C, float)
    if C.shape != (len(results), 6, 6):
        raise ValueError(f"C must be ({len(results)}, 6, 6), got {C.shape}")
    return [replace(r, covariance=r.covariance + c, **{part: c.copy()}) if np.all(np.isfinite(c)) else r
            for r, c in zip(results, C)]


def _part_std(results: Sequence[PairResult], part: str) -> np.ndarray:
    """(P, 6) standard deviations of (t [m], r [rad]) from each pair's covariance field ``part``;
    NaN rows where it was not measured."""
    out = np.full((len(results), 6), np.nan)
    for k, r in enumerate(results):
        C = getattr(r, part)
        if C is not None:
            out[k] = np.sqrt(np.clip(np.diag(C), 0.0, None))
    return out


def with_calibration(results: Sequence[PairResult], C: np.ndarray) -> list[PairResult]:
    """The results with ``C`` (P, 6, 6) added to their ``covariance`` and kept as
    ``covariance_calibration`` (pairs whose ``C`` is not finite are returned unchanged)."""
    return _with_part(results, C, "covariance_calibration")


def calibration_std(results: Sequence[PairResult]) -> np.ndarray:
    """(P, 6) standard deviations of (t [m], r [rad]) from each pair's ``covariance_calibration``;
    NaN rows where it was not measured."""
    return _part_std(results, "covariance_calibration")


def with_capture_timing(results: Sequence[PairResult], C: np.ndarray) -> list[PairResult]:
    """The results with ``C`` (P, 6, 6) added to their ``covariance`` and kept as ``covariance_sync``:
    the spread over capture times drawn from their uncertainty (unsynchronised cameras,
    :mod:`polycam.sync_draws_cli`; pairs whose ``C`` is not finite are returned unchanged)."""
    return _with_part(results, C, "covariance_sync")


def capture_timing_std(results: Sequence[PairResult]) -> np.ndarray:
    """(P, 6) standard deviations of (t [m], r [rad]) from each pair's ``covariance_sync``; NaN rows
    where it was not measured."""
    return _part_std(results, "covariance_sync")


def with_view_sampling(results: Sequence[PairResult], C: np.ndarray) -> list[PairResult]:
    """The results with ``C`` (P, 6, 6) added to their ``covariance`` and kept as
    ``covariance_sampling``: the change on a second view sampling (:func:`sampling_change_covariance`,
    :mod:`polycam.sampling_check_cli`; pairs whose ``C`` is not finite are returned unchanged)."""
    return _with_part(results, C, "covariance_sampling")


def view_sampling_std(results: Sequence[PairResult]) -> np.ndarray:
    """(P, 6) standard deviations of (t [m], r [rad]) from each pair's ``covariance_sampling``; NaN
    rows where it was not measured."""
    return _part_std(results, "covariance_sampling")
