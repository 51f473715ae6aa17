"""The two-plane light field: faces, sample grids and ray generation (SPEC.md, paper Sect. 4).

A light field has one or more faces. Face k has a rotation ``R_rig_face``
(columns = the face's axes in rig coordinates), a focal-plane offset ``z_pi``
[m] and a plane separation ``f`` (same unit as u, v). In face coordinates the
sample ``(x, y, u, v)`` is the ray with origin ``(x, y, z_pi)`` and direction
``(u, v, f) / |(u, v, f)|``. Arrays are indexed ``L[t, face, y, x, v, u]``.
See docs/conventions.md.
"""

from __future__ import annotations

import functools
import math
import os
from dataclasses import dataclass

import numpy as np

from .errors import FormatError, InputError
from .rays import RayBundle
from .tomlio import Table, load_toml

__all__ = [
    "FACE_NAMES",
    "R_rig_face_for",
    "Face",
    "Axis",
    "LightFieldGrid",
    "load_grid",
    "MAX_GRID_SAMPLES",
    "finite_frame",
]

FACE_NAMES = ("+z", "-z", "+x", "-x", "+y", "-y")


def R_rig_face_for(name: str) -> np.ndarray:
    """The rotation ``R_rig_face`` (3, 3) of a nested-cube face by name.

    Each face's z axis points along its name (``+x`` looks along rig +x); its
    y axis is rig +y for the four side faces (so images stay upright for a
    y-down rig) and rig +z / -z for the ``-y`` / ``+y`` faces. All are proper
    rotations (det = +1).
    """
    z = {"+z": (0, 0, 1), "-z": (0, 0, -1), "+x": (1, 0, 0), "-x": (-1, 0, 0),
         "+y": (0, 1, 0), "-y": (0, -1, 0)}
    y = {"+z": (0, 1, 0), "-z": (0, 1, 0), "+x": (0, 1, 0), "-x": (0, 1, 0),
         "+y": (0, 0, -1), "-y": (0, 0, 1)}
    if name not in z:
        raise ValueError(f"unknown face {name!r}; expected one of {' '.join(FACE_NAMES)}")
    zz = np.array(z[name], float)
    yy = np.array(y[name], float)
    xx = np.cross(yy, zz)
    return np.stack([xx, yy, zz], axis=1)


@dataclass(frozen=True, eq=False)
class Face:
    """One two-plane face of a light field."""

    name: str
    """Face name, ``+z -z +x -x +y -y`` for the nested cube (free text otherwise)."""
    R_rig_face: np.ndarray
    """(3, 3) rotation; columns are the face's x, y, z axes in rig coordinates."""
    z_pi: float
    """[m] offset of the focal plane Π along the face's z axis."""
    f: float
    """Separation of the (u, v) plane from the focal plane, in the units of u and v."""

    @classmethod
    def cube(cls, name: str, z_pi: float, f: float) -> "Face":
        return cls(name, R_rig_face_for(name), float(z_pi), float(f))

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, Face):
            return NotImplemented
        return (self.name == other.name and self.z_pi == other.z_pi and self.f == other.f
                and np.array_equal(np.asarray(self.R_rig_face), np.asarray(other.R_rig_face)))

    __hash__ = None  # mutable array inside

    def to_attrs(self) -> dict:
        return {"name": self.name, "R_rig_face": np.asarray(self.R_rig_face).tolist(),
                "z_pi": float(self.z_pi), "f": float(self.f)}


@dataclass(frozen=True)
class Axis:
    """A regular, increasing 1-D sample axis ``min + i * step``, ``i < count``."""

    min: float
    max: float
    count: int

    @functools.cached_property
    def values(self) -> np.ndarray:
        """(count,) sample coordinates (read-only: computed once, shared by every caller)."""
        v = np.linspace(self.min, self.max, self.count)
        v.flags.writeable = False
        return v

    @property
    def step(self) -> float:
        return (self.max - self.min) / (self.count - 1) if self.count > 1 else 0.0

    @classmethod
    def from_values(cls, values, where: str = "axis") -> "Axis":
        v = np.asarray(values, dtype=float)
        if v.ndim != 1 or v.size < 1 or not np.all(np.isfinite(v)):
            raise ValueError(f"{where}: expected a non-empty 1-D list of finite numbers")
        if v.size > 1:
            d = np.diff(v)
            if np.any(d <= 0) or np.ptp(d) > 1e-6 * max(abs(d[0]), 1e-12) + 1e-12:
                raise ValueError(f"{where}: samples must be regularly spaced and increasing")
        return cls(float(v[0]), float(v[-1]), int(v.size))


@dataclass(frozen=True)
class LightFieldGrid:
    """Where a light field is sampled: its faces and the shared (x, y, u, v) axes.

    A grid with ``F`` faces gives arrays of dims ``(F, Ny, Nx, Nv, Nu)`` per frame.
    """

    faces: tuple[Face, ...]
    x: Axis
    """[m] focal-plane positions (columns of the viewpoint grid)."""
    y: Axis
    """[m] focal-plane positions (rows of the viewpoint grid)."""
    u: Axis
    """Direction-plane coordinates, in the unit of f."""
    v: Axis
    """Direction-plane coordinates, in the unit of f."""

    @property
    def shape(self) -> tuple[int, int, int, int, int]:
        """``(F, Ny, Nx, Nv, Nu)``."""
        return (len(self.faces), self.y.count, self.x.count, self.v.count, self.u.count)

    @property
    def single_view_axis(self) -> str:
        """"x" or "y" for a linear array (one viewpoint along that axis, several along the
        other: a row or column of cameras), else "" (a 2-D array, or one viewpoint)."""
        if (self.x.count == 1) == (self.y.count == 1):
            return ""
        return "x" if self.x.count == 1 else "y"

    @property
    def num_rays(self) -> int:
        return int(np.prod(self.shape))

    def face_rays(self, k: int) -> RayBundle:
        """Rays of face ``k`` in the rig frame, dims (Ny, Nx, Nv, Nu, 3)."""
        face = self.faces[k]
        ys, xs, vs, us = np.meshgrid(self.y.values, self.x.values, self.v.values, self.u.values,
                                     indexing="ij")
        o = np.stack([xs, ys, np.full_like(xs, face.z_pi)], axis=-1)
        d = np.stack([us, vs, np.full_like(us, face.f)], axis=-1)
        d /= np.linalg.norm(d, axis=-1, keepdims=True)
        R = np.asarray(face.R_rig_face, float)
        return RayBundle(o @ R.T, d @ R.T, frame="rig")

    def rays(self) -> RayBundle:
        """Rays of every face in the rig frame, dims (F, Ny, Nx, Nv, Nu, 3)."""
        bundles = [self.face_rays(k) for k in range(len(self.faces))]
        return RayBundle(np.stack([b.origins for b in bundles]),
                         np.stack([b.directions for b in bundles]), frame="rig")

    def attrs(self) -> dict:
        """The grid as SPEC.md light-field store attributes."""
        return {"faces": [f.to_attrs() for f in self.faces],
                "x": self.x.values.tolist(), "y": self.y.values.tolist(),
                "u": self.u.values.tolist(), "v": self.v.values.tolist()}

    @classmethod
    def cube(cls, faces: list[str] | tuple[str, ...], *, f: float, z_pi: float,
             x: Axis, y: Axis, u: Axis, v: Axis) -> "LightFieldGrid":
        """A grid on named nested-cube faces, all with the same ``f`` and ``z_pi``."""
        return cls(tuple(Face.cube(n, z_pi, f) for n in faces), x, y, u, v)


MAX_GRID_SAMPLES = 2**30
"""The most samples per frame a ``GRID.toml`` may ask for: a float32 frame of 4 GiB, of which the motion
solver keeps about five copies at work (docs/motion.md, "Speed and memory"); catches a mistyped count
before anything allocates it."""


def load_grid(path: str | os.PathLike) -> LightFieldGrid:
    """Read a ``GRID.toml`` (SPEC.md): ``[grid]`` with ``f``, ``z_pi``, ``faces``,
    and ``x``, ``y``, ``u``, ``v`` each ``[min, max, count]``."""
    doc = load_toml(path)
    top = Table(path, "", doc)
    g = top.subtable("grid")
    top.finish()
    f = g.number("f", min=0.0, open_min=True)
    z_pi = g.number("z_pi")
    names = g.get("faces", list)
    if not names or not all(isinstance(n, str) for n in names):
        raise g.error("faces", f"expected a non-empty list of face names, got {names!r}")
    for n in names:
        if n not in FACE_NAMES:
            raise g.error("faces", f"unknown face {n!r}; expected some of {' '.join(FACE_NAMES)}")
    if len(set(names)) != len(names):
        raise g.error("faces", "a face is listed twice")
    axes = {}
    for key in ("x", "y", "u", "v"):
        lo, hi, n = g.vector(key, 3)
        if n != int(n) or n < 1:
            raise g.error(key, f"count must be an integer >= 1, got {n}")
        if n > 1 and not hi > lo:
            raise g.error(key, f"expected [min, max, count] with max > min, got {[lo, hi, n]}")
        if n == 1 and hi != lo:
            raise g.error(key, f"one sample (count 1) needs min = max, got {[lo, hi, n]}")
        axes[key] = Axis(lo, hi, int(n))
    g.finish()
    samples = len(names) * math.prod(a.count for a in axes.values())
    if samples > MAX_GRID_SAMPLES:
        raise FormatError(path, f"{samples} samples per frame (faces x x, y, u, v counts); at most "
                                f"{MAX_GRID_SAMPLES} (2^30: 4 GiB a float32 frame)", "[grid]")
    return LightFieldGrid.cube(names, f=f, z_pi=z_pi, **axes)


def _check_faces_attr(path, faces) -> tuple[Face, ...]:
    """Faces from store attributes (used by the store reader): each a rotation, finite ``z_pi``,
    finite ``f > 0``, a name given once; a nested-cube name (:data:`FACE_NAMES`) with that face's
    rotation (other names may have any rotation: SPEC.md names only the cube's)."""
    out = []
    if not isinstance(faces, list) or not faces:
        raise FormatError(path, "expected a non-empty list", "attrs.faces")
    for i, fa in enumerate(faces):
        where = f"attrs.faces[{i}]"
        if not isinstance(fa, dict) or set(fa) != {"name", "R_rig_face", "z_pi", "f"}:
            raise FormatError(path, 'expected {"name", "R_rig_face", "z_pi", "f"}', where)
        R = np.asarray(fa["R_rig_face"], dtype=float) if isinstance(fa["R_rig_face"], list) else None
        if R is None or R.shape != (3, 3) or not np.allclose(R @ R.T, np.eye(3), atol=1e-6) \
                or np.linalg.det(R) < 0:
            raise FormatError(path, "R_rig_face must be a 3x3 rotation", where)
        for key in ("z_pi", "f"):
            if not isinstance(fa[key], (int, float)) or isinstance(fa[key], bool) or not math.isfinite(fa[key]):
                raise FormatError(path, f"{key} must be a finite number", where)
        if fa["f"] <= 0:
            raise FormatError(path, "f must be > 0", where)
        name = fa["name"]
        if not isinstance(name, str) or not name.strip():
            raise FormatError(path, f"name must be a non-empty string, got {name!r}", where)
        if any(o.name == name for o in out):
            raise FormatError(path, f"a second face named {name!r}", where)
        if name in FACE_NAMES and not np.allclose(R, R_rig_face_for(name), atol=1e-6):
            raise FormatError(path, f"R_rig_face is not the rotation of the cube face {name!r} (SPEC.md)", where)
        out.append(Face(name, R, float(fa["z_pi"]), float(fa["f"])))
    return tuple(out)


def finite_frame(name: str, L: np.ndarray, W: np.ndarray | None = None, who: str = "") -> np.ndarray:
    """``L`` (any dims) itself when every sample is finite. Non-finite samples are an
    :class:`~polycam.errors.InputError` (``who``: ``name``: ...) unless the confidence ``W``
    (``L``'s dims, or without ``L``'s trailing colour axis; None: no confidences) is 0 at
    each of them; then a copy of ``L`` with them set to 0 (samples without data:
    docs/formats.md, the light-field store)."""
    L = np.asarray(L)
    if np.isfinite(L).all():
        return L
    bad = ~np.isfinite(L)
    w = None if W is None else np.asarray(W)
    if w is not None and w.ndim == L.ndim - 1:        # a colour frame: one W for its channels
        w = w[..., None]
    if w is None or np.any(bad & (w > 0)):
        raise InputError(f"{who + ': ' if who else ''}{name} contains NaN or infinite samples where the "
                         "confidence W is not 0; mask them with W = 0")
    return np.where(bad, np.zeros((), L.dtype), L)
