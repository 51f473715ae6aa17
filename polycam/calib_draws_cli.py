"""``--calib-draws``: a session's motion re-solved with camera models drawn from the calibration's
uncertainty, for the calibration's share of each pair's covariance (docs/motion.md, "How far to
trust the covariance").

CLI layer (``polycam motion SESSION``, ``polycam run``): it drives the calibration and resampling
stages (:mod:`calib.draws`, :class:`resample.stream.SessionLightField`); the numerics are
:mod:`polycam.calib_spread`'s.
"""

from __future__ import annotations

import logging
import os
import time
from contextlib import contextmanager, nullcontext
from typing import Callable

import numpy as np

from .calib_spread import antithetic_covariance, pair_vectors, with_calibration
from .lightfield import LightFieldGrid

__all__ = ["calibration_draws", "add_calibration_share", "calibration_line", "share_line", "quiet_logger",
           "resolved_pair_vectors"]

log = logging.getLogger(__name__)


def calibration_draws(session_path: str | os.PathLike, models: dict, grid: LightFieldGrid, *, draws: int,
                      seed: int = 0, resample_options=None, motion_options=None, scale_selection: bool = False,
                      progress: Callable[[int, int], None] | None = None, cov=None,
                      capture_motion=None) -> tuple[np.ndarray, np.ndarray]:
    """Re-solve every frame pair of a session with ``draws`` model sets drawn from the calibration
    of ``models`` (camera id → mrcal cameramodel with its ``optimization_inputs``), each at ``+δ``
    and ``−δ`` (``2 draws`` re-solves), resampled onto ``grid`` with ``resample_options`` and solved
    with ``motion_options`` / ``scale_selection`` as the nominal solve was.

    Returns ((P, 6, 6) each pair's covariance of (t [m], r [rad]) over the draws, NaN where no draw
    solved it; (P,) the draws that did): :func:`polycam.calib_spread.antithetic_covariance`.
    ``progress(done, total)`` after each re-solve. ``cov``: the models'
    :func:`calib.draws.calibration_covariance` when already computed. ``capture_motion``: as the nominal
    solve's (:class:`resample.stream.SessionLightField`: unsynchronised cameras moved to where they
    captured). Raises InputError when the models have no calibration covariance.
    """
    from calib.draws import calibration_covariance, covariance_factor, drawn_models

    if draws < 1:
        raise ValueError(f"draws must be >= 1, got {draws}")
    if cov is None:
        cov = calibration_covariance(models)
    factor = covariance_factor(cov)
    log.info("calibration draws: %d cameras, %d calibrated parameters, corner noise %.3f px",
             len(cov.cameras), cov.dim, cov.noise_px)
    rng = np.random.default_rng(seed)
    plus, minus = [], []
    for k in range(draws):
        z = rng.standard_normal(cov.dim)
        for sign, acc in ((1.0, plus), (-1.0, minus)):
            acc.append(resolved_pair_vectors(session_path, drawn_models(models, cov, sign * z, factor), grid,
                                             resample_options=resample_options, motion_options=motion_options,
                                             scale_selection=scale_selection, capture_motion=capture_motion))
            if progress is not None:
                progress(len(plus) + len(minus), 2 * draws)
    return antithetic_covariance(np.stack(plus), np.stack(minus))


def add_calibration_share(session_path: str | os.PathLike, models: dict, grid: LightFieldGrid, results: list, *,
                          draws: int, bar: Callable | None = None, **solve) -> tuple[list, str, float | None]:
    """What ``polycam motion --calib-draws`` and ``polycam run`` do with the draws: ``results`` with the
    calibration's share added (:func:`calibration_draws`, ``solve`` its keyword arguments;
    :func:`polycam.calib_spread.with_calibration`), the line the CLI prints, and the seconds the
    draws took (None: skipped, no pair was solved). ``bar(total)``: a context manager yielding
    ``advance(done, total)`` (a progress bar), opened only when the draws run."""
    if not any(results):
        return results, "calibration draws skipped: no pair solved", None
    t0 = time.perf_counter()
    with (bar(2 * draws) if bar is not None else nullcontext(None)) as advance:
        C, counts = calibration_draws(session_path, models, grid, draws=draws, progress=advance, **solve)
    results = with_calibration(results, C)
    seconds = time.perf_counter() - t0
    return results, calibration_line(results, draws, int(counts.min(initial=draws)), seconds), seconds


def resolved_pair_vectors(session, models: dict, grid: LightFieldGrid, *, resample_options=None, motion_options=None,
                          scale_selection: bool = False, progress: Callable[[int, int], None] | None = None,
                          **light_field) -> np.ndarray:
    """(P, 6) each pair's (t [m], r [rad]) (:func:`polycam.calib_spread.pair_vectors`, NaN rows where a
    pair failed) of ``session`` (an opened session or its folder) re-resampled with cameras ``models``
    onto ``grid`` and solved: the one re-solve of the calibration draws, the capture-time draws and the
    second view sampling. ``resample_options``, ``motion_options``, ``scale_selection`` as the nominal
    solve's; ``light_field``: further :class:`resample.stream.SessionLightField` keywords
    (``capture_motion``, ``capture_offsets_ns``); ``progress(done, total)`` per pair. The resampler's
    warnings, which repeat the nominal resampling's, are left out."""
    from resample.stream import SessionLightField

    from .motion import estimate_trajectory

    with quiet_logger("resample"):
        lf = SessionLightField(session, models=models, grid=grid, options=resample_options, camera_noise=False,
                               **light_field)
        _, results = estimate_trajectory(lf, options=motion_options, scale_selection=scale_selection,
                                         progress=progress)
    return pair_vectors(results)


@contextmanager
def quiet_logger(name: str):
    """Only errors from logger ``name`` (and its children) inside the block."""
    logger = logging.getLogger(name)
    level = logger.level
    logger.setLevel(logging.ERROR)
    try:
        yield
    finally:
        logger.setLevel(level)


def calibration_line(results, draws: int, fewest: int, seconds: float) -> str:
    """How large the calibration's share of the reported std is (median over the pairs that have it;
    ``fewest``: the fewest draws in which a pair was re-solved)."""
    from .calib_spread import calibration_std

    return share_line("calibration", "its uncertainty", calibration_std(results), results, draws, fewest, seconds)


def share_line(what: str, source: str, part_std: np.ndarray, results, draws: int, fewest: int, seconds: float) -> str:
    """``what: N draws from SOURCE (...): its std per pair ..., a% / b% of the reported std``: how large a
    measured part of the covariance is (``part_std``: (P, 6) its standard deviations, NaN rows where not
    measured; medians over the pairs that have it)."""
    from .evaluate import std_norms

    have = np.all(np.isfinite(part_std), axis=1)
    if not have.any():
        return f"{what}: {draws} draws, no pair re-solved ({seconds:.0f} s)"
    (ct, cr), (tt, tr) = std_norms(part_std[have]), std_norms(np.stack([r.std for r in results])[have])
    few = f"; a pair solved in only {fewest} of them" if fewest < draws else ""
    return (f"{what}: {draws} draws from {source} ({2 * draws} re-solves, {seconds:.0f} s{few}): "
            f"its std per pair {1e3 * np.median(ct):.3f} mm, {1e3 * np.degrees(np.median(cr)):.2f} mdeg (median), "
            f"{100 * np.median(ct / tt):.0f}% / {100 * np.median(cr / tr):.0f}% of the reported std")
