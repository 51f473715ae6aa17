"""Resampling camera frames onto a light-field grid: a sparse product plus the pull-push pyramid.

:class:`Resampler` holds everything that depends only on the calibration and
the grid (the splat geometry, :mod:`resample.geometry`) and the buffers of one
frame, so resampling a frame costs one sparse matrix product
(:func:`~resample.geometry.splat`), one pull-push pass
(:class:`~resample.pushpull.PushPull`) and, by default, the depth-aware filling
of the views between cameras (:mod:`resample.viewfill`: a plane sweep per view,
interpolating along the disparity instead of across it). A frame in which some cameras have no
image uses a geometry built for the cameras present (built on first use and
cached), so every cell is still a proper weighted fit of the data it has.

Images are normalised like the light-field store (SPEC.md): 8-bit / 255, 16-bit
/ 65535, floats as they are. With ``channels = 3`` grey images are repeated
into three channels; with ``channels = 1`` RGB images are averaged.

No file I/O; not thread-safe (use one per worker).
"""

from __future__ import annotations

import logging
from collections import OrderedDict
from dataclasses import dataclass, field

import numpy as np

from polycam.errors import InputError
from polycam.lightfield import LightFieldGrid

from .geometry import KernelOptions, SplatGeometry, build_geometry, splat
from .pushpull import SCHEDULES, PushPull, weighted_views
from .viewfill import (ViewFillOptions, ViewFillPlan, camera_heights, camera_positions, data_positions, fill_views,
                       plan_view_fill)

VIEW_FILLS = ("depth", "pushpull")
"""How views no camera measured are filled: along the disparity found by a plane sweep
(:mod:`resample.viewfill`), or by the pull-push alone (depth-free: linear in (x, y) at
fixed (u, v))."""

__all__ = ["VIEW_FILLS", "ResampleOptions", "ResampledFrame", "Resampler", "normalise_image", "COMPRESSED_FORMATS",
           "noise_cameras", "compressed_note", "images_noise_sigma", "median_noise"]

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class ResampleOptions:
    """Settings of the resampler (defaults are the tuned ones, docs/resample.md)."""

    kernel: KernelOptions = field(default_factory=KernelOptions)
    """Splat kernel and local-linear correction."""
    schedule: str = "xy-first"
    """Pyramid schedule (:data:`~resample.pushpull.SCHEDULES`)."""
    attenuation: float = 0.5
    """Confidence a filled cell inherits per pyramid level (:mod:`resample.pushpull`)."""
    full_weight: float = 0.5
    """Kernel sum [samples] at which a cell counts as fully covered: the pull-push weight is
    ``min(w0 / full_weight, 1)``. With the default one-pixel (u, v) step a cell gets about one
    sample's kernel weight on average, fluctuating with the sampling pattern; half of that
    is enough for the local-linear fit to be trusted on its own."""
    geometry_cache: int = 8
    """Geometries kept for frames with missing cameras (one per set of cameras present)."""
    view_fill: str = "depth"
    """How the views between cameras are filled (:data:`VIEW_FILLS`)."""
    fill: ViewFillOptions = field(default_factory=ViewFillOptions)
    """Settings of the depth-aware view filling (``view_fill="depth"``)."""

    def __post_init__(self) -> None:
        if self.view_fill not in VIEW_FILLS:
            raise ValueError(f"view_fill must be one of {VIEW_FILLS}, got {self.view_fill!r}")
        if self.schedule not in SCHEDULES:
            raise ValueError(f"schedule must be one of {SCHEDULES}, got {self.schedule!r}")
        if not 0.0 < self.attenuation <= 1.0:
            raise ValueError("attenuation must be in (0, 1]")
        if not self.full_weight > 0.0:
            raise ValueError("full_weight must be > 0")


@dataclass(frozen=True)
class ResampledFrame:
    """One resampled frame."""

    L: np.ndarray
    """(F, Ny, Nx, Nv, Nu) or (F, Ny, Nx, Nv, Nu, C) float32 intensities."""
    W: np.ndarray
    """(F, Ny, Nx, Nv, Nu) float32 confidence in [0, 1]."""
    cameras: tuple[str, ...]
    """Cameras that had an image in this frame."""


def _unit_scale(img: np.ndarray) -> np.float32:
    """The factor that takes an image's values to [0, 1]: 1/255 (uint8), 1/65535 (uint16), 1 (float)."""
    if img.dtype == np.uint8:
        return np.float32(1.0 / 255.0)
    if img.dtype == np.uint16:
        return np.float32(1.0 / 65535.0)
    if np.issubdtype(img.dtype, np.floating):
        return np.float32(1.0)
    raise InputError(f"resample: images must be uint8, uint16 or float, got {img.dtype}")


def normalise_image(image: np.ndarray, channels: int) -> np.ndarray:
    """(H, W) or (H, W, 3) uint8 / uint16 / float image → (H, W, channels) float32 in [0, 1]."""
    img = np.asarray(image)
    scale = _unit_scale(img)
    if img.ndim == 3 and img.shape[2] == 1:
        img = img[:, :, 0]
    if img.ndim == 2:
        out = (img.astype(np.float32) * scale)[:, :, None]
        return np.repeat(out, channels, axis=2) if channels > 1 else out
    if img.ndim == 3 and img.shape[2] == 3:
        out = img.astype(np.float32) * scale
        return out.mean(axis=2, keepdims=True) if channels == 1 else out
    raise InputError(f"resample: images must be (H, W) grey or (H, W, 3) RGB, got {img.shape}")


COMPRESSED_FORMATS = ("MJPG",)
"""Rig pixel formats whose images are decoded from a lossy compression. JPEG quantises away the
noise of the flat regions :func:`polycam.image_noise.image_noise_sigma` reads, and adds its own
block edges: a rendered 320 x 240 camera image with 1 / 2 / 4 grey levels of noise reads 1.04 /
1.97 / 3.91 as PNG, 0.43 / 1.51 / 4.43 after JPEG at quality 95, 0.44 / 0.63 / 2.56 at 90, 0.60 /
0.63 / 0.86 at 80 (tests/test_image_noise.py), and a camera's quality is its own: no estimate of
the sensor's noise. Their cameras are left out of it (:func:`noise_cameras`)."""


def noise_cameras(session, cameras) -> list[str]:
    """The ids among ``cameras`` whose images give a sensor-noise estimate: those whose pixel format
    in the session's rig is not in :data:`COMPRESSED_FORMATS`."""
    return [c for c in cameras if session.rig.camera(c).pixel_format not in COMPRESSED_FORMATS]


def compressed_note(n: int, total: int) -> str:
    """What the CLI says of ``n`` of ``total`` cameras left out of the noise estimate (''
    for none): all of them, or how many."""
    if n <= 0:
        return ""
    if n >= total:
        return ("the cameras' sensor noise is not estimated: they record MJPG, whose JPEG compression "
                "removes the noise from the flat regions the estimate reads")
    return f"{n} MJPG camera{'s' if n != 1 else ''} left out (JPEG removes the noise the estimate reads)"


def images_noise_sigma(images: dict, cameras) -> dict[str, float]:
    """Camera id → the sensor noise's std of its image in ``images`` (id → image, None: no image),
    for the ids in ``cameras`` that have one: per channel of the image as recorded (a grey camera's
    one, a colour camera's root mean over its three), in [0, 1] units as the images are resampled
    (:func:`polycam.image_noise.image_noise_sigma`, NaN where it gives no estimate)."""
    from polycam.image_noise import image_noise_sigma

    out = {}
    for c in cameras:
        img = images.get(c)
        if img is not None:
            img = np.asarray(img)
            out[c] = image_noise_sigma(img) * float(_unit_scale(img))
    return out


def median_noise(estimates) -> tuple[float, int]:
    """(median, count) of the finite values among ``estimates`` (images' noise stds,
    :func:`images_noise_sigma`); (NaN, 0) when there is none."""
    vals = [float(v) for v in estimates if np.isfinite(v)]
    return (float(np.median(vals)), len(vals)) if vals else (float("nan"), 0)


class Resampler:
    """Resample frames of cameras ``models`` (camera id → mrcal cameramodel, rig frame)
    onto ``grid``.

    channels: 1 (grey light field) or 3 (RGB). The geometry for all cameras is built
    here (the expensive part: a few seconds for millions of pixels); pass a prebuilt
    ``geometry`` for the same models and grid to skip that.
    """

    def __init__(self, models: dict, grid: LightFieldGrid, *, channels: int = 1,
                 options: ResampleOptions | None = None, geometry: SplatGeometry | None = None):
        if channels not in (1, 3):
            raise ValueError(f"channels must be 1 or 3, got {channels}")
        self.models = dict(models)
        self.grid = grid
        self.channels = int(channels)
        self.options = options or ResampleOptions()
        self.cameras = tuple(self.models)
        if geometry is None:
            geometry = build_geometry(self.models, grid, kernel=self.options.kernel)
        elif geometry.grid != grid or geometry.layout.ids != self.cameras:
            raise ValueError("geometry was built for another grid or camera set")
        self.geometry = geometry
        """Splat geometry for all cameras."""
        self._subsets: OrderedDict[tuple[str, ...], SplatGeometry] = OrderedDict()
        self._w0c: dict[int, np.ndarray] = {}
        self._views: dict[int, np.ndarray] = {}
        self._plans: dict[int, ViewFillPlan] = {}
        self._pp: PushPull | None = None
        self._pixels: np.ndarray | None = None
        self._L: np.ndarray | None = None
        self._W: np.ndarray | None = None

    # pickling (dask): drop the per-frame buffers, keep the geometry
    def __getstate__(self):
        st = self.__dict__.copy()
        st.update(_pp=None, _pixels=None, _L=None, _W=None, _w0c={}, _views={}, _plans={})
        return st

    @property
    def num_pixels(self) -> int:
        """Input rays (camera pixels) per frame."""
        return self.geometry.layout.num_pixels

    def _geometry_for(self, present: tuple[str, ...]) -> SplatGeometry:
        if present == self.cameras:
            return self.geometry
        geo = self._subsets.get(present)
        if geo is None:
            log.info("building the splat geometry for %d of %d cameras", len(present), len(self.cameras))
            geo = build_geometry(self.models, self.grid, ids=list(present), kernel=self.options.kernel)
            self._subsets[present] = geo
            while len(self._subsets) > self.options.geometry_cache:
                self._subsets.popitem(last=False)
        else:
            self._subsets.move_to_end(present)
        return geo

    def _clamped(self, geo: SplatGeometry) -> np.ndarray:
        key = id(geo)
        w = self._w0c.get(key)
        if w is None:
            if len(self._w0c) > self.options.geometry_cache + 1:
                self._w0c.clear()
                self._views.clear()
            w = np.minimum(geo.w0 * np.float32(1.0 / self.options.full_weight), np.float32(1.0))
            self._w0c[key] = w
            self._views[key] = weighted_views(w)
        return w

    def fill_plan(self, geo: SplatGeometry | None = None) -> ViewFillPlan:
        """The depth-aware fill plan (which views are filled from which) of a geometry
        (default: all cameras); built on first use."""
        geo = geo or self.geometry
        key = id(geo)
        plan = self._plans.get(key)
        if plan is None:
            if len(self._plans) > self.options.geometry_cache + 1:
                self._plans.clear()
            if self.cameras_on_focal_plane():
                pos, height = self._centres(geo.layout.ids)
                plan = plan_view_fill(self.grid, self._clamped(geo), self.options.fill,
                                      camera_positions=pos, camera_heights=height)
            else:
                log.warning("resample: the cameras are not on the focal plane z_pi (a grid view is then a "
                            "patchwork of several cameras): the views between them are filled by the "
                            "pull-push alone (depth-free)")
                plan = plan_view_fill(self.grid, np.zeros(self.grid.shape, np.float32), self.options.fill)
            self._plans[key] = plan
        return plan

    def _centres(self, ids) -> tuple[np.ndarray, np.ndarray]:
        """(positions (F, Ny, Nx, 2), heights (F, Ny, Nx)) of cameras ``ids``:
        :func:`resample.viewfill.camera_positions` and :func:`~resample.viewfill.camera_heights`."""
        from polycam.cameras import T_rig_cam_of

        T = np.stack([T_rig_cam_of(self.models[c]) for c in ids])
        return (camera_positions(self.grid, T[:, :3, 3], T[:, :3, 2]),
                camera_heights(self.grid, T[:, :3, 3], T[:, :3, 2]))

    def camera_positions(self) -> np.ndarray | None:
        """(F, Ny, Nx, 2) float64: where the cameras' data are, at the views that hold them, NaN
        elsewhere: (iy, ix) in fractional grid indices. The camera
        centres (:func:`resample.viewfill.camera_positions`), except for the camera views the depth
        fill re-centres onto their grid views (``ViewFillOptions.recentre``, the default): those
        are at their integer indices. None when the cameras are not on the focal plane
        (:meth:`cameras_on_focal_plane`: a grid view is then no one camera's view). Written to the
        store as its ``camera_positions`` attribute (docs/formats.md)."""
        if not self.cameras_on_focal_plane():
            return None
        pos = self._centres(self.cameras)[0]
        if self.options.view_fill != "depth":
            return pos
        return data_positions(self.fill_plan(), pos)

    def cameras_on_focal_plane(self, tolerance: float = 0.25) -> bool:
        """Whether the camera centres lie on the focal plane of the face their optical axis
        points into, to within ``tolerance`` viewpoint steps (median over the cameras): then a
        measured grid view is one camera's view from that viewpoint, which the depth-aware
        fill assumes."""
        from polycam.cameras import T_rig_cam_of

        steps = [a.step for a in (self.grid.x, self.grid.y) if a.count > 1]
        if not steps:
            return True
        off = []
        for m in self.models.values():
            T = T_rig_cam_of(m)
            normals = np.stack([np.asarray(fc.R_rig_face)[:, 2] for fc in self.grid.faces])
            k = int(np.argmax(normals @ T[:3, 2]))
            off.append(abs(float(normals[k] @ T[:3, 3]) - self.grid.faces[k].z_pi))
        return float(np.median(off)) <= tolerance * min(steps)

    def _buffers(self):
        if self._pp is None:
            C = self.channels
            self._pp = PushPull(self.grid.shape, C, schedule=self.options.schedule,
                                attenuation=self.options.attenuation)
            self._pixels = np.zeros((self.num_pixels, C), np.float32)
            self._L = np.zeros((*self.grid.shape, C), np.float32)
            self._W = np.zeros(self.grid.shape, np.float32)
        return self._pp, self._pixels, self._L, self._W

    def pixels(self, images: dict) -> tuple[np.ndarray, tuple[str, ...]]:
        """The frame's input vector (P, C) float32 in the layout of all cameras (the
        resampler's own buffer) and the cameras that had an image."""
        _, buf, _, _ = self._buffers()
        unknown = [c for c in images if c not in self.models]
        if unknown:
            raise InputError(f"resample: image from camera {unknown[0]!r}, which has no calibration")
        lay = self.geometry.layout
        present = []
        for ci, cam in enumerate(lay.ids):
            img = images.get(cam)
            seg = buf[lay.offsets[ci]:lay.offsets[ci + 1]]
            if img is None:
                seg[:] = 0.0
                continue
            H, W = lay.sizes[ci]
            if np.shape(img)[:2] != (H, W):
                raise InputError(f"resample: {cam}: image is {np.shape(img)[1]}x{np.shape(img)[0]} but its "
                                 f"calibration says {W}x{H}")
            seg[:] = normalise_image(img, self.channels).reshape(H * W, self.channels)
            present.append(cam)
        return buf, tuple(present)

    def new_output(self) -> tuple[np.ndarray, np.ndarray]:
        """A pair of output buffers for :meth:`resample_into`: L (F, Ny, Nx, Nv, Nu, C) and
        W (F, Ny, Nx, Nv, Nu), float32."""
        return (np.zeros((*self.grid.shape, self.channels), np.float32),
                np.zeros(self.grid.shape, np.float32))

    def resample_into(self, images: dict, out: tuple[np.ndarray, np.ndarray] | None = None) -> ResampledFrame:
        """Resample one frame (camera id → image or None) into buffers: ``out`` (from
        :meth:`new_output`) or the resampler's own.

        The returned arrays are views of those buffers, overwritten by the next call that
        uses them: copy them (or use :meth:`resample`) to keep them. A frame without any
        image raises InputError.
        """
        pp, _, L, W = self._buffers()
        if out is not None:
            L, W = out
            if L.shape != (*self.grid.shape, self.channels) or W.shape != self.grid.shape \
                    or L.dtype != np.float32 or W.dtype != np.float32 or not L.flags.c_contiguous:
                raise ValueError("out: expected the buffers of new_output()")
        pix, present = self.pixels(images)
        if not present:
            raise InputError("resample: the frame has no image from any calibrated camera")
        geo = self._geometry_for(present)
        if geo is not self.geometry:
            sub = np.concatenate([pix[self.geometry.layout.offsets[i]:self.geometry.layout.offsets[i + 1]]
                                  for i, c in enumerate(self.cameras) if c in present])
        else:
            sub = pix
        if self.channels == 1:
            splat(geo, sub[:, 0], out=L.reshape(-1))
        else:
            splat(geo, sub, out=L.reshape(-1, self.channels))
        w0c = self._clamped(geo)
        pp.run(L, w0c, W, views=self._views[id(geo)])
        if self.options.view_fill == "depth":
            fill_views(L, W, self.fill_plan(geo), self.options.fill)
        Lv = L[..., 0] if self.channels == 1 else L
        return ResampledFrame(L=Lv, W=W, cameras=present)

    def resample(self, images: dict) -> ResampledFrame:
        """Like :meth:`resample_into`, but the arrays are the caller's to keep."""
        r = self.resample_into(images)
        return ResampledFrame(L=r.L.copy(), W=r.W.copy(), cameras=r.cameras)
