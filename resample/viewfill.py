"""Depth-aware filling of the views between cameras (a plane sweep per view, lumigraph style).

Pull-push fills a view that no camera measured by interpolating its neighbours'
views at fixed (u, v): the depth-free limit, which ghosts wherever the scene is
not at infinity and breaks the plenoptic constraint the motion solver relies on.
This module replaces those views by interpolation *along the disparity*.

Geometry (face coordinates, SPEC.md). A scene point at depth ``Z`` in front of the
focal plane seen from viewpoint ``(x, y)`` has ``u = f (P_x - x) / Z``, so between two
viewpoints its direction moves by ``Δu = -f Δx / Z``. In grid indices, with the
*disparity* ``δ = f · step_x / (step_u · Z)`` (u-steps per x-step),

    L(target)(iv, iu) ≈ L(source s)(iv - δ r_y Δiy_s, iu - δ Δix_s),
    r_y = (step_y / step_x) (step_u / step_v),   Δi_s = source position − target position,

positions in (fractional) grid indices: a source view holds its camera's view from the
camera centre, which on a real rig is not exactly on the grid view (a 1 mm offset is
0.1 view steps of a 1 cm grid), so ``Δi_s`` is measured from that centre
(:func:`camera_positions`); a target view's position is its grid index.

**Which views.** A *source* is a view the cameras measured (a share of at least
``source_coverage`` of its cells have a full splat weight); a *target* is a view
with (almost) no measured cell (``target_coverage``). Each target takes the source
views within the smallest square ring (Chebyshev radius 1, 2, ... up to
``max_radius``: by default the views per camera spacing, at least 3) that holds at least two of
them, weighted by ``1 / distance²``.
For an auto grid (a view at every camera and one half-way) that is the two
cameras either side of a half-way view and the four around a centre view.

**Sweep.** For each candidate ``δ`` (``disparities``) every target sample gets the
source samples at the shifted positions (bilinear) and the cost is their weighted
variance, box-averaged over a ``(2 window + 1)²`` patch in (u, v). The disparity
with the smallest cost wins, refined to a fraction of a step by a parabola through
its neighbours. A candidate that sends a source off its view leaves that sample's
cost undefined (the box average uses the defined ones).

**Blend.** The target sample is the weighted mean of the source samples at its
disparity, each source weighted by ``1 / distance²`` times its confidence there.
The confidence ``W`` of filled samples stays the pull-push one (interpolated, not
measured: ``≤ attenuation``).

**Re-centring** (``ViewFillOptions.recentre``, with the cameras' positions). A camera view
holds the rays from the camera centre, which on a real rig is off its grid view by ``Δi`` and
off the focal plane by a height ``h``: its ray of direction ``(u, v)`` crosses the plane at
``(x, y) − h (u, v) / f``, so its offset from the view varies over the view,
``Δix(u) = Δix − h tan_u / step_x``. Before the other targets are filled, each such camera view
gets the sweep's disparity (matched against the nearest measured views, at offsets from its own
centre, itself as a source at offset 0) and is moved onto its view:
``L(view)(iv, iu) ≈ L(camera)(iv − δ r_y Δiy(v), iu − δ Δix(u))``; the other targets are then
filled from the grid views. A camera on its view and on the plane is left as it is. On a row
(or column) of views the offset across it is in steps along it (:func:`view_steps`): the
disparity per metre is the same in both directions.

Grey and colour frames are matched on the mean over channels and blended per channel.
No file I/O.

**Speed.** The sweep runs on ``downsample``-times smaller views, each source view shrunk
once per frame however many targets use it; a candidate disparity is one shift of every
source view, so its cost is computed row by row (vectorised), box-summed by running sums,
and the count of defined costs in a box is a product of two 1-D counts. The blend reads
the source views in place, per row first the sample positions and bilinear weights of a
source (vectorised), then its gathers. One numba thread per target view (about 0.1 s CPU
per frame for the 56 filled 296x384 views of a 9x9 grid from 5x5 cameras; docs/resample.md).
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field

import numba
import numpy as np

from polycam.lightfield import LightFieldGrid

__all__ = ["RECENTRE_SOURCES", "MIN_FILL_RADIUS", "source_spacing", "camera_views", "camera_positions", "view_steps",
           "camera_heights", "data_positions", "far_sources", "ViewFillOptions", "ViewFillPlan", "plan_view_fill",
           "fill_views"]

log = logging.getLogger(__name__)


RECENTRE_SOURCES = 4
"""Camera views a camera view is matched against when it is re-centred (the nearest; up to 8 lie
in the ring of a 2-D array's inner camera): the sweep's time grows with them, its disparity hardly
(docs/resample.md, step 6)."""

_MAX_CANDIDATES = 64
"""Most disparity candidates swept at full resolution (a larger range gets a coarser step)."""


@dataclass(frozen=True)
class ViewFillOptions:
    """Settings of the depth-aware view filling (see the module docstring)."""

    min_depth: float = 0.5
    """[m] nearest depth in front of the focal plane the sweep considers; sets the largest
    disparity ``f step_x / (step_u min_depth)``."""
    disparity_step: float = 0.375
    """Candidate spacing [u-steps of motion per x-step of viewpoint] before the sub-step refinement."""
    window: int = 3
    """Half-width [samples] of the (u, v) box over which the matching cost is averaged."""
    source_coverage: float = 0.25
    """A view is a source when at least this share of its cells have a full splat weight."""
    target_coverage: float = 0.02
    """A view is filled when less than this share of its cells have a full splat weight."""
    max_radius: int | None = None
    """Largest Chebyshev distance [views] at which sources are looked for. None (default): the
    larger of 3 and the sources' own spacing (:func:`source_spacing`: the views per camera spacing),
    so that every view between two cameras finds both however many views the grid puts between
    them. A fixed 3 left a row's views next to a camera with one source at 5 or more views per
    camera spacing (the other camera 4 or more views away): unfilled by the sweep, those views were
    the pull-push's depth-free blend and the motion erred 3–17x more (docs/motion.md, "A second view
    sampling")."""
    downsample: int = 2
    """The sweep runs on ``downsample x downsample`` averages of the views (and their disparity
    step is ``downsample`` times ``disparity_step``): much faster, and the box is wider."""
    refine: bool | None = None
    """After the sweep, try ``±disparity_step`` around it at full resolution. None (default): when
    some filled view's nearest source is about 2 or more view steps away (:func:`far_sources`: a grid
    with 4 views per camera spacing, as ``polycam run`` takes for linear arrays), where an error of
    the disparity per view step counts that many times at the sources. Measured
    (benchmarks/bench_view_fill.py; docs/resample.md, step 5): with 4 views per camera spacing the
    median translation error of five example rigs 2–23 % lower (webcam3x3 3.86 → 3.08 %), with 2
    within ±0.3 points either way, at twice the fill's time."""
    holes: bool = False
    """Also re-fill the holes (``W <= 0.5``) of the measured views, from the measured views
    around them (the pull-push fills them depth-free from the neighbouring views)."""
    recentre: bool = True
    """Move each camera's view onto its grid view along the disparity before the views between
    the cameras are filled from them (where the plan is given the cameras' positions): a camera view holds
    the rays from the camera centre, which on a real rig sits off its view in (x, y) and off the
    focal plane (each of its directions then crosses the plane at another (x, y)); the motion's
    derivatives across the views read those offsets as regressor errors, which shorten the
    translation (docs/resample.md, step 6). False: camera views keep their data as measured."""

    def __post_init__(self) -> None:
        if not (self.min_depth > 0 and self.disparity_step > 0 and self.window >= 0
                and (self.max_radius is None or self.max_radius >= 1)):
            raise ValueError("min_depth and disparity_step must be > 0, window >= 0, max_radius None or >= 1")
        if not 0 <= self.target_coverage < self.source_coverage <= 1:
            raise ValueError("need 0 <= target_coverage < source_coverage <= 1")


@dataclass(frozen=True)
class ViewFillPlan:
    """Which views are filled from which, for one grid and one splat geometry."""

    targets: tuple[tuple[int, int, int], ...]
    """(face, iy, ix) of every view to fill."""
    sources: tuple[np.ndarray, ...]
    """Per target: (S, 2) int64 source view indices (iy, ix) on the same face."""
    offsets: tuple[np.ndarray, ...]
    """Per target: (S, 2) float64 source minus target position (Δiy, Δix) [view steps]: grid
    indices, or the camera centres where the plan was given them (``camera_positions``)."""
    weights: tuple[np.ndarray, ...]
    """Per target: (S,) float32 source weights ``1 / distance²`` (distance in metres), summing to 1."""
    disparities: np.ndarray
    """(K,) float64 candidate disparities [u-steps per x-step], ascending."""
    r_y: tuple[float, ...]
    """Per face: v-steps per y-step for one u-step per x-step (``(step_y / step_x)(step_u / step_v)``)."""
    holes_only: tuple[bool, ...] = ()
    """Per target: a measured view of which only the holes (``W <= 0.5``) are re-filled."""
    shifts: tuple[np.ndarray, ...] = ()
    """Per target of a re-centring plan (:attr:`recentre`): (3,) float64 ``(Δiy, Δix, h)``, the
    camera centre minus its grid view [view steps; along a single-view axis, the other axis's] and
    its height above the focal plane [m]."""
    recentre: "ViewFillPlan | None" = None
    """The camera views re-centred onto their grid views before this plan's targets are filled
    from them (a plan whose first source per target is the camera view itself, at offset 0), or None."""
    tan_steps: tuple[tuple[np.ndarray, np.ndarray], ...] = ()
    """Per face of a re-centring plan: ``(tan_u / step_x (Nu,), tan_v / step_y (Nv,))`` [1/m], the
    directions' tangents over the view steps (a height ``h`` moves direction u's crossing of the
    plane by ``−h tan_u / step_x`` views)."""
    _arrays: dict = field(default_factory=dict, repr=False, compare=False)
    """The plan packed into arrays for the kernels (:func:`_packed`; built on first use)."""

    def __len__(self) -> int:
        return len(self.targets)


def far_sources(plan: "ViewFillPlan", steps: float = 1.5) -> bool:
    """Whether some target of ``plan`` has its nearest source more than ``steps`` view steps away
    (Chebyshev distance; ``ViewFillOptions.refine``'s default: the half-way view of a grid with 4
    views per camera spacing is 2 steps from its cameras, give or take their offsets)."""
    return any(len(o) and float(np.min(np.max(np.abs(o), axis=1))) > steps for o in plan.offsets)


def _camera_geometry(grid: LightFieldGrid, centres_rig: np.ndarray, axes_rig: np.ndarray):
    """(positions (F, Ny, Nx, 2), heights (F, Ny, Nx)) of :func:`camera_positions` and
    :func:`camera_heights`."""
    F, Ny, Nx = grid.shape[:3]
    out = np.full((F, Ny, Nx, 2), np.nan)
    height = np.full((F, Ny, Nx), np.nan)
    normals = np.stack([np.asarray(fc.R_rig_face, float)[:, 2] for fc in grid.faces])
    sx, sy = view_steps(grid)
    for c, a in zip(np.asarray(centres_rig, float), np.asarray(axes_rig, float)):
        k = int(np.argmax(normals @ a))
        p = np.asarray(grid.faces[k].R_rig_face, float).T @ c
        fx = (p[0] - grid.x.min) / sx if sx > 0 else 0.0
        fy = (p[1] - grid.y.min) / sy if sy > 0 else 0.0
        ix = int(round(fx)) if grid.x.count > 1 else 0       # a single-view axis: its one view
        iy = int(round(fy)) if grid.y.count > 1 else 0
        if 0 <= ix < Nx and 0 <= iy < Ny:
            pos = np.array([fy, fx])
            snap = np.abs(pos - np.round(pos)) < 1e-6
            out[k, iy, ix] = np.where(snap, np.round(pos), pos)
            h = float(p[2] - grid.faces[k].z_pi)
            height[k, iy, ix] = h if abs(h) >= 1e-9 else 0.0
    return out, height


def view_steps(grid: LightFieldGrid) -> tuple[float, float]:
    """(step_x, step_y) [m]: the grid's view steps, a single-view axis taking the other axis's (the
    unit in which :func:`camera_positions` gives offsets across a row or column of views; 0 for a
    single view)."""
    sx = grid.x.step if grid.x.count > 1 else 0.0
    sy = grid.y.step if grid.y.count > 1 else 0.0
    return (sx if sx > 0 else sy), (sy if sy > 0 else sx)


def camera_positions(grid: LightFieldGrid, centres_rig: np.ndarray, axes_rig: np.ndarray) -> np.ndarray:
    """(F, Ny, Nx, 2) float64: at the grid view nearest each camera centre (on the face its
    optical axis points into), that centre's position (iy, ix) in fractional grid indices;
    NaN at the other views. ``centres_rig``, ``axes_rig``: (N, 3) camera centres [m] and
    optical axes in the rig frame. Offsets below 1e-6 view steps are rounded away (a camera
    on a grid view is exactly there). Along a single-view axis (a row or column of views) the
    position is the centre's offset from that one view in steps of the other axis
    (:func:`view_steps`): the re-centring moves the camera views across the row too."""
    return _camera_geometry(grid, centres_rig, axes_rig)[0]


def camera_heights(grid: LightFieldGrid, centres_rig: np.ndarray, axes_rig: np.ndarray) -> np.ndarray:
    """(F, Ny, Nx) float64 [m]: at the grid view nearest each camera centre (as
    :func:`camera_positions`), the centre's height above the focal plane along the face's normal
    (``z`` in face coordinates minus ``z_pi``; below 1 nm: 0); NaN at the other views. A camera
    off the plane sees along each direction from another point of the plane: its ray of direction
    ``(u, v)`` crosses it at ``(x, y) − h (u, v) / f``."""
    return _camera_geometry(grid, centres_rig, axes_rig)[1]


def data_positions(plan: "ViewFillPlan", positions: np.ndarray) -> np.ndarray:
    """Where the camera views' data are after ``plan`` is applied: ``positions`` (F, Ny, Nx, 2),
    as :func:`camera_positions`, with the views the plan re-centres at their grid indices."""
    out = np.array(positions, float, copy=True)
    if plan.recentre is not None:
        for f, j, i in plan.recentre.targets:
            out[f, j, i] = (j, i)
    return out


def camera_views(grid: LightFieldGrid, centres_rig: np.ndarray, axes_rig: np.ndarray) -> np.ndarray:
    """(F, Ny, Nx) bool: the grid view nearest each camera centre, on the face its optical
    axis points into. ``centres_rig``, ``axes_rig``: (N, 3) camera centres [m] and optical
    axes in the rig frame."""
    return ~np.isnan(camera_positions(grid, centres_rig, axes_rig)[..., 0])


MIN_FILL_RADIUS = 3
"""The smallest search radius [views] of the default ``ViewFillOptions.max_radius``."""


def source_spacing(sources: np.ndarray) -> int:
    """The median over the set views of ``sources`` (Ny, Nx) bool of the Chebyshev distance [views]
    to the nearest other set view (the views per camera spacing of a camera array's grid); 0 with
    fewer than two."""
    jj, ii = np.nonzero(np.asarray(sources, bool))
    if jj.size < 2:
        return 0
    d = np.maximum(np.abs(jj[:, None] - jj[None, :]), np.abs(ii[:, None] - ii[None, :]))
    np.fill_diagonal(d, np.iinfo(d.dtype).max)
    return int(np.median(d.min(axis=1)))


def _neighbours(others: np.ndarray, j: int, i: int, max_radius: int, need: int):
    """(jj, ii) of the views set in ``others`` (Ny, Nx) within the smallest square ring around
    (j, i) (Chebyshev radius 1 .. ``max_radius``) that holds at least ``need``; None if none does."""
    for r in range(1, max_radius + 1):
        jj, ii = np.nonzero(others[max(0, j - r):j + r + 1, max(0, i - r):i + r + 1])
        if jj.size >= need:
            return jj + max(0, j - r), ii + max(0, i - r)
    return None


def plan_view_fill(grid: LightFieldGrid, w_clamped: np.ndarray,
                   options: ViewFillOptions | None = None, camera_views: np.ndarray | None = None,
                   camera_positions: np.ndarray | None = None,
                   camera_heights: np.ndarray | None = None) -> ViewFillPlan:
    """The fill plan for ``grid`` given the clamped splat weights ``w_clamped``
    (F, Ny, Nx, Nv, Nu) in [0, 1] (1 = measured). ``camera_views``: optional (F, Ny, Nx)
    bool, the views nearest a camera centre (:func:`camera_views`); the others count as
    unmeasured whatever splat weight they got (with cameras off the views, the splat
    kernel's tail gives the neighbouring views full weight from one camera's pixels: a
    copy of that camera's view at the wrong viewpoint). ``camera_positions``: optional
    (F, Ny, Nx, 2) from :func:`camera_positions` (implies ``camera_views``): the offsets
    and weights of a source are measured from its camera centre (and those of a measured
    view whose holes are re-filled from its own), not from its grid index.
    ``camera_heights``: optional (F, Ny, Nx) [m] from :func:`camera_heights` (None: 0).

    With positions and ``options.recentre``, each measured camera view off its grid view (or off
    the focal plane) is re-centred onto its view first (:attr:`ViewFillPlan.recentre`: the sweep
    matches it against the nearest measured views, at offsets from its centre), and the other
    targets are filled from the re-centred views, at their grid views. A row or column of views too:
    its offsets across the row are in steps along it (:func:`view_steps`), moved along the same
    disparity (docs/resample.md, step 6)."""
    opts = options or ViewFillOptions()
    F, Ny, Nx, Nv, Nu = grid.shape
    cov = np.mean(np.asarray(w_clamped) >= 1.0, axis=(3, 4))             # (F, Ny, Nx)
    pos = None
    if camera_positions is not None:
        pos = np.asarray(camera_positions, float)
        if pos.shape != (F, Ny, Nx, 2):
            raise ValueError(f"camera_positions must be (F, Ny, Nx, 2) = {(F, Ny, Nx, 2)}")
        camera_views = ~np.isnan(pos[..., 0]) if camera_views is None else camera_views
    if camera_views is not None:
        cov = np.where(np.asarray(camera_views, bool), cov, 0.0)
    height = np.zeros((F, Ny, Nx)) if camera_heights is None else np.nan_to_num(np.asarray(camera_heights, float))
    if height.shape != (F, Ny, Nx):
        raise ValueError(f"camera_heights must be (F, Ny, Nx) = {(F, Ny, Nx)}")
    sx = grid.x.step if grid.x.count > 1 else 0.0
    sy = grid.y.step if grid.y.count > 1 else 0.0

    def weights_of(off):
        d2 = (off[:, 0] * sy) ** 2 + (off[:, 1] * sx) ** 2
        return 1.0 / np.maximum(d2, 1e-30)

    # the camera views re-centred first: sources the camera view itself (offset 0) and the measured
    # views around it, at offsets from its centre
    rc = ([], [], [], [], [])
    if pos is not None and opts.recentre and (Nx > 1 or Ny > 1):
        for f in range(F):
            src = cov[f] >= opts.source_coverage
            for j, i in zip(*np.nonzero(src)):
                if np.isnan(pos[f, j, i, 0]):
                    continue
                shift = np.array([pos[f, j, i, 0] - j, pos[f, j, i, 1] - i, height[f, j, i]])
                if not np.any(shift != 0.0):
                    continue                                  # on its view and on the plane
                others = src.copy()
                others[j, i] = False
                nb = _neighbours(others, j, i, max(Ny, Nx), 1)     # the nearest, however far (4 views per spacing)
                if nb is None:
                    continue
                jj, ii = nb
                near = np.lexsort((np.hypot(jj - j, ii - i), np.maximum(abs(jj - j), abs(ii - i))))
                jj, ii = jj[near[:RECENTRE_SOURCES]], ii[near[:RECENTRE_SOURCES]]
                p_src = np.where(np.isnan(pos[f, jj, ii]), np.stack([jj, ii], axis=1), pos[f, jj, ii])
                off = np.concatenate([np.zeros((1, 2)), p_src - pos[f, j, i]])
                w = weights_of(off)
                w[0] = w[1:].max()                            # the view itself weighs as its nearest neighbour
                rc[0].append((f, int(j), int(i)))
                rc[1].append(np.concatenate([[[j, i]], np.stack([jj, ii], axis=1)]).astype(np.int64))
                rc[2].append(off)
                rc[3].append((w / w.sum()).astype(np.float32))
                rc[4].append(shift)
        if rc[0]:
            pos = pos.copy()
            for f, j, i in rc[0]:
                pos[f, j, i] = (j, i)                         # their data are at the views from now on

    targets, sources, offsets, weights, holes_only = [], [], [], [], []
    for f in range(F):
        src = cov[f] >= opts.source_coverage
        if src.sum() < 2:
            continue
        radius = opts.max_radius if opts.max_radius is not None else max(MIN_FILL_RADIUS, source_spacing(src))
        for j in range(Ny):
            for i in range(Nx):
                own = bool(src[j, i])
                if cov[f, j, i] >= opts.target_coverage and not (opts.holes and own):
                    continue
                others = src.copy()
                others[j, i] = False
                nb = _neighbours(others, j, i, radius, 2)
                if nb is None:
                    continue
                jj, ii = nb
                off = np.stack([jj - j, ii - i], axis=1).astype(np.float64)
                if pos is not None:         # from the camera centres (the target: its own, if any)
                    p_src = np.where(np.isnan(pos[f, jj, ii]), np.stack([jj, ii], axis=1), pos[f, jj, ii])
                    p_tgt = pos[f, j, i] if own and not np.isnan(pos[f, j, i, 0]) else np.array([j, i], float)
                    off = p_src - p_tgt
                w = weights_of(off)
                targets.append((f, j, i))
                holes_only.append(own)
                sources.append(np.stack([jj, ii], axis=1).astype(np.int64))
                offsets.append(off)
                weights.append((w / w.sum()).astype(np.float32))
    # candidate disparities: 0 (infinity) up to the nearest depth, on the face with the largest f
    r_y = []
    dmax = 0.0
    step_x, step_y = view_steps(grid)
    su = grid.u.step if grid.u.count > 1 else 1.0
    sv = grid.v.step if grid.v.count > 1 else 1.0
    for fc in grid.faces:
        r_y.append((step_y / step_x) * (su / sv) if step_x > 0 else 1.0)
        if step_x > 0:
            dmax = max(dmax, fc.f * step_x / (su * opts.min_depth))
    step = opts.disparity_step
    if dmax / step > _MAX_CANDIDATES:
        (log.warning if targets else log.debug)("view fill: disparities up to %.3g u-steps per x-step (min_depth %.3g m) would need %d "
                    "candidates; using %d, %.3g apart", dmax, opts.min_depth, int(dmax / step), _MAX_CANDIDATES,
                    dmax / _MAX_CANDIDATES)
        step = dmax / _MAX_CANDIDATES
    n = int(math.ceil(dmax / step)) + 1
    disp = np.arange(-1, n + 1) * step                          # one step beyond each end for the refinement
    recentre = None
    if rc[0]:
        tan_steps = tuple((grid.u.values / fc.f / step_x, grid.v.values / fc.f / step_y)   # view_steps': a
                          for fc in grid.faces)                                           # single axis in the other's
        recentre = ViewFillPlan(tuple(rc[0]), tuple(rc[1]), tuple(rc[2]), tuple(rc[3]), disp, tuple(r_y),
                                (False,) * len(rc[0]), tuple(rc[4]), tan_steps=tan_steps)
    plan = ViewFillPlan(tuple(targets), tuple(sources), tuple(offsets), tuple(weights), disp, tuple(r_y),
                        tuple(holes_only), recentre=recentre)
    log.info("view fill: %d views filled from their neighbours, %d camera views re-centred, over %d disparities "
             "(0..%.2f u-steps per x-step)", len(plan), len(recentre) if recentre else 0, disp.size, dmax)
    return plan


# ----------------------------------------------------------------------------- numba kernels
#
# One parallel loop over the target views; everything inside is serial (the views are
# many and equal in size, and a parallel region per small step costs more than it
# saves on a loaded machine).


@numba.njit(cache=True, inline="always")
def _corner1(x, N):
    """Linear-interpolation neighbours of x in [0, N - 1] along an axis of N samples: (x0, x1, fx)."""
    x0 = min(int(x), N - 2) if N > 1 else 0
    x1 = x0 + 1 if N > 1 else 0
    return x0, x1, np.float32(x - x0)


@numba.njit(cache=True, inline="always")
def _corners(y, x, Nv, Nu):
    """Bilinear corners of (y, x) inside an Nv x Nu image (y, x >= 0 and within the image):
    (y0, x0, y1, x1, fy, fx)."""
    y0, y1, fy = _corner1(y, Nv)
    x0, x1, fx = _corner1(x, Nu)
    return y0, x0, y1, x1, fy, fx


@numba.njit(cache=True, inline="always")
def _bilinear(img, y, x):
    """Bilinear sample of img (Nv, Nu) at (y, x); (value, inside)."""
    Nv, Nu = img.shape
    if not (y >= 0.0 and x >= 0.0 and y <= Nv - 1 and x <= Nu - 1):
        return np.float32(0.0), False
    y0, x0, y1, x1, fy, fx = _corners(y, x, Nv, Nu)
    a = img[y0, x0] + fx * (img[y0, x1] - img[y0, x0])
    if fy == 0.0:
        return a, True
    b = img[y1, x0] + fx * (img[y1, x1] - img[y1, x0])
    return a + fy * (b - a), True


@numba.njit(cache=True)
def _cost(G, S, dy, dx, sw, base, off, scale, r_y, cost, valid):
    """Per target sample (v, u): weighted variance of the S source samples (G: (≥S, Nv, Nu))
    at disparity ``base[v, u] + off`` [full-resolution units; ``scale`` converts to this
    level]; valid = 1 where every source sample is inside its view."""
    Nv, Nu = cost.shape
    for v in range(Nv):
        for u in range(Nu):
            d = (base[v, u] + off) * scale
            s0 = np.float32(0.0)
            s1 = np.float32(0.0)
            s2 = np.float32(0.0)
            ok = True
            for s in range(S):
                p, inside = _bilinear(G[s], v - d * r_y * dy[s], u - d * dx[s])
                if not inside:
                    ok = False
                    break
                s0 += sw[s]
                s1 += sw[s] * p
                s2 += sw[s] * p * p
            if ok:
                m = s1 / s0
                c = s2 / s0 - m * m
                cost[v, u] = c if c > 0.0 else np.float32(0.0)
                valid[v, u] = 1.0
            else:
                cost[v, u] = 0.0
                valid[v, u] = 0.0


@numba.njit(cache=True, fastmath=True)
def _box(a, r, tmp, out):
    """out = the (2r+1)² box sum of a (clipped at the borders); tmp: scratch of a's shape.
    Running sums; rows are views and indices unsigned (no negative-index checks in the loops)."""
    Nv, Nu = a.shape
    n = numba.uint64(Nu)
    ur = numba.uint64(r)
    for v in range(0, Nv, 4):       # four rows at a time: independent chains of adds
        a0, a1, a2, a3 = a[v], a[min(v + 1, Nv - 1)], a[min(v + 2, Nv - 1)], a[min(v + 3, Nv - 1)]
        t0, t1, t2, t3 = tmp[v], tmp[min(v + 1, Nv - 1)], tmp[min(v + 2, Nv - 1)], tmp[min(v + 3, Nv - 1)]
        c0 = c1 = c2 = c3 = np.float32(0.0)
        for u in range(numba.uint64(min(r, Nu - 1) + 1)):
            c0 += a0[u]
            c1 += a1[u]
            c2 += a2[u]
            c3 += a3[u]
        for u in range(n):
            t0[u] = c0
            t1[u] = c1
            t2[u] = c2
            t3[u] = c3
            if u + ur + 1 < n:
                c0 += a0[u + ur + 1]
                c1 += a1[u + ur + 1]
                c2 += a2[u + ur + 1]
                c3 += a3[u + ur + 1]
            if u >= ur:
                c0 -= a0[u - ur]
                c1 -= a1[u - ur]
                c2 -= a2[u - ur]
                c3 -= a3[u - ur]
    acc2 = np.zeros(Nu, np.float32)
    for v in range(min(r, Nv - 1) + 1):
        tr = tmp[v]
        for u in range(n):
            acc2[u] += tr[u]
    for v in range(Nv):
        orow = out[v]
        for u in range(n):
            orow[u] = acc2[u]
        if v + r + 1 < Nv:
            tr = tmp[v + r + 1]
            for u in range(n):
                acc2[u] += tr[u]
        if v - r >= 0:
            tr = tmp[v - r]
            for u in range(n):
                acc2[u] -= tr[u]


@numba.njit(cache=True)
def _sweep(G, S, dy, dx, sw, base, offs, scale, r_y, window, out):
    """out[v, u] = base + the offset (of ``offs``, ascending, equally spaced) with the smallest
    box-averaged cost, refined by a parabola through its neighbours."""
    Nv, Nu = out.shape
    cost = np.empty((Nv, Nu), np.float32)
    valid = np.empty((Nv, Nu), np.float32)
    tmp = np.empty((Nv, Nu), np.float32)
    agg_c = np.empty((Nv, Nu), np.float32)
    agg_n = np.empty((Nv, Nu), np.float32)
    best = np.full((Nv, Nu), np.inf, np.float32)
    best_k = np.full((Nv, Nu), -1, np.int64)
    c_left = np.full((Nv, Nu), np.inf, np.float32)
    c_right = np.full((Nv, Nu), np.inf, np.float32)
    prev = np.full((Nv, Nu), np.inf, np.float32)
    K = offs.shape[0]
    for k in range(K):
        _cost(G, S, dy, dx, sw, base, offs[k], scale, r_y, cost, valid)
        _box(cost, window, tmp, agg_c)
        _box(valid, window, tmp, agg_n)
        _update_best(k, agg_c, agg_n, best, best_k, c_left, c_right, prev)
    _refine_best(best, best_k, c_left, c_right, base, offs, out)


@numba.njit(cache=True)
def _update_best(k, agg_c, agg_n, best, best_k, c_left, c_right, prev):
    """Take candidate k's box-averaged cost agg_c / agg_n (box sums of the costs and of the
    samples with a cost; none: infinite) into the running minimum best / best_k (Nv, Nu) and
    the costs of its neighbouring candidates c_left / c_right; prev: candidate k - 1's cost."""
    Nv, Nu = best.shape
    for v in range(Nv):
        for u in range(Nu):
            n = agg_n[v, u]
            c = agg_c[v, u] / n if n > 0.5 else np.float32(np.inf)
            if best_k[v, u] == k - 1:
                c_right[v, u] = c
            if c < best[v, u]:
                best[v, u] = c
                best_k[v, u] = k
                c_left[v, u] = prev[v, u]
                c_right[v, u] = np.inf
            prev[v, u] = c


@numba.njit(cache=True)
def _refine_best(best, best_k, c_left, c_right, base, offs, out):
    """out = base + the best offset, moved by the vertex of the parabola through the costs
    of it and its neighbours (at most half a step); base where no offset had a cost."""
    Nv, Nu = out.shape
    K = offs.shape[0]
    step = offs[1] - offs[0] if K > 1 else 0.0
    inf = np.float32(np.inf)
    for v in range(Nv):
        bk, cl_r, c0_r, cr_r, b_r, o_r = best_k[v], c_left[v], best[v], c_right[v], base[v], out[v]
        for u in range(Nu):            # without branches, so it vectorises
            k = bk[u]
            cl, c0, cr = cl_r[u], c0_r[u], cr_r[u]
            den = cl - 2.0 * c0 + cr
            ok = (k >= 0) & (cl < inf) & (cr < inf) & (den > 0.0)         # (< inf: finite; costs >= 0)
            t = max(-0.5, min(0.5, 0.5 * (cl - cr) / den)) if ok else 0.0
            d = b_r[u] + offs[max(k, 0)]
            d = d + step * t if ok else d
            o_r[u] = d if k >= 0 else b_r[u]


@numba.njit(cache=True)
def _valid_span(o, n):
    """(lo, hi): the indices i in [0, n) with 0 <= i + o[s] <= n - 1 for every shift o[s]
    (empty when lo > hi)."""
    lo, hi = 0, n - 1
    for s in range(o.shape[0]):
        lo = max(lo, int(math.ceil(-o[s])))
        hi = min(hi, int(math.floor(n - 1 - o[s])))
    return lo, hi


@numba.njit(cache=True)
def _box_counts(lo, hi, r, n, out):
    """out[i] = how many of lo..hi lie in the box [i - r, i + r] (clipped to [0, n))."""
    for i in range(n):
        c = min(i + r, hi, n - 1) - max(i - r, lo, 0) + 1
        out[i] = np.float32(c) if c > 0 else np.float32(0.0)


@numba.njit(cache=True, fastmath=True)
def _cost_rows(G, src, S, oy, ox, sw, s0, v_lo, v_hi, u_lo, u_hi, s1, s2, cost):
    """The weighted variance of the S shifted source views G[src[s, 0], src[s, 1]] (G: (Ny, Nx,
    Nv, Nu)) at every sample of
    rows v_lo..v_hi, columns u_lo..u_hi (where every source sample is inside its view; the
    shifts (oy, ox) are the same at every sample), 0 elsewhere. s1, s2: (Nu,) scratch."""
    Nv, Nu = cost.shape
    iy = np.empty(S, np.int64)
    ix = np.empty(S, np.int64)
    fy = np.empty(S, np.float32)
    fx = np.empty(S, np.float32)
    for s in range(S):
        iy[s] = int(math.floor(oy[s]))
        ix[s] = int(math.floor(ox[s]))
        fy[s] = oy[s] - iy[s]
        fx[s] = ox[s] - ix[s]
    for v in range(Nv):
        if v < v_lo or v > v_hi or u_lo > u_hi:
            cost[v, :] = 0.0
            continue
        cost[v, :u_lo] = 0.0
        cost[v, u_hi + 1:] = 0.0
        s1[:] = 0.0
        s2[:] = 0.0
        for s in range(S):
            y0 = v + iy[s]
            y1 = y0 + 1 if fy[s] > 0.0 else y0          # inside: y0 + fy <= Nv - 1
            xo = ix[s]
            x1o = xo + 1 if fx[s] > 0.0 else xo
            g0 = G[src[s, 0], src[s, 1], y0]
            g1 = G[src[s, 0], src[s, 1], y1]
            x0 = numba.uint64(u_lo + xo)          # unsigned: no negative-index checks in the loop
            x1 = numba.uint64(u_lo + x1o)
            a_fx = fx[s]
            a_fy = fy[s]
            w = sw[s]
            for i in range(numba.uint64(u_hi + 1 - u_lo)):
                a = g0[x0 + i] + a_fx * (g0[x1 + i] - g0[x0 + i])
                b = g1[x0 + i] + a_fx * (g1[x1 + i] - g1[x0 + i])
                p = a + a_fy * (b - a)
                s1[numba.uint64(u_lo) + i] += w * p
                s2[numba.uint64(u_lo) + i] += w * p * p
        row = cost[v]
        for i in range(numba.uint64(u_lo), numba.uint64(u_hi + 1)):
            m = s1[i] / s0
            c = s2[i] / s0 - m * m
            row[i] = c if c > 0.0 else np.float32(0.0)


@numba.njit(cache=True)
def _sweep_const(G, src, S, dy, dx, sw, offs, scale, r_y, window, out):
    """:func:`_sweep` for a zero base disparity, over the source views G[src[s, 0], src[s, 1]]
    (G: (Ny, Nx, Nv, Nu)): each candidate is one shift of every source
    view, so its cost is computed row by row (vectorised over u) and the count of defined
    costs in each box is a product of two 1-D counts (the defined samples form a rectangle)."""
    Nv, Nu = out.shape
    K = offs.shape[0]
    s0 = np.float32(0.0)
    for s in range(S):
        s0 += sw[s]
    cost = np.empty((Nv, Nu), np.float32)
    tmp = np.empty((Nv, Nu), np.float32)
    agg_c = np.empty((Nv, Nu), np.float32)
    agg_n = np.empty((Nv, Nu), np.float32)
    s1 = np.empty(Nu, np.float32)
    s2 = np.empty(Nu, np.float32)
    rc = np.empty(Nv, np.float32)
    cc = np.empty(Nu, np.float32)
    best = np.full((Nv, Nu), np.inf, np.float32)
    best_k = np.full((Nv, Nu), -1, np.int64)
    c_left = np.full((Nv, Nu), np.inf, np.float32)
    c_right = np.full((Nv, Nu), np.inf, np.float32)
    prev = np.full((Nv, Nu), np.inf, np.float32)
    oy = np.empty(S)
    ox = np.empty(S)
    for k in range(K):
        d = offs[k] * scale
        for s in range(S):
            oy[s] = -d * r_y * dy[s]
            ox[s] = -d * dx[s]
        v_lo, v_hi = _valid_span(oy, Nv)
        u_lo, u_hi = _valid_span(ox, Nu)
        _cost_rows(G, src, S, oy, ox, sw, s0, v_lo, v_hi, u_lo, u_hi, s1, s2, cost)
        _box(cost, window, tmp, agg_c)
        _box_counts(v_lo, v_hi, window, Nv, rc)
        _box_counts(u_lo, u_hi, window, Nu, cc)
        for v in range(Nv):
            for u in range(Nu):
                agg_n[v, u] = rc[v] * cc[u]
        _update_best(k, agg_c, agg_n, best, best_k, c_left, c_right, prev)
    _refine_best(best, best_k, c_left, c_right, np.zeros((Nv, Nu), np.float32), offs, out)


@numba.njit(cache=True)
def _shrink(G, k, out):
    """k x k box average of the view G (Nv, Nu) into out (ceil(Nv/k), ceil(Nu/k))."""
    Nv, Nu = G.shape
    Mv, Mu = out.shape
    for i in range(Mv):
        for j in range(Mu):
            acc = np.float32(0.0)
            n = 0
            for a in range(k):
                for b in range(k):
                    y = k * i + a
                    x = k * j + b
                    if y < Nv and x < Nu:
                        acc += G[y, x]
                        n += 1
            out[i, j] = acc / n


@numba.njit(cache=True, parallel=True)
def _shrink_views(grey, views, k, out):
    """_shrink of the views grey[f, iy, ix] for every row (f, iy, ix) of views (V, 3) into
    out[f, iy, ix] (grey: (F, Ny, Nx, Nv, Nu); out: (F, Ny, Nx, ceil(Nv/k), ceil(Nu/k)))."""
    for n in numba.prange(views.shape[0]):
        f, j, i = views[n, 0], views[n, 1], views[n, 2]
        _shrink(grey[f, j, i], k, out[f, j, i])


@numba.njit(cache=True)
def _upsample(c, k, out):
    """Bilinear upsampling of a map of k x k averages to out's dims."""
    Mv, Mu = c.shape
    Nv, Nu = out.shape
    h = 0.5 * (k - 1)
    x0 = np.empty(Nu, np.int64)
    x1 = np.empty(Nu, np.int64)
    fx = np.empty(Nu, np.float32)
    for u in range(Nu):
        x = min(max((u - h) / k, 0.0), Mu - 1.0)
        _, x0[u], _, x1[u], _, fx[u] = _corners(0.0, x, Mv, Mu)
    for v in range(Nv):
        y = min(max((v - h) / k, 0.0), Mv - 1.0)
        y0, _, y1, _, fy, _ = _corners(y, 0.0, Mv, Mu)
        c0 = c[y0]
        c1 = c[y1]
        for u in range(Nu):
            a = c0[x0[u]] + fx[u] * (c0[x1[u]] - c0[x0[u]])
            if fy == 0.0:
                out[v, u] = a
            else:
                b = c1[x0[u]] + fx[u] * (c1[x1[u]] - c1[x0[u]])
                out[v, u] = a + fy * (b - a)


@numba.njit(cache=True, fastmath=True)
def _blend(Xf, Af, src, S, dy, dx, sw, r_y, d, out, tw, acc):
    """out[v, u, :] = Σ_s a_s X_s(v − d r_y dy_s, u − d dx_s) / Σ_s a_s (bilinear) with
    a_s = sw_s · A_s (nearest sample) at the per-sample disparity d (Nv, Nu), over the source
    views X_s = Xf[src[s, 0], src[s, 1]] (Xf: (Ny, Nx, Nv, Nu, C)) and their confidences
    A_s = Af[src[s, 0], src[s, 1]] (Af: (Ny, Nx, Nv, Nu)). Samples no source reaches keep out.
    tw (Nu,), acc (Nu, C): scratch. Computed row by row, the sources in order at each sample."""
    _, _, Nv, Nu, C = Xf.shape
    for v in range(Nv):
        dv = d[v]
        for u in range(Nu):
            tw[u] = 0.0
            for c in range(C):
                acc[u, c] = 0.0
        for s in range(S):
            X = Xf[src[s, 0], src[s, 1]]
            A = Af[src[s, 0], src[s, 1]]
            ky = r_y * dy[s]
            kx = dx[s]
            w = sw[s]
            same_row = ky == 0.0               # (a source beside the target: yy = v everywhere)
            y0, y1, fy = _corner1(float(v), Nv)
            for u in range(Nu):
                dd = dv[u]
                xx = u - dd * kx
                if not (xx >= 0.0 and xx <= Nu - 1):
                    continue
                if not same_row:
                    yy = v - dd * ky
                    if not (yy >= 0.0 and yy <= Nv - 1):
                        continue
                    y0, y1, fy = _corner1(yy, Nv)
                x0, x1, fx = _corner1(xx, Nu)
                # unsigned indices (all >= 0 here): no negative-index wrap-around checks
                ya = numba.uint64(y0 + 1 if fy > 0.5 else y0)
                xa = numba.uint64(x0 + 1 if fx > 0.5 else x0)
                a = w * max(A[ya, xa], np.float32(1e-3))
                tw[u] += a
                uy0, ux0, uy1, ux1 = numba.uint64(y0), numba.uint64(x0), numba.uint64(y1), numba.uint64(x1)
                if C == 1:
                    p0 = X[uy0, ux0, 0] + fx * (X[uy0, ux1, 0] - X[uy0, ux0, 0])
                    p1 = X[uy1, ux0, 0] + fx * (X[uy1, ux1, 0] - X[uy1, ux0, 0])
                    acc[u, 0] += a * (p0 + fy * (p1 - p0))
                    continue
                for c in range(C):
                    uc = numba.uint64(c)
                    p0 = X[uy0, ux0, uc] + fx * (X[uy0, ux1, uc] - X[uy0, ux0, uc])
                    p1 = X[uy1, ux0, uc] + fx * (X[uy1, ux1, uc] - X[uy1, ux0, uc])
                    acc[u, c] += a * (p0 + fy * (p1 - p0))
        for u in range(Nu):
            if tw[u] > 0.0:
                for c in range(C):
                    out[v, u, c] = acc[u, c] / tw[u]


@numba.njit(cache=True, fastmath=True)
def _blend_grey(Xf, Af, src, S, dy, dx, sw, r_y, d, out, scratch):
    """:func:`_blend` for grey views (Xf: (Ny, Nx, Nv, Nu); out: (Nv, Nu)), the same
    arithmetic in two passes per row and source: the sample positions, their bilinear
    corners and weights (vectorised), then the gathers, skipping the second row (column)
    of the bilinear sample where its weight is 0 (a source beside the target is read
    along one row, one above or below along one column). scratch: from :func:`_blend_scratch`."""
    Nv, Nu = d.shape
    n = numba.uint64(Nu)
    NuU = numba.uint64(Nu)
    Nu2, Nv2 = numba.uint64(Nu - 2), numba.uint64(Nv - 2)
    tw, acc, fxa, fya = scratch[0], scratch[1], scratch[2], scratch[3]
    i0 = scratch[4].view(np.uint32)
    ia = scratch[5].view(np.uint32)
    ok = scratch[6].view(np.uint32)
    for v in range(Nv):
        dv = d[v]
        for u in range(n):
            tw[u] = 0.0
            acc[u] = 0.0
        for s in range(S):
            X = Xf[src[s, 0], src[s, 1]].ravel()
            A = Af[src[s, 0], src[s, 1]].ravel()
            ky = r_y * dy[s]
            kx = dx[s]
            w = sw[s]
            for u in range(n):          # positions, corners, weights
                dd = dv[u]
                xx = u - dd * kx
                yy = v - dd * ky
                ok[u] = (xx >= 0.0) & (xx <= Nu - 1) & (yy >= 0.0) & (yy <= Nv - 1)
                xc = min(max(xx, 0.0), Nu - 1.0)
                yc = min(max(yy, 0.0), Nv - 1.0)
                x0 = min(numba.uint64(xc), Nu2)
                y0 = min(numba.uint64(yc), Nv2)
                fx = np.float32(xc - x0)
                fy = np.float32(yc - y0)
                fxa[u] = fx
                fya[u] = fy
                i0[u] = y0 * NuU + x0
                ia[u] = (y0 + numba.uint64(fy > 0.5)) * NuU + x0 + numba.uint64(fx > 0.5)   # nearest
            for u in range(n):          # gathers
                if not ok[u]:
                    continue
                j = numba.uint64(i0[u])
                fx = fxa[u]
                fy = fya[u]
                a = w * max(A[numba.uint64(ia[u])], np.float32(1e-3))
                p = X[j]
                if fx != 0.0:
                    p += fx * (X[j + 1] - p)
                if fy != 0.0:
                    q = X[j + NuU]
                    if fx != 0.0:
                        q += fx * (X[j + NuU + 1] - q)
                    p += fy * (q - p)
                tw[u] += a
                acc[u] += a * p
        orow = out[v]
        for u in range(n):
            if tw[u] > 0.0:
                orow[u] = acc[u] / tw[u]


@numba.njit(cache=True, fastmath=True)
def _shift_view(X, d, dy0, dx0, h, ax, ay, r_y, out):
    """out[v, u, :] = X(v − d r_y (dy0 − h ay[v]), u − d (dx0 − h ax[u]), :) (bilinear, clamped to
    the view): a camera view X (Nv, Nu, C) seen from its centre, moved onto its grid view along the
    per-sample disparity d (Nv, Nu) [u-steps per x-step]; (dy0, dx0) [view steps] the centre minus
    the view, h [m] its height above the focal plane, ax (Nu,), ay (Nv,) [1/m] the tangents per view
    step (:attr:`ViewFillPlan.tan_steps`)."""
    Nv, Nu, C = X.shape
    for v in range(Nv):
        kyv = r_y * (dy0 - h * ay[v])
        for u in range(Nu):
            dd = d[v, u]
            xx = min(max(u - dd * (dx0 - h * ax[u]), 0.0), Nu - 1.0)
            yy = min(max(v - dd * kyv, 0.0), Nv - 1.0)
            y0, x0, y1, x1, fy, fx = _corners(yy, xx, Nv, Nu)
            for c in range(C):
                a = X[y0, x0, c] + fx * (X[y0, x1, c] - X[y0, x0, c])
                b = X[y1, x0, c] + fx * (X[y1, x1, c] - X[y1, x0, c])
                out[v, u, c] = a + fy * (b - a)


@numba.njit(cache=True)
def _blend_scratch(Nu):
    """Row scratch of :func:`_blend_grey`: (7, Nu) float32."""
    return np.empty((7, Nu), np.float32)


@numba.njit(cache=True, parallel=True)
def _fill_all(grey, grey_c, Lsrc, L, L_grey, W, targets, holes, srcs, offs, sws, nsrc, r_y, coarse, k_down, fine, window,
              disp_out, shifts, ax, ay):
    """Fill every target view of L (F, Ny, Nx, Nv, Nu, C) in place from the source views of
    Lsrc (L itself when no target is a source), their grey values grey (F, Ny, Nx, Nv, Nu) and
    k_down x k_down averages of those grey_c (F, Ny, Nx, Mv, Mu); disp_out (T, Nv, Nu) receives
    the disparities (or (0, Nv, Nu): not kept). A target
    with holes[t] keeps its samples with W > 0.5. With C = 1, L_grey is L's (F, Ny, Nx, Nv, Nu)
    view, grey Lsrc's, and the blend runs on those. shifts (T, 3) (a re-centring pass; (0, 3)
    otherwise): each target is its own first source, moved onto its view along the disparity
    (:func:`_shift_view`, with ax (F, Nu), ay (F, Nv)) instead of blended from the sources."""
    F, Ny, Nx, Nv, Nu, C = L.shape
    Mv, Mu = (Nv + k_down - 1) // k_down, (Nu + k_down - 1) // k_down
    T = targets.shape[0]
    Smax = srcs.shape[1]
    for t in numba.prange(T):
        f, j, i = targets[t, 0], targets[t, 1], targets[t, 2]
        S = nsrc[t]
        src = srcs[t]
        dy = offs[t, :, 0].copy()
        dx = offs[t, :, 1].copy()
        sw = sws[t]
        ry = r_y[f]
        d = disp_out[t] if disp_out.shape[0] > 0 else np.empty((Nv, Nu), np.float32)
        # coarse: the whole disparity range at 1/k_down resolution
        dc = np.empty((Mv, Mu), np.float32)
        _sweep_const(grey_c[f], src, S, dy, dx, sw, coarse, 1.0 / k_down, ry, window, dc)
        _upsample(dc, k_down, d)
        if fine.shape[0] > 1:       # a few steps around it at full resolution
            G = np.empty((Smax, Nv, Nu), np.float32)
            for s in range(S):
                G[s] = grey[f, src[s, 0], src[s, 1]]
            base = d.copy()
            _sweep(G, S, dy, dx, sw, base, fine, 1.0, ry, window, d)
        if shifts.shape[0] > 0:     # re-centre the camera view (its own first source)
            _shift_view(Lsrc[f, j, i], d, shifts[t, 0], shifts[t, 1], shifts[t, 2], ax[f], ay[f], ry, L[f, j, i])
            continue
        if C == 1:              # grey: L_grey is L without its channel axis, grey the sources
            scratch = _blend_scratch(Nu)
            if holes[t]:
                tmp1 = grey[f, j, i].copy()
                _blend_grey(grey[f], W[f], src, S, dy, dx, sw, ry, d, tmp1, scratch)
                for v in range(Nv):
                    for u in range(Nu):
                        if W[f, j, i, v, u] <= 0.5:
                            L_grey[f, j, i, v, u] = tmp1[v, u]
            else:
                _blend_grey(grey[f], W[f], src, S, dy, dx, sw, ry, d, L_grey[f, j, i], scratch)
            continue
        tw = np.empty(Nu, np.float32)
        acc = np.empty((Nu, C), np.float32)
        if holes[t]:
            tmp = Lsrc[f, j, i].copy()
            _blend(Lsrc[f], W[f], src, S, dy, dx, sw, ry, d, tmp, tw, acc)
            for v in range(Nv):
                for u in range(Nu):
                    if W[f, j, i, v, u] <= 0.5:
                        L[f, j, i, v, u] = tmp[v, u]
        else:
            _blend(Lsrc[f], W[f], src, S, dy, dx, sw, ry, d, L[f, j, i], tw, acc)


# ----------------------------------------------------------------------------- driver


def _packed(plan: ViewFillPlan) -> tuple:
    """The plan as arrays (built once per plan): targets (T, 3) int64, sources (T, Smax, 2)
    int64, offsets (T, Smax, 2) float64, weights (T, Smax) float32, source counts (T,) int64,
    the source views (V, 3) int64 (f, iy, ix), holes_only (T,) bool, r_y (F,) float64."""
    if "packed" not in plan._arrays:
        T = len(plan)
        Smax = max(s.shape[0] for s in plan.sources)
        srcs = np.zeros((T, Smax, 2), np.int64)
        offs = np.zeros((T, Smax, 2), np.float64)
        sws = np.zeros((T, Smax), np.float32)
        nsrc = np.zeros(T, np.int64)
        for t in range(T):
            n = plan.sources[t].shape[0]
            srcs[t, :n] = plan.sources[t]
            offs[t, :n] = plan.offsets[t]
            sws[t, :n] = plan.weights[t]
            nsrc[t] = n
        views = np.unique(np.concatenate([np.concatenate([np.full((len(sv), 1), f), sv], axis=1)
                                          for (f, _, _), sv in zip(plan.targets, plan.sources)]), axis=0)
        holes = np.array(plan.holes_only if plan.holes_only else [False] * T, np.bool_)
        plan._arrays["packed"] = (np.array(plan.targets, np.int64), srcs, offs, sws, nsrc, views, holes,
                                  np.array(plan.r_y, np.float64))
    return plan._arrays["packed"]


def fill_views(L: np.ndarray, W: np.ndarray, plan: ViewFillPlan, options: ViewFillOptions | None = None,
               disparity_out: np.ndarray | None = None) -> None:
    """Fill the target views of ``plan`` in ``L`` in place (see the module docstring).

    L: (F, Ny, Nx, Nv, Nu, C) float32 pulled-pushed values (C-contiguous).
    W: (F, Ny, Nx, Nv, Nu) float32 confidences (read: source confidences).
    disparity_out: optional (F, Ny, Nx, Nv, Nu) float32 array receiving the disparity chosen
        at each filled sample [u-steps per x-step] (for diagnostics).
    """
    opts = options or ViewFillOptions()
    if L.ndim != 6 or L.dtype != np.float32 or not L.flags.c_contiguous or L.shape[:5] != W.shape:
        raise ValueError("L must be C-contiguous float32 (F, Ny, Nx, Nv, Nu, C) and W (F, Ny, Nx, Nv, Nu)")
    if plan.recentre is not None and len(plan.recentre):       # first: the fill reads the re-centred views
        _fill_pass(L, W, plan.recentre, opts, disparity_out, recentre=True)
    if len(plan):
        _fill_pass(L, W, plan, opts, disparity_out)


def _fill_pass(L: np.ndarray, W: np.ndarray, plan: ViewFillPlan, opts: ViewFillOptions,
               disparity_out: np.ndarray | None, recentre: bool = False) -> None:
    """One parallel pass of :func:`fill_views` over ``plan``'s targets (a re-centring plan with
    ``recentre``)."""
    T = len(plan)
    Nv, Nu = L.shape[3:5]
    targets, srcs, offs, sws, nsrc, views, holes, r_y = _packed(plan)
    disp = np.empty((T if disparity_out is not None else 0, Nv, Nu), np.float32)    # (else per target)
    step = float(plan.disparities[1] - plan.disparities[0])
    k = int(opts.downsample)
    d_max = plan.disparities[-1]
    coarse = np.arange(-1, int(math.ceil(d_max / (k * step))) + 1) * (k * step)   # same step at 1/k resolution
    # the re-centring's shifts are a fraction of a view step: the coarse sweep is enough there
    # (refined: 2x its time for no gain on the example rigs at 1 mm, docs/resample.md step 6)
    refine = bool(opts.refine) if recentre else (far_sources(plan) if opts.refine is None else bool(opts.refine))
    if recentre:
        shifts = np.array(plan.shifts, np.float64).reshape(T, 3)
        ax = np.stack([a for a, _ in plan.tan_steps]).astype(np.float64)
        ay = np.stack([b for _, b in plan.tan_steps]).astype(np.float64)
    else:
        shifts = np.zeros((0, 3))
        ax, ay = np.zeros((0, Nu)), np.zeros((0, Nv))
    fine = np.array([-step, 0.0, step]) if refine else np.zeros(1)
    Lsrc = L.copy() if (holes.any() or recentre) else L          # sources are re-filled too: read a snapshot
    grey = Lsrc.mean(axis=5) if L.shape[5] > 1 else Lsrc.reshape(L.shape[:5])     # (a view for grey frames)
    Mv, Mu = (Nv + k - 1) // k, (Nu + k - 1) // k
    grey_c = np.empty((*L.shape[:3], Mv, Mu), np.float32)    # only the source views are set
    _shrink_views(grey, views, k, grey_c)
    L_grey = L.reshape(L.shape[:5]) if L.shape[5] == 1 else grey                 # (unused for colour)
    _fill_all(grey, grey_c, Lsrc, L, L_grey, np.ascontiguousarray(W, np.float32), targets, holes, srcs,
              offs, sws, nsrc, r_y, coarse, k, fine, int(opts.window), disp, shifts, ax, ay)
    if disparity_out is not None:
        for t, (f, j, i) in enumerate(plan.targets):
            disparity_out[f, j, i] = disp[t]
