"""``--sync-draws``: an unsynchronised session's corrected motion re-solved with its cameras' capture
times drawn from their uncertainty, for that uncertainty's share of each pair's covariance
(docs/motion.md, "Unsynchronised cameras").

The correction (:class:`resample.stream.SessionLightField` with ``capture_motion``) moves each camera
to where it was at its capture time, which is estimated: each camera's running median offset of its
jittered timestamps (:meth:`polycam.session.Session.capture_times_ns`, std
:meth:`~polycam.session.Session.capture_time_std_ns` per camera). The error that leaves is the same
in the pairs around a frame and the solver's residuals do not show it; antithetic re-solves with
every camera's capture time moved by ``±δ_k`` (δ_k drawn per camera from that std) measure it as the
calibration draws do (:func:`polycam.calib_spread.antithetic_covariance`).

CLI layer (``polycam motion SESSION``): it drives the resampling stage; the numerics are
:mod:`polycam.calib_spread`'s.
"""

from __future__ import annotations

import time
from contextlib import nullcontext
from typing import Callable

import numpy as np

from .calib_draws_cli import quiet_logger, share_line
from .calib_spread import antithetic_covariance, capture_timing_std, pair_vectors, with_capture_timing
from .lightfield import LightFieldGrid

__all__ = ["capture_time_draws", "add_capture_timing_share"]


def capture_time_draws(session, models: dict, grid: LightFieldGrid, capture_motion: np.ndarray, *, draws: int,
                       seed: int = 0, resample_options=None, motion_options=None, scale_selection: bool = False,
                       progress: Callable[[int, int], None] | None = None) -> tuple[np.ndarray, np.ndarray, float]:
    """Re-solve every frame pair of an opened ``session`` (cameras ``models``, resampled onto ``grid`` with
    each camera moved by ``capture_motion``, (T - 1, 4, 4) ``T_prev_next`` per pair, as the corrected
    solve was) with ``draws`` sets of capture-time offsets, each at ``+δ`` and ``−δ`` (``2 draws``
    re-solves; δ per camera normal with the session's :meth:`~polycam.session.Session.capture_time_std_ns`).

    Returns ((P, 6, 6) each pair's covariance of (t [m], r [rad]) over the draws, NaN where no draw
    solved it; (P,) the draws that did; the std [ns] drawn from). ``progress(done, total)`` after each
    re-solve.
    """
    from resample.stream import SessionLightField

    from .motion import estimate_trajectory

    if draws < 1:
        raise ValueError(f"draws must be >= 1, got {draws}")
    sigma = session.capture_time_std_ns()
    rng = np.random.default_rng(seed)
    plus, minus = [], []
    for _ in range(draws):
        delta = sigma * rng.standard_normal(len(session.cameras))
        for sign, acc in ((1.0, plus), (-1.0, minus)):
            with quiet_logger("resample"):                  # its warnings repeat the nominal resampling's
                lf = SessionLightField(session, models=models, grid=grid, options=resample_options,
                                       camera_noise=False, capture_motion=capture_motion,
                                       capture_offsets_ns=sign * delta)
                _, results = estimate_trajectory(lf, options=motion_options, scale_selection=scale_selection)
            acc.append(pair_vectors(results))
            if progress is not None:
                progress(len(plus) + len(minus), 2 * draws)
    C, counts = antithetic_covariance(np.stack(plus), np.stack(minus))
    return C, counts, sigma


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
        C, counts, sigma = capture_time_draws(session, models, grid, capture_motion, draws=draws, progress=advance,
                                              **solve)
    results = with_capture_timing(results, C)
    source = f"their uncertainty ({1e-6 * sigma:.2f} ms per camera)"
    return results, share_line("capture times", source, capture_timing_std(results), results, draws,
                               int(counts.min(initial=draws)), time.perf_counter() - t0)
