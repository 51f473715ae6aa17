"""CLI smoke tests: the real command in a subprocess (evo style)."""

from __future__ import annotations

import math
import os
import re
import subprocess
import sys
import tomllib
from pathlib import Path

import numpy as np
import pytest

from tolerances import E2E_DEMO_MOTION_REL, IMAGE_NOISE_RTOL

REPO = Path(__file__).resolve().parents[1]


def polycam(*args: str, cwd: Path | None = None, timeout: float = 300) -> subprocess.CompletedProcess:
    env = dict(os.environ, PYTHONWARNINGS="error::DeprecationWarning")
    return subprocess.run([sys.executable, "-m", "polycam.cli", *args], capture_output=True, text=True,
                          cwd=cwd or REPO, env=env, timeout=timeout)


def assert_one_line_error(res: subprocess.CompletedProcess, *fragments: str) -> None:
    assert res.returncode == 1, res.stderr
    lines = [l for l in res.stderr.splitlines() if l.strip()]
    assert len(lines) == 1, res.stderr
    assert lines[0].startswith("polycam: error: ")
    assert "Traceback" not in res.stderr
    for frag in fragments:
        assert frag in lines[0]


def test_help_lists_verbs():
    res = polycam("--help")
    assert res.returncode == 0
    for verb in ("synth", "info", "demo"):
        assert verb in res.stdout


def test_help_does_not_import_heavy_modules():
    code = ("import sys; from polycam.cli import build_parser; build_parser(); "
            "print(sorted(m for m in ('mrcal','cv2','zarr','numba','scipy') if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=REPO)
    assert out.stdout.strip() == "[]"


def test_bad_usage_exits_2():
    res = polycam("synth", "lightfield", "--faces", "sideways", "--out", "x.zarr")
    assert res.returncode == 2
    assert "--faces" in res.stderr


def test_synth_specular(tmp_path):
    # --specular: a view-dependent highlight in the rendered frames (tests/test_synth.py checks the
    # term itself); negative is bad usage, and so is a board session with it
    from polycam.lfstore import open_lightfield

    grid = tmp_path / "grid.toml"
    grid.write_text('[grid]\nf = 60\nz_pi = 0\nfaces = ["+z"]\nx = [-0.02, 0.02, 3]\ny = [-0.02, 0.02, 3]\n'
                    'u = [-45, 45, 24]\nv = [-45, 45, 24]\n')
    frames = {}
    for k in ("0", "0.5"):
        out = tmp_path / f"lf{k}.zarr"
        res = polycam("synth", "lightfield", "--grid", str(grid), "--distance", "3", "--specular", k, "--out", str(out))
        assert res.returncode == 0, res.stderr
        frames[k] = open_lightfield(out).frame(0)
    diff = frames["0.5"] - frames["0"]
    assert diff.min() >= -1e-6 and diff.max() > 0.05          # highlights only add light
    res = polycam("synth", "lightfield", "--specular", "-1", "--out", str(tmp_path / "x.zarr"))
    assert res.returncode == 2 and "--specular" in res.stderr
    res = polycam("synth", "lightfield", "--specular", "inf", "--out", str(tmp_path / "x.zarr"))
    assert res.returncode == 2 and "finite" in res.stderr
    board = REPO / "rigs" / "boards" / "charuco_5x7.toml"
    res = polycam("synth", "session", "--rig", str(REPO / "rigs" / "mock5x5.toml"), "--board", str(board),
                  "--specular", "0.3", "--out", str(tmp_path / "b"))
    assert res.returncode == 2 and "--specular" in res.stderr and not (tmp_path / "b").exists()


def test_unsynchronised_sessions_are_named(tmp_path):
    # a session whose cameras captured each frame up to ~20 ms apart (--sync-spread-ms): polycam info gives
    # the capture times and warns, so do polycam motion and polycam resample; a synchronised one does not
    rig = str(REPO / "rigs" / "mock1x5.toml")
    for name, spread in (("u", "10"), ("s", "0")):
        res = polycam("synth", "session", "--rig", rig, "--frames", "2", "--sync-spread-ms", spread,
                      "--out", str(tmp_path / name))
        assert res.returncode == 0, res.stderr
    info = polycam("info", str(tmp_path / "u")).stdout
    assert re.search(r"capture times: the cameras' images of a frame span \d+\.\d\d ms .*; the timestamps jitter "
                     r"0\.00 ms \(RMS\) about them, which alone spreads them ~0\.00 ms", info)
    assert "warning: the cameras are not synchronised" in info
    for argv in (["motion", str(tmp_path / "u"), "--out", str(tmp_path / "t.tum")],
                 ["resample", str(tmp_path / "u"), "--out", str(tmp_path / "lf.zarr"), "--workers", "0"]):
        res = polycam(*argv)
        assert res.returncode == 0 and "warning: the cameras are not synchronised" in res.stdout, res.stderr
    info = polycam("info", str(tmp_path / "s")).stdout
    assert "span 0.00 ms" in info and "not synchronised" not in info
    assert "not synchronised" not in polycam("motion", str(tmp_path / "s"), "--out", str(tmp_path / "t0.tum")).stdout
    for opt in ("--sync-spread-ms", "--timestamp-jitter-ms"):
        res = polycam("synth", "session", "--rig", rig, "--board", str(REPO / "rigs" / "boards" / "charuco_5x7.toml"),
                      opt, "5", "--out", str(tmp_path / "b"))
        assert res.returncode == 2 and opt in res.stderr


def test_missing_rig_file_is_one_line(tmp_path):
    res = polycam("synth", "session", "--rig", str(tmp_path / "nope.toml"), "--out", str(tmp_path / "s"))
    assert_one_line_error(res, "nope.toml", "no such file")


def test_bad_rig_file_names_field(tmp_path):
    rig = tmp_path / "bad.toml"
    rig.write_text('[rig]\nname = "b"\n[grid]\nrows = "five"\ncols = 2\npitch = 0.1\n')
    res = polycam("synth", "session", "--rig", str(rig), "--out", str(tmp_path / "s"))
    assert_one_line_error(res, "bad.toml", "[grid].rows")


def test_bad_grid_file_names_field(tmp_path):
    grid = tmp_path / "grid.toml"
    grid.write_text('[grid]\nf = 60\nz_pi = 0\nfaces = ["+q"]\nx = [-1, 1, 3]\ny = [-1, 1, 3]\n'
                    'u = [-1, 1, 3]\nv = [-1, 1, 3]\n')
    res = polycam("synth", "lightfield", "--grid", str(grid), "--out", str(tmp_path / "lf.zarr"))
    assert_one_line_error(res, "grid.toml", "[grid].faces", "+q")


def test_readme_starts_with_the_two_commands():
    text = (REPO / "README.md").read_text()
    first_block = re.search(r"```[a-z]*\n(.*?)```", text, re.S).group(1)
    cmds = [l.split("#")[0].strip() for l in first_block.splitlines() if l.split("#")[0].strip()]
    assert cmds == ["make demo", "make test"]
    makefile = (REPO / "Makefile").read_text()
    assert "polycam demo" in makefile
    assert "make test" in (REPO / ".ci" / "run").read_text()


def test_demo_runs_end_to_end(tmp_path):
    """The README's main job (`make demo` runs `polycam demo`): the whole chain on the built-in
    mock rig (board, calibrate, capture, resample, motion, depth, report)."""
    res = polycam("demo", "--out", str(tmp_path / "demo"), timeout=900)
    assert res.returncode == 0, res.stderr
    assert "0 failed" in res.stdout
    for rel in ("session/session.toml", "calib/cam12.cameramodel", "lightfield.zarr/zarr.json",
                "trajectory.tum", "report/README.md", "report/trajectory.png", "report/mosaic.png",
                "report/epi.png", "report/depth.png", "report/points.ply", "report/calibration_residuals.png"):
        assert (tmp_path / "demo" / rel).exists(), rel
    from polycam.evaluate import pair_errors
    from polycam.trajectory import read_tum

    err = pair_errors(read_tum(tmp_path / "demo" / "trajectory.tum"),
                      read_tum(tmp_path / "demo" / "session" / "groundtruth.tum"))
    assert np.median(err.t_rel) < E2E_DEMO_MOTION_REL and np.median(err.w_rel) < E2E_DEMO_MOTION_REL


def _tiny_session(path: Path) -> Path:
    from polycam.rig import load_rig
    from polycam.session import SessionWriter

    rig_file = path.parent / "tiny.toml"
    rig_file.write_text('[rig]\nname = "tiny"\n[defaults]\nwidth = 8\nheight = 6\n'
                        '[grid]\nrows = 1\ncols = 2\npitch = 0.05\n')
    with SessionWriter(path, load_rig(rig_file)) as w:
        for i in range(3):
            w.add_frame(1_000 + i * 33_000_000, {"cam00": np.full((6, 8), i, np.uint8),
                                                 "cam01": np.full((6, 8), 2 * i, np.uint8)})
        w.close()
    return path


def test_info_on_a_session(tmp_path):
    s = _tiny_session(tmp_path / "s")
    res = polycam("info", str(s))
    assert res.returncode == 0, res.stderr
    assert "2 cameras" in res.stdout and "3 frames" in res.stdout


def test_info_on_a_session_gives_its_sensor_noise(tmp_path):
    # two 160 x 120 cameras: a ramp with 3 grey levels of noise; the tiny session's 8 x 6 images give
    # no estimate, and no line
    from polycam.rig import load_rig
    from polycam.session import SessionWriter

    rig_file = tmp_path / "noisy.toml"
    rig_file.write_text('[rig]\nname = "noisy"\n[defaults]\nwidth = 160\nheight = 120\n'
                        '[grid]\nrows = 1\ncols = 2\npitch = 0.05\n')
    rng = np.random.default_rng(4)
    ramp = 60.0 + np.add.outer(0.3 * np.arange(120), 0.5 * np.arange(160))
    with SessionWriter(tmp_path / "s", load_rig(rig_file)) as w:
        w.add_frame(1_000, {c: np.clip(np.rint(ramp + rng.normal(0.0, 3.0, ramp.shape)), 0, 255).astype(np.uint8)
                            for c in ("cam00", "cam01")})
        w.close()
    res = polycam("info", str(tmp_path / "s"))
    assert res.returncode == 0, res.stderr
    line = next(l for l in res.stdout.splitlines() if "sensor noise" in l)
    sigma = float(line.split("sensor noise ")[1].split()[0])
    assert abs(sigma / math.hypot(3.0, 12 ** -0.5) - 1) < IMAGE_NOISE_RTOL and "median over 2 cameras" in line
    assert "sensor noise" not in polycam("info", str(_tiny_session(tmp_path / "tiny"))).stdout
    # a truncated first image (its header intact): the summary without the figure
    png = sorted((tmp_path / "s" / "cam00").rglob("*.png"))[0]
    png.write_bytes(png.read_bytes()[:120])
    res = polycam("info", str(tmp_path / "s"))
    assert res.returncode == 0 and "sensor noise" not in res.stdout and "2 cameras" in res.stdout, res.stderr


def test_info_names_a_missing_camera_folder(tmp_path):
    import shutil

    s = _tiny_session(tmp_path / "s")
    shutil.rmtree(s / "cam01")
    assert_one_line_error(polycam("info", str(s)), "cam01")


def test_info_names_non_monotonic_timestamps(tmp_path):
    s = _tiny_session(tmp_path / "s")
    csv = s / "frames.csv"
    lines = csv.read_text().splitlines()
    row = lines[3].split(",")
    row[1] = "0"  # frame 2's timestamp before frame 1's
    lines[3] = ",".join(row)
    csv.write_text("\n".join(lines) + "\n")
    assert_one_line_error(polycam("info", str(s)), "frames.csv", "increasing")


def test_info_on_something_that_is_neither(tmp_path):
    (tmp_path / "junk").mkdir()
    assert_one_line_error(polycam("info", str(tmp_path / "junk")), "junk", "neither a session", "no zarr.json")


def test_info_on_a_calibration_folder(tmp_path):
    """A folder of .cameramodel files: its cameras, lens model and image size, the span of the
    centres, and the report's summary when ``polycam calibrate`` wrote one; a broken model is one
    line naming the file (not mrcal's list of every parser it tried)."""
    from polycam.cameras import nominal_cameramodel, write_cameramodel
    from polycam.rig import load_rig

    rig_file = tmp_path / "r.toml"
    rig_file.write_text('[rig]\nname = "r"\n[defaults]\nwidth = 64\nheight = 48\n'
                        '[grid]\nrows = 1\ncols = 3\npitch = 0.05\n')
    calib = tmp_path / "calib"
    calib.mkdir()
    for cam in load_rig(rig_file).cameras:
        write_cameramodel(nominal_cameramodel(cam), calib / f"{cam.id}.cameramodel")
    (calib / "report.toml").write_text('[calibration]\nmethod = "mrcal"\nframes = 25\nviews = 75\nrms_px = 0.12\n')
    res = polycam("info", str(calib))
    assert res.returncode == 0, res.stderr
    lines = res.stdout.splitlines()
    assert lines[0].startswith(f"calibration {calib}: 3 cameras, centres spanning 100.0 x 0.0 x 0.0 mm")
    assert "3 cameras (cam00, cam01, cam02): LENSMODEL_" in lines[1] and "64x48" in lines[1]
    assert lines[2] == "  report: method mrcal, frames 25, views 75, RMS 0.12 px"
    # a user's report.toml: only a [calibration] table's numbers and short one-line strings
    for text, expected in (('calibration = 5\n', "has no [calibration] table"),
                           ('[calibration]\nmethod = "a\\nb"\nframes = [1]\nrms_px = nan\n', "has none of"),
                           ('[calibration]\nmethod = "mrcal"\nrms_px = "0.1"\nviews = true\n', "method mrcal"),
                           ('[calibration\n', "not readable TOML")):
        (calib / "report.toml").write_text(text)
        res = polycam("info", str(calib))
        assert res.returncode == 0 and res.stderr == "", res.stderr
        line = res.stdout.splitlines()[2]
        assert line.startswith("  report: ") and expected in line and len(res.stdout.splitlines()) == 3, res.stdout
        assert line == "  report: method mrcal" or "report.toml" in line, line
    (calib / "cam01.cameramodel").write_text("not a model\n")
    res = polycam("info", str(calib))
    assert_one_line_error(res, "cam01.cameramodel", "not a valid mrcal cameramodel")
    assert "Errors for each attempt" not in res.stderr


def test_output_into_a_closed_pipe_is_quiet(tmp_path):
    """A reader that goes away (``polycam info X | head -1``) ends the command with status 141
    and nothing on stderr, not a traceback."""
    lf = _small_lightfield(tmp_path, 1)
    with subprocess.Popen([sys.executable, "-m", "polycam.cli", "info", str(lf)], stdout=subprocess.PIPE,
                          stderr=subprocess.PIPE, cwd=REPO) as p:
        p.stdout.close()                      # before the command writes
        err = p.stderr.read()
        assert p.wait(timeout=120) == 141 and err == b"", err


def _small_lightfield(tmp_path: Path, frames: int) -> Path:
    grid = tmp_path / "grid.toml"
    grid.write_text('[grid]\nf = 60\nz_pi = 0.02\nfaces = ["+z", "-x"]\nx = [-0.02, 0.02, 5]\n'
                    'y = [-0.02, 0.02, 5]\nu = [-45, 45, 32]\nv = [-45, 45, 32]\n')
    out = tmp_path / "lf.zarr"
    res = polycam("synth", "lightfield", "--grid", str(grid), "--frames", str(frames), "--distance", "4",
                  "--step-t", "0.01", "--out", str(out))
    assert res.returncode == 0, res.stderr
    return out


@pytest.mark.parametrize("selection", ["off", "on"])
def test_motion_on_a_lightfield_with_report(tmp_path, selection):
    lf = _small_lightfield(tmp_path, 3)
    res = polycam("motion", str(lf), "--out", str(tmp_path / "traj.tum"), "--report", str(tmp_path / "rep"),
                  "--scale-selection", selection)
    assert res.returncode == 0, res.stderr
    assert "against" in res.stdout  # compared with the store's ground truth
    assert re.search(r"errors / the reported std .*translation \d+\.\dx, rotation \d+\.\dx", res.stdout)
    from polycam.trajectory import read_tum

    assert len(read_tum(tmp_path / "traj.tum")) == 3
    for name in ("pairs.csv", "trajectory.png", "errors.png"):
        assert (tmp_path / "rep" / name).stat().st_size > 0
    header = (tmp_path / "rep" / "pairs.csv").read_text().splitlines()[0]
    assert header.startswith("pair,timestamp_ns,t_x") and ",sigma,noise_sigma," in header
    assert "sensor noise" in res.stdout and "--preset noisy" not in res.stdout     # noise-free float frames
    assert "one (u, v) level" not in res.stdout                                    # 32 directions: levels


def test_motion_points_to_the_noise_options_on_noisy_frames():
    """After a run with the default preset on frames with a grey level of noise or more, the
    command says so and names --preset noisy; not below, not with that preset, not on frames
    with confidences W (resampled: the noise options measured no better there, and the estimate
    is not the cameras' sensor noise: the line says so), not without estimates."""
    from types import SimpleNamespace

    from polycam.cli import _noise_line

    pairs = [SimpleNamespace(noise_sigma=s / 255.0) for s in (1.4, 1.1, float("nan"), 0.9)]
    line = _noise_line(pairs, "default")
    assert "1.10 grey levels" in line and "--preset noisy" in line
    assert "--preset noisy" not in _noise_line(pairs, "noisy")
    resampled = _noise_line(pairs, "default", confidences=True)
    assert "--preset noisy" not in resampled and not resampled.startswith("  sensor noise")
    assert "noise estimate 1.10 grey levels" in resampled and "parallax" in resampled
    assert "--preset noisy" not in _noise_line([SimpleNamespace(noise_sigma=0.5 / 255.0)], "default")
    assert _noise_line([SimpleNamespace(noise_sigma=float("nan"))], "default") == ""
    # a session: the cameras' own noise and the resampled samples' instead of the solver's estimate
    cams = _noise_line(pairs, "default", confidences=True, cameras=(2.0 / 255.0, 27, 0.4 / 255.0))
    assert "sensor noise 2.00 grey levels in the cameras' images" in cams and "27 images" in cams
    assert "0.40 per resampled sample" in cams and "noise estimate" not in cams
    assert "per resampled" not in _noise_line(pairs, "default", True, (2.0 / 255.0, 1, float("nan")))
    assert "noise estimate" in _noise_line(pairs, "default", True, (float("nan"), 0, float("nan")))


def test_level_line_names_the_coarse_levels():
    from types import SimpleNamespace

    from polycam.cli import _level_line

    fine = SimpleNamespace(uv_level=0, view_disparity=0.4)
    assert _level_line([fine, fine]) == ""
    line = _level_line([fine, SimpleNamespace(uv_level=2, view_disparity=2.5),
                        SimpleNamespace(uv_level=3, view_disparity=3.5)])
    assert "3.00 samples per view step" in line and "2 of 3 pairs" in line and "level 2/3" in line
    assert "max_view_disparity=inf" in line


@pytest.fixture(scope="module")
def two_frame_lightfield(tmp_path_factory) -> Path:
    return _small_lightfield(tmp_path_factory.mktemp("lf2"), 2)


def test_motion_takes_solver_options_and_records_them(tmp_path):
    """``--preset noisy`` takes the noise options of docs/motion.md and ``--option KEY=VALUE``
    sets MotionOptions fields on top (typed), the command says which differ from the
    defaults, and the report's options.toml records every field."""
    lf = _small_lightfield(tmp_path, 2)
    res = polycam("motion", str(lf), "--out", str(tmp_path / "traj.tum"), "--report", str(tmp_path / "rep"),
                  "--preset", "noisy", "--option", "levels=2", "--option", "uv_taps=6")
    assert res.returncode == 0, res.stderr
    assert ("solver options: levels=2, smooth_c=0.0, eiv=True, model_weight=True, model_weight_gain=8.0, "
            "depth_pool_views=True, whiten=on\n") in res.stdout
    doc = tomllib.loads((tmp_path / "rep" / "options.toml").read_text())["motion"]
    assert doc["smooth_c"] == 0.0 and doc["eiv"] is True and doc["whiten"] == "on" and doc["levels"] == 2
    assert doc["model_weight"] is True and doc["model_weight_gain"] == 8.0 and doc["depth_pool_views"] is True
    assert doc["uv_taps"] == 6 and doc["scale_selection"] is False       # the option over the preset; the defaults
    assert doc["preset"] == "noisy"


@pytest.mark.parametrize("option, problem", [("nope=1", "not a solver option"), ("eiv=maybe", "true or false"),
                                             ("levels=2.5", "integer"), ("robust=bogus", "robust"),
                                             ("filters=foo", "unknown filter"), ("smooth_c", "KEY=VALUE"),
                                             ("model_weight_gain=0", "model_weight_gain")])
def test_motion_rejects_a_bad_option_before_writing(tmp_path, two_frame_lightfield, option, problem):
    lf = two_frame_lightfield
    assert_one_line_error(polycam("motion", str(lf), "--out", str(tmp_path / "t.tum"), "--option", option), problem)
    assert not (tmp_path / "t.tum").exists()


@pytest.mark.parametrize("case", ["no_folder", "out_is_a_folder", "report_is_a_file"])
def test_motion_checks_where_it_writes_before_solving(tmp_path, two_frame_lightfield, case):
    """An --out it cannot write (its folder missing, or a folder) or a --report that is a file:
    one line naming the option and the path before any solve, and nothing written."""
    out, extra = tmp_path / "t.tum", []
    if case == "no_folder":
        out = tmp_path / "missing" / "t.tum"
        fragments = ("--out", str(out), f"its folder {tmp_path / 'missing'} does not exist")
    elif case == "out_is_a_folder":
        out = tmp_path / "adir"
        out.mkdir()
        fragments = ("--out", str(out), "is a folder")
    else:
        (tmp_path / "rep").write_text("keep me")
        extra = ["--report", str(tmp_path / "rep")]
        fragments = ("--report", str(tmp_path / "rep"), "exists and is not a folder")
    res = polycam("motion", str(two_frame_lightfield), "--out", str(out), *extra)
    assert_one_line_error(res, *fragments)
    assert "wrote" not in res.stdout and not (tmp_path / "t.tum").exists()
    if case == "report_is_a_file":
        assert (tmp_path / "rep").read_text() == "keep me"


def test_atomic_write_names_the_file_asked_for(tmp_path):
    """A missing folder is reported with the file asked for, not the temporary file beside it."""
    from polycam.tomlio import atomic_write_text

    with pytest.raises(FileNotFoundError) as e:
        atomic_write_text(tmp_path / "missing" / "a.toml", "x = 1\n")
    assert e.value.filename == str(tmp_path / "missing" / "a.toml")
    assert "does not exist" in e.value.strerror


def _linear_store(tmp_path) -> Path:
    """A 3-frame synthetic store whose grid is a linear array (one viewpoint along x, 9 along y)."""
    grid = tmp_path / "grid.toml"
    grid.write_text('[grid]\nf = 60\nz_pi = 0.04\nfaces = ["+z"]\nx = [0, 0, 1]\ny = [-0.04, 0.04, 9]\n'
                    'u = [-59.0625, 59.0625, 64]\nv = [-59.0625, 59.0625, 64]\n')
    lf = tmp_path / "lf.zarr"
    assert polycam("synth", "lightfield", "--grid", str(grid), "--frames", "3", "--out", str(lf)).returncode == 0
    return lf


def test_motion_on_a_linear_array(tmp_path):
    """A linear array's store is solved (every pair) and compared with its ground truth; with the
    symmetric warp, which cannot take it, every pair fails with the reason and the comparison says
    no pair was solved (no error medians of the failed pairs' start estimates, no NaN ratios)."""
    lf = _linear_store(tmp_path)
    res = polycam("motion", str(lf), "--out", str(tmp_path / "t.tum"))
    assert res.returncode == 0, res.stderr
    assert "failed" not in res.stdout and "median per-pair error translation" in res.stdout, res.stdout
    res = polycam("motion", str(lf), "--out", str(tmp_path / "t.tum"), "--option", "symmetric=true")
    assert res.returncode == 0, res.stderr
    assert "2 failed" in res.stdout and "(a linear array)" in res.stdout and "symmetric" in res.stdout
    assert "no pair solved" in res.stdout and "nan" not in res.stdout


def test_motion_needs_two_frames(tmp_path):
    lf = _small_lightfield(tmp_path, 1)
    assert_one_line_error(polycam("motion", str(lf), "--out", str(tmp_path / "t.tum")), str(lf), "1 frame(s)")
    assert not (tmp_path / "t.tum").exists()


def test_motion_names_the_store_of_a_frame_with_nans(tmp_path):
    from polycam.lfstore import open_lightfield, write_lightfield

    store = open_lightfield(_small_lightfield(tmp_path, 3))
    frames = [np.array(store.frame(i), np.float32) for i in range(len(store))]
    frames[2][1, 2, 2, 5, 7] = np.nan                 # no confidences: W is 1 everywhere
    bad = tmp_path / "nan.zarr"
    write_lightfield(bad, store.grid, frames, list(store.timestamps_ns))
    assert_one_line_error(polycam("motion", str(bad), "--out", str(tmp_path / "t.tum")),
                          str(bad), "frame 2 contains NaN")
    assert not (tmp_path / "t.tum").exists()


@pytest.mark.parametrize("verb", ["motion", "depth"])
@pytest.mark.parametrize("case", ["malformed", "other_times"])
def test_a_bad_groundtruth_fails_before_the_solve(tmp_path, verb, case):
    """A store's groundtruth.tum is read before the work: a malformed one is one line naming it and
    nothing is written; so is, for ``motion``, one whose poses are not at the frames' timestamps
    (``depth`` compares its one pair only where the truth has a pose per frame)."""
    import shutil

    (tmp_path / "src").mkdir()
    lf = tmp_path / "lf.zarr"
    shutil.copytree(_small_lightfield(tmp_path / "src", 3), lf)
    gt = lf / "groundtruth.tum"
    lines = gt.read_text().splitlines()
    k = next(i for i, line in enumerate(lines) if not line.startswith("#"))
    if case == "malformed":
        lines[k] += " 7"
        fragments = (f"line {k + 1}", "expected 8 values")
    else:
        del lines[-1]
        fragments = ("2 poses whose timestamps are not the 3 frames'",)
    gt.write_text("\n".join(lines) + "\n")
    out = tmp_path / ("t.tum" if verb == "motion" else "dep")
    res = polycam(verb, str(lf), "--out", str(out))
    if verb == "depth" and case == "other_times":
        assert res.returncode == 0 and "motion vs groundtruth" not in res.stdout, res.stderr
        return
    assert_one_line_error(res, str(gt), *fragments)
    assert "wrote" not in res.stdout and not out.exists()


def test_motion_on_one_uv_level_has_a_level_change(tmp_path):
    """24 directions allow no coarser (u, v) level: the pairs' covariance gets its model-error term from
    the estimate on frames blurred along u and v instead (pairs.csv level_change_t), so no warning; a
    pair without one (the blurred estimate failed) gets the warning line."""
    import csv

    from polycam.cli import _one_level_line
    from polycam.motion import PairResult

    grid = tmp_path / "grid.toml"
    grid.write_text('[grid]\nf = 60\nz_pi = 0.03\nfaces = ["+z"]\nx = [-0.03, 0.03, 5]\ny = [-0.03, 0.03, 5]\n'
                    'u = [-57.5, 57.5, 24]\nv = [-57.5, 57.5, 24]\n')
    lf = tmp_path / "lf.zarr"
    assert polycam("synth", "lightfield", "--grid", str(grid), "--frames", "2", "--out", str(lf)).returncode == 0
    res = polycam("motion", str(lf), "--out", str(tmp_path / "t.tum"), "--report", str(tmp_path / "rep"))
    assert res.returncode == 0 and "one (u, v) level" not in res.stdout, res.stdout
    with open(tmp_path / "rep" / "pairs.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    assert float(rows[0]["level_change_t"]) > 0
    res = polycam("motion", str(lf), "--out", str(tmp_path / "t.tum"), "--report", str(tmp_path / "rep1"),
                  "--option", "levels=1")
    assert res.returncode == 0 and "one (u, v) level" not in res.stdout, res.stdout     # as asked
    with open(tmp_path / "rep1" / "pairs.csv", newline="") as f:
        assert next(csv.DictReader(f))["level_change_t"] == ""
    C = np.eye(6) * 1e-6
    lacking = PairResult(index=0, T_prev_next=np.eye(4), covariance=C, covariance_noise=C, covariance_iid=C,
                         sigma=0.01, condition=10.0, inlier_fraction=1.0, num_rays=1000, iterations=3)
    assert "warning: 1 of 1 pairs solved on one (u, v) level" in _one_level_line([lacking], 3)
    assert _one_level_line([lacking], 1) == ""


def test_motion_on_a_broken_store_names_it(tmp_path):
    (tmp_path / "bad.zarr").mkdir()
    assert_one_line_error(polycam("motion", str(tmp_path / "bad.zarr"), "--out", str(tmp_path / "t.tum")),
                          "bad.zarr", "neither a session (no session.toml) nor a light-field store (no zarr.json)")
    (tmp_path / "bad.zarr" / "zarr.json").write_text("{not json")
    assert_one_line_error(polycam("motion", str(tmp_path / "bad.zarr"), "--out", str(tmp_path / "t.tum")),
                          str(tmp_path / "bad.zarr" / "zarr.json"), "not JSON")


def test_out_of_memory_is_one_line(monkeypatch, capsys):
    """A size no file check caught (a grid of absurd counts) ends in one line and status 1, not
    numpy's traceback."""
    from polycam import cli

    def boom(args):
        raise MemoryError("Unable to allocate 378. GiB for an array with shape (36, 1410065408) and data "
                          "type float64")

    monkeypatch.setattr(cli, "cmd_info", boom)
    assert cli.main(["info", "anything"]) == 1
    err = capsys.readouterr().err
    assert err == ("polycam: error: out of memory (Unable to allocate 378. GiB): check the sizes in the input "
                   "files (image sizes, grid counts)\n")


def test_cli_sets_a_passive_omp_wait_policy_unless_chosen(monkeypatch, capsys):
    """numba's OpenMP threads must not spin on a shared machine (polycam.cli docstring);
    a user's own OMP_WAIT_POLICY wins."""
    from polycam.cli import main

    monkeypatch.delenv("OMP_WAIT_POLICY", raising=False)
    with pytest.raises(SystemExit):
        main(["--help"])
    assert os.environ["OMP_WAIT_POLICY"] == "PASSIVE"
    monkeypatch.setenv("OMP_WAIT_POLICY", "ACTIVE")
    with pytest.raises(SystemExit):
        main(["--help"])
    assert os.environ["OMP_WAIT_POLICY"] == "ACTIVE"
