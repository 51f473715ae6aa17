"""Rendering synthetic light fields and camera images (no file I/O).

- :func:`render_lightfield` / :class:`LightFieldRenderer`: the two-plane light field
  ``L[face, y, x, v, u]`` of a scene seen from a rig pose. Each sample is the mean
  radiance of ``k x k`` rays spread over its (u, v) cell (a box filter over the
  direction footprint; the viewpoint (x, y) is exact); optionally after a Gaussian
  optics point-spread function (``psf``), which acts before the pixel integration as a
  lens does, so it also removes the aliasing a blur of the finished samples would keep.
- :class:`CameraArrayRenderer`: per-camera images of a rig through mrcal camera
  models (rays from ``mrcal.unproject`` of ``k x k`` sub-pixel points per pixel,
  averaged: box-filter anti-aliasing). The rays are computed once per camera and
  reused for every pose.
- :func:`quantize`: float radiance → 8/16-bit images with optional Gaussian noise.

Frames: rays are built in the rig frame and placed in the scene's world frame by
``T_world_rig`` (see docs/conventions.md).
"""

from __future__ import annotations

import math

import numpy as np

from ..cameras import camera_rays, nominal_cameramodel, pixel_grid
from ..lightfield import Axis, LightFieldGrid
from ..rig import Rig
from .raycast import trace_indexed, trace_outer
from .scenes import Scene

__all__ = [
    "default_lightfield_grid",
    "lightfield_face_rays",
    "LightFieldRenderer",
    "render_lightfield",
    "CameraArrayRenderer",
    "quantize",
]


def default_lightfield_grid(faces="all", *, f: float = 60.0, views: int = 9, spacing: float = 0.01,
                            directions: int = 64, z_pi: float | None = None) -> LightFieldGrid:
    """The paper's Sect. 5 grid: ``views x views`` viewpoints ``spacing`` [m] apart centred
    on the rig origin, ``directions x directions`` (u, v) samples at the centres of
    equal cells spanning a 90 deg field of view (``|u|, |v| < f``), plane separation
    ``f``, focal plane at ``z_pi`` (default: half the viewpoint span, so the six faces
    of ``"all"`` form a cube around the rig origin).

    faces: ``"all"``, a face name such as ``"+z"``, or a list of face names.
    """
    from ..lightfield import FACE_NAMES

    if isinstance(faces, str):
        faces = list(FACE_NAMES) if faces == "all" else [faces]
    half = spacing * (views - 1) / 2.0
    du = 2.0 * f / directions
    uv = Axis(-f + du / 2.0, f - du / 2.0, directions)
    xy = Axis(-half, half, views)
    return LightFieldGrid.cube(list(faces), f=f, z_pi=half if z_pi is None else z_pi, x=xy, y=xy, u=uv, v=uv)


def _subsample_offsets(k: int) -> np.ndarray:
    """(k*k, 2) offsets in cell units, centres of a k x k sub-grid of [-0.5, 0.5]^2 (x fastest)."""
    off = (np.arange(k) + 0.5) / k - 0.5
    ox, oy = np.meshgrid(off, off, indexing="xy")
    return np.stack([ox.ravel(), oy.ravel()], axis=-1)


def lightfield_face_rays(grid: LightFieldGrid, k: int, supersample: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """Rays of face ``k`` in the rig frame, split for :func:`~polycam.synth.raycast.trace_outer`.

    Returns origins (Ny*Nx, 3) [m] (row-major over y, x) and directions
    (Nv*Nu, S, 3) float32, S = supersample**2, not normalised: ``(u + du, v + dv, f)``
    rotated by ``R_rig_face``, with (du, dv) the sub-sample offsets over the cell
    (``step_u x step_v``; no spread along an axis with a single sample).
    """
    face = grid.faces[k]
    R = np.asarray(face.R_rig_face, float)
    ys, xs = np.meshgrid(grid.y.values, grid.x.values, indexing="ij")
    o_face = np.stack([xs.ravel(), ys.ravel(), np.full(xs.size, face.z_pi)], axis=-1)
    vs, us = np.meshgrid(grid.v.values, grid.u.values, indexing="ij")
    off = _subsample_offsets(int(supersample))
    su = us.ravel()[:, None] + off[None, :, 0] * grid.u.step
    sv = vs.ravel()[:, None] + off[None, :, 1] * grid.v.step
    d_face = np.stack([su, sv, np.full_like(su, face.f)], axis=-1)
    return o_face @ R.T, np.ascontiguousarray(d_face @ R.T, dtype=np.float32)


class LightFieldRenderer:
    """Renders a light-field grid from any rig pose; the per-face rays are cached.

    supersample: k; each sample averages k x k rays over its (u, v) cell (box filter).
    psf: std [samples] of a Gaussian optics point-spread function along u and v of every
        view (0: none), applied to the radiance *before* the pixel integration: each sample
        is the Gaussian ⊗ box of the radiance, computed on the k x k sub-sample rays of the
        grid extended by ``ceil(4 psf) + 1`` samples beyond its (u, v) border (so the border
        samples see the scene beyond it, as a lens does), then averaged per cell. Blurring
        finished samples instead keeps the aliased part of texture finer than a sample,
        which no warp of the samples reproduces (docs/motion_log.md, Session 26).
    """

    def __init__(self, scene: Scene, grid: LightFieldGrid, supersample: int = 1, psf: float = 0.0):
        if supersample < 1:
            raise ValueError("supersample must be >= 1")
        if psf < 0:
            raise ValueError("psf must be >= 0")
        if psf > 0 and (grid.u.count < 2 or grid.v.count < 2):
            raise ValueError("psf needs at least 2 samples along u and v")
        self.scene = scene
        self.grid = grid
        self.supersample = int(supersample)
        self.psf = float(psf)
        self.pad = math.ceil(4.0 * self.psf) + 1 if self.psf > 0 else 0
        ray_grid = _padded_subsample_grid(grid, self.supersample, self.pad) if self.psf > 0 else grid
        k = 1 if self.psf > 0 else self.supersample
        self._rays = [lightfield_face_rays(ray_grid, i, k) for i in range(len(grid.faces))]

    def render(self, T_world_rig: np.ndarray, scene: Scene | None = None) -> np.ndarray:
        """(F, Ny, Nx, Nv, Nu) float32 radiance in [0, 1] at pose ``T_world_rig`` (4, 4)."""
        sc = self.scene if scene is None else scene
        F, Ny, Nx, Nv, Nu = self.grid.shape
        out = np.empty((F, Ny, Nx, Nv, Nu), np.float32)
        for i, (o, d) in enumerate(self._rays):
            if self.psf == 0:
                out[i] = trace_outer(sc, o, d, T_world_rig).radiance.reshape(Ny, Nx, Nv, Nu)
                continue
            step = max(1, _PSF_CHUNK // d.shape[0])        # viewpoints per call: bounded memory
            for a in range(0, o.shape[0], step):
                rad = trace_outer(sc, o[a:a + step], d, T_world_rig).radiance
                out[i].reshape(Ny * Nx, Nv, Nu)[a:a + step] = self._integrate(rad)
        return out

    def _integrate(self, rad: np.ndarray) -> np.ndarray:
        """(A, Nv, Nu) samples from (A, nv_f * nu_f) sub-sample radiance of the padded grid:
        the Gaussian PSF along both fine axes, then the mean over each k x k cell, cropped."""
        from scipy.ndimage import gaussian_filter1d

        k, p = self.supersample, self.pad
        Nv, Nu = self.grid.v.count, self.grid.u.count
        fine = rad.reshape(-1, (Nv + 2 * p) * k, (Nu + 2 * p) * k)
        fine = gaussian_filter1d(fine, self.psf * k, axis=1, mode="nearest")
        fine = gaussian_filter1d(fine, self.psf * k, axis=2, mode="nearest")
        cells = fine.reshape(-1, Nv + 2 * p, k, Nu + 2 * p, k).mean(axis=(2, 4))
        return cells[:, p:p + Nv, p:p + Nu]


_PSF_CHUNK = 1 << 23
"""Sub-sample rays per :func:`trace_outer` call of a renderer with a PSF (memory bound)."""


def _padded_subsample_grid(grid: LightFieldGrid, k: int, pad: int) -> LightFieldGrid:
    """``grid`` with (u, v) replaced by its k x k sub-sample points (the supersampling's cell
    offsets) over the cells extended by ``pad`` samples on each side."""
    def axis(a: Axis) -> Axis:
        h = a.step
        lo = a.min - pad * h + ((0.5 / k) - 0.5) * h
        n = (a.count + 2 * pad) * k
        return Axis(lo, lo + (n - 1) * h / k, n)

    return LightFieldGrid(grid.faces, grid.x, grid.y, axis(grid.u), axis(grid.v))


def render_lightfield(scene: Scene, grid: LightFieldGrid, T_world_rig: np.ndarray | None = None,
                      supersample: int = 1, psf: float = 0.0) -> np.ndarray:
    """The light field ``L[face, y, x, v, u]`` (F, Ny, Nx, Nv, Nu) float32 in [0, 1].

    T_world_rig: (4, 4) rig pose in the scene (default identity).
    supersample: k; each sample averages k x k rays over its (u, v) cell.
    psf: std [samples] of a Gaussian optics blur before the pixel integration
        (:class:`LightFieldRenderer`).
    """
    T = np.eye(4) if T_world_rig is None else T_world_rig
    return LightFieldRenderer(scene, grid, supersample, psf).render(T)


class CameraArrayRenderer:
    """Renders every camera of a rig through its mrcal model; rays cached per camera.

    models: camera id → ``mrcal.cameramodel`` whose reference frame is the rig
        (``rt_cam_ref = T_cam_rig``); default :func:`~polycam.cameras.nominal_cameramodel`
        of each camera (its ``lens`` if any). Image sizes come from the models.
    supersample: k; each pixel averages the rays of k x k points spread over the
        pixel's square footprint (:func:`~polycam.cameras.pixel_grid`). Pixels (or
        sub-pixel points) the lens model cannot unproject render as 0.
    """

    def __init__(self, rig: Rig, models: dict | None = None, scene: Scene | None = None,
                 supersample: int = 1):
        if supersample < 1:
            raise ValueError("supersample must be >= 1")
        self.rig = rig
        self.scene = scene
        self.supersample = int(supersample)
        self.models = dict(models) if models is not None else {}
        for cam in rig.cameras:
            if cam.id not in self.models:
                self.models[cam.id] = nominal_cameramodel(cam)
        self._centre_rays: dict[str, tuple[np.ndarray, np.ndarray, tuple[int, int]]] = {}
        # All cameras' rays in one array, so a frame is one kernel call.
        origins, dirs, index, self._slices, self._sizes = [], [], [], {}, {}
        start = 0
        for i, cam in enumerate(rig.cameras):
            o, d, (H, W) = self._camera_rays(cam.id, self.supersample)
            origins.append(o[0])
            dirs.append(d)
            index.append(np.full(d.shape[0], i, np.int64))
            self._slices[cam.id] = slice(start, start + d.shape[0])
            self._sizes[cam.id] = (H, W)
            start += d.shape[0]
        self._origins = np.stack(origins)                              # (N_cam, 3)
        self._dirs = np.ascontiguousarray(np.concatenate(dirs))         # (sum H*W, S, 3) float32
        self._index = np.concatenate(index)                            # (sum H*W,)

    @property
    def ids(self) -> list[str]:
        return [c.id for c in self.rig.cameras]

    def _camera_rays(self, cam_id: str, k: int):
        model = self.models[cam_id]
        W, H = (int(v) for v in model.imagersize())
        q = pixel_grid(W, H, k)                                        # (H, W, S, 2)
        rays = camera_rays(model, q)
        d = np.ascontiguousarray(rays.directions.reshape(H * W, k * k, 3), dtype=np.float32)
        o = np.asarray(rays.origins, float).reshape(-1, 3)[:1].copy()  # one centre per camera
        return o, d, (H, W)

    def _scene(self, scene):
        sc = self.scene if scene is None else scene
        if sc is None:
            raise ValueError("no scene to render")
        return sc

    def render_camera(self, cam_id: str, T_world_rig: np.ndarray, scene: Scene | None = None) -> np.ndarray:
        """(H, W) float32 radiance in [0, 1] of one camera at rig pose ``T_world_rig`` (4, 4)."""
        i = self.ids.index(cam_id)
        sl = self._slices[cam_id]
        res = trace_outer(self._scene(scene), self._origins[i:i + 1], self._dirs[sl], T_world_rig)
        return res.radiance.reshape(self._sizes[cam_id])

    def render(self, T_world_rig: np.ndarray, scene: Scene | None = None) -> dict[str, np.ndarray]:
        """Camera id → (H, W) float32 radiance image in [0, 1] at rig pose ``T_world_rig``
        (all cameras in one parallel kernel call)."""
        rad = trace_indexed(self._scene(scene), self._origins, self._dirs, self._index, T_world_rig).radiance
        return {cid: rad[self._slices[cid]].reshape(self._sizes[cid]) for cid in self.ids}

    def distances(self, cam_id: str, T_world_rig: np.ndarray, scene: Scene | None = None
                  ) -> tuple[np.ndarray, np.ndarray]:
        """Ground truth of one camera through its pixel centres: ``(distance, primitive)``,
        (H, W) float64 [m] along the unit ray (inf: sky) and (H, W) int32 primitive ids."""
        sc = self._scene(scene)
        if cam_id not in self._centre_rays:
            self._centre_rays[cam_id] = self._camera_rays(cam_id, 1)
        o, d, (H, W) = self._centre_rays[cam_id]
        res = trace_outer(sc, o, d, T_world_rig)
        return res.distance.reshape(H, W), res.primitive.reshape(H, W)


def mjpg_frame(grey: np.ndarray, quality: int) -> np.ndarray:
    """An 8-bit grey image (H, W) as an MJPG camera delivers it: JPEG-encoded at ``quality`` (1–100,
    OpenCV's encoder: 4:2:0 chroma) and decoded in colour as ``capture/v4l2.py`` does, (H, W, 3) uint8
    RGB. The mock driver's and synthetic sessions' MJPG cameras (:attr:`polycam.rig.MockSpec.mjpg_quality`)."""
    import cv2

    img = np.asarray(grey)
    if img.dtype != np.uint8 or img.ndim != 2:
        raise ValueError(f"mjpg_frame: expected an (H, W) uint8 image, got {img.dtype} {img.shape}")
    if not 1 <= int(quality) <= 100:
        raise ValueError(f"mjpg_frame: quality must be 1..100, got {quality}")
    ok, data = cv2.imencode(".jpg", np.repeat(img[:, :, None], 3, axis=2), [cv2.IMWRITE_JPEG_QUALITY, int(quality)])
    if not ok:
        raise ValueError("mjpg_frame: the JPEG encoder failed")
    return cv2.cvtColor(cv2.imdecode(data, cv2.IMREAD_COLOR), cv2.COLOR_BGR2RGB)


def quantize(radiance: np.ndarray, bit_depth: int = 8, noise: float = 0.0,
             rng: np.random.Generator | None = None) -> np.ndarray:
    """Radiance (...) in [0, 1] → uint8 (bit_depth 8) or uint16 (16) with rounding.

    noise: std of additive Gaussian noise in [0, 1] units, drawn from ``rng``
        (required when noise > 0), added before clipping and rounding.
    """
    x = np.array(radiance, np.float64)                  # a copy, worked on in place
    if noise > 0:
        if rng is None:
            raise ValueError("quantize: noise needs an rng")
        x += rng.normal(0.0, noise, size=x.shape)
    if bit_depth not in (8, 16):
        raise ValueError(f"bit_depth must be 8 or 16, got {bit_depth}")
    np.clip(x, 0.0, 1.0, out=x)
    x *= 255.0 if bit_depth == 8 else 65535.0
    np.rint(x, out=x)
    return x.astype(np.uint8 if bit_depth == 8 else np.uint16)
