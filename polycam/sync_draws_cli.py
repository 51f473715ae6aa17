"""``--sync-draws``: an unsynchronised session's corrected motion re-solved with its cameras' capture
times and the first pass's motion drawn from their uncertainty, for that uncertainty's share of each
pair's covariance (docs/motion.md, "Unsynchronised cameras").

The correction (:class:`resample.stream.SessionLightField` with ``capture_motion``) moves each camera
to where it was at its capture time, which is estimated: each camera's running median offset of its
jittered timestamps, a slower camera's own clock (:meth:`polycam.session.Session.capture_times_ns`).
The error that leaves is the same in the pairs around a frame and the solver's residuals do not show
it; antithetic re-solves with every capture time moved by ``±δ`` (δ (F, C) a draw of the estimate's
error, :meth:`~polycam.session.Session.capture_time_draw_ns`: nearly one offset per camera, an offset
and a rate for a slower camera), and the first pass's motion that moves the cameras by ``±`` a draw
from its covariance, measure it as the calibration draws do
(:func:`polycam.calib_spread.antithetic_covariance`).

CLI layer (``polycam motion SESSION``): it drives the resampling stage; the numerics are
:mod:`polycam.calib_spread`'s.
"""

from __future__ import annotations

import time
from contextlib import nullcontext
from typing import Callable

import numpy as np

from .calib_draws_cli import resolved_pair_vectors, share_line
from .calib_spread import antithetic_covariance, capture_timing_std, with_capture_timing
from .lightfield import LightFieldGrid

__all__ = ["capture_time_draws", "add_capture_timing_share"]


def _motion_factors(motion_covariance: np.ndarray | None, pairs: int) -> np.ndarray:
    """(P, 6, 6) square roots ``A`` (``A Aᵀ`` = the covariance) of each pair's (t, r) covariance; zero
    where it is not finite (a failed pair) or not given."""
    out = np.zeros((pairs, 6, 6))
    if motion_covariance is None:
        return out
    for p, C in enumerate(np.asarray(motion_covariance, float)):
        if np.all(np.isfinite(C)):
            w, V = np.linalg.eigh(0.5 * (C + C.T))
            out[p] = V * np.sqrt(np.clip(w, 0.0, None))
    return out


def _moved_motion(capture_motion: np.ndarray, dx: np.ndarray) -> np.ndarray:
    """(P, 4, 4) ``capture_motion`` with each pair's (t [m], r [rad]) moved by ``dx`` (P, 6)."""
    from .geometry import T_from_Rt, R_from_r, r_from_R

    return np.stack([T_from_Rt(R_from_r(r_from_R(M[:3, :3]) + d[3:]), M[:3, 3] + d[:3])
                     for M, d in zip(capture_motion, dx)])


def capture_time_draws(session, models: dict, grid: LightFieldGrid, capture_motion: np.ndarray, *, draws: int,
                       motion_covariance: np.ndarray | None = None, seed: int = 0, resample_options=None,
                       motion_options=None, scale_selection: bool = False,
                       progress: Callable[[int, int], None] | None = None) -> tuple[np.ndarray, np.ndarray, float]:
    """Re-solve every frame pair of an opened ``session`` (cameras ``models``, resampled onto ``grid`` with
    each camera moved by ``capture_motion``, (T - 1, 4, 4) ``T_prev_next`` per pair, as the corrected
    solve was) with ``draws`` sets of capture-time offsets, each at ``+δ`` and ``−δ`` (``2 draws``
    re-solves; δ (F, C) [ns] a draw of the capture times' error,
    :meth:`~polycam.session.Session.capture_time_draw_ns`) and, with ``motion_covariance``
    ((T - 1, 6, 6) the first pass's covariance of each pair's (t, r), the estimate ``capture_motion``
    is), ``capture_motion`` drawn from it at the same ``±``: the camera moved by its share of an
    estimated motion is off by that share of the estimate's error too.

    Returns ((P, 6, 6) each pair's covariance of (t [m], r [rad]) over the draws, NaN where no draw
    solved it; (P,) the draws that did; (C,) [ns] the RMS over the draws of each camera's δ, NaN for
    a camera without images). ``progress(done, total)`` after each re-solve.
    """
    if draws < 1:
        raise ValueError(f"draws must be >= 1, got {draws}")
    capture_motion = np.asarray(capture_motion, np.float64)
    factors = _motion_factors(motion_covariance, len(capture_motion))
    rng = np.random.default_rng(seed)
    plus, minus, squares = [], [], []
    for _ in range(draws):
        delta = session.capture_time_draw_ns(rng)
        squares.append(delta ** 2)
        dx = np.einsum("pij,pj->pi", factors, rng.standard_normal((len(capture_motion), 6)))
        for sign, acc in ((1.0, plus), (-1.0, minus)):
            acc.append(resolved_pair_vectors(
                session, models, grid, resample_options=resample_options, motion_options=motion_options,
                scale_selection=scale_selection, capture_motion=_moved_motion(capture_motion, sign * dx),
                capture_offsets_ns=sign * delta))
            if progress is not None:
                progress(len(plus) + len(minus), 2 * draws)
    C, counts = antithetic_covariance(np.stack(plus), np.stack(minus))
    has = session.capture_times_ns() >= 0
    with np.errstate(invalid="ignore"):
        rms = np.sqrt(np.sum(squares, axis=0).sum(axis=0) / (draws * has.sum(axis=0)))
    return C, counts, rms


def _std_text(rms_ns: np.ndarray, other_rate) -> str:
    """The drawn capture-time errors' size for the CLI's line: the median over the cameras of their RMS
    [ns] (C,), and the slower cameras' separately when the rig has any."""
    rms_ns = np.asarray(rms_ns, np.float64)
    slow = np.asarray(other_rate, bool) & np.isfinite(rms_ns)
    rest = ~np.asarray(other_rate, bool) & np.isfinite(rms_ns)
    text = f"{1e-6 * float(np.median(rms_ns[rest])):.2f} ms RMS per camera" if rest.any() else "no camera"
    if slow.any():
        text += f", {1e-6 * float(np.median(rms_ns[slow])):.2f} ms for the {int(slow.sum())} slower ones"
    return text


def add_capture_timing_share(session, models: dict, grid: LightFieldGrid, capture_motion: np.ndarray, results: list,
                             *, draws: int, bar: Callable | None = None, **solve) -> tuple[list, str]:
    """What ``polycam motion --sync-draws`` does: ``results`` (the corrected solve's) with the capture
    times' share added (:func:`capture_time_draws`, ``solve`` its keyword arguments;
    :func:`polycam.calib_spread.with_capture_timing`) and the line the CLI prints. ``bar(total)``: a
    context manager yielding ``advance(done, total)``, opened only when the draws run."""
    if not any(results):
        return results, "capture-time draws skipped: no pair solved"
    t0 = time.perf_counter()
    with (bar(2 * draws) if bar is not None else nullcontext(None)) as advance:
        C, counts, rms = capture_time_draws(session, models, grid, capture_motion, draws=draws, progress=advance,
                                            **solve)
    results = with_capture_timing(results, C)
    source = f"their uncertainty ({_std_text(rms, session.other_rate)})"
    return results, share_line("capture times", source, capture_timing_std(results), results, draws,
                               int(counts.min(initial=draws)), time.perf_counter() - t0)
