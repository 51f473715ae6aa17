"""A light-field store written frame by frame, in any order, from several processes.

:class:`polycam.lfstore.LightFieldWriter` appends whole frames from one process.
Resampling workers finish frames out of order, so this writer creates the store
(SPEC.md layout, the same attributes and chunking as ``lfstore``) with all ``T``
frames sized up front, and :func:`write_frame` puts frame ``t`` straight into
its chunks. ``L`` and ``W`` are chunked one chunk per (frame, face), so two
workers never touch the same chunk file and need no locking.

Chunks are compressed with Blosc (LZ4, byte shuffle): about as small as zarr's default
Zstandard on light fields and three times faster to write, which matters when a
frame takes less time to resample than to compress.

Like ``LightFieldWriter``, the store is built in ``NAME.zarr.partial`` and
renamed to ``NAME.zarr`` by :meth:`FrameStore.finish`; a crash never leaves a
half-written ``NAME.zarr``. A frame never written reads as zeros (L and W).
"""

from __future__ import annotations

import logging
import os
import shutil
from pathlib import Path

import numpy as np

from polycam.errors import InputError
from polycam.lfstore import LIGHTFIELD_FORMAT, LIGHTFIELD_VERSION, check_store_target, publish_store
from polycam.lightfield import LightFieldGrid
from polycam.trajectory import Trajectory, write_tum

__all__ = ["FrameStore", "write_frame"]

log = logging.getLogger(__name__)


def _zarr():
    import zarr  # lazily: keeps `polycam --help` fast

    return zarr


class FrameStore:
    """Create a light-field store of ``len(timestamps_ns)`` frames for random-order frame writes.

    grid: the light-field grid; channels: None (grey) or C (trailing colour axis).
    timestamps_ns: (T,) int64 strictly increasing. ``extra_attrs`` are added to the
    group (provenance). An existing ``path`` is an error unless ``overwrite``.
    """

    def __init__(self, path: str | os.PathLike, grid: LightFieldGrid, timestamps_ns: np.ndarray, *,
                 channels: int | None = None, overwrite: bool = False, extra_attrs: dict | None = None):
        self.path = Path(path)
        self.grid = grid
        ts = np.asarray(timestamps_ns, np.int64)
        if ts.ndim != 1 or ts.size == 0 or np.any(np.diff(ts) <= 0) or np.any(ts < 0):
            raise InputError(f"{self.path}: need one or more strictly increasing non-negative frame timestamps")
        self.timestamps_ns = ts
        self.channels = channels
        self.overwrite = bool(overwrite)
        self._check_target()
        self.partial = self.path.with_name(self.path.name + ".partial")
        if self.partial.exists():
            log.warning("%s: removing a stale partial store from an earlier run", self.partial)
            shutil.rmtree(self.partial)
        zarr = _zarr()
        from zarr.codecs import BloscCodec

        T = int(ts.size)
        fshape = tuple(grid.shape) + ((int(channels),) if channels else ())
        group = zarr.open_group(str(self.partial), mode="w-", zarr_format=3)
        # Blosc LZ4 with byte shuffle: as small as zarr's default zstd on light fields, ~3x faster
        comp = BloscCodec(cname="lz4", clevel=5, shuffle="shuffle")
        group.create_array("L", shape=(T, *fshape), chunks=(1, 1, *fshape[1:]), dtype="float32", fill_value=0.0,
                           compressors=comp)
        group.create_array("W", shape=(T, *grid.shape), chunks=(1, 1, *grid.shape[1:]), dtype="float32",
                           fill_value=0.0, compressors=comp)
        attrs = {"format": LIGHTFIELD_FORMAT, "version": LIGHTFIELD_VERSION, **grid.attrs(),
                 "timestamps_ns": [int(v) for v in ts]}
        if extra_attrs:
            attrs.update(extra_attrs)
        group.attrs.update(attrs)
        self._finished = False

    def _check_target(self) -> None:
        check_store_target(self.path, self.overwrite)

    def finish(self, groundtruth: Trajectory | None = None) -> Path:
        """Write ``groundtruth.tum`` (if given) and rename the partial store to ``path``."""
        if self._finished:
            return self.path
        if groundtruth is not None:
            write_tum(self.partial / "groundtruth.tum", groundtruth)
        publish_store(self.partial, self.path, self.overwrite)
        self._finished = True
        return self.path

    def abort(self) -> None:
        """Remove the partial store."""
        self._finished = True
        shutil.rmtree(self.partial, ignore_errors=True)


_OPEN: dict[str, tuple] = {}
"""Per-process cache of opened (L, W) arrays by partial-store path."""


def write_frame(partial: str | os.PathLike, t: int, L: np.ndarray, W: np.ndarray) -> None:
    """Write frame ``t`` into the partial store at ``partial`` (from any process).

    L: (F, Ny, Nx, Nv, Nu[, C]) float32; W: (F, Ny, Nx, Nv, Nu) float32.
    """
    key = str(partial)
    arrays = _OPEN.get(key)
    if arrays is None:
        zarr = _zarr()
        g = zarr.open_group(key, mode="r+")
        arrays = (g["L"], g["W"])
        if len(_OPEN) > 4:
            _OPEN.clear()
        _OPEN[key] = arrays
    La, Wa = arrays
    La[t] = L
    Wa[t] = W
