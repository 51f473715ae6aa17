"""Per-pixel rays of calibrated cameras in the rig frame, and the ray-table export
the resample stage reads.

Every direction comes from ``mrcal.unproject`` of the camera's lens model (exact
for any distortion), rotated by ``R_rig_cam``; every origin is the camera centre
(mrcal models are central). Pixel centres are at integer coordinates.

Ray table (:func:`write_ray_table`): ``DIR/<cam>.npz`` per camera with arrays
``origins`` (H, W, S, 3) float32 [m], ``directions`` (H, W, S, 3) float32 unit,
``valid`` (H, W, S) bool (False where the lens model cannot unproject),
``q`` (H, W, S, 2) float32 pixel coordinates, ``T_rig_cam`` (4, 4) float64 and
``imagersize`` (2,) int; ``S = supersample**2`` sub-pixel rays per pixel
(:func:`polycam.cameras.pixel_grid`). Read it back with :func:`read_ray_table`.
"""

from __future__ import annotations

import io
import os
from pathlib import Path

import numpy as np

from polycam.cameras import T_rig_cam_of, pixel_grid
from polycam.errors import FormatError
from polycam.rays import RayBundle
from polycam.tomlio import atomic_write_bytes

__all__ = ["pixel_rays", "rig_rays", "write_ray_table", "read_ray_table"]


def pixel_rays(model, q: np.ndarray | None = None, *, supersample: int = 1) -> tuple[RayBundle, np.ndarray]:
    """Rays in the rig frame of pixels ``q`` (..., 2) of one cameramodel (rt_cam_ref = T_cam_rig).

    Default q: every pixel, dims (H, W, S) with S = supersample**2 sub-pixel samples.
    Returns (rays with batch dims of q, valid (...) bool). Invalid rays have NaN directions.
    """
    import mrcal

    if q is None:
        W, H = (int(v) for v in model.imagersize())
        q = pixel_grid(W, H, supersample)
    q = np.ascontiguousarray(q, dtype=float)
    d_cam = mrcal.unproject(q, *model.intrinsics(), normalize=True)
    valid = np.all(np.isfinite(d_cam), axis=-1)
    T = T_rig_cam_of(model)
    d_rig = d_cam @ T[:3, :3].T
    o_rig = np.broadcast_to(T[:3, 3], d_rig.shape)
    return RayBundle(o_rig, d_rig, frame="rig"), valid


def rig_rays(models: dict, *, supersample: int = 1) -> dict[str, tuple[RayBundle, np.ndarray]]:
    """Camera id → (rays (H, W, S), valid (H, W, S)) for every model (see :func:`pixel_rays`)."""
    return {cam: pixel_rays(m, supersample=supersample) for cam, m in models.items()}


def write_ray_table(models: dict, out: str | os.PathLike, *, supersample: int = 1) -> list[Path]:
    """Write ``out/<cam>.npz`` (see the module docstring) for every model; returns the paths."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    written = []
    for cam, model in models.items():
        W, H = (int(v) for v in model.imagersize())
        q = pixel_grid(W, H, supersample)
        rays, valid = pixel_rays(model, q)
        buf = io.BytesIO()
        np.savez_compressed(buf, origins=np.asarray(rays.origins, np.float32),
                            directions=np.asarray(rays.directions, np.float32), valid=valid,
                            q=q.astype(np.float32), T_rig_cam=T_rig_cam_of(model),
                            imagersize=np.array([W, H], np.int64))
        p = out / f"{cam}.npz"
        atomic_write_bytes(p, buf.getvalue())
        written.append(p)
    return written


def read_ray_table(path: str | os.PathLike) -> tuple[RayBundle, np.ndarray, np.ndarray]:
    """One camera's ray table: (rays (H, W, S) in the rig frame, valid (H, W, S), q (H, W, S, 2))."""
    path = Path(path)
    try:
        with np.load(path, allow_pickle=False) as z:
            o, d, v, q = z["origins"], z["directions"], z["valid"], z["q"]
    except FileNotFoundError:
        raise FormatError(path, "no such ray table") from None
    except (KeyError, ValueError, OSError) as e:
        raise FormatError(path, f"not a polycam ray table ({e})") from None
    if o.shape != d.shape or o.shape[-1] != 3 or v.shape != o.shape[:-1] or q.shape[:-1] != v.shape:
        raise FormatError(path, "inconsistent array shapes in the ray table")
    return RayBundle(o.astype(float), d.astype(float), frame="rig"), v.astype(bool), q.astype(float)
