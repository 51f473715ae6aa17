"""Choosing a two-plane grid for a rig from its calibration (``polycam resample`` without ``--grid``).

The grid follows the cameras (SPEC.md "Two-plane light field", docs/resample.md):

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
import math

import numpy as np

from polycam.cameras import T_rig_cam_of, camera_rays
from polycam.errors import InputError
from polycam.lightfield import FACE_NAMES, Axis, LightFieldGrid, R_rig_face_for

__all__ = ["auto_grid", "face_of_direction", "camera_spacing"]

log = logging.getLogger(__name__)

_MAX_SIDE_DEG = 70.0
"""With a single face, directions more than this off the face normal are not gridded
(tan grows without bound; a 140 deg wide face is already far beyond useful)."""


def face_of_direction(d_rig: np.ndarray) -> np.ndarray:
    """Index into :data:`~polycam.lightfield.FACE_NAMES` of the cube face each direction
    points into (the largest face-normal component). d_rig: (..., 3) → (...,) int."""
    normals = np.stack([R_rig_face_for(n)[:, 2] for n in FACE_NAMES])      # (6, 3)
    return np.argmax(np.asarray(d_rig, float) @ normals.T, axis=-1)


def camera_spacing(centres: np.ndarray) -> float:
    """Median distance [m] from each camera centre (N, 2) or (N, 3) to its nearest
    neighbour (0 for fewer than two cameras)."""
    c = np.asarray(centres, float)
    if c.shape[0] < 2:
        return 0.0
    d = np.linalg.norm(c[:, None, :] - c[None, :, :], axis=-1)
    np.fill_diagonal(d, np.inf)
    return float(np.median(d.min(axis=1)))


def _axis_from_range(lo: float, hi: float, spacing: float, oversample: int) -> Axis:
    """A regular axis from lo to hi with ``oversample`` steps per camera interval: the number
    of camera intervals is ``round((hi - lo) / spacing)`` so that a regular array's cameras
    land on viewpoints (count 1 if the range is empty)."""
    span = hi - lo
    if spacing <= 0 or span <= 1e-9 or span < 0.5 * spacing:
        mid = 0.5 * (lo + hi)
        return Axis(mid, mid, 1)
    n = max(int(round(span / spacing)), 1) * oversample + 1
    return Axis(float(lo), float(hi), n)


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
    centres = T[:, :3, 3]
    axes = T[:, :3, 2]                                                    # optical axes in the rig
    own = face_of_direction(axes)                                         # (N,)
    if faces is None:
        faces = [FACE_NAMES[i] for i in sorted(set(own.tolist()))]
    for n in faces:
        if n not in FACE_NAMES:
            raise InputError(f"resample: unknown face {n!r}; expected some of {' '.join(FACE_NAMES)}")
    fx = np.array([float(models[c].intrinsics()[1][0]) for c in ids])
    f = float(np.median(fx)) / float(uv_step_px)
    max_tan = 1.0 if len(faces) > 1 else math.tan(math.radians(_MAX_SIDE_DEG))

    # z_pi: median distance of the centres along the normal of the face each camera looks into
    names_own = [FACE_NAMES[i] for i in own]
    depth = np.array([centres[i] @ R_rig_face_for(names_own[i])[:, 2] for i in range(len(ids))])
    z_pi = float(np.median(depth))

    # x, y: camera centres in face coordinates, over all faces used
    xs, ys, steps = [], [], []
    for n in faces:
        R = R_rig_face_for(n)
        c_face = centres @ R
        sel = [i for i in range(len(ids)) if names_own[i] == n] or list(range(len(ids)))
        xs.append(c_face[sel, 0])
        ys.append(c_face[sel, 1])
        steps.append(camera_spacing(c_face[sel, :2]))
    xs = np.concatenate(xs)
    ys = np.concatenate(ys)
    spacing = float(np.median([s for s in steps if s > 0])) if any(s > 0 for s in steps) else 0.0
    x_axis = _axis_from_range(float(xs.min()), float(xs.max()), spacing, xy_oversample)
    y_axis = _axis_from_range(float(ys.min()), float(ys.max()), spacing, xy_oversample)
    step_xy = max(x_axis.step, y_axis.step)

    # u, v: union of the fields of view, in grid pixels
    lo = np.array([np.inf, np.inf])
    hi = -lo
    for c in ids:
        m = models[c]
        W, H = (int(v) for v in m.imagersize())
        qx = np.unique(np.r_[np.arange(0, W, rays_stride), W - 1]).astype(float)
        qy = np.unique(np.r_[np.arange(0, H, rays_stride), H - 1]).astype(float)
        q = np.stack(np.meshgrid(qx, qy, indexing="xy"), axis=-1)
        d = camera_rays(m, q).directions.reshape(-1, 3)
        d = d[np.all(np.isfinite(d), axis=1)]
        for n in faces:
            d_face = d @ R_rig_face_for(n)
            ok = d_face[:, 2] > 1e-6
            uv = d_face[ok, :2] / d_face[ok, 2:3]
            uv = uv[np.all(np.abs(uv) <= max_tan, axis=1)]
            if uv.size:
                lo = np.minimum(lo, uv.min(axis=0) * f)
                hi = np.maximum(hi, uv.max(axis=0) * f)
    if not np.all(np.isfinite(lo)):
        raise InputError("resample: no camera looks into the chosen faces")
    u_axis = Axis(float(math.floor(lo[0])), float(math.ceil(hi[0])),
                  int(math.ceil(hi[0]) - math.floor(lo[0])) + 1)
    v_axis = Axis(float(math.floor(lo[1])), float(math.ceil(hi[1])),
                  int(math.ceil(hi[1]) - math.floor(lo[1])) + 1)
    grid = LightFieldGrid.cube(list(faces), f=f, z_pi=z_pi, x=x_axis, y=y_axis, u=u_axis, v=v_axis)
    log.info("auto grid: faces %s, %dx%d views (step %.4g m), %dx%d directions (f %.4g), z_pi %.4g m",
             " ".join(faces), y_axis.count, x_axis.count, step_xy, v_axis.count, u_axis.count, f, z_pi)
    return grid
