"""Target-free calibration with pycolmap: SIFT features and matching across the rig's
frames, incremental mapping, then rig bundle adjustment with the rig constraint, and
metric scale from the rig file (or a board); output as rig-frame cameramodels.

Pipeline (:func:`calibrate_colmap`):

1. Staging: every session image is linked as ``<workdir>/images/<cam>/<frame>.png``
   so each camera folder is one COLMAP camera (``CameraMode.PER_FOLDER``) and
   equal file names across folders are one rig frame (what COLMAP's rig
   configurator expects; ``frames.csv`` decides what belongs together, so
   timestamp jitter does not matter).
2. ``pycolmap.extract_features`` (images downscaled to ``max_image_size``),
   ``pycolmap.match_exhaustive`` (``match_sequential`` with ``overlap`` frames
   for long sessions).
3. Rig constraint: a ``RigConfig`` with one ``RigConfigCamera`` per camera (image
   prefix ``<cam>/``, the first camera the reference sensor). By default
   (``rig_prior``) each camera's ``cam_from_rig`` starts at the rig file's nominal
   pose and the config goes into the database *before* ``pycolmap.incremental_mapping``,
   so the mapper registers whole rig frames and refines ``sensor_from_rig`` as it
   goes (without it, mapping registered some cameras only, run to run, on a 2x2 rig
   in a room with a board). Otherwise the mapping is unconstrained and
   ``pycolmap.apply_rig_config`` derives each ``sensor_from_rig`` from that model.
   Either way the largest model is kept, fewer than half of the frames registered
   is an error (a static rig, e.g. a board session, cannot work), and a last
   ``pycolmap.bundle_adjustment`` refines ``sensor_from_rig``, rig poses, points and
   intrinsics.
4. Scale: with a board, the board corners seen in >= 2 cameras of a frame are
   triangulated and a similarity from the board's true corners (metres) onto them
   gives the scale (median over frames; fitted in that direction, the depth noise
   of the triangulation does not bias it); otherwise an Umeyama similarity fit of the solved camera
   centres to the rig file's nominal ones gives it (that needs >= 2 distinct
   nominal positions). Then :func:`calib.align.fit_rig_frame` puts the cameras into
   the rig frame (rigid fit, as on the board path).
5. Models: COLMAP intrinsics converted with :mod:`calib.colmap_text` (pixel
   centres moved by -0.5), ``rt_cam_ref = T_cam_rig``. These models carry no
   ``optimization_inputs`` (COLMAP's problem is not an mrcal problem), so
   mrcal's uncertainty tools do not apply to them.
"""

from __future__ import annotations

import logging
import math
import os
import shutil
import tempfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from polycam.errors import InputError, PolycamError
from polycam.geometry import T_from_rt, T_inverse, rt_from_T
from polycam.tomlio import atomic_write_text

from .align import RigFit, fit_rig_frame, fit_similarity
from .colmap_text import ColmapCamera, colmap_to_mrcal

__all__ = ["ColmapCalibration", "calibrate_colmap", "reconstruct_images", "write_colmap_report",
           "reconstruction_poses"]

log = logging.getLogger(__name__)


def _pycolmap():
    import pycolmap  # lazily: heavy

    return pycolmap


@dataclass
class ColmapCalibration:
    """Result of :func:`calibrate_colmap`."""

    cameras: list[str]
    models: dict
    """Camera id → mrcal.cameramodel (rt_cam_ref = T_cam_rig, metric)."""
    rms_px: float
    """[px] RMS reprojection error per coordinate after the rig bundle adjustment."""
    scale: float
    """Factor that took the reconstruction to metres."""
    scale_source: str
    """``"board"`` or ``"rig"``."""
    rig_fit: RigFit
    frames_registered: int
    frames_total: int
    points: int
    """3-D points in the reconstruction."""
    unconstrained_rms_px: float
    """[px] RMS of the mapper's model, before the final rig bundle adjustment (without the rig
    constraint when ``rig_prior`` is False)."""
    notes: list[str] = field(default_factory=list)


def _rms_reprojection(rec) -> float:
    """RMS per coordinate [px] of every observation of a pycolmap reconstruction."""
    sq, n = 0.0, 0
    for image_id in rec.reg_image_ids():
        im = rec.image(image_id)
        cam = rec.camera(im.camera_id)
        T = np.asarray(im.cam_from_world().matrix())
        pts, xy = [], []
        for p2 in im.points2D:
            if p2.has_point3D():
                pts.append(rec.point3D(p2.point3D_id).xyz)
                xy.append(p2.xy)
        if not pts:
            continue
        pc = np.asarray(pts) @ T[:3, :3].T + T[:3, 3]
        q = np.asarray(cam.img_from_cam(pc))
        e = q[:, :2] - np.asarray(xy)
        ok = np.all(np.isfinite(e), axis=1)
        sq += float(np.sum(e[ok] ** 2))
        n += int(ok.sum())
    return math.sqrt(sq / (2 * n)) if n else float("nan")


def reconstruction_poses(rec) -> dict[str, np.ndarray]:
    """Image name → (4, 4) cam_from_world of every registered image."""
    out = {}
    for image_id in rec.reg_image_ids():
        im = rec.image(image_id)
        out[im.name] = np.vstack([np.asarray(im.cam_from_world().matrix()), [0, 0, 0, 1]])
    return out


_MAPPING_ATTEMPTS = 3
"""Incremental mappings (seeds seed, seed + 1, ...) tried before a session counts as unmappable."""


def reconstruct_images(image_dir: str | os.PathLike, workdir: str | os.PathLike, *,
                       camera_mode: str = "PER_FOLDER", camera_model: str = "SIMPLE_RADIAL",
                       max_image_size: int = 1600, max_features: int = 8192, sequential_overlap: int | None = None,
                       num_threads: int = 1, seed: int = 0, image_names: list[str] | None = None,
                       rig_configs: list | None = None):
    """SIFT + matching + incremental mapping of the images under ``image_dir``; returns
    (largest pycolmap.Reconstruction, database path). ``camera_mode``: ``PER_FOLDER``,
    ``PER_IMAGE`` or ``SINGLE``. ``rig_configs``: ``pycolmap.RigConfig`` s applied to the
    database before mapping (with their ``cam_from_rig`` given, the mapper registers whole
    rig frames and refines ``sensor_from_rig`` in its bundle adjustments). ``num_threads``:
    the feature extraction's (on 2 threads, runs with one seed differed: 1439 or 1440 points,
    cameras 0.035 apart in their parameters; on 1 they are the same to the last bit). Every
    RANSAC gets ``seed``, so one seed gives one result."""
    pycolmap = _pycolmap()
    pycolmap.set_random_seed(int(seed))
    workdir = Path(workdir)
    workdir.mkdir(parents=True, exist_ok=True)
    db = workdir / "database.db"
    if db.exists():
        db.unlink()
    reader = pycolmap.ImageReaderOptions()
    reader.camera_model = camera_model
    extraction = pycolmap.FeatureExtractionOptions()
    extraction.max_image_size = int(max_image_size)
    extraction.num_threads = int(num_threads)
    extraction.sift.max_num_features = int(max_features)
    pycolmap.extract_features(db, image_dir, image_names=image_names or [],
                              camera_mode=getattr(pycolmap.CameraMode, camera_mode), reader_options=reader,
                              extraction_options=extraction, device=pycolmap.Device.cpu)
    # matching on one thread: on two, runs with one seed differed when other threads loaded
    # the cores (numba's, just after rendering the session: 1440 or 1441 points, cameras up to
    # 0.1 apart in their parameters); and the geometric verification's RANSAC seeded (its
    # default, -1, seeds each worker thread's generator from the clock, whatever
    # set_random_seed did on this thread)
    matching = pycolmap.FeatureMatchingOptions()
    matching.num_threads = 1
    verification = pycolmap.TwoViewGeometryOptions()
    verification.ransac.random_seed = int(seed)
    if sequential_overlap:
        pairing = pycolmap.SequentialPairingOptions()
        pairing.overlap = int(sequential_overlap)
        pycolmap.match_sequential(db, matching_options=matching, pairing_options=pairing,
                                  verification_options=verification, device=pycolmap.Device.cpu)
    else:
        pycolmap.match_exhaustive(db, matching_options=matching, verification_options=verification,
                                  device=pycolmap.Device.cpu)
    if rig_configs:
        database = pycolmap.Database.open(db)
        try:
            pycolmap.apply_rig_config(list(rig_configs), database)
        finally:
            database.close()
    # the incremental mapper is reproducible only on one thread (its multi-threaded bundle
    # adjustments and registration order vary from run to run: seen as 2 of 8 frames registered
    # in one run of a session that registers 8 of 8 in others), and with its RANSACs seeded
    pycolmap.set_random_seed(int(seed))
    opts = pycolmap.IncrementalPipelineOptions()
    opts.num_threads = 1
    opts.random_seed = int(seed)
    opts.mapper.num_threads = 1
    opts.mapper.random_seed = int(seed)
    opts.triangulation.random_seed = int(seed)
    opts.multiple_models = False
    sparse = workdir / "sparse"
    sparse.mkdir(exist_ok=True)
    recs = pycolmap.incremental_mapping(db, image_dir, sparse, options=opts)
    if not recs:
        raise PolycamError(f"COLMAP could not reconstruct the images in {image_dir} (too few matches: "
                           "is there texture, overlap and parallax?)")
    best = max(recs.values(), key=lambda r: r.num_reg_images())
    return best, db


def _stage_images(session, cams: list[str], dst: Path, frames: list[int]) -> dict[str, dict[int, Path]]:
    """Symlink (or copy) session images as dst/<cam>/<frame:06d>.png."""
    staged: dict[str, dict[int, Path]] = {c: {} for c in cams}
    col = {c: session.cameras.index(c) for c in cams}
    for cam in cams:
        (dst / cam).mkdir(parents=True, exist_ok=True)
    for i in frames:
        for cam in cams:
            ns = int(session.cam_timestamps[i, col[cam]])
            if ns < 0:
                continue
            src = session.image_path(cam, ns).resolve()
            link = dst / cam / f"{i:06d}.png"
            try:
                os.symlink(src, link)
            except OSError:
                shutil.copyfile(src, link)
            staged[cam][i] = src
    return staged


def _board_scale(session, board, cams: list[str], models_ref: dict, frame_poses: dict) -> float | None:
    """Metres per reconstruction unit from triangulated board corners, or None.

    Per frame, the corners seen by >= 2 cameras are triangulated (reconstruction units) and a
    similarity ``p_rec = s R p_board + t`` is fitted to the board's true corner positions
    (metres) with at least 6 corners; the scale is the median of ``1 / s`` over frames. Fitting
    in this direction keeps the triangulation noise (mostly along the short-baseline depth) on
    the dependent side, where it does not bias ``s``: the ratio of reconstructed to true
    neighbouring-corner distances would be biased by the depth noise (each distance grows by
    it; ~5 % on a 6 cm rig at 1.2 m).
    """
    import mrcal

    from .detect import _Detector

    det = _Detector(board)
    P_board = board.object_points()
    col = {c: session.cameras.index(c) for c in cams}
    scales = []
    for i, T_ref_world in frame_poses.items():        # per frame; ref = camera 0
        rays: dict[int, list[tuple[np.ndarray, np.ndarray]]] = {}
        for cam in cams:
            ns = int(session.cam_timestamps[i, col[cam]])
            if ns < 0:
                continue
            d = det.detect(session.read_image(cam, ns), 6)
            if not d.ok:
                continue
            m = models_ref[cam]
            T_cam_ref = np.asarray(m[1])
            v = mrcal.unproject(np.ascontiguousarray(d.q), *m[0], normalize=True)
            T_world_cam = T_inverse(T_cam_ref @ T_ref_world)
            for cid, vi in zip(d.ids, v):
                rays.setdefault(int(cid), []).append((T_world_cam[:3, 3], T_world_cam[:3, :3] @ vi))
        ids, pts = [], []
        for cid, rs in rays.items():
            if len(rs) < 2:
                continue
            A = np.zeros((3, 3))
            b = np.zeros(3)
            for o, dvec in rs:
                P = np.eye(3) - np.outer(dvec, dvec)
                A += P
                b += P @ o
            ids.append(cid)
            pts.append(np.linalg.solve(A, b))
        if len(ids) >= 6:
            s, _, _ = fit_similarity(P_board[ids], np.array(pts))
            if s > 0:
                scales.append(1.0 / s)
    if not scales:
        return None
    return float(np.median(scales))


def calibrate_colmap(session, *, board=None, cameras: list[str] | None = None, frames: list[int] | None = None,
                     max_image_size: int = 1600, camera_model: str = "OPENCV", max_features: int = 8192,
                     sequential_overlap: int | None = None, workdir: str | os.PathLike | None = None,
                     keep_workdir: bool = False, seed: int = 0, rig_prior: bool = True) -> ColmapCalibration:
    """Target-free calibration of a session's cameras (see the module docstring).

    session: an open :class:`polycam.session.Session` of a moving rig (texture and parallax).
    board: optional :class:`polycam.board.Board` for metric scale (else the rig file's positions).
    frames: session frame indices to use (default all).
    camera_model: COLMAP model per camera (``SIMPLE_RADIAL``, ``RADIAL``, ``OPENCV``, ``FULL_OPENCV``...).
    workdir: where the COLMAP database and model go (default a temporary folder, removed).
    rig_prior: map with the rig constraint from the start, the rig file's nominal poses as the
        starting ``cam_from_rig`` (whole frames are registered together, so every camera is
        registered whenever its frame is); False: map without it and derive ``sensor_from_rig``
        from the unconstrained model afterwards (camera 0's images must then carry the rig).
    seed: COLMAP's random seed; when a mapping registers too few frames (or no image of a
        camera) it is retried with seed + 1, seed + 2 (``_MAPPING_ATTEMPTS`` in all).
    """
    import mrcal

    pycolmap = _pycolmap()
    if not log.isEnabledFor(logging.INFO):      # COLMAP's glog chatter only with -v
        pycolmap.logging.minloglevel = 2
    cams = list(cameras) if cameras is not None else list(session.cameras)
    frames = list(range(len(session))) if frames is None else [int(i) for i in frames]
    if len(frames) < 2:
        raise InputError(f"{session.path}: the COLMAP method needs at least 2 frames of a moving rig")
    tmp = None
    if workdir is None:
        tmp = tempfile.mkdtemp(prefix="polycam-colmap-")
        workdir = Path(tmp)
    workdir = Path(workdir)
    try:
        img_dir = workdir / "images"
        if img_dir.exists():
            shutil.rmtree(img_dir)
        _stage_images(session, cams, img_dir, frames)
        configs = None
        if rig_prior:
            T0 = session.rig.camera(cams[0]).T_rig_cam
            configs = [pycolmap.RigConfig(cameras=[
                pycolmap.RigConfigCamera(image_prefix=f"{c}/", ref_sensor=True) if k == 0 else
                pycolmap.RigConfigCamera(image_prefix=f"{c}/", ref_sensor=False, cam_from_rig=pycolmap.Rigid3d(
                    (T_inverse(session.rig.camera(c).T_rig_cam) @ T0)[:3, :]))
                for k, c in enumerate(cams)])]
        for attempt in range(_MAPPING_ATTEMPTS):
            # COLMAP's incremental mapping now and then starts from a poor initial pair and
            # registers only a few frames of a session it maps whole with another seed: retry
            # with the next seeds before giving up (each attempt is reproducible)
            if (workdir / "sparse").exists():
                shutil.rmtree(workdir / "sparse")
            last = attempt + 1 == _MAPPING_ATTEMPTS
            try:
                rec, db_path = reconstruct_images(img_dir, workdir, camera_model=camera_model,
                                                  max_image_size=max_image_size, max_features=max_features,
                                                  sequential_overlap=sequential_overlap, seed=seed + attempt,
                                                  rig_configs=configs)
            except PolycamError as e:
                if last:
                    raise
                log.warning("colmap: seed %d: %s; retrying with the next seed", seed + attempt, e)
                continue
            registered = {rec.image(i).name for i in rec.reg_image_ids()}
            missing = [c for c in cams if not any(n.startswith(f"{c}/") for n in registered)]
            reg_frames = {int(Path(n.split("/", 1)[1]).stem) for n in registered}
            enough = len(reg_frames) >= max(2, math.ceil(0.5 * len(frames)))
            if enough and not missing:
                break
            log.warning("colmap: seed %d registered %d of %d frames%s; %s", seed + attempt, len(reg_frames),
                        len(frames), f", no image of {', '.join(missing)}" if missing else "",
                        "giving up" if last else "retrying with the next seed")
        if missing:
            raise PolycamError(f"{session.path}: COLMAP registered no image of camera(s) {', '.join(missing)} "
                               "(not enough overlap or texture)")
        if not enough:
            raise PolycamError(f"{session.path}: COLMAP registered only {len(reg_frames)} of {len(frames)} frames; "
                               "the target-free method needs a rig moving through a static textured scene (a board "
                               "session of a static rig is not one: use the board method)")
        rms0 = _rms_reprojection(rec)
        log.info("colmap: first model: %d of %d images, %d points, RMS %.3f px", len(registered),
                 sum(1 for _ in img_dir.rglob("*.png")), rec.num_points3D(), rms0)

        # the rig constraint
        rc = pycolmap.RigConfig(cameras=[pycolmap.RigConfigCamera(image_prefix=f"{c}/", ref_sensor=(k == 0))
                                         for k, c in enumerate(cams)])
        if not rig_prior:
            db = pycolmap.Database.open(db_path)
            try:
                pycolmap.apply_rig_config([rc], db, rec)
            finally:
                db.close()
        ba = pycolmap.BundleAdjustmentOptions()
        ba.refine_sensor_from_rig = True
        ba.refine_focal_length = True
        ba.refine_principal_point = True
        ba.refine_extra_params = True
        ba.print_summary = False
        ba.ceres.solver_options.num_threads = 1       # (threaded, Ceres' sums vary in the last digits)
        pycolmap.bundle_adjustment(rec, ba)
        rms = _rms_reprojection(rec)
        if keep_workdir:
            (workdir / "rig").mkdir(exist_ok=True)
            rec.write_text(str(workdir / "rig"))

        # per camera: intrinsics and T_cam_ref (ref = camera 0's frame, reconstruction units)
        rig = next(iter(rec.rigs.values()))
        cam_of_sensor = {}
        for cid, camera in rec.cameras.items():
            cam_of_sensor[camera.sensor_id.id] = camera
        name_cam = {}
        for i in rec.reg_image_ids():
            im = rec.image(i)
            name_cam[im.name.split("/")[0]] = im.camera_id
        intr, T_cam_ref = {}, {}
        for cam in cams:
            camera = rec.camera(name_cam[cam])
            ccam = ColmapCamera(camera.camera_id, camera.model_name, camera.width, camera.height,
                                np.asarray(camera.params, float))
            intr[cam] = colmap_to_mrcal(ccam)
            if rig.is_ref_sensor(camera.sensor_id):
                T_cam_ref[cam] = np.eye(4)
            else:
                T_cam_ref[cam] = np.vstack([np.asarray(rig.sensor_from_rig(camera.sensor_id).matrix()), [0, 0, 0, 1]])
        # rig poses per frame: T_ref_world from the reference camera's images (or any camera's)
        frame_poses = {}
        for i in rec.reg_image_ids():
            im = rec.image(i)
            cam, fname = im.name.split("/", 1)
            fi = int(Path(fname).stem)
            if fi not in frame_poses:
                T_cam_world = np.vstack([np.asarray(im.cam_from_world().matrix()), [0, 0, 0, 1]])
                frame_poses[fi] = T_inverse(T_cam_ref[cam]) @ T_cam_world

        # metric scale
        notes = []
        scale, source = None, "rig"
        if board is not None:
            scale = _board_scale(session, board, cams, {c: (intr[c], T_cam_ref[c]) for c in cams},
                                 {i: T for i, T in frame_poses.items()})
            if scale is None:
                notes.append("board given but too few corners triangulated: scale from the rig file instead")
            else:
                source = "board"
        nominal = np.stack([session.rig.camera(c).T_rig_cam for c in cams])
        T_ref_cam = np.stack([T_inverse(T_cam_ref[c]) for c in cams])
        if scale is None:
            centres = T_ref_cam[:, :3, 3]
            if len(cams) < 2 or np.ptp(nominal[:, :3, 3], axis=0).max() <= 0:
                raise InputError(f"{session.path}: metric scale needs a board (--board) or >= 2 cameras at "
                                 "distinct nominal positions in the rig file")
            scale, _, _ = fit_similarity(centres, nominal[:, :3, 3])
        T_ref_cam[:, :3, 3] *= scale
        fit = fit_rig_frame(T_ref_cam, nominal)
        models = {}
        for k, cam in enumerate(cams):
            T_rig_cam = fit.T_rig_ref @ T_ref_cam[k]
            lens, ii = intr[cam]
            models[cam] = mrcal.cameramodel(intrinsics=(lens, ii),
                                            imagersize=np.array([rec.camera(name_cam[cam]).width,
                                                                 rec.camera(name_cam[cam]).height]),
                                            rt_cam_ref=rt_from_T(T_inverse(T_rig_cam)))
        log.info("colmap: rig BA RMS %.3f px (mapper %.3f), scale %.6g from the %s", rms, rms0, scale, source)
        return ColmapCalibration(cameras=cams, models=models, rms_px=rms, scale=float(scale), scale_source=source,
                                 rig_fit=fit, frames_registered=len(frame_poses), frames_total=len(frames),
                                 points=int(rec.num_points3D()), unconstrained_rms_px=rms0, notes=notes)
    finally:
        if tmp is not None and not keep_workdir:
            shutil.rmtree(tmp, ignore_errors=True)


def write_colmap_report(cal: ColmapCalibration, out: str | os.PathLike) -> dict:
    """``report.toml`` and ``report.md`` of a COLMAP calibration; returns the dict."""
    import tomli_w

    from polycam.geometry import r_from_R

    out = Path(out)
    fit = cal.rig_fit
    doc = {
        "calibration": {
            "method": "colmap",
            "cameras": list(cal.cameras),
            "rms_px": round(cal.rms_px, 4),
            "unconstrained_rms_px": round(cal.unconstrained_rms_px, 4),
            "frames_registered": cal.frames_registered,
            "frames": cal.frames_total,
            "points": cal.points,
            "scale": cal.scale,
            "scale_source": cal.scale_source,
            "notes": list(cal.notes),
            "rig_fit": {
                "kind": "rigid (rotation + translation, after the metric scale) to the rig file's nominal poses",
                "position_rms_m": float(np.sqrt(np.mean(fit.position_residuals_m**2))),
                "position_max_m": float(fit.position_residuals_m.max()),
                "rotation_rms_deg": math.degrees(float(np.sqrt(np.mean(fit.rotation_residuals_rad**2)))),
                "rotation_max_deg": math.degrees(float(fit.rotation_residuals_rad.max())),
            },
        },
        "camera": {},
    }
    for k, cam in enumerate(cal.cameras):
        m = cal.models[cam]
        T = T_inverse(T_from_rt(m.rt_cam_ref()))
        doc["camera"][cam] = {"lensmodel": m.intrinsics()[0], "intrinsics": [float(v) for v in m.intrinsics()[1]],
                              "position_m": [float(v) for v in T[:3, 3]],
                              "rotation_rad": [float(v) for v in r_from_R(T[:3, :3])],
                              "rig_fit_position_m": float(fit.position_residuals_m[k]),
                              "rig_fit_rotation_deg": math.degrees(float(fit.rotation_residuals_rad[k]))}
    atomic_write_text(out / "report.toml", "# polycam calibration report (docs/calibration.md)\n" + tomli_w.dumps(doc))
    c = doc["calibration"]
    lines = ["# Calibration report (COLMAP, target-free)", "",
             f"- {len(cal.cameras)} cameras, {c['frames_registered']} of {c['frames']} frames registered, "
             f"{c['points']} points",
             f"- RMS reprojection error {c['rms_px']:.3f} px per coordinate after the rig bundle adjustment "
             f"({c['unconstrained_rms_px']:.3f} px before the final rig bundle adjustment)",
             f"- metric scale {c['scale']:.6g} from the {c['scale_source']}",
             f"- rig frame: {c['rig_fit']['kind']}; centres within {1e3 * c['rig_fit']['position_max_m']:.2f} mm, "
             f"orientations within {c['rig_fit']['rotation_max_deg']:.3f} deg of nominal"]
    lines += [f"- note: {n}" for n in cal.notes]
    lines += ["", "| camera | lens model | fx | fy | cx | cy | position [m] |", "| --- | --- | --- | --- | --- | --- | --- |"]
    for cam, e in doc["camera"].items():
        i = e["intrinsics"]
        lines.append(f"| {cam} | {e['lensmodel']} | {i[0]:.2f} | {i[1]:.2f} | {i[2]:.2f} | {i[3]:.2f} | "
                     + ", ".join(f"{v:+.4f}" for v in e["position_m"]) + " |")
    atomic_write_text(out / "report.md", "\n".join(lines) + "\n")
    return doc
