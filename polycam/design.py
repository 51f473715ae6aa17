"""Rig design study: how well each camera rig can measure its own motion (paper Sect. 1, 3, Fig. 3).

For a candidate rig (any rig file) this module builds the light field the
pipeline would build from it, renders representative frame pairs of a
synthetic scene, and answers, per frame pair:

- **predicted** 1-σ errors of translation and rotation at a given image noise,
  from the linear system the plenoptic solver (:mod:`polycam.motion`) solves
  (paper Eq. 5), with the sensor noise propagated through the derivative
  filters;
- **measured** errors of the real solver (:func:`polycam.motion.estimate_motion`)
  on noisy renderings of the same pairs;
- the **weakly observable** motion directions (eigenvectors of the covariance),
  with the classical rotation–translation ambiguity of small fields of view
  named as such, and a clear **unobservable** verdict where the data cannot fix
  a direction at all.

No file I/O: :mod:`polycam.design_report` writes the CSV tables and plots and
:mod:`polycam.design_cli` is the ``polycam design`` verb. Frames and units:
docs/conventions.md; the method and its limits: docs/design.md.

From a rig to a light field (the rig → grid choice)
---------------------------------------------------
The rules of the resample stage's automatic grid, shared through
:func:`polycam.gridrules.choose_grid`: each camera belongs to the nested-cube
face its optical axis points into; ``z_pi`` is the median distance of the camera
centres along their face normal; ``x``, ``y`` run over the camera centres in face
coordinates with ``xy_oversample`` steps per median camera spacing; ``u``, ``v``
span the union of the cameras' fields of view (at most 45 deg off the normal with
several faces). One difference: the directions are sampled every ``uv_step_deg``
(grid ``f = 1 / tan(uv_step_deg)``, not every camera pixel) so that
many designs can be compared quickly; a grid sample then stands for a block of
``k x k`` camera pixels (k = camera focal length in pixels / grid ``f``) and
carries the noise of their mean, ``σ / k``. This keeps the information of
texture resolved at the grid scale and ignores finer texture (a conservative
estimate for the full-resolution pipeline).

A viewpoint with a camera is rendered straight onto the grid rays (an ideal
resampling of that camera); a viewpoint between cameras (``xy_oversample`` > 1)
is the bilinear interpolation, at fixed ``(u, v)``, of the camera viewpoints
around it no more than one camera spacing apart, as push-pull would fill it,
with the noise interpolated alike; anything else has no data (``W = 0``).
Directions outside a camera's field of view have no data either. A single
camera is a light field with one viewpoint: no positional derivatives.

The predicted covariance (noise model)
--------------------------------------
The solver iterates warps until frame 2, resampled at the estimated motion,
matches frame 1; at that point its estimate solves the weighted normal
equations ``Σ w c (L_t + c·δ) = 0`` with ``c`` the Eq. 5 coefficients. Image
noise ``n0``, ``n1`` enters ``L_t = K P (n1 − n0)`` through the prefilter ``K`` of
every differentiated axis and the viewpoint interpolation ``P``, so

    Cov(p) = N⁺ (2 Σ_src σ² ‖(K P)ᵀ (w c)‖²) N⁺,      N = Σ w c cᵀ,

a sandwich that respects the correlation of filtered noise (the textbook
``σ² N⁻¹`` would be several times too small). ``c`` and ``L_t`` come from the
noise-free pair warped by the true motion; the weights ``w`` are the solver's:
data confidence and filter support inside the grid, the discontinuity weight of
the noisy frames' mean, and the robust (Tukey) part. The solver's IRLS converges to
the M-estimate ``Σ b c ψ(r) = 0`` (``b`` the other weights, ``ψ(r) = w(r) r``), so noise
moves it through ``ψ'`` at the model-error residual ``r`` left at the linearised
fixed point, at the robust scale of model error plus noise: the sandwich uses
``b ψ'(r)`` (``= b`` where the model error is small against the scale; smaller, even
negative, where it is not). The result is mapped from the ray motion the solver
solves for to the rig's ``(t, r)`` like the solver maps its own covariance.

Measured against the real solver (tests/test_design.py with 32 noise draws;
docs/design.md has the table): the scatter over noise draws is 0.95–1.06x the
prediction (std_t, std_w and the whitened 6x6 covariance) on a six-face and a
well-conditioned one-face design, and 1.1–1.2x on an ill-conditioned face (t~w
correlation −0.89) with model error above the noise. The systematic error —
the solver on the noise-free pair, :class:`DesignMeasurement` ``bias_*`` — is a
separate quantity: on one face it is often several times the noise σ
(interpolation error of the warp amplified along the weak t~w direction;
docs/design.md). Noise in the derivatives themselves and the noise dependence
of the discontinuity weights are left out (the ~1.2x left on the ill-conditioned
face comes with those weights: without them it matches to 5%; their first-order
noise response is negligible, so a non-linear one is the likely cause).

One viewpoint per face: the translation scale
---------------------------------------------
Without positional sampling the plenoptic model has no translation term at all
(``L_x = L_y = 0``); physically, translation then enters only through the
unknown depth: ``L_x = f L_u / Z`` (paper Eq. 6). For such rigs a second model
adds the depth: the positional derivatives are written ``ρ f (L_u, L_v)`` with
the true inverse depth ``ρ`` and one unknown relative inverse-depth correction
per patch of ``depth_patch x depth_patch`` directions, eliminated
(Frisch–Waugh–Lovell) before the same sandwich. For a central camera the
translation along the true motion ``t`` is then exactly unobservable — the
scale: ``(t, ρ) → (s t, ρ / s)`` changes nothing — while the translation
direction and the rotation get finite, honest errors (this is the classical
pinhole case of the paper's Fig. 3). The solver itself reports ``t_x t_y t_z``
unobservable for these rigs (``solver_unobservable``).
"""

from __future__ import annotations

import dataclasses
import logging
import math
from dataclasses import dataclass, field
from typing import Callable, Sequence

import numpy as np

from .derivatives import plenoptic_derivatives, smooth_all
from .errors import InputError
from .gridrules import choose_grid
from .geometry import R_from_r, T_from_Rt, T_inverse, r_from_R
from .lightfield import FACE_NAMES, Axis, LightFieldGrid, R_rig_face_for
from .motion import (PARAM_NAMES, MotionOptions, discontinuity_weight, estimate_motion, min_over_support,
                     ray_motion_coefficients, ray_to_rig_jacobian, robust_scale, robust_slope, robust_weight,
                     scaled_eigen, solver_filter_pairs, warp_lightfield)
from .rig import CameraSpec, MockSpec, Rig

__all__ = [
    "DesignOptions",
    "Source",
    "RigSampling",
    "design_grid",
    "SourceRenderer",
    "Direction",
    "DesignPrediction",
    "DesignMeasurement",
    "DesignResult",
    "pair_motions",
    "predict_pair",
    "measure_pairs",
    "analyse_covariance",
    "rig_features",
    "evaluate_rig",
    "design_study",
    "hierarchy_rigs",
    "single_camera_rig",
    "planar_array_rig",
    "cube_array_rig",
]

log = logging.getLogger(__name__)

_SNAP = 0.3
"""A camera centre within this fraction of a grid step (and of the spacing) of a viewpoint sits on it."""
_SCALE_FLOOR = 1e-5
"""Smallest robust residual scale [intensity], as in the solver."""


# ============================================================================ options


@dataclass(frozen=True)
class DesignOptions:
    """Settings of a design study (defaults: the ``polycam design`` defaults)."""

    scene: str = "room"
    """Synthetic scene: ``room`` or ``spheres`` (the same for every rig, so designs compare fairly)."""
    distance: float = 4.0
    """[m] scene distance (far wall of the room; nearest sphere surface)."""
    noise: float = 0.01
    """Grey-level noise std per camera pixel, [0, 1] units (0.01 ≈ 2.5 levels of 8 bits)."""
    step_t: float = 0.005
    """[m] translation of each representative frame pair (random direction)."""
    step_r_deg: float = 0.2
    """[deg] rotation of each representative frame pair (random axis)."""
    pairs: int = 3
    """Representative frame pairs per rig (the prediction uses the first)."""
    draws: int = 3
    """Noise draws per pair for the measured errors."""
    measure: bool = True
    """Run the real solver on noisy renderings (else predictions only: fast)."""
    uv_step_deg: float = 1.5
    """[deg] direction sampling of the design grid at the face centre (f = 1 / tan)."""
    xy_oversample: int = 2
    """Viewpoints per camera spacing along x and y (2, as the resample stage)."""
    supersample: int = 2
    """k: each grid sample averages k x k rays over its (u, v) cell."""
    depth_patch: int = 8
    """(u, v) patch side [samples] with one unknown inverse depth (one-viewpoint rigs)."""
    sweep: tuple[float, ...] = ()
    """Scene distances [m] at which to repeat the prediction (error against distance)."""
    seed: int = 0
    """Seed of the scene, the pair motions and the noise (the same for every rig)."""
    solver: MotionOptions = field(default_factory=MotionOptions)
    """The plenoptic solver's settings (the prediction mirrors its weights and filters)."""

    def __post_init__(self) -> None:
        if self.scene not in ("room", "spheres"):
            raise InputError(f"design: scene must be room or spheres, got {self.scene!r}")
        for name in ("distance", "uv_step_deg"):
            if not getattr(self, name) > 0:
                raise InputError(f"design: {name} must be > 0, got {getattr(self, name)}")
        if self.noise < 0 or self.step_t < 0 or self.step_r_deg < 0:
            raise InputError("design: noise, step_t and step_r_deg must be >= 0")
        if self.pairs < 1 or self.draws < 1 or self.xy_oversample < 1 or self.supersample < 1 \
                or self.depth_patch < 2:
            raise InputError("design: pairs, draws, xy_oversample, supersample must be >= 1 and "
                             "depth_patch >= 2")
        if any(not d > 0 for d in self.sweep):
            raise InputError(f"design: sweep distances must be > 0, got {list(self.sweep)}")


# ============================================================================ rig → light-field grid


@dataclass(frozen=True)
class Source:
    """A camera placed on a grid viewpoint: the light field there is its image."""

    camera: str
    """Camera id."""
    face: int
    """Index of the face (into the grid's faces) the camera looks into."""
    jy: int
    """Row of the viewpoint (index into the grid's y axis)."""
    ix: int
    """Column of the viewpoint (index into the grid's x axis)."""
    binning: float
    """Camera pixels per grid sample along an axis at the image centre (noise of a sample: σ / max(1, binning))."""


@dataclass(frozen=True, eq=False)
class RigSampling:
    """How a rig's cameras fill a two-plane light-field grid (see the module docstring)."""

    grid: LightFieldGrid
    sources: tuple[Source, ...]
    """Cameras on viewpoints, grouped by face (face 0 first)."""
    P: tuple[np.ndarray, ...]
    """Per face k: (Ny*Nx, n_k) interpolation from that face's sources (in order) to every
    viewpoint (row-major over y, x); identity rows at camera viewpoints."""
    masks: np.ndarray
    """(n_src, Nv, Nu) bool: grid directions inside each source camera's field of view."""
    W: np.ndarray
    """(F, Ny, Nx, Nv, Nu) float32 in {0, 1}: samples with data."""
    spacing: float
    """[m] median nearest-neighbour camera spacing (0 for one camera per face)."""
    skipped: tuple[str, ...] = ()
    """Cameras that could not be placed on a viewpoint (off the regular lattice)."""

    @property
    def face_slices(self) -> list[slice]:
        """Per face, the slice of :attr:`sources` on it."""
        out, start = [], 0
        for k in range(len(self.grid.faces)):
            n = sum(1 for s in self.sources if s.face == k)
            out.append(slice(start, start + n))
            start += n
        return out

    @property
    def has_positional(self) -> bool:
        """Whether some face has data at two or more viewpoints along x or y (an array)."""
        return any(len({(s.jy, s.ix) for s in self.sources if s.face == k}) >= 2
                   for k in range(len(self.grid.faces)))

    @property
    def all_data(self) -> bool:
        return bool(self.W.min() > 0)

    def assemble(self, src: np.ndarray) -> np.ndarray:
        """The light field (F, Ny, Nx, Nv, Nu) float32 from per-source images src (n_src, Nv, Nu)."""
        F, Ny, Nx, Nv, Nu = self.grid.shape
        out = np.zeros((F, Ny, Nx, Nv, Nu), np.float32)
        for k, sl in enumerate(self.face_slices):
            if sl.stop > sl.start:
                s = np.asarray(src[sl], np.float32).reshape(sl.stop - sl.start, Nv * Nu)
                out[k] = (self.P[k].astype(np.float32) @ s).reshape(Ny, Nx, Nv, Nu)
        return out * self.W


def _boundary_pixels(W: int, H: int, step: int = 4) -> np.ndarray:
    """(n, 2) pixel coordinates along the image border every ``step`` pixels, and the centre:
    the extent of a field of view (lens models map the border to the extreme directions)."""
    xs = np.unique(np.r_[np.arange(0, W, step), W - 1]).astype(float)
    ys = np.unique(np.r_[np.arange(0, H, step), H - 1]).astype(float)
    border = [np.stack([xs, np.zeros_like(xs)], -1), np.stack([xs, np.full_like(xs, H - 1)], -1),
              np.stack([np.zeros_like(ys), ys], -1), np.stack([np.full_like(ys, W - 1), ys], -1),
              np.array([[(W - 1) / 2.0, (H - 1) / 2.0]])]
    return np.concatenate(border)


def _interp_matrix(xs: np.ndarray, ys: np.ndarray, pts: list[tuple[int, int]], spacing: float) -> np.ndarray:
    """(Ny*Nx, n) bilinear interpolation at fixed (u, v) from source viewpoints ``pts`` (jy, ix).

    A viewpoint takes the four source viewpoints around it (nearest source rows and
    columns on either side) when they all exist and are at most ``spacing`` apart.
    """
    Ny, Nx = len(ys), len(xs)
    P = np.zeros((Ny * Nx, len(pts)))
    index = {p: i for i, p in enumerate(pts)}
    rows = sorted({p[0] for p in pts})
    cols = sorted({p[1] for p in pts})
    tol = 1.01 * spacing + 1e-9
    for jy in range(Ny):
        for ix in range(Nx):
            g = jy * Nx + ix
            if (jy, ix) in index:
                P[g, index[(jy, ix)]] = 1.0
                continue
            if spacing <= 0:
                continue
            lo_r = [r for r in rows if r <= jy]
            hi_r = [r for r in rows if r >= jy]
            lo_c = [c for c in cols if c <= ix]
            hi_c = [c for c in cols if c >= ix]
            if not (lo_r and hi_r and lo_c and hi_c):
                continue
            ya, yb, xl, xr = lo_r[-1], hi_r[0], lo_c[-1], hi_c[0]
            if ys[yb] - ys[ya] > tol or xs[xr] - xs[xl] > tol:
                continue
            corners = {(ya, xl), (ya, xr), (yb, xl), (yb, xr)}
            if not all(c in index for c in corners):
                continue
            ax = 0.0 if xr == xl else (xs[ix] - xs[xl]) / (xs[xr] - xs[xl])
            ay = 0.0 if yb == ya else (ys[jy] - ys[ya]) / (ys[yb] - ys[ya])
            for (cy, cx), wgt in (((ya, xl), (1 - ay) * (1 - ax)), ((ya, xr), (1 - ay) * ax),
                                  ((yb, xl), ay * (1 - ax)), ((yb, xr), ay * ax)):
                P[g, index[(cy, cx)]] += wgt
    return P


def design_grid(rig: Rig, models: dict | None = None, *, uv_step_deg: float = 1.5,
                xy_oversample: int = 2) -> RigSampling:
    """The light-field grid a rig gives and how its cameras fill it (module docstring).

    models: camera id → mrcal cameramodel whose reference frame is the rig (default
        :func:`polycam.cameras.nominal_cameramodel` of each camera).
    uv_step_deg: [deg] direction step at the face centre (the grid's ``f = 1 / tan``).
    xy_oversample: viewpoints per camera spacing along x and y.
    """
    from .cameras import T_rig_cam_of, camera_rays, nominal_cameramodel
    import mrcal

    if not rig.cameras:
        raise InputError(f"design: rig {rig.name!r} has no cameras")
    models = dict(models or {})
    for cam in rig.cameras:
        models.setdefault(cam.id, nominal_cameramodel(cam))
    ids = [c.id for c in rig.cameras]
    T = np.stack([T_rig_cam_of(models[c]) for c in ids])
    centres = T[:, :3, 3]
    f = 1.0 / math.tan(math.radians(uv_step_deg))
    dirs = []
    for c in ids:
        W_px, H_px = (int(v) for v in models[c].imagersize())
        dirs.append(camera_rays(models[c], _boundary_pixels(W_px, H_px)).directions.reshape(-1, 3))
    choice = choose_grid(centres, T[:, :3, 2], dirs, f, xy_oversample=xy_oversample,
                         who=f"design: rig {rig.name!r}")
    grid, own, spacing = choice.grid, choice.own, choice.spacing
    faces = [face.name for face in grid.faces]
    face_idx = [FACE_NAMES.index(n) for n in faces]
    R_faces = [R_rig_face_for(n) for n in faces]
    x_axis, y_axis, u_axis, v_axis = grid.x, grid.y, grid.u, grid.v
    F, Ny, Nx, Nv, Nu = grid.shape

    # place cameras on viewpoints
    xv, yv = x_axis.values, y_axis.values
    tol_x = _SNAP * (x_axis.step if Nx > 1 else max(spacing, 1e-3))
    tol_y = _SNAP * (y_axis.step if Ny > 1 else max(spacing, 1e-3))
    vs, us = np.meshgrid(v_axis.values, u_axis.values, indexing="ij")
    sources: list[Source] = []
    masks: list[np.ndarray] = []
    skipped: list[str] = []
    for k in range(F):
        taken: set[tuple[int, int]] = set()
        for i, c in enumerate(ids):
            if own[i] != face_idx[k]:
                continue
            cf = centres[i] @ R_faces[k]
            ix = int(np.argmin(np.abs(xv - cf[0])))
            jy = int(np.argmin(np.abs(yv - cf[1])))
            if abs(xv[ix] - cf[0]) > tol_x or abs(yv[jy] - cf[1]) > tol_y or (jy, ix) in taken:
                skipped.append(c)
                continue
            taken.add((jy, ix))
            m = models[c]
            lensmodel, intr = m.intrinsics()
            # directions of the grid in the camera frame → inside the imager?
            d_rig = np.stack([us, vs, np.full_like(us, f)], axis=-1) @ R_faces[k].T
            d_cam = d_rig @ T[i, :3, :3]
            front = d_cam[..., 2] > 1e-6
            q = mrcal.project(np.where(front[..., None], d_cam, np.array([0.0, 0.0, 1.0])), lensmodel, intr)
            W_px, H_px = (int(v) for v in m.imagersize())
            inside = front & np.all(np.isfinite(q), axis=-1) & (q[..., 0] >= -0.5) & (q[..., 0] <= W_px - 0.5) \
                & (q[..., 1] >= -0.5) & (q[..., 1] <= H_px - 0.5)
            fx = float(intr[0])
            sources.append(Source(camera=c, face=k, jy=jy, ix=ix, binning=fx / f))
            masks.append(inside)
    if skipped:
        log.warning("design: rig %s: camera(s) %s are not on the regular viewpoint lattice and are left out",
                    rig.name, ", ".join(skipped))
    if not sources:
        raise InputError(f"design: rig {rig.name!r}: no camera could be placed on the grid")
    P = []
    Wm = np.zeros(grid.shape, np.float32)
    for k in range(F):
        idx = [j for j, s in enumerate(sources) if s.face == k]
        pts = [(sources[j].jy, sources[j].ix) for j in idx]
        Pk = _interp_matrix(xv, yv, pts, spacing)
        P.append(Pk)
        if idx:
            mk = np.stack([masks[j] for j in idx]).reshape(len(idx), -1)       # (n_k, Nv*Nu)
            # a sample has data where every source it is interpolated from has data
            bad = ((Pk > 0).astype(np.float32) @ (~mk).astype(np.float32)) > 0
            has = (Pk.sum(axis=1) > 0.5)[:, None] & ~bad
            Wm[k] = has.reshape(Ny, Nx, Nv, Nu)
    return RigSampling(grid=grid, sources=tuple(sources), P=tuple(P), masks=np.stack(masks), W=Wm,
                       spacing=spacing, skipped=tuple(skipped))


# ============================================================================ rendering (shared)


class SourceRenderer:
    """Renders the source viewpoints of rig samplings, caching each viewpoint image.

    Rigs that share a camera (same face, viewpoint, grid ``f`` and (u, v) axes) share
    its rendering: the images are keyed by the rays, not by the rig.
    """

    def __init__(self, scene, supersample: int = 2):
        self.scene = scene
        self.supersample = int(supersample)
        self._cache: dict[tuple, np.ndarray] = {}
        self._depth: dict[tuple, np.ndarray] = {}
        self.rendered = 0
        """Viewpoint images rendered so far (cache misses)."""
        self.reused = 0
        """Viewpoint images served from the cache."""

    @staticmethod
    def _key(sampling: RigSampling, s: Source, T_world_rig: np.ndarray, what: str) -> tuple:
        g = sampling.grid
        face = g.faces[s.face]
        o = (round(float(g.x.values[s.ix]), 7), round(float(g.y.values[s.jy]), 7), round(face.z_pi, 7))
        return (what, face.name, o, round(face.f, 9), (g.u.min, g.u.max, g.u.count),
                (g.v.min, g.v.max, g.v.count), np.round(np.asarray(T_world_rig, float), 12).tobytes())

    def _trace(self, sampling: RigSampling, T_world_rig: np.ndarray, what: str) -> np.ndarray:
        from .synth import trace_outer
        from .synth.render import lightfield_face_rays

        g = sampling.grid
        _, _, _, Nv, Nu = g.shape
        store = self._cache if what == "radiance" else self._depth
        out = np.zeros((len(sampling.sources), Nv, Nu), np.float32 if what == "radiance" else np.float64)
        keys = [self._key(sampling, s, T_world_rig, what) for s in sampling.sources]
        for k, sl in enumerate(sampling.face_slices):
            todo = [j for j in range(sl.start, sl.stop) if keys[j] not in store]
            if todo:
                ss = self.supersample if what == "radiance" else 1
                o_all, d = lightfield_face_rays(g, k, ss)                 # (Ny*Nx, 3), (Nv*Nu, S, 3)
                o = np.stack([o_all[sampling.sources[j].jy * g.x.count + sampling.sources[j].ix] for j in todo])
                res = trace_outer(self.scene, o, d, T_world_rig)
                vals = res.radiance if what == "radiance" else res.distance
                for n, j in enumerate(todo):
                    store[keys[j]] = np.asarray(vals[n]).reshape(Nv, Nu)
                self.rendered += len(todo)
            self.reused += (sl.stop - sl.start) - len(todo)
            for j in range(sl.start, sl.stop):
                out[j] = store[keys[j]]
        return out

    def render(self, sampling: RigSampling, T_world_rig: np.ndarray) -> np.ndarray:
        """(n_src, Nv, Nu) float32 radiance of every source viewpoint at rig pose ``T_world_rig``
        (zero outside each camera's field of view)."""
        return self._trace(sampling, T_world_rig, "radiance") * sampling.masks

    def distance(self, sampling: RigSampling, T_world_rig: np.ndarray) -> np.ndarray:
        """(n_src, Nv, Nu) float64 [m] distance along each grid direction's centre ray (inf: sky)."""
        return self._trace(sampling, T_world_rig, "distance")

    def clear(self) -> None:
        self._cache.clear()
        self._depth.clear()


# ============================================================================ results


@dataclass(frozen=True)
class Direction:
    """A weakly determined combination of motion parameters (an eigenvector of their
    correlation matrix, i.e. of the Jacobi-scaled covariance)."""

    vector: np.ndarray
    """(6,) unit vector over (t_x, t_y, t_z, w_x, w_y, w_z), each in units of its own σ (rig frame)."""
    inflation: float
    """Eigenvalue of the correlation matrix: the variance of this combination relative to
    uncorrelated parameters (1: no coupling; up to 6)."""
    name: str
    """Its dominant components, e.g. ``+0.71 t_x -0.70 w_y``."""
    kind: str
    """``translation``, ``rotation`` or ``mixed`` (both, each at least 15% of the norm²)."""


@dataclass(frozen=True)
class DesignPrediction:
    """Predicted noise errors of one frame pair from the linear model (module docstring)."""

    model: str
    """``plenoptic`` (the solver's linear model) or ``depth`` (one viewpoint per face: depth eliminated)."""
    covariance: np.ndarray
    """(6, 6) covariance of the rig motion's ``(t [m], r [rad])`` on the observable subspace."""
    std_t: float
    """[m] sqrt(trace) of the translation covariance: expected |t error| (inf if unobservable)."""
    std_w: float
    """[rad] sqrt(trace) of the rotation covariance (inf if unobservable)."""
    std_t_dir: float
    """[rad] 1-σ error of the translation *direction* (the angle), for any model."""
    unobservable: tuple[str, ...]
    """Names of directions the data cannot fix (``t_scale`` = the scale of translation)."""
    solver_unobservable: tuple[str, ...]
    """What the plenoptic solver's linear model cannot fix (e.g. ``t_x t_y t_z`` for one viewpoint)."""
    directions: tuple[Direction, ...]
    """Observable directions, weakest (largest inflation) first."""
    condition: float
    """Condition number of the correlation matrix over the observable directions (1: decoupled)."""
    ambiguity: str
    """The classical rotation–translation ambiguity when present: the most correlated
    translation/rotation pair, e.g. ``t_x~w_y (corr -0.95)`` (|corr| >= 0.7), else ''."""
    bias: np.ndarray
    """(6,) one linearised step of (t, r) from the truth on the noise-free pair: the direction
    of the model error's pull only — the solver's actual systematic error (its fixed point,
    often several times larger on one face) is :attr:`DesignMeasurement.bias_t` / ``clean``."""
    misfit: float
    """Robust scale of the noise-free residual / that of the noise: > 1 means model error
    (occlusions, aliasing) dominates and the solver scatters more than predicted."""
    num_rays: int
    """Rays with a positive weight."""


@dataclass(frozen=True)
class DesignMeasurement:
    """Errors of the real solver over frame pairs x noise draws."""

    errors: np.ndarray
    """(pairs, draws, 6) estimated − true (t [m], r [rad]) of ``T_prev_next``."""
    clean: np.ndarray
    """(pairs, 6) error of the solver on the noise-free pair: its systematic error (bias)."""
    ok: np.ndarray
    """(pairs, draws) bool: the solver reported success."""
    err_t: float
    """[m] RMS |t error| over all estimates (NaN when the solver cannot estimate t)."""
    err_w: float
    """[rad] RMS |r error|."""
    bias_t: float
    """[m] RMS over pairs of |t error| of the noise-free pair (systematic part: the
    pipeline's model error on the scene — see docs/design.md for its causes)."""
    bias_w: float
    """[rad] RMS over pairs of |r error| of the noise-free pair."""
    scatter_t: float
    """[m] RMS |t error − pair mean| (noise part; compare with the predicted std_t)."""
    scatter_w: float
    """[rad] RMS |r error − pair mean|."""
    solver_unobservable: tuple[str, ...]
    """Unobservable directions the solver reported (first pair)."""


@dataclass(frozen=True)
class DesignResult:
    """Everything the study knows about one rig."""

    rig: Rig
    sampling: RigSampling
    features: dict
    """Design features: cameras, faces, baseline [m], spacing [m], fov_deg, coverage_deg,
    viewpoints, rays, class."""
    prediction: DesignPrediction
    measurement: DesignMeasurement | None
    sweep: tuple[tuple[float, float, float], ...] = ()
    """(distance [m], std_t [m], std_w [rad]) per sweep distance."""
    warnings: tuple[str, ...] = ()

    @property
    def name(self) -> str:
        return self.rig.name

    def summary_row(self) -> dict:
        """The ``summary.csv`` columns (SPEC.md) plus the extras (docs/design.md)."""
        p, m = self.prediction, self.measurement
        row = {"rig": self.rig.name, "cameras": self.features["cameras"], "faces": self.features["faces"],
               "std_t": p.std_t, "std_w": p.std_w,
               "err_t": (m.err_t if m is not None else math.nan),
               "err_w": (m.err_w if m is not None else math.nan),
               "unobservable": " ".join(p.unobservable)}
        row.update({
            "class": self.features["class"], "model": p.model,
            "baseline": self.features["baseline"], "spacing": self.features["spacing"],
            "fov_deg": self.features["fov_deg"], "coverage_deg": self.features["coverage_deg"],
            "viewpoints": self.features["viewpoints"], "rays": self.features["rays"],
            "std_t_dir": p.std_t_dir, "condition": p.condition, "weakest": p.directions[0].name if p.directions else "",
            "ambiguity": p.ambiguity, "solver_unobservable": " ".join(p.solver_unobservable),
            "bias_t": (m.bias_t if m is not None else math.nan), "bias_w": (m.bias_w if m is not None else math.nan),
            "scatter_t": (m.scatter_t if m is not None else math.nan),
            "scatter_w": (m.scatter_w if m is not None else math.nan),
            "misfit": p.misfit,
        })
        return row


# ============================================================================ motions


def pair_motions(n: int, step_t: float, step_r_deg: float, seed: int = 0) -> np.ndarray:
    """(n, 4, 4) rig motions ``T_rig0_rig1`` of the representative pairs: translation of
    length ``step_t`` [m] and rotation of ``step_r_deg`` [deg] about seeded random axes."""
    rng = np.random.default_rng([seed, 808])
    out = np.empty((n, 4, 4))
    for i in range(n):
        a = rng.normal(size=3)
        b = rng.normal(size=3)
        out[i] = T_from_Rt(R_from_r(b / np.linalg.norm(b) * math.radians(step_r_deg)),
                           a / np.linalg.norm(a) * step_t)
    return out


# ============================================================================ the prediction


def _observable(N: np.ndarray, rcond: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Jacobi-scaled eigen-analysis of a normal matrix N (6, 6), the solver's own
    (:func:`polycam.motion.scaled_eigen`).

    Returns (pinv (6, 6) of N on the observable subspace, unobservable unit vectors
    (k, 6) in the *unscaled* parameters, good (6,) bool over the scaled eigenvalues)."""
    eig = scaled_eigen(N, rcond)
    pinv, vec, good, live, s = eig.N_pinv, eig.evecs, eig.good, eig.live, eig.scale
    bad = []
    for j in np.where(~good)[0]:
        v = vec[:, j].copy()
        # scaled → unscaled direction: dead columns are axis vectors
        u = np.where(live, v * s, v)
        u /= max(np.linalg.norm(u), 1e-300)
        bad.append(u)
    return pinv, (np.array(bad) if bad else np.zeros((0, 6))), good


def _component_name(v: np.ndarray, thresh: float = 0.3, most: int = 3) -> str:
    """'t_x' for an (almost) axis vector, else its largest components, e.g. '+0.71 t_x -0.70 w_y'."""
    a = np.abs(v)
    i = int(np.argmax(a))
    if a[i] > 0.95:
        return PARAM_NAMES[i]
    return " ".join(f"{v[j]:+.2f} {PARAM_NAMES[j]}" for j in np.argsort(-a)[:most] if a[j] > thresh)


def _kind(v: np.ndarray) -> str:
    nt = float(np.sum(v[:3] ** 2))
    if nt > 0.85:
        return "translation"
    if nt < 0.15:
        return "rotation"
    return "mixed"


AMBIGUITY_CORR = 0.7
"""|correlation| between a translation and a rotation component from which their coupling
is reported as the rotation–translation ambiguity."""


def analyse_covariance(C: np.ndarray, n_unobservable: int = 0) -> tuple[tuple[Direction, ...], float, str]:
    """Weak directions and the rotation–translation ambiguity of a covariance C (6, 6) of (t, r).

    Parameters are scaled by their own σ (the correlation matrix; scale free, like the
    solver's Jacobi scaling); its eigenvectors with the largest eigenvalues are the
    weakly determined combinations. The ``n_unobservable`` smallest eigenvalues (null
    space of a covariance computed on the observable subspace) and parameters with no
    variance are left out. Returns (directions weakest first, condition number, ambiguity).
    """
    d = np.sqrt(np.clip(np.diag(C), 0.0, None))
    live = np.isfinite(d) & (d > 1e-300)
    if not live.any():
        return (), math.inf, ""
    idx = np.where(live)[0]
    R = C[np.ix_(idx, idx)] / np.outer(d[idx], d[idx])
    ev, vec = np.linalg.eigh(0.5 * (R + R.T))
    n_drop = max(0, int(n_unobservable) - (6 - len(idx)))
    order = np.argsort(-ev)[: len(idx) - n_drop]
    dirs = []
    for j in order:
        v = np.zeros(6)
        v[idx] = vec[:, j]
        v = v * (1.0 if v[int(np.argmax(np.abs(v)))] > 0 else -1.0)
        dirs.append(Direction(vector=v, inflation=float(ev[j]), name=_component_name(v), kind=_kind(v)))
    lam = [dd.inflation for dd in dirs]
    cond = (max(lam) / min(lam)) if lam and min(lam) > 1e-12 else math.inf
    best, amb = 0.0, ""
    for i in range(3):
        for j in range(3, 6):
            if live[i] and live[j]:
                c = float(C[i, j] / (d[i] * d[j]))
                if abs(c) >= AMBIGUITY_CORR and abs(c) > best:
                    best, amb = abs(c), f"{PARAM_NAMES[i]}~{PARAM_NAMES[j]} (corr {c:+.2f})"
    return tuple(dirs), cond, amb


def _normal(A_faces: list[np.ndarray], w: np.ndarray) -> np.ndarray:
    """N = Σ w A Aᵀ (6, 6) over faces; A_faces[k]: (Ny, Nx, Nv, Nu, 6), w: (F, Ny, Nx, Nv, Nu)."""
    return sum((w[k].astype(np.float64)[..., None] * A).reshape(-1, 6).T @ A.reshape(-1, 6)
               for k, A in enumerate(A_faces))


def _sandwich(A_faces: list[np.ndarray], w: np.ndarray, sampling: RigSampling, sigma_src: np.ndarray,
              pairs: dict) -> tuple[np.ndarray, np.ndarray]:
    """N = Σ w A Aᵀ and the noise meat 2 Σ_src σ² ‖(K P)ᵀ (w A)‖² over faces.

    A_faces[k]: (Ny, Nx, Nv, Nu, 6) coefficient rows of face k (rig frame); w: (F, Ny, Nx, Nv, Nu).
    """
    F, Ny, Nx, Nv, Nu = sampling.grid.shape
    N = np.zeros((6, 6))
    meat = np.zeros((6, 6))
    for k, sl in enumerate(sampling.face_slices):
        A = A_faces[k]
        wA = w[k].astype(np.float64)[..., None] * A
        N += wA.reshape(-1, 6).T @ A.reshape(-1, 6)
        if sl.stop == sl.start:
            continue
        cols = np.stack([wA[..., j] for j in range(6)]).astype(np.float32)         # (6, Ny, Nx, Nv, Nu)
        KtA = smooth_all(np.ascontiguousarray(cols), pairs)                      # prefilters are symmetric: Kᵀ = K
        G = KtA.reshape(6, Ny * Nx, Nv * Nu).astype(np.float64)
        Pk = sampling.P[k]                                                       # (Ny*Nx, n_k)
        PtG = np.einsum("gs,jgq->sqj", Pk, G)                                    # (n_k, Nv*Nu, 6)
        sc = (sigma_src[sl][:, None] * sampling.masks[sl].reshape(sl.stop - sl.start, -1))[..., None]
        X = (PtG * sc).reshape(-1, 6)
        meat += 2.0 * X.T @ X
    return N, meat


def _flow_xy(grid: LightFieldGrid, k: int, p_rig: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Positional ray flow (δx, δy) (Ny, Nx, Nv, Nu) of face k for the ray motion p_rig (6,) (paper Eq. 5)."""
    face = grid.faces[k]
    R = np.asarray(face.R_rig_face, float)
    t = R.T @ p_rig[:3]
    w = R.T @ p_rig[3:]
    f, Z = face.f, face.z_pi
    y, x, v, u = np.meshgrid(grid.y.values, grid.x.values, grid.v.values, grid.u.values, indexing="ij")
    dx = t[0] - u / f * t[2] - u * y / f * w[0] + (u * x / f + Z) * w[1] - y * w[2]
    dy = t[1] - v / f * t[2] - (v * y / f + Z) * w[0] + v * x / f * w[1] + x * w[2]
    return dx, dy


def _depth_coefficients(der, sampling: RigSampling, rho: np.ndarray, p_ray: np.ndarray, patch: int, w: np.ndarray
                        ) -> list[np.ndarray]:
    """Eq. 5 rows with L_x = ρ f L_u, L_y = ρ f L_v (Lambertian, paper Eq. 6) and one unknown
    relative inverse-depth correction per (u, v) patch eliminated (Frisch–Waugh–Lovell).

    rho: (F, Ny, Nx, Nv, Nu) true inverse depth along each face's normal [1/m] (0: sky).
    p_ray: (6,) the true ray motion (rig frame) at which the depth column is linearised.
    """
    g = sampling.grid
    F, Ny, Nx, Nv, Nu = g.shape
    out = []
    pv = (np.arange(Nv) // patch)[:, None]
    pu = (np.arange(Nu) // patch)[None, :]
    npu = (Nu + patch - 1) // patch
    npv = (Nv + patch - 1) // patch
    for k, face in enumerate(g.faces):
        f = face.f
        Lu = der.Lu[k].astype(np.float64)
        Lv = der.Lv[k].astype(np.float64)
        d2 = dataclasses.replace(der, Lx=(rho * f * der.Lu).astype(np.float32),
                                 Ly=(rho * f * der.Lv).astype(np.float32))
        A = ray_motion_coefficients(d2, g, k)                                     # (Ny, Nx, Nv, Nu, 6)
        dx, dy = _flow_xy(g, k, p_ray)
        Js = rho[k] * f * (Lu * dx + Lv * dy)                                    # d residual / d(relative ρ)
        pid = (np.arange(Ny * Nx)[:, None, None] * (npv * npu) + (pv * npu + pu)[None]).reshape(Ny, Nx, Nv, Nu)
        n_p = Ny * Nx * npv * npu
        wk = w[k].astype(np.float64)
        den = np.bincount(pid.ravel(), weights=(wk * Js * Js).ravel(), minlength=n_p)
        beta = np.stack([np.bincount(pid.ravel(), weights=(wk * Js * A[..., j]).ravel(), minlength=n_p)
                         for j in range(6)], axis=-1)
        ok = den > 1e-300
        beta[ok] /= den[ok, None]
        beta[~ok] = 0.0
        out.append(A - Js[..., None] * beta[pid])
    return out


def predict_pair(sampling: RigSampling, src0: np.ndarray, src1: np.ndarray, M: np.ndarray,
                 sigma_src: np.ndarray, *, options: MotionOptions | None = None,
                 rng: np.random.Generator | None = None, depth0: np.ndarray | None = None,
                 depth_patch: int = 8) -> DesignPrediction:
    """Predicted errors of the rig motion ``M`` (4, 4) ``T_rig0_rig1`` from one rendered pair.

    src0, src1: (n_src, Nv, Nu) noise-free source images of frames 0 and 1
    (:meth:`SourceRenderer.render`); sigma_src: (n_src,) noise std per grid sample;
    rng: for the one noise draw that sets the data-dependent weights (seeded default);
    depth0: (n_src, Nv, Nu) [m] distances along the grid rays at frame 0 — needed for
    the depth model of one-viewpoint rigs (else their translation is only reported
    unobservable), and for a linear array's single-view axis, whose regressor the solver takes
    from depth (else that translation is reported unobservable).
    """
    # the solver's options on these frames: measure_pairs passes the confidences W unless every
    # sample has data
    opts = (options or MotionOptions()).for_frames(not sampling.all_data)
    rng = rng if rng is not None else np.random.default_rng(0)
    g = sampling.grid
    F, Ny, Nx, Nv, Nu = g.shape
    pairs = solver_filter_pairs(g, opts)
    W = sampling.W
    L0 = sampling.assemble(src0)
    L1 = sampling.assemble(src1)
    noise = [sigma_src[:, None, None] * sampling.masks * rng.normal(size=src0.shape) for _ in range(2)]
    L0n = sampling.assemble(src0 + noise[0])
    L1n = sampling.assemble(src1 + noise[1])

    # the solver's state at convergence: frame 2 warped by the (true) motion
    T_ray = T_inverse(M)
    if sampling.all_data:
        w1, ok = warp_lightfield(np.stack([L1, L1n]), g, T_ray, uv_taps=opts.uv_taps)
        conf = ok.astype(np.float32)
    else:
        w1, ok = warp_lightfield(np.stack([L1, L1n, W, (W <= 0).astype(np.float32)]), g, T_ray,
                                 uv_taps=opts.uv_taps)
        conf = ok.astype(np.float32) * W * np.clip(w1[2], 0, 1) * (np.abs(w1[3]) < 1e-6)
    conf = min_over_support(np.ascontiguousarray(conf, np.float32), {k: v for k, v in pairs.items()})
    fnames = opts.filters if isinstance(opts.filters, dict) else {k: opts.filters for k in "xyuv"}
    filt = {k: fnames.get(k, "fs5") for k in "xyuv"}
    der = plenoptic_derivatives(L0, w1[0], g, filters=filt)
    S = 0.5 * (L0n + L1n) * (W > 0)
    base = conf * der.valid[None].astype(np.float32)
    if opts.smooth_c > 0:
        base = base * discontinuity_weight(np.ascontiguousarray(S, np.float32), opts)
    Lt_noisy = smooth_all(np.ascontiguousarray(w1[1] - L0n, np.float32), pairs)
    scale = max(robust_scale(Lt_noisy, base), _SCALE_FLOOR)
    w = base * robust_weight(Lt_noisy, scale, opts)

    single = g.single_view_axis
    if single and depth0 is not None:
        # a linear array: the solver's regressor along the single-view axis is ρ̂ L_u (or ρ̂ L_v),
        # ρ̂ = f / Z from the other axis's parallax (polycam.motion, "Linear arrays"): here the
        # true one (its noise left out, as the derivatives' own)
        rho_f = np.stack([g.faces[k].f * r for k, r in enumerate(_inverse_depth(sampling, depth0))]).astype(np.float32)
        der = dataclasses.replace(der, **({"Lx": rho_f * der.Lu} if single == "x" else {"Ly": rho_f * der.Lv}))
    A_faces = [ray_motion_coefficients(der, g, k) for k in range(F)]
    Jm = ray_to_rig_jacobian(M)
    N = _normal(A_faces, w)
    pinv, bad, good = _observable(N, opts.rcond)

    # linearised bias from the noise-free residual (model error) and the misfit ratio
    rhs = sum((w[k].astype(np.float64)[..., None] * A_faces[k]).reshape(-1, 6).T @ der.Lt[k].reshape(-1)
              for k in range(F))
    delta = -(pinv @ rhs)
    bias = Jm @ delta
    res0 = np.stack([der.Lt[k] + (A_faces[k] @ delta).astype(np.float32) for k in range(F)])
    noise_scale = robust_scale(Lt_noisy - der.Lt, base)
    misfit = robust_scale(res0, base) / max(noise_scale, 1e-12) if noise_scale > 0 else math.inf

    # the solver's robust weights and scale belong to its residual at convergence: the model
    # error left at the (linearised) fixed point plus the noise
    r_fix = res0 + (Lt_noisy - der.Lt)
    scale = max(robust_scale(r_fix, base), _SCALE_FLOOR)
    w = base * robust_weight(r_fix, scale, opts)
    num = int(np.count_nonzero(w > 0))
    N = _normal(A_faces, w)
    pinv, bad, good = _observable(N, opts.rcond)
    w_cov = w
    if not len(bad) and opts.robust != "none" and opts.irls_steps > 0:
        # IRLS converges to the M-estimate Σ base a ψ(r) = 0; noise n moves it through
        # ψ'(r) at the model-error residual r = res0, not through the weight w(r): rays whose
        # model error is a sizeable part of the robust scale respond less (or oppositely)
        w_m = base * robust_slope(res0, scale, opts)
        d = 1.0 / np.sqrt(np.diag(N))
        ev = np.linalg.eigvalsh(_normal(A_faces, w_m) * np.outer(d, d))
        if ev.min() > 0.05 * ev.max() * opts.rcond ** 0.5:
            w_cov = w_m
    N, meat = _sandwich(A_faces, w_cov, sampling, sigma_src, pairs)
    if w_cov is not w:
        pinv, _, _ = _observable(N, opts.rcond)
    solver_unobs = tuple(_component_name(Jm @ b / np.linalg.norm(Jm @ b)) for b in bad)

    model = "plenoptic"
    t_dead = bool(len(bad)) and any(np.linalg.norm(b[:3]) > 0.5 for b in bad)
    if t_dead and depth0 is not None:
        # one viewpoint per face: translation only through depth (paper Eq. 6)
        model = "depth"
        rho = _inverse_depth(sampling, depth0)
        p_ray = np.r_[T_ray[:3, 3], r_from_R(T_ray[:3, :3])]
        # no robust weights: the solver's residual holds the parallax it cannot model, the
        # depth model's does not
        A_faces = _depth_coefficients(der, sampling, rho, p_ray, depth_patch, base)
        N, meat = _sandwich(A_faces, base, sampling, sigma_src, pairs)
        pinv, bad, good = _observable(N, opts.rcond)

    C_ray = pinv @ meat @ pinv
    C = Jm @ C_ray @ Jm.T
    C = 0.5 * (C + C.T)
    bad_rig = [Jm @ b for b in bad]
    bad_rig = [b / np.linalg.norm(b) for b in bad_rig]
    t_true = M[:3, 3]
    names = []
    for b in bad_rig:
        if model == "depth" and np.linalg.norm(t_true) > 0 and np.linalg.norm(b[3:]) < 0.2 \
                and abs(b[:3] @ t_true) / np.linalg.norm(t_true) > 0.9:
            names.append("t_scale")
        else:
            names.append(_component_name(b))
    dirs, cond, amb = analyse_covariance(C, len(bad_rig))
    unobs_t = any(np.linalg.norm(b[:3]) > 0.2 for b in bad_rig)
    unobs_w = any(np.linalg.norm(b[3:]) > 0.2 for b in bad_rig)
    std_t = math.inf if unobs_t else math.sqrt(max(float(np.trace(C[:3, :3])), 0.0))
    std_w = math.inf if unobs_w else math.sqrt(max(float(np.trace(C[3:, 3:])), 0.0))
    tn = float(np.linalg.norm(t_true))
    if tn > 0:
        that = t_true / tn
        Pp = np.eye(3) - np.outer(that, that)
        t_dir_bad = any(np.linalg.norm(Pp @ b[:3]) > 0.2 for b in bad_rig)
        std_t_dir = math.inf if t_dir_bad else math.sqrt(max(float(np.trace(Pp @ C[:3, :3] @ Pp)), 0.0)) / tn
    else:
        std_t_dir = math.nan
    return DesignPrediction(model=model, covariance=C, std_t=std_t, std_w=std_w, std_t_dir=std_t_dir,
                            unobservable=tuple(names), solver_unobservable=solver_unobs, directions=dirs,
                            condition=cond, ambiguity=amb, bias=bias, misfit=float(misfit), num_rays=num)


def _inverse_depth(sampling: RigSampling, depth0: np.ndarray) -> np.ndarray:
    """(F, Ny, Nx, Nv, Nu) [1/m] 1 / Z per grid ray (Z along its face's z axis) from ``depth0``
    (n_src, Nv, Nu) [m], the distances along the sources' rays, through the viewpoint
    interpolation ``P`` (0 where the distance is unknown)."""
    g = sampling.grid
    F, Ny, Nx, Nv, Nu = g.shape
    rho = np.zeros(g.shape)
    vv, uu = np.meshgrid(g.v.values, g.u.values, indexing="ij")
    for k, sl in enumerate(sampling.face_slices):
        if sl.stop == sl.start:
            continue
        face = g.faces[k]
        cosz = face.f / np.sqrt(uu * uu + vv * vv + face.f ** 2)
        dist = depth0[sl]
        r_src = np.where(np.isfinite(dist) & (dist > 0), 1.0 / np.maximum(dist * cosz, 1e-9), 0.0)
        rho[k] = (sampling.P[k] @ r_src.reshape(sl.stop - sl.start, -1)).reshape(Ny, Nx, Nv, Nu)
    return rho


# ============================================================================ the measurement


def measure_pairs(sampling: RigSampling, src0: np.ndarray, src1s: Sequence[np.ndarray], motions: np.ndarray,
                  sigma_src: np.ndarray, *, draws: int, options: MotionOptions | None = None,
                  rng: np.random.Generator | None = None, solver_can_t: bool = True) -> DesignMeasurement:
    """Run the real solver on every pair once without noise and on ``draws`` noisy renderings.

    src0: (n_src, Nv, Nu) frame 0 (shared by all pairs); src1s: per pair the frame-1
    images; motions: (pairs, 4, 4) true ``T_rig0_rig1``; solver_can_t: False when the
    solver cannot estimate translation (one viewpoint): err_t is then NaN.
    The noise-free run is the systematic error (bias) of the pipeline on the pair; the
    scatter of the noisy runs about their mean is what the prediction describes.
    """
    rng = rng if rng is not None else np.random.default_rng(0)
    g = sampling.grid
    W = None if sampling.all_data else sampling.W
    n = len(src1s)
    errors = np.zeros((n, draws, 6))
    clean = np.zeros((n, 6))
    ok = np.zeros((n, draws), bool)
    unobs: tuple[str, ...] = ()

    def error(res, i):
        return np.r_[res.t - motions[i][:3, 3], res.r - r_from_R(motions[i][:3, :3])]

    for i in range(n):
        clean[i] = error(estimate_motion(sampling.assemble(src0), sampling.assemble(src1s[i]), g, W0=W, W1=W,
                                         options=options, index=i), i)
        for d in range(draws):
            a = sampling.assemble(src0 + sigma_src[:, None, None] * sampling.masks * rng.normal(size=src0.shape))
            b = sampling.assemble(src1s[i] + sigma_src[:, None, None] * sampling.masks * rng.normal(size=src0.shape))
            res = estimate_motion(a, b, g, W0=W, W1=W, options=options, index=i)
            errors[i, d] = error(res, i)
            ok[i, d] = res.ok
            if i == 0 and d == 0:
                unobs = tuple(res.unobservable)

    def rms_norm(e):
        return float(np.sqrt(np.mean(np.sum(e * e, axis=-1))))

    dev = errors - errors.mean(axis=1, keepdims=True)
    sc = math.sqrt(draws / (draws - 1)) if draws > 1 else math.nan
    nan_t = not solver_can_t
    return DesignMeasurement(
        errors=errors, clean=clean, ok=ok, err_t=math.nan if nan_t else rms_norm(errors[..., :3]),
        err_w=rms_norm(errors[..., 3:]),
        bias_t=math.nan if nan_t else rms_norm(clean[:, :3]), bias_w=rms_norm(clean[:, 3:]),
        scatter_t=math.nan if nan_t else rms_norm(dev[..., :3]) * sc,
        scatter_w=rms_norm(dev[..., 3:]) * sc, solver_unobservable=unobs)


# ============================================================================ features


def rig_features(rig: Rig, sampling: RigSampling) -> dict:
    """Design features of a rig: cameras, faces, baseline [m] (largest distance between
    camera centres), spacing [m], fov_deg (median camera horizontal FOV), coverage_deg
    (apex angle of the cone with the solid angle the light field covers; 360 = sphere),
    viewpoints (with data), rays (samples with data) and class (the paper's hierarchy:
    pinhole / polydioptric x small FOV / spherical)."""
    c = rig.positions
    base = float(np.max(np.linalg.norm(c[:, None] - c[None], axis=-1))) if len(c) > 1 else 0.0
    g = sampling.grid
    vs, us = np.meshgrid(g.v.values, g.u.values, indexing="ij")
    omega = 0.0
    for k, face in enumerate(g.faces):
        f = face.f
        dA = (g.u.step or 1.0) * (g.v.step or 1.0)
        sa = dA * f / (us * us + vs * vs + f * f) ** 1.5
        covered = sampling.W[k].max(axis=(0, 1)) > 0
        omega += float(np.sum(sa[covered]))
    omega = min(omega, 4 * math.pi)
    coverage = math.degrees(2.0 * math.acos(max(-1.0, 1.0 - omega / (2 * math.pi))))
    positional = sampling.has_positional
    spherical = len(g.faces) >= 3
    cls = ("polydioptric" if positional else "pinhole") + (", spherical" if spherical else ", small FOV")
    vp = int(np.count_nonzero(sampling.W.max(axis=(3, 4)) > 0))
    return {"cameras": len(rig.cameras), "faces": len(g.faces), "baseline": base, "spacing": sampling.spacing,
            "fov_deg": float(np.median([cam.fov_deg for cam in rig.cameras])), "coverage_deg": coverage,
            "viewpoints": vp, "rays": int(np.count_nonzero(sampling.W > 0)), "class": cls}


# ============================================================================ a rig, a study


def _scene(options: DesignOptions, distance: float | None = None):
    from .synth import make_scene

    return make_scene(options.scene, options.distance if distance is None else distance, options.seed)


def _sigma_src(sampling: RigSampling, noise: float) -> np.ndarray:
    return np.array([noise / max(1.0, s.binning) for s in sampling.sources])


def evaluate_rig(rig: Rig, options: DesignOptions | None = None, *, renderer: SourceRenderer | None = None,
                 sweep_renderers: dict | None = None, models: dict | None = None) -> DesignResult:
    """Prediction (and, with ``options.measure``, measurement) for one rig.

    renderer: a :class:`SourceRenderer` of the options' scene to share renderings
    between rigs (made if None); sweep_renderers: distance → renderer, likewise.
    """
    opts = options or DesignOptions()
    sampling = design_grid(rig, models, uv_step_deg=opts.uv_step_deg, xy_oversample=opts.xy_oversample)
    feats = rig_features(rig, sampling)
    warnings = []
    if sampling.skipped:
        warnings.append(f"cameras off the viewpoint lattice, left out: {', '.join(sampling.skipped)}")
    small = [s.camera for s in sampling.sources if s.binning < 1.0]
    if small:
        warnings.append(f"grid finer than the camera pixels for {', '.join(small[:3])}"
                        + (" ..." if len(small) > 3 else "") + ": raise --uv-step")
    renderer = renderer or SourceRenderer(_scene(opts), opts.supersample)
    motions = pair_motions(opts.pairs, opts.step_t, opts.step_r_deg, opts.seed)
    sigma = _sigma_src(sampling, opts.noise)
    if not np.any(sigma > 0):
        raise InputError("design: the noise must be > 0 to predict errors")
    I4 = np.eye(4)
    src0 = renderer.render(sampling, I4)
    src1s = [renderer.render(sampling, motions[i]) for i in range(opts.pairs if opts.measure else 1)]
    one_view = not sampling.has_positional
    # depth for the one-viewpoint model, and for a linear array's regressor along its single-view axis
    with_depth = one_view or bool(sampling.grid.single_view_axis)
    depth0 = renderer.distance(sampling, I4) if with_depth else None
    rng = np.random.default_rng([opts.seed, 909])
    pred = predict_pair(sampling, src0, src1s[0], motions[0], sigma, options=opts.solver,
                        rng=rng, depth0=depth0, depth_patch=opts.depth_patch)
    if pred.num_rays == 0:
        warnings.append("no usable rays once frame 2 is warped by the motion (too few viewpoints or directions "
                        "for the filter supports): the solver cannot work with this rig")
    elif pred.misfit > 1.0:
        warnings.append(f"model error exceeds the noise (misfit {pred.misfit:.1f}): the solver's error is "
                        "mostly systematic and its scatter may exceed the prediction")
    meas = None
    if opts.measure:
        meas = measure_pairs(sampling, src0, src1s, motions, sigma, draws=opts.draws, options=opts.solver,
                             rng=np.random.default_rng([opts.seed, 910]), solver_can_t=not one_view)
    sweep = []
    for D in opts.sweep:
        rend = (sweep_renderers or {}).get(D) or SourceRenderer(_scene(opts, D), opts.supersample)
        if sweep_renderers is not None:
            sweep_renderers[D] = rend
        s0 = rend.render(sampling, I4)
        s1 = rend.render(sampling, motions[0])
        dd = rend.distance(sampling, I4) if with_depth else None
        p = predict_pair(sampling, s0, s1, motions[0], sigma, options=opts.solver,
                         rng=np.random.default_rng([opts.seed, 909]), depth0=dd, depth_patch=opts.depth_patch)
        sweep.append((float(D), p.std_t, p.std_w))
    for wmsg in warnings:
        log.info("design: %s: %s", rig.name, wmsg)
    return DesignResult(rig=rig, sampling=sampling, features=feats, prediction=pred, measurement=meas,
                        sweep=tuple(sweep), warnings=tuple(warnings))


def design_study(rigs: Sequence[Rig], options: DesignOptions | None = None, *,
                 progress: Callable[[int, int], None] | None = None,
                 renderer: SourceRenderer | None = None) -> list[DesignResult]:
    """Evaluate every rig on the same scene, motions and noise (renderings shared).

    renderer: a :class:`SourceRenderer` of the options' scene and supersampling to use
    (and whose counters say how much was shared); made if None.
    """
    opts = options or DesignOptions()
    renderer = renderer or SourceRenderer(_scene(opts), opts.supersample)
    sweep_renderers: dict = {}
    out = []
    for i, rig in enumerate(rigs):
        out.append(evaluate_rig(rig, opts, renderer=renderer, sweep_renderers=sweep_renderers))
        if progress is not None:
            progress(i + 1, len(rigs))
    log.info("design: %d viewpoint images rendered, %d reused", renderer.rendered, renderer.reused)
    return out


# ============================================================================ reference rigs


def _camera(template: CameraSpec | None, cam_id: str, position, rotation=(0.0, 0.0, 0.0)) -> CameraSpec:
    t = template or CameraSpec(id="cam", driver="mock", device=None, width=320, height=240, fps=30.0,
                               pixel_format="GREY", position=np.zeros(3), rotation=np.zeros(3), fov_deg=60.0)
    return dataclasses.replace(t, id=cam_id, device=None if t.driver == "mock" else t.device,
                               position=np.asarray(position, float), rotation=np.asarray(rotation, float))


_CUBE_ROTATIONS = {
    # axis-angle of R_rig_cam for a camera looking along each face normal (camera y stays "down"
    # for the side faces): the nested-cube face rotations of polycam.lightfield
    name: r_from_R(R_rig_face_for(name)) for name in FACE_NAMES
}


def single_camera_rig(camera: CameraSpec | None = None, name: str = "single") -> Rig:
    """One camera at the rig origin looking along +z (the classical small-FOV pinhole)."""
    return Rig(name=name, cameras=(_camera(camera, "cam0", (0, 0, 0)),), mock=MockSpec())


def planar_array_rig(rows: int, cols: int, pitch: float, camera: CameraSpec | None = None,
                     name: str | None = None) -> Rig:
    """A forward-looking rows x cols array with ``pitch`` [m] (the rig file's ``[grid]``)."""
    cams = []
    w = max(2, len(str(rows * cols - 1)))
    for r in range(rows):
        for c in range(cols):
            cams.append(_camera(camera, f"cam{r * cols + c:0{w}d}",
                                ((c - (cols - 1) / 2) * pitch, (r - (rows - 1) / 2) * pitch, 0.0)))
    return Rig(name=name or f"array{rows}x{cols}", cameras=tuple(cams), mock=MockSpec())


def cube_array_rig(n: int, pitch: float, camera: CameraSpec | None = None, half: float | None = None,
                   name: str | None = None) -> Rig:
    """Six faces, each an n x n array of ``pitch`` looking out of a cube of half-size ``half``
    [m] (default: half the array width + pitch); n = 1 with half = 0 is the spherical pinhole
    (six cameras sharing one centre)."""
    if half is None:
        half = (n - 1) * pitch / 2 + pitch
    cams = []
    for fn in FACE_NAMES:
        R = R_rig_face_for(fn)
        for r in range(n):
            for c in range(n):
                p_face = np.array([(c - (n - 1) / 2) * pitch, (r - (n - 1) / 2) * pitch, half])
                cams.append(_camera(camera, f"{fn.replace('+', 'p').replace('-', 'm')}_{r}{c}", R @ p_face,
                                    _CUBE_ROTATIONS[fn]))
    return Rig(name=name or (f"cube6x{n}x{n}" if half > 0 else "sphere6"), cameras=tuple(cams), mock=MockSpec())


def hierarchy_rigs(camera: CameraSpec | None = None, pitch: float = 0.02, n: int = 3) -> list[Rig]:
    """The paper's Fig. 3 hierarchy built from one camera type: a single camera (small-FOV
    pinhole), six cameras sharing a centre (spherical pinhole), an n x n array (small-FOV
    polydioptric) and six n x n arrays on a cube (spherical polydioptric)."""
    return [single_camera_rig(camera, "H1-pinhole"),
            cube_array_rig(1, pitch, camera, half=0.0, name="H2-spherical-pinhole"),
            planar_array_rig(n, n, pitch, camera, name="H3-polydioptric"),
            cube_array_rig(n, pitch, camera, name="H4-spherical-polydioptric")]
