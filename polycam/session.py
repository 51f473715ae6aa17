"""Recorded sessions: EuRoC/ASL-compatible folders of per-camera PNG streams (SPEC.md).

Layout (docs/formats.md gives the details)::

    SESSION/
      session.toml          [session] format, version, rig, status, created, cameras
      rig.toml              the rig the session was captured with
      cam00/data.csv        "#timestamp [ns],filename", one row "<ns>,<ns>.png" per image
      cam00/data/<ns>.png   8- or 16-bit PNG, grey or RGB
      frames.csv            "frame,timestamp_ns,cam00,cam01,...": per synchronised frame,
                            each camera's image timestamp [ns] (empty where it has none)
      calib/cam00.cameramodel   optional mrcal models, rt_cam_ref = T_cam_rig
      groundtruth.tum       optional T_world_rig per frame (synthetic sessions)

:class:`SessionWriter` writes a session so that it is readable at any moment:
every PNG goes through a temporary name and ``os.replace``, each csv row is
flushed as soon as it is written (images before the frame row that refers to
them) and ``status`` stays ``"incomplete"`` until :meth:`SessionWriter.close`.
A crash therefore loses at most the frame being written.

:func:`open_session` validates a session and returns a :class:`Session`
reader. Problems raise :class:`~polycam.errors.FormatError` naming the file
and the line or field. In an ``"incomplete"`` session a last csv line without
a newline (a row cut short by a crash) is ignored; in a ``"complete"`` one it
is an error.

Timestamps are int64 nanoseconds, non-negative (so ``-1`` can mark "no image"
in :attr:`Session.cam_timestamps`). Colour images are RGB in memory (the PNG
files are standard RGB; OpenCV's BGR order never leaks out). See
docs/conventions.md for frames and units.
"""

from __future__ import annotations

import dataclasses
import logging
import math
import os
import shutil
import struct
import threading
import warnings
from datetime import datetime, timezone
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np

from .cameras import write_cameramodel
from .errors import FormatError, InputError
from .rig import Rig, load_rig
from .tomlio import Table, atomic_write_text, load_toml
from .trajectory import Trajectory, read_tum, write_tum

__all__ = [
    "SESSION_FORMAT",
    "SESSION_VERSION",
    "DATA_CSV_HEADER",
    "SessionWriter",
    "Session",
    "open_session",
    "SYNC_WARN_MS",
    "SYNC_AS_IF_TOGETHER",
    "sync_warning",
    "capture_times",
    "capture_time_draw",
    "frame_times",
    "CAPTURE_OFFSET_FRAMES",
    "OTHER_RATE",
    "other_rate_cameras",
]

log = logging.getLogger(__name__)

SESSION_FORMAT = "polycam-session"
SESSION_VERSION = 1
DATA_CSV_HEADER = "#timestamp [ns],filename"
_STATUSES = ("complete", "incomplete")
_RESERVED = {"session.toml", "rig.toml", "frames.csv", "groundtruth.tum", "calib", "lenses"}
_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
_INT64_MAX = np.iinfo(np.int64).max


def _cv2():
    import cv2  # lazily: keeps `polycam --help` fast

    return cv2


# --------------------------------------------------------------------------- writing


def _check_timestamp(value: Any, what: str) -> int:
    """A non-negative int64 timestamp [ns] (numpy integers accepted)."""
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)):
        raise InputError(f"{what}: timestamp must be an integer number of nanoseconds, got {value!r}")
    v = int(value)
    if not 0 <= v <= _INT64_MAX:
        raise InputError(f"{what}: timestamp must be a non-negative int64 [ns], got {v}")
    return v


def _rig_document(rig: Rig, lens_names: Mapping[str, str]) -> dict:
    """A rig as a TOML document that :func:`~polycam.rig.load_rig` reads back to the same rig.

    Grid rigs are written as explicit ``[[camera]]`` entries. ``lens_names``
    maps camera id → lens path to write (relative to the new rig file).
    """
    cams = []
    special = {"id", "device", "position", "rotation", "lens"}
    for c in rig.cameras:
        entry: dict[str, Any] = {"id": c.id}
        if c.device is not None:
            entry["device"] = c.device
        entry["position"] = [float(v) for v in np.asarray(c.position, float)]
        rot = np.asarray(c.rotation, float)
        if np.any(rot != 0):
            entry["rotation"] = [float(v) for v in rot]
        for f in dataclasses.fields(c):
            if f.name in special:
                continue
            v = getattr(c, f.name)
            if v is None:
                continue
            entry[f.name] = _toml_value(v)
        if c.lens is not None:
            entry["lens"] = lens_names[c.id]
        cams.append(entry)
    doc: dict[str, Any] = {"rig": {"name": rig.name}, "camera": cams}
    if rig.mock is not None:
        mock = {}
        for f in dataclasses.fields(rig.mock):
            v = getattr(rig.mock, f.name)
            if v is None or (isinstance(v, dict) and not v):
                continue
            mock[f.name] = _toml_value(v)
        doc["mock"] = mock
    return doc


def _toml_value(v: Any) -> Any:
    if isinstance(v, np.ndarray):
        return v.tolist()
    if isinstance(v, np.generic):
        return v.item()
    if isinstance(v, Path):
        return str(v)
    if isinstance(v, dict):
        return {str(k): _toml_value(x) for k, x in v.items()}
    return v


class SessionWriter:
    """Write a recorded session folder while capturing (SPEC.md "Recorded session").

    ``SessionWriter(path, rig)`` creates the folder (an existing non-empty
    folder is an error unless ``overwrite``, and even then only an earlier
    session, i.e. a folder with a ``session.toml``, is replaced: it is moved
    aside to ``PATH.old-<pid>`` and removed only when the new session closes
    ``complete``; a session that ends otherwise leaves it there, and says so,
    and :meth:`discard` puts it back), writes
    ``session.toml`` with ``status = "incomplete"``, ``rig.toml``, the
    per-camera ``data/`` folders and the csv headers.

    Then, per frame, either :meth:`add_frame` or :meth:`write_image` for each
    camera followed by :meth:`write_frame`. Every row is flushed when written,
    after the image it refers to is in place. :meth:`close` marks the session
    ``"complete"``. As a context manager, an exception inside the block leaves
    the status ``"incomplete"`` (the data written so far stays readable).

    :meth:`write_image` may be called from several threads at once for
    different cameras (PNG encoding runs outside the GIL); with ``threads`` > 1
    :meth:`add_frame` does that itself on a pool of that many threads.

    ``rig.toml`` is a verbatim copy of ``rig.path`` when the rig was read from a
    file and uses no ``lens`` files; otherwise the rig is serialised (grid
    rigs become ``[[camera]]`` lists) and lens models are copied to
    ``SESSION/lenses/`` so the session stays self-contained.
    """

    def __init__(self, path: str | os.PathLike, rig: Rig, *, overwrite: bool = False, threads: int = 1):
        self.path = Path(path)
        self.rig = rig
        self.replaced: Path | None = None
        """Where the session this one replaces (``overwrite``) waits until this one is complete."""
        self.cameras: list[str] = list(rig.ids)
        if not self.cameras:
            raise InputError(f"{self.path}: the rig {rig.name!r} has no cameras")
        clash = [c for c in self.cameras if c in _RESERVED]
        if clash:
            raise InputError(f"{self.path}: camera id {clash[0]!r} clashes with a session file name")
        if self.path.exists():
            if not self.path.is_dir():
                raise InputError(f"{self.path}: exists and is not a folder")
            if any(self.path.iterdir()):
                if not overwrite:
                    raise InputError(f"{self.path}: folder exists and is not empty "
                                     "(choose a new folder or allow overwriting)")
                if not (self.path / "session.toml").is_file():
                    raise InputError(f"{self.path}: refusing to overwrite a folder that is not a "
                                     "polycam session (no session.toml)")
                self.replaced = self.path.with_name(f"{self.path.name}.old-{os.getpid()}")
                if self.replaced.exists():
                    shutil.rmtree(self.replaced)
                os.replace(self.path, self.replaced)
        self.path.mkdir(parents=True, exist_ok=True)
        self.created = datetime.now(timezone.utc).replace(microsecond=0)
        self.status = "incomplete"
        self._closed = False
        self._write_session_toml()
        self._write_rig_toml()

        self._data_csv = {}
        self._locks = {}
        self._last_ns: dict[str, int | None] = {}
        for cam in self.cameras:
            (self.path / cam / "data").mkdir(parents=True, exist_ok=True)
            f = open(self.path / cam / "data.csv", "w", encoding="utf-8", newline="\n")
            f.write(DATA_CSV_HEADER + "\n")
            f.flush()
            self._data_csv[cam] = f
            self._locks[cam] = threading.Lock()
            self._last_ns[cam] = None
        self._frames_csv = open(self.path / "frames.csv", "w", encoding="utf-8", newline="\n")
        self._frames_csv.write(",".join(["frame", "timestamp_ns", *self.cameras]) + "\n")
        self._frames_csv.flush()
        self._frames_lock = threading.Lock()
        self._next_frame = 0
        self._last_frame_ns: int | None = None
        self._pool = None
        if threads > 1:
            from concurrent.futures import ThreadPoolExecutor

            self._pool = ThreadPoolExecutor(int(threads), thread_name_prefix="polycam-png")
        log.debug("session %s: started with %d cameras", self.path, len(self.cameras))

    # -- metadata files

    def _write_session_toml(self) -> None:
        import tomli_w

        created = self.created.isoformat().replace("+00:00", "Z")
        doc = {"session": {"format": SESSION_FORMAT, "version": SESSION_VERSION,
                           "rig": self.rig.name, "status": self.status, "created": created,
                           "cameras": list(self.cameras)}}
        atomic_write_text(self.path / "session.toml",
                          "# polycam recorded session (docs/formats.md)\n" + tomli_w.dumps(doc))

    def _write_rig_toml(self) -> None:
        import tomli_w

        with_lens = [c for c in self.rig.cameras if c.lens is not None]
        if self.rig.path is not None and not with_lens:
            try:
                text = Path(self.rig.path).read_text(encoding="utf-8")
            except OSError as e:
                raise FormatError(self.rig.path, f"cannot read ({e.strerror})") from None
            atomic_write_text(self.path / "rig.toml", text)
            return
        lens_names: dict[str, str] = {}
        copied: dict[Path, str] = {}
        for c in with_lens:
            src = Path(c.lens).resolve()
            if src not in copied:
                name = src.name
                if name in copied.values():
                    name = f"{c.id}-{src.name}"
                (self.path / "lenses").mkdir(exist_ok=True)
                shutil.copyfile(src, self.path / "lenses" / name)
                copied[src] = name
            lens_names[c.id] = f"lenses/{copied[src]}"
        header = f"# rig {self.rig.name!r} as captured (serialised by polycam)\n"
        atomic_write_text(self.path / "rig.toml",
                          header + tomli_w.dumps(_rig_document(self.rig, lens_names)))

    # -- images and frames

    def _check_open(self) -> None:
        if self._closed:
            raise ValueError(f"{self.path}: session writer is closed")

    def _to_png_array(self, cam_id: str, image: np.ndarray) -> np.ndarray:
        img = np.asarray(image)
        if img.dtype not in (np.uint8, np.uint16):
            raise InputError(f"{self.path}: {cam_id}: image dtype must be uint8 or uint16, got {img.dtype}")
        if img.ndim == 3 and img.shape[2] == 1:
            img = img[:, :, 0]
        if not (img.ndim == 2 or (img.ndim == 3 and img.shape[2] == 3)):
            raise InputError(f"{self.path}: {cam_id}: image must be (H, W) grey or (H, W, 3) RGB, "
                             f"got shape {img.shape}")
        spec = self.rig.camera(cam_id)
        if img.shape[:2] != (spec.height, spec.width):
            raise InputError(f"{self.path}: {cam_id}: image is {img.shape[1]}x{img.shape[0]} but the rig "
                             f"gives {spec.width}x{spec.height}")
        if img.ndim == 3:
            img = img[:, :, ::-1]  # RGB → BGR for cv2
        return np.ascontiguousarray(img)

    def write_image(self, cam_id: str, timestamp_ns: int, image: np.ndarray) -> Path:
        """Write one image as ``cam_id/data/<timestamp_ns>.png`` and append its data.csv row.

        image: (H, W) grey or (H, W, 3) RGB, uint8 or uint16, H x W as in the rig.
        timestamp_ns: int [ns] >= 0, strictly increasing per camera.
        Returns the PNG path.
        """
        self._check_open()
        if cam_id not in self._locks:
            raise InputError(f"{self.path}: unknown camera {cam_id!r} (rig has {', '.join(self.cameras)})")
        ns = _check_timestamp(timestamp_ns, f"{self.path}: {cam_id}")
        img = self._to_png_array(cam_id, image)
        with self._locks[cam_id]:
            last = self._last_ns[cam_id]
            if last is not None and ns <= last:
                raise InputError(f"{self.path}: {cam_id}: timestamp {ns} is not after the previous "
                                 f"image's {last}")
            ok, buf = _cv2().imencode(".png", img)
            if not ok:
                raise RuntimeError(f"cv2.imencode failed for {cam_id} image {img.shape} {img.dtype}")
            name = f"{ns}.png"
            data_dir = self.path / cam_id / "data"
            tmp = data_dir / f".tmp-{name}"
            try:
                with open(tmp, "wb") as f:
                    f.write(buf.tobytes())
                os.replace(tmp, data_dir / name)
            except BaseException:
                tmp.unlink(missing_ok=True)
                raise
            f = self._data_csv[cam_id]
            f.write(f"{ns},{name}\n")
            f.flush()
            self._last_ns[cam_id] = ns
        return data_dir / name

    def write_frame(self, timestamp_ns: int, cam_timestamps: Mapping[str, int | None]) -> int:
        """Append a ``frames.csv`` row and return its frame index (0, 1, ...).

        cam_timestamps: camera id → that camera's image timestamp [ns] for this
        frame, or None (cameras not in the mapping also get an empty cell).
        Write the images first (:meth:`write_image`).
        """
        self._check_open()
        ns = _check_timestamp(timestamp_ns, f"{self.path}: frames.csv")
        unknown = [c for c in cam_timestamps if c not in self._locks]
        if unknown:
            raise InputError(f"{self.path}: unknown camera {unknown[0]!r} (rig has {', '.join(self.cameras)})")
        cells = []
        for cam in self.cameras:
            v = cam_timestamps.get(cam)
            cells.append("" if v is None else str(_check_timestamp(v, f"{self.path}: {cam}")))
        with self._frames_lock:
            if self._last_frame_ns is not None and ns <= self._last_frame_ns:
                raise InputError(f"{self.path}: frames.csv: frame timestamp {ns} is not after the "
                                 f"previous frame's {self._last_frame_ns}")
            idx = self._next_frame
            self._frames_csv.write(",".join([str(idx), str(ns), *cells]) + "\n")
            self._frames_csv.flush()
            self._next_frame += 1
            self._last_frame_ns = ns
        return idx

    def add_frame(self, timestamp_ns: int, images: Mapping[str, np.ndarray | None]) -> int:
        """Write every image of ``images`` (camera id → image or None) at ``timestamp_ns``,
        then the frame row; returns the frame index. Cameras left out have no image."""
        stamps = {cam: (None if img is None else timestamp_ns) for cam, img in images.items()}
        todo = [(cam, img) for cam, img in images.items() if img is not None]
        if self._pool is not None and len(todo) > 1:
            from concurrent.futures import wait

            futures = [self._pool.submit(self.write_image, cam, timestamp_ns, img) for cam, img in todo]
            wait(futures)
            for f in futures:
                f.result()  # re-raises the first failure, once every image is done
        else:
            for cam, img in todo:
                self.write_image(cam, timestamp_ns, img)
        return self.write_frame(timestamp_ns, stamps)

    @property
    def num_frames(self) -> int:
        """Frames written so far."""
        return self._next_frame

    # -- optional files

    def write_calibration(self, cam_id: str, model) -> Path:
        """Write ``calib/<cam_id>.cameramodel`` (an mrcal cameramodel, rt_cam_ref = T_cam_rig)."""
        if cam_id not in self._locks:
            raise InputError(f"{self.path}: unknown camera {cam_id!r} (rig has {', '.join(self.cameras)})")
        d = self.path / "calib"
        d.mkdir(exist_ok=True)
        return write_cameramodel(model, d / f"{cam_id}.cameramodel")

    def write_groundtruth(self, traj: Trajectory) -> Path:
        """Write ``groundtruth.tum`` (``T_world_rig`` per frame)."""
        dst = self.path / "groundtruth.tum"
        write_tum(dst, traj)
        return dst

    def write_extra(self, relname: str | os.PathLike, text: str) -> Path:
        """Write a text file (report, statistics) at ``relname`` inside the session, atomically."""
        rel = Path(relname)
        reserved = {*_RESERVED, *self.cameras}
        if rel.is_absolute() or not rel.parts or ".." in rel.parts or rel.parts[0] in reserved:
            raise ValueError(f"write_extra: {str(relname)!r} must be a relative path that does not "
                             "touch the session's own files")
        dst = self.path / rel
        dst.parent.mkdir(parents=True, exist_ok=True)
        atomic_write_text(dst, text)
        return dst

    # -- ending

    def flush(self) -> None:
        """Flush every open csv file to the operating system."""
        if self._closed:
            return
        for cam, f in self._data_csv.items():
            with self._locks[cam]:
                f.flush()
        with self._frames_lock:
            self._frames_csv.flush()

    def _close_files(self) -> None:
        if self._pool is not None:
            self._pool.shutdown(wait=True)
        for f in [*self._data_csv.values(), self._frames_csv]:
            try:
                f.flush()
                os.fsync(f.fileno())
            finally:
                f.close()

    def close(self, status: str = "complete") -> None:
        """Flush and close the csv files and record ``status`` in session.toml (idempotent)."""
        if status not in _STATUSES:
            raise ValueError(f"status must be one of {_STATUSES}, got {status!r}")
        if self._closed:
            return
        self._closed = True
        self._close_files()
        self.status = status
        self._write_session_toml()
        log.debug("session %s: closed (%s, %d frames)", self.path, status, self._next_frame)
        self._settle_replaced()

    def _settle_replaced(self) -> None:
        """The replaced session: removed once this one is complete, else kept beside it."""
        if self.replaced is None or not self.replaced.exists():
            return
        if self.status == "complete":
            shutil.rmtree(self.replaced, ignore_errors=True)
            self.replaced = None
        else:
            log.warning("session %s: %s; the session it was to replace is kept in %s", self.path,
                        self.status, self.replaced)

    def discard(self) -> None:
        """Remove this session's folder (nothing was recorded worth keeping) and put the session it
        replaced, if any, back in its place."""
        if not self._closed:
            self._closed = True
            self._close_files()
        shutil.rmtree(self.path, ignore_errors=True)
        if self.replaced is not None and self.replaced.exists():
            os.replace(self.replaced, self.path)
            self.replaced = None

    def __enter__(self) -> "SessionWriter":
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is None:
            self.close("complete")
        elif not self._closed:
            self._closed = True
            self._close_files()  # status stays "incomplete"
            log.warning("session %s: left incomplete after %d frames (%s)", self.path,
                        self._next_frame, exc_type.__name__)
            self._settle_replaced()


# --------------------------------------------------------------------------- reading


def _png_header(data: bytes, path: Path) -> tuple[int, int, int, int]:
    """(width, height, bit depth, colour type) from the first 26 bytes of a PNG."""
    if len(data) < 26 or data[:8] != _PNG_SIGNATURE or data[12:16] != b"IHDR":
        raise FormatError(path, "not a PNG file (bad signature or IHDR header)")
    w, h, depth, ctype = struct.unpack(">IIBB", data[16:26])
    return w, h, depth, ctype


def _csv_lines(path: Path, incomplete: bool) -> tuple[str | None, list[str], list[int]]:
    """Header line, data lines and their 1-based line numbers of a small csv file.

    Blank lines are skipped. A last line without a newline is dropped in an
    incomplete session (cut short by a crash) and is an error otherwise.
    """
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise FormatError(path, "no such file") from None
    except UnicodeDecodeError:
        raise FormatError(path, "not UTF-8 text") from None
    except OSError as e:
        raise FormatError(path, f"cannot read ({e.strerror})") from None
    lines = text.split("\n")
    if lines[-1] != "":
        if not incomplete:
            raise FormatError(path, "last line is truncated (no newline at the end of the file)",
                              f"line {len(lines)}")
        log.info("%s: ignoring a truncated last line (incomplete session)", path)
    lines = lines[:-1]
    kept = [(i + 1, ln.rstrip("\r")) for i, ln in enumerate(lines) if ln.strip()]
    if not kept:
        return None, [], []
    return kept[0][1], [ln for _, ln in kept[1:]], [n for n, _ in kept[1:]]


def _split_rows(path: Path, rows: list[str], linenos: list[int], ncols: int, what: str) -> np.ndarray:
    """Rows split on commas into an (N, ncols) array of stripped strings."""
    parts = [r.split(",") for r in rows]
    for p, n in zip(parts, linenos):
        if len(p) != ncols:
            raise FormatError(path, f"expected {ncols} comma-separated values ({what}), got {len(p)}",
                              f"line {n}")
    if not parts:
        return np.zeros((0, ncols), dtype=str)
    return np.strings.strip(np.array(parts, dtype=str))


def _parse_ints(path: Path, cells: np.ndarray, linenos: list[int], what: str) -> np.ndarray:
    """(N,) strings → int64, all >= 0; errors name the line."""
    try:
        vals = cells.astype(np.int64) if cells.size else np.zeros(0, np.int64)
        ok = bool(np.all(vals >= 0))
    except (ValueError, OverflowError):
        ok = False
    if not ok:
        for s, n in zip(cells.tolist(), linenos):
            try:
                v = int(s)
            except ValueError:
                raise FormatError(path, f"{what}: {s!r} is not an integer", f"line {n}") from None
            if not 0 <= v <= _INT64_MAX:
                raise FormatError(path, f"{what}: {v} is not a non-negative int64", f"line {n}")
        raise FormatError(path, f"{what}: not integers")  # unreachable in practice
    return vals


def _first_bad(path: Path, bad: np.ndarray, linenos: list[int], problem: str) -> None:
    idx = np.flatnonzero(bad)
    if idx.size:
        raise FormatError(path, problem, f"line {linenos[int(idx[0])]}")


class Session:
    """A validated recorded session (read with :func:`open_session`).

    Validation on open: session.toml keys and values, rig.toml, every listed
    camera's folder and ``data.csv`` (header, ``<ns>,<ns>.png`` rows, strictly
    increasing timestamps, listed PNGs present in ``data/``), the first image of
    each camera (PNG header: size equal to the rig's width x height, 8/16-bit
    grey or RGB) and ``frames.csv`` (columns = cameras, frame indices 0..N-1,
    strictly increasing timestamps, every camera timestamp listed in that
    camera's data.csv). Each later :meth:`read_image` checks its own PNG.
    """

    path: Path
    """The session folder."""
    rig: Rig
    """The rig of ``rig.toml``."""
    cameras: list[str]
    """Camera ids in column order (session.toml ``cameras``)."""
    status: str
    """``"complete"`` or ``"incomplete"``."""
    created: datetime
    """Creation time (timezone-aware; UTC when the file gives no offset)."""
    timestamps_ns: np.ndarray
    """(N,) int64 [ns] frame timestamps (read-only)."""
    cam_timestamps: np.ndarray
    """(N, C) int64 [ns] image timestamp of camera c in frame i, -1 where it has none (read-only)."""

    def __init__(self, path: str | os.PathLike):
        self.path = Path(path)
        self._capture_times: np.ndarray | None = None
        self._frame_times: np.ndarray | None = None
        if not self.path.is_dir():
            raise FormatError(self.path, "no such session folder")
        self._read_session_toml()
        incomplete = self.status == "incomplete"
        self.rig = load_rig(self.path / "rig.toml")
        if self.rig.name != self._rig_name:
            raise FormatError(self.path / "session.toml",
                              f"{self._rig_name!r} does not match rig.toml's name {self.rig.name!r}",
                              "[session].rig")
        rig_ids = set(self.rig.ids)
        for cam in self.cameras:
            if cam not in rig_ids:
                raise FormatError(self.path / "session.toml", f"camera {cam!r} is not in rig.toml",
                                  "[session].cameras")
        self._images: dict[str, np.ndarray] = {}
        for cam in self.cameras:
            self._images[cam] = self._read_data_csv(cam, incomplete)
        self._read_frames_csv(incomplete)
        log.debug("opened session %s: %d cameras, %d frames, %s", self.path, len(self.cameras),
                  len(self), self.status)

    # -- validation on open

    def _read_session_toml(self) -> None:
        p = self.path / "session.toml"
        doc = load_toml(p)
        top = Table(p, "", doc)
        s = top.subtable("session")
        top.finish()
        fmt = s.get("format", str)
        if fmt != SESSION_FORMAT:
            raise s.error("format", f"expected {SESSION_FORMAT!r}, got {fmt!r}")
        version = s.number("version", integer=True)
        if version != SESSION_VERSION:
            raise s.error("version", f"unsupported version {version} (this polycam reads version "
                                     f"{SESSION_VERSION})")
        self._rig_name = s.get("rig", str)
        self.status = s.choice("status", _STATUSES)
        created = s.get("created", (str, datetime))
        if isinstance(created, str):
            try:
                created = datetime.fromisoformat(created)
            except ValueError:
                raise s.error("created", f"not an ISO-8601 date and time: {created!r}") from None
        if created.tzinfo is None:
            created = created.replace(tzinfo=timezone.utc)
        self.created = created
        cams = s.get("cameras", list)
        if not cams or not all(isinstance(c, str) and c for c in cams):
            raise s.error("cameras", f"expected a non-empty list of camera ids, got {cams!r}")
        dup = sorted({c for c in cams if cams.count(c) > 1})
        if dup:
            raise s.error("cameras", f"camera {dup[0]!r} is listed twice")
        bad = [c for c in cams if "/" in c or "\\" in c or c.startswith(".") or "," in c]
        if bad:
            raise s.error("cameras", f"not usable as a folder name: {bad[0]!r}")
        s.finish()
        self.cameras = list(cams)

    def _read_data_csv(self, cam: str, incomplete: bool) -> np.ndarray:
        cam_dir = self.path / cam
        if not cam_dir.is_dir():
            raise FormatError(cam_dir, "camera folder missing (listed in session.toml cameras)")
        p = cam_dir / "data.csv"
        header, rows, linenos = _csv_lines(p, incomplete)
        if header is None:
            if incomplete:
                return np.zeros(0, np.int64)
            raise FormatError(p, f"empty file: expected the header {DATA_CSV_HEADER!r}")
        if header.replace(" ", "") != DATA_CSV_HEADER.replace(" ", ""):
            raise FormatError(p, f"expected the header {DATA_CSV_HEADER!r}, got {header!r}", "line 1")
        cells = _split_rows(p, rows, linenos, 2, "timestamp, filename")
        ts = _parse_ints(p, cells[:, 0], linenos, "timestamp")
        names = cells[:, 1].tolist()
        for t, name, n in zip(ts.tolist(), names, linenos):
            if name != f"{t}.png":
                raise FormatError(p, f"filename {name!r} does not match the timestamp (expected '{t}.png')",
                                  f"line {n}")
        _first_bad(p, np.diff(ts) <= 0, linenos[1:], "timestamps are not strictly increasing")
        if ts.size:
            data_dir = cam_dir / "data"
            try:
                present = set(os.listdir(data_dir))
            except FileNotFoundError:
                raise FormatError(data_dir, "image folder missing") from None
            for name, n in zip(names, linenos):
                if name not in present:
                    raise FormatError(p, f"image {cam}/data/{name} is listed but missing", f"line {n}")
            self._check_png(cam, data_dir / names[0])
        ts.flags.writeable = False
        return ts

    def _read_frames_csv(self, incomplete: bool) -> None:
        p = self.path / "frames.csv"
        C = len(self.cameras)
        header, rows, linenos = _csv_lines(p, incomplete)
        expected = ["frame", "timestamp_ns", *self.cameras]
        if header is None:
            if not incomplete:
                raise FormatError(p, f"empty file: expected the header {','.join(expected)!r}")
        elif [h.strip() for h in header.split(",")] != expected:
            raise FormatError(p, f"columns {header!r} do not match session.toml's cameras "
                                 f"(expected {','.join(expected)!r})", "line 1")
        cells = _split_rows(p, rows, linenos, 2 + C, ",".join(expected))
        frame = _parse_ints(p, cells[:, 0], linenos, "frame")
        _first_bad(p, frame != np.arange(frame.size), linenos,
                   "frame indices must count 0, 1, 2, ... in order")
        ts = _parse_ints(p, cells[:, 1], linenos, "timestamp_ns")
        _first_bad(p, np.diff(ts) <= 0, linenos[1:], "timestamps are not strictly increasing")
        cam_ts = np.full((ts.size, C), -1, dtype=np.int64)
        for c, cam in enumerate(self.cameras):
            col = cells[:, 2 + c]
            have = col != ""
            rows_have = [n for n, h in zip(linenos, have.tolist()) if h]
            vals = _parse_ints(p, col[have], rows_have, cam)
            known = self._images[cam]
            _first_bad(p, ~np.isin(vals, known), rows_have,
                       f"{cam}: timestamp has no image in {cam}/data.csv")
            cam_ts[have, c] = vals
        ts.flags.writeable = False
        cam_ts.flags.writeable = False
        self.timestamps_ns = ts
        self.cam_timestamps = cam_ts

    def _check_png(self, cam: str, path: Path, head: bytes | None = None) -> None:
        """Check a PNG's IHDR against the rig (cheap: reads 26 bytes)."""
        if head is None:
            try:
                with open(path, "rb") as f:
                    head = f.read(26)
            except FileNotFoundError:
                raise FormatError(path, f"image listed in {cam}/data.csv is missing") from None
        w, h, depth, ctype = _png_header(head, path)
        spec = self.rig.camera(cam)
        if (w, h) != (spec.width, spec.height):
            raise FormatError(path, f"image is {w}x{h} but rig.toml gives {cam} "
                                    f"{spec.width}x{spec.height}")
        if depth not in (8, 16) or ctype not in (0, 2):
            raise FormatError(path, f"expected an 8- or 16-bit grey or RGB PNG, got bit depth {depth}, "
                                    f"colour type {ctype}")

    # -- access

    def __len__(self) -> int:
        return int(self.timestamps_ns.shape[0])

    def _cam(self, cam: str) -> np.ndarray:
        try:
            return self._images[cam]
        except KeyError:
            raise KeyError(f"{self.path}: no camera {cam!r} (session has {', '.join(self.cameras)})") from None

    def image_timestamps(self, cam: str) -> np.ndarray:
        """(M,) int64 [ns] timestamps of every image of ``cam`` (read-only)."""
        return self._cam(cam)

    def image_path(self, cam: str, timestamp_ns: int) -> Path:
        """Path of the PNG of ``cam`` at ``timestamp_ns``; KeyError if there is none."""
        ts = self._cam(cam)
        ns = int(timestamp_ns)
        i = int(np.searchsorted(ts, ns))
        if i >= ts.size or ts[i] != ns:
            raise KeyError(f"{self.path}: {cam} has no image at {ns} ns")
        return self.path / cam / "data" / f"{ns}.png"

    def image_size(self, cam: str) -> tuple[int, int]:
        """``(width, height)`` [px] of ``cam``'s images (mrcal's imagersize order)."""
        self._cam(cam)
        spec = self.rig.camera(cam)
        return spec.width, spec.height

    def read_image(self, cam: str, timestamp_ns: int) -> np.ndarray:
        """The image of ``cam`` at ``timestamp_ns``: (H, W) grey or (H, W, 3) RGB, uint8 or uint16."""
        p = self.image_path(cam, timestamp_ns)
        try:
            data = p.read_bytes()
        except FileNotFoundError:
            raise FormatError(p, f"image listed in {cam}/data.csv is missing") from None
        except OSError as e:
            raise FormatError(p, f"cannot read ({e.strerror})") from None
        self._check_png(cam, p, data[:26])
        cv2 = _cv2()
        img = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
        if img is None:
            raise FormatError(p, "unreadable PNG (corrupt or truncated)")
        if img.ndim == 3:
            img = np.ascontiguousarray(img[:, :, ::-1])  # cv2's BGR → RGB
        return img

    def capture_times_ns(self) -> np.ndarray:
        """(F, C) int64 [ns]: when camera c captured its image of frame i, its image timestamp with the
        timestamp jitter taken out (:func:`capture_times`: the frame's timestamp plus the camera's
        running median offset from it; a camera at a slower frame rate than the rig's fastest in
        ``rig.toml``, its own clock); -1 where it has none. Computed once per session."""
        if self._capture_times is None:
            times = capture_times(self.frame_times_ns(), self.cam_timestamps, other_rate=self.other_rate)
            times.setflags(write=False)
            self._capture_times = times
        return self._capture_times

    @property
    def other_rate(self) -> list[bool]:
        """(C,) per camera (session order): does it run at a slower frame rate than the rig's fastest
        (``rig.toml``'s fps, :func:`other_rate_cameras`)?"""
        return other_rate_cameras([self.rig.camera(c).fps for c in self.cameras])

    def frame_times_ns(self) -> np.ndarray:
        """(F,) int64 [ns]: the frames' times without the jitter of their timestamps (:func:`frame_times`),
        the times :meth:`capture_times_ns` and the correction of unsynchronised cameras refer to."""
        if self._frame_times is None:
            times = frame_times(self.timestamps_ns)
            times.setflags(write=False)
            self._frame_times = times
        return self._frame_times

    def timestamp_jitter_ns(self) -> float:
        """[ns] RMS of the image timestamps about :meth:`capture_times_ns` (0 without images): the
        jitter of the timestamps themselves (USB transfer, kernel scheduling), which does not move
        what the images show."""
        has = self.cam_timestamps >= 0
        if not has.any():
            return 0.0
        d = (self.cam_timestamps[has] - self.capture_times_ns()[has]).astype(np.float64)
        return float(np.sqrt(np.mean(d * d)))

    def jitter_spread_ns(self) -> float:
        """[ns] the capture spread the timestamps' jitter alone would give synchronised cameras: the
        expected range over the cameras of the errors of their running medians
        (:func:`capture_times`: a median of n of the jitter has ~1.25 jitter / sqrt(n) std), with n the
        session's frames up to :data:`CAPTURE_OFFSET_FRAMES`."""
        have = int(np.count_nonzero(np.any(self.cam_timestamps >= 0, axis=0)))
        if have < 2:
            return 0.0
        return self.capture_time_std_ns() * _normal_range(have)

    def capture_time_std_ns(self) -> float:
        """[ns] the std of each camera's capture time (:meth:`capture_times_ns`) as an estimate: its
        running median of n of the jittered timestamps (~1.25 jitter / sqrt(n)), n the session's frames
        up to :data:`CAPTURE_OFFSET_FRAMES`."""
        n = min(len(self), CAPTURE_OFFSET_FRAMES)
        return _MEDIAN_STD * self.timestamp_jitter_ns() / math.sqrt(max(n, 1))

    def capture_time_draw_ns(self, rng: np.random.Generator) -> np.ndarray:
        """(F, C) float64 [ns]: one draw of the error of :meth:`capture_times_ns` (:func:`capture_time_draw`),
        what ``polycam motion --sync-draws`` moves the cameras by (:mod:`polycam.sync_draws_cli`)."""
        return capture_time_draw(self.timestamps_ns, self.cam_timestamps, rng, other_rate=self.other_rate)

    def capture_spread_ns(self) -> np.ndarray:
        """(F,) int64 [ns]: per frame, the latest minus the earliest of its cameras' capture times
        (:meth:`capture_times_ns`, the timestamps without their jitter; 0 for a frame with fewer than two
        images): how far apart in time the cameras captured it."""
        times = self.capture_times_ns()
        ts = times.astype(np.float64)
        ts[times < 0] = np.nan
        with np.errstate(invalid="ignore"), warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)          # all-NaN rows: frames without images
            spread = np.nanmax(ts, axis=1) - np.nanmin(ts, axis=1)
        return np.nan_to_num(spread, nan=0.0).astype(np.int64)

    def read_frame(self, i: int) -> dict[str, np.ndarray | None]:
        """Images of frame ``i``: camera id → image, or None where the camera has none."""
        row = self.cam_timestamps[i]
        return {cam: (self.read_image(cam, int(ns)) if ns >= 0 else None)
                for cam, ns in zip(self.cameras, row.tolist())}

    def calibration(self, calib_dir: str | os.PathLike | None = None) -> dict | None:
        """``<cam>.cameramodel`` of every camera (mrcal cameramodels, rt_cam_ref = T_cam_rig).

        From ``calib_dir`` (e.g. ``polycam calibrate --out``; an error if it does
        not exist) or by default ``SESSION/calib`` (None when the session has
        none). A missing model or one whose imagersize differs from the
        camera's is a :class:`FormatError`.
        """
        from .cameras import load_cameramodel

        if calib_dir is not None:
            d = Path(calib_dir)
            if not d.is_dir():
                raise FormatError(d, "no such calibration folder")
        else:
            d = self.path / "calib"
            if not d.is_dir():
                return None
        models = {}
        for cam in self.cameras:
            p = d / f"{cam}.cameramodel"
            m = load_cameramodel(p)
            W, H = (int(v) for v in m.imagersize())
            if (W, H) != self.image_size(cam):
                w0, h0 = self.image_size(cam)
                raise FormatError(p, f"imagersize {W}x{H} does not match the camera's {w0}x{h0}")
            models[cam] = m
        return models

    def groundtruth(self) -> Trajectory | None:
        """``groundtruth.tum`` (``T_world_rig`` per frame) or None if the session has none."""
        p = self.path / "groundtruth.tum"
        return read_tum(p) if p.exists() else None

    def __repr__(self) -> str:
        return (f"Session({str(self.path)!r}, rig={self.rig.name!r}, cameras={len(self.cameras)}, "
                f"frames={len(self)}, status={self.status!r})")


def open_session(path: str | os.PathLike) -> Session:
    """Open and validate a recorded session folder (see :class:`Session`)."""
    return Session(path)


CAPTURE_OFFSET_FRAMES = 31
"""The window [frames] of :func:`capture_times`' running median of a camera's capture offset from the
frame time: free-running cameras at one frame rate keep their phase for many frames, and a centred
median follows a steady drift (two cameras' rates 0.1 % apart: 1 ms in 31 frames at 30 Hz), while the
timestamps jitter from frame to frame (the median of 31 has ~1/4 of their std)."""

OTHER_RATE = 0.01
"""A camera whose nominal frame rate is further than this fraction below the fastest camera's runs at
another rate (:func:`other_rate_cameras`)."""


def other_rate_cameras(fps: Sequence[float]) -> list[bool]:
    """(C,) per camera of nominal frame rates ``fps`` (C,) [Hz]: does it run at another rate than the
    fastest (slower by more than :data:`OTHER_RATE`)? Free-running, such a camera's images have no phase
    that stays put against the frames (``capture.sync``), and :func:`capture_times` follows its own clock."""
    top = max(fps) if len(fps) else 0.0
    return [float(f) < (1.0 - OTHER_RATE) * top for f in fps]


_MEDIAN_STD = math.sqrt(math.pi / 2)
"""The std of the median of n Gaussian samples, times sqrt(n) / their std (large n)."""


def _normal_range(n: int) -> float:
    """The expected range (max − min) of n independent standard normal samples."""
    x = np.linspace(-9.0, 9.0, 3601)
    cdf = 0.5 * (1.0 + np.vectorize(math.erf)(x / math.sqrt(2.0)))
    return float(np.sum(1.0 - cdf ** n - (1.0 - cdf) ** n) * (x[1] - x[0]))


def frame_times(timestamps_ns: np.ndarray, window: int = CAPTURE_OFFSET_FRAMES) -> np.ndarray:
    """The frames' times without the jitter their timestamps inherit from their images' (a frame's
    timestamp is the median of its images'): each frame's time on the frame clock (the first frame's time
    plus a whole number of median frame intervals) plus a line fitted through the timestamps' offsets from
    it over ``window`` frames around it (least squares, offsets beyond three robust stds left out). (F,) int64 [ns] → (F,) int64 [ns], non-decreasing where the intervals
    are."""
    ts = np.asarray(timestamps_ns, np.int64)
    if ts.size < 3:
        return ts.copy()
    steps = np.diff(ts).astype(np.float64)
    ticks = np.concatenate([[0.0], np.cumsum(np.maximum(np.round(steps / np.median(steps)), 1.0))])
    period = float(np.polyfit(ticks, ts - ts[0], 1)[0])           # frame intervals, a lost frame two
    clock = ts[0] + ticks * period
    half = max(int(window), 1) // 2
    off = (ts - clock).astype(np.float64)
    smooth = np.empty_like(off)
    for f in range(ts.size):                      # a line through the window's offsets (a rate off the
        lo, hi = max(f - half, 0), min(f + half + 1, ts.size)        # nominal one drifts them linearly)
        x, y = ticks[lo:hi] - ticks[f], off[lo:hi]
        keep = np.abs(y - np.median(y)) <= 3.0 * max(1.4826 * np.median(np.abs(y - np.median(y))), 1.0)
        A = np.stack([np.ones(int(keep.sum())), x[keep]], axis=1)
        smooth[f] = np.linalg.lstsq(A, y[keep], rcond=None)[0][0]
    return np.round(clock + smooth).astype(np.int64)


def capture_times(timestamps_ns: np.ndarray, cam_timestamps: np.ndarray,
                  window: int = CAPTURE_OFFSET_FRAMES, other_rate: Sequence[bool] | None = None) -> np.ndarray:
    """When each camera captured its image of each frame, from the image timestamps without their jitter.

    A camera's image timestamp is its capture time plus jitter (the time the driver stamps it at
    varies with the USB transfer and the scheduler) and, for free-running cameras, plus a phase offset
    from the other cameras that stays put for many frames. Per camera, the offset from the frame's
    timestamp is replaced by its running median over ``window`` frames (centred; fewer at the ends),
    restarted wherever it jumps by more than half the frame interval (the capture's grouping moved to
    the camera's next image: its phase drifted past the tolerance). A camera at another frame rate
    (``other_rate``, :func:`other_rate_cameras`: its offset from the frames' times saws through a period)
    follows its own clock instead: :func:`frame_times` of its own image timestamps.

    timestamps_ns: (F,) int64 [ns] frame times (:func:`frame_times`: the timestamps without their jitter).
    cam_timestamps: (F, C) int64 [ns] image timestamps, -1 where a camera has no image. other_rate: (C,)
    the cameras at another frame rate (default none). Returns (F, C) int64 [ns], -1 where
    ``cam_timestamps`` is."""
    frames = np.asarray(timestamps_ns, np.int64)
    stamps = np.asarray(cam_timestamps, np.int64)
    out = np.full(stamps.shape, -1, np.int64)
    if stamps.size == 0:
        return out
    half = max(int(window), 1) // 2
    jump = 0.5 * float(np.median(np.diff(frames))) if frames.size > 1 else math.inf
    for k in range(stamps.shape[1]):
        rows = np.flatnonzero(stamps[:, k] >= 0)
        if rows.size == 0:
            continue
        if other_rate is not None and other_rate[k]:
            out[rows, k] = frame_times(stamps[rows, k], window)
            continue
        offset = (stamps[rows, k] - frames[rows]).astype(np.float64)
        cuts = np.flatnonzero(np.abs(np.diff(offset)) > jump) + 1
        smooth = np.empty_like(offset)
        for seg in np.split(np.arange(rows.size), cuts):
            padded = np.concatenate([np.full(half, np.nan), offset[seg], np.full(half, np.nan)])
            smooth[seg] = np.nanmedian(np.lib.stride_tricks.sliding_window_view(padded, 2 * half + 1), axis=1)
        out[rows, k] = frames[rows] + np.round(smooth).astype(np.int64)
    return out


def capture_time_draw(timestamps_ns: np.ndarray, cam_timestamps: np.ndarray, rng: np.random.Generator, *,
                      window: int = CAPTURE_OFFSET_FRAMES, other_rate: Sequence[bool] | None = None) -> np.ndarray:
    """One draw of the error of :func:`capture_times`' estimate (a parametric bootstrap): the estimate
    run again on image timestamps made from the capture times plus new jitter (normal, with the std of
    the timestamps about the capture times, counting what the estimate fitted per camera: an offset
    per window, a slower camera's line two) and on frame times made again from the frame times plus
    their timestamps' jitter (:func:`frame_times`). So each camera's error is what its estimator makes
    of the jitter: a running median's, nearly one offset for a session shorter than its window, and a
    slower camera's (its own clock, a line through its timestamps) an offset and a rate, larger at the
    session's ends, against the frame clock's own.

    timestamps_ns: (F,) int64 [ns] the frames' timestamps; cam_timestamps: (F, C) int64 [ns] the image
    timestamps, -1 where a camera has no image; window, other_rate: as :func:`capture_times`. Returns
    (F, C) float64 [ns], 0 where there is no image (and everywhere when the timestamps do not jitter)."""
    stamps = np.asarray(cam_timestamps, np.int64)
    frames = frame_times(timestamps_ns, window)
    times = capture_times(frames, stamps, window, other_rate)
    has = times >= 0
    out = np.zeros(times.shape)
    if not has.any():
        return out

    def std(residuals: np.ndarray, fitted: float) -> float:
        return math.sqrt(float(np.sum(residuals.astype(np.float64) ** 2)) / max(residuals.size - fitted, 1.0))

    # the residuals' RMS counting what the estimate fitted: per camera an offset per window of its
    # images, a line (two) for a slower camera; the frame clock a line per window of frames
    windows = np.ceil(has.sum(axis=0) / max(int(window), 1))
    slow = np.zeros(has.shape[1], bool) if other_rate is None else np.asarray(other_rate, bool)
    sigma = std(stamps[has] - times[has], float(np.sum(windows * np.where(slow, 2.0, 1.0))))
    if sigma == 0.0:
        return out
    residuals = np.asarray(timestamps_ns, np.int64) - frames
    sigma_frames = std(residuals, 2.0 * math.ceil(residuals.size / max(int(window), 1)))
    again = frame_times(frames + np.round(sigma_frames * rng.standard_normal(frames.shape)).astype(np.int64), window)
    noise = np.round(sigma * rng.standard_normal(times.shape)).astype(np.int64)
    again = capture_times(again, np.where(has, times + noise, -1), window, other_rate)
    out[has] = (again - times)[has]
    return out


SYNC_WARN_MS = 1.0
"""[ms] median capture spread (:meth:`Session.capture_spread_ns`) from which the commands that read a
session's images into a light field warn (:func:`sync_warning`)."""


def sync_warning(session: Session) -> str:
    """'' for a session whose cameras captured each frame together (median spread under
    :data:`SYNC_WARN_MS` plus what the timestamps' jitter alone spreads, :meth:`Session.jitter_spread_ns`),
    else the start of the line the CLI prints, which each command ends with what it does about it
    (:data:`SYNC_AS_IF_TOGETHER` or its own): the resampling puts every image of a frame at the frame's
    time, so a moving rig's cameras seen at different times make an inconsistent light field
    (docs/motion.md, "Unsynchronised cameras")."""
    if len(session) == 0 or len(session.cameras) < 2:
        return ""
    spread = session.capture_spread_ns() / 1e6
    med = float(np.median(spread))
    if med < SYNC_WARN_MS + session.jitter_spread_ns() / 1e6:
        return ""
    return (f"the cameras are not synchronised: their images of a frame span {med:.1f} ms (median; "
            f"{float(spread.max()):.1f} ms at most)")


SYNC_AS_IF_TOGETHER = ("; each is resampled as if taken at the frame's time, which on a moving rig makes the errors "
                       "several times larger and the reported std too small (polycam motion SESSION and polycam "
                       "depth SESSION correct for it, polycam resample with --sync-motion TRAJ.tum; docs/motion.md, "
                       "\"Unsynchronised cameras\")")
"""How :func:`sync_warning`'s line ends where the images are resampled as they are."""
