"""The rules that choose a two-plane light-field grid for a set of cameras.

One place for them: the resample stage's automatic grid
(:func:`resample.grid.auto_grid`, docs/resample.md) and the rig design study
(:func:`polycam.design.design_grid`, docs/design.md) both call
:func:`choose_grid`. The rules (SPEC.md "Two-plane light field"):

- faces: the nested-cube faces the cameras' optical axes point into (one face,
  ``+z``, for a forward-looking planar array), unless given;
- ``z_pi``: the median distance of the camera centres from the rig origin along
  the normal of the face each camera looks into, so the focal plane passes
  through the cameras and a camera sits at a viewpoint ``(x, y)``;
- ``x``, ``y``: through the columns (rows) of camera centres on the faces, a
  viewpoint per column and ``xy_oversample`` steps per column interval, the start
  and step fitted to the cameras by least squares (:func:`axis_through_columns`;
  columns are centres closer than half the median nearest-neighbour spacing):
  a regular array's cameras land on viewpoints, a perturbed one's within their
  position errors, and ``xy_oversample`` = 2 adds one half-way;
- ``u``, ``v``: the union over the cameras of their viewing directions
  projected on every face, at most :data:`MAX_SIDE_DEG` off the normal with one
  face and 45 deg with several (faces do not overlap), leaving out a camera's
  strip along the edge of a face it only grazes (:data:`EDGE_GRAZE_TAN`), in units of the grid's
  ``f`` (the caller's choice: camera pixels for resampling, degrees for design),
  rounded outwards to whole samples.

Pure functions of geometry (rig frame, metres); no file I/O.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from .errors import InputError
from .lightfield import FACE_NAMES, Axis, LightFieldGrid, R_rig_face_for

__all__ = [
    "MAX_SIDE_DEG",
    "EDGE_GRAZE_TAN",
    "GridChoice",
    "face_of_direction",
    "camera_spacing",
    "column_spacing",
    "axis_from_range",
    "axis_through_columns",
    "max_side_tan",
    "choose_grid",
]

MAX_SIDE_DEG = 70.0
"""With a single face, directions more than this off the face normal are not gridded
(tan grows without bound; a 140 deg wide face is already far beyond useful)."""


EDGE_GRAZE_TAN = 0.07
"""A camera's directions on a face other than the one its optical axis points into count towards
the face's (u, v) extent only if some reach further than this (in tan units, about 2 deg at a
face's 45-deg edge) inside the face's edge. A nested cube's cameras whose horizontal field of view
ends at the face edge tip a strip of their rays over it by their mounting errors: on `polycam run`'s
cube (0.3 deg) that strip alone stretched every face's v from ±0.79 to ±1, a quarter more directions
with no data (docs/resample.md, "The automatic grid")."""


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


def _columns(coords: np.ndarray, spacing: float) -> list[np.ndarray]:
    """Sorted camera coordinates (N,) [m] split into columns: coordinates closer than half
    ``spacing`` [m] are one column."""
    c = np.sort(np.asarray(coords, float).ravel())
    return np.split(c, np.flatnonzero(np.diff(c) > 0.5 * spacing) + 1)


def column_spacing(coords: np.ndarray, spacing: float) -> float:
    """[m] spacing of the camera columns (or rows) along one axis.

    coords: (N,) [m] camera coordinates along the axis; spacing: [m] the nearest-neighbour
    camera spacing. Coordinates closer than half ``spacing`` are one column; the result is
    the median gap between consecutive column centres (``spacing`` when there is one
    column). Unlike the nearest-neighbour distance, which small position errors bias low
    (the minimum over several neighbours), this keeps a perturbed regular array's
    cameras on viewpoints.
    """
    if spacing <= 0 or np.asarray(coords).size < 2:
        return spacing
    centres = np.array([g.mean() for g in _columns(coords, spacing)])
    return float(np.median(np.diff(centres))) if centres.size > 1 else spacing


def axis_from_range(lo: float, hi: float, spacing: float, oversample: int) -> Axis:
    """A regular axis from lo to hi with ``oversample`` steps per camera interval: the number
    of camera intervals is ``round((hi - lo) / spacing)`` so that a regular array's cameras
    land on viewpoints (count 1 at the middle if the range is empty or below half a spacing)."""
    span = hi - lo
    if spacing <= 0 or span <= 1e-9 or span < 0.5 * spacing:
        mid = 0.5 * (lo + hi)
        return Axis(mid, mid, 1)
    n = max(int(round(span / spacing)), 1) * oversample + 1
    return Axis(float(lo), float(hi), n)


def axis_through_columns(coords: np.ndarray, spacing: float, oversample: int) -> Axis:
    """A regular axis through the camera columns (or rows) along one axis, ``oversample``
    steps per camera interval.

    coords: (N,) [m] camera coordinates along the axis; spacing: [m] the nearest-neighbour
    camera spacing. The columns (:func:`column_spacing`) are numbered by their distance from
    the first in column spacings, and the axis's start and camera interval are the least-squares
    fit of every camera's coordinate to its column's viewpoint. A regular array's axis is then its
    exact range; a perturbed one's cameras sit on their viewpoints to within their own position
    errors. The range of the extreme cameras (:func:`axis_from_range`, the rule before session 45)
    stretched the axis by the extreme position errors: on ``polycam run``'s nested cube (1 mm std,
    18 cameras per outer column) by 6 %, so each view's data came from a viewpoint 6 % closer to
    the centre than its coordinate said, and the motion's translation came out 2 % long
    (docs/resample.md, "The automatic grid"). Falls back to :func:`axis_from_range` where the
    cameras do not form columns (a chain of cameras closer than half ``spacing``)."""
    c = np.asarray(coords, float).ravel()
    lo, hi = float(c.min()), float(c.max())
    if spacing <= 0 or hi - lo <= 1e-9 or hi - lo < 0.5 * spacing:
        return axis_from_range(lo, hi, spacing, oversample)
    cols = _columns(c, spacing)
    centres = np.array([g.mean() for g in cols])
    if centres.size < 2:
        return axis_from_range(lo, hi, spacing, oversample)
    step0 = float(np.median(np.diff(centres)))
    k_col = np.round((centres - centres[0]) / step0)
    k = np.concatenate([np.full(g.size, kc) for g, kc in zip(cols, k_col)])
    x = np.concatenate(cols)
    A = np.stack([np.ones_like(k), k], axis=1)
    (start, step), *_ = np.linalg.lstsq(A, x, rcond=None)
    n_int = int(k_col[-1])
    end = start + step * n_int
    # a regular array: its exact range (the fit reproduces it to rounding)
    if abs(start - lo) < 1e-12 and abs(end - hi) < 1e-12:
        start, end = lo, hi
    return Axis(float(start), float(end), n_int * oversample + 1)


def max_side_tan(n_faces: int) -> float:
    """Largest |u / f|, |v / f| gridded: tan 45 deg with several faces, tan MAX_SIDE_DEG with one."""
    return 1.0 if n_faces > 1 else math.tan(math.radians(MAX_SIDE_DEG))


@dataclass(frozen=True)
class GridChoice:
    """A grid chosen for a set of cameras and what it was chosen from."""

    grid: LightFieldGrid
    own: np.ndarray
    """(N,) int: index into FACE_NAMES of the face each camera's optical axis points into."""
    spacing: float
    """[m] median nearest-neighbour camera spacing on the faces (0: one camera per face)."""


def choose_grid(centres: np.ndarray, optical_axes: np.ndarray, directions: Sequence[np.ndarray], f: float, *,
                xy_oversample: int = 2, faces: Sequence[str] | None = None, who: str = "resample") -> GridChoice:
    """The grid of the module rules for N cameras.

    centres: (N, 3) [m] camera centres in the rig frame; optical_axes: (N, 3) their
    optical axes (rig frame); directions: per camera an (n_i, 3) array of viewing
    directions in the rig frame spanning its field of view (non-finite rows ignored);
    f: the grid's focal length (u, v units per unit tan); faces: face names (default:
    the faces the optical axes point into); who: the prefix of error messages.
    Raises :class:`InputError` for an unknown face or when no camera looks into the faces.
    """
    centres = np.asarray(centres, float)
    own = face_of_direction(np.asarray(optical_axes, float))
    if faces is None:
        faces = [FACE_NAMES[i] for i in sorted(set(own.tolist()))]
    faces = list(faces)
    for n in faces:
        if n not in FACE_NAMES:
            raise InputError(f"{who}: unknown face {n!r}; expected some of {' '.join(FACE_NAMES)}")
    max_tan = max_side_tan(len(faces))
    N = centres.shape[0]

    # z_pi: median distance of the centres along the normal of the face each camera looks into
    names_own = [FACE_NAMES[i] for i in own]
    depth = np.array([centres[i] @ R_rig_face_for(names_own[i])[:, 2] for i in range(N)])
    z_pi = float(np.median(depth))

    # x, y: camera centres in face coordinates, over all faces used
    xs, ys, steps = [], [], []
    for n in faces:
        c_face = centres @ R_rig_face_for(n)
        sel = [i for i in range(N) if names_own[i] == n] or list(range(N))
        xs.append(c_face[sel, 0])
        ys.append(c_face[sel, 1])
        steps.append(camera_spacing(c_face[sel, :2]))
    xs = np.concatenate(xs)
    ys = np.concatenate(ys)
    spacing = float(np.median([s for s in steps if s > 0])) if any(s > 0 for s in steps) else 0.0
    x_axis = axis_through_columns(xs, spacing, xy_oversample)
    y_axis = axis_through_columns(ys, spacing, xy_oversample)

    # u, v: union of the fields of view, in grid units
    lo = np.array([np.inf, np.inf])
    hi = -lo
    for i, d in enumerate(directions):
        d = np.asarray(d, float).reshape(-1, 3)
        d = d[np.all(np.isfinite(d), axis=1)]
        for n in faces:
            d_face = d @ R_rig_face_for(n)
            ok = d_face[:, 2] > 1e-6
            uv = d_face[ok, :2] / d_face[ok, 2:3]
            uv = uv[np.all(np.abs(uv) <= max_tan, axis=1)]
            if not uv.size:
                continue
            if n != names_own[i] and np.abs(uv).max(axis=1).min() > max_tan - EDGE_GRAZE_TAN:
                continue        # a strip along the face's edge: the camera only grazes this face
            lo = np.minimum(lo, uv.min(axis=0) * f)
            hi = np.maximum(hi, uv.max(axis=0) * f)
    if not np.all(np.isfinite(lo)):
        raise InputError(f"{who}: no camera looks into the chosen faces")
    u_axis = Axis(float(math.floor(lo[0])), float(math.ceil(hi[0])),
                  int(math.ceil(hi[0]) - math.floor(lo[0])) + 1)
    v_axis = Axis(float(math.floor(lo[1])), float(math.ceil(hi[1])),
                  int(math.ceil(hi[1]) - math.floor(lo[1])) + 1)
    grid = LightFieldGrid.cube(faces, f=f, z_pi=z_pi, x=x_axis, y=y_axis, u=u_axis, v=v_axis)
    return GridChoice(grid=grid, own=own, spacing=spacing)
