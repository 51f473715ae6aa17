"""A fake of the DepthAI v3 SDK surface the OAK driver uses, for tests without devices.

:func:`make_fake_depthai` returns an object used in place of the ``depthai``
module (:class:`capture.oak.DepthAISource` ``dai=``). It has the same names,
call signatures and behaviours as depthai 3.x for that surface
(tests/test_capture_oak.py checks every name against the installed SDK):

- ``Device.getAllAvailableDevices()`` → ``DeviceInfo`` (``getDeviceId()``,
  ``name``, ``state``); ``Device(info)``; ``setExternalFrameSyncRole(role)`` →
  ``(ok, message)`` (refused by devices without an FSYNC connector);
  ``close()``.
- ``Pipeline(device)``; ``create(node.Camera)``; ``Camera.build(boardSocket,
  sensorResolution=None, sensorFps=None)``; ``requestOutput(size, type=None,
  resizeMode=..., fps=None)``; ``initialControl`` (``setManualExposure``,
  ``setManualWhiteBalance``, ``setFrameSyncMode``); ``Output.createOutputQueue(
  maxSize=16, blocking=False)``; ``start()`` / ``stop()`` / ``isRunning()``.
- ``MessageQueue.tryGet()`` (None when empty; a non-blocking queue keeps the
  newest ``maxSize`` frames, the older ones are lost with their sequence
  numbers), ``get()``; ``MessageQueue.QueueException`` when the device is gone.
- ``ImgFrame``: ``getCvFrame()`` (grey, or BGR for colour types),
  ``getTimestamp()`` (host-synchronised ``timedelta`` of the end of the exposure) and
  ``getTimestamp(CameraExposureOffset)`` (``START`` / ``MIDDLE`` / ``END``: the end minus the
  exposure, half of it in whole microseconds, or nothing), ``getExposureTime()``,
  ``getTimestampDevice()``, ``getSequenceNum()``, ``getWidth()``,
  ``getHeight()``, ``getType()``. A sensor's exposure is its ``setManualExposure`` time, else
  its device's ``auto_exposure_us``.

Time is simulated: ``fake.sleep(s)`` advances it and ``fake.clock()`` reads it
(pass both to the driver). Sensors of one device are exposed together when
frame sync is configured (one ``OUTPUT``, the others ``INPUT``); otherwise
each free-runs with its own seeded phase. Devices share one phase only when
external frame sync was accepted. Images are the :mod:`capture.mock` pattern
with the sequence number in row 0.
"""

from __future__ import annotations

import datetime as _dt
import enum
from collections import deque
from dataclasses import dataclass, field
from types import SimpleNamespace

import numpy as np

__all__ = ["FakeOak", "make_fake_depthai"]


@dataclass
class FakeOak:
    """One simulated OAK device."""

    device_id: str = "18443010D1E4A71200"
    name: str = "1.1"
    sockets: tuple[str, ...] = ("CAM_A", "CAM_B", "CAM_C")
    colour_sockets: tuple[str, ...] = ("CAM_A",)
    fsync: bool = True
    """Has an FSYNC connector (accepts an external frame-sync role)."""
    disconnect_after: int | None = None
    """The device vanishes after this many frames on any of its sensors."""
    boot_offset_ns: int = 5_000_000_000
    """[ns] device clock = host clock − this."""
    auto_exposure_us: dict[str, int] = field(default_factory=dict)
    """Sensor socket name → [µs] exposure its auto exposure settles on (default 10000: the same for
    every sensor); a frame's timestamp is the end of its exposure, as with a real FSYNC'd OAK."""
    seed: int = 0


class _QueueException(Exception):
    """depthai.MessageQueue.QueueException."""


def make_fake_depthai(oaks: list[FakeOak], start_s: float = 1000.0):
    """A fake ``depthai`` module over the given devices (see the module docstring)."""

    class ImgType(enum.Enum):
        GRAY8 = 0
        RGB888i = 1
        BGR888i = 2
        NV12 = 3
        RAW16 = 4

    class CameraBoardSocket(enum.IntEnum):
        AUTO = -1
        CAM_A = 0
        CAM_B = 1
        CAM_C = 2
        CAM_D = 3
        CAM_E = 4
        CAM_F = 5
        CAM_G = 6
        CAM_H = 7

    class FrameSyncMode(enum.Enum):
        AUTO = 0
        OFF = 1
        OUTPUT = 2
        INPUT = 3

    class CameraExposureOffset(enum.Enum):
        START = 0
        MIDDLE = 1
        END = 2

    class ExternalFrameSyncRole(enum.Enum):
        AUTO_DETECT = -1
        MASTER = 0
        SLAVE = 1

    class XLinkDeviceState(enum.Enum):
        X_LINK_ANY_STATE = 0
        X_LINK_BOOTED = 1
        X_LINK_UNBOOTED = 2

    state = SimpleNamespace(now_ns=int(round(start_s * 1e9)), opened=[], events=[])

    def clock() -> float:
        return state.now_ns / 1e9

    def sleep(seconds: float) -> None:
        state.now_ns += max(int(round(seconds * 1e9)), 1)

    class DeviceInfo:
        def __init__(self, oak: FakeOak | str | None = None):
            if isinstance(oak, str):
                oak = next((o for o in oaks if oak in (o.device_id, o.name)), FakeOak(device_id=oak))
            self._oak = oak
            self.name = oak.name if oak else ""
            self.deviceId = oak.device_id if oak else ""
            self.state = XLinkDeviceState.X_LINK_UNBOOTED

        def getDeviceId(self) -> str:
            return self.deviceId

    class CameraControl:
        def __init__(self):
            self.exposure = None
            self.white_balance = None
            self.frame_sync = FrameSyncMode.AUTO

        def setManualExposure(self, exposureTimeUs: int, sensitivityIso: int):
            self.exposure = (int(exposureTimeUs), int(sensitivityIso))
            return self

        def setManualWhiteBalance(self, colorTemperatureK: int):
            self.white_balance = int(colorTemperatureK)
            return self

        def setFrameSyncMode(self, mode):
            self.frame_sync = mode
            return self

    CameraControl.FrameSyncMode = FrameSyncMode

    class ImgFrame:

        def __init__(self, img: np.ndarray, kind, ts_ns: int, dev_ns: int, seq: int, exposure_us: int):
            self._img, self._type, self._ts, self._dev, self._seq = img, kind, ts_ns, dev_ns, seq
            self._exposure_us = int(exposure_us)

        def getCvFrame(self) -> np.ndarray:
            return self._img.copy()

        def getFrame(self) -> np.ndarray:
            return self._img.copy()

        def getTimestamp(self, offset=None) -> _dt.timedelta:
            end = _dt.timedelta(microseconds=self._ts // 1000)
            if offset is None or offset == CameraExposureOffset.END:
                return end
            if offset == CameraExposureOffset.MIDDLE:
                return end - _dt.timedelta(microseconds=self._exposure_us // 2)
            if offset == CameraExposureOffset.START:
                return end - _dt.timedelta(microseconds=self._exposure_us)
            raise TypeError(f"getTimestamp(): incompatible offset {offset!r}")

        def getExposureTime(self) -> _dt.timedelta:
            return _dt.timedelta(microseconds=self._exposure_us)

        def getTimestampDevice(self) -> _dt.timedelta:
            return _dt.timedelta(microseconds=self._dev // 1000)

        def getSequenceNum(self) -> int:
            return self._seq

        def getWidth(self) -> int:
            return self._img.shape[1]

        def getHeight(self) -> int:
            return self._img.shape[0]

        def getType(self):
            return self._type

    ImgFrame.Type = ImgType

    class MessageQueue:

        def __init__(self, output, maxSize: int, blocking: bool):
            self._out = output
            self._max = int(maxSize)
            self._blocking = blocking
            self._q: deque = deque()
            self._next = 0     # next frame index to produce
            self.closed = False

        def _fill(self) -> None:
            cam = self._out.camera
            dev = cam.pipeline.device
            if not cam.pipeline.running:
                return
            while True:
                t = cam.frame_time(self._next)
                if t > state.now_ns:
                    break
                if dev.oak.disconnect_after is not None and self._next >= dev.oak.disconnect_after:
                    dev.gone = True
                    break
                self._q.append(self._next)
                self._next += 1
                while len(self._q) > self._max:  # non-blocking: the oldest is overwritten
                    self._q.popleft()

        def tryGet(self):
            dev = self._out.camera.pipeline.device
            if dev.gone or dev.closed:
                raise _QueueException("Communication exception - possible device error/misconfiguration. "
                                      "Original message 'Couldn't read data from stream' (X_LINK_ERROR)")
            self._fill()
            if dev.gone:
                raise _QueueException("Communication exception - possible device error/misconfiguration. "
                                      "Original message 'Couldn't read data from stream' (X_LINK_ERROR)")
            if not self._q:
                return None
            return self._out.make(self._q.popleft())

        def get(self):
            while True:
                m = self.tryGet()
                if m is not None:
                    return m
                sleep(0.001)

        def getMaxSize(self) -> int:
            return self._max

        def isClosed(self) -> bool:
            return self.closed

    MessageQueue.QueueException = _QueueException

    class Output:
        def __init__(self, camera, size, kind, fps):
            self.camera, self.size, self.type, self.fps = camera, tuple(size), kind, fps
            self.queue = None

        def createOutputQueue(self, maxSize: int = 16, blocking: bool = False):
            self.queue = MessageQueue(self, maxSize, blocking)
            return self.queue

        def make(self, k: int):
            from polycam.rig import CameraSpec

            from .mock import PatternRenderer

            w, h = self.size
            cam = self.camera
            if cam.renderer is None:
                spec = CameraSpec(id="oak", driver="depthai", device=None, width=w, height=h, fps=cam.fps,
                                  pixel_format="GREY", position=np.zeros(3), rotation=np.zeros(3))
                cam.renderer = PatternRenderer([spec], cam.pipeline.device.oak.seed + int(cam.socket), 0.0)
            grey = cam.renderer.image(0, k / cam.fps, k)
            img = grey if self.type == ImgType.GRAY8 else np.repeat(grey[:, :, None], 3, axis=2)
            t = cam.frame_time(k)
            oak = cam.pipeline.device.oak
            manual = cam.initialControl.exposure
            exposure = manual[0] if manual is not None else oak.auto_exposure_us.get(cam.socket.name, 10_000)
            return ImgFrame(img, self.type, t, t - oak.boot_offset_ns, k, exposure)

    class Camera:
        initialControl = property(lambda self: self._initial_control)

        def __init__(self, pipeline):
            self.pipeline = pipeline
            self._initial_control = CameraControl()
            self.socket = None
            self.fps = 30.0
            self.outputs: list[Output] = []
            self.renderer = None

        def build(self, boardSocket=CameraBoardSocket.AUTO, sensorResolution=None, sensorFps=None):
            oak = self.pipeline.device.oak
            if boardSocket.name not in oak.sockets:
                raise RuntimeError(f"Camera on socket {boardSocket.name} not found on device {oak.device_id}")
            self.socket = boardSocket
            if sensorFps is not None:
                self.fps = float(sensorFps)
            return self

        def requestOutput(self, size, type=None, resizeMode=None, fps=None, enableUndistortion=None,
                          alphaScaling=None):
            if self.socket is None:
                raise RuntimeError("Camera node not built")
            oak = self.pipeline.device.oak
            if type == ImgType.GRAY8 and self.socket.name in oak.colour_sockets:
                pass  # colour sensors can output grey
            if type in (ImgType.RGB888i, ImgType.BGR888i) and self.socket.name not in oak.colour_sockets:
                raise RuntimeError(f"{self.socket.name} is a mono sensor: no colour output")
            if fps is not None:
                self.fps = float(fps)
            out = Output(self, size, type if type is not None else ImgType.NV12, self.fps)
            self.outputs.append(out)
            return out

        def phase_ns(self) -> int:
            dev = self.pipeline.device
            period = 1e9 / self.fps
            if dev.external_sync:
                return 0
            base = np.random.default_rng([dev.oak.seed, 7]).uniform(0, period)
            hw = any(c.initialControl.frame_sync == FrameSyncMode.OUTPUT for c in self.pipeline.cameras)
            if hw and self.initialControl.frame_sync in (FrameSyncMode.OUTPUT, FrameSyncMode.INPUT):
                return int(base)
            return int(np.random.default_rng([dev.oak.seed, 8, int(self.socket)]).uniform(0, period))

        def frame_time(self, k: int) -> int:
            return self.pipeline.t0 + self.phase_ns() + int(round(k * 1e9 / self.fps))

    class Pipeline:
        def __init__(self, defaultDevice=None):
            if defaultDevice is None:
                defaultDevice = Device()
            self.device = defaultDevice
            self.cameras: list[Camera] = []
            self.running = False
            self.t0 = 0

        def create(self, cls, *args, **kwargs):
            if cls is not Camera:
                raise NotImplementedError("the fake depthai has only node.Camera")
            c = Camera(self)
            self.cameras.append(c)
            return c

        def start(self) -> None:
            if not self.cameras:
                raise RuntimeError("Pipeline is empty")
            self.running = True
            self.t0 = state.now_ns + 50_000_000
            state.events.append(("start", self.device.oak.device_id))

        def stop(self) -> None:
            self.running = False
            state.events.append(("stop", self.device.oak.device_id))

        def isRunning(self) -> bool:
            return self.running and not self.device.gone

    class Device:
        def __init__(self, deviceInfo=None, *args):
            if deviceInfo is None:
                if not oaks:
                    raise RuntimeError("No available devices")
                deviceInfo = DeviceInfo(oaks[0])
            oak = deviceInfo._oak if isinstance(deviceInfo, DeviceInfo) else None
            if oak is None or oak not in oaks:
                raise RuntimeError(f"Device {deviceInfo.getDeviceId()} not found")
            if any(d.oak is oak and not d.closed for d in state.opened):
                raise RuntimeError(f"Device {oak.device_id} is already in use (X_LINK_DEVICE_ALREADY_IN_USE)")
            self.oak = oak
            self.closed = False
            self.gone = False
            self.external_sync = False
            self.role = None
            state.opened.append(self)

        @staticmethod
        def getAllAvailableDevices():
            return [DeviceInfo(o) for o in oaks if not any(d.oak is o and not d.closed for d in state.opened)]

        def getDeviceId(self) -> str:
            return self.oak.device_id

        def setExternalFrameSyncRole(self, role=ExternalFrameSyncRole.AUTO_DETECT):
            if not self.oak.fsync:
                return False, "External frame sync is not supported on this device"
            self.role = role
            self.external_sync = True
            return True, ""

        def close(self) -> None:
            self.closed = True

        def isClosed(self) -> bool:
            return self.closed

    node = SimpleNamespace(Camera=Camera)
    Node = SimpleNamespace(Output=Output)
    return SimpleNamespace(
        __name__="fake_depthai", __version__="3.12.0-fake", Device=Device, DeviceInfo=DeviceInfo,
        Pipeline=Pipeline, node=node, Node=Node, ImgFrame=ImgFrame, MessageQueue=MessageQueue,
        CameraBoardSocket=CameraBoardSocket, CameraControl=CameraControl, CameraExposureOffset=CameraExposureOffset,
        ExternalFrameSyncRole=ExternalFrameSyncRole, XLinkDeviceState=XLinkDeviceState,
        clock=clock, sleep=sleep, state=state)
