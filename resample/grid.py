"""Choosing a two-plane grid for a rig from its calibration (``polycam resample`` without ``--grid``).

The grid follows the cameras (SPEC.md "Two-plane light field", docs/resample.md)
by the rules of :mod:`polycam.gridrules` (shared with the rig design study):

- faces: the nested-cube faces the cameras' optical axes point into (one face,
  ``+z``, for a forward-looking planar array);
- ``z_pi``: the median distance of the camera centres from the rig origin along
  their face's normal, so the focal plane passes through the cameras and a
  camera sits at a viewpoint ``(x, y)``;
- ``x``, ``y``: from the smallest to the largest camera-centre coordinate, with a
  step of the median nearest-neighbour camera spacing divided by
  ``xy_oversample`` (2: a viewpoint at every camera and one half-way between);
- ``u``, ``v``: the union of the cameras' fields of view on the face (at most
  45 deg off the face normal when there are several faces, so faces do not
  overlap), with ``f`` set to the median focal length in pixels divided by
  ``uv_step_px``: one (u, v) step is ``uv_step_px`` camera pixels at the image
  centre, and u, v are in those grid-pixel units.

All functions take cameramodels whose reference frame is the rig
(``rt_cam_ref = T_cam_rig``, docs/conventions.md). No file I/O.
"""

from __future__ import annotations

import logging

import numpy as np

from polycam.cameras import T_rig_cam_of, camera_rays
from polycam.errors import InputError
from polycam.gridrules import camera_spacing, choose_grid, face_of_direction
from polycam.lightfield import LightFieldGrid

__all__ = ["auto_grid", "face_of_direction", "camera_spacing"]

log = logging.getLogger(__name__)


def auto_grid(models: dict, *, uv_step_px: float = 1.0, xy_oversample: int = 2,
              faces: list[str] | None = None, rays_stride: int = 4) -> LightFieldGrid:
    """A light-field grid for cameras ``models`` (camera id → mrcal cameramodel, rig frame).

    uv_step_px: (u, v) sample spacing in camera pixels at the image centre (median focal
        length over the cameras); 1 keeps the cameras' angular resolution.
    xy_oversample: viewpoints per median camera spacing along x and y.
    faces: face names to use (default: the faces the optical axes point into).
    rays_stride: the field of view is measured on every ``rays_stride``-th pixel (and
        the image border), which is plenty for the extent.
    """
    if not models:
        raise InputError("resample: no camera models to build a grid from")
    if uv_step_px <= 0 or xy_oversample < 1:
        raise ValueError("uv_step_px must be > 0 and xy_oversample >= 1")
    ids = list(models)
    T = np.stack([T_rig_cam_of(models[c]) for c in ids])                  # (N, 4, 4)
    fx = np.array([float(models[c].intrinsics()[1][0]) for c in ids])
    f = float(np.median(fx)) / float(uv_step_px)
    dirs = []
    for c in ids:
        m = models[c]
        W, H = (int(v) for v in m.imagersize())
        qx = np.unique(np.r_[np.arange(0, W, rays_stride), W - 1]).astype(float)
        qy = np.unique(np.r_[np.arange(0, H, rays_stride), H - 1]).astype(float)
        q = np.stack(np.meshgrid(qx, qy, indexing="xy"), axis=-1)
        dirs.append(camera_rays(m, q).directions.reshape(-1, 3))
    grid = choose_grid(T[:, :3, 3], T[:, :3, 2], dirs, f, xy_oversample=xy_oversample, faces=faces,
                       who="resample").grid
    step_xy = max(grid.x.step, grid.y.step)
    log.info("auto grid: faces %s, %dx%d views (step %.4g m), %dx%d directions (f %.4g), z_pi %.4g m",
             " ".join(f.name for f in grid.faces), grid.y.count, grid.x.count, step_xy, grid.v.count,
             grid.u.count, f, grid.faces[0].z_pi)
    return grid
