"""A faithful fake of the Linux V4L2 kernel interface, for testing without cameras.

:class:`FakeV4L2` implements :class:`capture.v4l2.Syscalls` (open, close,
ioctl, mmap, select, monotonic_ns) over simulated UVC-like devices
(:class:`FakeCamera`) on a simulated ``CLOCK_MONOTONIC``. It follows the
kernel's documented semantics (videobuf2 + uvcvideo) for what the driver uses:

- ``VIDIOC_QUERYCAP`` (capture + streaming, device caps), ``VIDIOC_ENUM_FMT`` /
  ``ENUM_FRAMESIZES`` / ``ENUM_FRAMEINTERVALS`` (discrete; ``EINVAL`` past the
  end or for an unknown format);
- ``VIDIOC_S_FMT`` adjusts to the nearest supported format and size rather
  than failing (``EBUSY`` once buffers are allocated), filling
  ``bytesperline`` (rows may be padded: ``stride_align``) and ``sizeimage``;
  ``VIDIOC_G/S_PARM`` pick the nearest supported frame interval;
- controls: ``QUERYCTRL`` / ``G_CTRL`` / ``S_CTRL`` with ``EINVAL`` for unknown
  ids, ``ERANGE`` out of range, and manual exposure / gain / white balance
  *inactive* (``S_CTRL`` → ``EACCES``, as uvcvideo does) while their automatic
  control is on;
- buffers: ``REQBUFS`` (MMAP only; count 0 frees; ``EBUSY`` while mapped and
  streaming), ``QUERYBUF`` (offsets), ``mmap`` of exactly those offsets,
  ``QBUF`` (``EINVAL`` for a bad index or a buffer already queued),
  ``STREAMON`` / ``STREAMOFF`` (which returns every buffer to the application),
  non-blocking ``DQBUF`` (``EAGAIN`` when no buffer is done) with
  ``bytesused``, ``sequence``, ``V4L2_BUF_FLAG_TIMESTAMP_MONOTONIC`` timestamps
  (timeval, microseconds) and ``V4L2_BUF_FLAG_ERROR`` for corrupt frames;
- the sensor runs at the set frame rate whatever the application does: a
  frame that finds no queued buffer is lost, but its sequence number is used
  up (a gap, as uvcvideo reports);
- unplugging: every later ioctl fails with ``ENODEV`` and ``select`` reports
  the descriptor ready (``POLLERR``), so ``DQBUF`` sees ``ENODEV``.

Time only moves in :meth:`FakeV4L2.select` (up to the next frame, within the
timeout) and :meth:`FakeV4L2.advance` (an application busy elsewhere), so
tests are deterministic and never sleep.

Frame content: ``GREY`` frames are the :mod:`capture.mock` pattern with the
sequence number in row 0 (see :func:`capture.mock.pattern_sequence`); other
formats carry the same grey image (``Y16`` x 257, ``YUYV`` with neutral chroma,
``MJPG`` JPEG-encoded, ``RGB3`` grey in three channels).
"""

from __future__ import annotations

import ctypes
import errno
from dataclasses import dataclass, field

import numpy as np

from . import v4l2 as V

__all__ = ["FakeCamera", "FakeV4L2", "default_controls"]

_PAGE = 4096


def default_controls() -> dict[int, dict[str, int]]:
    """A typical UVC webcam's controls: id → min, max, step, default, value, type."""
    I, B, M = V.V4L2_CTRL_TYPE_INTEGER, V.V4L2_CTRL_TYPE_BOOLEAN, V.V4L2_CTRL_TYPE_MENU
    return {
        V.V4L2_CID_EXPOSURE_AUTO: dict(min=0, max=3, step=1, default=3, value=3, type=M),
        V.V4L2_CID_EXPOSURE_ABSOLUTE: dict(min=3, max=2047, step=1, default=250, value=250, type=I),
        V.V4L2_CID_AUTOGAIN: dict(min=0, max=1, step=1, default=1, value=1, type=B),
        V.V4L2_CID_GAIN: dict(min=0, max=255, step=1, default=32, value=32, type=I),
        V.V4L2_CID_AUTO_WHITE_BALANCE: dict(min=0, max=1, step=1, default=1, value=1, type=B),
        V.V4L2_CID_WHITE_BALANCE_TEMPERATURE: dict(min=2800, max=6500, step=10, default=4600, value=4600,
                                                   type=I),
    }


_AUTO_OF = {V.V4L2_CID_EXPOSURE_ABSOLUTE: (V.V4L2_CID_EXPOSURE_AUTO, lambda v: v != V.V4L2_EXPOSURE_MANUAL),
            V.V4L2_CID_GAIN: (V.V4L2_CID_AUTOGAIN, bool),
            V.V4L2_CID_WHITE_BALANCE_TEMPERATURE: (V.V4L2_CID_AUTO_WHITE_BALANCE, bool)}


@dataclass
class FakeCamera:
    """One simulated video node and what can go wrong with it."""

    path: str = "/dev/video0"
    card: str = "Fake UVC Camera"
    driver: str = "uvcvideo"
    bus_info: str = "usb-0000:00:14.0-1"
    modes: dict[str, dict[tuple[int, int], list[float]]] = field(default_factory=lambda: {
        "GREY": {(640, 480): [30.0, 15.0], (320, 240): [60.0, 30.0]},
        "YUYV": {(640, 480): [30.0], (320, 240): [30.0]},
        "MJPG": {(640, 480): [30.0], (320, 240): [30.0]}})
    """fourcc → (width, height) → frame rates [Hz], in the device's order."""
    controls: dict[int, dict[str, int]] = field(default_factory=default_controls)
    stride_align: int = 1
    """Rows are padded to a multiple of this many bytes (``bytesperline``)."""
    max_buffers: int = 32
    monotonic: bool = True
    """Timestamps flagged CLOCK_MONOTONIC (else TIMESTAMP_UNKNOWN)."""
    tstamp_src: str = "SOE"
    """``SOE``: timestamps flagged taken at the start of the exposure (as uvcvideo's); ``EOF``: at the end
    of the frame (``V4L2_BUF_FLAG_TSTAMP_SRC_EOF``, 0)."""
    phase_ns: int = 0
    """[ns] offset of this sensor's frame clock after STREAMON."""
    lose: set[int] = field(default_factory=set)
    """Sequence numbers the hardware loses (no buffer filled; the number is used up)."""
    corrupt: set[int] = field(default_factory=set)
    """Sequence numbers delivered with V4L2_BUF_FLAG_ERROR."""
    unplug_after: int | None = None
    """Unplug after this many frames were produced."""
    seed: int = 0

    # state (kernel side)
    unplugged: bool = False
    fmt: tuple[str, int, int] = ("", 0, 0)
    fps: float = 0.0
    streaming: bool = False
    buffers: list[dict] = field(default_factory=list)
    incoming: list[int] = field(default_factory=list)
    done: list[int] = field(default_factory=list)
    sequence: int = 0
    next_frame_ns: int = 0
    produced: int = 0
    open_fds: int = 0


class _Mapping(bytearray):
    """What mmap returns: the buffer's memory (closing it only marks it unmapped)."""

    closed = False

    def close(self) -> None:
        self.closed = True


class FakeV4L2(V.Syscalls):
    """Fake kernel over :class:`FakeCamera` s (see the module docstring)."""

    def __init__(self, cameras: list[FakeCamera], start_ns: int = 1_000_000_000_000):
        super().__init__()
        self.cameras = {c.path: c for c in cameras}
        self.now_ns = int(start_ns)
        self._fds: dict[int, FakeCamera] = {}
        self._next_fd = 100
        self.calls: list[tuple[str, int]] = []
        """(ioctl name, fd) of every ioctl, in order (tests check the driver's sequence)."""
        self._names = {getattr(V, n): n for n in dir(V) if n.startswith("VIDIOC_")}
        self._mappings: dict[tuple[str, int], _Mapping] = {}

    # -- files

    def open(self, path: str) -> int:
        cam = self.cameras.get(path)
        if cam is None or cam.unplugged:
            raise OSError(errno.ENOENT, "No such file or directory", path)
        fd = self._next_fd
        self._next_fd += 1
        self._fds[fd] = cam
        cam.open_fds += 1
        if not cam.fmt[0]:
            code = next(iter(cam.modes))
            cam.fmt = (code, *next(iter(cam.modes[code])))
            cam.fps = cam.modes[code][cam.fmt[1:]][0]
        return fd

    def close(self, fd: int) -> None:
        cam = self._cam(fd)
        del self._fds[fd]
        cam.open_fds -= 1
        if cam.open_fds == 0:  # last close frees the queue, as the kernel does
            cam.streaming = False
            cam.buffers, cam.incoming, cam.done = [], [], []

    def _cam(self, fd: int) -> FakeCamera:
        try:
            return self._fds[fd]
        except KeyError:
            raise OSError(errno.EBADF, "Bad file descriptor") from None

    def monotonic_ns(self) -> int:
        return self.now_ns

    # -- geometry of the current format

    def _layout(self, cam: FakeCamera) -> tuple[int, int]:
        code, w, h = cam.fmt
        bpp = {"GREY": 1, "Y16": 2, "YUYV": 2, "RGB3": 3, "MJPG": 1}[code]
        bpl = -(-w * bpp // cam.stride_align) * cam.stride_align
        size = bpl * h if code != "MJPG" else w * h * 2
        return (bpl if code != "MJPG" else 0), size

    # -- ioctl

    def ioctl(self, fd: int, request: int, arg) -> None:
        cam = self._cam(fd)
        name = self._names.get(request, hex(request))
        self.calls.append((name, fd))
        if cam.unplugged:
            raise OSError(errno.ENODEV, "No such device")
        handler = getattr(self, "_" + name.lower(), None)
        if handler is None:
            raise OSError(errno.ENOTTY, "Inappropriate ioctl for device")
        expected = {"VIDIOC_STREAMON": ctypes.c_int, "VIDIOC_STREAMOFF": ctypes.c_int}
        if ctypes.sizeof(arg) != (request >> 16) & 0x3FFF and name not in expected:
            raise OSError(errno.ENOTTY, "argument size does not match the ioctl")
        handler(cam, arg)

    def _vidioc_querycap(self, cam, c) -> None:
        ctypes.memset(ctypes.addressof(c), 0, ctypes.sizeof(c))
        c.driver[:len(cam.driver)] = cam.driver.encode()
        c.card[:len(cam.card)] = cam.card.encode()
        c.bus_info[:len(cam.bus_info)] = cam.bus_info.encode()
        c.version = (6 << 16) | (8 << 8)
        c.device_caps = V.V4L2_CAP_VIDEO_CAPTURE | V.V4L2_CAP_STREAMING
        c.capabilities = c.device_caps | V.V4L2_CAP_DEVICE_CAPS | V.V4L2_CAP_META_CAPTURE

    def _vidioc_enum_fmt(self, cam, d) -> None:
        codes = list(cam.modes)
        if d.type != V.V4L2_BUF_TYPE_VIDEO_CAPTURE or d.index >= len(codes):
            raise OSError(errno.EINVAL, "Invalid argument")
        code = codes[d.index]
        d.pixelformat = V.fourcc(code)
        desc = {"GREY": "8-bit Greyscale", "YUYV": "YUYV 4:2:2", "MJPG": "Motion-JPEG"}.get(code, code).encode()
        d.description[:len(desc)] = desc
        d.flags = 1 if code == "MJPG" else 0  # V4L2_FMT_FLAG_COMPRESSED

    def _vidioc_enum_framesizes(self, cam, s) -> None:
        code = V.fourcc_str(s.pixel_format)
        sizes = list(cam.modes.get(code, {}))
        if not sizes or s.index >= len(sizes):
            raise OSError(errno.EINVAL, "Invalid argument")
        s.type = V.V4L2_FRMSIZE_TYPE_DISCRETE
        s.discrete.width, s.discrete.height = sizes[s.index]

    def _vidioc_enum_frameintervals(self, cam, f) -> None:
        rates = cam.modes.get(V.fourcc_str(f.pixel_format), {}).get((f.width, f.height))
        if not rates or f.index >= len(rates):
            raise OSError(errno.EINVAL, "Invalid argument")
        f.type = V.V4L2_FRMIVAL_TYPE_DISCRETE
        f.discrete.numerator, f.discrete.denominator = 1000, int(round(rates[f.index] * 1000))

    def _fill_fmt(self, cam, f) -> None:
        code, w, h = cam.fmt
        bpl, size = self._layout(cam)
        p = f.fmt.pix
        p.width, p.height, p.pixelformat, p.field = w, h, V.fourcc(code), V.V4L2_FIELD_NONE
        p.bytesperline, p.sizeimage = bpl, size

    def _vidioc_g_fmt(self, cam, f) -> None:
        if f.type != V.V4L2_BUF_TYPE_VIDEO_CAPTURE:
            raise OSError(errno.EINVAL, "Invalid argument")
        self._fill_fmt(cam, f)

    def _vidioc_s_fmt(self, cam, f) -> None:
        if f.type != V.V4L2_BUF_TYPE_VIDEO_CAPTURE:
            raise OSError(errno.EINVAL, "Invalid argument")
        if cam.buffers:
            raise OSError(errno.EBUSY, "Device or resource busy")
        code = V.fourcc_str(f.fmt.pix.pixelformat)
        if code not in cam.modes:
            code = next(iter(cam.modes))
        w, h = f.fmt.pix.width, f.fmt.pix.height
        size = min(cam.modes[code], key=lambda s: (abs(s[0] - w) + abs(s[1] - h), -s[0]))
        cam.fmt = (code, *size)
        rates = cam.modes[code][size]
        if cam.fps not in rates:
            cam.fps = rates[0]
        self._fill_fmt(cam, f)

    def _vidioc_g_parm(self, cam, p) -> None:
        if p.type != V.V4L2_BUF_TYPE_VIDEO_CAPTURE:
            raise OSError(errno.EINVAL, "Invalid argument")
        ctypes.memset(ctypes.addressof(p.parm), 0, ctypes.sizeof(p.parm))
        p.parm.capture.capability = V.V4L2_CAP_TIMEPERFRAME
        p.parm.capture.timeperframe.numerator = 1000
        p.parm.capture.timeperframe.denominator = int(round(cam.fps * 1000))
        p.parm.capture.readbuffers = 0

    def _vidioc_s_parm(self, cam, p) -> None:
        if p.type != V.V4L2_BUF_TYPE_VIDEO_CAPTURE:
            raise OSError(errno.EINVAL, "Invalid argument")
        t = p.parm.capture.timeperframe
        want = t.denominator / t.numerator if t.numerator else 0.0
        rates = cam.modes[cam.fmt[0]][cam.fmt[1:]]
        cam.fps = min(rates, key=lambda r: abs(r - want))
        self._vidioc_g_parm(cam, p)

    def _control(self, cam, cid):
        c = cam.controls.get(cid)
        if c is None:
            raise OSError(errno.EINVAL, "Invalid argument")
        return c

    def _inactive(self, cam, cid) -> bool:
        if cid not in _AUTO_OF:
            return False
        auto_id, is_auto = _AUTO_OF[cid]
        a = cam.controls.get(auto_id)
        return a is not None and is_auto(a["value"])

    def _vidioc_queryctrl(self, cam, q) -> None:
        c = self._control(cam, q.id)
        q.type, q.minimum, q.maximum, q.step, q.default_value = c["type"], c["min"], c["max"], c["step"], \
            c["default"]
        q.flags = V.V4L2_CTRL_FLAG_INACTIVE if self._inactive(cam, q.id) else 0

    def _vidioc_g_ctrl(self, cam, c) -> None:
        c.value = self._control(cam, c.id)["value"]

    def _vidioc_s_ctrl(self, cam, c) -> None:
        ctl = self._control(cam, c.id)
        if not ctl["min"] <= c.value <= ctl["max"]:
            raise OSError(errno.ERANGE, "Numerical result out of range")
        if self._inactive(cam, c.id):
            raise OSError(errno.EACCES, "Permission denied")
        if c.id == V.V4L2_CID_EXPOSURE_AUTO and c.value not in (V.V4L2_EXPOSURE_MANUAL, 3):
            raise OSError(errno.EINVAL, "Invalid argument")  # UVC: manual or aperture priority only
        ctl["value"] = ctl["min"] + (c.value - ctl["min"]) // max(ctl["step"], 1) * max(ctl["step"], 1)

    def _vidioc_reqbufs(self, cam, r) -> None:
        if r.type != V.V4L2_BUF_TYPE_VIDEO_CAPTURE or r.memory != V.V4L2_MEMORY_MMAP:
            raise OSError(errno.EINVAL, "Invalid argument")
        if cam.streaming:
            raise OSError(errno.EBUSY, "Device or resource busy")
        if any(not self._mappings[(cam.path, b["index"])].closed for b in cam.buffers
               if (cam.path, b["index"]) in self._mappings):
            raise OSError(errno.EBUSY, "Device or resource busy")  # buffers still mapped
        cam.buffers, cam.incoming, cam.done = [], [], []
        r.capabilities = 1  # V4L2_BUF_CAP_SUPPORTS_MMAP
        if r.count == 0:
            return
        n = max(2, min(int(r.count), cam.max_buffers))
        _, size = self._layout(cam)
        length = -(-size // _PAGE) * _PAGE
        for i in range(n):
            cam.buffers.append({"index": i, "length": length, "offset": i * length, "bytesused": 0,
                                "sequence": 0, "ts": 0, "flags": 0, "mapped": False})
            self._mappings.pop((cam.path, i), None)
        r.count = n

    def _fill_buf(self, cam, b, buf) -> None:
        b.index, b.length, b.m.offset = buf["index"], buf["length"], buf["offset"]
        b.memory, b.field = V.V4L2_MEMORY_MMAP, V.V4L2_FIELD_NONE
        flags = buf["flags"]
        if buf["mapped"]:
            flags |= V.V4L2_BUF_FLAG_MAPPED
        if buf["index"] in cam.incoming:
            flags |= V.V4L2_BUF_FLAG_QUEUED
        flags |= V.V4L2_BUF_FLAG_TIMESTAMP_MONOTONIC if cam.monotonic else V.V4L2_BUF_FLAG_TIMESTAMP_UNKNOWN
        if cam.tstamp_src == "SOE":
            flags |= V.V4L2_BUF_FLAG_TSTAMP_SRC_SOE
        b.flags = flags
        b.bytesused, b.sequence = buf["bytesused"], buf["sequence"]
        b.timestamp.tv_sec, b.timestamp.tv_usec = divmod(buf["ts"] // 1000, 1_000_000)

    def _buffer(self, cam, b) -> dict:
        if b.type != V.V4L2_BUF_TYPE_VIDEO_CAPTURE or b.memory != V.V4L2_MEMORY_MMAP or \
                b.index >= len(cam.buffers):
            raise OSError(errno.EINVAL, "Invalid argument")
        return cam.buffers[b.index]

    def _vidioc_querybuf(self, cam, b) -> None:
        self._fill_buf(cam, b, self._buffer(cam, b))

    def _vidioc_qbuf(self, cam, b) -> None:
        buf = self._buffer(cam, b)
        if buf["index"] in cam.incoming or buf["index"] in cam.done:
            raise OSError(errno.EINVAL, "Invalid argument")
        buf["flags"] = 0
        cam.incoming.append(buf["index"])
        self._fill_buf(cam, b, buf)

    def _vidioc_dqbuf(self, cam, b) -> None:
        if b.type != V.V4L2_BUF_TYPE_VIDEO_CAPTURE or b.memory != V.V4L2_MEMORY_MMAP:
            raise OSError(errno.EINVAL, "Invalid argument")
        if not cam.streaming:
            raise OSError(errno.EINVAL, "Invalid argument")
        if not cam.done:
            raise OSError(errno.EAGAIN, "Resource temporarily unavailable")
        buf = cam.buffers[cam.done.pop(0)]
        self._fill_buf(cam, b, buf)
        b.flags |= V.V4L2_BUF_FLAG_DONE

    def _vidioc_streamon(self, cam, t) -> None:
        if t.value != V.V4L2_BUF_TYPE_VIDEO_CAPTURE or not cam.buffers:
            raise OSError(errno.EINVAL, "Invalid argument")
        if cam.streaming:
            return
        cam.streaming = True
        cam.sequence = 0
        cam.next_frame_ns = self.now_ns + int(round(1e9 / cam.fps)) + cam.phase_ns

    def _vidioc_streamoff(self, cam, t) -> None:
        if t.value != V.V4L2_BUF_TYPE_VIDEO_CAPTURE:
            raise OSError(errno.EINVAL, "Invalid argument")
        cam.streaming = False
        cam.incoming, cam.done = [], []

    # -- memory

    def mmap(self, fd: int, length: int, offset: int):
        cam = self._cam(fd)
        if cam.unplugged:
            raise OSError(errno.ENODEV, "No such device")
        for buf in cam.buffers:
            if buf["offset"] == offset and length <= buf["length"]:
                m = _Mapping(buf["length"])
                self._mappings[(cam.path, buf["index"])] = m
                buf["mapped"] = True
                return m
        raise OSError(errno.EINVAL, "Invalid argument")

    # -- time and frames

    def _image(self, cam: FakeCamera, seq: int) -> bytes:
        from .mock import PatternRenderer

        code, w, h = cam.fmt
        if not hasattr(cam, "_pattern") or cam._pattern[0] != (w, h):
            from polycam.rig import CameraSpec

            spec = CameraSpec(id="fake", driver="v4l2", device=cam.path, width=w, height=h, fps=cam.fps,
                              pixel_format="GREY", position=np.zeros(3), rotation=np.zeros(3))
            cam._pattern = ((w, h), PatternRenderer([spec], cam.seed, 0.0))
        grey = cam._pattern[1].image(0, seq / cam.fps, seq)
        bpl, size = self._layout(cam)
        if code == "MJPG":
            import cv2

            ok, data = cv2.imencode(".jpg", grey, [cv2.IMWRITE_JPEG_QUALITY, 95])
            return data.tobytes()
        if code == "GREY":
            px = grey
        elif code == "Y16":
            px = (grey.astype("<u2") * 257).view(np.uint8).reshape(h, 2 * w)
        elif code == "YUYV":
            px = np.stack([grey, np.full_like(grey, 128)], axis=2).reshape(h, 2 * w)
        else:  # RGB3
            px = np.repeat(grey[:, :, None], 3, axis=2).reshape(h, 3 * w)
        rows = np.zeros((h, bpl), np.uint8)
        rows[:, :px.shape[1]] = px
        return rows.tobytes()

    def _produce(self, cam: FakeCamera) -> None:
        """The sensor finishes a frame at cam.next_frame_ns."""
        seq = cam.sequence
        cam.sequence += 1
        t = cam.next_frame_ns
        cam.next_frame_ns += int(round(1e9 / cam.fps))
        cam.produced += 1
        if cam.unplug_after is not None and cam.produced > cam.unplug_after:
            cam.unplugged = True
            return
        if seq in cam.lose or not cam.incoming:
            return  # no buffer (or lost on the bus): the frame is gone, its number used up
        buf = cam.buffers[cam.incoming.pop(0)]
        data = self._image(cam, seq)
        m = self._mappings.get((cam.path, buf["index"]))
        if m is not None and not m.closed:
            m[:len(data)] = data
        buf["bytesused"] = len(data)
        buf["sequence"] = seq
        buf["ts"] = t
        buf["flags"] = V.V4L2_BUF_FLAG_ERROR if seq in cam.corrupt else 0
        cam.done.append(buf["index"])

    def advance(self, seconds: float) -> None:
        """Let simulated time pass (the application is busy): frames are produced meanwhile."""
        self._run_until(self.now_ns + int(round(seconds * 1e9)))

    def _run_until(self, t_ns: int) -> None:
        while True:
            live = [c for c in self.cameras.values() if c.streaming and not c.unplugged]
            due = [c for c in live if c.next_frame_ns <= t_ns]
            if not due:
                break
            c = min(due, key=lambda c: c.next_frame_ns)
            self.now_ns = max(self.now_ns, c.next_frame_ns)
            self._produce(c)
        self.now_ns = max(self.now_ns, t_ns)

    def select(self, fds: list[int], timeout: float) -> list[int]:
        def ready() -> list[int]:
            return [fd for fd in fds if (c := self._fds.get(fd)) is not None and (c.done or c.unplugged)]

        r = ready()
        if r:
            return r
        deadline = self.now_ns + int(round(max(timeout, 0.0) * 1e9))
        while True:
            nxt = [c.next_frame_ns for fd in fds if (c := self._fds.get(fd)) is not None and c.streaming
                   and not c.unplugged]
            if not nxt or min(nxt) > deadline:
                self.now_ns = max(self.now_ns, deadline)
                return []
            self._run_until(min(nxt))
            r = ready()
            if r:
                return r
