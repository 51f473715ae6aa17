"""The light-field store ``NAME.zarr``: a Zarr v3 group holding ``L[t, face, y, x, v, u]`` (SPEC.md).

Contents:

* array ``L``: float32, dims ``(T, F, Ny, Nx, Nv, Nu)`` or ``(T, F, Ny, Nx, Nv, Nu, C)``,
  intensities normalised to [0, 1] (8-bit / 255, 16-bit / 65535). ``L`` may
  hold NaN where a sample has no data (e.g. a ray no camera saw); this module
  stores whatever it is given and does not check values. Readers that cannot
  handle NaN should use ``W`` (0 there) or ``np.nan_to_num``.
* array ``W`` (optional): float32 in [0, 1], dims ``(T, F, Ny, Nx, Nv, Nu)``:
  confidence of each sample (push-pull weight; 0 = no data).
* attributes ``format = "polycam-lightfield"``, ``version = 1``, ``faces``
  (``{"name", "R_rig_face", "z_pi", "f"}`` each), ``x``, ``y``, ``u``, ``v``
  (regular increasing sample coordinates shared by all faces) and
  ``timestamps_ns`` (T ints, strictly increasing). Other attributes and arrays
  are allowed and ignored (room for provenance).
* attribute ``camera_positions`` (optional; written by ``polycam resample`` for cameras on
  the focal plane): ``[[face, iy, ix], ...]``, one per camera, its centre's position in
  fractional grid indices; the camera's data are at the view ``(round(iy), round(ix))`` (Python's round)
  (:func:`camera_positions_attr`, :attr:`LightFieldStore.camera_positions`).
* attribute ``camera_noise`` (optional; written by ``polycam resample``): ``{"sigma", "images"}``,
  the median sensor noise's std of the cameras' images ([0, 1] units, as ``L``) and how many
  images it was estimated from (:attr:`LightFieldStore.camera_noise_sigma`).
* file ``groundtruth.tum`` (optional): ``T_world_rig`` per frame.

Both arrays are chunked one chunk per (frame, face): a frame is written or read
without touching any other, and writers of different faces never share a
chunk. :class:`LightFieldWriter` builds the store in ``NAME.zarr.partial`` next
to the target and renames it on :meth:`~LightFieldWriter.close`, so a crash
never leaves a half-written ``NAME.zarr``. See docs/conventions.md for frames
and axis orders.
"""

from __future__ import annotations

import json
import logging
import operator
import os
import shutil
from pathlib import Path
from typing import Any, Iterable, Iterator

import numpy as np

from .errors import FormatError, InputError
from .lightfield import Axis, LightFieldGrid, _check_faces_attr
from .trajectory import Trajectory, read_tum, write_tum

__all__ = [
    "LIGHTFIELD_FORMAT",
    "LIGHTFIELD_VERSION",
    "LightFieldWriter",
    "write_lightfield",
    "LightFieldStore",
    "open_lightfield",
    "camera_positions_attr",
    "check_store_target",
    "publish_store",
]

log = logging.getLogger(__name__)

LIGHTFIELD_FORMAT = "polycam-lightfield"
LIGHTFIELD_VERSION = 1
_INT64_MAX = int(np.iinfo(np.int64).max)


def _zarr():
    import zarr  # lazily: keeps `polycam --help` fast

    return zarr


def _is_int(v: Any) -> bool:
    return isinstance(v, (int, np.integer)) and not isinstance(v, (bool, np.bool_))


def _check_groundtruth(traj: Trajectory, timestamps_ns: list[int]) -> None:
    if len(traj) != len(timestamps_ns) or not np.array_equal(
            np.asarray(traj.timestamps_ns, np.int64), np.asarray(timestamps_ns, np.int64)):
        raise ValueError(f"groundtruth: needs one pose per frame at the frame timestamps "
                         f"({len(timestamps_ns)} frames, {len(traj)} poses)")


def check_store_target(path: Path, overwrite: bool) -> None:
    """Raise :class:`InputError` (one line naming ``path``) unless a store may be written at
    ``path``: nothing there, or ``overwrite`` and either a Zarr store or an empty folder (a
    folder holding something else is never replaced)."""
    if not path.exists():
        return
    if not overwrite:
        raise InputError(f"{path}: already exists (choose another name or allow overwriting)")
    if path.is_dir() and any(path.iterdir()) and not (path / "zarr.json").is_file():
        raise InputError(f"{path}: refusing to overwrite a folder that is not a Zarr store")


def publish_store(partial: Path, path: Path, overwrite: bool) -> None:
    """Move the finished store ``partial`` to ``path``, replacing what is there only as
    :func:`check_store_target` allows (checked again: it may have appeared since the writer
    began); the old store is moved aside first and removed after the rename."""
    if not path.exists():
        os.replace(partial, path)
        return
    check_store_target(path, overwrite)
    old = path.with_name(f"{path.name}.old-{os.getpid()}")
    os.replace(path, old)
    os.replace(partial, path)
    if old.is_dir():
        shutil.rmtree(old)
    else:
        old.unlink()


class LightFieldWriter:
    """Write a light-field store frame by frame.

    ``grid`` fixes the per-frame dims ``(F, Ny, Nx, Nv, Nu)``; ``colour`` = C
    adds a trailing colour axis; ``with_weights`` adds the ``W`` array. The
    store is built in ``<path>.partial`` (a stale one from a crash is removed)
    and renamed to ``path`` by :meth:`close`. An existing ``path`` is an error
    unless ``overwrite`` (and then it is only replaced once the new store is
    complete). As a context manager an exception removes the partial store.
    """

    def __init__(self, path: str | os.PathLike, grid: LightFieldGrid, *, colour: int | None = None,
                 with_weights: bool = False, overwrite: bool = False,
                 groundtruth: Trajectory | None = None):
        self.path = Path(path)
        self.grid = grid
        if colour is not None and (not _is_int(colour) or colour < 1):
            raise ValueError(f"colour must be None or an integer >= 1, got {colour!r}")
        self.colour = None if colour is None else int(colour)
        self.with_weights = bool(with_weights)
        self.overwrite = bool(overwrite)
        self.groundtruth = groundtruth
        self._check_target()
        self.partial = self.path.with_name(self.path.name + ".partial")
        if self.partial.exists():
            log.warning("%s: removing a stale partial store from an earlier run", self.partial)
            shutil.rmtree(self.partial)
        self.frame_shape = tuple(grid.shape) + ((self.colour,) if self.colour else ())
        """Dims of one frame of L: (F, Ny, Nx, Nv, Nu[, C])."""
        zarr = _zarr()
        self._group = zarr.open_group(str(self.partial), mode="w-", zarr_format=3)
        self._L = self._group.create_array(
            "L", shape=(0, *self.frame_shape), chunks=(1, 1, *self.frame_shape[1:]),
            dtype="float32", fill_value=0.0)
        self._W = None
        if self.with_weights:
            self._W = self._group.create_array(
                "W", shape=(0, *grid.shape), chunks=(1, 1, *grid.shape[1:]),
                dtype="float32", fill_value=0.0)
        self._timestamps: list[int] = []
        self._closed = False
        self._write_attrs()

    def _check_target(self) -> None:
        check_store_target(self.path, self.overwrite)

    def _write_attrs(self) -> None:
        attrs = {"format": LIGHTFIELD_FORMAT, "version": LIGHTFIELD_VERSION, **self.grid.attrs(),
                 "timestamps_ns": list(self._timestamps)}
        self._group.attrs.update(attrs)

    def __len__(self) -> int:
        return len(self._timestamps)

    def append(self, L_frame: np.ndarray, timestamp_ns: int, W_frame: np.ndarray | None = None) -> int:
        """Append one frame; returns its index t.

        L_frame: (F, Ny, Nx, Nv, Nu[, C]) intensities in [0, 1] (cast to float32; NaN allowed).
        timestamp_ns: int [ns], strictly increasing.
        W_frame: (F, Ny, Nx, Nv, Nu) weights in [0, 1]; required iff ``with_weights``.
        """
        if self._closed:
            raise ValueError(f"{self.path}: writer is closed")
        L = np.asarray(L_frame, dtype=np.float32)
        if L.shape != self.frame_shape:
            raise ValueError(f"L_frame: expected dims {self.frame_shape}, got {L.shape}")
        if not _is_int(timestamp_ns) or not 0 <= int(timestamp_ns) <= _INT64_MAX:
            raise ValueError(f"timestamp_ns: expected a non-negative integer [ns], got {timestamp_ns!r}")
        ns = int(timestamp_ns)
        if self._timestamps and ns <= self._timestamps[-1]:
            raise ValueError(f"timestamp_ns {ns} is not after the previous frame's {self._timestamps[-1]}")
        if self._W is not None:
            if W_frame is None:
                raise ValueError("W_frame is required: the store was opened with with_weights=True")
            W = np.asarray(W_frame, dtype=np.float32)
            if W.shape != tuple(self.grid.shape):
                raise ValueError(f"W_frame: expected dims {tuple(self.grid.shape)}, got {W.shape}")
        elif W_frame is not None:
            raise ValueError("W_frame given but the store was opened with with_weights=False")
        t = len(self._timestamps)
        self._L.resize((t + 1, *self.frame_shape))
        self._L[t] = L
        if self._W is not None:
            self._W.resize((t + 1, *self.grid.shape))
            self._W[t] = W
        self._timestamps.append(ns)
        return t

    def close(self, groundtruth: Trajectory | None = None) -> Path:
        """Finish the store: write the attributes (and ``groundtruth.tum`` when a trajectory
        is given here or to the constructor: one pose per frame at the frame timestamps),
        then rename the partial store to ``path``. Returns ``path``. Idempotent."""
        if self._closed:
            return self.path
        traj = groundtruth if groundtruth is not None else self.groundtruth
        try:
            self._write_attrs()
            if traj is not None:
                _check_groundtruth(traj, self._timestamps)
                write_tum(self.partial / "groundtruth.tum", traj)
            self._publish()
        except BaseException:
            self.abort()
            raise
        self._closed = True
        log.debug("light field %s: %d frames written", self.path, len(self._timestamps))
        return self.path

    def _publish(self) -> None:
        publish_store(self.partial, self.path, self.overwrite)

    def abort(self) -> None:
        """Drop the partial store (nothing is left at ``path``)."""
        self._closed = True
        shutil.rmtree(self.partial, ignore_errors=True)

    def __enter__(self) -> "LightFieldWriter":
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is None:
            self.close()
        else:
            self.abort()
            log.warning("light field %s: not written (%s)", self.path, exc_type.__name__)


def write_lightfield(path: str | os.PathLike, grid: LightFieldGrid, frames: np.ndarray | Iterable[np.ndarray],
                     timestamps_ns: np.ndarray | Iterable[int], weights: np.ndarray | Iterable[np.ndarray] | None = None,
                     groundtruth: Trajectory | None = None, *, overwrite: bool = False) -> Path:
    """Write a whole light-field store at once.

    frames: (T, F, Ny, Nx, Nv, Nu[, C]) array or an iterable of per-frame arrays
        (the colour axis is inferred from the first frame).
    timestamps_ns: (T,) int [ns], strictly increasing.
    weights: optional (T, F, Ny, Nx, Nv, Nu) array or iterable.
    """
    ts = np.asarray(timestamps_ns if isinstance(timestamps_ns, np.ndarray) else list(timestamps_ns))
    if ts.ndim != 1 or (ts.size and not np.issubdtype(ts.dtype, np.integer)):
        raise ValueError(f"timestamps_ns: expected (T,) integers [ns], got {ts.dtype} {ts.shape}")
    it = iter(frames)
    ws = iter(weights) if weights is not None else None
    first = next(it, None)
    colour = None
    if first is not None:
        nd = np.ndim(first)
        if nd == 6:
            colour = int(np.shape(first)[-1])
        elif nd != 5:
            raise ValueError(f"frames: expected frames of dims (F, Ny, Nx, Nv, Nu[, C]), got {np.shape(first)}")
    with LightFieldWriter(path, grid, colour=colour, with_weights=weights is not None,
                          overwrite=overwrite, groundtruth=groundtruth) as w:
        if first is not None:
            for n, frame in enumerate(_chain(first, it)):
                if n >= ts.size:
                    raise ValueError(f"more frames than timestamps ({ts.size})")
                w.append(frame, int(ts[n]), next(ws) if ws is not None else None)
        if len(w) != ts.size:
            raise ValueError(f"{len(w)} frames but {ts.size} timestamps")
    return Path(path)


def _chain(first, rest: Iterator) -> Iterator:
    yield first
    yield from rest


def camera_positions_attr(positions: np.ndarray) -> list[list[float]]:
    """The ``camera_positions`` attribute of (F, Ny, Nx, 2) positions (iy, ix) in fractional grid
    indices, NaN at views without a camera (``resample.viewfill.camera_positions``)."""
    pos = np.asarray(positions, float)
    return [[int(k), float(pos[k, j, i, 0]), float(pos[k, j, i, 1])]
            for k, j, i in np.argwhere(np.isfinite(pos[..., 0]))]


def _parse_camera_positions(p: Path, value: Any, grid: LightFieldGrid) -> np.ndarray | None:
    """(F, Ny, Nx, 2) from the ``camera_positions`` attribute (None when absent); FormatError
    naming the entry for anything else than ``[face, iy, ix]`` on the grid."""
    if value is None:
        return None
    field = "attrs.camera_positions"
    if not isinstance(value, list):
        raise FormatError(p, "expected a list of [face, iy, ix]", field)
    F, Ny, Nx = grid.shape[:3]
    out = np.full((F, Ny, Nx, 2), np.nan)
    for n, e in enumerate(value):
        if (not isinstance(e, list) or len(e) != 3 or not _is_int(e[0])
                or not all(isinstance(a, (int, float)) and not isinstance(a, bool) and np.isfinite(a) for a in e[1:])):
            raise FormatError(p, f"entry {n}: expected [face, iy, ix] (an integer and two numbers), got {e!r}", field)
        k, fy, fx = int(e[0]), float(e[1]), float(e[2])
        j, i = int(round(fy)), int(round(fx))           # as resample.viewfill.camera_positions assigns them
        if not (0 <= k < F and 0 <= j < Ny and 0 <= i < Nx):
            raise FormatError(p, f"entry {n}: [{k}, {fy}, {fx}] is off the grid's {F} face(s) x {Ny}x{Nx} views",
                              field)
        if np.isfinite(out[k, j, i, 0]):
            raise FormatError(p, f"entry {n}: a second camera at view ({j}, {i}) of face {k}", field)
        out[k, j, i] = (fy, fx)
    return out


def _parse_camera_noise(p: Path, value: Any) -> tuple[float, int]:
    """(sigma, images) from the ``camera_noise`` attribute ((NaN, 0) when absent); FormatError for
    anything else than a table with a finite sigma >= 0 and a positive integer count."""
    if value is None:
        return float("nan"), 0
    field = "attrs.camera_noise"
    if not isinstance(value, dict) or set(value) != {"sigma", "images"}:
        raise FormatError(p, f"expected a table with keys sigma and images, got {value!r}", field)
    sigma, images = value["sigma"], value["images"]
    if isinstance(sigma, bool) or not isinstance(sigma, (int, float)) or not np.isfinite(sigma) or sigma < 0:
        raise FormatError(p, f"sigma: expected a finite number >= 0, got {sigma!r}", field)
    if not _is_int(images) or images < 1:
        raise FormatError(p, f"images: expected a positive integer, got {images!r}", field)
    return float(sigma), int(images)


def _array_member(group, name: str, path: Path):
    """The zarr array ``name`` of ``group``, or None if there is none (or it is a group);
    :class:`FormatError` naming the store ``path`` when its metadata cannot be read."""
    zarr = _zarr()
    try:
        node = group[name]
    except KeyError:
        return None
    except Exception as e:      # zarr.json of the array not JSON, not UTF-8, not a mapping, ...
        raise FormatError(path, f"unreadable array metadata ({type(e).__name__})", name) from None
    return node if isinstance(node, zarr.Array) else None


def _check_group_json(meta: Path) -> None:
    """:class:`FormatError` naming ``meta`` (a store's ``zarr.json``) when it is there but not a JSON
    object in UTF-8; nothing otherwise."""
    if not meta.is_file():
        return
    try:
        doc = json.loads(meta.read_bytes().decode("utf-8"))
    except UnicodeDecodeError:
        raise FormatError(meta, "not UTF-8 text") from None
    except ValueError as e:
        raise FormatError(meta, f"not JSON ({e})") from None
    except OSError as e:
        raise FormatError(meta, f"cannot read ({e.strerror})") from None
    if not isinstance(doc, dict):
        raise FormatError(meta, f"expected a JSON object, got {type(doc).__name__}")


def _read_frame(path: Path, array, name: str, t: int) -> np.ndarray:
    """Frame ``t`` of the zarr ``array`` as float32; :class:`FormatError` naming the store, the
    array and the frame when its chunks cannot be decoded (truncated or corrupt chunk files,
    chunk dims that do not match the array)."""
    try:
        return np.asarray(array[t], dtype=np.float32)
    except MemoryError:
        raise                  # not the file's fault: the CLI says so in its own line
    except Exception as e:     # zarr and its codecs raise many types (RuntimeError, ValueError, OSError, ...)
        raise FormatError(path, f"frame {t}: unreadable chunk data ({type(e).__name__})", name) from None


class LightFieldStore:
    """A validated, lazily read light-field store (see :func:`open_lightfield`).

    Opening reads only metadata; :meth:`frame` and :meth:`weights` read the
    chunks of one frame. ``L`` and ``W`` give the raw zarr arrays for other
    slices (e.g. an orthographic image ``store.L[t, k, :, :, m, n]``).
    """

    def __init__(self, path: str | os.PathLike):
        self.path = Path(path)
        p = self.path
        if not p.exists():
            raise FormatError(p, "no such light-field store")
        zarr = _zarr()
        try:
            group = zarr.open_group(str(p), mode="r")
        except Exception as e:  # zarr raises several types (GroupNotFoundError, ContainsArrayError, ...)
            _check_group_json(p / "zarr.json")           # name the file when it is what is broken
            raise FormatError(p, f"not a Zarr group ({type(e).__name__})") from None
        attrs = dict(group.attrs)
        self.attrs: dict = attrs
        """All attributes of the group."""
        fmt = attrs.get("format")
        if fmt != LIGHTFIELD_FORMAT:
            raise FormatError(p, f"expected {LIGHTFIELD_FORMAT!r}, got {fmt!r}", "attrs.format")
        version = attrs.get("version")
        if not _is_int(version) or version != LIGHTFIELD_VERSION:
            raise FormatError(p, f"unsupported version {version!r} (this polycam reads version "
                                 f"{LIGHTFIELD_VERSION})", "attrs.version")
        faces = _check_faces_attr(p, attrs.get("faces"))
        axes = {}
        for key in ("x", "y", "u", "v"):
            values = attrs.get(key)
            if not isinstance(values, list) or not all(
                    isinstance(a, (int, float)) and not isinstance(a, bool) for a in values):
                raise FormatError(p, "expected a list of numbers", f"attrs.{key}")
            try:
                axes[key] = Axis.from_values(values, where=f"attrs.{key}")
            except ValueError as e:
                raise FormatError(p, str(e).split(": ", 1)[-1], f"attrs.{key}") from None
        self.grid = LightFieldGrid(faces, **axes)
        """Faces and sample axes of the store."""
        ts = attrs.get("timestamps_ns")
        if not isinstance(ts, list) or not all(_is_int(t) for t in ts):
            raise FormatError(p, "expected a list of integers [ns]", "attrs.timestamps_ns")
        timestamps = np.array(ts, dtype=np.int64) if ts else np.zeros(0, np.int64)
        if np.any(np.diff(timestamps) <= 0):
            i = int(np.flatnonzero(np.diff(timestamps) <= 0)[0]) + 1
            raise FormatError(p, f"not strictly increasing (entry {i})", "attrs.timestamps_ns")
        timestamps.flags.writeable = False
        self.timestamps_ns = timestamps
        """(T,) int64 [ns] frame timestamps (read-only)."""

        # members are looked up by name: listing the group would trip over groundtruth.tum
        L = _array_member(group, "L", p)
        if L is None:
            raise FormatError(p, "missing array", "L")
        F_shape = tuple(self.grid.shape)
        if L.dtype != np.float32:
            raise FormatError(p, f"expected float32, got {L.dtype}", "L")
        if L.ndim not in (6, 7) or tuple(L.shape[1:6]) != F_shape:
            raise FormatError(p, f"dims {tuple(L.shape)} do not match (T, F, Ny, Nx, Nv, Nu[, C]) with "
                                 f"(F, Ny, Nx, Nv, Nu) = {F_shape} from the faces and axes", "L")
        if L.shape[0] != timestamps.size:
            raise FormatError(p, f"{timestamps.size} timestamps for {L.shape[0]} frames in L",
                              "attrs.timestamps_ns")
        self.L = L
        """The zarr array ``L`` (lazy)."""
        self.colour: int | None = int(L.shape[6]) if L.ndim == 7 else None
        """Size C of the colour axis, or None for grey stores."""
        W = _array_member(group, "W", p)
        if W is not None:
            if W.dtype != np.float32:
                raise FormatError(p, f"expected float32, got {W.dtype}", "W")
            if tuple(W.shape) != tuple(L.shape[:6]):
                raise FormatError(p, f"dims {tuple(W.shape)} do not match L's (T, F, Ny, Nx, Nv, Nu) = "
                                     f"{tuple(L.shape[:6])}", "W")
        self.W = W
        """The zarr array ``W`` (lazy) or None."""
        self.camera_positions: np.ndarray | None = _parse_camera_positions(p, attrs.get("camera_positions"), self.grid)
        """(F, Ny, Nx, 2) float64: the camera centres (iy, ix) in fractional grid indices at the views
        holding their data, NaN elsewhere; None when the store does not record them (module docstring)."""
        self.camera_noise_sigma, self.camera_noise_images = _parse_camera_noise(p, attrs.get("camera_noise"))
        """The cameras' sensor noise (std, [0, 1] units) the resampling measured in their images, and
        from how many images (NaN, 0: not recorded; module docstring)."""

    @property
    def num_frames(self) -> int:
        """T, the number of frames."""
        return int(self.timestamps_ns.size)

    def __len__(self) -> int:
        return self.num_frames

    @property
    def has_weights(self) -> bool:
        return self.W is not None

    @property
    def frame_shape(self) -> tuple[int, ...]:
        """Dims of one frame of L: (F, Ny, Nx, Nv, Nu[, C])."""
        return tuple(self.L.shape[1:])

    def _index(self, t: int) -> int:
        i = operator.index(t)
        n = self.num_frames
        if i < 0:
            i += n
        if not 0 <= i < n:
            raise IndexError(f"{self.path}: frame {t} out of range (T = {n})")
        return i

    def frame(self, t: int) -> np.ndarray:
        """Frame t of L: float32 (F, Ny, Nx, Nv, Nu[, C]); reads only that frame's chunks."""
        return _read_frame(self.path, self.L, "L", self._index(t))

    def weights(self, t: int) -> np.ndarray | None:
        """Frame t of W: float32 (F, Ny, Nx, Nv, Nu), or None if the store has no W
        (every sample then has full confidence)."""
        if self.W is None:
            return None
        i = self._index(t)
        W = _read_frame(self.path, self.W, "W", i)
        lo, hi = (float(W.min()), float(W.max())) if W.size else (0.0, 0.0)
        if not (lo >= 0.0 and hi <= 1.0):        # NaN fails too
            raise FormatError(self.path, f"frame {i}: confidences outside [0, 1] (from {lo:g} to {hi:g})", "W")
        return W

    def __iter__(self) -> Iterator[np.ndarray]:
        """Frames of L in order, one at a time."""
        for t in range(self.num_frames):
            yield self.frame(t)

    def groundtruth(self) -> Trajectory | None:
        """``groundtruth.tum`` inside the store (``T_world_rig`` per frame), or None."""
        p = self.path / "groundtruth.tum"
        return read_tum(p) if p.exists() else None

    def __repr__(self) -> str:
        return (f"LightFieldStore({str(self.path)!r}, frames={self.num_frames}, "
                f"frame_shape={self.frame_shape}, weights={self.has_weights})")


def open_lightfield(path: str | os.PathLike) -> LightFieldStore:
    """Open and validate a light-field store (metadata only; frames are read lazily)."""
    return LightFieldStore(path)
