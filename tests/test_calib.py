"""Board calibration (calib/): a rendered board session end to end, exact recovery from
noise-free synthetic observations for every lens model, and the user errors
(disconnected cameras, cameras without views, wrong board files, skipped images)."""

from __future__ import annotations

import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from polycam.board import load_board
from polycam.cameras import T_rig_cam_of
from polycam.geometry import T_from_rt
from polycam.errors import InputError
from polycam.rig import load_rig
from polycam.synth import board_poses, synth_board_session, true_cameramodels

from conftest import SHARED_DATA
from tolerances import (CALIB_CORNER_DRIFT_PX, CALIB_REFINED_CORNER_GAIN, CALIB_SPLINED_POSITION_M, CALIB_EXACT_POSITION_M, CALIB_EXACT_PROJECTION_PX, CALIB_EXACT_REPROJ_PX,
                        CALIB_EXACT_ROTATION_DEG, CALIB_RENDERED_POSITION_M, CALIB_RENDERED_PROJECTION_PX,
                        CALIB_RENDERED_RMS_PX, CALIB_RENDERED_ROTATION_DEG, CALIB_UNCERTAINTY_DRAWS,
                        CALIB_UNCERTAINTY_RATIO, CALIB_SPLINED_BUNDLE_DEG, CALIB_SPLINED_RIG_DEG)

BOARD = """[board]
type = "charuco"
squares = [5, 7]
square_length = 0.04
marker_length = 0.03
dictionary = "DICT_5X5_100"
"""

LENS = SHARED_DATA / "mrcal-models" / "cam0.opencv8.cameramodel"


def _rig(tmp: Path, *, lens: bool = True, cols: int = 2, rows: int = 2, width: int = 320, height: int = 240):
    lens_line = f'lens = "{LENS}"\n' if lens and LENS.is_file() else ""
    p = tmp / "rig.toml"
    p.write_text(f"""[rig]
name = "calibtest"
[defaults]
width = {width}
height = {height}
fov_deg = 65
{lens_line}
[grid]
rows = {rows}
cols = {cols}
pitch = 0.05
""")
    return load_rig(p)


def _board(tmp: Path, text: str = BOARD, name: str = "board.toml"):
    p = tmp / name
    p.write_text(text)
    return load_board(p)


def _inside(model, q: np.ndarray) -> np.ndarray:
    """(...) bool: pixels q (..., 2) inside the model's valid-intrinsics region (or, when that is
    missing or tiny, the central half of the imager)."""
    import cv2

    W, H = model.imagersize()
    region = model.valid_intrinsics_region()
    if region is not None and len(region) >= 4 and cv2.contourArea(region.astype(np.float32)) > 0.1 * W * H:
        c = region.astype(np.float32)
        return np.array([cv2.pointPolygonTest(c, (float(x), float(y)), False) >= 0
                         for x, y in q.reshape(-1, 2)]).reshape(q.shape[:-1])
    return (np.abs(q[..., 0] - (W - 1) / 2) <= W / 4) & (np.abs(q[..., 1] - (H - 1) / 2) <= H / 4)


def _aligned_errors(T_est: np.ndarray, T_true: np.ndarray) -> tuple[float, float]:
    """(max position error [m], max rotation error [deg]) after a rigid alignment."""
    from calib.align import fit_rig_frame

    fit = fit_rig_frame(T_est, T_true, position_sigma_m=1.0, rotation_sigma_deg=1e-3)   # rotation from orientations
    return float(fit.position_residuals_m.max()), math.degrees(float(fit.rotation_residuals_rad.max()))


def _render_board_session(tmp: Path, lens: bool):
    rig = _rig(tmp, lens=lens)
    board = _board(tmp)
    out = synth_board_session(rig, tmp / "session", board=board, frames=16, seed=3, supersample=2, noise=0.004,
                              perturb_position_m=0.001, perturb_rotation_deg=0.3, perturb_focal_frac=0.01)
    return out, board


@pytest.fixture(scope="module")
def board_session(tmp_path_factory):
    """A rendered 2x2 board session with a pinhole truth (no external data needed)."""
    return _render_board_session(tmp_path_factory.mktemp("calib"), lens=False)


@pytest.fixture(scope="module")
def lens_board_session(tmp_path_factory):
    """The same session through the real OPENCV8 lens from ../shared/data (skipped without it)."""
    if not LENS.is_file():
        pytest.skip(f"real lens model not found at {LENS}")
    return _render_board_session(tmp_path_factory.mktemp("calib-lens"), lens=True)


@pytest.mark.parametrize("truth", ["pinhole", "real lens"])
def test_rendered_board_session_end_to_end(truth, request, tmp_path):
    """`polycam calibrate` on a rendered session (pinhole truth, and the real OPENCV8 lens when
    ../shared/data has it): models in the rig frame close to the truth, optimization_inputs
    usable by mrcal's own tools, report and exports written.

    The projection difference is taken at the board distance, where the data pin the lens
    down: at infinity 16 poses of a 2x2 rig leave mrcal's own predicted projection
    uncertainty at ~0.19 px (worst direction, 1 sigma), and the measured differences there
    (0.06-0.44 px, seed-dependent, pinhole and real lens alike) are that noise, not a bias."""
    import mrcal

    from polycam.cli import main
    from polycam.session import open_session

    session, board = request.getfixturevalue("board_session" if truth == "pinhole" else "lens_board_session")
    out = tmp_path / "calib"
    rc = main(["calibrate", str(session), "--board", str(session / "board.toml"), "--out", str(out),
               "--export", "colmap,opencv", "--rays", "--no-plots"])
    assert rc == 0
    s = open_session(session)
    true = s.calibration()
    est = s.calibration(out)
    cams = list(true)
    T_est = np.stack([T_rig_cam_of(est[c]) for c in cams])
    T_true = np.stack([T_rig_cam_of(true[c]) for c in cams])
    pos, rot = _aligned_errors(T_est, T_true)
    assert pos <= CALIB_RENDERED_POSITION_M and rot <= CALIB_RENDERED_ROTATION_DEG
    # the rig frame comes from the nominal layout: solved centres near the rig file's
    nominal = np.stack([c.position for c in s.rig.cameras])
    assert np.abs(T_est[:, :3, 3] - nominal).max() < 0.01
    import tomllib

    report = tomllib.loads((out / "report.toml").read_text())
    assert report["calibration"]["rms_px"] <= CALIB_RENDERED_RMS_PX
    assert report["graph"]["shared_frames"][0][1] >= 2
    sigma = report["camera"][cams[1]]["pose_sigma_vs_first_camera"]      # mrcal's predicted pose errors
    assert 0 < sigma["position_m"] < CALIB_RENDERED_POSITION_M and 0 < sigma["rotation_deg"] < CALIB_RENDERED_ROTATION_DEG
    for cam in cams:
        m = est[cam]
        assert m.optimization_inputs() is not None           # mrcal's tools work on the files
        u = mrcal.projection_uncertainty(np.array([0.0, 0.0, 1.0]), model=m, atinfinity=True,
                                         what="worstdirection-stdev")
        assert np.isfinite(u) and u > 0
        diff, _, q0, _ = mrcal.projection_diff((m, true[cam]), use_uncertainties=False, gridn_width=20,
                                               distance=report["calibration"]["board_distance_m"])
        assert math.sqrt(np.nanmean(diff[_inside(m, q0)] ** 2)) <= CALIB_RENDERED_PROJECTION_PX
        assert report["camera"][cam]["views"] >= 2
    assert (out / "corners.vnl").is_file() and (out / "colmap" / "rig_config.json").is_file()
    assert (out / "opencv.yaml").is_file() and (out / "rays" / "cam00.npz").is_file()
    assert (out / "report.md").read_text().startswith("# Calibration report")


def _exact_problem(tmp: Path, lensmodel_true: str):
    rig = _rig(tmp, lens=lensmodel_true == "opencv8", cols=3, rows=1, width=400, height=300)
    board = _board(tmp)
    true = true_cameramodels(rig, seed=2, perturb_position_m=0.001, perturb_rotation_deg=0.3,
                             perturb_focal_frac=0.01)
    poses = board_poses(board, true, 18, seed=2)
    return rig, board, true, poses


@pytest.mark.parametrize("lensmodel", ["opencv4", "opencv5", "opencv8", "splined"])
def test_lens_models_recover_noise_free_truth(tmp_path, lensmodel):
    """Noise-free synthetic corners: every lens model reproduces a pinhole truth exactly
    (and OPENCV8 the real OPENCV8 lens) with the cameras where they were."""
    import mrcal

    from calib import calibrate_board
    from calib.synthetic import synthetic_observations

    truth_lens = "opencv8" if lensmodel == "opencv8" else "pinhole"
    if truth_lens == "opencv8" and not LENS.is_file():
        pytest.skip(f"real lens model not found at {LENS}")
    rig, board, true, poses = _exact_problem(tmp_path, truth_lens)
    obs = synthetic_observations(true, board, poses, noise_px=0.0)
    exact = lensmodel != "splined"      # splined models need mrcal's regularisation
    cal = calibrate_board(obs, rig, lensmodel=lensmodel, valid_region=False, board_warp=False,
                          regularization=not exact)
    assert cal.lensmodel.startswith("LENSMODEL_" + ("SPLINED" if lensmodel == "splined" else lensmodel.upper()))
    # OPENCV5/8 start from an OPENCV4 solve (from the stereographic core, a noise-free OPENCV8 solve of
    # the real lens stopped in a 0.3 px local minimum on one CPU type)
    staged = [name for name, _ in cal.stages]
    assert ("LENSMODEL_OPENCV4" in staged[:-1]) == (lensmodel in ("opencv5", "opencv8"))
    # the calibration's covariance (calib.draws) maps the solve's lens states onto the lens
    # parameters: all of them, or without the 4 core ones the splined solve locks
    from calib.draws import calibration_covariance, drawn_models

    cc = calibration_covariance(cal.models)
    n_lens = len(cal.models[next(iter(cal.models))].intrinsics()[1])
    assert list(cc.lens_parameters) == list(range(4 if lensmodel == "splined" else 0, n_lens))
    if lensmodel == "splined":                                       # its locked core stays
        drawn = drawn_models(cal.models, cc, np.random.default_rng(0).standard_normal(cc.dim))
        assert all(np.array_equal(drawn[c].intrinsics()[1][:4], m.intrinsics()[1][:4]) for c, m in cal.models.items())
    from calib.align import fit_rig_frame, rotation_angle

    cams = list(true)
    T_est = np.stack([cal.T_rig_cam[c] for c in cams])
    T_true = np.stack([T_rig_cam_of(true[c]) for c in cams])
    pos, rot = _aligned_errors(T_est, T_true)
    T_aligned = np.einsum("ij,njk->nik", fit_rig_frame(T_est, T_true, position_sigma_m=1.0,
                                                       rotation_sigma_deg=1e-3).T_rig_ref, T_est)
    # splined models are regularised (not exact), and a spline can absorb part of a camera
    # rotation, so for them only positions and rig-frame projections are checked
    assert cal.rms_px <= (CALIB_EXACT_REPROJ_PX if exact else 0.05)
    assert pos <= (CALIB_EXACT_POSITION_M if exact else CALIB_SPLINED_POSITION_M)
    if exact:
        assert rot <= CALIB_EXACT_ROTATION_DEG
    for c in cams:
        m, t = cal.models[c], true[c]
        o = obs.observations[obs.indices_frame_camera[:, 1] == cams.index(c)].reshape(-1, 3)
        q = o[o[:, 2] > 0, :2]                                       # where the board was seen
        v = mrcal.unproject(np.ascontiguousarray(q), *m.intrinsics(), normalize=True)
        k = cams.index(c)
        R = T_true[k, :3, :3].T @ T_aligned[k, :3, :3]               # est camera → true camera
        d = np.linalg.norm(mrcal.project(v @ R.T, *t.intrinsics()) - q, axis=-1)
        if exact:
            assert math.sqrt(np.mean(d**2)) <= CALIB_EXACT_PROJECTION_PX
    if not exact:
        # a spline absorbs part of its camera's rotation, so compare ray bundles: the rotation taking each
        # camera's solved rig-frame rays onto the true ones (observed pixels) is one common rotation (the
        # rig-frame definition), and that is small because the rig fit uses the bundles' orientations
        R_bundle = []
        for k, c in enumerate(cams):
            o = obs.observations[obs.indices_frame_camera[:, 1] == k].reshape(-1, 3)
            q = np.ascontiguousarray(o[o[:, 2] > 0, :2])
            d_est = mrcal.unproject(q, *cal.models[c].intrinsics(), normalize=True) @ cal.T_rig_cam[c][:3, :3].T
            d_true = mrcal.unproject(q, *true[c].intrinsics(), normalize=True) @ T_true[k, :3, :3].T
            U, _, Vt = np.linalg.svd(d_true.T @ d_est)
            R_bundle.append(U @ np.diag([1, 1, np.sign(np.linalg.det(U @ Vt))]) @ Vt)
        common = max(math.degrees(rotation_angle(R)) for R in R_bundle)
        spread = max(math.degrees(rotation_angle(R @ R_bundle[0].T)) for R in R_bundle)
        assert spread <= CALIB_SPLINED_BUNDLE_DEG and common <= CALIB_SPLINED_RIG_DEG


def test_cameramodel_file_round_trip(tmp_path):
    """Written models read back identically, optimization_inputs included."""
    from calib import calibrate_board, load_models, write_models
    from calib.synthetic import synthetic_observations

    rig, board, true, poses = _exact_problem(tmp_path, "pinhole")
    cal = calibrate_board(synthetic_observations(true, board, poses, noise_px=0.1), rig, lensmodel="opencv4",
                          valid_region=False)
    write_models(cal.models, tmp_path / "out")
    back = load_models(tmp_path / "out")
    assert sorted(back) == sorted(cal.models)
    for c, m in cal.models.items():
        np.testing.assert_allclose(back[c].intrinsics()[1], m.intrinsics()[1], rtol=1e-9)
        np.testing.assert_allclose(back[c].rt_cam_ref(), m.rt_cam_ref(), atol=1e-9)
        np.testing.assert_allclose(back[c].optimization_inputs()["intrinsics"],
                                   m.optimization_inputs()["intrinsics"], rtol=1e-9)


def test_disconnected_cameras_are_named(tmp_path):
    """Two camera groups that never see the board together: one clear error naming them."""
    from calib import calibrate_board
    from calib.synthetic import synthetic_observations

    rig = _rig(tmp_path, lens=False, cols=4, rows=1)
    board = _board(tmp_path)
    true = true_cameramodels(rig)
    poses = board_poses(board, true, 8, seed=1)
    obs = synthetic_observations(true, board, poses)
    f, c = obs.indices_frame_camera[:, 0], obs.indices_frame_camera[:, 1]
    keep = ((f % 2 == 0) & (c < 2)) | ((f % 2 == 1) & (c >= 2))    # cam00/01 on even, cam02/03 on odd frames
    with pytest.raises(InputError, match=r"cam02, cam03.*\{cam00, cam01\} \| \{cam02, cam03\}"):
        calibrate_board(obs.subset(keep), rig)


def test_camera_without_views_is_named(tmp_path):
    from calib import calibrate_board
    from calib.synthetic import synthetic_observations

    rig = _rig(tmp_path, lens=False, cols=3, rows=1)
    board = _board(tmp_path)
    true = true_cameramodels(rig)
    obs = synthetic_observations(true, board, board_poses(board, true, 6, seed=1))
    with pytest.raises(InputError, match="no usable board view in camera.*cam01"):
        calibrate_board(obs.subset(obs.indices_frame_camera[:, 1] != 1), rig)


def test_wrong_dictionary_is_diagnosed(board_session, tmp_path):
    from calib import detect_session
    from polycam.session import open_session

    session, _ = board_session
    wrong = _board(tmp_path, BOARD.replace("DICT_5X5_100", "DICT_4X4_50"), "wrong.toml")
    with pytest.raises(InputError, match="DICT_5X5_100 were found"):
        detect_session(open_session(session), wrong)


def test_wrong_square_count_is_counted(board_session, tmp_path, caplog):
    """Markers the board file cannot have (a 3x3 board has 4 markers) count as 'wrong board'."""
    from calib import detect_session
    from polycam.session import open_session

    session, _ = board_session
    small = _board(tmp_path, BOARD.replace("[5, 7]", "[3, 3]"), "small.toml")
    with pytest.raises(InputError, match="do not fit a 3x3 board"):
        detect_session(open_session(session), small)
    assert "wrong board" in caplog.text


def test_blank_and_blurred_images_are_counted(board_session, tmp_path, caplog):
    """A session with an empty frame and a blurred frame: counted per camera, warned about by name."""
    import cv2

    from calib import detect_session
    from polycam.session import SessionWriter, open_session

    src = open_session(board_session[0])
    board = board_session[1]
    out = tmp_path / "mixed"
    with SessionWriter(out, src.rig) as w:
        for i in range(3):
            w.add_frame(i * 1000, src.read_frame(i))
        imgs = src.read_frame(3)
        w.add_frame(5000, {c: np.full_like(im, 128) for c, im in imgs.items()})           # no board
        w.add_frame(6000, {c: cv2.GaussianBlur(im, (0, 0), 6.0) for c, im in imgs.items()})  # blurred
    obs = detect_session(open_session(out), board)
    for cam, counts in obs.counts.items():
        assert counts["images"] == 5
        assert counts["used"] + sum(counts[r] for r in ("no board", "blurred", "wrong board", "too few corners")) == 5
        assert counts["blurred"] + counts["no board"] >= 2
    assert "cam00" in caplog.text and "6000.png" in caplog.text


def test_corner_refinement_removes_the_markers_pull(board_session):
    """The refinement inside the markers' margin (calib.detect.SUBPIX_MARGIN_SHARE) against OpenCV's own
    ChArUco corners, both against the true projections: a smaller error, and no drift outward from the
    board's centre (the drift a focal length absorbs; docs/calibration.md)."""
    from calib.detect import _Detector, _to_gray8
    from calib.synthetic import project_board
    from polycam.session import open_session
    from polycam.trajectory import read_tum

    session, board = board_session
    s = open_session(session)
    poses = read_tum(session / "board_poses.tum").T_world_rig
    true = s.calibration()
    det = _Detector(board)
    w = board.cols - 1
    err = {"opencv": [], "refined": []}
    index = []
    for i in range(len(s)):
        for cam, image in s.read_frame(i).items():
            g = _to_gray8(image)
            q, ids, _, _ = det._charuco(g)
            if q is None or len(ids) < 8:
                continue
            truth = project_board(true[cam], board, poses[i]).reshape(-1, 2)[ids]
            axis = project_board(true[cam], board, poses[i])
            ax = np.gradient(axis, axis=1).reshape(-1, 2)[ids]          # the board's x axis in the image
            ax /= np.linalg.norm(ax, axis=1, keepdims=True)
            for name, c in (("opencv", q), ("refined", det.refine(g, q, ids))):
                e = c - truth
                err[name].append(np.stack([np.sum(e * ax, axis=1), np.hypot(*e.T)], axis=1))
            index.append(ids % w - (w - 1) / 2)                             # corner column from the centre
    index = np.concatenate(index)
    stats = {}
    for name, v in err.items():
        e = np.concatenate(v)
        stats[name] = (math.sqrt(np.mean(e[:, 1] ** 2)), np.polyfit(index, e[:, 0], 1)[0])   # RMS, drift
    assert stats["refined"][0] < CALIB_REFINED_CORNER_GAIN * stats["opencv"][0], stats
    assert abs(stats["refined"][1]) < CALIB_CORNER_DRIFT_PX < abs(stats["opencv"][1]), stats


def test_detected_corners_match_the_truth(board_session):
    """Detections land where the true model projects the true board pose."""
    from calib import detect_session
    from calib.synthetic import project_board
    from polycam.session import open_session
    from polycam.trajectory import read_tum

    session, board = board_session
    s = open_session(session)
    obs = detect_session(s, board)
    poses = read_tum(session / "board_poses.tum").T_world_rig
    true = s.calibration()
    errs = []
    for o, (i, c) in zip(obs.observations, obs.indices_frame_camera):
        q = project_board(true[obs.cameras[c]], board, poses[i])
        ok = o[..., 2] > 0
        errs.append(o[ok][:, :2] - q[ok])
    e = np.concatenate(errs)
    assert math.sqrt(np.mean(np.sum(e**2, axis=1))) < 0.25 and np.abs(e.mean(axis=0)).max() < 0.05


def test_cli_errors_are_one_line(tmp_path, board_session):
    """Missing board file / board option: exit 1 with one line on stderr."""
    session, _ = board_session
    cmd = [sys.executable, "-m", "polycam.cli", "calibrate", str(session), "--out", str(tmp_path / "o")]
    r = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
    assert r.returncode == 1 and "--board" in r.stderr and len(r.stderr.strip().splitlines()) == 1
    r = subprocess.run(cmd + ["--board", str(tmp_path / "missing.toml")], capture_output=True, text=True, timeout=120)
    assert r.returncode == 1 and "missing.toml" in r.stderr and len(r.stderr.strip().splitlines()) == 1


def test_extrinsics_uncertainty_matches_the_scatter(tmp_path):
    """mrcal's covariance of the camera poses (calib.extrinsics_uncertainty) predicts the scatter of
    the relative poses over noise draws: the measured errors are noise, not a bias."""
    from calib import calibrate_board, extrinsics_uncertainty
    from calib.synthetic import synthetic_observations
    from polycam.geometry import T_inverse, r_from_R

    rig, board, true, poses = _exact_problem(tmp_path, "pinhole")
    cams = list(true)
    T_true = [T_inverse(T_rig_cam_of(true[c])) @ T_rig_cam_of(true[cams[0]]) for c in cams]   # T_camk_cam0
    rot, pos, pred = [], [], None
    for seed in range(CALIB_UNCERTAINTY_DRAWS):
        obs = synthetic_observations(true, board, poses, noise_px=0.3, rng=np.random.default_rng(seed))
        cal = calibrate_board(obs, rig, lensmodel="opencv4", valid_region=False, board_warp=False,
                              outlier_rejection=False)
        if pred is None:
            pred = extrinsics_uncertainty(cal.optimization_inputs, 0.3)
            assert pred.shape == (len(cams), 2) and np.all(pred[0] == 0) and np.all(pred[1:] > 0)
        for k in range(1, len(cams)):
            T = T_from_rt(cal.optimization_inputs["rt_cam_ref"][k - 1])
            rot.append(np.linalg.norm(r_from_R(T[:3, :3] @ T_true[k][:3, :3].T)))
            pos.append(np.linalg.norm(T[:3, 3] - T_true[k][:3, 3]))
    # predicted 3-D sigma vs the RMS of the measured 3-D errors over draws and cameras
    for measured, predicted in ((np.array(rot), pred[1:, 0]), (np.array(pos), pred[1:, 1])):
        ratio = math.sqrt(np.mean(measured**2)) / math.sqrt(np.mean(predicted**2))
        assert 1 / CALIB_UNCERTAINTY_RATIO <= ratio <= CALIB_UNCERTAINTY_RATIO


def test_a_failed_calibration_leaves_no_empty_folder(tmp_path):
    """A session in which no board is seen: one error, and the --out folder the command would have
    made is not left behind empty (an existing one stays)."""
    from calib.pipeline import calibrate_session
    from polycam.session import SessionWriter

    rig = _rig(tmp_path, lens=False, cols=2, rows=1, width=64, height=48)
    with SessionWriter(tmp_path / "s", rig) as w:
        for k in range(3):
            w.add_frame(1000 + k, {c: np.full((48, 64), 128, np.uint8) for c in rig.ids})
    board = _board(tmp_path)
    with pytest.raises(InputError):
        calibrate_session(tmp_path / "s", tmp_path / "o", board=board)
    assert not (tmp_path / "o").exists()
    (tmp_path / "mine").mkdir()
    with pytest.raises(InputError):
        calibrate_session(tmp_path / "s", tmp_path / "mine", board=board)
    assert (tmp_path / "mine").is_dir()
