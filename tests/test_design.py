"""Rig design study (polycam.design, design_report, design_cli) and the example rigs.

Small grids throughout (160x120 cameras, directions every 5 deg) so the file stays fast.
"""

from __future__ import annotations

import argparse
import csv
import math
import subprocess
import sys

import numpy as np
import pytest

from polycam import design as dz
from polycam.design_report import SUMMARY_COLUMNS, summary_csv, write_design_report
from polycam.errors import InputError
from polycam.rig import CameraSpec, Rig, load_rig
from tolerances import (DESIGN_AMBIGUITY_MIN_CORR, DESIGN_LINEAR_SIGMA_REL, DESIGN_RENDER_ATOL,
                        DESIGN_SCATTER_REL)

EXAMPLE_RIGS = {"webcam3x3": 9, "webcam5x5": 25, "oak_array": 9, "cube6x3x3": 54, "single": 1, "mock1x5": 5, "oak_d_lite": 3,
                "mock1x2": 2}

CAM = CameraSpec(id="c", driver="mock", device=None, width=160, height=120, fps=30.0, pixel_format="GREY",
                 position=np.zeros(3), rotation=np.zeros(3), fov_deg=90.0)
"""A small camera for fast studies."""

OPTS = dz.DesignOptions(scene="room", distance=4.0, noise=0.02, pairs=1, draws=1, measure=False,
                        uv_step_deg=5.0, seed=0)


@pytest.fixture(scope="module")
def renderer():
    return dz.SourceRenderer(dz._scene(OPTS), OPTS.supersample)


@pytest.fixture(scope="module")
def hierarchy(renderer):
    """Predictions for the paper's four designs built from CAM (one renderer: shared renderings)."""
    rigs = dz.hierarchy_rigs(CAM, pitch=0.02)
    return {r.name: dz.evaluate_rig(r, OPTS, renderer=renderer) for r in rigs}


# ----------------------------------------------------------------------------- example rigs


@pytest.mark.parametrize("name,count", sorted(EXAMPLE_RIGS.items()))
def test_example_rigs_load_and_render_with_the_mock_driver(repo, name, count):
    from capture.mock import MockSource
    from capture.source import Frame

    rig = load_rig(repo / "rigs" / f"{name}.toml")
    assert rig.name == name and len(rig.cameras) == count
    # the mock driver renders any rig's cameras (the OAK array's are depthai cameras)
    src = MockSource(rig, list(rig.cameras), realtime=False, frames=1)
    got = {}
    with src:
        for _ in range(10 * count):
            for item in src.read(1.0):
                assert isinstance(item, Frame)
                got[item.cam_id] = item.image
            if len(got) == count:
                break
    assert sorted(got) == sorted(rig.ids)
    for cam in rig.cameras:
        img = got[cam.id]
        assert img.shape[:2] == (cam.height, cam.width)
        assert img.std() > 5          # textured scene, not a blank image


def test_example_rigs_geometry(repo):
    oak = load_rig(repo / "rigs" / "oak_array.toml")
    assert {c.driver for c in oak.cameras} == {"depthai"}
    assert all("/CAM_" in c.device for c in oak.cameras)
    cube = load_rig(repo / "rigs" / "cube6x3x3.toml")
    s = dz.design_grid(cube, uv_step_deg=5.0)
    assert [f.name for f in s.grid.faces] == ["+z", "-z", "+x", "-x", "+y", "-y"]
    assert s.grid.y.count == s.grid.x.count == 5 and not s.skipped
    # every camera looks out of the cube through its face: optical axis = face normal
    for cam in cube.cameras:
        axis = cam.R_rig_cam[:, 2]
        assert np.abs(axis).max() == pytest.approx(1.0)          # along a cube axis
        assert axis @ cam.position == pytest.approx(0.05)         # on that face, looking out
    for name in ("webcam3x3", "webcam5x5", "oak_array"):
        s = dz.design_grid(load_rig(repo / "rigs" / f"{name}.toml"), uv_step_deg=5.0)
        assert len(s.grid.faces) == 1 and not s.skipped and s.has_positional


# ----------------------------------------------------------------------------- rig -> grid


def test_design_grid_of_a_planar_array():
    rig = dz.planar_array_rig(3, 3, 0.02, CAM)
    s = dz.design_grid(rig, uv_step_deg=5.0, xy_oversample=2)
    g = s.grid
    assert [f.name for f in g.faces] == ["+z"] and g.faces[0].z_pi == pytest.approx(0.0)
    assert (g.y.count, g.x.count) == (5, 5) and g.x.step == pytest.approx(0.01)
    assert g.faces[0].f == pytest.approx(1.0 / math.tan(math.radians(5.0)))
    assert {(src.jy, src.ix) for src in s.sources} == {(j, i) for j in (0, 2, 4) for i in (0, 2, 4)}
    P = s.P[0]
    assert np.allclose(P.sum(axis=1), 1.0)                       # every viewpoint interpolated
    assert np.allclose(P[2 * 5 + 2], np.eye(9)[4])              # the centre camera sits on (2, 2)
    assert np.allclose(P[1 * 5 + 1][[0, 1, 3, 4]], 0.25)         # (1, 1): mean of four cameras
    # 90 deg cameras: u spans +-45 deg
    assert g.u.max == pytest.approx(math.ceil(g.faces[0].f), abs=1)
    assert s.has_positional and s.W.max() == 1


def test_design_grid_single_camera_and_spherical_pinhole():
    s = dz.design_grid(dz.single_camera_rig(CAM), uv_step_deg=5.0)
    assert s.grid.shape[:3] == (1, 1, 1) and not s.has_positional
    sph = dz.design_grid(dz.cube_array_rig(1, 0.02, CAM, half=0.0), uv_step_deg=5.0)
    assert sph.grid.shape[:3] == (6, 1, 1) and sph.grid.faces[0].z_pi == 0.0 and not sph.has_positional


def test_design_grid_leaves_gaps_without_data_and_skips_off_lattice_cameras():
    # two 1x2 arrays with a 6 cm gap: viewpoints in the gap are not interpolated across it
    cams = [dz._camera(CAM, f"c{i}", (x, 0.0, 0.0)) for i, x in enumerate((-0.05, -0.03, 0.03, 0.05))]
    rig = Rig(name="gap", cameras=tuple(cams))
    s = dz.design_grid(rig, uv_step_deg=5.0, xy_oversample=1)
    assert s.grid.x.count == 6 and not s.skipped
    has = s.W[0, 0].max(axis=(1, 2)) > 0                          # per viewpoint along x
    assert has.tolist() == [True, True, False, False, True, True]
    # a camera between lattice points is left out (with a warning in the result)
    xs = (-0.06, -0.04, -0.02, 0.0, 0.02, 0.04, 0.06, 0.031)
    cams2 = [dz._camera(CAM, f"c{i}", (x, 0.0, 0.0)) for i, x in enumerate(xs)]
    s2 = dz.design_grid(Rig(name="odd", cameras=tuple(cams2)), uv_step_deg=5.0, xy_oversample=1)
    assert s2.grid.x.count == 7 and s2.skipped == ("c7",)


def test_source_renderer_matches_the_light_field_renderer_and_shares(renderer):
    from polycam.synth import render_lightfield

    small = dz.design_grid(dz.planar_array_rig(3, 3, 0.02, CAM), uv_step_deg=5.0, xy_oversample=1)
    big = dz.design_grid(dz.planar_array_rig(5, 5, 0.02, CAM), uv_step_deg=5.0, xy_oversample=1)
    rend = dz.SourceRenderer(renderer.scene, 2)
    L = small.assemble(rend.render(small, np.eye(4)))
    ref = render_lightfield(renderer.scene, small.grid, np.eye(4), supersample=2)
    m = small.W > 0
    assert np.max(np.abs(L[m] - ref[m])) < DESIGN_RENDER_ATOL
    before = rend.rendered
    rend.render(big, np.eye(4))
    # the 3x3 array's cameras are the 5x5 array's inner ones: rendered once
    assert rend.rendered - before == 25 - 9 and rend.reused >= 9


# ----------------------------------------------------------------------------- the prediction


def test_noise_propagation_matches_monte_carlo_of_the_linear_estimator(renderer):
    """The sandwich N⁺ Σ σ² ‖(K P)ᵀ w A‖² N⁺ is the exact covariance of the weighted
    least-squares solution with noise filtered by K and interpolated by P."""
    from polycam.derivatives import plenoptic_derivatives, smooth_all
    from polycam.geometry import T_inverse
    from polycam.motion import MotionOptions, ray_motion_coefficients, warp_lightfield

    s = dz.design_grid(dz.planar_array_rig(3, 3, 0.02, CAM), uv_step_deg=5.0, xy_oversample=2)
    M = dz.pair_motions(1, 0.005, 0.2)[0]
    src0, src1 = renderer.render(s, np.eye(4)), renderer.render(s, M)
    g = s.grid
    opts = MotionOptions()
    pairs = dz.solver_filter_pairs(g, opts)
    L1w, ok = warp_lightfield(s.assemble(src1)[None], g, T_inverse(M))
    der = plenoptic_derivatives(s.assemble(src0), L1w[0], g, filters=opts.filters)
    w = (dz.min_over_support(ok.astype(np.float32), pairs) * der.valid[None]).astype(np.float32)
    A = [ray_motion_coefficients(der, g, 0)]
    sigma = np.linspace(0.01, 0.02, len(s.sources))              # per camera, to test the weighting
    N, meat = dz._sandwich(A, w, s, sigma, pairs)
    C = np.linalg.inv(N) @ meat @ np.linalg.inv(N)
    rng = np.random.default_rng(5)
    est = []
    for _ in range(400):
        n = [s.assemble(sigma[:, None, None] * s.masks * rng.normal(size=src0.shape)) for _ in range(2)]
        Lt = smooth_all(np.ascontiguousarray(n[1] - n[0]), pairs)
        est.append(np.linalg.solve(N, (w[0][..., None] * A[0]).reshape(-1, 6).T @ Lt[0].reshape(-1)))
    mc = np.std(np.array(est), axis=0)
    assert np.allclose(mc, np.sqrt(np.diag(C)), rtol=DESIGN_LINEAR_SIGMA_REL)


def _camera(fov_deg: float) -> CameraSpec:
    return CameraSpec(id="c", driver="mock", device=None, width=160, height=120, fps=30.0, pixel_format="GREY",
                      position=np.zeros(3), rotation=np.zeros(3), fov_deg=fov_deg)


SCATTER_DRAWS = 32
"""Noise draws per design in the scatter test: a std from n draws has a relative sampling
error of ~1/sqrt(2n) = 12.5% per component; the whitened statistic below pools all six
(~5%), so the 20% tolerance is a real test."""

SCATTER_CASES = {
    # one face: t and w coupled by the limited field of view (condition ~7 against ~3 for six
    # faces), viewpoints at the cameras
    "one face 5x5": (lambda: dz.planar_array_rig(5, 5, 0.01, _camera(90.0)), 5.0, 1),
    # six faces of 3x3 arrays, viewpoints between the cameras interpolated (the default xy_oversample 2)
    "six faces 3x3, interpolated viewpoints": (lambda: dz.cube_array_rig(3, 0.02, _camera(90.0)), 5.0, 2),
    # ill-conditioned: one face of a 3x3 array of 70 deg cameras 4 cm apart (the webcam3x3 layout),
    # t_x~w_y correlation -0.89, condition ~20, model error above the noise (misfit > 1)
    "one face 3x3, t~w ambiguity": (lambda: dz.planar_array_rig(3, 3, 0.04, _camera(70.0)), 2.5, 2),
    # a linear array: one row of five cameras, the vertical regressor from depth (ρ L_v; the
    # solver's ρ̂ from the horizontal parallax). Its directions at 2.5 deg: at 5 deg (19 x 25) the
    # extrapolation's and windows' (u, v) borders leave the solver too few rays (docs/motion.md)
    "one face 1x5 row (a linear array)": (lambda: dz.planar_array_rig(1, 5, 0.01, _camera(90.0)), 2.5, 1),
}
WHITENED_CASES = ("one face 5x5", "six faces 3x3, interpolated viewpoints", "one face 1x5 row (a linear array)")
"""Designs whose whole covariance (not only std_t, std_w) is checked: on the ill-conditioned
face the whitened statistic is ~1.2 (docs/design.md)."""


@pytest.mark.parametrize("case", sorted(SCATTER_CASES))
def test_predicted_sigma_matches_the_solver_scatter(renderer, case):
    """Issue 8: the predicted σ matches the scatter of the real solver over noise draws
    (within 20%), for designs of different conditioning, in the regime the prediction is
    for: the solver converges near the truth (its noise-free bias well below the step).

    Checked three ways: std_t and std_w (sqrt of the traces) against the scatter, and the
    whole 6x6 covariance through the whitened deviations z = C^(-1/2) (e - mean), whose
    mean |z|² is 6 when C is right."""
    make, uv_step, xyo = SCATTER_CASES[case]
    opts = dz.DesignOptions(scene="room", distance=4.0, noise=0.02, pairs=1, measure=False, uv_step_deg=uv_step,
                            xy_oversample=xyo, supersample=3, seed=0)
    rend = dz.SourceRenderer(renderer.scene, opts.supersample)
    res = dz.evaluate_rig(make(), opts, renderer=rend)
    p, s = res.prediction, res.sampling
    assert p.model == "plenoptic" and not p.unobservable
    M = dz.pair_motions(1, opts.step_t, opts.step_r_deg, opts.seed)
    src0, src1 = rend.render(s, np.eye(4)), rend.render(s, M[0])
    m = dz.measure_pairs(s, src0, [src1], M, dz._sigma_src(s, opts.noise), draws=SCATTER_DRAWS,
                         rng=np.random.default_rng(12))
    assert m.ok.all()
    assert np.linalg.norm(m.clean[0, :3]) < 0.5 * opts.step_t          # converges near the truth
    assert m.scatter_t / p.std_t == pytest.approx(1.0, rel=DESIGN_SCATTER_REL)
    assert m.scatter_w / p.std_w == pytest.approx(1.0, rel=DESIGN_SCATTER_REL)
    dev = m.errors[0] - m.errors[0].mean(axis=0)
    z = np.linalg.solve(np.linalg.cholesky(p.covariance), dev.T)
    whitened = math.sqrt(np.mean(np.sum(z * z, axis=0)) * SCATTER_DRAWS / (SCATTER_DRAWS - 1) / 6)
    if case in WHITENED_CASES:
        assert whitened == pytest.approx(1.0, rel=DESIGN_SCATTER_REL)


def test_single_camera_cannot_see_the_scale_of_translation(hierarchy):
    p = hierarchy["H1-pinhole"].prediction
    assert p.model == "depth"
    assert p.unobservable == ("t_scale",)
    assert p.solver_unobservable == ("t_x", "t_y", "t_z")
    assert math.isinf(p.std_t) and math.isfinite(p.std_w) and math.isfinite(p.std_t_dir)
    assert "t_scale" in summary_csv([hierarchy["H1-pinhole"]]).splitlines()[1]


def test_hierarchy_of_cameras(hierarchy):
    """Issue 8: six faces beat one face of the same cameras; small fields of view show the
    rotation–translation ambiguity, spherical ones do not."""
    one = hierarchy["H3-polydioptric"].prediction
    six = hierarchy["H4-spherical-polydioptric"].prediction
    assert not one.unobservable and not six.unobservable
    assert six.std_t < one.std_t and six.std_w < one.std_w
    assert six.condition < one.condition
    assert one.ambiguity and not six.ambiguity
    i, j = (dz.PARAM_NAMES.index(n) for n in one.ambiguity.split()[0].split("~"))
    d = np.sqrt(np.diag(one.covariance))
    assert abs(one.covariance[i, j] / (d[i] * d[j])) >= DESIGN_AMBIGUITY_MIN_CORR
    assert {i, j} in ({0, 4}, {1, 3})                            # t_x~w_y or t_y~w_x
    sph = hierarchy["H2-spherical-pinhole"].prediction
    assert sph.unobservable == ("t_scale",) and not sph.ambiguity
    assert [hierarchy[n].features["class"] for n in hierarchy] == [
        "pinhole, small FOV", "pinhole, spherical", "polydioptric, small FOV", "polydioptric, spherical"]


def test_analyse_covariance_names_directions():
    C = np.diag([1e-6, 1e-6, 1e-6, 1e-8, 1e-8, 1e-8])
    dirs, cond, amb = dz.analyse_covariance(C)
    assert amb == "" and cond == pytest.approx(1.0) and all(d.inflation == pytest.approx(1.0) for d in dirs)
    C[0, 4] = C[4, 0] = -0.95 * 1e-7                             # t_x and w_y strongly coupled
    dirs, cond, amb = dz.analyse_covariance(C)
    assert amb.startswith("t_x~w_y") and "-0.95" in amb
    assert dirs[0].kind == "mixed" and dirs[0].inflation == pytest.approx(1.95)
    assert set(dirs[0].name.split()[1::2]) == {"t_x", "w_y"}


# ----------------------------------------------------------------------------- report and CLI


def _parser():
    from polycam import design_cli

    p = argparse.ArgumentParser(prog="polycam")
    sub = p.add_subparsers(dest="verb", required=True)
    design_cli.add_parsers(sub)
    return p


def _small_rig(tmp_path, name, body):
    path = tmp_path / f"{name}.toml"
    path.write_text(f'[rig]\nname = "{name}"\n[defaults]\ndriver = "mock"\nwidth = 160\nheight = 120\n'
                    f'fov_deg = 90\n{body}')
    return path


def test_design_cli_writes_summary_and_plots(tmp_path, capsys):
    a = _small_rig(tmp_path, "one", '[[camera]]\nid = "c"\nposition = [0, 0, 0]\n')
    b = _small_rig(tmp_path, "arr", "[grid]\nrows = 3\ncols = 3\npitch = 0.02\n")
    out = tmp_path / "study"
    args = _parser().parse_args(["design", str(a), str(b), "--out", str(out), "--uv-step", "5", "--pairs", "1",
                                 "--draws", "1", "--sweep", "4,8", "--noise", "0.02"])
    assert args.func(args) == 0
    assert "t_scale" in capsys.readouterr().out
    with open(out / "summary.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert list(rows[0]) == list(SUMMARY_COLUMNS) and list(SUMMARY_COLUMNS[:8]) == [
        "rig", "cameras", "faces", "std_t", "std_w", "err_t", "err_w", "unobservable"]
    one, arr = rows
    assert (one["rig"], one["cameras"], one["faces"], one["std_t"], one["err_t"], one["unobservable"]) == \
        ("one", "1", "1", "inf", "", "t_scale")
    assert float(one["std_w"]) > 0 and float(one["err_w"]) > 0
    assert arr["unobservable"] == "" and 0 < float(arr["std_t"]) < 0.005 and 0 < float(arr["err_t"]) < 0.005
    for name in ("directions.csv", "errors.csv", "sweep.csv", "report.md", "error_vs_cameras.png",
                 "error_vs_baseline.png", "error_vs_fov.png", "error_vs_distance.png", "hierarchy.png"):
        assert (out / name).stat().st_size > 0, name
    assert len((out / "sweep.csv").read_text().splitlines()) == 1 + 2 * 2
    # a second run refuses to overwrite without --overwrite
    args = _parser().parse_args(["design", str(a), "--out", str(out)])
    with pytest.raises(InputError, match="--overwrite"):
        args.func(args)


def test_design_cli_user_errors(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text('[rig]\nname = "x"\n[grid]\nrows = 0\ncols = 1\npitch = 0.01\n')
    args = _parser().parse_args(["design", str(bad), "--out", str(tmp_path / "o")])
    from polycam.errors import FormatError

    with pytest.raises(FormatError, match="rows"):
        args.func(args)
    with pytest.raises(SystemExit):
        _parser().parse_args(["design", str(bad), "--out", "o", "--noise", "0"])
    with pytest.raises(SystemExit):
        _parser().parse_args(["design", str(bad), "--out", "o", "--sweep", "4,-1"])


def test_report_without_measurement(tmp_path, hierarchy):
    results = list(hierarchy.values())
    files = write_design_report(results, tmp_path / "r", OPTS, plots=False)
    assert {f.name for f in files} == {"summary.csv", "directions.csv", "report.md"}
    text = (tmp_path / "r" / "report.md").read_text()
    assert "scale of translation is unobservable" in text and "Rotation–translation ambiguity" in text
    with open(tmp_path / "r" / "summary.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert all(r["err_t"] == "" and r["err_w"] == "" for r in rows)


def test_design_verb_in_a_subprocess(tmp_path, repo):
    """The real command (registered in polycam.cli.STAGE_CLIS): success and a one-line user error."""
    rig = _small_rig(tmp_path, "arr", "[grid]\nrows = 3\ncols = 3\npitch = 0.02\n")
    out = tmp_path / "study"
    cmd = [sys.executable, "-m", "polycam.cli", "design", str(rig), "--out", str(out), "--no-measure",
           "--sweep", "none", "--uv-step", "5", "--no-plots"]
    res = subprocess.run(cmd, capture_output=True, text=True, cwd=repo, timeout=300)
    assert res.returncode == 0, res.stderr
    assert (out / "summary.csv").read_text().startswith("rig,cameras,faces,std_t,std_w,err_t,err_w,unobservable")
    res = subprocess.run(cmd[:4] + [str(tmp_path / "missing.toml")] + cmd[5:], capture_output=True, text=True,
                         cwd=repo, timeout=300)
    assert res.returncode == 1 and len(res.stderr.strip().splitlines()) == 1 and "missing.toml" in res.stderr
