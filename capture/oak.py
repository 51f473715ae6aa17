"""The DepthAI v3 driver: Luxonis OAK devices, several sensors per device, several devices.

Rig cameras with ``driver = "depthai"`` name a sensor by ``device``:
``"<device>/<socket>"``, where ``<device>`` is an OAK device id (MxId) or name
as :func:`depthai.Device.getAllAvailableDevices` lists them (``polycam
devices`` prints them) and ``<socket>`` a :class:`depthai.CameraBoardSocket`
name (``CAM_A``, ``CAM_B``, ...). A bare socket name means the only connected
device.

Per device: ``dai.Device(info)``, ``dai.Pipeline(device)``, one
``dai.node.Camera`` per sensor (``build(socket, sensorFps=fps)``), one output
per sensor (``requestOutput((w, h), type=GRAY8 | RGB888i, fps=fps)``) with a
non-blocking host queue (``createOutputQueue(maxSize, blocking=False)``: when
the host falls behind, the oldest frames are overwritten, which shows as a
gap in ``getSequenceNum()``), then ``pipeline.start()``.

Timestamps: ``ImgFrame.getTimestamp(CameraExposureOffset.MIDDLE)``, the middle of the
image's exposure (DepthAI stamps the end; the middle is the moment the image shows, so
sensors with different exposure times, each under its own auto exposure, are stamped when
they saw the scene even when one FSYNC pulse ends their exposures together), on the device
clock already mapped by DepthAI's time synchronisation onto the host's
``std::chrono::steady_clock``, which on Linux is ``CLOCK_MONOTONIC`` (the clock of the V4L2
and mock drivers).
Sequence numbers: ``getSequenceNum()``.

Synchronisation (``sync``): ``hardware`` ties the sensors of a device to one
FSYNC signal (first sensor ``FrameSyncMode.OUTPUT``, the others ``INPUT``) and,
with several devices, makes the first the external frame-sync master
(``setExternalFrameSyncRole(MASTER)``, the others ``SLAVE``); a device that
refuses is an error. ``software`` leaves the sensors free-running (the
synchroniser groups frames by timestamp). ``auto`` (default) tries hardware
sync and falls back to software, logging why. What was used per device goes
into the capture statistics.

Controls: with :class:`Controls` ``fixed`` (default) and an exposure given,
every sensor gets ``initialControl.setManualExposure(exposure_us, iso)``; a
white balance given sets ``setManualWhiteBalance(K)`` on colour sensors.

The SDK module is imported only in :meth:`DepthAISource.start` (or injected:
tests pass :mod:`capture.fake_depthai`).
"""

from __future__ import annotations

import datetime as _dt
import logging
import time
from dataclasses import dataclass
from typing import Any, Callable

import numpy as np

from polycam.rig import CameraSpec

from .source import CameraLost, CaptureError, Frame, FrameSource, Item

__all__ = ["DepthAISource", "DepthAIControls", "parse_device", "list_depthai_devices", "import_depthai"]

log = logging.getLogger(__name__)

SYNC_MODES = ("auto", "hardware", "software")


def import_depthai():
    """The real ``depthai`` module, or a :class:`CaptureError` saying how to get it."""
    try:
        import depthai
    except ImportError as e:
        raise CaptureError(f"the depthai driver needs the depthai package (pip install depthai): {e}") from None
    return depthai


@dataclass
class DepthAIControls:
    """Exposure and white balance for every OAK sensor (None: the sensor's automatic control)."""

    fixed: bool = True
    exposure_us: int | None = None
    """[µs] manual exposure time."""
    iso: int = 400
    """Sensitivity used with a manual exposure."""
    white_balance: int | None = None
    """[K] manual white-balance temperature (colour sensors)."""


def parse_device(device: str | None) -> tuple[str | None, str]:
    """``"<device>/<socket>"`` → (device id or name, socket name); a bare socket → (None, socket)."""
    if not device:
        raise CaptureError("driver depthai needs device = \"<device id>/<socket>\" (e.g. \"CAM_B\")")
    dev, _, sock = device.rpartition("/")
    return (dev or None), sock


def _ns(td: _dt.timedelta) -> int:
    """A timedelta as int64 nanoseconds (exact at its microsecond resolution)."""
    return (td.days * 86_400 + td.seconds) * 1_000_000_000 + td.microseconds * 1000


class _Device:
    """One OAK device with its pipeline and output queues."""

    def __init__(self, info, cams: list[CameraSpec]):
        self.info = info
        self.cams = cams
        self.device = None
        self.pipeline = None
        self.queues: dict[str, Any] = {}
        self.sync = "software"
        self.lost = False


class DepthAISource(FrameSource):
    """OAK sensors of a rig (see the module docstring).

    cams: rig cameras with ``driver = "depthai"``.
    sync: ``auto``, ``hardware`` or ``software``.
    queue_size: host queue length per sensor [frames].
    dai: the SDK module (default: import ``depthai``); clock/sleep for polling.
    """

    driver = "depthai"

    def __init__(self, cams: list[CameraSpec], *, controls: DepthAIControls | None = None, sync: str = "auto",
                 queue_size: int = 8, dai=None, sleep: Callable[[float], None] = time.sleep,
                 clock: Callable[[], float] = time.monotonic, realtime: bool = True):
        if sync not in SYNC_MODES:
            raise ValueError(f"sync must be one of {SYNC_MODES}")
        for c in cams:
            parse_device(c.device)
            if c.pixel_format not in ("GREY", "RGB", "YUYV", "MJPG"):
                raise CaptureError(f"camera {c.id}: the depthai driver delivers GREY or RGB images, "
                                   f"not {c.pixel_format}")
        self.cams = list(cams)
        self.cameras = tuple(c.id for c in cams)
        self.controls = controls or DepthAIControls()
        self.sync_mode = sync
        self.queue_size = int(queue_size)
        self._dai = dai
        self._sleep = sleep
        self._clock = clock
        self.realtime = realtime
        self.devices: list[_Device] = []
        self._pending: list[Item] = []
        self.finished = False

    # -- start

    def _resolve(self, dai) -> list[_Device]:
        infos = list(dai.Device.getAllAvailableDevices())
        if not infos:
            raise CaptureError("depthai: no OAK device found (check the USB cable and udev rules; "
                               "`polycam devices` lists what is connected)")
        by_key: dict[str, Any] = {}
        for info in infos:
            by_key[info.getDeviceId()] = info
            if info.name:
                by_key.setdefault(info.name, info)
        groups: dict[str, tuple[Any, list[CameraSpec]]] = {}
        for cam in self.cams:
            dev, _ = parse_device(cam.device)
            if dev is None:
                if len(infos) != 1:
                    ids = ", ".join(i.getDeviceId() for i in infos)
                    raise CaptureError(f"camera {cam.id}: device {cam.device!r} names no OAK device but "
                                       f"{len(infos)} are connected ({ids}); use \"<device id>/<socket>\"")
                info = infos[0]
            else:
                info = by_key.get(dev)
                if info is None:
                    raise CaptureError(f"camera {cam.id}: OAK device {dev!r} not found (connected: "
                                       f"{', '.join(i.getDeviceId() for i in infos)})")
            groups.setdefault(info.getDeviceId(), (info, []))[1].append(cam)
        return [_Device(info, cams) for info, cams in groups.values()]

    def start(self) -> None:
        dai = self._dai if self._dai is not None else import_depthai()
        self._dai = dai
        self.devices = self._resolve(dai)
        try:
            for k, d in enumerate(self.devices):
                self._open(dai, d, master=(k == 0))
            for d in self.devices:
                d.pipeline.start()
        except CaptureError:
            self.stop()
            raise
        except (RuntimeError, ValueError, TypeError) as e:
            self.stop()
            raise CaptureError(f"depthai: {e}") from None
        log.info("depthai: %d device(s), %d sensors; sync %s", len(self.devices), len(self.cams),
                 ", ".join(d.sync for d in self.devices))

    def _open(self, dai, d: _Device, master: bool) -> None:
        d.device = dai.Device(d.info)
        d.pipeline = dai.Pipeline(d.device)
        hw = self.sync_mode in ("auto", "hardware")
        if hw and len(self.devices) > 1:
            role = dai.ExternalFrameSyncRole.MASTER if master else dai.ExternalFrameSyncRole.SLAVE
            ok, msg = d.device.setExternalFrameSyncRole(role)
            if not ok:
                if self.sync_mode == "hardware":
                    raise CaptureError(f"depthai {d.info.getDeviceId()}: external frame sync refused ({msg})")
                log.warning("depthai %s: no external frame sync (%s); software sync", d.info.getDeviceId(), msg)
                hw = False
        ctl = self.controls
        for i, cam in enumerate(d.cams):
            _, sock_name = parse_device(cam.device)
            try:
                socket = getattr(dai.CameraBoardSocket, sock_name)
            except AttributeError:
                raise CaptureError(f"camera {cam.id}: unknown OAK socket {sock_name!r} (CAM_A, CAM_B, ...)") from None
            node = d.pipeline.create(dai.node.Camera).build(socket, sensorFps=float(cam.fps))
            kind = dai.ImgFrame.Type.GRAY8 if cam.pixel_format == "GREY" else dai.ImgFrame.Type.RGB888i
            out = node.requestOutput((cam.width, cam.height), type=kind, fps=float(cam.fps))
            init = node.initialControl
            if ctl.fixed and ctl.exposure_us is not None:
                init.setManualExposure(int(ctl.exposure_us), int(ctl.iso))
            if ctl.fixed and ctl.white_balance is not None and cam.pixel_format != "GREY":
                init.setManualWhiteBalance(int(ctl.white_balance))
            if hw and len(d.cams) > 1:
                mode = dai.CameraControl.FrameSyncMode.OUTPUT if i == 0 else dai.CameraControl.FrameSyncMode.INPUT
                init.setFrameSyncMode(mode)
            d.queues[cam.id] = out.createOutputQueue(maxSize=self.queue_size, blocking=False)
        d.sync = "hardware" if hw and (len(d.cams) > 1 or len(self.devices) > 1) else "software"

    # -- frames

    def read(self, timeout: float) -> list[Item]:
        deadline = self._clock() + max(timeout, 0.0)
        while True:
            out = self._pending
            self._pending = []
            for d in self.devices:
                if not d.lost:
                    out.extend(self._poll(d))
            if out:
                out.sort(key=lambda it: it.timestamp_ns if isinstance(it, Frame) else -1)
                return out
            if all(d.lost for d in self.devices):
                self.finished = True
                return out
            if self._clock() >= deadline:
                return out
            self._sleep(0.001)

    def _poll(self, d: _Device) -> list[Item]:
        dai = self._dai
        errors = (RuntimeError, dai.MessageQueue.QueueException)
        out: list[Item] = []
        try:
            for cam in d.cams:
                q = d.queues[cam.id]
                while (msg := q.tryGet()) is not None:
                    out.append(self._frame(cam, msg))
        except errors as e:
            d.lost = True
            reason = str(e).splitlines()[0] if str(e) else type(e).__name__
            log.warning("depthai %s: device lost (%s)", d.info.getDeviceId(), reason)
            out.extend(CameraLost(c.id, f"OAK device lost: {reason}") for c in d.cams)
        return out

    def _frame(self, cam: CameraSpec, msg) -> Frame:
        img = msg.getCvFrame()
        if img.ndim == 3:
            img = img[:, :, ::-1]  # OpenCV BGR → RGB
        img = np.ascontiguousarray(img)
        if img.shape[:2] != (cam.height, cam.width):
            raise CaptureError(f"camera {cam.id}: OAK delivered {img.shape[1]}x{img.shape[0]}, the rig "
                               f"asks for {cam.width}x{cam.height}")
        mid = msg.getTimestamp(self._dai.CameraExposureOffset.MIDDLE)
        return Frame(cam.id, _ns(mid), int(msg.getSequenceNum()), img)

    def stop(self) -> None:
        for d in self.devices:
            try:
                if d.pipeline is not None:
                    d.pipeline.stop()
            except Exception as e:  # noqa: BLE001 - a lost device may refuse; close anyway
                log.info("depthai: stopping pipeline: %s", e)
            try:
                if d.device is not None:
                    d.device.close()
            except Exception as e:  # noqa: BLE001
                log.info("depthai: closing device: %s", e)
            d.pipeline = d.device = None

    def info(self) -> dict[str, Any]:
        return {"depthai": {d.info.getDeviceId(): {"sync": d.sync, "sensors": [c.device for c in d.cams]}
                            for d in self.devices}}


def list_depthai_devices(dai=None) -> list[dict[str, str]]:
    """Connected OAK devices: id, name, state (no device is booted). [] without the SDK."""
    if dai is None:
        try:
            dai = import_depthai()
        except CaptureError as e:
            log.info("%s", e)
            return []
    out = []
    for info in dai.Device.getAllAvailableDevices():
        state = getattr(info.state, "name", str(info.state))
        out.append({"id": info.getDeviceId(), "name": info.name, "state": state})
    return out
