"""Rig files (``rigs/NAME.toml``, SPEC.md): the cameras of an array and how to drive them.

A rig file has a ``[rig]`` table (``name``), ``[defaults]`` applied to every
camera, and either ``[[camera]]`` entries or a ``[grid]`` table that generates
a forward-looking planar array. The ``[mock]`` table configures the mock
driver. Keys polycam adds beyond SPEC.md are documented in docs/formats.md.

Frames (docs/conventions.md): ``position`` is the camera centre in the rig
frame [m]; ``rotation`` is the axis-angle vector [rad] of ``R_rig_cam``.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .errors import FormatError
from .geometry import R_from_r, T_from_Rt
from .tomlio import Table, load_toml

__all__ = ["CameraSpec", "MockSpec", "Rig", "load_rig", "DRIVERS", "PIXEL_FORMATS", "MOCK_SCENES", "MJPG_QUALITY",
           "MAX_CAMERAS", "MAX_IMAGE_SIDE"]

DRIVERS = ("v4l2", "depthai", "mock", "replay")
PIXEL_FORMATS = ("GREY", "Y16", "YUYV", "MJPG", "RGB")

MJPG_QUALITY = 90
"""Default ``[mock]`` ``mjpg_quality``: the JPEG quality of simulated MJPG cameras (a webcam's own is
its firmware's; 90 costs the 5 x 5 mock rig's motion ~15 %, 75 ~70 %: docs/capture.md)."""
MOCK_SCENES = ("room", "spheres", "pattern")

MAX_CAMERAS = 4096
"""The most cameras a rig file may have (the largest published arrays have a few hundred; the bound
catches a mistyped ``[grid]`` before a rig of millions is built)."""

MAX_IMAGE_SIDE = 32768
"""[px] the largest ``width`` / ``height`` a rig file may give (a 100-megapixel sensor is ~12000
wide; the bound catches a mistyped size before anything allocates images of it)."""

_CAMERA_KEYS = ("driver", "width", "height", "fps", "pixel_format", "fov_deg", "lens")


@dataclass(frozen=True)
class CameraSpec:
    """One camera of a rig, with ``[defaults]`` already applied."""

    id: str
    """Camera id, e.g. ``cam00``; also its folder name in a session."""
    driver: str
    """One of :data:`DRIVERS`."""
    device: str | None
    """Driver-specific device address (``/dev/video0``, an OAK MxId, ...); None for mock."""
    width: int
    """[px] image width."""
    height: int
    """[px] image height."""
    fps: float
    """[Hz] nominal frame rate."""
    pixel_format: str
    """One of :data:`PIXEL_FORMATS`."""
    position: np.ndarray
    """(3,) [m] nominal camera centre in the rig frame."""
    rotation: np.ndarray
    """(3,) [rad] axis-angle vector of ``R_rig_cam`` (zeros: looks along rig +z)."""
    fov_deg: float = 60.0
    """[deg] nominal horizontal field of view (polycam extension; seeds intrinsics)."""
    lens: Path | None = None
    """Optional mrcal ``.cameramodel`` whose lens model and distortion the mock and
    synthetic cameras use, rescaled to ``width`` x ``height`` (polycam extension)."""

    @property
    def R_rig_cam(self) -> np.ndarray:
        """(3, 3) rotation, camera frame → rig frame."""
        return R_from_r(self.rotation)

    @property
    def T_rig_cam(self) -> np.ndarray:
        """(4, 4) nominal pose of the camera in the rig: camera frame → rig frame."""
        return T_from_Rt(self.R_rig_cam, self.position)


@dataclass(frozen=True)
class MockSpec:
    """The ``[mock]`` table: what the mock driver renders and how it misbehaves."""

    scene: str = "room"
    """``room``, ``spheres`` or ``pattern``."""
    motion: str = "smooth"
    """``static`` or ``smooth`` (a seeded smooth random trajectory)."""
    seed: int = 0
    noise: float = 0.0
    """Grey-level noise std in [0, 1] units."""
    jitter_ms: float = 0.0
    """Std of per-camera timestamp jitter [ms] (moves the timestamps, not what the images show)."""
    sync_spread_ms: float = 0.0
    """[ms] free-running cameras: each captures at its own constant offset from the others, uniform in
    ±``sync_spread_ms`` (seeded), and its images show those moments (0: one trigger for all)."""
    clock_ppm: float = 0.0
    """[ppm] free-running cameras' clocks: each camera's frame period is off the nominal one by its own
    amount, uniform in ±``clock_ppm`` (seeded), so the cameras' phases drift apart (0: one clock)."""
    drop_rate: float = 0.0
    """Probability in [0, 1] that a camera drops a frame."""
    disconnect_after: dict[str, int] = field(default_factory=dict)
    """Camera id → number of frames after which that camera vanishes."""
    distance: float = 4.0
    """[m] distance from the rig to the scene (spheres) or to the far wall (room)."""
    step_t: float = 0.005
    """[m] typical translation per frame of the ``smooth`` motion."""
    step_r_deg: float = 0.2
    """[deg] typical rotation per frame of the ``smooth`` motion."""
    mjpg_quality: int = MJPG_QUALITY
    """JPEG quality (1–100) of the mock's and the synthetic sessions' ``MJPG`` cameras: their frames
    are JPEG-compressed and decoded as a webcam's are (:data:`MJPG_QUALITY`)."""

    @property
    def free_running(self) -> bool:
        """The cameras have no common trigger (``sync_spread_ms`` or ``clock_ppm`` set): capture them
        with the free-running grouping (``polycam capture --free-running``)."""
        return self.sync_spread_ms > 0 or self.clock_ppm > 0


@dataclass(frozen=True)
class Rig:
    """A validated rig file."""

    name: str
    cameras: tuple[CameraSpec, ...]
    mock: MockSpec | None = None
    path: Path | None = None
    """The file it was read from (None when built in code)."""

    @property
    def ids(self) -> list[str]:
        return [c.id for c in self.cameras]

    def camera(self, cam_id: str) -> CameraSpec:
        for c in self.cameras:
            if c.id == cam_id:
                return c
        raise KeyError(cam_id)

    @property
    def positions(self) -> np.ndarray:
        """(N, 3) [m] nominal camera centres in the rig frame."""
        return np.stack([c.position for c in self.cameras])


def _camera_settings(t: Table, base: dict, rig_dir: Path) -> dict:
    """Per-camera settings from table ``t`` over ``base`` (the defaults)."""
    out = dict(base)
    if t.has("driver"):
        out["driver"] = t.choice("driver", DRIVERS)
    if t.has("width"):
        out["width"] = t.number("width", integer=True, min=1, max=MAX_IMAGE_SIDE)
    if t.has("height"):
        out["height"] = t.number("height", integer=True, min=1, max=MAX_IMAGE_SIDE)
    if t.has("fps"):
        out["fps"] = t.number("fps", min=0.0, open_min=True)
    if t.has("pixel_format"):
        out["pixel_format"] = t.choice("pixel_format", PIXEL_FORMATS)
    if t.has("fov_deg"):
        out["fov_deg"] = t.number("fov_deg", min=1.0, max=179.0)
    if t.has("lens"):
        lens = Path(t.get("lens", str))
        lens = lens if lens.is_absolute() else rig_dir / lens
        if not lens.is_file():
            raise t.error("lens", f"no such cameramodel file {str(lens)!r}")
        out["lens"] = lens
    return out


def load_rig(path: str | os.PathLike) -> Rig:
    """Read and validate a rig file; errors name the file and the field."""
    path = Path(path)
    doc = load_toml(path)
    top = Table(path, "", doc)
    rig_t = top.subtable("rig")
    name = rig_t.get("name", str)
    rig_t.finish()

    base = {"driver": "mock", "width": 640, "height": 480, "fps": 30.0, "pixel_format": "GREY",
            "fov_deg": 60.0, "lens": None}
    defaults = top.subtable("defaults", None)
    if defaults is not None:
        base = _camera_settings(defaults, base, path.parent)
        defaults.finish()

    has_cams, has_grid = top.has("camera"), top.has("grid")
    if has_cams == has_grid:
        raise FormatError(path, "needs either [[camera]] entries or a [grid] table (exactly one)")
    cameras: list[CameraSpec] = []
    if has_grid:
        g = top.subtable("grid")
        rows = g.number("rows", integer=True, min=1, max=MAX_CAMERAS)
        cols = g.number("cols", integer=True, min=1, max=MAX_CAMERAS)
        pitch = g.number("pitch", min=0.0, open_min=True)
        g.finish()
        if rows * cols > MAX_CAMERAS:
            raise g.error("rows", f"rows x cols = {rows * cols} cameras; at most {MAX_CAMERAS}")
        width = max(2, len(str(rows * cols - 1)))
        for r in range(rows):
            for c in range(cols):
                pos = np.array([(c - (cols - 1) / 2) * pitch, (r - (rows - 1) / 2) * pitch, 0.0])
                cameras.append(CameraSpec(id=f"cam{r * cols + c:0{width}d}", device=None,
                                          position=pos, rotation=np.zeros(3), **base))
    else:
        entries = top.get("camera", list)
        if not entries:
            raise FormatError(path, "expected at least one [[camera]] entry", "camera")
        if len(entries) > MAX_CAMERAS:
            raise FormatError(path, f"{len(entries)} [[camera]] entries; at most {MAX_CAMERAS}", "camera")
        for i, entry in enumerate(entries):
            t = Table(path, f"[[camera]] #{i + 1}", entry)
            cam_id = t.get("id", str)
            if not cam_id or any(ch in cam_id for ch in "/\\ ,") or cam_id.startswith("."):
                raise t.error("id", f"not usable as a folder name: {cam_id!r}")
            device = t.get("device", str, None)
            position = np.array(t.vector("position", 3))
            rotation = np.array(t.vector("rotation", 3, [0.0, 0.0, 0.0]))
            settings = _camera_settings(t, base, path.parent)
            t.finish()
            cameras.append(CameraSpec(id=cam_id, device=device, position=position,
                                      rotation=rotation, **settings))
        ids = [c.id for c in cameras]
        dup = sorted({i for i in ids if ids.count(i) > 1})
        if dup:
            raise FormatError(path, f"duplicate camera id {dup[0]!r}", "camera")

    mock = None
    m = top.subtable("mock", None)
    if m is not None:
        disc_t = m.subtable("disconnect_after", None)
        disconnect = {}
        if disc_t is not None:
            known = {c.id for c in cameras}
            for cam_id in list(disc_t.data):
                n = disc_t.number(cam_id, integer=True, min=0)
                if cam_id not in known:
                    raise disc_t.error(cam_id, "no camera with this id")
                disconnect[cam_id] = n
        mock = MockSpec(
            scene=m.choice("scene", MOCK_SCENES, "room"),
            motion=m.choice("motion", ("static", "smooth"), "smooth"),
            seed=m.number("seed", 0, integer=True, min=0),
            noise=m.number("noise", 0.0, min=0.0, max=1.0),
            jitter_ms=m.number("jitter_ms", 0.0, min=0.0),
            sync_spread_ms=m.number("sync_spread_ms", 0.0, min=0.0),
            clock_ppm=m.number("clock_ppm", 0.0, min=0.0, max=1e5),
            drop_rate=m.number("drop_rate", 0.0, min=0.0, max=1.0),
            disconnect_after=disconnect,
            distance=m.number("distance", 4.0, min=0.0, open_min=True),
            step_t=m.number("step_t", 0.005, min=0.0),
            step_r_deg=m.number("step_r_deg", 0.2, min=0.0),
            mjpg_quality=m.number("mjpg_quality", MJPG_QUALITY, integer=True, min=1, max=100),
        )
        m.finish()
    top.finish()
    return Rig(name=name, cameras=tuple(cameras), mock=mock, path=path)
