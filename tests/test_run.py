"""`polycam run` (issue 7): the whole chain on a small mock rig (both sessions recorded through
the capture stage's mock driver), its report folder with depth against the truth, and the
chain stopping with `run: STAGE: reason` when a stage's output is unusable."""

from __future__ import annotations

import math

import numpy as np

from polycam.cli import main
from polycam.trajectory import read_tum
from conftest import assert_one_line_error as _one_line_error
from conftest import REPO, mock_grid_rig_text
from tolerances import E2E_RUN_DEPTH_REL, E2E_RUN_MOTION_REL, E2E_RUN_PAIR_DEPTH_REL, IMAGE_NOISE_LOW_RTOL

RUN_RIG_TEXT = mock_grid_rig_text("run3x3", 160, 120)


def test_run_small_rig_end_to_end(tmp_path, capsys):
    """`polycam run` on a 3x3 rig of 160x120 cameras: every stage prints its line, the report
    folder has every picture, the trajectory follows the ground truth."""
    import tomllib

    (tmp_path / "rig.toml").write_text(RUN_RIG_TEXT)
    out = tmp_path / "run"
    code = main(["run", str(tmp_path / "rig.toml"), "--out", str(out), "--board-frames", "12", "--frames", "3"])
    cap = capsys.readouterr()
    assert code == 0, cap.err
    for stage in ("board", "calibrate", "capture", "resample", "motion", "depth", "report"):
        assert any(line.startswith(stage) for line in cap.out.splitlines()), (stage, cap.out)
    for rel in ("calib/cam04.cameramodel", "calib/report.md", "session/groundtruth.tum", "lightfield.zarr/zarr.json",
                "trajectory.tum", "board_session/board_poses.tum", "board_session/capture_stats.toml",
                "session/capture_stats.toml", "session/calib/cam04.cameramodel"):
        assert (out / rel).exists(), rel
    rep = out / "report"
    for name in ("README.md", "summary.toml", "pairs.csv", "trajectory.png", "errors.png", "options.toml",
                 "calibration_residuals.png", "mosaic.png", "epi.png", "depth.png", "points.ply"):
        assert (rep / name).stat().st_size > 0, name
    summary = tomllib.loads((rep / "summary.toml").read_text())
    assert summary["motion"]["failed"] == 0 and summary["motion"]["pairs"] == 2
    assert summary["motion"]["sampling_check_xy_oversample"] == 0 and "second view sampling" not in cap.out
    assert summary["motion"]["seconds_per_pair"] > 0 and summary["motion"]["seconds_first_pair"] > 0
    assert summary["motion"]["error_over_std_t"] > 0 and summary["motion"]["error_over_std_w"] > 0
    assert summary["calibrate"]["rms_px"] < 0.5
    assert summary["resample"]["mean_W"] > 0.3
    # the rig's 1 grey level of noise (and the rounding), from the cameras' images: the image estimator's
    # tolerance at 1 grey level (160 x 120 images), printed on the resample line too
    assert abs(summary["resample"]["camera_noise_grey"] / math.hypot(1.02, 12 ** -0.5) - 1) < IMAGE_NOISE_LOW_RTOL
    assert "the cameras' sensor noise" in next(l for l in cap.out.splitlines() if l.startswith("resample"))
    assert summary["depth"]["points"] > 1000
    assert summary["depth"]["truth_rays"] > 1000 and summary["depth"]["median_rel_error"] < E2E_RUN_DEPTH_REL
    assert summary["board"]["dropped"] == 0 and summary["capture"]["frames"] == 3
    assert summary["resample"]["views"] == [5, 5]        # a 3x3 rig gets in-between views (run.MIN_VIEWS)
    header = (rep / "points.ply").read_text().split("end_header")[0]
    assert header.startswith("ply") and f"element vertex {summary['depth']['points']}" in header
    from polycam.evaluate import pair_errors

    err = pair_errors(read_tum(out / "trajectory.tum"), read_tum(out / "session" / "groundtruth.tum"))
    assert np.median(err.t_rel) < E2E_RUN_MOTION_REL and np.median(err.w_rel) < E2E_RUN_MOTION_REL
    _check_calibration_draws(tmp_path, out, summary, cap.out, capsys)


def _check_calibration_draws(tmp_path, out, summary: dict, printed: str, capsys) -> None:
    """The calibration's share of the covariance: `polycam run`'s default draws (summary, its line,
    pairs.csv, inside the reported std), `polycam motion SESSION --calib-draws`, and its user errors."""
    import csv

    from polycam.run import RunOptions

    m = summary["motion"]
    assert m["calibration_draws"] == RunOptions.calib_draws and m["median_std_calib_t_m"] > 0
    assert m["median_std_calib_w_deg"] > 0 and m["seconds_calibration_draws"] > 0
    lines = printed.splitlines()
    k = next(i for i, line in enumerate(lines) if line.startswith("motion"))
    assert lines[k + 1].strip().startswith(f"calibration: {RunOptions.calib_draws} draws from its uncertainty"), printed
    rows = list(csv.DictReader((out / "report" / "pairs.csv").read_text().splitlines()))
    for row in rows:
        std_t = np.sqrt(sum(float(row[f"std_t_{a}"]) ** 2 for a in "xyz"))
        assert 0 < float(row["std_calib_t"]) <= std_t and 0 < float(row["std_calib_r"])
    # the motion verb on the recorded session with the run's calibration, one draw
    code = main(["motion", str(out / "session"), "--calib", str(out / "calib"), "--uv-step", "2",
                 "--xy-oversample", "2", "--calib-draws", "1", "--out", str(tmp_path / "m.tum"),
                 "--report", str(tmp_path / "mrep")])
    cap = capsys.readouterr()
    assert code == 0, cap.err
    assert "calibration: 1 draws from its uncertainty (2 re-solves" in cap.out, cap.out
    rows = list(csv.DictReader((tmp_path / "mrep" / "pairs.csv").read_text().splitlines()))
    assert len(rows) == 2 and all(float(r["std_calib_t"]) > 0 for r in rows)
    # a store keeps no models; the true models (a rig file's nominal ones) have no covariance
    code = main(["motion", str(out / "lightfield.zarr"), "--calib-draws", "1", "--out", str(tmp_path / "s.tum")])
    _one_line_error(capsys, code, "lightfield.zarr: --calib-draws needs a session and its calibration")
    code = main(["motion", str(out / "session"), "--calib", str(out / "session" / "calib"), "--calib-draws", "1",
                 "--out", str(tmp_path / "t.tum")])
    _one_line_error(capsys, code, f"{out / 'session' / 'calib'}: camera ", "no optimisation record")
    assert not (tmp_path / "s.tum").exists() and not (tmp_path / "t.tum").exists()


def test_run_stops_at_an_unusable_stage(tmp_path, capsys):
    """Two board frames cannot calibrate nine cameras: the chain stops naming the stage."""
    (tmp_path / "rig.toml").write_text(RUN_RIG_TEXT)
    code = main(["run", str(tmp_path / "rig.toml"), "--out", str(tmp_path / "run"), "--board-frames", "2",
                 "--frames", "2"])
    _one_line_error(capsys, code, "run: calibrate: ")
    assert not (tmp_path / "run" / "session").exists()      # later stages did not run


def test_run_bad_rig_file_is_one_line(tmp_path, capsys):
    code = main(["run", str(tmp_path / "nope.toml"), "--out", str(tmp_path / "run")])
    _one_line_error(capsys, code, "nope.toml")


def test_run_out_that_is_a_file_is_one_line(tmp_path, capsys):
    (tmp_path / "run").write_text("keep me")
    code = main(["run", str(REPO / "rigs" / "mock5x5.toml"), "--out", str(tmp_path / "run")])
    _one_line_error(capsys, code, f"--out {tmp_path / 'run'}: exists and is not a folder")
    assert (tmp_path / "run").read_text() == "keep me"


def test_run_single_camera_stops_at_motion_naming_the_unobservable(tmp_path, capsys):
    """One camera cannot see the translation: the chain calibrates and resamples, then stops at the
    motion stage with the solver's reason, and its summary line says no pair was solved (no NaNs)."""
    (tmp_path / "rig.toml").write_text(mock_grid_rig_text("one", 160, 120, rows=1, cols=1))
    code = main(["run", str(tmp_path / "rig.toml"), "--out", str(tmp_path / "run"), "--board-frames", "6",
                 "--frames", "2"])
    cap = capsys.readouterr()
    assert code == 1
    motion = [line for line in cap.out.splitlines() if line.startswith("motion")]
    assert len(motion) == 1 and "no pair solved" in motion[0] and "nan" not in motion[0], cap.out
    assert cap.err.strip().splitlines()[-1].startswith("polycam: error: run: motion: ")
    assert "unobservable: t_x, t_y, t_z" in cap.err


def test_run_linear_rig_end_to_end(tmp_path, capsys):
    """A row of three cameras (a linear array: one viewpoint along y) runs the whole chain: the
    motion solver takes the unmeasured L_y from ρ̂ L_v and extrapolates off the row by Eq. 6.
    With --sampling-check: the pairs re-solved on 5 views per camera spacing (the row's default 4, plus
    one), the change's share in the summary and on its own line."""
    import tomllib

    (tmp_path / "rig.toml").write_text(mock_grid_rig_text("row", 160, 120, rows=1, cols=3))
    out = tmp_path / "run"
    code = main(["run", str(tmp_path / "rig.toml"), "--out", str(out), "--board-frames", "12", "--frames", "3",
                 "--sampling-check"])
    cap = capsys.readouterr()
    assert code == 0, cap.err
    summary = tomllib.loads((out / "report" / "summary.toml").read_text())
    assert sorted(summary["resample"]["views"]) == [1, 9]
    m = summary["motion"]
    assert m["sampling_check_xy_oversample"] == 5 and m["seconds_sampling_check"] > 0
    assert m["median_std_sampling_t_m"] > 0 and m["median_std_sampling_w_deg"] > 0
    assert "second view sampling (5 views per camera spacing, 1x11 views" in cap.out, cap.out
    assert summary["resample"]["uv_step_px"] == 2.0 and "uv_disparity" not in summary["resample"]
    assert summary["motion"]["failed"] == 0 and summary["motion"]["pairs"] == 2
    from polycam.evaluate import pair_errors

    err = pair_errors(read_tum(out / "trajectory.tum"), read_tum(out / "session" / "groundtruth.tum"))
    assert np.median(err.t_rel) < E2E_RUN_MOTION_REL and np.median(err.w_rel) < E2E_RUN_MOTION_REL
    assert summary["depth"]["points"] > 1000


def test_run_chooses_the_direction_step_on_request(tmp_path, capsys):
    """`polycam run --uv-step auto`: the step polycam motion SESSION would choose (a row of cameras 2 cm
    apart in the room: views close for the scene, 1 pixel), in the resample line and the summary; and the
    views per camera spacing it chooses for a 2-D array far apart for the scene (3)."""
    import tomllib

    from polycam.run import AUTO_UV_MAX_DISPARITY, AUTO_XY_MAX_DISPARITY

    (tmp_path / "rig.toml").write_text(mock_grid_rig_text("row", 160, 120, rows=1, cols=3))
    out = tmp_path / "run"
    code = main(["run", str(tmp_path / "rig.toml"), "--out", str(out), "--board-frames", "12", "--frames", "2",
                 "--uv-step", "auto", "--calib-draws", "0"])
    cap = capsys.readouterr()
    assert code == 0, cap.err
    r = tomllib.loads((out / "report" / "summary.toml").read_text())["resample"]
    assert r["uv_step_px"] == 1.0 and 0.0 < r["uv_disparity"] <= AUTO_UV_MAX_DISPARITY
    assert r["directions"][1] > 150                             # about one direction per camera pixel
    line = next(x for x in cap.out.splitlines() if x.startswith("resample"))
    assert "(every 1 camera pixel(s), --uv-step auto: 0." in line, cap.out
    # a 3 x 3 rig 5 cm apart: views far apart for the room at 2 pixels, so 3 views per camera spacing
    (tmp_path / "far.toml").write_text(mock_grid_rig_text("far", 160, 120, pitch=0.05))
    code = main(["run", str(tmp_path / "far.toml"), "--out", str(tmp_path / "far"), "--board-frames", "12",
                 "--frames", "2", "--uv-step", "auto", "--calib-draws", "0"])
    cap = capsys.readouterr()
    assert code == 0, cap.err
    r = tomllib.loads((tmp_path / "far" / "report" / "summary.toml").read_text())["resample"]
    assert r["uv_step_px"] == 2.0 and r["uv_disparity"] > AUTO_XY_MAX_DISPARITY and r["views"] == [7, 7]
    line = next(x for x in cap.out.splitlines() if x.startswith("resample"))
    assert "; 3 views per camera spacing (over 0.6 samples per view step with 2))" in line, cap.out


def test_run_stereo_pair_gives_motion_and_depth_between_its_cameras(tmp_path, capsys):
    """Two cameras (a stereo pair, resampled onto views between them): the motion is solved, and
    the depth of the middle view (no captured data of its own) comes from matching the two
    cameras' samples (polycam.depth_refine). Without that refinement (`polycam depth --refine
    off`) the views between hold no captured data and the verb says so. `polycam motion` on the
    session resamples it on the run's grid (4 views per camera spacing, not 2)."""
    import csv
    import tomllib

    (tmp_path / "rig.toml").write_text(mock_grid_rig_text("pair", 160, 120, rows=1, cols=2, pitch=0.05))
    out = tmp_path / "run"
    code = main(["run", str(tmp_path / "rig.toml"), "--out", str(out), "--board-frames", "12", "--frames", "3"])
    cap = capsys.readouterr()
    assert code == 0, cap.err
    motion = [line for line in cap.out.splitlines() if line.startswith("motion")]
    assert len(motion) == 1 and "0 failed" in motion[0], cap.out
    d = tomllib.loads((out / "report" / "summary.toml").read_text())["depth"]
    assert d["refined_on_views"] == 2 and d["data_fraction"] == 0 and d["views"] == "1x1"
    assert d["points"] > 1000 and d["median_rel_error"] < E2E_RUN_PAIR_DEPTH_REL
    depth = [line for line in cap.out.splitlines() if line.startswith("depth")]
    assert len(depth) == 1 and "refined on 2 camera views" in depth[0], cap.out
    # the motion verb on the session takes the run's grid rule: 4 views per camera spacing here (with 2
    # the pair has 3 views along x, too few for the solver)
    # (--sampling-check: re-solved on 5 views per spacing, 6 views; with --xy-oversample 2 the second
    # sampling's 3 per spacing give the pair 4 views, too few: skipped, and said so)
    code = main(["motion", str(out / "session"), "--calib", str(out / "calib"), "--uv-step", "2",
                 "--out", str(tmp_path / "m.tum"), "--sampling-check", "--report", str(tmp_path / "mrep")])
    cap = capsys.readouterr()
    assert code == 0, cap.err
    wrote = next(line for line in cap.out.splitlines() if line.startswith("wrote"))
    assert "2 frame pairs" in wrote and "failed" not in wrote, cap.out
    assert "second view sampling (5 views per camera spacing, 1x6 views" in cap.out, cap.out
    with open(tmp_path / "mrep" / "pairs.csv", newline="") as f:
        assert all(float(r["std_sampling_t"]) > 0 for r in csv.DictReader(f))
    code = main(["motion", str(out / "session"), "--calib", str(out / "calib"), "--uv-step", "2",
                 "--xy-oversample", "2", "--out", str(tmp_path / "m2.tum"), "--sampling-check"])
    cap = capsys.readouterr()
    assert code == 0, cap.err
    assert ("second view sampling skipped: 3 views per camera spacing give 4 views along the cameras, fewer than "
            "the solver's 5") in cap.out, cap.out
    from polycam.depth_cli import open_source

    assert open_source(out / "session", calib=str(out / "calib"), uv_step=2).grid.x.count == 5
    assert open_source(out / "session", calib=str(out / "calib"), uv_step=2, xy_oversample=2).grid.x.count == 3
    code = main(["depth", str(out / "lightfield.zarr"), "--traj", str(out / "trajectory.tum"),
                 "--out", str(tmp_path / "depth")])
    cap = capsys.readouterr()
    assert code == 0 and "0 points" not in cap.out, cap.out
    doc = tomllib.loads((tmp_path / "depth" / "depth.toml").read_text())["depth"]
    assert doc["refined_on_views"] == 2
    # the cameras' noise the store records (1 grey level and the rounding), beside the solver's estimate
    assert abs(255 * doc["camera_noise_sigma"] / math.hypot(1.02, 12 ** -0.5) - 1) < IMAGE_NOISE_LOW_RTOL
    code = main(["depth", str(out / "lightfield.zarr"), "--traj", str(out / "trajectory.tum"),
                 "--out", str(tmp_path / "depth_off"), "--refine", "off"])
    cap = capsys.readouterr()
    assert code == 0 and "0 points" in cap.out and "no captured data" in cap.out and "--refine on" in cap.out, cap.out


def test_run_free_running_cameras_are_grouped_and_corrected(tmp_path, capsys, monkeypatch):
    """Mock cameras at their own phases within ±12 ms (beyond the capture's default tolerance): the run
    records them grouped by their phases (--free-running: every multi-frame complete), sees that they are
    not synchronised, resamples each frame again with the cameras where they captured and solves again
    (measured: median error translation / rotation 5.1 / 9.2 % against 5.5 / 13.0 % uncorrected, the
    synchronised run 5.1 / 10.5 %: the calibration's error dominates these small rigs)."""
    import tomllib

    import polycam.session as session_module
    from polycam.evaluate import pair_errors
    from polycam.session import open_session

    (tmp_path / "rig.toml").write_text(RUN_RIG_TEXT + "sync_spread_ms = 12.0\nstep_t = 0.01\n")
    err = {}
    for mode in ("auto", "off"):
        if mode == "off":
            monkeypatch.setattr(session_module, "sync_warning", lambda s: "")
        out = tmp_path / mode
        code = main(["run", str(tmp_path / "rig.toml"), "--out", str(out), "--board-frames", "12", "--frames", "4",
                     "--sync-draws", "1"])
        cap = capsys.readouterr()
        assert code == 0, cap.err
        assert ("the cameras are not synchronised" in cap.out) == (mode == "auto")
        summary = tomllib.loads((out / "report" / "summary.toml").read_text())
        assert summary["motion"]["cameras_moved_to_capture"] == (mode == "auto")
        # --sync-draws: the capture times' and the first solve's share in each pair's covariance
        assert ("capture times: 1 draws from their uncertainty" in cap.out) == (mode == "auto")
        assert summary["motion"]["capture_time_draws"] == (1 if mode == "auto" else 0)
        assert (summary["motion"].get("median_std_sync_t_m", 0.0) > 0) == (mode == "auto")
        assert "which --sync-draws N measures" not in cap.out
        s = open_session(out / "session")
        assert (s.cam_timestamps >= 0).all() and np.ptp(s.capture_times_ns()[0]) > 16e6   # beyond half a period
        e = pair_errors(read_tum(out / "trajectory.tum"), read_tum(out / "session" / "groundtruth.tum"))
        err[mode] = (float(np.median(e.t_rel)), float(np.median(e.w_rel)))
    assert err["auto"][0] < E2E_RUN_MOTION_REL and err["auto"][1] < E2E_RUN_MOTION_REL
    assert sum(err["auto"]) < 0.9 * sum(err["off"]), err       # the calibration's error dominates t here
