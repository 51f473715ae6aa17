"""The ``polycam`` command: a thin layer over library functions (SPEC.md, CLI verbs).

Arguments are parsed before any heavy import so ``--help`` is instant. Known
user errors (:class:`polycam.errors.PolycamError`, and OS errors on a named
file) print one line on stderr and exit 1; bad usage exits 2 (argparse); any
other exception is a bug and keeps its traceback. Output into a pipe whose reader has gone
(``polycam info X | head -1``) ends quietly with 141, the status a shell gives a process that
SIGPIPE stopped (SPEC.md's 0 / 1 / 2 are for runs that read their output to the end).
"""

from __future__ import annotations

import argparse
import logging
import math
import os
import statistics
import sys
import time
from contextlib import contextmanager
from pathlib import Path

from .cliargs import check_output_file, check_output_folder
from .cliargs import nonneg_float as _nonneg_float
from .cliargs import nonneg_int as _nonneg_int
from .cliargs import positive_float as _positive_float
from .cliargs import positive_int as _positive_int

__all__ = ["main", "build_parser", "STAGE_CLIS"]

NOISY_HINT_GREY = 1.0
"""Sensor noise [grey levels of 255] from which ``polycam motion`` with the default preset points to
``--preset noisy`` on frames without confidences (docs/motion.md, "Noise": on six faces of finely
integrated pixels the defaults are 1.3–2.3x the bound there, the noise options 1.1–1.4x; "Which
preset": not on every kind of frame, so a hint, not an automatic choice)."""

STAGE_CLIS = ("capture.cli", "calib.cli", "resample.cli", "polycam.run", "polycam.design_cli", "polycam.depth_cli")
"""Modules whose ``add_parsers(subparsers)`` add the pipeline stages' verbs."""

log = logging.getLogger("polycam")


# ----------------------------------------------------------------------------- helpers


@contextmanager
def _progress(description: str, total: int | None):
    """A rich progress bar on stderr; yields ``advance(done, total)`` for library callbacks."""
    from rich.progress import (BarColumn, MofNCompleteColumn, Progress, TextColumn,
                               TimeElapsedColumn, TimeRemainingColumn)

    columns = [TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(),
               TimeElapsedColumn(), TimeRemainingColumn()]
    with Progress(*columns, transient=False, disable=not sys.stderr.isatty()) as bar:
        task = bar.add_task(description, total=total)

        def advance(done: int, total_now: int | None = None) -> None:
            bar.update(task, completed=done, total=total_now if total_now is not None else total)

        yield advance


def _faces_arg(text: str) -> list[str]:
    from .lightfield import FACE_NAMES

    if text == "all":
        return list(FACE_NAMES)
    names = [n.strip() for n in text.split(",") if n.strip()]
    bad = [n for n in names if n not in FACE_NAMES]
    if not names or bad:
        raise argparse.ArgumentTypeError(
            f"expected 'all' or a comma-separated list of {' '.join(FACE_NAMES)}, got {text!r}")
    return names




# ----------------------------------------------------------------------------- verbs


def cmd_synth_lightfield(args: argparse.Namespace) -> int:
    from .lightfield import load_grid

    grid = load_grid(args.grid) if args.grid else None  # user files first: fail before heavy work
    from .synth import default_lightfield_grid, synth_lightfield

    grid = grid or default_lightfield_grid(args.faces)
    with _progress(f"rendering {args.out}", args.frames) as advance:
        synth_lightfield(args.out, grid=grid, scene=args.scene, distance=args.distance,
                         frames=args.frames, seed=args.seed, supersample=args.supersample,
                         step_t=args.step_t, step_r_deg=args.step_r, fps=args.fps, noise=args.noise,
                         bit_depth=args.bit_depth, specular=args.specular, overwrite=args.overwrite,
                         progress=advance)
    print(f"wrote {args.out}: {args.frames} frames, {len(grid.faces)} face(s), "
          f"{grid.shape[1]}x{grid.shape[2]} views of {grid.shape[3]}x{grid.shape[4]}; "
          f"ground truth in {Path(args.out) / 'groundtruth.tum'}")
    return 0


def cmd_synth_session(args: argparse.Namespace) -> int:
    from .rig import load_rig

    rig = load_rig(args.rig)  # user files first: fail before heavy work
    board = None
    if args.board:
        from .board import load_board

        board = load_board(args.board)
    from .synth import synth_board_session, synth_session

    common = dict(seed=args.seed, supersample=args.supersample, bit_depth=args.bit_depth,
                  noise=args.noise, perturb_position_m=args.perturb_position,
                  perturb_rotation_deg=args.perturb_rotation, perturb_focal_frac=args.perturb_focal,
                  overwrite=args.overwrite)
    if args.board is None:
        common.update(specular=args.specular, sync_spread_ms=args.sync_spread_ms,
                      timestamp_jitter_ms=args.timestamp_jitter_ms)
    elif args.specular or args.sync_spread_ms or args.timestamp_jitter_ms:
        print("polycam synth session: error: --specular, --sync-spread-ms and --timestamp-jitter-ms apply to "
              "scene sessions, not to --board", file=sys.stderr)
        return 2
    with _progress(f"rendering {args.out}", args.frames) as advance:
        if board is not None:
            synth_board_session(rig, args.out, board=board, frames=args.frames, progress=advance,
                                **common)
            what = "calibration-board session"
        else:
            synth_session(rig, args.out, scene=args.scene, frames=args.frames, progress=advance,
                          **common)
            what = "session"
    print(f"wrote {what} {args.out}: {args.frames} frames from {len(rig.cameras)} cameras "
          f"(true calibration in {Path(args.out) / 'calib'})")
    return 0


def cmd_motion(args: argparse.Namespace) -> int:
    from .depth_cli import open_source, solver_options, uv_step_line
    from .errors import InputError
    from .motion_options import describe_options

    opts = solver_options(args)                       # before anything is read or written
    check_output_file(args.out, "--out")
    if args.report:
        check_output_folder(args.report, "--report")
    src = Path(args.source)
    store = open_source(src, calib=args.calib, uv_step=args.uv_step,   # validates before the solver import
                        xy_oversample=args.xy_oversample)
    if len(store) < 2:
        raise InputError(f"{src}: has {len(store)} frame(s); motion needs a frame pair (at least 2)")
    calib_cov = None
    if args.calib_draws:
        if not hasattr(store, "resampler"):
            raise InputError(f"{src}: --calib-draws needs a session and its calibration (a light-field store "
                             "keeps no camera models)")
        from calib.draws import calibration_covariance   # the CLI layer may import stages

        try:
            calib_cov = calibration_covariance(store.models)          # before the solve: fail early
        except InputError as e:
            raise InputError(f"{args.calib or src / 'calib'}: {e}") from None
    if args.sampling_check and not hasattr(store, "resampler"):
        raise InputError(f"{src}: --sampling-check needs a session (a light-field store is already resampled "
                         "on one view sampling)")
    truth_name = src / "groundtruth.tum"
    truth = store.groundtruth()                         # read before the solve: a bad file fails early
    import numpy as np

    if truth is not None and not np.array_equal(truth.timestamps_ns, store.timestamps_ns):
        raise InputError(f"{truth_name}: {len(truth)} poses whose timestamps are not the {len(store)} frames' "
                         "(one pose per frame, at its timestamp)")
    unsync = ""
    grid = None                                         # a session: how it is resampled (the report's [grid])
    if hasattr(store, "resampler"):
        grid = {"shape": list(store.grid.shape), "uv_step": "auto" if args.uv_step is None else args.uv_step,
                "uv_step_px": store.uv_step_px, "xy_oversample": store.xy_oversample}
        if math.isfinite(store.uv_disparity):
            grid["uv_disparity"] = store.uv_disparity
        F, Ny, Nx, Nv, Nu = store.grid.shape
        print(f"resampling {src} on the fly: {len(store.resampler.cameras)} calibrated cameras onto "
              f"{F} face(s) x {Ny}x{Nx} views x {Nv}x{Nu} directions (geometry {store.seconds_geometry:.1f} s)")
        if args.uv_step is None:
            print("  " + uv_step_line(store))
        from .session import SYNC_AS_IF_TOGETHER, sync_warning

        unsync = sync_warning(store.session)
        if unsync:
            print("  warning: " + unsync + (SYNC_AS_IF_TOGETHER if args.sync_correct == "off" else
                                            "; the motion is solved twice, the second time with every camera "
                                            "where it captured its image (--sync-correct)"))
    from .motion import estimate_trajectory
    from .trajectory import write_tum

    described = describe_options(opts)
    if described:
        print("solver options: " + described)
    scale_selection = args.scale_selection == "on"
    with _progress(f"motion {src.name}", len(store) - 1) as advance:
        try:
            traj, results = estimate_trajectory(store, progress=advance, options=opts,
                                                scale_selection=scale_selection)
        except InputError as e:                       # e.g. a frame with NaNs: name the store
            raise InputError(f"{src}: {e}") from None
    capture_motion = None
    if hasattr(store, "resampler") and args.sync_correct == "auto" and unsync:
        from resample.stream import SessionLightField   # the CLI layer may import stages

        capture_motion = np.stack([r.T_prev_next for r in results])   # a failed pair: the identity
        motion_covariance = np.stack([r.covariance for r in results])  # (--sync-draws draws it)
        first = store
        store = SessionLightField(first.session, models=first.models, grid=first.grid,
                                  options=first.options, capture_motion=capture_motion)
        store.uv_step_px, store.xy_oversample = first.uv_step_px, first.xy_oversample
        t0 = time.perf_counter()
        with _progress(f"motion {src.name}, cameras where they captured", len(store) - 1) as advance:
            try:
                traj, results = estimate_trajectory(store, progress=advance, options=opts,
                                                    scale_selection=scale_selection)
            except InputError as e:
                raise InputError(f"{src}: {e}") from None
        print(f"  second pass: every frame resampled with each camera where it captured its image "
              f"({time.perf_counter() - t0:.1f} s)" + ("" if args.sync_draws else
              "; the reported std leaves out the capture times' and the first pass's share, which "
              "--sync-draws N measures"))
        if args.sync_draws:
            from .sync_draws_cli import add_capture_timing_share

            results, line = add_capture_timing_share(
                store.session, store.models, store.grid, capture_motion, results, draws=args.sync_draws,
                motion_covariance=motion_covariance,
                bar=lambda total: _progress(f"capture-time draws {src.name}", total),
                resample_options=store.options, motion_options=opts, scale_selection=scale_selection)
            print("  " + line)
    elif args.sync_draws:
        print("  capture-time draws skipped: " + ("no second pass (--sync-correct off)" if unsync else
                                                  "the cameras are synchronised" if hasattr(store, "resampler")
                                                  else "a light-field store keeps no capture times"))
    if calib_cov is not None:
        from .calib_draws_cli import add_calibration_share

        results, line, _ = add_calibration_share(
            store.path, store.models, store.grid, results, draws=args.calib_draws,
            bar=lambda total: _progress(f"calibration draws {src.name}", total), cov=calib_cov,
            resample_options=store.options, motion_options=opts, scale_selection=scale_selection,
            capture_motion=capture_motion)
        print("  " + line)
    if args.sampling_check:
        from .sampling_check_cli import add_view_sampling_share

        results, line, _ = add_view_sampling_share(
            store.session, store.models, store.uv_step_px, store.xy_oversample, results,
            bar=lambda total: _progress(f"second view sampling {src.name}", total),
            resample_options=store.options, motion_options=opts, scale_selection=scale_selection,
            capture_motion=capture_motion)
        print("  " + line)
    write_tum(args.out, traj)
    failed = [r for r in results if not r]
    print(f"wrote {args.out}: {len(traj)} poses from {len(results)} frame pairs"
          + (f"; {len(failed)} failed (first: pair {failed[0].index}: {failed[0].reason})" if failed else ""))
    if hasattr(store, "seconds_frames"):
        print(f"  resampled {store.frames_resampled} frames in {store.seconds_frames:.1f} s; "
              f"mean confidence W {store.mean_W:.2f}")
    cameras = None
    if getattr(store, "camera_noise_images", 0):     # a session, or a store polycam resample wrote
        per_sample = store.sample_noise_sigma() if hasattr(store, "sample_noise_sigma") else math.nan
        cameras = (store.camera_noise_sigma, store.camera_noise_images, per_sample)
    noise = _noise_line(results, args.preset, bool(getattr(store, "has_weights", False)), cameras)
    if noise:
        print(noise)
    if getattr(store, "compressed_cameras", 0):      # a session with MJPG cameras
        from resample.resampler import compressed_note

        print("  " + compressed_note(store.compressed_cameras, len(store.session.cameras)))
    levels = _level_line(results)
    if levels:
        print(levels)
    one = _one_level_line(results, opts.levels)
    if one:
        print(one)
    if truth is not None:
        from .evaluate import ate_rmse, error_over_std, pair_errors, solved_pairs

        err = pair_errors(traj, truth)
        solved = np.array([bool(r) for r in results])
        ate = f"ATE {1e3 * ate_rmse(traj, truth):.3f} mm"
        if not solved.any():
            print(f"against {truth_name}: no pair solved; {ate}")
        else:
            # the failed pairs (their start, e.g. the previous pair's motion) are in the ATE only
            of = f" (the {int(solved.sum())} solved pairs)" if not solved.all() else ""
            err, std = solved_pairs(err, np.stack([r.std for r in results]), solved)
            print(f"against {truth_name}: median per-pair error{of} translation "
                  f"{100 * np.median(err.t_rel):.2f}%, rotation {100 * np.median(err.w_rel):.2f}%; {ate}")
            k_t, k_r = error_over_std(err, std)
            print(f"  errors / the reported std (median over the pairs; 1: the covariance explains them): "
                  f"translation {k_t:.1f}x, rotation {k_r:.1f}x")
    if args.report:
        from .motion_report import write_motion_report

        written = write_motion_report(args.report, results, traj, truth, store.timestamps_ns, options=opts,
                                      scale_selection=scale_selection, preset=args.preset, grid=grid)
        print(f"report in {args.report}: {', '.join(written)}")
    return 0


def _camera_group(cams: list[str]) -> str:
    """``polycam info``'s name of cameras listed on one line: the camera, or "N cameras (a, b, c, ...)"."""
    if len(cams) == 1:
        return cams[0]
    return f"{len(cams)} cameras ({', '.join(cams[:3])}" + (", ...)" if len(cams) > 3 else ")")


def _info_calibration(path: Path) -> None:
    """``polycam info`` of a calibration folder: its cameras (lens models, image sizes, centres in
    the rig frame) and, when ``polycam calibrate`` wrote one, its report's summary."""
    import numpy as np

    from .cameras import load_cameramodel

    files = sorted(path.glob("*.cameramodel"))
    models = {f.stem: load_cameramodel(f) for f in files}
    lens: dict[str, list[str]] = {}
    for cam, m in models.items():
        w, h = m.imagersize()
        lens.setdefault(f"{m.intrinsics()[0]} {w}x{h}", []).append(cam)
    centres = np.array([m.extrinsics_Rt_toref()[3] for m in models.values()])     # (N, 3) [m], rig frame
    span = centres.max(axis=0) - centres.min(axis=0)
    print(f"calibration {path}: {len(models)} cameras, centres spanning {1e3 * span[0]:.1f} x {1e3 * span[1]:.1f} x "
          f"{1e3 * span[2]:.1f} mm (x, y, z in the rig frame)")
    for what, cams in lens.items():
        print(f"  {_camera_group(cams)}: {what}")
    report = path / "report.toml"
    if report.is_file():
        print("  report: " + _report_summary(report))


def _report_summary(report: Path) -> str:
    """``polycam info``'s summary of a calibration's ``report.toml`` (method, frames, views, RMS), or
    what keeps it from being read: the file comes from the user, so only a ``[calibration]`` table's
    numbers and short one-line strings are shown."""
    import tomllib

    try:
        doc = tomllib.loads(report.read_text())
    except (tomllib.TOMLDecodeError, UnicodeDecodeError, OSError):
        return f"{report} is not readable TOML"
    c = doc.get("calibration")
    if not isinstance(c, dict):
        return f"{report} has no [calibration] table"

    def shown(v) -> bool:
        if isinstance(v, bool):
            return False
        if isinstance(v, (int, float)):
            return math.isfinite(v)
        return isinstance(v, str) and 0 < len(v) <= 40 and v.isprintable()

    parts = [f"{k} {c[k]}" for k in ("method", "frames", "views") if shown(c.get(k))]
    if shown(c.get("rms_px")) and not isinstance(c["rms_px"], str):
        parts.append(f"RMS {c['rms_px']} px")
    return ", ".join(parts) if parts else f"{report} has none of method, frames, views, rms_px"


def _noise_line(results, preset: str, confidences: bool = False, cameras: tuple[float, int, float] | None = None) -> str:
    """The frames' sensor noise in grey levels of 255 (median over the pairs), with a hint to the
    noise options when the defaults ran on frames with a grey level or more and without
    confidences W ('' without estimates). The noise options assume noise independent from
    sample to sample; on resampled frames (W; viewpoints interpolated between the cameras) they
    measured no better or worse (docs/motion.md, "Which preset"), so there is no hint. There the
    solver's estimate (second differences across the views) also reads the scene's parallax between
    the cameras, off by up to 2x either way from the samples' noise (docs/motion_log.md, session 44):
    with ``cameras`` (the cameras' sensor noise estimated from their images, how many images, and the
    noise a resampled sample carries, all in [0, 1] units: a session resampled on the fly,
    :class:`resample.stream.SessionLightField`, or the first two from a store ``polycam resample``
    wrote, the third NaN) the line gives those instead, else it says "noise estimate" instead of
    calling it the sensor noise."""
    if cameras is not None and math.isfinite(cameras[0]):
        sigma, n, per_sample = cameras
        line = (f"  sensor noise {255.0 * sigma:.2f} grey levels in the cameras' images (of 255, median over "
                f"{n} image{'s' if n != 1 else ''}")
        if math.isfinite(per_sample):
            line += f"; {255.0 * per_sample:.2f} per resampled sample, push-pull averages the pixels"
        return line + ")"
    vals = [255.0 * r.noise_sigma for r in results if math.isfinite(r.noise_sigma)]
    if not vals:
        return ""
    med = statistics.median(vals)
    if confidences:
        return (f"  noise estimate {med:.2f} grey levels (of 255, median over the pairs; across the views, which on a "
                "resampled camera array also see the scene's parallax between the cameras: not their sensor noise)")
    line = f"  sensor noise {med:.2f} grey levels (of 255, median over the pairs)"
    if preset == "default" and med >= NOISY_HINT_GREY:
        line += ("; with a grey level or more, --preset noisy came closer to the noise bound on six-face "
                 "frames of finely integrated pixels, at two to three times the time: try it on your frames "
                 "(docs/motion.md, \"Which preset\")")
    return line


def _session_noise_line(session) -> str:
    """``polycam info`` of a session: the sensor noise of the first frame's images (median over the
    cameras, grey levels of 255; :func:`resample.resampler.images_noise_sigma`; MJPG cameras left out,
    :func:`resample.resampler.noise_cameras`, and the line says so), '' when no image gives an estimate
    (too small, or none)."""
    from resample.resampler import compressed_note, images_noise_sigma, median_noise, noise_cameras   # a stage

    from .errors import PolycamError

    if len(session) == 0:
        return ""
    cams = noise_cameras(session, session.cameras)
    note = compressed_note(len(session.cameras) - len(cams), len(session.cameras))
    if not cams:
        return "  " + note
    try:
        images = session.read_frame(0)
    except PolycamError:            # an unreadable image: the summary stands without the figure
        return ""
    sigma, n = median_noise(images_noise_sigma(images, cams).values())
    if not n:
        return ""
    return (f"  sensor noise {255.0 * sigma:.2f} grey levels in the first frame's images (of 255, "
            f"median over {n} camera{'s' if n != 1 else ''}{'; ' + note if note else ''})")


def _level_line(results) -> str:
    """When the views were too far apart for the scene in some pairs (``PairResult.uv_level`` >
    0, ``MotionOptions.max_view_disparity``): the median disparity per view step and the (u, v)
    levels used; '' otherwise."""
    coarse = [r for r in results if r.uv_level > 0]
    if not coarse:
        return ""
    disp = statistics.median(r.view_disparity for r in coarse)
    levels = sorted({r.uv_level for r in coarse})
    return (f"  views far apart for the scene ({disp:.2f} samples per view step, median): "
            f"{len(coarse)} of {len(results)} pairs solved at (u, v) level {'/'.join(map(str, levels))} "
            "(--option max_view_disparity=inf forces the finest; docs/motion.md, \"Camera arrays\")")


def _one_level_line(results, levels: int) -> str:
    """When solved pairs had one (u, v) level only although the options ask for ``levels`` and no
    level change either (the grid's directions allow no coarser level, and the estimate on frames
    blurred along u and v that stands in for one failed: ``PairResult.level_change`` NaN): their
    covariance lacks the model error the residuals do not show and may be several times too small;
    '' otherwise."""
    one = [r for r in results if r and not all(math.isfinite(float(c)) for c in r.level_change)]
    if levels < 2 or not one:
        return ""
    return (f"  warning: {len(one)} of {len(results)} pairs solved on one (u, v) level (too few directions for a "
            "coarser one): their std counts the residuals' scatter only, not the model error a second level "
            "shows, and may be several times too small (docs/motion.md, \"How far to trust the covariance\")")


def _slower_cameras_line(session) -> str:
    """``polycam info``: the cameras at a slower frame rate than the rig's fastest
    (:attr:`polycam.session.Session.other_rate`), whose capture times follow their own clocks; ''
    without."""
    fps = [session.rig.camera(c).fps for c in session.cameras]
    slower = [(c, f) for c, f, o in zip(session.cameras, fps, session.other_rate) if o]
    if not slower:
        return ""
    rates = "/".join(f"{f:g}" for f in sorted({f for _, f in slower}, reverse=True))
    return (f"  {_camera_group([c for c, _ in slower])} at {rates} fps against {max(fps):g}: missing from some "
            f"frames, their capture times from their own clocks (docs/capture.md, \"Synchronisation\")")


def cmd_info(args: argparse.Namespace) -> int:
    from .errors import InputError

    path = Path(args.path)
    if (path / "session.toml").exists():
        from .session import open_session

        s = open_session(path)
        print(f"session {path}: rig {s.rig.name!r}, {len(s.cameras)} cameras, {len(s)} frames, "
              f"status {s.status}")
        groups: dict[tuple, list[str]] = {}
        for cam in s.cameras:  # cameras with the same image count and size on one line
            groups.setdefault((len(s.image_timestamps(cam)), *s.image_size(cam)), []).append(cam)
        for (count, w, h), cams in groups.items():
            print(f"  {_camera_group(cams)}: {count} images of {w}x{h} each")
        print(f"  calibration: {'yes' if s.calibration() is not None else 'no'}; "
              f"ground truth: {'yes' if s.groundtruth() is not None else 'no'}")
        noise = _session_noise_line(s)
        if noise:
            print(noise)
        if len(s.cameras) > 1 and len(s):
            import numpy as np

            from .session import SYNC_AS_IF_TOGETHER, sync_warning

            spread = s.capture_spread_ns() / 1e6
            print(f"  capture times: the cameras' images of a frame span {float(np.median(spread)):.2f} ms "
                  f"(median; {float(spread.max()):.2f} ms at most); the timestamps jitter "
                  f"{s.timestamp_jitter_ns() / 1e6:.2f} ms (RMS) about them, which alone spreads them "
                  f"~{s.jitter_spread_ns() / 1e6:.2f} ms")
            slower = _slower_cameras_line(s)
            if slower:
                print(slower)
            unsync = sync_warning(s)
            if unsync:
                print("  warning: " + unsync + SYNC_AS_IF_TOGETHER)
    elif path.is_dir() and any(path.glob("*.cameramodel")):
        _info_calibration(path)
    elif path.is_dir() and not any((path / n).exists() for n in ("zarr.json", ".zgroup")):
        raise InputError(f"{path}: neither a session (no session.toml), a calibration (no .cameramodel files) "
                         "nor a light-field store (no zarr.json)")
    else:
        from .lfstore import open_lightfield

        lf = open_lightfield(path)
        F, Ny, Nx, Nv, Nu = lf.grid.shape
        print(f"light field {path}: {len(lf)} frames, faces {' '.join(f.name for f in lf.grid.faces)}, "
              f"{Ny}x{Nx} views of {Nv}x{Nu} samples"
              + (f", {lf.colour} colour channels" if lf.colour else "")
              + (", with confidence W" if lf.has_weights else ""))
        print(f"  x [{lf.grid.x.min:g}, {lf.grid.x.max:g}] y [{lf.grid.y.min:g}, {lf.grid.y.max:g}] m; "
              f"u [{lf.grid.u.min:g}, {lf.grid.u.max:g}] v [{lf.grid.v.min:g}, {lf.grid.v.max:g}]; "
              f"f {lf.grid.faces[0].f:g}, z_pi {lf.grid.faces[0].z_pi:g} m")
        noise = (f"; the cameras' sensor noise {255.0 * lf.camera_noise_sigma:.2f} grey levels (of 255, median over "
                 f"{lf.camera_noise_images} images)" if lf.camera_noise_images else "")
        print(f"  ground truth: {'yes' if lf.groundtruth() is not None else 'no'}{noise}")
    return 0


def cmd_demo(args: argparse.Namespace) -> int:
    from .demo import run_demo

    run_demo(Path(args.out), progress_factory=_progress, echo=print)
    return 0


# ----------------------------------------------------------------------------- parser


def build_parser() -> argparse.ArgumentParser:
    from .depth_cli import add_solver_options, add_source_options

    p = argparse.ArgumentParser(prog="polycam", description="Polydioptric camera arrays: "
                                "capture, calibrate, resample, plenoptic egomotion.")
    p.add_argument("-v", "--verbose", action="count", default=0, help="log more (-v info, -vv debug)")
    sub = p.add_subparsers(dest="verb", metavar="VERB", required=True)

    # synth
    ps = sub.add_parser("synth", help="ray-traced synthetic light fields and camera-array sessions")
    ss = ps.add_subparsers(dest="what", metavar="WHAT", required=True)

    pl = ss.add_parser("lightfield", help="a light-field sequence rendered straight onto the two-plane grid")
    pl.add_argument("--scene", choices=("spheres", "room"), default="spheres")
    pl.add_argument("--distance", type=_positive_float, default=6.0,
                    help="distance from the sensor to the scene [m] (default 6)")
    pl.add_argument("--faces", type=_faces_arg, default=["+z"],
                    help="'all' (six nested-cube faces) or a list such as +z or +z,-x (default +z)")
    pl.add_argument("--frames", type=_positive_int, default=2)
    pl.add_argument("--out", required=True, help="output store NAME.zarr")
    pl.add_argument("--grid", help="GRID.toml (default: 9x9 views, 64x64 directions, f = 60)")
    pl.add_argument("--seed", type=int, default=0)
    pl.add_argument("--supersample", type=_positive_int, default=2,
                    help="k: average k x k rays over each (u, v) cell (default 2)")
    pl.add_argument("--step-t", type=_nonneg_float, default=0.015, help="typical translation per frame [m]")
    pl.add_argument("--step-r", type=_nonneg_float, default=0.2, help="typical rotation per frame [deg]")
    pl.add_argument("--fps", type=_positive_float, default=30.0)
    pl.add_argument("--noise", type=_nonneg_float, default=0.0,
                    help="std of Gaussian sensor noise per sample in [0, 1] units, seeded (default 0)")
    pl.add_argument("--bit-depth", type=int, choices=(8, 16), default=None,
                    help="round the samples to 8 or 16 bits, as a camera does (default: float samples)")
    pl.add_argument("--specular", type=_nonneg_float, default=0.0,
                    help="strength of a view-dependent (Phong) highlight on every surface: a non-Lambertian "
                         "scene (default 0: Lambertian)")
    pl.add_argument("--overwrite", action="store_true", help="replace an existing output")
    pl.set_defaults(func=cmd_synth_lightfield)

    pss = ss.add_parser("session", help="a camera-array session (or, with --board, a calibration session)")
    pss.add_argument("--rig", required=True, help="rig file RIG.toml")
    pss.add_argument("--scene", choices=("room", "spheres"), default=None,
                     help="scene (default: the rig's [mock] scene, else room)")
    pss.add_argument("--frames", type=_positive_int, default=10)
    pss.add_argument("--out", required=True, help="output session folder")
    pss.add_argument("--seed", type=int, default=None, help="default: the rig's [mock] seed, else 0")
    pss.add_argument("--board", help="BOARD.toml: render a calibration-board session instead")
    pss.add_argument("--supersample", type=_positive_int, default=2, help="k x k rays per pixel (default 2)")
    pss.add_argument("--bit-depth", type=int, choices=(8, 16), default=8)
    pss.add_argument("--noise", type=_nonneg_float, default=None,
                     help="grey-level noise std in [0, 1] units (default: the rig's [mock] noise, else 0)")
    pss.add_argument("--perturb-position", type=_nonneg_float, default=0.0,
                     help="std of per-camera position offsets from the rig file [m]")
    pss.add_argument("--perturb-rotation", type=_nonneg_float, default=0.0,
                     help="std of per-camera rotation offsets [deg]")
    pss.add_argument("--perturb-focal", type=_nonneg_float, default=0.0,
                     help="std of per-camera relative focal-length offsets")
    pss.add_argument("--specular", type=_nonneg_float, default=0.0,
                     help="strength of a view-dependent (Phong) highlight on every surface: a non-Lambertian "
                          "scene (default 0: Lambertian)")
    pss.add_argument("--sync-spread-ms", type=_nonneg_float, default=0.0, metavar="MS",
                     help="unsynchronised cameras: each captures at its own constant offset from the frame's "
                          "time, uniform in +-MS (seeded), and its image shows that moment (default 0)")
    pss.add_argument("--timestamp-jitter-ms", type=_nonneg_float, default=0.0, metavar="MS",
                     help="Gaussian jitter of this std on each image's timestamp, not on what it shows (a "
                          "driver's varying transfer time; default 0)")
    pss.add_argument("--overwrite", action="store_true", help="replace an existing output")
    pss.set_defaults(func=cmd_synth_session)

    pm = sub.add_parser("motion", help="plenoptic egomotion per frame pair, integrated into a trajectory")
    pm.add_argument("source", metavar="LF.zarr|SESSION",
                    help="light-field store, or a recorded session (resampled on the fly, frame by frame)")
    pm.add_argument("--out", required=True, help="output trajectory TRAJ.tum (T_world_rig per frame)")
    add_source_options(pm, uv_step_default="auto")
    pm.add_argument("--report", metavar="DIR", help="also write per-pair diagnostics (pairs.csv) and plots")
    pm.add_argument("--scale-selection", choices=("on", "off"), default="off",
                    help="pre-smooth (u, v) at the scale where the four depth estimates agree (Sect. 4.1), "
                         "capped by the disparity between views: for grids whose views are far apart for "
                         "the scene; about 1.5x the time per pair (default off; docs/end_to_end.md)")
    pm.add_argument("--calib-draws", type=_nonneg_int, default=0, metavar="N",
                    help="SESSION with a board calibration (mrcal): re-solve every pair with N sets of camera "
                         "models drawn from the calibration's uncertainty, each at +δ and −δ (2N re-solves), and "
                         "add the estimates' spread to each pair's covariance (default 0: the camera models are "
                         "taken as exact; docs/motion.md, \"How far to trust the covariance\")")
    pm.add_argument("--sync-correct", choices=("auto", "off"), default="auto",
                    help="SESSION whose cameras are not synchronised (their images of a frame over 1 ms apart, "
                         "median): solve a second time with every frame resampled with each camera where it "
                         "captured its image, its share of the first pass's motion (auto, the default), or not "
                         "(off; docs/motion.md, \"Unsynchronised cameras\")")
    pm.add_argument("--sync-draws", type=_nonneg_int, default=0, metavar="N",
                    help="with that second pass: re-solve it with N sets of the cameras' capture times (the jitter "
                         "of their timestamps) and the first pass's motion drawn from their uncertainty, each at +δ "
                         "and −δ (2N re-solves), and "
                         "add the estimates' spread to each pair's covariance (default 0; docs/motion.md, "
                         "\"Unsynchronised cameras\")")
    pm.add_argument("--sampling-check", action="store_true",
                    help="SESSION: re-solve every pair on a second view sampling (one more view per camera "
                         "spacing: an array's 2 -> 3, 2.3x the rays) and add the change of each estimate to its "
                         "covariance, "
                         "for the error the views' sampling leaves that the solver's std does not show (the "
                         "example camera arrays' std is within 0.7-1.1x of their errors without it, 0.5-1.0x "
                         "with it; docs/motion.md, \"A second view sampling\")")
    add_solver_options(pm)
    pm.set_defaults(func=cmd_motion)

    pi = sub.add_parser("info", help="summarise a session folder or a light-field store")
    pi.add_argument("path")
    pi.set_defaults(func=cmd_info)

    pd = sub.add_parser("demo", help="the main job on the built-in mock rig, end to end")
    pd.add_argument("--out", default="demo-out", help="output folder (default demo-out)")
    pd.set_defaults(func=cmd_demo)

    # The stages register their own verbs (capture, replay, devices, calibrate, resample).
    # Each STAGE/cli.py defines add_parsers(sub) and imports nothing heavy at module level.
    import importlib

    for modname in STAGE_CLIS:
        try:
            mod = importlib.import_module(modname)
        except ModuleNotFoundError as e:
            if e.name != modname:
                raise
            continue  # stage not built yet
        mod.add_parsers(sub)
    return p


OMP_WAIT_POLICY_DEFAULT = "PASSIVE"
"""OpenMP wait policy the CLI sets unless the environment chooses one: numba's parallel
kernels run on OpenMP, whose threads otherwise spin between parallel regions (~120 per
estimate of benchmarks/bench_motion.py's frame pair). Measured on that pair (session 39,
2 cores): on an idle machine ~8 % more wall time than OpenMP's default (140–143 against
129–135 ms) for ~13 % less CPU (233 against 266–273 ms); with another process loading a core,
35–40 % less wall time (244 against 378–407 ms, median). ``GOMP_SPINCOUNT=10000`` lies between
(131–133 ms idle, 278–284 loaded). The benchmarks run with OpenMP's default."""


def main(argv: list[str] | None = None) -> int:
    # before anything starts the OpenMP runtime (numba loads it at the first parallel kernel)
    os.environ.setdefault("OMP_WAIT_POLICY", OMP_WAIT_POLICY_DEFAULT)
    # before OpenCV loads: its warnings (e.g. "PNG input buffer is incomplete") would be a second line
    # beside polycam's own one-line error about the same file
    os.environ.setdefault("OPENCV_LOG_LEVEL", "ERROR")
    parser = build_parser()
    args = parser.parse_args(argv)
    level = logging.WARNING - 10 * min(args.verbose, 2)
    logging.basicConfig(level=level, format="%(levelname)s %(name)s: %(message)s", stream=sys.stderr)

    from .errors import PolycamError

    try:
        return int(args.func(args) or 0)
    except PolycamError as e:
        print(f"polycam: error: {e}", file=sys.stderr)
        return 1
    except BrokenPipeError:                 # the reader went away (e.g. `polycam info X | head -1`)
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())     # no second error at exit
        return 141
    except OSError as e:
        if e.filename is None:
            raise
        print(f"polycam: error: {e.filename}: {e.strerror}", file=sys.stderr)
        return 1
    except MemoryError as e:                # e.g. a rig or grid file asking for absurd sizes
        what = str(e).split(" for an array")[0] if str(e) else "an allocation failed"
        print(f"polycam: error: out of memory ({what}): check the sizes in the input files "
              "(image sizes, grid counts)", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print("polycam: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
