"""Synthetic data products on disk: light-field stores, camera-array sessions and
calibration-board sessions, each with its ground truth.

- :func:`synth_lightfield` / :func:`write_lightfield_sequence`: a ray-traced
  light-field sequence in a ``NAME.zarr`` store, ``groundtruth.tum`` inside.
- :func:`synth_session`: a camera-array session (SPEC.md) of a rig moving through
  a scene, with ``groundtruth.tum`` (``T_world_rig``, world = rig at frame 0) and
  the TRUE camera models in ``calib/`` (:func:`true_cameramodels`: the nominal
  models of the rig file with seeded per-camera perturbations).
- :func:`synth_board_session`: a static rig watching a ChArUco / chess board moved
  through varied poses in front of a room, with ``board_poses.tum`` (below).

``board_poses.tum`` (written by :func:`synth_board_session`): one TUM line per
frame, ``timestamp tx ty tz qx qy qz qw`` with the frame timestamp in seconds and
the pose ``T_rig_board`` (board frame → rig frame; board frame as in
:mod:`polycam.board`: origin at the outer corner of the top-left square, z into
the board). Because the rig is static at the world origin, ``T_world_board`` is
the same.

Seeds: every random choice derives from ``seed`` through its own stream
(scene layout, textures, motion, camera perturbations, board poses, noise), so
equal seeds give byte-identical output.
"""

from __future__ import annotations

import dataclasses
import logging
import math
import os
from pathlib import Path
from typing import Callable

import numpy as np

from ..cameras import T_rig_cam_of, nominal_cameramodel
from ..errors import InputError
from ..geometry import R_from_r, T_from_Rt, T_inverse, rt_from_T
from ..lightfield import LightFieldGrid
from ..rig import MJPG_QUALITY, Rig
from ..trajectory import Trajectory, pose_at, tum_text
from .boardrender import BoardRenderer
from .motion import frames_of, make_trajectory, static_trajectory
from .render import CameraArrayRenderer, LightFieldRenderer, default_lightfield_grid, mjpg_frame, quantize
from .scenes import Scene, make_scene, room_scene

__all__ = [
    "true_cameramodels",
    "board_poses",
    "camera_groups",
    "default_board_frames",
    "write_lightfield_sequence",
    "synth_lightfield",
    "synth_session",
    "synth_board_session",
    "scene_for_rig",
    "trajectory_for_rig",
]

log = logging.getLogger(__name__)

Progress = Callable[[int, int], None]
"""``progress(done, total)``: called after each frame."""

_SALT_PERTURB, _SALT_NOISE, _SALT_BOARD, _SALT_SYNC, _SALT_JITTER = 31, 32, 33, 34, 35
TIMESTAMP_JITTER_MARGIN = 5.0
"""A trajectory :func:`synth_session` builds for timestamp jitter starts this many jitter stds (plus the
capture spread) after 0, so that no image timestamp is negative."""


def _mrcal():
    import mrcal  # lazily: heavy

    return mrcal


# ----------------------------------------------------------------------------- cameras


def true_cameramodels(rig: Rig, *, seed: int = 0, perturb_position_m: float = 0.0,
                      perturb_rotation_deg: float = 0.0, perturb_focal_frac: float = 0.0) -> dict:
    """Camera id → the TRUE ``mrcal.cameramodel`` of a synthetic rig (rt_cam_ref = T_cam_rig).

    Each camera starts from :func:`~polycam.cameras.nominal_cameramodel` and gets,
    from its own seeded stream: a position offset with std ``perturb_position_m`` [m]
    per axis, a rotation by an axis-angle vector with std ``perturb_rotation_deg``
    [deg] per component (applied in the camera frame), and a focal-length factor
    ``1 + N(0, perturb_focal_frac)`` (fx and fy alike) with a principal-point shift of
    std ``perturb_focal_frac * fx`` [px] per axis. Distortion is not perturbed.
    """
    mrcal = _mrcal()
    out = {}
    for i, cam in enumerate(rig.cameras):
        rng = np.random.default_rng([seed, _SALT_PERTURB, i])
        dp = rng.normal(size=3) * perturb_position_m
        dr = rng.normal(size=3) * math.radians(perturb_rotation_deg)
        kf = 1.0 + rng.normal() * perturb_focal_frac
        dc = rng.normal(size=2) * perturb_focal_frac
        T_rig_cam = cam.T_rig_cam.copy()
        T_rig_cam[:3, :3] = T_rig_cam[:3, :3] @ R_from_r(dr)
        T_rig_cam[:3, 3] += dp
        m = nominal_cameramodel(cam, T_rig_cam)
        lensmodel, intr = m.intrinsics()
        intr = np.array(intr, float)
        fx = intr[0]
        intr[0] *= kf
        intr[1] *= kf
        intr[2:4] += dc * fx
        out[cam.id] = mrcal.cameramodel(intrinsics=(lensmodel, intr), imagersize=m.imagersize(),
                                        rt_cam_ref=rt_from_T(T_inverse(T_rig_cam)))
    return out


def _sync_offsets_ns(rig: Rig, seed: int, spread_ms: float) -> dict[str, int]:
    """Camera id → its constant capture offset [ns], uniform in ±``spread_ms`` (seeded); {} for 0."""
    if spread_ms <= 0.0:
        return {}
    rng = np.random.default_rng([seed, _SALT_SYNC])
    return {c.id: int(round(rng.uniform(-spread_ms, spread_ms) * 1e6)) for c in rig.cameras}


def _mjpg_quality(rig: Rig) -> int:
    """The JPEG quality of the rig's MJPG cameras: its ``[mock]`` ``mjpg_quality``, else the default."""
    return rig.mock.mjpg_quality if rig.mock is not None else MJPG_QUALITY


def _image_for(cam, radiance: np.ndarray, bit_depth: int | None, noise: float, rng,
               mjpg_quality: int = MJPG_QUALITY) -> np.ndarray:
    """Quantised image in the camera's pixel format: grey (H, W), or (H, W, 3) for RGB, and for 8-bit
    MJPG the JPEG round trip at ``mjpg_quality`` (:func:`~polycam.synth.render.mjpg_frame`)."""
    depth = bit_depth if bit_depth is not None else (16 if cam.pixel_format == "Y16" else 8)
    img = quantize(radiance, depth, noise, rng)
    if cam.pixel_format == "RGB":
        img = np.repeat(img[:, :, None], 3, axis=2)
    elif cam.pixel_format == "MJPG" and depth == 8:
        img = mjpg_frame(img, mjpg_quality)
    return img


# ----------------------------------------------------------------------------- light fields


def write_lightfield_sequence(out: str | os.PathLike, scene: Scene, grid: LightFieldGrid,
                              trajectory: Trajectory, *, supersample: int = 1, noise: float = 0.0,
                              bit_depth: int | None = None, seed: int = 0, overwrite: bool = False,
                              progress: Progress | None = None) -> Path:
    """Render ``scene`` on ``grid`` at every pose of ``trajectory`` into a light-field store
    ``out`` (SPEC.md), with the trajectory as ``groundtruth.tum``; returns the store path.
    ``noise``: std of Gaussian sensor noise in [0, 1] units, drawn per frame from ``seed``;
    ``bit_depth`` 8 or 16: the samples rounded to that many bits (and clipped to [0, 1], as a
    camera's; stored as float32 multiples of 1 / 255 or 1 / 65535); None: float samples
    (with noise, unclipped)."""
    from ..lfstore import LightFieldWriter

    renderer = LightFieldRenderer(scene, grid, supersample)
    n = len(trajectory)
    scale = None if bit_depth is None else (255.0 if bit_depth == 8 else 65535.0)
    with LightFieldWriter(out, grid, overwrite=overwrite) as w:
        for i in range(n):
            L = renderer.render(trajectory.T_world_rig[i])
            if noise > 0 or scale is not None:
                rng = np.random.default_rng([seed, _SALT_NOISE, i])
                if scale is not None:
                    L = (quantize(L, bit_depth, noise, rng) / np.float32(scale)).astype(np.float32)
                else:
                    L = (L + rng.normal(0.0, noise, L.shape)).astype(np.float32)
            w.append(L, int(trajectory.timestamps_ns[i]))
            if progress is not None:
                progress(i + 1, n)
        return w.close(groundtruth=trajectory)


def _with_specular(scene: Scene, specular: float) -> Scene:
    """``scene`` with its highlight set to ``specular`` (> 0), else as it is."""
    if not specular >= 0.0 or not math.isfinite(specular):
        raise ValueError(f"specular must be >= 0 and finite, got {specular}")
    return dataclasses.replace(scene, specular=float(specular)) if specular > 0.0 else scene


def synth_lightfield(out: str | os.PathLike, *, grid: LightFieldGrid | None = None, scene: str | Scene = "spheres",
                     distance: float = 6.0, frames: int = 2, seed: int = 0, supersample: int = 2,
                     step_t: float = 0.015, step_r_deg: float = 0.2, fps: float = 30.0,
                     trajectory: Trajectory | None = None, noise: float = 0.0, bit_depth: int | None = None,
                     specular: float = 0.0, overwrite: bool = False, progress: Progress | None = None) -> Path:
    """``polycam synth lightfield``: a seeded scene and smooth trajectory rendered into ``out``.

    grid: default :func:`~polycam.synth.render.default_lightfield_grid` on all six faces.
    scene: a :class:`Scene` or a name (``spheres``: all directions, ``spheres-forward``,
        ``room``) built with ``distance`` [m] and ``seed``.
    trajectory: default a smooth random one with RMS steps ``step_t`` [m], ``step_r_deg``.
    noise, bit_depth: sensor noise and rounding (:func:`write_lightfield_sequence`; seeded
        with ``seed``).
    specular: > 0 adds a view-dependent highlight of that strength to the scene's surfaces
        (:attr:`Scene.specular`; 0: as the scene has it).
    """
    grid = grid if grid is not None else default_lightfield_grid("all")
    sc = _with_specular(scene if isinstance(scene, Scene) else make_scene(scene, distance, seed), specular)
    traj = trajectory if trajectory is not None else make_trajectory(
        "smooth", frames, step_t=step_t, step_r_deg=step_r_deg, fps=fps, seed=seed)
    return write_lightfield_sequence(out, sc, grid, traj, supersample=supersample, noise=noise,
                                     bit_depth=bit_depth, seed=seed, overwrite=overwrite, progress=progress)


# ----------------------------------------------------------------------------- sessions


def scene_for_rig(rig: Rig, scene: str | Scene | None = None, *, distance: float | None = None,
                  seed: int | None = None) -> Scene:
    """The scene a rig's ``[mock]`` table asks for (what the mock driver and
    :func:`synth_session` render): ``scene`` (default the rig's, else ``room``),
    ``distance`` [m] (default the rig's, else 4) and ``seed`` (default the rig's, else 0).
    A :class:`Scene` passes through. The mock-only ``pattern`` scene is refused."""
    if isinstance(scene, Scene):
        return scene
    mock = rig.mock
    name = scene if scene is not None else (mock.scene if mock is not None else "room")
    if name == "pattern":
        raise InputError(f"{rig.path or rig.name}: [mock] scene 'pattern' is the mock driver's test "
                         "pattern; synthetic sessions need 'room' or 'spheres'")
    d = distance if distance is not None else (mock.distance if mock is not None else 4.0)
    sd = seed if seed is not None else (mock.seed if mock is not None else 0)
    return make_scene(name, d, sd)


def trajectory_for_rig(rig: Rig, frames: int, *, seed: int | None = None, start_ns: int = 0,
                       margin: int = 0) -> Trajectory:
    """The rig motion its ``[mock]`` table asks for: ``motion`` (``static``/``smooth``,
    default smooth), ``step_t`` [m] and ``step_r_deg`` [deg] per frame (defaults 5 mm,
    0.2 deg), seeded by ``seed`` (default the rig's, else 0); frames at the first
    camera's ``fps``; ``margin`` poses of the same motion before and after them
    (:func:`~polycam.synth.motion.smooth_trajectory`)."""
    mock = rig.mock
    sd = seed if seed is not None else (mock.seed if mock is not None else 0)
    return make_trajectory(mock.motion if mock is not None else "smooth", frames,
                           step_t=mock.step_t if mock is not None else 0.005,
                           step_r_deg=mock.step_r_deg if mock is not None else 0.2,
                           fps=float(rig.cameras[0].fps), seed=sd, start_ns=start_ns, margin=margin)


def synth_session(rig: Rig, out: str | os.PathLike, *, scene: str | Scene | None = None, frames: int = 10,
                  seed: int | None = None, supersample: int = 2, bit_depth: int | None = 8,
                  noise: float | None = None, perturb_position_m: float = 0.0,
                  perturb_rotation_deg: float = 0.0, perturb_focal_frac: float = 0.0,
                  distance: float | None = None, trajectory: Trajectory | None = None,
                  models: dict | None = None, specular: float = 0.0, sync_spread_ms: float = 0.0,
                  timestamp_jitter_ms: float = 0.0, overwrite: bool = False, threads: int = 2,
                  progress: Progress | None = None) -> Path:
    """``polycam synth session``: render a rig moving through a scene into a session folder.

    Defaults come from the rig's ``[mock]`` table where it has one: ``scene``,
    ``distance``, ``seed``, ``noise``, ``motion`` (``static``/``smooth``), ``step_t``,
    ``step_r_deg``; otherwise room, 4 m, seed 0, no noise, smooth, 5 mm, 0.2 deg.
    Frame timestamps follow the first camera's ``fps``.

    scene: a :class:`Scene` or a name (``room``, ``spheres``, ``spheres-forward``).
    bit_depth: 8 or 16; None: 16 for ``Y16`` cameras, 8 otherwise. ``RGB`` cameras get
        the grey radiance in three channels.
    noise: Gaussian grey-level std in [0, 1] units, seeded per frame.
    perturb_*: see :func:`true_cameramodels`; ignored when ``models`` are given.
    trajectory: ``T_world_rig`` per frame (overrides frames / motion settings).
    specular: > 0 adds a view-dependent highlight of that strength (:attr:`Scene.specular`).
    sync_spread_ms: > 0: free-running, unsynchronised cameras: each camera captures at its own
        constant offset from the frames' times, uniform in ±``sync_spread_ms`` (seeded), and its image
        shows the scene at that time (:func:`~polycam.trajectory.pose_at`) with that timestamp; the
        frame's timestamp and the ground truth stay at the frames' times (a trajectory built here then
        starts at ``sync_spread_ms``, so that no timestamp is negative, and its motion goes on a period
        before and after the frames, as a rig's does; a given one's first and last steps go on).
    timestamp_jitter_ms: > 0: each image's timestamp is its capture time plus Gaussian jitter of this
        std (seeded per frame and camera; a camera's timestamps kept increasing), as a driver stamps it
        late by a varying transfer time; the image still shows the capture time (a trajectory built
        here starts ``TIMESTAMP_JITTER_MARGIN`` stds later).
    Writes ``groundtruth.tum`` and ``calib/<cam>.cameramodel`` (the true models).
    """
    from ..session import SessionWriter

    mock = rig.mock
    seed = seed if seed is not None else (mock.seed if mock is not None else 0)
    noise = noise if noise is not None else (mock.noise if mock is not None else 0.0)
    sc = _with_specular(scene_for_rig(rig, scene, distance=distance, seed=seed), specular)
    if not 0.0 <= sync_spread_ms < math.inf:
        raise ValueError(f"sync_spread_ms must be >= 0 and finite, got {sync_spread_ms}")
    if not 0.0 <= timestamp_jitter_ms < math.inf:
        raise ValueError(f"timestamp_jitter_ms must be >= 0 and finite, got {timestamp_jitter_ms}")
    spread_ns = int(math.ceil((sync_spread_ms + TIMESTAMP_JITTER_MARGIN * timestamp_jitter_ms) * 1e6))
    offsets = _sync_offsets_ns(rig, seed, sync_spread_ms)
    if trajectory is None:                   # the motion goes on a period before and after the frames,
        motion = trajectory_for_rig(rig, frames, seed=seed, start_ns=spread_ns, margin=1)   # where free-
        trajectory = frames_of(motion, 1)                                 # running cameras capture
    else:
        motion = trajectory                  # given: beyond its ends its first and last steps go on
    if offsets and int(trajectory.timestamps_ns[0]) + min(offsets.values()) < 0:
        raise ValueError(f"sync_spread_ms {sync_spread_ms}: the trajectory must start at "
                         f"{int(math.ceil(sync_spread_ms * 1e6))} ns or later")
    if models is None:
        models = true_cameramodels(rig, seed=seed, perturb_position_m=perturb_position_m,
                                   perturb_rotation_deg=perturb_rotation_deg,
                                   perturb_focal_frac=perturb_focal_frac)
    renderer = CameraArrayRenderer(rig, models, sc, supersample)
    own = ({c.id: CameraArrayRenderer(dataclasses.replace(rig, cameras=(c,)), {c.id: models[c.id]}, sc, supersample)
            for c in rig.cameras} if offsets else {})          # one renderer per camera: its own pose
    n = len(trajectory)
    log.info("synth session %s: %d frames of %d cameras, scene %s (%.3g m), supersample %d", out, n,
             len(rig.cameras), sc.name, sc.distance, supersample)
    with SessionWriter(out, rig, overwrite=overwrite, threads=threads) as w:
        for cam in rig.cameras:
            w.write_calibration(cam.id, models[cam.id])
        last = {cam.id: -1 for cam in rig.cameras}
        for i in range(n):
            rng = np.random.default_rng([seed, _SALT_NOISE, i])
            t_f = int(trajectory.timestamps_ns[i])
            if not offsets and timestamp_jitter_ms <= 0.0:
                rad = renderer.render(trajectory.T_world_rig[i])
                images = {cam.id: _image_for(cam, rad[cam.id], bit_depth, noise, rng, _mjpg_quality(rig))
                          for cam in rig.cameras}
                w.add_frame(t_f, images)
            else:      # each image at its own capture time and timestamp
                jitter = np.random.default_rng([seed, _SALT_JITTER, i]).normal(
                    0.0, timestamp_jitter_ms * 1e6, len(rig.cameras))
                rad = None if offsets else renderer.render(trajectory.T_world_rig[i])
                stamps = {}
                for cam, jit in zip(rig.cameras, jitter.tolist()):
                    t_c = t_f + offsets.get(cam.id, 0)                   # when the camera captured
                    img = rad[cam.id] if rad is not None else own[cam.id].render(pose_at(motion, t_c))[cam.id]
                    ts = max(t_c + int(round(jit)), last[cam.id] + 1, 0)
                    w.write_image(cam.id, ts, _image_for(cam, img, bit_depth, noise, rng, _mjpg_quality(rig)))
                    stamps[cam.id] = last[cam.id] = ts
                w.write_frame(t_f, stamps)
            if progress is not None:
                progress(i + 1, n)
        w.write_groundtruth(trajectory)
        w.close()
    return Path(out)


# ----------------------------------------------------------------------------- boards


FACE_GROUP_DEG = 30.0
"""Cameras whose optical axes lie within this angle of a group's first camera look through one face
(:func:`camera_groups`)."""
ADJACENT_FACE_DEG = 120.0
"""Two faces whose mean optical axes are less than this apart are adjacent: a board held across their
common edge can be seen by both (:func:`board_poses`' bridge frames)."""
BRIDGE_CORNERS = 8
"""A bridge frame shows at least this many inner corners (:func:`_corners_seen`: with the squares
around them, large enough) to at least :data:`BRIDGE_CAMERAS` cameras of each of its two faces
(ChArUco keeps partial views of 8 corners by default)."""
BRIDGE_CAMERAS = 2
"""Cameras of each face that must see a bridge frame (:data:`BRIDGE_CORNERS`)."""
BRIDGE_SQUARE_PX = 20.0
"""[px] smallest projected square of a corner counted as seen by a bridge frame (a 5 x 5 ArUco marker
of 3 / 4 of the square then has ~2 px per bit)."""
BRIDGE_SHARE = 3
"""With several faces, every BRIDGE_SHARE-th frame of :func:`board_poses` is a bridge frame."""
BRIDGE_FRAMES_PER_PAIR = 4
"""Bridge frames per pair of adjacent faces in :func:`default_board_frames` (the calibration's camera graph
needs 2 frames seen together per link: ``calib.board_solve.MIN_SHARED_FRAMES``)."""


def camera_groups(models: dict, cam_ids: list[str] | None = None) -> list[list[str]]:
    """The cameras grouped by viewing direction: each group (a face of a multi-face rig, e.g. the
    nested cube's) holds the cameras whose optical axis (rig frame) lies within
    :data:`FACE_GROUP_DEG` of its first camera's, in ``cam_ids`` order (default: the models')."""
    ids = list(cam_ids) if cam_ids is not None else list(models)
    cos_max = math.cos(math.radians(FACE_GROUP_DEG))
    groups: list[list[str]] = []
    first_axis: list[np.ndarray] = []
    for cid in ids:
        axis = T_rig_cam_of(models[cid])[:3, 2]
        for g, a in zip(groups, first_axis):
            if float(a @ axis) >= cos_max:
                g.append(cid)
                break
        else:
            groups.append([cid])
            first_axis.append(axis)
    return groups


def _adjacent_pairs(models: dict, groups: list[list[str]]) -> tuple[list[tuple[int, int]], list[np.ndarray]]:
    """(pairs (a, b) of adjacent groups, each group's unit mean optical axis in the rig frame)."""
    axes = []
    for g in groups:
        a = np.mean([T_rig_cam_of(models[c])[:3, 2] for c in g], axis=0)
        axes.append(a / np.linalg.norm(a))
    cos_min = math.cos(math.radians(ADJACENT_FACE_DEG))
    pairs = [(a, b) for a in range(len(groups)) for b in range(a + 1, len(groups)) if axes[a] @ axes[b] > cos_min]
    return pairs, axes


def default_board_frames(models: dict, cam_ids: list[str] | None = None, single: int = 25) -> int:
    """Board frames a calibration session of these cameras needs by default: ``single`` when they
    all look one way; with several faces, :data:`BRIDGE_FRAMES_PER_PAIR` bridge frames per pair of
    adjacent faces, which are every :data:`BRIDGE_SHARE`-th frame of :func:`board_poses` (the nested
    cube: 12 pairs, 144 frames, 16 aimed at each face)."""
    groups = camera_groups(models, cam_ids)
    if len(groups) == 1:
        return single
    pairs, _ = _adjacent_pairs(models, groups)
    return max(single, BRIDGE_SHARE * BRIDGE_FRAMES_PER_PAIR * len(pairs))


def _in_image(q: np.ndarray, W: float, H: float, margin_px: float) -> np.ndarray:
    """(...) bool: the pixel coordinates q (..., 2) are finite and inside a W x H image (pixel centres at
    integers) with ``margin_px`` to spare."""
    return np.all(np.isfinite(q), axis=-1) & np.all(q >= margin_px - 0.5, axis=-1) & \
        (q[..., 0] <= W - 0.5 - margin_px) & (q[..., 1] <= H - 0.5 - margin_px)


def _corners_seen(model, T_rig_board: np.ndarray, board, margin_px: float) -> int:
    """How many of the board's inner corners a detector can be expected to find in the camera's
    image: the four squares around the corner (its ChArUco markers) project inside the image with
    ``margin_px`` to spare, and a square is at least :data:`BRIDGE_SQUARE_PX` wide there."""
    mrcal = _mrcal()
    lensmodel, intr = model.intrinsics()
    W, H = (float(v) for v in model.imagersize())
    T_cam_board = T_inverse(T_rig_cam_of(model)) @ T_rig_board
    s = float(board.square_length)
    offsets = np.array([[0, 0, 0], [s, 0, 0], [0, s, 0], [-s, -s, 0], [s, -s, 0], [-s, s, 0], [s, s, 0]], float)
    pts = board.object_points()[:, None, :] + offsets                           # (N, 7, 3)
    p = pts @ T_cam_board[:3, :3].T + T_cam_board[:3, 3]
    front = p[..., 2] > 0.05
    q = mrcal.project(np.where(front[..., None], p, np.array([0.0, 0.0, 1.0])), lensmodel, intr)   # (N, 7, 2)
    inside = front & _in_image(q, W, H, margin_px)
    size = np.minimum(np.linalg.norm(q[:, 1] - q[:, 0], axis=-1), np.linalg.norm(q[:, 2] - q[:, 0], axis=-1))
    return int(np.sum(np.all(inside, axis=1) & (size >= BRIDGE_SQUARE_PX)))


def _bridge_pose(board, models: dict, group_a: list[str], group_b: list[str], axis_a: np.ndarray,
                 axis_b: np.ndarray, rng, tilt_deg: float, roll_deg: float, margin_px: float) -> np.ndarray:
    """``T_rig_board`` of a board held across the edge between two faces: its centre on the bisector of
    their mean optical axes, 0.25–0.45 m out from the centroid of their cameras (distances for a
    poster-sized board such as rigs/boards/charuco_7x9.toml), facing it (tilted by up to half of
    ``tilt_deg`` and rolled by up to ``roll_deg``), redrawn until :data:`BRIDGE_CAMERAS` cameras of
    each face see :data:`BRIDGE_CORNERS` inner corners (:func:`_corners_seen`)."""
    bw, bh = board.size_m
    centre_b = np.array([bw / 2.0, bh / 2.0, 0.0])
    centre_rig = np.mean([T_rig_cam_of(models[c])[:3, 3] for c in group_a + group_b], axis=0)
    d = axis_a + axis_b
    d /= np.linalg.norm(d)
    across = axis_a - axis_b
    across -= (across @ d) * d
    across /= np.linalg.norm(across)
    for _ in range(500):
        x = across if rng.uniform() < 0.5 else np.cross(d, across)     # the board's long side across or along
        R = np.stack([x, np.cross(d, x), d], axis=1)                     # board z away from the rig
        phi = rng.uniform(0.0, 2.0 * np.pi)
        tilt = math.radians(rng.uniform(-tilt_deg, tilt_deg) / 2.0)
        az = math.radians(rng.uniform(-roll_deg, roll_deg))
        R = R @ R_from_r(tilt * np.array([math.cos(phi), math.sin(phi), 0.0])) @ R_from_r(np.array([0.0, 0.0, az]))
        p = centre_rig + d * rng.uniform(0.25, 0.45) + rng.normal(0.0, 0.02, 3)
        T = T_from_Rt(R, p - R @ centre_b)
        if all(sum(_corners_seen(models[c], T, board, margin_px) >= BRIDGE_CORNERS for c in g) >= BRIDGE_CAMERAS
               for g in (group_a, group_b)):
            return T
    raise InputError(f"could not place the board across the edge between the faces of cameras {group_a[0]} and "
                     f"{group_b[0]} so that both see {BRIDGE_CORNERS} of its corners (do their fields of view "
                     "overlap? is the board large enough?)")


def board_poses(board, models: dict, frames: int, *, seed: int = 0, tilt_deg: float = 40.0,
                roll_deg: float = 20.0, fill: tuple[float, float] = (0.6, 0.95), margin_px: float = 4.0,
                cam_ids: list[str] | None = None, spread: float = 0.5, min_visible: float = 1.0) -> np.ndarray:
    """(frames, 4, 4) seeded board poses ``T_rig_board`` for calibration sessions.

    When the cameras look through several faces (:func:`camera_groups`: the nested cube's), every
    :data:`BRIDGE_SHARE`-th frame is a *bridge*: a board held across the edge between two adjacent
    faces, seen by cameras of both (:func:`_bridge_pose`), the pairs of adjacent faces in turn; a
    board calibration can tie faces together only through such views, so the faces' fields of view
    must overlap. The other frames aim at the cameras in turn, as for one face.

    Otherwise frame i aims at camera ``cam_ids[i % N]`` (default: the models' order): seen
    square-on, the board's squared area would span a fraction ``fill`` (uniform) of
    that camera's image along the limiting dimension (fx-based scale), its centre at a
    random point of the central half of the image, facing the camera, tilted by up to
    ``tilt_deg`` about a random axis in the board plane and rolled by up to
    ``roll_deg``; a pose is redrawn until all four outer corners project inside that
    camera's image with ``margin_px`` to spare. With nearby parallel cameras (a
    planar array) most poses are seen by several cameras at once.

    Better-conditioned calibration sets (closer boards, partial views reaching the
    imager's corners, as mrcal's calibration guide asks): ``spread`` is the central
    fraction of the image (per axis) the board centre is drawn from (default 0.5, the
    central half), and ``min_visible < 1`` replaces the whole-board test by "at least
    this fraction of the inner corners inside the image (with ``margin_px``)", so ``fill``
    may exceed 1 (a board larger than the view). The defaults reproduce the poses of
    earlier versions exactly.
    """
    mrcal = _mrcal()
    ids = list(cam_ids) if cam_ids is not None else list(models)
    rng = np.random.default_rng([seed, _SALT_BOARD])
    bw, bh = board.size_m
    centre_b = np.array([bw / 2.0, bh / 2.0, 0.0])
    corners_b = np.array([[0, 0, 0], [bw, 0, 0], [0, bh, 0], [bw, bh, 0]], float)
    inner_b = board.object_points()
    lo, hi = 0.5 - spread / 2.0, 0.5 + spread / 2.0
    out = np.empty((frames, 4, 4))
    groups = camera_groups(models, ids)
    pairs, axes = _adjacent_pairs(models, groups) if len(groups) > 1 else ([], [])
    n_aimed = 0
    for i in range(frames):
        if pairs and i % BRIDGE_SHARE == BRIDGE_SHARE - 1:
            a, b = pairs[(i // BRIDGE_SHARE) % len(pairs)]
            out[i] = _bridge_pose(board, models, groups[a], groups[b], axes[a], axes[b], rng, tilt_deg, roll_deg,
                                  margin_px)
            continue
        cid = ids[n_aimed % len(ids)]
        n_aimed += 1
        model = models[cid]
        lensmodel, intr = model.intrinsics()
        W, H = (float(v) for v in model.imagersize())
        T_rig_cam = T_rig_cam_of(model)
        for attempt in range(200):
            scale = rng.uniform(*fill) * min(W / bw, H / bh)          # [px/m] square-on
            z = intr[0] / scale
            q = np.array([rng.uniform(lo, hi) * W, rng.uniform(lo, hi) * H])
            d = mrcal.unproject(q, lensmodel, intr, normalize=True)
            p_c = d * (z / d[2])
            # tilt: up to tilt_deg about a random axis in the board plane; then roll about z
            phi = rng.uniform(0.0, 2.0 * np.pi)
            tilt = math.radians(rng.uniform(-tilt_deg, tilt_deg))
            az = math.radians(rng.uniform(-roll_deg, roll_deg))
            R = R_from_r(np.array([0.0, 0.0, az])) @ R_from_r(tilt * np.array([math.cos(phi), math.sin(phi), 0.0]))
            T_cam_board = T_from_Rt(R, p_c - R @ centre_b)
            pc = (corners_b if min_visible >= 1.0 else inner_b) @ T_cam_board[:3, :3].T + T_cam_board[:3, 3]
            if np.any(pc[:, 2] <= 0.05):
                continue
            qc = mrcal.project(pc, lensmodel, intr)
            ok = _in_image(qc, W, H, margin_px)
            if (np.all(ok) if min_visible >= 1.0 else np.mean(ok) >= min_visible):
                break
        else:
            raise InputError(f"could not place the board inside the view of camera {cid} "
                             "(is the board too large for the lens?)")
        out[i] = T_rig_cam @ T_cam_board
    return out


def synth_board_session(rig: Rig, out: str | os.PathLike, *, board, frames: int = 20, seed: int | None = None,
                        supersample: int = 2, bit_depth: int | None = 8, noise: float | None = None,
                        perturb_position_m: float = 0.0, perturb_rotation_deg: float = 0.0,
                        perturb_focal_frac: float = 0.0, scene: Scene | None = None,
                        distance: float | None = None, models: dict | None = None,
                        poses: np.ndarray | None = None, tilt_deg: float = 40.0, overwrite: bool = False,
                        threads: int = 2, progress: Progress | None = None) -> Path:
    """``polycam synth session --board``: a static rig (at the world origin) watching a
    calibration board moved through :func:`board_poses` in front of a room.

    board: a :class:`polycam.board.Board`. Its image (:meth:`~polycam.board.Board.render`,
        white margin of half a square, at least 2x the finest camera sampling) is a
        two-sided textured rectangle, placed at ``T_rig_board`` per frame (rendered by
        :class:`~polycam.synth.boardrender.BoardRenderer`: the static background is traced
        once, the board per frame; same images as tracing the whole scene).
    scene: the background (default an object-free :func:`room_scene` with the rig's
        ``[mock] distance`` to the far wall, so nothing occludes the board).
    poses: (frames, 4, 4) ``T_rig_board`` (default :func:`board_poses`).
    Writes ``groundtruth.tum`` (identity poses), ``calib/`` (true models),
    ``board_poses.tum`` (see the module docstring) and ``board.toml`` (a copy of the
    board file, when the board was read from one). Other arguments as
    :func:`synth_session`.
    """
    from ..session import SessionWriter

    mock = rig.mock
    seed = seed if seed is not None else (mock.seed if mock is not None else 0)
    noise = noise if noise is not None else (mock.noise if mock is not None else 0.0)
    if scene is None:
        d = distance if distance is not None else (mock.distance if mock is not None else 4.0)
        scene = room_scene(max(d, 2.0), seed=seed, n_spheres=0, n_boxes=0)
    if models is None:
        models = true_cameramodels(rig, seed=seed, perturb_position_m=perturb_position_m,
                                   perturb_rotation_deg=perturb_rotation_deg,
                                   perturb_focal_frac=perturb_focal_frac)
    if poses is None:
        poses = board_poses(board, models, frames, seed=seed, tilt_deg=tilt_deg,
                            cam_ids=[c.id for c in rig.cameras])
    poses = np.asarray(poses, float)
    frames = poses.shape[0]
    traj = static_trajectory(frames, float(rig.cameras[0].fps))

    # Texture resolution: at least twice the finest sampling of any camera.
    z_min = float(np.min([np.min(np.linalg.norm(
        poses[:, :3, 3] - T_rig_cam_of(m)[:3, 3], axis=1)) for m in models.values()]))
    fx_max = max(float(m.intrinsics()[1][0]) for m in models.values())
    pps = int(np.clip(math.ceil(2.0 * fx_max * board.square_length / max(z_min, 1e-3)), 40, 240))
    image, H_image_board = board.render(pps, 0.5)
    k = pps / board.square_length
    m_m = (image.shape[1] - board.cols * pps) / 2.0 / k             # margin [m]
    bw, bh = board.size_m
    scene, rect = scene.with_image_rect(image, poses[0], (-m_m, bw + m_m, -m_m, bh + m_m),
                                        np.asarray(H_image_board)[:2])

    renderer = BoardRenderer(rig, models, scene, rect, traj.T_world_rig[0], supersample)
    log.info("synth board session %s: %d frames of %d cameras, board texture %d px per square", out, frames,
             len(rig.cameras), pps)
    with SessionWriter(out, rig, overwrite=overwrite, threads=threads) as w:
        for cam in rig.cameras:
            w.write_calibration(cam.id, models[cam.id])
        for i in range(frames):
            rng = np.random.default_rng([seed, _SALT_NOISE, i])
            rad = renderer.render(poses[i])             # the rig is static at the world origin
            images = {cam.id: _image_for(cam, rad[cam.id], bit_depth, noise, rng, _mjpg_quality(rig)) for cam in rig.cameras}
            w.add_frame(int(traj.timestamps_ns[i]), images)
            if progress is not None:
                progress(i + 1, frames)
        w.write_groundtruth(traj)
        w.write_extra("board_poses.tum", tum_text(traj.timestamps_ns, poses))
        if getattr(board, "path", None) is not None and Path(board.path).is_file():
            w.write_extra("board.toml", Path(board.path).read_text())
        w.close()
    return Path(out)
