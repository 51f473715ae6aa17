"""``polycam run RIG.toml --out DIR``: the whole chain on a mock rig, with a report folder.

Capture → calibrate → resample → motion and depth, on synthetic data with exact
ground truth (docs/end_to_end.md):

1. **board**: a calibration-board session recorded through the capture stage
   (``capture.record``) from the mock driver (``capture.mock.MockSource`` showing the
   board) with cameras that deviate from the rig file (the "true" rig: small position,
   rotation and focal offsets); the mock adds the truth (``board_poses.tum``, ``calib/``);
2. **calibrate**: the calibration stage's mrcal board solve (``calib``) into
   ``DIR/calib`` (models, ``report.md``, residual plots);
3. **capture**: a motion session of the same true rig moving through the rig's
   ``[mock]`` scene, recorded the same way (``DIR/session``, with the mock's
   ``groundtruth.tum`` and true ``calib/``);
4. **resample**: the resampling stage onto the two-plane light field with the
   *calibrated* models (``DIR/lightfield.zarr``);
5. **motion**: plenoptic egomotion of every frame pair (``DIR/trajectory.tum``),
   compared with the ground truth; cameras that are not synchronised (``[mock]
   sync_spread_ms``) are resampled again with each camera where it captured its image
   and solved again, as ``polycam motion SESSION`` does;
6. **depth**: per-ray depth of the first frame pair (paper Eq. 6-7) and a point cloud;
7. **report**: ``DIR/report/`` — ``README.md`` (every number below), ``summary.toml``,
   ``trajectory.png``, ``errors.png``, ``pairs.csv``, ``calibration_residuals.png``,
   ``mosaic.png``, ``epi.png``, ``depth.png``, ``points.ply``.

Every stage reports one summary line through ``echo`` (counts, residuals,
confidence). A stage whose output is unusable stops the chain with
``run: STAGE: reason`` (a :class:`~polycam.errors.PolycamError`; the CLI exits 1).

Like :mod:`polycam.cli`, this module is CLI-layer orchestration: it is the one place
besides the CLI allowed to import the pipeline stages (``capture``, ``calib``, ``resample``),
and it does so lazily, inside functions. The core never imports it.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import os
import time
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

from .cliargs import check_output_folder
from .cliargs import nonneg_int as _nonneg_int
from .cliargs import positive_int as _positive_int

__all__ = ["RunOptions", "run_chain", "add_parsers", "cmd_run", "DEFAULT_RIG", "DEFAULT_BOARD",
           "DEFAULT_BOARD_FACES", "write_ply", "UNUSABLE", "MIN_VIEWS", "run_grid", "session_grid",
           "choose_uv_step", "AUTO_UV_STEPS_PX", "AUTO_UV_MAX_DISPARITY", "AUTO_XY_MAX_DISPARITY", "AUTO_XY_DENSER"]

_REPO = Path(__file__).resolve().parents[1]
DEFAULT_RIG = _REPO / "rigs" / "mock5x5.toml"
DEFAULT_BOARD = _REPO / "rigs" / "boards" / "charuco_5x7.toml"
DEFAULT_BOARD_FACES = _REPO / "rigs" / "boards" / "charuco_7x9.toml"
"""The default board of a rig whose cameras look through several faces (``polycam.synth.camera_groups``):
large enough to be seen across the edge between two faces (``polycam.synth.board_poses``' bridge frames)."""

UNUSABLE = {
    "calib_rms_px": 1.0,        # [px] board residual RMS above which the calibration is unusable
    "resample_mean_W": 0.2,     # mean confidence of the light field below which it is unusable
    "motion_failed_frac": 0.5,  # more than this fraction of failed frame pairs: motion unusable
    "depth_min_points": 100,    # fewer confident depth rays than this: depth unusable
}
"""Thresholds at which a stage's output stops the chain."""

MIN_VIEWS = 5
"""Fewest light-field viewpoints along x and y for the motion solver's (x, y) derivatives
and pyramid (a 3x3 rig needs in-between views; see :attr:`RunOptions.xy_oversample`)."""


@dataclass(frozen=True)
class RunOptions:
    """Sizes and settings of :func:`run_chain` (defaults: a few minutes on 2 cores)."""

    board_frames: int | None = None
    """Board poses in the calibration session (each aims at one camera in turn; with cameras that
    look through several faces every third is held across an edge between two faces). None:
    :func:`polycam.synth.default_board_frames` (25; 144 for the nested cube's six faces)."""
    frames: int = 5
    """Frames of the motion session (frames - 1 pairs)."""
    seed: int | None = None
    """Seed of the true rig, board poses, trajectory and noise (default: the rig's [mock] seed)."""
    perturb_position_m: float = 0.001
    """Std of the true cameras' position offsets from the rig file [m]."""
    perturb_rotation_deg: float = 0.3
    """Std of the true cameras' rotation offsets [deg]."""
    perturb_focal_frac: float = 0.005
    """Std of the true cameras' relative focal-length offsets."""
    lensmodel: str = "opencv4"
    """mrcal lens model solved for."""
    uv_step_px: float | None = 2.0
    """(u, v) grid step in camera pixels: 2 gives 4x fewer rays than the cameras' resolution
    (motion 4x faster, the same accuracy on the mock rig: 10.8% / 4.9% vs 9.6% / 6.3% median
    per-pair error with 1); None: chosen from the session (:func:`choose_uv_step`, ``--uv-step
    auto``: 1 where the views are close for the scene, e.g. a row of cameras)."""
    xy_oversample: int | None = None
    """Viewpoints of the light-field grid per camera spacing (``resample.auto_grid``).
    None: 2 (the resampler fills the view between two cameras from the plane-sweep depth,
    ``resample.viewfill``), or 4 when 2 gives fewer than ``MIN_VIEWS`` views along x or y.
    On three 5x5 sessions (seeds 1-3, docs/end_to_end.md) 2 gave a median per-pair error of
    2.9% / 0.9% against 7.1% / 1.7% with 1 (one view per camera: the (x, y) derivatives
    across views 2 cm apart are aliased in a room), at ~3x the solve time. A linear array's
    single-view axis counts too, so a row of cameras always gets 4 (session 40, one session each:
    rigs/mock1x5.toml 1.5% / 0.8% with 4 against 2.8% / 0.9% with 2, rigs/oak_d_lite.toml 3.0% /
    0.8% against 3.7% / 1.5%)."""
    scale_selection: bool = True
    """Pre-smooth the light field in (u, v) at the scale of paper Sect. 4.1 before the motion
    solve (``estimate_trajectory(scale_selection=True)``, :class:`polycam.scales.ScaleTracker`).
    With one view per camera (2 cm apart in a room) the (x, y) derivatives across views are
    aliased; docs/end_to_end.md has the measured effect."""
    calib_draws: int = 4
    """Sets of camera models drawn from the calibration's uncertainty (each solved at +δ and −δ) whose
    spread of each pair's estimate is added to its covariance (:mod:`polycam.calib_draws_cli`;
    0: the calibrated models are taken as exact). About one resampling and solve of the session
    per re-solve (the demo: ~7 s each)."""
    sync_draws: int = 0
    """For cameras that are not synchronised (the second pass of docs/motion.md, "Unsynchronised
    cameras"): sets of capture times and first-pass motions drawn from their uncertainty (each solved
    at +δ and −δ) whose spread of each pair's estimate is added to its covariance
    (:mod:`polycam.sync_draws_cli`, as ``polycam motion --sync-draws``; 0: not measured)."""
    sampling_check: bool = False
    """Re-solve the motion on a second view sampling (one more view per camera spacing: an array's
    2 → 3, 2.3x the nominal solve's rays; a row's 4 → 5) and add each pair's change to its covariance
    (:mod:`polycam.sampling_check_cli`, as ``polycam motion --sampling-check``)."""
    calib_plots: bool = False
    """Also write the calibration stage's own plots (per-camera residual maps; slow for many cameras)."""
    depth_views: int = 3
    """The point cloud takes the central depth_views x depth_views viewpoints."""
    supersample: int = 2
    """Rays per pixel side of the mock driver's renderer (2: anti-aliased images)."""


def _fail(stage: str, reason: str):
    from .errors import PolycamError

    return PolycamError(f"run: {stage}: {reason}")


@contextmanager
def _stage(name: str):
    """Re-raise a stage's user-level error (PolycamError) as ``run: STAGE: reason``."""
    from .errors import PolycamError

    try:
        yield
    except PolycamError as e:
        if str(e).startswith("run: "):
            raise
        raise _fail(name, str(e)) from None


def run_chain(rig_path: str | os.PathLike, out: str | os.PathLike, *, board_path: str | os.PathLike | None = None,
              options: RunOptions | None = None, progress_factory: Callable | None = None,
              echo: Callable[[str], None] = lambda s: None) -> dict:
    """Run the chain (module docstring) for rig file ``rig_path`` into folder ``out``.

    ``board_path``: the calibration board (None: :data:`DEFAULT_BOARD`, or :data:`DEFAULT_BOARD_FACES`
    when the rig's cameras look through several faces).

    Returns the summary dict (also written to ``out/report/summary.toml``).
    ``progress_factory(description, total)``: a context manager yielding
    ``advance(done, total)`` (the CLI's progress bars); ``echo``: one line per stage.
    """
    from contextlib import nullcontext

    import numpy as np

    from .board import load_board
    from .errors import InputError
    from .rig import MockSpec, load_rig

    opts = options or RunOptions()
    rig_path, out = Path(rig_path), Path(out)
    if not rig_path.is_file():
        raise InputError(f"{rig_path}: no such rig file")
    rig = load_rig(rig_path)
    if opts.frames < 2:
        raise InputError(f"run: need at least 2 motion frames, got {opts.frames}")
    seed = opts.seed if opts.seed is not None else (rig.mock.seed if rig.mock is not None else 0)
    # the mock driver simulates every camera of the rig, seeded by the run's seed
    rig = dataclasses.replace(rig, mock=dataclasses.replace(rig.mock or MockSpec(), seed=seed))
    from .synth import camera_groups, default_board_frames, true_cameramodels

    true_models = true_cameramodels(rig, seed=seed, perturb_position_m=opts.perturb_position_m,
                                    perturb_rotation_deg=opts.perturb_rotation_deg,
                                    perturb_focal_frac=opts.perturb_focal_frac)
    ids = [c.id for c in rig.cameras]
    if board_path is None:
        board_path = DEFAULT_BOARD if len(camera_groups(true_models, ids)) == 1 else DEFAULT_BOARD_FACES
    board = load_board(board_path)
    board_frames = opts.board_frames or default_board_frames(true_models, ids)
    W0, H0 = rig.cameras[0].width, rig.cameras[0].height
    check_output_folder(out, "--out")
    out.mkdir(parents=True, exist_ok=True)
    report = out / "report"
    report.mkdir(exist_ok=True)
    summary: dict = {"rig": rig.name, "cameras": len(rig.cameras), "seed": seed}

    def bar(desc: str, total):
        return progress_factory(desc, total) if progress_factory else nullcontext(None)

    # 1. board session
    t0 = time.perf_counter()
    with bar(f"1/6 board session ({len(rig.cameras)} cameras)", board_frames) as adv, _stage("board"):
        rec = _record_mock(rig, out / "board_session", board_frames, true_models, board, opts.supersample, adv)
    s = time.perf_counter() - t0
    summary["board"] = {**rec, "seconds": s}
    echo(f"board     {out / 'board_session'}: {len(rig.cameras)} cameras x {rec['frames']} frames of "
         f"{W0}x{H0} recorded from the mock driver ({rec['dropped']} dropped), board {board.squares[0]}x"
         f"{board.squares[1]} squares; truth: {', '.join(rec['truth'])} ({s:.1f} s)")

    # 2. calibration
    from calib.pipeline import calibrate_session

    t0 = time.perf_counter()
    with bar("2/6 calibrate (mrcal)", None) as adv, _stage("calibrate"):
        cal = calibrate_session(out / "board_session", out / "calib", board=board, method="mrcal",
                                lensmodel=opts.lensmodel, uncertainty=False, plots=opts.calib_plots,
                                overwrite=True, progress=adv)
    s = time.perf_counter() - t0
    cal_sum = _calibration_summary(cal, true_models)
    cal_sum["seconds"] = s
    summary["calibrate"] = cal_sum
    echo(f"calibrate {out / 'calib'}: {len(cal.models)} cameras, {cal_sum['views']} board views, RMS "
         f"{cal.rms_px:.3f} px, {cal_sum['outliers']} outliers; vs truth: centres {1e3 * cal_sum['position_rms_m']:.2f} mm "
         f"RMS, axes {cal_sum['rotation_rms_deg']:.3f} deg RMS ({s:.1f} s)")
    missing = [c.id for c in rig.cameras if c.id not in cal.models]
    if missing:
        raise _fail("calibrate", f"no model for camera(s) {', '.join(missing)}")
    if not cal.rms_px <= UNUSABLE["calib_rms_px"]:
        raise _fail("calibrate", f"residual RMS {cal.rms_px:.2f} px exceeds {UNUSABLE['calib_rms_px']} px "
                                 f"(see {out / 'calib' / 'report.md'})")
    _plot_calibration(report / "calibration_residuals.png", cal)

    # 3. motion session
    t0 = time.perf_counter()
    with bar("3/6 capture (motion session)", opts.frames) as adv, _stage("capture"):
        rec = _record_mock(rig, out / "session", opts.frames, true_models, None, opts.supersample, adv)
    s = time.perf_counter() - t0
    from .session import open_session

    sess = open_session(out / "session")
    truth = sess.groundtruth()
    steps = truth.relative()
    from .geometry import r_from_R

    step_t = float(np.median(np.linalg.norm(steps[:, :3, 3], axis=1)))
    step_r = float(np.median(np.linalg.norm(r_from_R(steps[:, :3, :3]), axis=1)))
    summary["capture"] = {**rec, "cameras": len(sess.cameras), "seconds": s,
                          "median_step_m": step_t, "median_step_deg": math.degrees(step_r)}
    echo(f"capture   {out / 'session'}: {len(sess.cameras)} cameras x {len(sess)} frames recorded from the mock "
         f"driver ({rec['dropped']} dropped), scene {rig.mock.scene}, motion {1e3 * step_t:.1f} mm and "
         f"{math.degrees(step_r):.2f} deg per frame; truth: {', '.join(rec['truth'])} ({s:.1f} s)")

    # 4. resampling with the calibrated models
    from resample.pipeline import resample_session

    t0 = time.perf_counter()
    with bar("4/6 resample", None) as adv, _stage("resample"):
        from .depth_cli import denser_views_reason, uv_step_reason

        uv_step, uv_disparity, xy_rule, denser = opts.uv_step_px, math.nan, opts.xy_oversample, False
        if uv_step is None:                          # --uv-step auto: from the session's own frames
            uv_step, uv_disparity, probe = choose_uv_step(sess, cal.models, opts.xy_oversample)
            if probe is not None:                    # (it may have chosen more views per camera spacing)
                xy_rule, denser = probe.xy_oversample, getattr(probe, "denser_views", False)
        grid, xy_oversample = session_grid(cal.models, uv_step, xy_rule)
        rs = resample_session(out / "session", out / "lightfield.zarr", calib_dir=out / "calib", grid=grid,
                              scheduler="sync", overwrite=True, progress=adv)
    s = time.perf_counter() - t0
    F, Ny, Nx, Nv, Nu = rs.grid.shape
    noise_grey = 255.0 * rs.camera_noise_sigma                 # NaN: no estimate
    summary["resample"] = {"faces": F, "views": [Ny, Nx], "directions": [Nv, Nu], "uv_step_px": uv_step,
                           **({"uv_disparity": uv_disparity} if math.isfinite(uv_disparity) else {}),
                           "mean_W": rs.mean_W, "missing_images": rs.missing_images, "seconds": s,
                           **({"camera_noise_grey": noise_grey} if math.isfinite(noise_grey) else {})}
    noise = (f", the cameras' sensor noise {noise_grey:.2f} grey levels" if math.isfinite(noise_grey)
             else ", the cameras' sensor noise not estimated (MJPG)" if rs.compressed_cameras else "")
    chosen = (f" (every {uv_step:g} camera pixel(s), {uv_step_reason(uv_disparity)}"
              + (f"; {xy_oversample} views per camera spacing ({denser_views_reason()})" if denser else "") + ")"
              if opts.uv_step_px is None else "")
    echo(f"resample  {out / 'lightfield.zarr'}: {F} face(s) x {Ny}x{Nx} views x {Nv}x{Nu} directions{chosen}, "
         f"mean confidence W {rs.mean_W:.2f}, {rs.missing_images} missing images{noise} ({s:.1f} s)")
    if not rs.mean_W >= UNUSABLE["resample_mean_W"]:
        raise _fail("resample", f"mean confidence W {rs.mean_W:.2f} below {UNUSABLE['resample_mean_W']}: "
                                "the cameras do not cover the grid")

    # 5. motion
    from .evaluate import ate_rmse, error_over_std, pair_errors, solved_pairs, std_norms
    from .lfstore import open_lightfield
    from .motion import MotionOptions, estimate_trajectory
    from .motion_report import write_motion_report
    from .trajectory import write_tum

    from .session import sync_warning

    motion_options = MotionOptions()     # (no discontinuity weight on these resampled frames:
                                         # MotionOptions.smooth_c_resampled)

    def solve(desc: str):
        """The trajectory, the pairs' results and their times [s] on the store as it is now."""
        lf = open_lightfield(out / "lightfield.zarr")
        stamps = [time.perf_counter()]                 # after each pair: per-pair times
        with bar(desc, len(lf) - 1) as adv, _stage("motion"):
            def tick(done: int, total: int) -> None:
                stamps.append(time.perf_counter())
                if adv is not None:
                    adv(done, total)

            traj, results = estimate_trajectory(lf, progress=tick, options=motion_options,
                                                scale_selection=opts.scale_selection)
        per_pair = np.diff(stamps) if len(stamps) > 1 else np.array([time.perf_counter() - stamps[0]])
        return lf, traj, results, per_pair

    lf, traj, results, per_pair = solve("5/6 plenoptic motion")
    unsync = sync_warning(sess)
    capture_motion = None
    sync_line, sync_s = "", None
    if unsync:
        # free-running cameras: as polycam motion SESSION, the frames resampled again with each camera
        # where it captured its image (its share of this motion) and solved again
        capture_motion = np.stack([r.T_prev_next for r in results])
        motion_covariance = np.stack([r.covariance for r in results])      # (the sync draws draw it)
        t0 = time.perf_counter()
        with bar("5/6 resample, cameras where they captured", None) as adv, _stage("resample"):
            resample_session(out / "session", out / "lightfield.zarr", calib_dir=out / "calib", grid=grid,
                             scheduler="sync", overwrite=True, capture_motion=capture_motion, progress=adv)
        lf, traj, results, per_pair = solve("5/6 plenoptic motion, second pass")
        unsync += (f": every frame resampled again with each camera where it captured its image, its share "
                   f"of the first solve's motion, and solved again ({time.perf_counter() - t0:.1f} s)")
        if opts.sync_draws:
            from .sync_draws_cli import add_capture_timing_share

            t0 = time.perf_counter()
            results, sync_line = add_capture_timing_share(
                sess, cal.models, lf.grid, capture_motion, results, draws=opts.sync_draws,
                motion_covariance=motion_covariance, bar=lambda total: bar("5/6 capture-time draws", total),
                seed=seed, motion_options=motion_options, scale_selection=opts.scale_selection)
            sync_s = time.perf_counter() - t0
        else:
            unsync += ("; the reported std leaves out the capture times' and the first solve's share, which "
                       "--sync-draws N measures")
    draws_line, drawn, draws_s = "", 0, None
    if opts.calib_draws:
        from .calib_draws_cli import add_calibration_share

        try:
            results, draws_line, draws_s = add_calibration_share(
                out / "session", cal.models, lf.grid, results, draws=opts.calib_draws,
                bar=lambda total: bar("5/6 calibration draws", total), seed=seed, motion_options=motion_options,
                scale_selection=opts.scale_selection, capture_motion=capture_motion)
        except InputError as e:                 # models without a covariance: the solver's covariance alone
            draws_line = f"calibration draws skipped: {e}"
        drawn = opts.calib_draws if draws_s is not None else 0
    sampling_line, sampling_s = "", None
    if opts.sampling_check:
        from .sampling_check_cli import add_view_sampling_share

        results, sampling_line, sampling_s = add_view_sampling_share(
            out / "session", cal.models, uv_step, xy_oversample, results,
            bar=lambda total: bar("5/6 second view sampling", total), motion_options=motion_options,
            scale_selection=opts.scale_selection, capture_motion=capture_motion)
    write_tum(out / "trajectory.tum", traj)
    failed = [r for r in results if not r]
    ok = [r for r in results if r]
    err, std = solved_pairs(pair_errors(traj, truth), np.stack([r.std for r in results]),
                            np.array([bool(r) for r in results]))
    # the median: the first pair of a first run also compiles numba's kernels (about a minute)
    m = {"pairs": len(results), "failed": len(failed), "seconds_per_pair": float(np.median(per_pair)),
         "seconds_first_pair": float(per_pair[0]),
         "median_t_rel": float(np.median(err.t_rel)), "median_w_rel": float(np.median(err.w_rel)),
         "median_t_err_m": float(np.median(err.t_err)), "median_w_err_deg": math.degrees(float(np.median(err.w_err))),
         "ate_m": ate_rmse(traj, truth),
         "median_inlier_fraction": float(np.median([r.inlier_fraction for r in ok])) if ok else 0.0,
         "median_std_t_m": float(np.median([np.linalg.norm(r.std[:3]) for r in ok])) if ok else float("nan"),
         "calibration_draws": drawn, "cameras_moved_to_capture": capture_motion is not None,
         "capture_time_draws": opts.sync_draws if sync_s is not None else 0,
         "sampling_check_xy_oversample": xy_oversample + 1 if sampling_s is not None else 0}
    from .calib_spread import calibration_std, capture_timing_std, view_sampling_std

    for seconds, part_std, name, key in ((draws_s if drawn else None, calibration_std, "calibration_draws", "calib"),
                                         (sync_s, capture_timing_std, "capture_time_draws", "sync"),
                                         (sampling_s, view_sampling_std, "sampling_check", "sampling")):
        if seconds is not None:                       # the medians over the pairs of the part's std
            pt, pr = std_norms(part_std(results))
            have = np.isfinite(pt)
            m[f"seconds_{name}"] = seconds
            m[f"median_std_{key}_t_m"] = float(np.median(pt[have])) if have.any() else float("nan")
            m[f"median_std_{key}_w_deg"] = math.degrees(float(np.median(pr[have]))) if have.any() else float("nan")
    m["error_over_std_t"], m["error_over_std_w"] = error_over_std(err, std)
    summary["motion"] = m
    first = (f" (median; the first took {m['seconds_first_pair']:.0f} s, compiling the kernels)"
             if m["seconds_first_pair"] > 3 * m["seconds_per_pair"] + 1 else "")
    solved = (f"inliers {100 * m['median_inlier_fraction']:.0f}%, predicted std {1e3 * m['median_std_t_m']:.2f} mm "
              f"(the errors {m['error_over_std_t']:.1f}x it; rotation {m['error_over_std_w']:.1f}x)"
              if ok else "no pair solved")
    echo(f"motion    {out / 'trajectory.tum'}: {m['pairs']} frame pairs, {m['failed']} failed, "
         f"{m['seconds_per_pair']:.1f} s per pair{first}; median error translation {100 * m['median_t_rel']:.1f}%, "
         f"rotation {100 * m['median_w_rel']:.1f}%; ATE {1e3 * m['ate_m']:.2f} mm; {solved}")
    if draws_line:
        echo(f"          {draws_line}")
    if unsync:
        echo(f"          {unsync}")
    if sync_line:
        echo(f"          {sync_line}")
    if sampling_line:
        echo(f"          {sampling_line}")
    if len(failed) > UNUSABLE["motion_failed_frac"] * len(results):
        raise _fail("motion", f"{len(failed)} of {len(results)} frame pairs failed "
                              f"(first: pair {failed[0].index}: {failed[0].reason})")
    written = write_motion_report(report, results, traj, truth, lf.timestamps_ns, options=motion_options,
                                  scale_selection=opts.scale_selection)

    # 6. depth and the pictures of the light field
    t0 = time.perf_counter()
    L0, L1, W0f = lf.frame(0), lf.frame(1), lf.weights(0)
    from .synth import scene_for_rig

    dsum = _depth(report, lf.grid, xy_oversample, L0, L1, W0f, results[0].T_prev_next if results[0] else None,
                  opts, positions=lf.camera_positions, truth=(scene_for_rig(rig), truth.T_world_rig[0]))
    s = time.perf_counter() - t0
    dsum["seconds"] = s
    summary["depth"] = dsum
    how = (f"refined on {dsum['refined_on_views']} camera views" if dsum["refined_on_views"] else
           "Eq. 7 alone: the calibrated cameras are off the focal plane, docs/depth.md")
    echo(f"depth     {report / 'depth.png'}: {100 * dsum['confident_fraction']:.0f}% of the central view's rays "
         f"confident ({how}), median depth {dsum['median_depth_m']:.2f} m, median error vs truth "
         f"{100 * dsum['median_rel_error']:.1f}% ({dsum['truth_rays']} rays); {dsum['points']} points in "
         f"{report / 'points.ply'} ({s:.1f} s)")
    if dsum["points"] < UNUSABLE["depth_min_points"]:
        from .depth import NO_CAPTURED_DATA

        why = "" if dsum["data_fraction"] > 0 or dsum["refined_on_views"] else f": the central views {NO_CAPTURED_DATA}"
        raise _fail("depth", f"only {dsum['points']} confident depth rays (need {UNUSABLE['depth_min_points']})"
                    + why)
    _plot_mosaic(report / "mosaic.png", lf.grid, L0)
    _plot_epi(report / "epi.png", lf.grid, L0)
    written += ["calibration_residuals.png", "mosaic.png", "epi.png", "depth.png", "points.ply"]

    _write_summary(report, summary, written)
    echo(f"report    {report}: README.md, summary.toml, {', '.join(written)}")
    return summary


# ----------------------------------------------------------------------------- stages


def _record_mock(rig, path: Path, frames: int, models: dict, board, supersample: int, advance) -> dict:
    """Record ``frames`` multi-frames of ``rig``'s mock driver into the session ``path``
    the way ``polycam capture --rig RIG --fast`` does (``capture.record`` on a simulated
    clock, nothing lost), rendering with ``models`` (and showing ``board`` if given), then
    add the mock's ground truth. Free-running mock cameras (``[mock] sync_spread_ms``, ``clock_ppm``) are grouped
    by their phases, as ``polycam capture --free-running`` does. Returns counts for the summary."""
    from capture.mock import MockSource
    from capture.recorder import record

    src = MockSource(rig, realtime=False, frames=frames, supersample=supersample, models=models, board=board)
    on_update = (lambda st: advance(st.written, frames)) if advance is not None else None
    free = board is None and rig.mock is not None and rig.mock.free_running
    res = record(src, rig, path, frames=frames, overwrite=True, on_update=on_update, update_interval=0.25,
                 free_running=free)
    st = res.stats
    if res.status != "complete" or st.written < frames:
        raise _fail("board" if board is not None else "capture",
                    f"recorded {st.written} of {frames} frames ({res.status}, stopped by {res.stopped_by})")
    truth = src.write_truth(path)
    dropped = sum(c.dropped + c.overflow + c.late for c in st.per_camera.values())
    return {"frames": int(st.written), "dropped": int(dropped), "truth": truth}


# ----------------------------------------------------------------------------- stage summaries


def _calibration_summary(cal, true_models: dict) -> dict:
    """Counts and residuals of the board solve, and the solved camera poses against the truth."""
    import numpy as np

    from .cameras import T_rig_cam_of
    from .geometry import r_from_R

    doc = cal.report.get("calibration", {}) if isinstance(cal.report, dict) else {}
    ids = [c for c in cal.models if c in true_models]
    Ts = np.stack([T_rig_cam_of(cal.models[c]) for c in ids])
    Tt = np.stack([T_rig_cam_of(true_models[c]) for c in ids])
    # both rig frames are tied to the rig file's nominal poses (the solve fits its frame to
    # them; the truth deviates from them by the perturbation), so compare directly
    dp = np.linalg.norm(Ts[:, :3, 3] - Tt[:, :3, 3], axis=1)
    dr = np.linalg.norm(r_from_R(np.swapaxes(Tt[:, :3, :3], 1, 2) @ Ts[:, :3, :3]), axis=1)
    return {"cameras": len(cal.models), "rms_px": float(cal.rms_px), "views": int(doc.get("views", 0)),
            "per_camera_rms_px": {c: float(s.rms_px) for c, s in cal.result.stats.items()},
            "outliers": int(doc.get("outliers", 0)),
            "position_rms_m": float(np.sqrt(np.mean(np.square(dp)))) if len(dp) else float("nan"),
            "rotation_rms_deg": math.degrees(float(np.sqrt(np.mean(np.square(dr))))) if len(dr) else float("nan")}


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _plot_calibration(path: Path, cal) -> None:
    """Per-camera residual RMS [px] of the board solve and the histogram of all residuals."""
    import numpy as np

    from calib.board_solve import observation_residuals

    plt = _pyplot()
    fig, axes = plt.subplots(1, 2, figsize=(11, 3.6))
    bc = cal.result                                           # calib.board_solve.BoardCalibration
    names = list(bc.stats)
    rms = [float(bc.stats[c].rms_px) for c in names]
    axes[0].bar(range(len(names)), rms, color="tab:blue")
    axes[0].set_xticks(range(len(names)), names, rotation=90, fontsize=6)
    axes[0].set_ylabel("residual RMS [px]")
    axes[0].set_title(f"board solve: RMS {cal.rms_px:.3f} px over {len(names)} cameras")
    try:
        res, weight = observation_residuals(bc.optimization_inputs)
        r = np.asarray(res, float)[np.asarray(weight) > 0].reshape(-1)
        axes[1].hist(r, bins=60, color="tab:orange")
        axes[1].set_xlabel("residual per coordinate [px]")
        axes[1].set_title("all inlier residuals")
    except Exception as e:  # noqa: BLE001 -- a plot must not stop the chain
        axes[1].text(0.5, 0.5, f"residuals unavailable: {e}", ha="center", transform=axes[1].transAxes)
    for ax in axes:
        ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _plot_mosaic(path: Path, grid, L0) -> None:
    """All perspective views of face 0 tiled as on the array (frame 0)."""
    import numpy as np

    from PIL import Image

    from .depth import grey_frame

    L = grey_frame(L0)[0]                                     # (Ny, Nx, Nv, Nu)
    Ny, Nx, Nv, Nu = L.shape
    step = max(1, int(math.ceil(max(Nv, Nu) * max(Ny, Nx) / 1600)))  # keep it under ~1600 px
    tiles = L[:, :, ::step, ::step]
    h, w = tiles.shape[2:]
    gap = 2
    img = np.ones((Ny * (h + gap) - gap, Nx * (w + gap) - gap), np.float32)
    for j in range(Ny):
        for i in range(Nx):
            img[j * (h + gap):j * (h + gap) + h, i * (w + gap):i * (w + gap) + w] = tiles[j, i]
    tmp = path.with_name(path.name + ".tmp.png")
    Image.fromarray(np.round(np.clip(img, 0, 1) * 255).astype(np.uint8)).save(tmp)
    os.replace(tmp, path)


def _plot_epi(path: Path, grid, L0) -> None:
    """The central view with the sampled row and column, the horizontal EPI L(x, u) at the
    central y and v, and the vertical EPI L(y, v) at the central x and u."""
    import numpy as np

    from .depth import grey_frame

    plt = _pyplot()
    L = grey_frame(L0)[0]
    Ny, Nx, Nv, Nu = L.shape
    jc, ic, vc, uc = Ny // 2, Nx // 2, Nv // 2, Nu // 2
    epi_h = L[jc, :, vc, :]                                    # (Nx, Nu)
    epi_v = L[:, ic, :, uc].T                                  # (Nv, Ny)
    fig = plt.figure(figsize=(11, 7))
    gs = fig.add_gridspec(2, 2, width_ratios=(4, 1), height_ratios=(3, 1))
    ax = fig.add_subplot(gs[0, 0])
    ax.imshow(L[jc, ic], cmap="gray", vmin=0, vmax=1)
    ax.axhline(vc, color="tab:red", lw=0.8)
    ax.axvline(uc, color="tab:blue", lw=0.8)
    ax.set_title(f"central view (x = {grid.x.values[ic]:.3f} m, y = {grid.y.values[jc]:.3f} m)")
    ax.axis("off")
    axh = fig.add_subplot(gs[1, 0])
    axh.imshow(epi_h, cmap="gray", vmin=0, vmax=1, aspect="auto", interpolation="nearest")
    axh.set_title("EPI L(x, u) along the red row: slope = depth", fontsize=9)
    axh.set_xlabel("u")
    axh.set_ylabel("x (view)")
    axv = fig.add_subplot(gs[0, 1])
    axv.imshow(epi_v, cmap="gray", vmin=0, vmax=1, aspect="auto", interpolation="nearest")
    axv.set_title("EPI L(y, v)\nalong the blue column", fontsize=9)
    axv.set_xlabel("y (view)")
    axv.set_ylabel("v")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def write_ply(path: str | os.PathLike, points, values=None) -> None:
    """ASCII PLY point cloud: points (N, 3) [m] and optional grey values (N,) in [0, 1]."""
    import io

    import numpy as np

    from .tomlio import atomic_write_text

    P = np.asarray(points, float).reshape(-1, 3)
    buf = io.StringIO()
    buf.write(f"ply\nformat ascii 1.0\ncomment polycam run: rig frame at frame 0 [m]\nelement vertex {len(P)}\n"
              "property float x\nproperty float y\nproperty float z\n")
    if values is not None:
        buf.write("property uchar red\nproperty uchar green\nproperty uchar blue\n")
    buf.write("end_header\n")
    if values is None:
        np.savetxt(buf, P, fmt="%.5f")
    else:
        g = np.clip(np.round(np.asarray(values, float).reshape(-1) * 255), 0, 255).astype(int)
        np.savetxt(buf, np.column_stack([P, g, g, g]), fmt=["%.5f"] * 3 + ["%d"] * 3)
    atomic_write_text(path, buf.getvalue())


def run_grid(models: dict, opts: RunOptions):
    """(grid, views per camera spacing) of ``polycam run``'s light field for cameras ``models``:
    :func:`session_grid` with ``opts.uv_step_px`` (a number: ``auto`` needs the session's frames,
    :func:`choose_uv_step`) and ``opts.xy_oversample``."""
    if opts.uv_step_px is None:
        raise ValueError("run_grid: uv_step_px None (auto) is chosen from a session: use choose_uv_step")
    return session_grid(models, opts.uv_step_px, opts.xy_oversample)


def session_grid(models: dict, uv_step_px: float, xy_oversample: int | None = None):
    """(grid, views per camera spacing) of a session's light field for cameras ``models`` (as
    ``polycam run``, ``polycam motion SESSION`` and ``polycam depth SESSION`` resample it):
    ``resample.auto_grid`` with ``uv_step_px`` and ``xy_oversample`` viewpoints per camera spacing
    (None: 2, or 4 when 2 gives fewer than :data:`MIN_VIEWS` views along x or y: a row of cameras,
    a stereo pair)."""
    from resample.grid import auto_grid

    every = xy_oversample or 2
    grid = auto_grid(models, uv_step_px=uv_step_px, xy_oversample=every)
    if xy_oversample is None and min(grid.x.count, grid.y.count) < MIN_VIEWS:
        every = 4
        grid = auto_grid(models, uv_step_px=uv_step_px, xy_oversample=every)
    return grid, every


AUTO_UV_STEPS_PX = (1.0, 2.0)
"""The direction steps [camera pixels] ``--uv-step auto`` chooses from (:func:`choose_uv_step`)."""
AUTO_UV_MAX_DISPARITY = 0.6
"""``--uv-step auto``: the finest of :data:`AUTO_UV_STEPS_PX` whose disparity per view step is at most
this many of its samples. The solver's own limit (``MotionOptions.max_view_disparity``, 0.75) stops
aliasing from biasing the estimate; between ~0.6 and it, a 1-pixel step's finest level gives errors
like a 2-pixel step's with a covariance 2x too small (the bias coherent over the image is shared
with the level above it, so neither the residuals nor the level change show it), and a 1-pixel
grid reduced by the solver's pyramid comes out worse than a 2-pixel grid resampled from the images
(docs/motion.md, "The direction step")."""
AUTO_XY_MAX_DISPARITY = 0.6
"""``--uv-step auto`` with the default views per camera spacing on a 2-D array (2): where even the
coarsest step's views are more than this many samples apart for the scene, the grid takes
:data:`AUTO_XY_DENSER` views per camera spacing instead. The solver otherwise solves such a grid one
or two (u, v) levels up (``MotionOptions.max_view_disparity``); one more view filled between the
cameras keeps it at a finer level. Measured on 10 such sessions of four rigs (webcam3x3, webcam5x5,
oak_array at 1.22–1.71, mock5x5 at 0.63–0.66): every one erred less in translation, median per-pair
1.64 → 0.97 % (rotation 0.63 → 0.54 %), at about twice the time; below it 2 did better on five of six
sessions (docs/motion.md, "The direction step")."""
AUTO_XY_DENSER = 3
"""Views per camera spacing :data:`AUTO_XY_MAX_DISPARITY` switches a 2-D array's grid to (4 was
better than 3 on three of the 10 sessions and worse on seven, at about twice the time)."""
AUTO_UV_PROBE_FRAMES = 3
"""Frames (first, middle, last) whose median disparity :func:`choose_uv_step` uses."""


def choose_uv_step(session, models: dict, xy_oversample: int | None = None):
    """(uv_step_px, disparity, store) of ``--uv-step auto`` for an opened ``session`` with camera
    ``models``: the finest step of :data:`AUTO_UV_STEPS_PX` whose disparity per view step (the
    solver's measure, :func:`polycam.motion.frame_view_disparity`, median over
    :data:`AUTO_UV_PROBE_FRAMES` frames resampled at the coarsest step) is at most
    :data:`AUTO_UV_MAX_DISPARITY` samples of that step, else the coarsest (the solver's pyramid goes
    on from there); ``disparity`` in the chosen step's samples (NaN: not measurable, e.g. no texture,
    and the finest step is chosen); ``store`` the :class:`resample.stream.SessionLightField` of the
    coarsest step when that is chosen (its frames already resampled; ``xy_oversample`` the views per
    camera spacing its grid has), else None. With ``xy_oversample`` None on a 2-D array (2 views per
    camera spacing) whose views are more than :data:`AUTO_XY_MAX_DISPARITY` samples apart at the
    coarsest step, ``store`` is opened on :data:`AUTO_XY_DENSER` views per camera spacing instead
    (``disparity`` stays the 2-view grid's, which chose it; ``store.denser_views`` True)."""
    import numpy as np
    from resample.stream import SessionLightField

    from .motion import frame_view_disparity

    coarse = AUTO_UV_STEPS_PX[-1]
    grid, every = session_grid(models, coarse, xy_oversample)
    store = SessionLightField(session, models=models, grid=grid)
    store.xy_oversample = every
    n = len(store)
    picks = sorted({round(i * (n - 1) / max(AUTO_UV_PROBE_FRAMES - 1, 1)) for i in range(AUTO_UV_PROBE_FRAMES)},
                   reverse=True)        # frame 0 last: the store keeps it for the solve, which reads it first
    d = [frame_view_disparity(store.frame(i), grid, store.weights(i)) for i in picks]
    d = [x for x in d if math.isfinite(x)]
    if not d:
        return AUTO_UV_STEPS_PX[0], math.nan, None
    d_coarse = float(np.median(d))
    for step in AUTO_UV_STEPS_PX[:-1]:
        if d_coarse * coarse / step <= AUTO_UV_MAX_DISPARITY:
            return step, d_coarse * coarse / step, None
    if xy_oversample is None and store.xy_oversample == 2 and d_coarse > AUTO_XY_MAX_DISPARITY:
        grid, _ = session_grid(models, coarse, AUTO_XY_DENSER)
        store = SessionLightField(session, models=models, grid=grid)
        store.xy_oversample, store.denser_views = AUTO_XY_DENSER, True
    return coarse, d_coarse, store


def _camera_indices(n: int, every: int, h: int | None = None) -> list[int]:
    """Every ``every``-th of ``n`` view indices through the central one (the middle ``2 h + 1``
    of them with ``h``)."""
    every = max(int(every), 1)
    idx = list(range((n // 2) % every, n, every))
    if h is None:
        return idx
    c = len(idx) // 2
    return idx[max(0, c - h):c + h + 1]


def _views_at_cameras(grid, every: int, *arrays):
    """The sub-grid of every ``every``-th viewpoint through the central one (the views at the
    cameras of a grid with ``every`` views per camera spacing) and the arrays (F, Ny, Nx, ...)
    on it (None stays None). Depth uses these: the (x, y) derivatives of filled in-between
    views carry the view fill's own depth, not the cameras'."""
    from .lightfield import Axis

    if every <= 1:
        return grid, arrays
    F, Ny, Nx = grid.shape[:3]
    js, is_ = _camera_indices(Ny, every), _camera_indices(Nx, every)
    yv, xv = grid.y.values[js], grid.x.values[is_]
    sub = dataclasses.replace(grid, x=Axis(float(xv[0]), float(xv[-1]), len(xv)),
                              y=Axis(float(yv[0]), float(yv[-1]), len(yv)))
    pick = (slice(None), slice(js[0], None, every), slice(is_[0], None, every))
    return sub, tuple(None if a is None else a[pick] for a in arrays)


def _depth(report: Path, grid, every: int, L0, L1, W0, T_prev_next, opts: RunOptions, positions=None,
           truth=None) -> dict:
    """Depth of the first frame pair at the views through the central one every ``every``-th
    (the cameras of a grid with ``every`` views per camera spacing): depth.png (central view,
    and against the truth) and points.ply. ``positions``: the store's camera centres
    (:attr:`polycam.lfstore.LightFieldStore.camera_positions`): Eq. 7's depth is then refined on
    the cameras' data (:func:`polycam.depth_refine.refine_depth`), also at views no camera holds
    (a stereo pair's middle view); None: Eq. 7 on the camera views alone. ``truth``: (scene,
    T_world_rig (4, 4) of frame 0) of the ray tracer the session was rendered with; the central
    views' rays are traced in it for their true depth, and the confident rays' relative depth
    error is reported."""
    import numpy as np

    from .depth import DEPTH_FILTERS, MIN_W, DepthMap, depth_from_derivatives, grey_frame
    from .derivatives import derivative_noise, plenoptic_derivatives
    from .motion_weights import frame_noise_variance

    g0, g1 = grey_frame(L0), grey_frame(L1)
    sources = 0
    if positions is None:
        grid, (g0, g1, W0) = _views_at_cameras(grid, every, g0, g1, W0)
    noise_var = frame_noise_variance(g0, g1, grid, W0)
    der = plenoptic_derivatives(g0, g1, grid, filters=DEPTH_FILTERS)
    dm = depth_from_derivatives(der, grid, T_prev_next=T_prev_next,
                                noise=derivative_noise(noise_var, grid, DEPTH_FILTERS))
    conf = dm.confidence
    if positions is not None:
        from .depth_refine import refine_depth

        F, Ny, Nx = grid.shape[:3]
        h = opts.depth_views // 2
        targets = np.zeros((F, Ny, Nx), bool)
        targets[np.ix_(range(F), _camera_indices(Ny, every, h), _camera_indices(Nx, every, h))] = True
        dm = refine_depth(g0, grid, dm.Z, sources=positions, targets=targets, W=W0, noise_var=noise_var)
        sources = int(np.isfinite(positions[..., 0]).sum())
        grid, (g0, W0, Z, C, K) = _views_at_cameras(grid, every, g0, W0, dm.Z, dm.confidence, dm.consistency)
        dm = DepthMap(Z=Z, confidence=C, consistency=K)
        conf = dm.confidence               # from the cameras' data: the views' own W does not matter
    elif W0 is not None:
        conf = conf * (W0 > MIN_W)
    pos = conf[conf > 0]
    thr = float(np.percentile(pos, 50)) if pos.size else np.inf    # keep the better half
    good = (conf >= thr) & np.isfinite(dm.Z) & (dm.Z > 0)
    rng_ray = dm.range_along_ray(grid)
    F, Ny, Nx, Nv, Nu = grid.shape
    jc, ic = Ny // 2, Nx // 2
    # the central views: point cloud and comparison with the truth
    h = opts.depth_views // 2
    js, is_ = slice(max(0, jc - h), min(Ny, jc + h + 1)), slice(max(0, ic - h), min(Nx, ic + h + 1))
    rays = grid.face_rays(0)
    o, d = rays.origins[js, is_], rays.directions[js, is_]                     # (ny, nx, Nv, Nu, 3)
    m = good[0, js, is_]
    P = o[m] + d[m] * rng_ray[0, js, is_][m][:, None]
    write_ply(report / "points.ply", P, g0[0, js, is_][m])
    out = {"points": int(len(P)), "confident_fraction": float(np.mean(good[0, jc, ic])),
           "with_motion": T_prev_next is not None, "views": f"{o.shape[0]}x{o.shape[1]}",
           # the central views' rays with captured data (0 for a stereo pair, whose cameras are its
           # end views: those between are filled)
           "data_fraction": 1.0 if W0 is None else float(np.mean(W0[0, js, is_] > MIN_W)),
           # views whose data the refinement matched (0: Eq. 7 alone)
           "refined_on_views": sources}
    Z_true = None
    if truth is not None:
        from .rays import RayBundle
        from .synth import trace_rays

        scene, T_world_rig = truth
        dist = trace_rays(scene, RayBundle(o, d, frame="rig"), T_world_rig).distance   # (ny, nx, Nv, Nu)
        Z_true = dist * (d @ np.asarray(grid.faces[0].R_rig_face, float)[:, 2])      # along the face's z
        ok = m & np.isfinite(dist)
        rel = np.abs(rng_ray[0, js, is_][ok] - dist[ok]) / dist[ok]
        out.update({"truth_rays": int(rel.size),
                    "median_rel_error": float(np.median(rel)) if rel.size else float("nan"),
                    "p90_rel_error": float(np.percentile(rel, 90)) if rel.size else float("nan"),
                    "within_5pct": float(np.mean(rel < 0.05)) if rel.size else float("nan")})
    # depth map of the central view
    Zc = np.where(good[0, jc, ic], dm.Z[0, jc, ic], np.nan)
    finite = Zc[np.isfinite(Zc)]
    out["median_depth_m"] = float(np.median(finite)) if finite.size else float("nan")
    _plot_depth(report / "depth.png", g0[0, jc, ic], Zc,
                None if Z_true is None else Z_true[jc - js.start, ic - is_.start], out)
    return out


def _plot_depth(path: Path, image, Z, Z_true, stats: dict) -> None:
    """Central view, its estimated depth Z (confident rays), and with the truth: the true
    depth on the same colour scale and the relative error of the confident rays."""
    import numpy as np

    plt = _pyplot()
    n = 2 if Z_true is None else 4
    fig, axes = plt.subplots(1, n, figsize=(5.2 * n, 4))
    axes[0].imshow(image, cmap="gray", vmin=0, vmax=1)
    axes[0].set_title("central view, frame 0")
    finite = Z[np.isfinite(Z)]
    lo, hi = (np.percentile(finite, [2, 98]) if finite.size else (0.0, 1.0))
    im = axes[1].imshow(Z, cmap="turbo", vmin=lo, vmax=hi)
    axes[1].set_title("estimated depth Z [m] (blank: low confidence)")
    fig.colorbar(im, ax=axes[1], fraction=0.035)
    if Z_true is not None:
        im = axes[2].imshow(Z_true, cmap="turbo", vmin=lo, vmax=hi)
        axes[2].set_title("true depth Z [m] (ray tracer)")
        fig.colorbar(im, ax=axes[2], fraction=0.035)
        with np.errstate(divide="ignore", invalid="ignore"):      # rays without a true depth: blank
            rel = np.where(np.isfinite(Z_true) & (Z_true > 0), 100 * (Z - Z_true) / Z_true, np.nan)
        im = axes[3].imshow(rel, cmap="coolwarm", vmin=-20, vmax=20)
        axes[3].set_title(f"error [%]: median |err| {100 * stats['median_rel_error']:.1f}% "
                          f"({stats['views']} views)", fontsize=9)
        fig.colorbar(im, ax=axes[3], fraction=0.035)
    for ax in axes:
        ax.axis("off")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _write_summary(report: Path, summary: dict, written: list[str]) -> None:
    """report/summary.toml and report/README.md."""
    import tomli_w

    from .tomlio import atomic_write_text

    def clean(x):
        if isinstance(x, dict):
            return {k: clean(v) for k, v in x.items()}
        if isinstance(x, (list, tuple)):
            return [clean(v) for v in x]
        if isinstance(x, float):
            return x if math.isfinite(x) else "nan"
        return x

    atomic_write_text(report / "summary.toml", tomli_w.dumps(clean(summary)))
    c, r, m, d = summary["calibrate"], summary["resample"], summary["motion"], summary["depth"]
    noise = (f", the cameras' sensor noise {r['camera_noise_grey']:.2f} grey levels" if "camera_noise_grey" in r
             else "")
    cap = summary["capture"]
    md = f"""# polycam run: {summary['rig']} ({summary['cameras']} cameras)

| stage | result |
| --- | --- |
| board | {summary['board']['frames']} frames ({summary['board']['seconds']:.0f} s) |
| calibrate | RMS {c['rms_px']:.3f} px, {c['views']} views, {c['outliers']} outliers; centres vs truth {1e3 * c['position_rms_m']:.2f} mm RMS, axes {c['rotation_rms_deg']:.3f} deg RMS ([calib/report.md](../calib/report.md)) |
| capture | {cap['frames']} frames, {1e3 * cap['median_step_m']:.1f} mm and {cap['median_step_deg']:.2f} deg per frame |
| resample | {r['faces']} face(s), {r['views'][0]}x{r['views'][1]} views, {r['directions'][0]}x{r['directions'][1]} directions, mean W {r['mean_W']:.2f}{noise} |
| motion | {m['pairs']} pairs, {m['failed']} failed; median error translation {100 * m['median_t_rel']:.1f}% ({1e3 * m['median_t_err_m']:.2f} mm), rotation {100 * m['median_w_rel']:.1f}% ({m['median_w_err_deg']:.4f} deg); ATE {1e3 * m['ate_m']:.2f} mm; {m['seconds_per_pair']:.1f} s per pair (median) |
| depth | {100 * d['confident_fraction']:.0f}% of the central view confident, median {d['median_depth_m']:.2f} m, {d['points']} points; against the true depth (ray tracer) of the confident rays of the central {d['views']} views: median relative error {100 * d['median_rel_error']:.1f}%, 90th percentile {100 * d['p90_rel_error']:.1f}%, {100 * d['within_5pct']:.0f}% within 5% |

![trajectory](trajectory.png)
![per-pair errors](errors.png)

(Each pair's error beside the error norm its reported standard deviations predict: the
residuals' scatter plus the change from the coarser (u, v) level's estimate, which stands in for
the model error of a camera array that the residuals do not show; pairs.csv has both parts.
docs/motion.md, "How far to trust the covariance".)

![calibration residuals](calibration_residuals.png)
![light-field mosaic](mosaic.png)
![epipolar-plane images](epi.png)
![depth](depth.png)

Files: {', '.join(written)}.
"""
    atomic_write_text(report / "README.md", md)


# ----------------------------------------------------------------------------- CLI


def add_parsers(sub) -> None:
    """Add the ``run`` verb (registered through polycam/cli.py's STAGE_CLIS)."""
    from .depth_cli import uv_step_arg

    p = sub.add_parser("run", help="the whole chain on a mock rig: board, calibrate, capture, resample, "
                                   "motion, depth, report",
                       description="Capture a board session and a motion session of a mock rig, calibrate "
                                   "(mrcal), resample with the calibrated models, estimate motion and depth, "
                                   "and write a report folder. See docs/end_to_end.md.")
    p.add_argument("rig", nargs="?", default=str(DEFAULT_RIG), metavar="RIG.toml",
                   help="rig file with a [mock] table (default rigs/mock5x5.toml)")
    p.add_argument("--out", required=True, metavar="DIR", help="output folder")
    p.add_argument("--board", default=None, metavar="BOARD.toml",
                   help="calibration board (default rigs/boards/charuco_5x7.toml; for a rig whose cameras look "
                        "through several faces rigs/boards/charuco_7x9.toml, large enough to be seen across an edge)")
    p.add_argument("--frames", type=_positive_int, default=RunOptions.frames, help="motion frames (default 5)")
    p.add_argument("--board-frames", type=_positive_int, default=RunOptions.board_frames,
                   help="board frames (default 25; for a rig whose cameras look through several faces, 12 per "
                        "pair of adjacent faces: 144 for the nested cube, a third of them held across an edge)")
    p.add_argument("--seed", type=int, default=None, help="default: the rig's [mock] seed")
    p.add_argument("--uv-step", type=uv_step_arg, default=RunOptions.uv_step_px, metavar="PX|auto",
                   help="direction spacing of the light field in camera pixels (default 2), or auto: 1, or 2 where "
                        "the views are more than 0.6 of a 1-pixel sample apart for the scene (docs/motion.md, "
                        "\"The direction step\")")
    p.add_argument("--xy-oversample", type=_positive_int, default=None, metavar="N",
                   help="light-field viewpoints per camera spacing (default: 2, one depth-filled view "
                        f"between cameras, or 4 when 2 gives fewer than {MIN_VIEWS} views along x or y)")
    p.add_argument("--scale-selection", choices=("on", "off"), default="on" if RunOptions.scale_selection else "off",
                   help="(u, v) scale selection of paper Sect. 4.1 before the motion solve (default %(default)s)")
    p.add_argument("--calib-draws", type=_nonneg_int, default=RunOptions.calib_draws, metavar="N",
                   help="re-solve the motion with N sets of camera models drawn from the calibration's uncertainty "
                        "(2N re-solves) and add the spread to each pair's covariance (default %(default)s; 0: the "
                        "calibrated models are taken as exact)")
    p.add_argument("--sync-draws", type=_nonneg_int, default=RunOptions.sync_draws, metavar="N",
                   help="cameras that are not synchronised: re-solve their second pass with N sets of capture times "
                        "and first-pass motions drawn from their uncertainty (2N re-solves) and add the spread to "
                        "each pair's covariance (default %(default)s; docs/motion.md, \"Unsynchronised cameras\")")
    p.add_argument("--sampling-check", action="store_true",
                   help="re-solve the motion on a second view sampling (one more view per camera spacing) and add "
                        "each pair's change to its covariance (docs/motion.md, \"A second view sampling\")")
    p.set_defaults(func=cmd_run)


def cmd_run(args: argparse.Namespace) -> int:
    from .cli import _progress

    run_chain(args.rig, args.out, board_path=args.board,
              options=RunOptions(frames=args.frames, board_frames=args.board_frames, seed=args.seed,
                                 uv_step_px=args.uv_step, xy_oversample=args.xy_oversample,
                                 scale_selection=args.scale_selection == "on", calib_draws=args.calib_draws,
                                 sync_draws=args.sync_draws, sampling_check=args.sampling_check),
              progress_factory=_progress, echo=print)
    return 0
