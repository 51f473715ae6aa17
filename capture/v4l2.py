"""The V4L2 driver: USB webcams through the kernel's Video4Linux2 API, by direct ioctls.

No GPL code and no extra package: the ioctls are issued through ``ctypes``
with the structures of the kernel's uapi header ``linux/videodev2.h``, laid out
for x86_64 (checked against the header by tests/test_capture_v4l2.py when a C
compiler and the header are present).

Per camera (rig ``device`` = ``/dev/videoN`` or a ``/dev/v4l/by-id|by-path``
link): ``VIDIOC_QUERYCAP`` (must be a streaming video-capture node),
``VIDIOC_S_FMT`` (the rig's width x height and pixel format: ``GREY``, ``Y16``,
``YUYV``, ``MJPG`` or ``RGB`` = V4L2 ``RGB3``; a device that adjusts them is an
error), ``VIDIOC_S_PARM`` (frame interval 1/fps), controls (below),
``VIDIOC_REQBUFS`` / ``VIDIOC_QUERYBUF`` / ``mmap`` / ``VIDIOC_QBUF`` for
``buffers`` memory-mapped buffers, ``VIDIOC_STREAMON``. Frames are taken with
``select`` over all cameras' file descriptors and ``VIDIOC_DQBUF`` (non-blocking;
``EAGAIN`` = nothing yet), copied out of the buffer and the buffer queued again.

Timestamps and sequence numbers come from the dequeued ``v4l2_buffer``: when
the driver flags its timestamps ``V4L2_BUF_FLAG_TIMESTAMP_MONOTONIC`` (every
uvcvideo device does) they are ``CLOCK_MONOTONIC`` at microsecond resolution,
the clock the other drivers use; otherwise the host's monotonic clock at
dequeue time is used and a warning logged. A timestamp of the start of the
exposure (``V4L2_BUF_FLAG_TSTAMP_SRC_SOE``, as uvcvideo's) is moved to its middle,
the moment the image shows (as the OAK driver's), by half the manual exposure
the controls set; with automatic exposure (``Controls(fixed=False)``, or a
device without the controls) the exposure is unknown and the stamp stays at the
start. An end-of-frame timestamp (``TSTAMP_SRC_EOF``) stays as it is: it lags the
exposure by the readout, which the device does not report (logged once). A buffer flagged
``V4L2_BUF_FLAG_ERROR`` (or an undecodable MJPG frame) is discarded, so it
shows as a sequence gap (a drop). ``ENODEV``/``EIO`` on a camera report it as
lost.

Controls (:class:`Controls`): an array needs equal exposure, gain and white
balance on every camera, so by default the driver switches auto exposure,
auto gain and auto white balance off where the device has those controls and
sets the same exposure (``V4L2_CID_EXPOSURE_ABSOLUTE``, 100 µs units), gain and
white-balance temperature [K] on every camera: the values given, or else the
first camera's current values. What was applied is reported by
:meth:`V4L2Source.info` (and so in ``capture_stats.toml``).

All system calls go through a :class:`Syscalls` object so tests can put a
faithful fake kernel underneath (:class:`capture.fakes.FakeV4L2`).
"""

from __future__ import annotations

import ctypes
import errno
import logging
import os
import select as _select
import time
from dataclasses import dataclass
from typing import Any

import numpy as np

from polycam.rig import CameraSpec

from .source import CameraLost, CaptureError, Frame, FrameSource, Item

__all__ = [
    "Syscalls", "V4L2Device", "V4L2Source", "Controls", "fourcc", "fourcc_str", "list_v4l2_devices",
    "v4l2_capability", "v4l2_fmtdesc", "v4l2_frmsizeenum", "v4l2_frmivalenum", "v4l2_pix_format",
    "v4l2_format", "v4l2_streamparm", "v4l2_control", "v4l2_queryctrl", "v4l2_requestbuffers",
    "v4l2_buffer", "timeval", "PIXEL_FORMAT_FOURCC",
]

log = logging.getLogger(__name__)

# ----------------------------------------------------------------------------- uapi structures (x86_64)

u8, u32, s32 = ctypes.c_uint8, ctypes.c_uint32, ctypes.c_int32


class v4l2_capability(ctypes.Structure):
    _fields_ = [("driver", u8 * 16), ("card", u8 * 32), ("bus_info", u8 * 32), ("version", u32),
                ("capabilities", u32), ("device_caps", u32), ("reserved", u32 * 3)]


class v4l2_fmtdesc(ctypes.Structure):
    _fields_ = [("index", u32), ("type", u32), ("flags", u32), ("description", u8 * 32),
                ("pixelformat", u32), ("mbus_code", u32), ("reserved", u32 * 3)]


class v4l2_frmsize_discrete(ctypes.Structure):
    _fields_ = [("width", u32), ("height", u32)]


class v4l2_frmsize_stepwise(ctypes.Structure):
    _fields_ = [("min_width", u32), ("max_width", u32), ("step_width", u32),
                ("min_height", u32), ("max_height", u32), ("step_height", u32)]


class _frmsize_union(ctypes.Union):
    _fields_ = [("discrete", v4l2_frmsize_discrete), ("stepwise", v4l2_frmsize_stepwise)]


class v4l2_frmsizeenum(ctypes.Structure):
    _anonymous_ = ("u",)
    _fields_ = [("index", u32), ("pixel_format", u32), ("type", u32), ("u", _frmsize_union),
                ("reserved", u32 * 2)]


class v4l2_fract(ctypes.Structure):
    _fields_ = [("numerator", u32), ("denominator", u32)]


class v4l2_frmival_stepwise(ctypes.Structure):
    _fields_ = [("min", v4l2_fract), ("max", v4l2_fract), ("step", v4l2_fract)]


class _frmival_union(ctypes.Union):
    _fields_ = [("discrete", v4l2_fract), ("stepwise", v4l2_frmival_stepwise)]


class v4l2_frmivalenum(ctypes.Structure):
    _anonymous_ = ("u",)
    _fields_ = [("index", u32), ("pixel_format", u32), ("width", u32), ("height", u32), ("type", u32),
                ("u", _frmival_union), ("reserved", u32 * 2)]


class v4l2_pix_format(ctypes.Structure):
    _fields_ = [("width", u32), ("height", u32), ("pixelformat", u32), ("field", u32),
                ("bytesperline", u32), ("sizeimage", u32), ("colorspace", u32), ("priv", u32),
                ("flags", u32), ("ycbcr_enc", u32), ("quantization", u32), ("xfer_func", u32)]


class _format_union(ctypes.Union):
    # raw_data[200]; the kernel union also holds struct v4l2_window (with pointers), so it
    # is 8-byte aligned on x86_64: the c_uint64 member reproduces that alignment.
    _fields_ = [("pix", v4l2_pix_format), ("raw_data", u8 * 200), ("_align", ctypes.c_uint64)]


class v4l2_format(ctypes.Structure):
    _fields_ = [("type", u32), ("fmt", _format_union)]


class v4l2_captureparm(ctypes.Structure):
    _fields_ = [("capability", u32), ("capturemode", u32), ("timeperframe", v4l2_fract),
                ("extendedmode", u32), ("readbuffers", u32), ("reserved", u32 * 4)]


class _parm_union(ctypes.Union):
    _fields_ = [("capture", v4l2_captureparm), ("raw_data", u8 * 200)]


class v4l2_streamparm(ctypes.Structure):
    _fields_ = [("type", u32), ("parm", _parm_union)]


class v4l2_control(ctypes.Structure):
    _fields_ = [("id", u32), ("value", s32)]


class v4l2_queryctrl(ctypes.Structure):
    _fields_ = [("id", u32), ("type", u32), ("name", u8 * 32), ("minimum", s32), ("maximum", s32),
                ("step", s32), ("default_value", s32), ("flags", u32), ("reserved", u32 * 2)]


class v4l2_requestbuffers(ctypes.Structure):
    _fields_ = [("count", u32), ("type", u32), ("memory", u32), ("capabilities", u32),
                ("flags", u8), ("reserved", u8 * 3)]


class timeval(ctypes.Structure):
    _fields_ = [("tv_sec", ctypes.c_long), ("tv_usec", ctypes.c_long)]


class v4l2_timecode(ctypes.Structure):
    _fields_ = [("type", u32), ("flags", u32), ("frames", u8), ("seconds", u8), ("minutes", u8),
                ("hours", u8), ("userbits", u8 * 4)]


class _buffer_m(ctypes.Union):
    _fields_ = [("offset", u32), ("userptr", ctypes.c_ulong), ("planes", ctypes.c_void_p), ("fd", s32)]


class v4l2_buffer(ctypes.Structure):
    _fields_ = [("index", u32), ("type", u32), ("bytesused", u32), ("flags", u32), ("field", u32),
                ("timestamp", timeval), ("timecode", v4l2_timecode), ("sequence", u32), ("memory", u32),
                ("m", _buffer_m), ("length", u32), ("reserved2", u32), ("request_fd", s32)]


# ----------------------------------------------------------------------------- ioctl numbers and constants

_IOC_WRITE, _IOC_READ = 1, 2


def _IOC(direction: int, nr: int, size: int) -> int:
    return (direction << 30) | (size << 16) | (ord("V") << 8) | nr


def _IOR(nr: int, st) -> int:
    return _IOC(_IOC_READ, nr, ctypes.sizeof(st))


def _IOW(nr: int, st) -> int:
    return _IOC(_IOC_WRITE, nr, ctypes.sizeof(st))


def _IOWR(nr: int, st) -> int:
    return _IOC(_IOC_READ | _IOC_WRITE, nr, ctypes.sizeof(st))


VIDIOC_QUERYCAP = _IOR(0, v4l2_capability)
VIDIOC_ENUM_FMT = _IOWR(2, v4l2_fmtdesc)
VIDIOC_G_FMT = _IOWR(4, v4l2_format)
VIDIOC_S_FMT = _IOWR(5, v4l2_format)
VIDIOC_REQBUFS = _IOWR(8, v4l2_requestbuffers)
VIDIOC_QUERYBUF = _IOWR(9, v4l2_buffer)
VIDIOC_QBUF = _IOWR(15, v4l2_buffer)
VIDIOC_DQBUF = _IOWR(17, v4l2_buffer)
VIDIOC_STREAMON = _IOW(18, ctypes.c_int)
VIDIOC_STREAMOFF = _IOW(19, ctypes.c_int)
VIDIOC_G_PARM = _IOWR(21, v4l2_streamparm)
VIDIOC_S_PARM = _IOWR(22, v4l2_streamparm)
VIDIOC_G_CTRL = _IOWR(27, v4l2_control)
VIDIOC_S_CTRL = _IOWR(28, v4l2_control)
VIDIOC_QUERYCTRL = _IOWR(36, v4l2_queryctrl)
VIDIOC_ENUM_FRAMESIZES = _IOWR(74, v4l2_frmsizeenum)
VIDIOC_ENUM_FRAMEINTERVALS = _IOWR(75, v4l2_frmivalenum)

V4L2_BUF_TYPE_VIDEO_CAPTURE = 1
V4L2_MEMORY_MMAP = 1
V4L2_FIELD_NONE = 1
V4L2_CAP_VIDEO_CAPTURE = 0x00000001
V4L2_CAP_META_CAPTURE = 0x00800000
V4L2_CAP_STREAMING = 0x04000000
V4L2_CAP_DEVICE_CAPS = 0x80000000
V4L2_CAP_TIMEPERFRAME = 0x1000
V4L2_FRMSIZE_TYPE_DISCRETE, V4L2_FRMSIZE_TYPE_CONTINUOUS, V4L2_FRMSIZE_TYPE_STEPWISE = 1, 2, 3
V4L2_FRMIVAL_TYPE_DISCRETE, V4L2_FRMIVAL_TYPE_CONTINUOUS, V4L2_FRMIVAL_TYPE_STEPWISE = 1, 2, 3
V4L2_BUF_FLAG_MAPPED = 0x00000001
V4L2_BUF_FLAG_QUEUED = 0x00000002
V4L2_BUF_FLAG_DONE = 0x00000004
V4L2_BUF_FLAG_ERROR = 0x00000040
V4L2_BUF_FLAG_TIMESTAMP_MASK = 0x0000E000
V4L2_BUF_FLAG_TIMESTAMP_UNKNOWN = 0x00000000
V4L2_BUF_FLAG_TIMESTAMP_MONOTONIC = 0x00002000
V4L2_BUF_FLAG_TIMESTAMP_COPY = 0x00004000
V4L2_BUF_FLAG_TSTAMP_SRC_MASK = 0x00070000
V4L2_BUF_FLAG_TSTAMP_SRC_EOF = 0x00000000
V4L2_BUF_FLAG_TSTAMP_SRC_SOE = 0x00010000
V4L2_CTRL_FLAG_DISABLED = 0x0001
V4L2_CTRL_FLAG_INACTIVE = 0x0010
V4L2_CTRL_TYPE_INTEGER, V4L2_CTRL_TYPE_BOOLEAN, V4L2_CTRL_TYPE_MENU = 1, 2, 3

V4L2_CID_BASE = 0x00980900
V4L2_CID_AUTO_WHITE_BALANCE = V4L2_CID_BASE + 12
V4L2_CID_AUTOGAIN = V4L2_CID_BASE + 18
V4L2_CID_GAIN = V4L2_CID_BASE + 19
V4L2_CID_WHITE_BALANCE_TEMPERATURE = V4L2_CID_BASE + 26
V4L2_CID_CAMERA_CLASS_BASE = 0x009A0900
V4L2_CID_EXPOSURE_AUTO = V4L2_CID_CAMERA_CLASS_BASE + 1
V4L2_CID_EXPOSURE_ABSOLUTE = V4L2_CID_CAMERA_CLASS_BASE + 2
V4L2_EXPOSURE_AUTO, V4L2_EXPOSURE_MANUAL = 0, 1


def fourcc(code: str) -> int:
    """V4L2 pixel-format code of a four-character string (``v4l2_fourcc``)."""
    b = code.encode("ascii").ljust(4)
    return b[0] | (b[1] << 8) | (b[2] << 16) | (b[3] << 24)


def fourcc_str(value: int) -> str:
    return bytes((value >> (8 * i)) & 0xFF for i in range(4)).decode("ascii", "replace").rstrip()


PIXEL_FORMAT_FOURCC = {"GREY": fourcc("GREY"), "Y16": fourcc("Y16 "), "YUYV": fourcc("YUYV"),
                       "MJPG": fourcc("MJPG"), "RGB": fourcc("RGB3")}
"""Rig ``pixel_format`` → V4L2 fourcc."""


def _cstr(arr) -> str:
    return bytes(arr).split(b"\0", 1)[0].decode("utf-8", "replace")


# ----------------------------------------------------------------------------- system calls


class Syscalls:
    """The kernel boundary: open/close/ioctl/mmap/select (the real ones).

    ``ioctl`` raises :class:`OSError` with the errno, like the C call's -1/errno.
    """

    def __init__(self):
        self._libc = None

    def _ioctl_fn(self):
        if self._libc is None:
            libc = ctypes.CDLL(None, use_errno=True)
            fn = libc.ioctl
            fn.argtypes = [ctypes.c_int, ctypes.c_ulong, ctypes.c_void_p]
            fn.restype = ctypes.c_int
            self._libc = fn
        return self._libc

    def open(self, path: str) -> int:
        return os.open(path, os.O_RDWR | os.O_NONBLOCK | os.O_CLOEXEC)

    def close(self, fd: int) -> None:
        os.close(fd)

    def ioctl(self, fd: int, request: int, arg) -> None:
        fn = self._ioctl_fn()
        ptr = ctypes.addressof(arg) if arg is not None else None
        while True:
            if fn(fd, request, ptr) == 0:
                return
            e = ctypes.get_errno()
            if e != errno.EINTR:
                raise OSError(e, os.strerror(e))

    def mmap(self, fd: int, length: int, offset: int):
        import mmap

        return mmap.mmap(fd, length, mmap.MAP_SHARED, mmap.PROT_READ | mmap.PROT_WRITE, offset=offset)

    def select(self, fds: list[int], timeout: float) -> list[int]:
        r, _, x = _select.select(fds, [], fds, max(timeout, 0.0))
        return sorted(set(r) | set(x))

    def monotonic_ns(self) -> int:
        return time.monotonic_ns()


# ----------------------------------------------------------------------------- one device


@dataclass
class _Buffer:
    index: int
    length: int
    mapping: Any


class V4L2Device:
    """One V4L2 video node (a thin, checked wrapper over the ioctls)."""

    def __init__(self, path: str, sys: Syscalls | None = None):
        self.path = str(path)
        self.sys = sys if sys is not None else Syscalls()
        self.fd: int | None = None
        self.buffers: list[_Buffer] = []
        self.streaming = False
        self.width = self.height = self.bytesperline = self.sizeimage = 0
        self.pixelformat = 0

    # -- plumbing

    def open(self) -> None:
        try:
            self.fd = self.sys.open(self.path)
        except OSError as e:
            raise CaptureError(f"{self.path}: cannot open ({e.strerror or e})") from None

    def _ioctl(self, request: int, arg) -> None:
        if self.fd is None:
            raise OSError(errno.EBADF, "device not open")
        self.sys.ioctl(self.fd, request, arg)

    def close(self) -> None:
        if self.fd is None:
            return
        try:
            self.stop()
        except OSError:
            pass
        try:
            self.sys.close(self.fd)
        finally:
            self.fd = None

    # -- queries

    def querycap(self) -> dict[str, Any]:
        cap = v4l2_capability()
        self._ioctl(VIDIOC_QUERYCAP, cap)
        caps = cap.device_caps if cap.capabilities & V4L2_CAP_DEVICE_CAPS else cap.capabilities
        return {"driver": _cstr(cap.driver), "card": _cstr(cap.card), "bus_info": _cstr(cap.bus_info),
                "version": cap.version, "capabilities": cap.capabilities, "device_caps": caps,
                "capture": bool(caps & V4L2_CAP_VIDEO_CAPTURE), "streaming": bool(caps & V4L2_CAP_STREAMING)}

    def formats(self) -> list[tuple[str, str]]:
        """(fourcc, description) of every capture format, in the driver's order."""
        out = []
        for i in range(256):
            d = v4l2_fmtdesc(index=i, type=V4L2_BUF_TYPE_VIDEO_CAPTURE)
            try:
                self._ioctl(VIDIOC_ENUM_FMT, d)
            except OSError as e:
                if e.errno == errno.EINVAL:
                    break
                raise
            out.append((fourcc_str(d.pixelformat), _cstr(d.description)))
        return out

    def frame_sizes(self, code: str) -> list[tuple[int, int]]:
        """Discrete (width, height) sizes of format ``code`` (for a stepwise range: min and max)."""
        out = []
        for i in range(256):
            s = v4l2_frmsizeenum(index=i, pixel_format=fourcc(code))
            try:
                self._ioctl(VIDIOC_ENUM_FRAMESIZES, s)
            except OSError as e:
                if e.errno == errno.EINVAL:
                    break
                raise
            if s.type == V4L2_FRMSIZE_TYPE_DISCRETE:
                out.append((s.discrete.width, s.discrete.height))
            else:
                sw = s.stepwise
                out += [(sw.min_width, sw.min_height), (sw.max_width, sw.max_height)]
                break
        return out

    def frame_rates(self, code: str, width: int, height: int) -> list[float]:
        """Frame rates [Hz] offered for a format and size (discrete; stepwise: min and max)."""
        out = []
        for i in range(256):
            f = v4l2_frmivalenum(index=i, pixel_format=fourcc(code), width=width, height=height)
            try:
                self._ioctl(VIDIOC_ENUM_FRAMEINTERVALS, f)
            except OSError as e:
                if e.errno == errno.EINVAL:
                    break
                raise
            if f.type == V4L2_FRMIVAL_TYPE_DISCRETE:
                fr = f.discrete
                if fr.numerator:
                    out.append(fr.denominator / fr.numerator)
            else:
                for fr in (f.stepwise.min, f.stepwise.max):
                    if fr.numerator:
                        out.append(fr.denominator / fr.numerator)
                break
        return out

    # -- configuration

    def set_format(self, code: str, width: int, height: int) -> tuple[str, int, int]:
        """VIDIOC_S_FMT; returns what the driver chose (fourcc, width, height)."""
        f = v4l2_format(type=V4L2_BUF_TYPE_VIDEO_CAPTURE)
        f.fmt.pix.width, f.fmt.pix.height = width, height
        f.fmt.pix.pixelformat = fourcc(code)
        f.fmt.pix.field = V4L2_FIELD_NONE
        self._ioctl(VIDIOC_S_FMT, f)
        p = f.fmt.pix
        self.width, self.height, self.pixelformat = p.width, p.height, p.pixelformat
        self.bytesperline, self.sizeimage = p.bytesperline, p.sizeimage
        return fourcc_str(p.pixelformat), p.width, p.height

    def set_fps(self, fps: float) -> float | None:
        """VIDIOC_S_PARM with time per frame 1/fps; returns the rate the driver chose (None if it
        cannot set one)."""
        from fractions import Fraction

        p = v4l2_streamparm(type=V4L2_BUF_TYPE_VIDEO_CAPTURE)
        try:
            self._ioctl(VIDIOC_G_PARM, p)
        except OSError as e:
            if e.errno in (errno.EINVAL, errno.ENOTTY):
                return None
            raise
        if not p.parm.capture.capability & V4L2_CAP_TIMEPERFRAME:
            return None
        fr = Fraction(1 / fps).limit_denominator(1_000_000)
        p.parm.capture.timeperframe.numerator = fr.numerator
        p.parm.capture.timeperframe.denominator = fr.denominator
        self._ioctl(VIDIOC_S_PARM, p)
        t = p.parm.capture.timeperframe
        return t.denominator / t.numerator if t.numerator else None

    def query_control(self, cid: int) -> dict[str, int] | None:
        """min/max/step/default/flags of a control, or None if the device has none."""
        q = v4l2_queryctrl(id=cid)
        try:
            self._ioctl(VIDIOC_QUERYCTRL, q)
        except OSError as e:
            if e.errno == errno.EINVAL:
                return None
            raise
        if q.flags & V4L2_CTRL_FLAG_DISABLED:
            return None
        return {"min": q.minimum, "max": q.maximum, "step": q.step, "default": q.default_value,
                "flags": q.flags, "type": q.type, "name": _cstr(q.name)}

    def get_control(self, cid: int) -> int:
        c = v4l2_control(id=cid)
        self._ioctl(VIDIOC_G_CTRL, c)
        return c.value

    def set_control(self, cid: int, value: int) -> int:
        """VIDIOC_S_CTRL; returns the value read back."""
        c = v4l2_control(id=cid, value=int(value))
        self._ioctl(VIDIOC_S_CTRL, c)
        return self.get_control(cid)

    # -- streaming

    def start(self, count: int = 4) -> None:
        """Allocate and map ``count`` buffers, queue them, start streaming."""
        r = v4l2_requestbuffers(count=count, type=V4L2_BUF_TYPE_VIDEO_CAPTURE, memory=V4L2_MEMORY_MMAP)
        self._ioctl(VIDIOC_REQBUFS, r)
        if r.count < 2:
            raise CaptureError(f"{self.path}: the driver granted {r.count} buffer(s); need at least 2")
        try:
            for i in range(r.count):
                b = v4l2_buffer(index=i, type=V4L2_BUF_TYPE_VIDEO_CAPTURE, memory=V4L2_MEMORY_MMAP)
                self._ioctl(VIDIOC_QUERYBUF, b)
                m = self.sys.mmap(self.fd, b.length, b.m.offset)
                self.buffers.append(_Buffer(i, b.length, m))
            for buf in self.buffers:
                self.queue(buf.index)
            self._ioctl(VIDIOC_STREAMON, ctypes.c_int(V4L2_BUF_TYPE_VIDEO_CAPTURE))
        except BaseException:
            self._release()
            raise
        self.streaming = True

    def queue(self, index: int) -> None:
        b = v4l2_buffer(index=index, type=V4L2_BUF_TYPE_VIDEO_CAPTURE, memory=V4L2_MEMORY_MMAP)
        self._ioctl(VIDIOC_QBUF, b)

    def dequeue(self) -> v4l2_buffer | None:
        """VIDIOC_DQBUF on the non-blocking descriptor: a filled buffer, or None (EAGAIN)."""
        b = v4l2_buffer(type=V4L2_BUF_TYPE_VIDEO_CAPTURE, memory=V4L2_MEMORY_MMAP)
        try:
            self._ioctl(VIDIOC_DQBUF, b)
        except OSError as e:
            if e.errno == errno.EAGAIN:
                return None
            raise
        return b

    def data(self, b: v4l2_buffer) -> np.ndarray:
        """(bytesused,) uint8 copy of a dequeued buffer's data."""
        m = self.buffers[b.index].mapping
        n = min(int(b.bytesused) or self.sizeimage, self.buffers[b.index].length)
        view = np.frombuffer(m, dtype=np.uint8, count=n)
        out = view.copy()
        del view
        return out

    def stop(self) -> None:
        if self.streaming:
            self.streaming = False
            try:
                self._ioctl(VIDIOC_STREAMOFF, ctypes.c_int(V4L2_BUF_TYPE_VIDEO_CAPTURE))
            finally:
                self._release()

    def _release(self) -> None:
        for buf in self.buffers:
            try:
                buf.mapping.close()
            except (BufferError, OSError, AttributeError):
                pass
        had = bool(self.buffers)
        self.buffers = []
        if had and self.fd is not None:
            try:
                self._ioctl(VIDIOC_REQBUFS, v4l2_requestbuffers(count=0, type=V4L2_BUF_TYPE_VIDEO_CAPTURE,
                                                                memory=V4L2_MEMORY_MMAP))
            except OSError:
                pass


# ----------------------------------------------------------------------------- the source


@dataclass
class Controls:
    """Exposure, gain and white balance for every camera (see the module docstring)."""

    fixed: bool = True
    """Switch auto exposure / gain / white balance off and set equal values (False: leave the
    devices' automatic control alone)."""
    exposure: int | None = None
    """V4L2 ``EXPOSURE_ABSOLUTE`` [100 µs]; None: the first camera's current value."""
    gain: int | None = None
    """Device gain units; None: the first camera's current value."""
    white_balance: int | None = None
    """White-balance temperature [K]; None: the first camera's current value."""


def _decode(cam: CameraSpec, dev: V4L2Device, raw: np.ndarray) -> np.ndarray | None:
    """A dequeued buffer as the rig's image: (H, W) grey uint8/uint16 or (H, W, 3) RGB; None if corrupt."""
    import cv2

    H, W, bpl = dev.height, dev.width, dev.bytesperline
    fmt = cam.pixel_format
    if fmt == "MJPG":
        img = cv2.imdecode(raw, cv2.IMREAD_COLOR)
        if img is None or img.shape[:2] != (H, W):
            return None
        return cv2.cvtColor(img, cv2.COLOR_BGR2RGB)
    if raw.size < bpl * (H - 1) + W * {"GREY": 1, "Y16": 2, "YUYV": 2, "RGB": 3}[fmt]:
        return None
    if raw.size < bpl * H:
        raw = np.concatenate([raw, np.zeros(bpl * H - raw.size, np.uint8)])
    rows = raw[:bpl * H].reshape(H, bpl)
    if fmt == "GREY":
        return np.ascontiguousarray(rows[:, :W])
    if fmt == "Y16":
        return np.ascontiguousarray(rows[:, :2 * W]).view("<u2").astype(np.uint16)
    if fmt == "RGB":
        return np.ascontiguousarray(rows[:, :3 * W]).reshape(H, W, 3)
    yuyv = np.ascontiguousarray(rows[:, :2 * W]).reshape(H, W, 2)
    return cv2.cvtColor(yuyv, cv2.COLOR_YUV2RGB_YUYV)


class V4L2Source(FrameSource):
    """V4L2 cameras of a rig (see the module docstring).

    cams: the rig cameras with ``driver = "v4l2"``; each needs ``device``.
    buffers: mmap buffers per camera.
    sys: the kernel boundary (default the real one; tests pass :class:`capture.fake_v4l2.FakeV4L2`).
    realtime: False only over a simulated kernel whose clock runs as fast as it is read.
    """

    driver = "v4l2"

    def __init__(self, cams: list[CameraSpec], *, controls: Controls | None = None, buffers: int = 4,
                 sys: Syscalls | None = None, realtime: bool = True):
        missing = [c.id for c in cams if not c.device]
        if missing:
            raise CaptureError(f"camera {missing[0]}: driver v4l2 needs a device (e.g. /dev/video0)")
        self.cams = list(cams)
        self.cameras = tuple(c.id for c in cams)
        self.controls = controls or Controls()
        self.buffers = int(buffers)
        self.sys = sys if sys is not None else Syscalls()
        self.devices: dict[str, V4L2Device] = {}
        self.applied: dict[str, dict[str, Any]] = {}
        self._lost: list[Item] = []
        self._warned_clock: set[str] = set()
        self._noted_eof: set[str] = set()
        self.finished = False
        self.realtime = realtime  # False only over a simulated kernel (tests)

    # -- start

    def start(self) -> None:
        try:
            for cam in self.cams:
                dev = V4L2Device(cam.device, self.sys)
                dev.open()
                self.devices[cam.id] = dev
                self._configure(cam, dev)
            self._apply_controls()
            for cam in self.cams:
                self.devices[cam.id].start(self.buffers)
        except OSError as e:
            self.stop()
            raise CaptureError(f"v4l2: {e.strerror or e}") from None
        except BaseException:
            self.stop()
            raise
        log.info("v4l2: streaming %d cameras", len(self.cams))

    def _configure(self, cam: CameraSpec, dev: V4L2Device) -> None:
        where = f"{cam.id} ({cam.device})"
        cap = dev.querycap()
        if not cap["capture"] or not cap["streaming"]:
            raise CaptureError(f"{where}: not a streaming video-capture device ({cap['card']})")
        want = PIXEL_FORMAT_FOURCC[cam.pixel_format]
        have = [f for f, _ in dev.formats()]
        if fourcc_str(want) not in have:
            raise CaptureError(f"{where}: pixel format {cam.pixel_format} not offered "
                               f"(device has {', '.join(have) or 'none'})")
        got, w, h = dev.set_format(fourcc_str(want), cam.width, cam.height)
        if (got, w, h) != (fourcc_str(want), cam.width, cam.height):
            raise CaptureError(f"{where}: asked for {cam.width}x{cam.height} {cam.pixel_format}, the device "
                               f"gives {w}x{h} {got} (see `polycam devices` for its modes)")
        rate = dev.set_fps(cam.fps)
        if rate is not None and abs(rate - cam.fps) > 0.01 * cam.fps:
            raise CaptureError(f"{where}: asked for {cam.fps:g} fps, the device gives {rate:g} fps")
        self.applied[cam.id] = {"device": cam.device, "card": cap["card"], "bus_info": cap["bus_info"],
                                "fps": rate if rate is not None else cam.fps}

    def _apply_controls(self) -> None:
        ctl = self.controls
        if not ctl.fixed:
            return
        autos = [(V4L2_CID_EXPOSURE_AUTO, V4L2_EXPOSURE_MANUAL, "auto_exposure"),
                 (V4L2_CID_AUTOGAIN, 0, "auto_gain"), (V4L2_CID_AUTO_WHITE_BALANCE, 0, "auto_white_balance")]
        values = [(V4L2_CID_EXPOSURE_ABSOLUTE, ctl.exposure, "exposure"), (V4L2_CID_GAIN, ctl.gain, "gain"),
                  (V4L2_CID_WHITE_BALANCE_TEMPERATURE, ctl.white_balance, "white_balance")]
        for cam in self.cams:  # automatic control off first: manual values are inactive until then
            dev = self.devices[cam.id]
            for cid, value, name in autos:
                if dev.query_control(cid) is not None:
                    try:
                        self.applied[cam.id][name] = dev.set_control(cid, value)
                    except OSError as e:
                        log.warning("%s: cannot set %s (%s)", cam.id, name, e.strerror)
        for cid, value, name in values:
            target = value
            for cam in self.cams:
                dev = self.devices[cam.id]
                q = dev.query_control(cid)
                if q is None:
                    continue
                if target is None:
                    target = dev.get_control(cid)  # the first camera's current value, for all
                v = int(min(max(target, q["min"]), q["max"]))
                if q["step"] > 1:
                    v = q["min"] + (v - q["min"]) // q["step"] * q["step"]
                try:
                    self.applied[cam.id][name] = dev.set_control(cid, v)
                except OSError as e:
                    log.warning("%s: cannot set %s = %d (%s)", cam.id, name, v, e.strerror)
                if v != target:
                    log.warning("%s: %s %d clamped to %d (device range %d..%d step %d)", cam.id, name, target,
                                v, q["min"], q["max"], q["step"])
        vals = {n: {self.applied[c.id].get(n) for c in self.cams} for _, _, n in values}
        for n, vs in vals.items():
            if len(vs - {None}) > 1:
                log.warning("v4l2: %s differs between cameras: %s", n, sorted(vs - {None}))

    # -- frames

    def read(self, timeout: float) -> list[Item]:
        out: list[Item] = self._lost
        self._lost = []
        live = {dev.fd: cam for cam in self.cams if (dev := self.devices.get(cam.id)) is not None
                and dev.fd is not None and dev.streaming}
        if not live:
            if not out:
                self.finished = True
            return out
        ready = self.sys.select(sorted(live), 0.0 if out else timeout)
        for fd in ready:
            cam = live[fd]
            dev = self.devices[cam.id]
            while True:
                try:
                    b = dev.dequeue()
                except OSError as e:
                    out.append(self._lose(cam, e))
                    break
                if b is None:
                    break
                item = self._frame(cam, dev, b)
                try:
                    dev.queue(b.index)
                except OSError as e:
                    if item is not None:
                        out.append(item)
                    out.append(self._lose(cam, e))
                    break
                if item is not None:
                    out.append(item)
        out.sort(key=lambda it: it.timestamp_ns if isinstance(it, Frame) else -1)
        return out

    def _half_exposure_ns(self, cam: CameraSpec) -> int:
        """[ns] from the start of ``cam``'s exposure to its middle: half the manual exposure the controls
        set (``EXPOSURE_ABSOLUTE`` in 100 µs units, active once auto exposure is off); 0 when unknown."""
        applied = self.applied.get(cam.id, {})
        if applied.get("auto_exposure") != V4L2_EXPOSURE_MANUAL or applied.get("exposure") is None:
            return 0
        return int(applied["exposure"]) * 100_000 // 2

    def _frame(self, cam: CameraSpec, dev: V4L2Device, b: v4l2_buffer) -> Frame | None:
        if b.flags & V4L2_BUF_FLAG_ERROR:
            log.info("%s: buffer %d flagged as corrupt (sequence %d); discarded", cam.id, b.index, b.sequence)
            return None
        if b.flags & V4L2_BUF_FLAG_TIMESTAMP_MASK == V4L2_BUF_FLAG_TIMESTAMP_MONOTONIC:
            ts = int(b.timestamp.tv_sec) * 1_000_000_000 + int(b.timestamp.tv_usec) * 1000
            if b.flags & V4L2_BUF_FLAG_TSTAMP_SRC_MASK == V4L2_BUF_FLAG_TSTAMP_SRC_SOE:
                ts += self._half_exposure_ns(cam)
            elif cam.id not in self._noted_eof:
                self._noted_eof.add(cam.id)
                log.info("%s: the driver stamps the end of each frame, which lags the exposure by the readout "
                         "(not known): on a rig mixing it with start-of-exposure cameras their capture times "
                         "differ by that", cam.id)
        else:
            if cam.id not in self._warned_clock:
                self._warned_clock.add(cam.id)
                log.warning("%s: driver timestamps are not CLOCK_MONOTONIC; using the time of dequeue", cam.id)
            ts = self.sys.monotonic_ns()
        image = _decode(cam, dev, dev.data(b))
        if image is None:
            log.info("%s: undecodable frame (sequence %d); discarded", cam.id, b.sequence)
            return None
        return Frame(cam.id, ts, int(b.sequence), image)

    def _lose(self, cam: CameraSpec, e: OSError) -> CameraLost:
        dev = self.devices[cam.id]
        dev.streaming = False
        for buf in dev.buffers:  # a vanished device: unmap, no more ioctls
            try:
                buf.mapping.close()
            except (BufferError, OSError, AttributeError):
                pass
        dev.buffers = []
        try:
            dev.close()
        except OSError:
            pass
        return CameraLost(cam.id, e.strerror or str(e))

    def stop(self) -> None:
        for cam_id, dev in list(self.devices.items()):
            try:
                dev.close()
            except OSError as e:
                log.warning("%s: closing %s: %s", cam_id, dev.path, e.strerror)

    def info(self) -> dict[str, Any]:
        return {"v4l2": {c: dict(v) for c, v in self.applied.items()}}


# ----------------------------------------------------------------------------- listing


def list_v4l2_devices(paths: list[str] | None = None, sys: Syscalls | None = None) -> list[dict[str, Any]]:
    """Every V4L2 video-capture node with its formats, sizes and rates.

    paths: nodes to probe (default ``/dev/video*``). Nodes that are not capture
    devices (e.g. uvcvideo's metadata nodes) or cannot be opened are skipped.
    Each entry: path, driver, card, bus_info, formats = [{fourcc, description,
    modes = [{width, height, fps: [...]}]}].
    """
    import glob
    import re

    sys = sys if sys is not None else Syscalls()
    if paths is None:
        paths = sorted(glob.glob("/dev/video*"), key=lambda p: int(re.sub(r"\D", "", p) or 0))
    out = []
    for path in paths:
        dev = V4L2Device(path, sys)
        try:
            dev.open()
        except CaptureError as e:
            log.info("%s", e)
            continue
        try:
            cap = dev.querycap()
            if not cap["capture"]:
                continue
            fmts = []
            for code, desc in dev.formats():
                modes = [{"width": w, "height": h, "fps": dev.frame_rates(code, w, h)}
                         for w, h in dev.frame_sizes(code)]
                fmts.append({"fourcc": code, "description": desc, "modes": modes})
            out.append({"path": path, "driver": cap["driver"], "card": cap["card"],
                        "bus_info": cap["bus_info"], "formats": fmts})
        except OSError as e:
            log.info("%s: %s", path, e.strerror)
        finally:
            dev.close()
    return out
