"""Board calibration accuracy and speed on rendered sessions (issue 4 targets).

For each rig (3x3 640x480 and 5x5 320x240, real OPENCV8 lens from
../shared/data/mrcal-models when present), a board session is rendered with
``polycam synth`` (cached under --work; board poses from
:func:`polycam.synth.board_poses` with the ``--motion`` design of :data:`MOTIONS`),
the ChArUco corners are detected and Gaussian noise is injected into them: by
default (``--noise-mode total``) just enough to bring the detector's own error
(measured against the true projections, ~0.09-0.16 px) up to 0.2 px per coordinate
in all ("corner" column); ``add`` puts 0.2 px on top (session 1's figures). The same
detections are solved twice:

- polycam/mrcal (:func:`calib.calibrate_board`, LENSMODEL_OPENCV8), and
- OpenCV 5 ``cv2.calibrateMultiview`` (pinhole + rational 8-coefficient model),
  the baseline.

Reported per solver: RMS reprojection error (per coordinate, inliers), the projection
difference to the true model (``mrcal.projection_diff`` with its implied-transform
fit, RMS inside the estimated mrcal model's valid-intrinsics region, or the central
half of the imager when that is empty; "proj" at the median board distance, with the
median over cameras and "worst" camera; "inf" at infinity, median over cameras),
camera positions [mm] and orientations [deg] (worst camera after a rigid alignment
to the truth whose rotation comes from the orientations: "pos mm", "rot deg"), the
same without any alignment as poses relative to the first camera, ``T_cam0_camk``
("relpos", "relrot", worst camera), mrcal's predicted 1-sigma of those relative
poses from its covariance at the measured corner noise
(:func:`calib.extrinsics_uncertainty`, worst camera: "predpos", "predrot"), and
solve time. A third case times a 4x4 rig with 40 board poses (detection + solve)
against the 60 s target.

Boards (:data:`BOARDS`): an 8x11 ChArUco (70 corners) for 640x480, a 5x7 one with 40 mm
squares (24 corners) for 320x240, where 8x11's squares are too small to detect cleanly, and
denser 20 cm wide ones (12x16: 165 corners, 16x22: 315) for 1280x960 cameras. OpenCV gets the
whole-board views only (partial views spoil its initialisation).

The design is chosen with ``--predict-only``: mrcal's predicted worst-camera sigma of the
relative poses from the exact corner projections (:func:`calib.predicted_extrinsics_sigma`,
seconds instead of a render); every run prints it too ("truthrot"), next to the prediction
from the solved problem ("predrot") and the measured error ("relrot"). Per case the table
also gives the render, detection and solve times, and the fraction of detected corners mrcal
rejected as outliers ("outl%"; mrcal's own log counts the unseen corners of partial views too).

Run: ``python benchmarks/bench_calib.py [--frames 40] [--rigs 3x3,5x5] [--resolution WxH]
[--board 8x11|5x7|12x16|16x22] [--predict-only] [--motion wide|basic] [--noise-mode total|add]
[--skip-opencv] [--skip-3x3] [--skip-5x5] [--skip-speed] [--work /tmp/polycam-bench-calib]``.
The orientation target (issue 4): ``--frames 120 --rigs 3x3 --resolution 1280x960 --board 16x22
--skip-opencv --skip-speed`` (and ``--frames 100 --rigs 5x5`` likewise), see docs/calibration.md.
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

LENS = REPO.parent / "shared" / "data" / "mrcal-models" / "cam0.opencv8.cameramodel"
BOARDS = {
    # 70 corners: for 640x480 cameras
    "8x11": '[board]\ntype = "charuco"\nsquares = [8, 11]\nsquare_length = 0.025\nmarker_length = 0.019\n'
            'dictionary = "DICT_5X5_100"\n',
    # 24 corners, 40 mm squares: for 320x240 cameras (8x11 squares are too small to detect well there)
    "5x7": '[board]\ntype = "charuco"\nsquares = [5, 7]\nsquare_length = 0.04\nmarker_length = 0.03\n'
           'dictionary = "DICT_5X5_100"\n',
    # denser boards of the same 20 cm width (165 / 315 corners): for 1280x960 cameras
    "12x16": '[board]\ntype = "charuco"\nsquares = [12, 16]\nsquare_length = 0.016667\nmarker_length = 0.0125\n'
             'dictionary = "DICT_5X5_100"\n',
    "16x22": '[board]\ntype = "charuco"\nsquares = [16, 22]\nsquare_length = 0.0125\nmarker_length = 0.0094\n'
             'dictionary = "DICT_5X5_250"\n',
}
RIGS = {"3x3": (3, 3, (640, 480), "8x11"), "5x5": (5, 5, (320, 240), "5x7")}
"""rig name → (rows, cols, default resolution, default board)."""


def rig_file(work: Path, name: str, rows: int, cols: int, w: int, h: int, pitch: float) -> Path:
    lens = f'lens = "{LENS}"\n' if LENS.is_file() else ""
    p = work / f"{name}.toml"
    p.write_text(f"[rig]\nname = \"{name}\"\n[defaults]\nwidth = {w}\nheight = {h}\nfov_deg = 65\n{lens}"
                 f"[grid]\nrows = {rows}\ncols = {cols}\npitch = {pitch}\n")
    return p


MOTIONS = {
    # polycam.synth.board_poses defaults (session 1): whole boards in the central half, 60-95 % fill, tilt <= 40 deg
    "basic": {},
    # closer boards (50-150 % of the view, half of the corners may be outside), centres over 90 % of the
    # imager, tilt <= 60 deg: mrcal's guide (fill the imager, reach its corners, tilt); conditioned best in
    # mrcal's predicted uncertainty among the designs tried (see docs/calibration.md)
    "wide": dict(fill=(0.5, 1.5), spread=0.9, min_visible=0.5, tilt_deg=60.0),
}
PERTURB = dict(perturb_position_m=0.001, perturb_rotation_deg=0.3, perturb_focal_frac=0.01)


def session_for(work: Path, name: str, rows: int, cols: int, w: int, h: int, frames: int, board_name: str,
                pitch: float = 0.04, motion: str = "wide"):
    from polycam.board import load_board
    from polycam.synth import synth_board_session

    bp = work / f"board-{board_name}.toml"
    bp.write_text(BOARDS[board_name])
    board = load_board(bp)
    out = work / f"{name}-{frames}-{board_name}" if motion == "basic" else work / f"{name}-{frames}-{board_name}-{motion}"
    if (w, h) != RIGS.get(name[3:], (0, 0, (w, h)))[2]:
        out = out.with_name(f"{out.name}-{w}x{h}")
    if not (out / "session.toml").is_file():
        t = time.perf_counter()
        rig, models, poses = design(work, name, rows, cols, w, h, frames, board, pitch, motion)
        synth_board_session(rig, out, board=board, frames=frames, seed=7, supersample=2, noise=0.002,
                            models=models, poses=poses, overwrite=True)
        print(f"  rendered {out.name} in {time.perf_counter() - t:.0f} s", flush=True)
    return out, board


def design(work: Path, name: str, rows: int, cols: int, w: int, h: int, frames: int, board, pitch: float = 0.04,
           motion: str = "wide"):
    """(rig, true models, board poses T_rig_board (frames, 4, 4)) of a benchmark case (seeded)."""
    from polycam.rig import load_rig
    from polycam.synth import board_poses, true_cameramodels

    rig = load_rig(rig_file(work, f"{name}-{w}x{h}", rows, cols, w, h, pitch))
    models = true_cameramodels(rig, seed=7, **PERTURB)
    poses = board_poses(board, models, frames, seed=7, cam_ids=[c.id for c in rig.cameras], **MOTIONS[motion])
    return rig, models, poses


def predicted_sigma(work: Path, name: str, rows: int, cols: int, w: int, h: int, frames: int, board_name: str,
                    motion: str = "wide", noise_px: float = 0.2) -> tuple[float, float, float]:
    """mrcal's predicted worst-camera 1-sigma (rotation [deg], position [mm]) of the poses relative to
    camera 0 for this design, from the exact corner projections (no rendering, no detection, no
    outliers: :func:`calib.predicted_extrinsics_sigma`), and the seconds it took."""
    from calib import predicted_extrinsics_sigma
    from polycam.board import load_board

    bp = work / f"board-{board_name}.toml"
    bp.write_text(BOARDS[board_name])
    board = load_board(bp)
    t = time.perf_counter()
    _, models, poses = design(work, name, rows, cols, w, h, frames, board, motion=motion)
    lens = "LENSMODEL_OPENCV8"
    s = predicted_extrinsics_sigma(models, board, poses, noise_px, lensmodel=lens)[1:]
    return math.degrees(float(s[:, 0].max())), 1e3 * float(s[:, 1].max()), time.perf_counter() - t


def inside(model, q: np.ndarray) -> np.ndarray:
    import cv2

    W, H = model.imagersize()
    r = model.valid_intrinsics_region()
    if r is not None and len(r) >= 4 and cv2.contourArea(r.astype(np.float32)) > 0.05 * W * H:
        c = r.astype(np.float32)
        return np.array([cv2.pointPolygonTest(c, (float(x), float(y)), False) >= 0
                         for x, y in q.reshape(-1, 2)]).reshape(q.shape[:-1])
    return (np.abs(q[..., 0] - (W - 1) / 2) <= W / 4) & (np.abs(q[..., 1] - (H - 1) / 2) <= H / 4)


def metrics(est: dict, true: dict, distance: float, region_from: dict | None = None) -> dict:
    import mrcal

    from calib.align import fit_rig_frame
    from polycam.cameras import T_rig_cam_of

    cams = list(true)
    fit = fit_rig_frame(np.stack([T_rig_cam_of(est[c]) for c in cams]),
                        np.stack([T_rig_cam_of(true[c]) for c in cams]), position_sigma_m=1.0,
                        rotation_sigma_deg=1e-3)
    diffs, diffs_inf = [], []
    for c in cams:
        d, _, q0, _ = mrcal.projection_diff((est[c], true[c]), use_uncertainties=False, gridn_width=40,
                                            distance=distance)
        m = inside((region_from or est)[c], q0)
        diffs.append(math.sqrt(float(np.nanmean(d[m] ** 2))))
        d, _, q0, _ = mrcal.projection_diff((est[c], true[c]), use_uncertainties=False, gridn_width=40)
        diffs_inf.append(math.sqrt(float(np.nanmean(d[m] ** 2))))
    rel_pos, rel_rot = relative_errors(est, true)
    return {"proj_rms_px": float(np.median(diffs)), "proj_worst_cam_px": float(np.max(diffs)),
            "proj_inf_px": float(np.median(diffs_inf)),
            "pos_mm": 1e3 * float(fit.position_residuals_m.max()),
            "rot_deg": math.degrees(float(fit.rotation_residuals_rad.max())),
            "rel_pos_mm": 1e3 * float(rel_pos.max()), "rel_rot_deg": math.degrees(float(rel_rot.max()))}


def relative_errors(est: dict, true: dict) -> tuple[np.ndarray, np.ndarray]:
    """(C-1,) position [m] and rotation [rad] errors of each camera's pose relative to the first
    camera, ``T_cam0_camk`` estimated vs true: free of any rig-frame alignment (the quantity
    mrcal's covariance of the extrinsics describes, the solve's reference being camera 0)."""
    from calib.align import rotation_angle
    from polycam.cameras import T_rig_cam_of
    from polycam.geometry import T_inverse

    cams = list(true)
    pos, rot = [], []
    for c in cams[1:]:
        Te = T_inverse(T_rig_cam_of(est[cams[0]])) @ T_rig_cam_of(est[c])
        Tt = T_inverse(T_rig_cam_of(true[cams[0]])) @ T_rig_cam_of(true[c])
        pos.append(np.linalg.norm(Te[:3, 3] - Tt[:3, 3]))
        rot.append(rotation_angle(Te[:3, :3] @ Tt[:3, :3].T))
    return np.array(pos), np.array(rot)


def detection_error(obs, true: dict, board, poses: np.ndarray) -> float:
    """[px] RMS per coordinate of the detected corners vs the true models' projections."""
    from calib.synthetic import project_board

    e = []
    for o, (i, c) in zip(obs.observations, obs.indices_frame_camera):
        ok = o[..., 2] > 0
        e.append(o[ok][:, :2] - project_board(true[obs.cameras[c]], board, poses[i])[ok])
    return math.sqrt(float(np.mean(np.concatenate(e) ** 2)))


def opencv_multiview(obs, object_points: np.ndarray):
    """cv2.calibrateMultiview on mrcal-layout observations → (models dict in camera 0's frame, rms, seconds)."""
    import cv2
    import mrcal

    from polycam.geometry import T_from_Rt, rt_from_T

    cams = obs.cameras
    frames = np.unique(obs.indices_frame_camera[:, 0])
    fidx = {f: k for k, f in enumerate(frames)}
    C, F, N = len(cams), len(frames), object_points.shape[0]
    img = [[np.full((N, 2), -1.0, np.float32) for _ in range(F)] for _ in range(C)]
    mask = np.zeros((C, F), np.uint8)
    for o, (f, c) in zip(obs.observations, obs.indices_frame_camera):
        o = o.reshape(-1, 3)
        if np.all(o[:, 2] > 0):             # whole boards only (partial views confuse its initialisation)
            img[c][fidx[f]][:] = o[:, :2]
            mask[c, fidx[f]] = 1
    objp = [object_points.astype(np.float32)] * F
    sizes = [tuple(int(v) for v in s) for s in obs.imagersizes]
    models = np.full((1, C), cv2.CALIB_MODEL_PINHOLE, np.uint8)
    flags = np.full((1, C), cv2.CALIB_RATIONAL_MODEL, np.int32)
    t = time.perf_counter()
    rms, Ks, dists, Rs, Ts = cv2.calibrateMultiview(objp, img, sizes, mask, models, None, None, None, None,
                                                    flagsForIntrinsics=flags)
    dt = time.perf_counter() - t
    out = {}
    for c, cam in enumerate(cams):
        K, d = np.asarray(Ks[c]), np.asarray(dists[c]).ravel()
        d = np.concatenate([d, np.zeros(max(0, 8 - d.size))])[:8]
        R = np.asarray(Rs[c])
        R = cv2.Rodrigues(R)[0] if R.size == 3 else R.reshape(3, 3)
        T_cam_ref = T_from_Rt(R, np.asarray(Ts[c]).ravel())
        out[cam] = mrcal.cameramodel(intrinsics=("LENSMODEL_OPENCV8", np.concatenate([[K[0, 0], K[1, 1], K[0, 2],
                                                                                        K[1, 2]], d])),
                                     imagersize=np.array(sizes[c]), rt_cam_ref=rt_from_T(T_cam_ref))
    return out, float(rms), dt


NAN_METRICS = dict(proj_rms_px=float("nan"), proj_worst_cam_px=float("nan"), proj_inf_px=float("nan"),
                   pos_mm=float("nan"), rot_deg=float("nan"), rel_pos_mm=float("nan"), rel_rot_deg=float("nan"))


def run_case(work: Path, name: str, rows: int, cols: int, w: int, h: int, frames: int, board_name: str,
             rng, motion: str = "wide", noise_mode: str = "total", noise_px: float = 0.2,
             opencv: bool = True, synthetic: bool = False) -> list[dict]:
    from calib import board_distance, calibrate_board, detect_session, extrinsics_uncertainty
    from polycam.session import open_session
    from polycam.trajectory import read_tum

    pred_truth = predicted_sigma(work, name, rows, cols, w, h, frames, board_name, motion=motion, noise_px=noise_px)
    if synthetic:
        # the solver alone at this design: exact projections + noise_px, no rendering or detection
        from calib import synthetic_observations
        from polycam.board import load_board

        board = load_board(work / f"board-{board_name}.toml")
        rig, true, poses = design(work, name, rows, cols, w, h, frames, board, motion=motion)
        obs = synthetic_observations(true, board, poses, noise_px=noise_px, rng=rng)
        t_render = t_detect = det = 0.0
        seen = obs.observations[..., 2] > 0
    else:
        t = time.perf_counter()
        session, board = session_for(work, name, rows, cols, w, h, frames, board_name, motion=motion)
        t_render = time.perf_counter() - t
        s = open_session(session)
        rig, true = s.rig, s.calibration()
        t = time.perf_counter()
        obs = detect_session(s, board)
        t_detect = time.perf_counter() - t
        poses = read_tum(session / "board_poses.tum").T_world_rig
        det = detection_error(obs, true, board, poses)
        # "total": top the detector's own error up to noise_px per coordinate; "add": noise_px on top of it
        inject = math.sqrt(max(noise_px**2 - det**2, 0.0)) if noise_mode == "total" else noise_px
        seen = obs.observations[..., 2] > 0
        obs.observations[..., :2] += np.where(seen[..., None],
                                              rng.normal(size=obs.observations[..., :2].shape) * inject, 0)
    corner = detection_error(obs, true, board, poses)
    t = time.perf_counter()
    cal = calibrate_board(obs, rig, lensmodel="opencv8")
    t_mrcal = time.perf_counter() - t
    pred = extrinsics_uncertainty(cal.optimization_inputs, corner)[1:]      # relative to camera 0, 1 sigma (3-D)
    case = f"{name} {w}x{h} {board_name} {frames}p {motion}" + (" exact+noise" if synthetic else "")
    n_seen = int(np.count_nonzero(seen))
    outliers = n_seen - int(np.count_nonzero(cal.optimization_inputs["observations_board"][..., 2] > 0))
    rows_out = [dict(case=case, solver="polycam/mrcal", rms_px=cal.rms_px, corner_px=corner, det_px=det,
                     seconds=t_mrcal, detect_s=t_detect, render_s=t_render, pred_pos_mm=1e3 * float(pred[:, 1].max()),
                     pred_rot_deg=math.degrees(float(pred[:, 0].max())), truth_rot_deg=pred_truth[0],
                     truth_pos_mm=pred_truth[1], outlier_frac=outliers / max(n_seen, 1),
                     **metrics(cal.models, true, board_distance(cal.optimization_inputs)))]
    if not opencv:
        return rows_out
    try:
        ocv, rms, t_ocv = opencv_multiview(obs, board.object_points())
        rows_out.append(dict(case=case, solver="OpenCV multiview (full views)", rms_px=rms / math.sqrt(2),
                             corner_px=corner, det_px=det, seconds=t_ocv, detect_s=t_detect, render_s=t_render,
                             pred_pos_mm=float("nan"), pred_rot_deg=float("nan"), truth_rot_deg=float("nan"),
                             truth_pos_mm=float("nan"), outlier_frac=float("nan"),
                             **metrics(ocv, true, board_distance(cal.optimization_inputs), region_from=cal.models)))
    except Exception as e:  # the baseline failing is a result too
        rows_out.append(dict(case=case, solver=f"OpenCV calibrateMultiview FAILED: {e}"[:80], rms_px=float("nan"),
                             corner_px=corner, det_px=det, seconds=float("nan"), detect_s=t_detect,
                             render_s=t_render, pred_pos_mm=float("nan"), pred_rot_deg=float("nan"),
                             truth_rot_deg=float("nan"), truth_pos_mm=float("nan"), outlier_frac=float("nan"),
                             **NAN_METRICS))
    return rows_out


def render_speed(work: Path, repeat: int = 3) -> None:
    """Board-session frames: :class:`polycam.synth.BoardRenderer` (background traced once, the board
    per frame) vs tracing the whole scene (:class:`polycam.synth.CameraArrayRenderer`, the baseline)
    on the 3x3 rig, same poses, best of ``repeat`` after a warm-up, 2 threads and 1 thread."""
    import numba

    from polycam.board import load_board
    from polycam.synth import BoardRenderer, CameraArrayRenderer, room_scene

    print(f"\nboard-session render speed (3x3 rig, supersample 2, load {os.getloadavg()[0]:.1f}); per frame of 9 images")
    print(f"{'resolution':10s} {'board':6s} {'threads':>7s} {'full trace s':>12s} {'BoardRenderer s':>15s} "
          f"{'ratio':>6s} {'traced px %':>11s}")
    for (w, h), bname in (((640, 480), "8x11"), ((1280, 960), "16x22")):
        bp = work / f"board-{bname}.toml"
        bp.write_text(BOARDS[bname])
        board = load_board(bp)
        rig, models, poses = design(work, "rig3x3", 3, 3, w, h, 4, board)
        image, H_image_board = board.render(120, 0.5)
        m = (image.shape[1] - board.cols * 120) / 2.0 / (120 / board.square_length)
        bw, bh = board.size_m
        scene, rect = room_scene(4.0, seed=7, n_spheres=0, n_boxes=0).with_image_rect(
            image, poses[0], (-m, bw + m, -m, bh + m), np.asarray(H_image_board)[:2])
        full = CameraArrayRenderer(rig, models, scene, 2)
        fast = BoardRenderer(rig, models, scene, rect, np.eye(4), 2)
        for threads in (min(2, numba.config.NUMBA_NUM_THREADS), 1):
            numba.set_num_threads(threads)
            tf, tb, mixed = [], [], []
            full.render(np.eye(4), scene.with_rect_pose(rect, poses[0]))      # warm-up (compile)
            fast.render(poses[0])
            for _ in range(repeat):
                for T in poses:
                    t = time.perf_counter()
                    full.render(np.eye(4), scene.with_rect_pose(rect, T))
                    tf.append(time.perf_counter() - t)
                    t = time.perf_counter()
                    fast.render(T)
                    tb.append(time.perf_counter() - t)
                    mixed.append(fast.mixed_fraction)
            a, b = float(np.min(tf)), float(np.min(tb))
            print(f"{w}x{h:<5d} {bname:6s} {threads:7d} {a:12.3f} {b:15.3f} {a / b:6.1f} "
                  f"{100 * float(np.mean(mixed)):11.2f}", flush=True)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=40, help="board poses per session")
    ap.add_argument("--work", default="/tmp/polycam-bench-calib", help="cache of rendered sessions")
    ap.add_argument("--rigs", default="3x3,5x5", help="comma-separated rigs of RIGS (3x3, 5x5)")
    ap.add_argument("--skip-5x5", action="store_true")
    ap.add_argument("--skip-3x3", action="store_true")
    ap.add_argument("--skip-speed", action="store_true", help="skip the 4x4 timing case")
    ap.add_argument("--skip-opencv", action="store_true", help="skip the OpenCV multiview baseline")
    ap.add_argument("--resolution", default=None,
                    help="WxH of every camera (default per rig: 640x480 for 3x3, 320x240 for 5x5)")
    ap.add_argument("--board", choices=sorted(BOARDS), default=None,
                    help="board of BOARDS (default per rig: 8x11 for 3x3, 5x7 for 5x5)")
    ap.add_argument("--predict-only", action="store_true",
                    help="only mrcal's predicted worst-camera sigma of the design (no rendering)")
    ap.add_argument("--synthetic", action="store_true",
                    help="the solver alone: exact corner projections + 0.2 px noise instead of rendered "
                         "detections (no rendering, no detection)")
    ap.add_argument("--motion", choices=sorted(MOTIONS), default="wide", help="board-pose design (see MOTIONS)")
    ap.add_argument("--noise-mode", choices=("total", "add"), default="total",
                    help="total: top the detector's own corner error up to 0.2 px per coordinate; "
                         "add: 0.2 px on top of it (session 1's figures)")
    ap.add_argument("--render-speed", action="store_true",
                    help="only time board-session frames: BoardRenderer vs tracing the whole scene")
    args = ap.parse_args()
    work = Path(args.work)
    work.mkdir(parents=True, exist_ok=True)
    if args.render_speed:
        render_speed(work)
        return 0
    rng = np.random.default_rng(4)
    cases = []
    for rig in (r.strip() for r in args.rigs.split(",") if r.strip()):
        if rig not in RIGS:
            ap.error(f"unknown rig {rig!r} (choose from {', '.join(RIGS)})")
        if (rig == "3x3" and args.skip_3x3) or (rig == "5x5" and args.skip_5x5):
            continue
        r, c, (w, h), b = RIGS[rig]
        if args.resolution:
            w, h = (int(v) for v in args.resolution.lower().split("x"))
        cases.append((f"rig{rig}", r, c, w, h, args.board or b))
    print(f"lens: {'real OPENCV8 ' + LENS.name if LENS.is_file() else 'pinhole (shared data absent)'}; "
          f"corner noise 0.2 px ({args.noise_mode}); board motion {args.motion}; load {os.getloadavg()[0]:.1f}",
          flush=True)
    if args.predict_only:
        for name, r, c, w, h, b in cases:
            rot, pos, dt = predicted_sigma(work, name, r, c, w, h, args.frames, b, motion=args.motion)
            print(f"{name} {w}x{h} {b} {args.frames}p {args.motion}: predicted worst-camera sigma "
                  f"{rot:.4f} deg, {pos:.4f} mm ({dt:.1f} s)", flush=True)
        return 0
    hdr = f"{'case':50s} {'solver':22s} {'RMS':>6s} {'corner':>6s} {'outl%':>5s} {'proj':>6s} {'worst':>6s} " \
          f"{'inf':>6s} {'pos mm':>7s} {'rot deg':>8s} {'relpos':>7s} {'relrot':>7s} {'predpos':>7s} " \
          f"{'predrot':>7s} {'truthrot':>8s} {'render s':>8s} {'detect s':>8s} {'solve s':>7s}"

    def show(rs):
        for r in rs:
            print(f"{r['case']:50s} {r['solver'][:22]:22s} {r['rms_px']:6.3f} {r['corner_px']:6.3f} "
                  f"{100 * r['outlier_frac']:5.1f} {r['proj_rms_px']:6.3f} {r['proj_worst_cam_px']:6.3f} "
                  f"{r['proj_inf_px']:6.3f} {r['pos_mm']:7.3f} {r['rot_deg']:8.4f} {r['rel_pos_mm']:7.3f} "
                  f"{r['rel_rot_deg']:7.4f} {r['pred_pos_mm']:7.3f} {r['pred_rot_deg']:7.4f} "
                  f"{r['truth_rot_deg']:8.4f} {r['render_s']:8.0f} {r['detect_s']:8.1f} {r['seconds']:7.1f}",
                  flush=True)

    print(hdr)
    print("-" * len(hdr), flush=True)
    rows = []
    for name, r, c, w, h, b in cases:
        t = time.perf_counter()
        rs = run_case(work, name, r, c, w, h, args.frames, b, rng, motion=args.motion, noise_mode=args.noise_mode,
                      opencv=not args.skip_opencv, synthetic=args.synthetic)
        show(rs)
        print(f"  {rs[0]['case']}: whole case {time.perf_counter() - t:.0f} s (load {os.getloadavg()[0]:.1f})",
              flush=True)
        rows += rs
    for k in range(0, len(rows) - 1, 2):
        a, b = rows[k], rows[k + 1]
        if a["case"] == b["case"] and math.isfinite(b["seconds"]):
            print(f"{a['case']}: mrcal / OpenCV time ratio {a['seconds'] / b['seconds']:.2f}; projection error "
                  f"ratio {a['proj_rms_px'] / b['proj_rms_px']:.2f}")
    print("targets: proj <= 0.05 px, pos <= 0.2 mm, rot <= 0.01 deg, RMS near 0.2 px")
    if args.skip_speed:
        return 0

    # speed: 4x4 rig, 40 poses, detection + solve
    from calib import calibrate_board, detect_session
    from polycam.session import open_session

    session, board = session_for(work, "rig4x4", 4, 4, 320, 240, 40, "5x7", motion="basic")
    s = open_session(session)
    t = time.perf_counter()
    obs = detect_session(s, board)
    t1 = time.perf_counter()
    calibrate_board(obs, s.rig, lensmodel="opencv8")
    t2 = time.perf_counter()
    calibrate_board(obs, s.rig, lensmodel="opencv8", valid_region=False)
    t3 = time.perf_counter()
    print(f"\n4x4 rig, 40 poses, 320x240: detection {t1 - t:.1f} s + solve {t2 - t1:.1f} s = {t2 - t:.1f} s "
          f"(target < 60 s); solve without uncertainty/valid region {t3 - t2:.1f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
