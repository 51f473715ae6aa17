"""Resampling (pipeline stage, issue 5): calibrated camera frames → the two-plane light field.

Push-pull after Gortler et al., "The Lumigraph" (1996), in 4-D: every pixel ray is
intersected with the two planes of each face it points into, splatted onto the
grid with a tent kernel and a local-linear correction, and the holes are filled by
a pull-push pyramid that also gives the confidence ``W`` (SPEC.md); the views no
camera measured are then filled along the disparity a plane sweep finds. The geometry
(which pixels feed which cells, with what weight) depends only on the calibration
and the grid, so it is built once; a frame is then a sparse product plus the
pyramid. ``polycam resample`` streams a session's frames through it, in parallel
through dask.distributed. See docs/resample.md.

Modules: :mod:`~resample.grid` (automatic grid), :mod:`~resample.geometry` (rays →
sparse splat), :mod:`~resample.pushpull` (pyramid), :mod:`~resample.resampler`
(per-frame resampling), :mod:`~resample.viewfill` (depth-aware filling of the
views between cameras), :mod:`~resample.store` (frame-addressed store writes),
:mod:`~resample.pipeline` (sessions, dask), :mod:`~resample.cli` (the verb).
"""

import importlib

_EXPORTS = {
    "auto_grid": "grid",
    "KernelOptions": "geometry", "SplatGeometry": "geometry", "build_geometry": "geometry",
    "ray_samples": "geometry", "splat": "geometry",
    "PushPull": "pushpull", "push_pull": "pushpull", "push_pull_reference": "pushpull",
    "ViewFillOptions": "viewfill", "fill_views": "viewfill", "plan_view_fill": "viewfill",
    "ResampleOptions": "resampler", "ResampledFrame": "resampler", "Resampler": "resampler",
    "normalise_image": "resampler",
    "FrameStore": "store", "write_frame": "store",
    "ResampleSummary": "pipeline", "resample_session": "pipeline",
}

__all__ = list(_EXPORTS)


def __getattr__(name: str):
    # Lazy: `polycam --help` imports resample.cli, which must not pull in numba and mrcal.
    mod = _EXPORTS.get(name)
    if mod is None:
        raise AttributeError(f"module 'resample' has no attribute {name!r}")
    return getattr(importlib.import_module(f".{mod}", __name__), name)


def __dir__():
    return sorted(__all__)
