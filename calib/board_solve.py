"""Board calibration with mrcal: seed, staged joint solve of every camera's intrinsics and
extrinsics, rig-frame alignment, and cameramodels that keep their ``optimization_inputs``.

Pipeline (:func:`calibrate_board`), all mrcal's own machinery:

1. Camera graph: cameras that saw the board in the same frame (>= 2 shared
   frames, mrcal's own threshold for a usable link). A camera with no board
   views, or one not connected to the others, is an :class:`InputError`
   naming it.
2. Seed: ``mrcal.seed_stereographic`` (monocular PnP per view with a
   stereographic core from the rig file's ``fov_deg``, relative camera poses
   along ``mrcal.traverse_sensor_links``, board poses from
   ``mrcal.estimate_joint_frame_poses``).
3. Staged ``mrcal.optimize`` (as ``mrcal-calibrate-cameras`` does): geometry
   only, then the stereographic core, then (for OPENCV5/8) OPENCV4, then the full lens model (OPENCV4/5/8,
   or splined stereographic with its core locked) with outlier rejection and
   regularisation, and a last pass that also fits the board's flex
   (``calobject_warp``) unless disabled.
4. Rig frame: the solve's reference is camera 0; :func:`calib.align.fit_rig_frame`
   rigidly maps the solved cameras onto the rig file's nominal poses, and each
   model stores ``rt_cam_ref = T_cam_rig``. The ``optimization_inputs`` stay in
   the solve's frame (mrcal's uncertainty and diff tools only need the camera
   frame), so ``mrcal-show-projection-uncertainty`` etc. work on the files.

Board frames: mrcal's board origin is the first inner corner; OpenCV's (and
polycam's, :mod:`polycam.board`) is the outer corner of the first square, so a
point ``p_cv = p_mrcal + (s, s, 0)`` for square length ``s``.
"""

from __future__ import annotations

import logging
import math
import re
from dataclasses import dataclass, field

import numpy as np

from polycam.errors import InputError, PolycamError
from polycam.geometry import T_from_rt, T_inverse, rt_from_T
from polycam.rig import Rig

from .align import RigFit, fit_rig_frame
from .detect import BoardObservations

__all__ = [
    "LENSMODEL_CHOICES",
    "lensmodel_name",
    "camera_graph",
    "BoardCalibration",
    "CameraStats",
    "calibrate_board",
    "observation_residuals",
    "board_distance",
    "extrinsics_uncertainty",
    "state_covariance",
    "board_rms_px",
    "lens_rotation",
    "uncertainty_grid",
    "valid_region_contour",
]

log = logging.getLogger(__name__)

LENSMODEL_CHOICES = ("opencv4", "opencv5", "opencv8", "splined")
"""Short lens-model names accepted by :func:`lensmodel_name` (or a full ``LENSMODEL_...``)."""

MIN_SHARED_FRAMES = 2
"""Frames two cameras must share for a link in the camera graph (mrcal's seeding needs 2)."""


def _mrcal():
    import mrcal  # lazily: heavy

    return mrcal


def lensmodel_name(name: str, fov_x_deg: float = 90.0, spline_knots: tuple[int, int] = (16, 12)) -> str:
    """Full mrcal lens-model string for a short name (:data:`LENSMODEL_CHOICES`) or a full one.

    ``splined`` → ``LENSMODEL_SPLINED_STEREOGRAPHIC_order=3_Nx=16_Ny=12_fov_x_deg=<fov_x_deg>``.
    """
    n = name.strip()
    if n.upper().startswith("LENSMODEL_"):
        try:
            _mrcal().lensmodel_num_params(n)
        except Exception:
            raise InputError(f"unknown mrcal lens model {n!r}") from None
        return n
    key = n.lower()
    if key in ("opencv4", "opencv5", "opencv8"):
        return f"LENSMODEL_OPENCV{key[-1]}"
    if key == "splined":
        Nx, Ny = spline_knots
        return f"LENSMODEL_SPLINED_STEREOGRAPHIC_order=3_Nx={Nx}_Ny={Ny}_fov_x_deg={int(math.ceil(fov_x_deg))}"
    raise InputError(f"unknown lens model {name!r} (choose one of {', '.join(LENSMODEL_CHOICES)} "
                     "or a full mrcal LENSMODEL_... name)")


def camera_graph(indices_frame_camera: np.ndarray, n_cameras: int) -> np.ndarray:
    """(C, C) int: number of frames in which cameras i and j both saw the board (0 diagonal)."""
    idx = np.asarray(indices_frame_camera)
    frames = np.unique(idx[:, 0])
    seen = np.zeros((frames.size, n_cameras), dtype=np.int64)
    seen[np.searchsorted(frames, idx[:, 0]), idx[:, 1]] = 1
    shared = seen.T @ seen
    np.fill_diagonal(shared, 0)
    return shared


def _components(adjacent: np.ndarray) -> list[list[int]]:
    """Connected components (lists of indices) of a boolean adjacency matrix, largest first."""
    n = adjacent.shape[0]
    label = -np.ones(n, int)
    comps = []
    for s in range(n):
        if label[s] >= 0:
            continue
        stack, comp = [s], []
        label[s] = len(comps)
        while stack:
            i = stack.pop()
            comp.append(i)
            for j in np.flatnonzero(adjacent[i]):
                if label[j] < 0:
                    label[j] = len(comps)
                    stack.append(j)
        comps.append(sorted(comp))
    return sorted(comps, key=lambda c: (-len(c), c[0]))


def _check_graph(obs: BoardObservations) -> np.ndarray:
    """The shared-frames matrix; raises InputError for cameras without views or links."""
    mrcal = _mrcal()
    C = len(obs.cameras)
    n_views = np.bincount(obs.indices_frame_camera[:, 1], minlength=C)
    blind = [obs.cameras[i] for i in range(C) if n_views[i] == 0]
    if blind:
        detail = "; ".join(
            f"{c}: " + ", ".join(f"{v} {k}" for k, v in obs.counts.get(c, {}).items() if v and k != "used")
            for c in blind)
        raise InputError(f"no usable board view in camera(s) {', '.join(blind)} ({detail})")
    shared = camera_graph(obs.indices_frame_camera, C)
    if C == 1:
        return shared
    links = np.where(shared >= MIN_SHARED_FRAMES, shared, 0).astype(np.uint16)
    reached = {0}
    mrcal.traverse_sensor_links(connectivity_matrix=links,
                                callback_sensor_link=lambda to, frm: reached.add(int(to)) or True)
    if len(reached) < C:
        comps = _components(links > 0)
        groups = " | ".join("{" + ", ".join(obs.cameras[i] for i in c) + "}" for c in comps)
        lonely = [obs.cameras[i] for i in range(C) if i not in reached]
        raise InputError(f"cameras not connected through shared board views (>= {MIN_SHARED_FRAMES} frames "
                         f"seen together): {', '.join(lonely)} cannot be tied to {obs.cameras[0]}; "
                         f"groups: {groups}")
    return shared


@dataclass(frozen=True)
class CameraStats:
    """Residual statistics of one camera after the solve."""

    views: int
    """Board views used."""
    corners: int
    """Corner observations (inliers)."""
    outliers: int
    """Corner observations rejected as outliers."""
    rms_px: float
    """[px] RMS of the inlier reprojection errors per coordinate (mrcal's convention:
    sqrt(mean(ex^2 + ey^2) / 2))."""
    worst_px: float
    """[px] largest inlier reprojection error."""
    worst_path: str
    """Image holding the worst inlier."""


@dataclass
class BoardCalibration:
    """Result of :func:`calibrate_board`."""

    cameras: list[str]
    models: dict
    """Camera id → mrcal.cameramodel (rt_cam_ref = T_cam_rig, with optimization_inputs)."""
    lensmodel: str
    optimization_inputs: dict
    """The final mrcal problem (reference frame = camera 0's)."""
    rig_fit: RigFit
    """Alignment of the solve to the rig file's nominal poses."""
    shared_frames: np.ndarray
    """(C, C) frames each pair of cameras saw the board in together (the camera graph)."""
    rms_px: float
    """[px] overall RMS reprojection error per coordinate (inliers, mrcal's convention)."""
    stats: dict[str, CameraStats]
    observations: BoardObservations
    frames: np.ndarray
    """(F,) session frame index of each solved board pose."""
    stages: list[tuple[str, float]] = field(default_factory=list)
    """(stage name, RMS [px] after it) of the staged solve."""
    uncertainty: dict[str, np.ndarray] = field(default_factory=dict)
    """Camera id → (Ny, Nx) [px] worst-direction projection uncertainty at the median board
    distance on mrcal.sample_imager's 30-wide grid (empty unless computed)."""

    @property
    def T_rig_cam(self) -> dict[str, np.ndarray]:
        """Camera id → (4, 4) solved pose in the rig frame."""
        return {c: T_inverse(T_from_rt(m.rt_cam_ref())) for c, m in self.models.items()}


def observation_residuals(inputs: dict) -> tuple[np.ndarray, np.ndarray]:
    """Unweighted reprojection errors of every board corner of a solved mrcal problem.

    Returns (err (N, H, W, 2) [px] projected − observed, weight (N, H, W); < 0 where the
    corner was not seen or is an outlier).
    """
    mrcal = _mrcal()
    obs = inputs["observations_board"]
    idx = inputs["indices_frame_camintrinsics_camextrinsics"]
    H, W = obs.shape[1:3]
    pts = mrcal.ref_calibration_object(W, H, inputs["calibration_object_spacing"],
                                       calobject_warp=inputs.get("calobject_warp"))
    p_ref = mrcal.transform_point_rt(inputs["rt_ref_frame"][idx[:, 0]][:, None, None, :], pts)
    rt_cam_ref = np.zeros((len(idx), 6))
    has_ext = idx[:, 2] >= 0
    if np.any(has_ext):
        rt_cam_ref[has_ext] = inputs["rt_cam_ref"][idx[has_ext, 2]]
    p_cam = mrcal.transform_point_rt(rt_cam_ref[:, None, None, :], p_ref)
    q = np.empty(p_cam.shape[:-1] + (2,))
    for ci in np.unique(idx[:, 1]):
        sel = idx[:, 1] == ci
        q[sel] = mrcal.project(np.ascontiguousarray(p_cam[sel]), inputs["lensmodel"], inputs["intrinsics"][ci])
    return q - obs[..., :2], obs[..., 2]


def _stats(inputs: dict, obs: BoardObservations, initial_weight: np.ndarray) -> tuple[float, dict]:
    err, w = observation_residuals(inputs)
    e = np.linalg.norm(err, axis=-1)
    idx = inputs["indices_frame_camintrinsics_camextrinsics"]
    inl = w > 0
    out = {}
    for ci, cam in enumerate(obs.cameras):
        sel = idx[:, 1] == ci
        ei, mi = e[sel], inl[sel]
        vals = ei[mi]
        rms = _rms_per_coordinate(vals)
        if vals.size:
            k = int(np.argmax(np.where(mi, ei, -1).reshape(len(ei), -1).max(axis=1)))
            worst = float(vals.max())
            worst_path = obs.paths[int(np.flatnonzero(sel)[k])]
        else:
            worst, worst_path = float("nan"), ""
        outl = int(np.count_nonzero((initial_weight[sel] > 0) & ~mi))
        out[cam] = CameraStats(views=int(sel.sum()), corners=int(mi.sum()), outliers=outl, rms_px=rms,
                               worst_px=worst, worst_path=worst_path)
    return _rms_per_coordinate(e[inl]), out


def _focal_estimates(obs: BoardObservations, rig: Rig | None) -> np.ndarray:
    f = []
    for cam, (W, _H) in zip(obs.cameras, obs.imagersizes):
        fov = rig.camera(cam).fov_deg if rig is not None else 60.0
        f.append((W / 2.0) / math.tan(math.radians(fov) / 2.0))
    return np.array(f)


def board_distance(inputs: dict) -> float:
    """[m] median distance from the reference camera to the solved board poses."""
    return float(np.median(np.linalg.norm(inputs["rt_ref_frame"][:, 3:], axis=1)))


def state_covariance(inputs: dict, noise_px: float, columns: np.ndarray) -> np.ndarray:
    """(n, n) covariance of the solve's state entries ``columns`` ((n,) int indices into mrcal's
    state vector, e.g. from ``mrcal.state_index_intrinsics``), in their own (unpacked) units.

    mrcal's first-order propagation of independent Gaussian corner noise of ``noise_px`` per
    coordinate (for weight-1 corners; a corner of weight w has ``noise_px / w``) through the final
    solve: ``Var(b) = σ² (JᵀJ)⁻¹ J_obsᵀ J_obs (JᵀJ)⁻¹`` with J the Jacobian at the optimum
    (regularisation included in JᵀJ, as ``mrcal.projection_uncertainty`` does). Only the n
    requested columns of the inverse are solved for (a sparse factorisation), so large problems
    (thousands of board poses) stay cheap. inputs: the solve's ``optimization_inputs``.
    """
    from scipy.sparse.linalg import splu

    mrcal = _mrcal()
    columns = np.asarray(columns, dtype=np.int64)
    _, _, J, _ = mrcal.optimizer_callback(**inputs, no_factorization=True)
    J = J.tocsr()
    Jo = J[:mrcal.num_measurements_boards(**inputs)]
    n = J.shape[1]
    E = np.zeros((n, len(columns)))
    E[columns, np.arange(len(columns))] = 1.0
    X = splu((J.T @ J).tocsc()).solve(E)                      # the requested columns of (JᵀJ)⁻¹
    A = X.T @ ((Jo.T @ Jo) @ X)             # packed covariance (J_oᵀJ_o first: sparse, state-sized)
    scale = np.ones(n)
    mrcal.unpack_state(scale, **inputs)
    sc = scale[columns]
    return float(noise_px) ** 2 * A * sc[:, None] * sc[None, :]


def board_rms_px(inputs: dict) -> float:
    """[px] RMS per coordinate of the inlier corners' reprojection errors of a solve (the noise
    :func:`state_covariance` takes; the report's ``rms_px``)."""
    err, w = observation_residuals(inputs)
    return _rms_per_coordinate(np.linalg.norm(err, axis=-1)[w > 0])


def _rms_per_coordinate(e: np.ndarray) -> float:
    """RMS per coordinate of 2-D error norms e: √(mean e² / 2) (NaN without any)."""
    return float(np.sqrt(np.mean(e**2) / 2.0)) if e.size else float("nan")


def extrinsics_uncertainty(inputs: dict, noise_px: float) -> np.ndarray:
    """(C, 2) predicted 1-sigma errors of each camera's pose relative to camera 0 (the solve's
    reference): column 0 the rotation [rad], column 1 the position [m], each the square root of
    the trace of its 3x3 covariance block (so a 3-D error magnitude); row 0 (camera 0) is 0.
    The covariance is :func:`state_covariance`'s. inputs: the solve's ``optimization_inputs``.
    """
    mrcal = _mrcal()
    n_ext = inputs["rt_cam_ref"].shape[0]
    i0 = mrcal.state_index_extrinsics(0, **inputs)
    if i0 is None or i0 < 0 or n_ext == 0:
        return np.zeros((n_ext + 1, 2))
    cov = state_covariance(inputs, noise_px, np.arange(i0, i0 + 6 * n_ext))
    out = np.zeros((n_ext + 1, 2))
    for k in range(n_ext):
        b = cov[6 * k:6 * k + 6, 6 * k:6 * k + 6]
        out[k + 1] = math.sqrt(max(np.trace(b[:3, :3]), 0.0)), math.sqrt(max(np.trace(b[3:, 3:]), 0.0))
    return out


def lens_rotation(intrinsics, q: np.ndarray, reference=None) -> np.ndarray:
    """(3, 3) rotation ``R`` that best maps a lens model's unprojected rays of pixels q (N, 2)
    onto a reference lens's rays of the same pixels (``v_ref ≈ R v_model``, least squares).

    A splined model can absorb a rotation of its camera (the spline shifts the whole image),
    so a splined solve's extrinsic rotations are only defined up to such a per-camera
    rotation (seen: up to 8 deg on a noise-free 3-camera problem with RMS 0.001 px, while
    the cameras' ray bundles agreed with the truth to 4e-4 deg up to one common rotation).
    The orientation of a camera's *ray bundle* relative to the reference lens is
    ``R_ref_cam @ R.T``; :func:`calibrate_board` aligns that to the rig file, with the
    rig file's nominal lens as the reference.
    intrinsics, reference: (lensmodel, parameters); reference default: the model's own
    first four parameters as a stereographic lens (a splined model's core).
    q: pixels where the model is trusted (observed).
    """
    mrcal = _mrcal()
    lens, p = intrinsics
    q = np.ascontiguousarray(q, dtype=float)
    v = mrcal.unproject(q, lens, np.ascontiguousarray(p, dtype=float), normalize=True)
    if reference is None:
        reference = ("LENSMODEL_STEREOGRAPHIC", np.asarray(p, float)[:4])
    v0 = mrcal.unproject(q, reference[0], np.ascontiguousarray(reference[1], dtype=float), normalize=True)
    ok = np.all(np.isfinite(v), axis=1) & np.all(np.isfinite(v0), axis=1)
    if ok.sum() < 3:
        return np.eye(3)
    U, _, Vt = np.linalg.svd(v0[ok].T @ v[ok])
    return U @ np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))]) @ Vt


def uncertainty_grid(model, distance: float | None, gridn_width: int = 30) -> np.ndarray:
    """(Ny, Nx) [px] mrcal worst-direction projection uncertainty on ``mrcal.sample_imager``'s grid.

    distance: [m] range of the points looked at (None: at infinity). NaN where it cannot be computed.
    """
    mrcal = _mrcal()
    W, H = (int(v) for v in model.imagersize())
    gh = max(2, int(round(H / W * gridn_width)))
    q = mrcal.sample_imager(gridn_width, gh, W, H)
    v = mrcal.unproject(np.ascontiguousarray(q, dtype=float), *model.intrinsics(), normalize=True)
    try:
        if distance is None:
            return mrcal.projection_uncertainty(v, model=model, atinfinity=True, what="worstdirection-stdev")
        return mrcal.projection_uncertainty(v * distance, model=model, atinfinity=False, what="worstdirection-stdev")
    except Exception as e:  # degenerate solves: report NaN rather than fail the whole run
        log.warning("projection uncertainty not computed: %s", str(e).strip().splitlines()[0] if str(e) else e)
        return np.full(q.shape[:2], np.nan)


def valid_region_contour(uncertainty: np.ndarray, q_obs: np.ndarray, imagersize, threshold_px: float,
                 min_count: int = 3) -> np.ndarray:
    """Valid-intrinsics region (closed contour (N, 2) [px]; (0, 2) if empty), mrcal-style.

    The imager grid cells (of ``uncertainty`` (Ny, Nx), on mrcal.sample_imager's grid) where
    the projection uncertainty is below ``threshold_px`` and at least ``min_count`` corners
    q_obs (M, 2) were observed; the largest connected area's outline.
    """
    import cv2

    mrcal = _mrcal()
    W, H = (int(v) for v in imagersize)
    ny, nx = uncertainty.shape
    ix = np.clip(np.rint(q_obs[:, 0] / (W - 1) * (nx - 1)).astype(int), 0, nx - 1)
    iy = np.clip(np.rint(q_obs[:, 1] / (H - 1) * (ny - 1)).astype(int), 0, ny - 1)
    count = np.zeros((ny, nx), int)
    np.add.at(count, (iy, ix), 1)
    u = np.where(np.isfinite(uncertainty), uncertainty, np.inf)
    mask = (u < threshold_px) & (count >= min_count)
    contours = cv2.findContours(mask.astype(np.uint8), cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)[-2]
    if not contours:
        return np.zeros((0, 2))
    c = max(contours, key=cv2.contourArea)[:, 0, :].astype(float)
    c = mrcal.close_contour(c)
    if c.ndim != 2 or c.shape[0] < 4:
        return np.zeros((0, 2))
    c[:, 0] *= (W - 1) / (nx - 1)
    c[:, 1] *= (H - 1) / (ny - 1)
    return np.rint(c).astype(np.int32)


def calibrate_board(obs: BoardObservations, rig: Rig | None, *, lensmodel: str = "opencv8",
                    board_warp: bool = True, outlier_rejection: bool = True, valid_region: bool = True,
                    region_threshold_px: float | None = None, regularization: bool = True,
                    seed: int = 0) -> BoardCalibration:
    """Jointly calibrate every camera of ``obs`` (intrinsics and rig-frame extrinsics) with mrcal.

    obs: detections (:func:`calib.detect.detect_session`).
    rig: the session's rig (nominal poses define the rig frame; ``fov_deg`` seeds the focal
        lengths). None: keep camera 0 as the reference frame.
    lensmodel: a :data:`LENSMODEL_CHOICES` name or a full mrcal lens-model string.
    board_warp: also fit the board's flex in a last stage.
    valid_region: compute each camera's projection uncertainty (:func:`uncertainty_grid`, at the
        median board distance) and store the valid-intrinsics region (:func:`valid_region_contour`: uncertainty
        below ``region_threshold_px``, default the camera's RMS residual, and >= 3 observed corners per
        grid cell) in each model. This is the slow part of a large solve.
    regularization: mrcal's regularisation of the lens parameters (on by default, as in
        mrcal-calibrate-cameras; it biases noise-free solves by ~0.01 px).
    seed: seeds the tiny random distortion start values (mrcal-calibrate-cameras does the same).
    """
    mrcal = _mrcal()
    C = len(obs.cameras)
    shared = _check_graph(obs)

    # contiguous frame indices, observations sorted by (frame, camera) as mrcal requires
    order = np.lexsort((obs.indices_frame_camera[:, 1], obs.indices_frame_camera[:, 0]))
    obs = obs.subset(np.ones(len(order), bool))
    obs.observations = np.ascontiguousarray(obs.observations[order])
    obs.indices_frame_camera = np.ascontiguousarray(obs.indices_frame_camera[order])
    obs.paths = [obs.paths[i] for i in order]
    frames, iframe = np.unique(obs.indices_frame_camera[:, 0], return_inverse=True)
    ifc = np.stack([iframe, obs.indices_frame_camera[:, 1]], axis=1).astype(np.int32)
    observations = obs.observations.copy()
    initial_weight = observations[..., 2].copy()
    imagersizes = np.asarray(obs.imagersizes, np.int32)
    spacing = obs.object_spacing

    try:
        intrinsics, rt_cam_ref, rt_ref_frame = mrcal.seed_stereographic(
            imagersizes=imagersizes, focal_estimate=_focal_estimates(obs, rig), indices_frame_camera=ifc,
            observations=observations, object_spacing=spacing, paths=obs.paths)
    except Exception as e:  # mrcal raises bare Exceptions for unusable seeds
        msg = str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__
        raise PolycamError(f"calibration seed failed: {msg}") from None
    rt_cam_ref = np.ascontiguousarray(np.reshape(rt_cam_ref, (-1, 6)))
    ifcc = np.concatenate([ifc, ifc[:, 1:2] - 1], axis=1).astype(np.int32)

    inputs = dict(intrinsics=np.ascontiguousarray(intrinsics, dtype=float), rt_cam_ref=rt_cam_ref,
                  rt_ref_frame=np.ascontiguousarray(rt_ref_frame), points=None,
                  observations_board=observations, indices_frame_camintrinsics_camextrinsics=ifcc,
                  observations_point=None, indices_point_camintrinsics_camextrinsics=None,
                  lensmodel="LENSMODEL_STEREOGRAPHIC", imagersizes=imagersizes, calobject_warp=None,
                  do_optimize_intrinsics_core=False, do_optimize_intrinsics_distortions=False,
                  do_optimize_extrinsics=True, do_optimize_frames=True, do_optimize_calobject_warp=False,
                  calibration_object_spacing=spacing, do_apply_outlier_rejection=False,
                  do_apply_regularization=False, verbose=False, imagepaths=list(obs.paths))
    stages: list[tuple[str, float]] = []

    def run(name: str, **changes) -> None:
        inputs.update(changes)
        st = mrcal.optimize(**inputs)
        stages.append((name, float(st["rms_reproj_error__pixels"])))
        log.info("calibrate: %s: RMS %.3f px, %d outliers", name, stages[-1][1], int(st.get("Noutliers", 0)))

    run("geometry")
    run("stereographic core", do_optimize_intrinsics_core=True)

    # the full lens model
    core = inputs["intrinsics"]
    W0 = float(imagersizes[:, 0].max())
    fov_x = 2.0 * math.degrees(2.0 * math.atan((W0 / 2.0) / (2.0 * float(np.min(core[:, 0])))))
    full = lensmodel_name(lensmodel, fov_x_deg=min(fov_x * 1.1 + 2.0, 179.0))
    nparams = mrcal.lensmodel_num_params(full)
    rng = np.random.default_rng(seed)
    extra = (rng.random((C, nparams - 4)) - 0.5) * 2e-6
    splined = full.startswith("LENSMODEL_SPLINED")
    m = re.match(r"LENSMODEL_OPENCV(\d+)", full)
    if m and int(m.group(1)) >= 8:
        extra[:, 5:8] *= 1e-3        # keep the rational denominator near 1 at the start
    if splined:
        extra[:] = 0.0
    if m and int(m.group(1)) > 4:
        # the radial and tangential terms first, from the core: the higher-order and rational
        # terms started from ~0 can send the full solve to a local minimum
        run("LENSMODEL_OPENCV4", intrinsics=np.ascontiguousarray(np.concatenate([core, extra[:, :4]], axis=1)),
            lensmodel="LENSMODEL_OPENCV4", do_optimize_intrinsics_core=True, do_optimize_intrinsics_distortions=True)
        extra[:, :4] = inputs["intrinsics"][:, 4:8]
        core = inputs["intrinsics"][:, :4]
    run(f"{full}", intrinsics=np.ascontiguousarray(np.concatenate([core, extra], axis=1)), lensmodel=full,
        do_optimize_intrinsics_core=not splined, do_optimize_intrinsics_distortions=True,
        do_apply_outlier_rejection=outlier_rejection, do_apply_regularization=regularization)
    if board_warp:
        run("board warp", calobject_warp=np.zeros(2), do_optimize_calobject_warp=True)

    rms, stats = _stats(inputs, obs, initial_weight)

    # rig frame (splined models: from the orientations of their ray bundles, see lens_rotation)
    T_ref_cam = np.stack([np.eye(4)] + [T_inverse(T_from_rt(r)) for r in inputs["rt_cam_ref"]])
    T_ref_cam_fit = T_ref_cam.copy()
    if splined:
        from polycam.cameras import nominal_cameramodel

        for ci in range(C):
            o = observations[ifc[:, 1] == ci].reshape(-1, 3)
            ref = nominal_cameramodel(rig.camera(obs.cameras[ci])).intrinsics() if rig is not None else None
            R_lens = lens_rotation((full, inputs["intrinsics"][ci]), o[o[:, 2] > 0, :2], ref)
            T_ref_cam_fit[ci, :3, :3] = T_ref_cam[ci, :3, :3] @ R_lens.T
    if rig is not None:
        nominal = np.stack([rig.camera(c).T_rig_cam for c in obs.cameras])
        rig_fit = fit_rig_frame(T_ref_cam_fit, nominal)
    else:
        rig_fit = fit_rig_frame(T_ref_cam_fit[:1], np.eye(4)[None])
    T_ref_rig = T_inverse(rig_fit.T_rig_ref)
    models, uncertainty = {}, {}
    for ci, cam in enumerate(obs.cameras):
        model = mrcal.cameramodel(optimization_inputs=inputs, icam_intrinsics=ci)
        model.rt_cam_ref(rt_from_T(T_inverse(T_ref_cam[ci]) @ T_ref_rig))
        if valid_region:
            unc = uncertainty_grid(model, board_distance(inputs))
            uncertainty[cam] = unc
            sel = ifc[:, 1] == ci
            o = inputs["observations_board"][sel].reshape(-1, 3)
            region = valid_region_contour(unc, o[o[:, 2] > 0, :2], model.imagersize(),
                                  max(region_threshold_px if region_threshold_px is not None else 0.0,
                                      stats[cam].rms_px if region_threshold_px is None else 0.0))
            if len(region):
                model.valid_intrinsics_region(region)
        models[cam] = model
    log.info("calibrate: %d cameras, %d views, RMS %.3f px; rig fit residuals %.2f mm / %.3f deg RMS", C,
             len(ifc), rms, 1e3 * float(np.sqrt(np.mean(rig_fit.position_residuals_m**2))),
             math.degrees(float(np.sqrt(np.mean(rig_fit.rotation_residuals_rad**2)))))
    return BoardCalibration(cameras=list(obs.cameras), models=models, lensmodel=full, optimization_inputs=inputs,
                            rig_fit=rig_fit, shared_frames=shared, rms_px=rms, stats=stats, observations=obs,
                            frames=frames, stages=stages, uncertainty=uncertainty)
