"""``--sampling-check``: a session's motion re-solved on a second view sampling (one more viewpoint per
camera spacing), and the change of each pair's estimate added to its covariance (docs/motion.md, "A
second view sampling").

On camera arrays the views between the cameras are filled from the plane-sweep depth and blended
across cameras; the error that leaves is shared by neighbouring rays and by the (u, v) levels, so
neither the residuals' sandwich nor the level change shows it, and the covariance can be ~2x
optimistic there (docs/motion.md, "The direction step"). It moves with the views' sampling: the
change ``d`` of a pair's estimate between the grid's ``xy_oversample`` views per camera spacing and
``xy_oversample + 1``, added as ``d dᵀ`` (:func:`polycam.calib_spread.sampling_change_covariance`),
measures it. It measures how far the two samplings differ, not which is right, so where the std was
honest it makes it conservative (up to ~1.5x, measured).

CLI layer (``polycam motion SESSION``, ``polycam run``): it drives the resampling stage; the
numerics are :mod:`polycam.calib_spread`'s.
"""

from __future__ import annotations

import time
from contextlib import nullcontext
from typing import Callable

import numpy as np

from .calib_draws_cli import resolved_pair_vectors
from .calib_spread import pair_vectors, sampling_change_covariance, view_sampling_std, with_view_sampling

__all__ = ["add_view_sampling_share", "sampling_line"]


def add_view_sampling_share(session, models: dict, uv_step_px: float, xy_oversample: int, results: list, *,
                            bar: Callable | None = None, **solve) -> tuple[list, str, float | None]:
    """What ``polycam motion --sampling-check`` and ``polycam run --sampling-check`` do: ``results`` (the
    nominal solve's, on ``xy_oversample`` views per camera spacing) with the change on ``xy_oversample
    + 1`` added (:func:`polycam.calib_draws_cli.resolved_pair_vectors`, ``solve`` its keyword arguments;
    :func:`polycam.calib_spread.with_view_sampling`), the line the CLI prints, and the seconds it took
    (None: skipped: no pair was solved, or the second sampling has fewer than
    :data:`polycam.run.MIN_VIEWS` views along an axis with more than one, e.g. a stereo pair given
    ``--xy-oversample 1``). ``bar(total)``: a context manager yielding ``advance(done,
    total)``, opened only when the re-solve runs."""
    from .run import MIN_VIEWS, session_grid

    if not any(results):
        return results, "second view sampling skipped: no pair solved", None
    t0 = time.perf_counter()
    second = xy_oversample + 1
    grid, _ = session_grid(models, uv_step_px, second)
    shape = tuple(grid.shape)
    few = [n for n in shape[1:3] if 1 < n < MIN_VIEWS]
    if few:
        return results, (f"second view sampling skipped: {second} views per camera spacing give {few[0]} views "
                         f"along the cameras, fewer than the solver's {MIN_VIEWS} (its std then leaves the "
                         f"sampling's share out)"), None
    with (bar(len(results)) if bar is not None else nullcontext(None)) as advance:
        other = resolved_pair_vectors(session, models, grid, progress=advance, **solve)
    before = np.stack([r.std for r in results])
    results = with_view_sampling(results, sampling_change_covariance(pair_vectors(results), other))
    seconds = time.perf_counter() - t0
    return results, sampling_line(results, before, second, shape, seconds), seconds


def sampling_line(results, std_before: np.ndarray, xy_oversample: int, shape, seconds: float) -> str:
    """How far the estimates moved on the second view sampling (``xy_oversample`` views per camera
    spacing, a grid of ``shape`` (F, Ny, Nx, Nv, Nu)): medians over the pairs that have the change of its
    norms and of their ratio to ``std_before`` ((P, 6) the reported std without it), and how many
    pairs moved by more than twice that std."""
    from .evaluate import std_norms

    change = view_sampling_std(results)               # |d| per axis: the change itself
    have = np.all(np.isfinite(change), axis=1)
    views = f"{xy_oversample} views per camera spacing, {shape[1]}x{shape[2]} views"
    if not have.any():
        return f"second view sampling ({views}, {seconds:.0f} s): no pair solved on it"
    (ct, cr), (bt, br) = std_norms(change[have]), std_norms(std_before[have])
    far = int(np.sum((ct > 2 * bt) | (cr > 2 * br)))
    failed = len(results) - int(have.sum())
    return (f"second view sampling ({views}, {seconds:.0f} s): the estimates moved by "
            f"{1e3 * np.median(ct):.3f} mm, {1e3 * np.degrees(np.median(cr)):.2f} mdeg per pair (median), "
            f"{100 * np.median(ct / bt):.0f}% / {100 * np.median(cr / br):.0f}% of the std before; "
            f"{far} of {int(have.sum())} pairs by more than twice it"
            + (f"; {failed} pair(s) not solved on it, left as they were" if failed else "")
            + "; the change is added to the covariance")
