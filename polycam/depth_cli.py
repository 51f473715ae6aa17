"""The ``polycam depth`` verb: per-ray depth of one frame pair (paper Eq. 6–7) written as
per-view depth maps and a PLY point cloud (docs/depth.md; files: docs/formats.md,
"Depth output").

Registered through polycam/cli.py's STAGE_CLIS; imports nothing heavy at module level.
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

from .cliargs import check_output_folder
from .cliargs import nonneg_int as _nonneg_int
from .cliargs import positive_float as _positive_float
from .cliargs import positive_int as _positive_int
from .motion_options import PRESETS, options_from_strings

__all__ = ["add_parsers", "add_source_options", "cmd_depth", "open_source", "pair_motion_from_trajectory",
           "uv_step_arg", "uv_step_line", "uv_step_reason", "denser_views_reason", "add_solver_options",
           "solver_options"]


def uv_step_arg(text: str) -> float | None:
    """``--uv-step``: ``auto`` (None) or a positive number of camera pixels."""
    if text == "auto":
        return None
    try:
        return _positive_float(text)
    except argparse.ArgumentTypeError as e:
        raise argparse.ArgumentTypeError(f"{e} (or auto)") from None


def add_source_options(p: argparse.ArgumentParser, uv_step_default: str = "1") -> None:
    """``--calib``, ``--uv-step`` and ``--xy-oversample``: how a SESSION source is resampled on
    the fly (see :func:`open_source`); shared by the verbs that read a store or a session.
    ``uv_step_default``: ``--uv-step``'s default (``auto`` or a number of pixels)."""
    p.add_argument("--calib", metavar="CALIB_DIR",
                   help="sessions: folder of <camera>.cameramodel files (default: SESSION/calib)")
    p.add_argument("--uv-step", type=uv_step_arg, default=uv_step_arg(uv_step_default), metavar="PX|auto",
                   help="sessions: direction spacing of the automatic grid in camera pixels, or auto: 1, or 2 "
                        "where the views are more than 0.6 of a 1-pixel sample apart for the scene (docs/motion.md, "
                        f"\"The direction step\"; default {uv_step_default})")
    p.add_argument("--xy-oversample", type=_positive_int, default=None, metavar="N",
                   help="sessions: viewpoints of the automatic grid per camera spacing (default: 2, one "
                        "between neighbouring cameras, or 4 where 2 gives fewer than 5 views along x or y, "
                        "as polycam run: a row of cameras, a stereo pair; with --uv-step auto 3 on a 2-D array "
                        "whose views are over 0.6 samples apart at 2, docs/motion.md \"The direction step\")")


def add_solver_options(p: argparse.ArgumentParser) -> None:
    """``--preset NAME`` and ``--option KEY=VALUE``: the motion solver's MotionOptions
    (:data:`polycam.motion_options.PRESETS`, :func:`polycam.motion_options.options_from_strings`);
    shared by the verbs that estimate motion. :func:`solver_options` reads them."""
    p.add_argument("--preset", choices=sorted(PRESETS), default="default",
                   help="a named set of solver options: default (tuned for 8-bit cameras in good light) or "
                        "noisy (light fields with a grey level of noise or more, independent per sample; not resampled "
                        "sessions; docs/motion.md, \"Noise\")")
    p.add_argument("--option", action="append", default=[], metavar="KEY=VALUE",
                   help="a motion solver setting (a MotionOptions field; repeatable), on top of --preset, "
                        "e.g. --option levels=2")


def solver_options(args: argparse.Namespace):
    """The :class:`~polycam.motion_options.MotionOptions` of ``--preset`` and ``--option``
    (:class:`~polycam.errors.InputError`, one line, for a bad item)."""
    return options_from_strings(args.option, PRESETS[args.preset])


def add_parsers(sub) -> None:
    """Add the ``depth`` verb."""
    p = sub.add_parser("depth", help="depth of a frame pair (Eq. 6-7): per-view depth maps and a PLY point cloud",
                       description="Estimate the motion of frames (I, I+1) (or take it from --traj), compute "
                                   "the depth of every ray (differential stereo and motion, fused, with a "
                                   "confidence) and write per-view depth maps (PFM float32 and 16-bit PNG in "
                                   "mm) and a PLY point cloud in the rig frame of frame I (--stereo-only: frame "
                                   "I alone, from the stereo estimates). See docs/depth.md.")
    p.add_argument("source", metavar="LF.zarr|SESSION",
                   help="light-field store, or a recorded session (resampled on the fly)")
    p.add_argument("--out", required=True, metavar="DIR", help="output folder")
    p.add_argument("--frame", type=_nonneg_int, default=0, metavar="I", help="first frame of the pair (default 0)")
    motion_group = p.add_mutually_exclusive_group()
    motion_group.add_argument("--traj", metavar="TRAJ.tum",
                              help="take the pair's motion from this trajectory (T_world_rig) instead of "
                                   "estimating it")
    motion_group.add_argument("--stereo-only", action="store_true",
                              help="depth of frame I alone from its two differential-stereo estimates (paper "
                                   "Eq. 6: across the viewpoints, no motion): a light field of one frame, or a "
                                   "static scene")
    p.add_argument("--sync-correct", choices=("auto", "off"), default="auto",
                   help="SESSION whose cameras are not synchronised: resample the pair again with each camera "
                        "where it captured its image, its share of the motion (auto, the default), or take the "
                        "images as captured together (off); docs/motion.md, \"Unsynchronised cameras\"")
    p.add_argument("--views", choices=("central", "all"), default="central",
                   help="write maps (and points) for the central view of each face or all views (default central)")
    p.add_argument("--scale-selection", choices=("auto", "off", "face", "region"), default="auto",
                   help="choose the derivative scales per face (or per (u, v) region) where the four depth "
                        "estimates agree (Sect. 4.1): about 2x lower depth error at 4-16 m, but smoothing across "
                        "viewpoints leaves only the inner views with depth; auto (default) = face with "
                        "--views central, off with --views all (docs/depth.md)")
    p.add_argument("--refine", choices=("auto", "on", "off"), default="auto",
                   help="refine the depth by matching the views that hold captured data (iterated multi-view "
                        "stereo; polycam.depth_refine): auto (default) = on where the source records its cameras "
                        "(a resampled session: the camera views; also gives a stereo pair depth), on = also on "
                        "other stores (every view is then a source), off = Eq. 7 alone (docs/depth.md)")
    keep = p.add_mutually_exclusive_group()
    keep.add_argument("--keep", type=_positive_float, default=0.5, metavar="FRAC",
                      help="keep the most confident FRAC of the rays (default 0.5)")
    keep.add_argument("--max-std", type=_positive_float, default=None, metavar="REL",
                      help="instead, keep the rays whose depth's predicted relative standard deviation "
                           "(1 / sqrt(confidence)) is at most REL, e.g. 0.05 (docs/depth.md)")
    add_source_options(p)
    add_solver_options(p)
    p.add_argument("--ascii-ply", action="store_true", help="write an ASCII PLY (default binary little-endian)")
    p.set_defaults(func=cmd_depth)


def open_source(source: str | Path, *, calib: str | None = None, uv_step: float | None = 1.0,
                xy_oversample: int | None = None):
    """A light-field store, or a session resampled on the fly (resample.stream.SessionLightField,
    on the automatic grid of ``uv_step`` camera pixels (None: :func:`polycam.run.choose_uv_step`'s
    rule, ``--uv-step auto``) and ``xy_oversample`` viewpoints per camera spacing (None:
    :func:`polycam.run.session_grid`'s rule, as ``polycam run``): anything with ``grid``,
    ``timestamps_ns``, ``frame(i)``, ``weights(i)``, ``groundtruth()``; a session's also has
    ``uv_step_px``, ``uv_disparity`` (the auto rule's measure, NaN when not used) and
    ``xy_oversample`` (the views per camera spacing the grid has)."""
    from .errors import InputError

    src = Path(source)
    if (src / "session.toml").exists():
        if calib is not None and not Path(calib).is_dir():
            raise InputError(f"{calib}: no such calibration folder")
        from resample.pipeline import open_calibration   # the CLI layer may import stages
        from resample.stream import SessionLightField

        from .run import choose_uv_step, session_grid
        from .session import open_session

        session = open_session(src)
        if len(session) == 0:
            raise InputError(f"{session.path}: the session has no frames")
        models = open_calibration(session, calib)
        store, disparity = None, math.nan
        if uv_step is None:
            uv_step, disparity, store = choose_uv_step(session, models, xy_oversample)
        if store is None:
            grid, every = session_grid(models, uv_step, xy_oversample)
            store = SessionLightField(session, models=models, grid=grid)     # (opened and validated once)
            store.xy_oversample = every
        store.uv_step_px, store.uv_disparity = float(uv_step), disparity
        return store
    if calib is not None:
        raise InputError(f"{src}: --calib applies to sessions only (a light-field store is already resampled)")
    if not src.exists():
        raise InputError(f"{src}: no such light-field store or session")
    if src.is_dir() and not (src / "zarr.json").exists():
        raise InputError(f"{src}: neither a session (no session.toml) nor a light-field store (no zarr.json)")
    from .lfstore import open_lightfield

    return open_lightfield(src)


def uv_step_reason(disparity: float) -> str:
    """``--uv-step auto: ...``: what the rule chose its step by (``disparity`` [samples per view step],
    NaN: not measurable)."""
    return ("--uv-step auto: " + (f"{disparity:.2f} samples per view step" if math.isfinite(disparity)
                                  else "disparity not measurable: the finest step"))


def denser_views_reason() -> str:
    """Why ``--uv-step auto`` gave a 2-D array more views per camera spacing
    (:data:`polycam.run.AUTO_XY_MAX_DISPARITY`)."""
    from .run import AUTO_XY_MAX_DISPARITY

    return f"over {AUTO_XY_MAX_DISPARITY:g} samples per view step with 2"


def uv_step_line(store) -> str:
    """One line on the direction step ``--uv-step auto`` chose for a session ``store`` (:func:`open_source`),
    and on the views per camera spacing when the rule made them denser."""
    denser = (f"; {store.xy_oversample} views per camera spacing ({denser_views_reason()})"
              if getattr(store, "denser_views", False) else "")
    return f"directions every {store.uv_step_px:g} camera pixel(s) ({uv_step_reason(store.uv_disparity)}{denser})"


def pair_motion_from_trajectory(path: str | Path, t0_ns: int, t1_ns: int, trajectory=None):
    """(4, 4) ``T_rig0_rig1`` between the poses of a TUM trajectory at two frame times
    (each matched within :data:`polycam.trajectory.MATCH_TOLERANCE_NS`); ``trajectory``: the file's
    :class:`~polycam.trajectory.Trajectory` when already read (``path`` then names it in errors)."""
    from .errors import InputError
    from .geometry import T_inverse
    from .trajectory import poses_at_times, read_tum

    try:
        T0, T1 = poses_at_times(trajectory if trajectory is not None else read_tum(path), [t0_ns, t1_ns])
    except ValueError as e:
        raise InputError(f"{path}: {e}") from None
    return T_inverse(T0) @ T1


def cmd_depth(args: argparse.Namespace) -> int:
    import numpy as np

    from .depth import MIN_W, NO_CAPTURED_DATA, confident_mask, depth_of_pair, grey_frame, view_mask
    from .depth_io import write_depth_folder
    from .errors import InputError
    from .lightfield import finite_frame
    from .motion_options import changed_options
    from .motion_weights import frame_noise_variance
    from .motion import estimate_motion
    from .session import SYNC_AS_IF_TOGETHER, sync_warning

    opts = solver_options(args)                       # before anything is read or written
    check_output_folder(args.out, "--out")
    src = Path(args.source)
    store = open_source(src, calib=args.calib, uv_step=args.uv_step, xy_oversample=args.xy_oversample)
    if args.uv_step is None and hasattr(store, "uv_disparity"):
        print(uv_step_line(store))
    n = len(store.timestamps_ns)
    i = args.frame
    stereo = args.stereo_only
    j = i if stereo else i + 1                         # the pair's second frame (itself: stereo only)
    if n < 2 and not stereo:
        raise InputError(f"{src}: has {n} frame(s); depth needs a frame pair (at least 2), or --stereo-only "
                         "for one frame's stereo depth")
    if j > n - 1:
        raise InputError(f"{src}: --frame {i} needs frame{'' if stereo else f's {i} and'} {j}, but there are {n} "
                         f"(0..{n - 1})")
    if not args.keep <= 1.0:
        raise InputError(f"--keep must be in (0, 1], got {args.keep}")
    grid = store.grid
    ts = np.asarray(store.timestamps_ns, np.int64)
    get_w = getattr(store, "weights", None)
    # the pair's motion against the ground truth (not with --traj or --stereo-only): read before the work
    truth = store.groundtruth() if hasattr(store, "groundtruth") and not (args.traj or stereo) else None

    def read(t):       # (L, W) of frame t: a session resampled on the fly keeps its last frame, so read each once
        W = get_w(t) if get_w else None
        # NaNs where W is not 0 are an error (also with --traj, where no solver would see them)
        return finite_frame(f"frame {t}", store.frame(t), W, who=str(src)), W

    L0, W0 = read(i)
    L1, W1 = (L0, W0) if stereo else read(j)
    if stereo:                     # Eq. 7's stereo estimates only (depth_of_pair without a motion)
        M = None
        motion = {"motion_source": "none (stereo only)"}
    elif args.traj:
        from .trajectory import read_tum

        given = read_tum(args.traj)                 # read once: the pairs around i may need it again
        M = pair_motion_from_trajectory(args.traj, int(ts[i]), int(ts[i + 1]), given)
        motion = {"motion_source": str(args.traj)}
    else:
        res = estimate_motion(L0, L1, grid, W0=W0, W1=W1, index=i, options=opts)
        if not res:
            raise InputError(f"{src}: motion of frames {i}, {i + 1} failed ({res.reason}); "
                             "give it with --traj")
        M = res.T_prev_next
        motion = {"motion_source": "estimated", "motion_condition": float(res.condition)}
        changed = changed_options(opts)
        if changed:
            motion["motion_options"] = changed
    unsync = sync_warning(store.session) if hasattr(store, "session") else ""
    correct = bool(unsync) and not stereo and args.sync_correct == "auto"
    if correct:
        # unsynchronised cameras: the pair resampled again with each camera where it captured its image, its
        # share of the motion to the neighbouring frame (the pairs before and after too: their own motion,
        # estimated or from --traj), and its motion estimated again
        from resample.stream import SessionLightField   # the CLI layer may import stages

        capture = np.repeat(M[None], n - 1, axis=0)
        for p in (i - 1, i + 1):
            if 0 <= p < n - 1:
                if args.traj:
                    capture[p] = pair_motion_from_trajectory(args.traj, int(ts[p]), int(ts[p + 1]), given)
                else:
                    (La, Wa), (Lb, Wb) = read(p), read(p + 1)
                    near = estimate_motion(La, Lb, grid, W0=Wa, W1=Wb, index=p, options=opts)
                    if near:
                        capture[p] = near.T_prev_next
        store = SessionLightField(store.session, models=store.models, grid=grid, options=store.options,
                                  camera_noise=False, capture_motion=capture)
        get_w = store.weights
        (L0, W0), (L1, W1) = read(i), read(j)
        if not args.traj:
            res = estimate_motion(L0, L1, grid, W0=W0, W1=W1, index=i, options=opts)
            if res:
                M = res.T_prev_next
                motion["motion_condition"] = float(res.condition)
        motion["cameras_moved_to_capture"] = True
    mode = args.scale_selection
    if mode == "auto":
        mode = "face" if args.views == "central" else "off"
    g0, g1 = grey_frame(L0), grey_frame(L1)
    # the sensor noise, whose energy the depth fusion takes out (docs/depth.md)
    noise_var = frame_noise_variance(g0, g1, grid, W0, W1)
    if mode == "off":
        dm = depth_of_pair(g0, g1, grid, M, noise_var=noise_var)
        scale_info = {}
    else:
        from .scales import depth_scale_selected

        eqs = ("stereo_x", "stereo_y") if stereo else ("stereo_x", "stereo_y", "motion_pos")
        dm, sel = depth_scale_selected(g0, g1, grid, M, per=mode, W0=W0, noise_var=noise_var, equations=eqs)
        scale_info = {"face_scales": [s.name for s in sel.face_scales()]}
    views = view_mask(grid, 1 if args.views == "central" else None)
    positions = getattr(store, "camera_positions", None)
    refine = args.refine == "on" or (args.refine == "auto" and positions is not None)
    sources = 0
    if refine:
        from .depth_refine import grid_positions, refine_depth

        if positions is None:                      # every view holds data (e.g. a rendered light field)
            positions = grid_positions(grid, np.ones(grid.shape[:3], bool))
        from .cli import _progress

        with _progress(f"refining the depth of {int(views.sum())} view(s)", int(views.sum())) as advance:
            dm = refine_depth(g0, grid, dm.Z, sources=positions, targets=views, W=W0, noise_var=noise_var,
                              progress=advance)
        sources = int(np.isfinite(positions[..., 0]).sum())
    # refined depth comes from the sources' data: the written views' own W does not matter
    mask = confident_mask(dm, keep=args.keep, W=None if refine else W0, max_rel_std=args.max_std)
    L0a = np.asarray(L0, np.float32)
    meta = {"source": str(src), "frame": i, "frame_next": j, "timestamp_ns": int(ts[i]),
            "timestamp_next_ns": int(ts[j]), "T_prev_next": np.asarray(np.eye(4) if M is None else M, float).tolist(),
            **({"keep": float(args.keep)} if args.max_std is None else {"max_rel_std": float(args.max_std)}),
            "scale_selection": mode, "sensor_noise_sigma": float(np.sqrt(noise_var)), "refined_on_views": sources,
            **motion, **scale_info}
    camera_noise = float(getattr(store, "camera_noise_sigma", math.nan))   # a session, or a store that records it
    if math.isfinite(camera_noise):
        meta["camera_noise_sigma"] = camera_noise
    summary = write_depth_folder(args.out, grid, dm, intensity=L0a, mask=mask, views=views, meta=meta,
                                 binary_ply=not args.ascii_ply)
    out = Path(args.out)
    if summary["points"]:
        kept = f"kept, median depth {summary['median_depth_m']:.2f} m"
    else:                                  # say why, and what would keep some
        best = float(np.max(dm.confidence[views], initial=0.0))
        no_data = not refine and W0 is not None and not np.any(np.asarray(W0)[views] > MIN_W)
        kept = ("kept: no ray with a depth" if best <= 0 else
                f"kept: the written views {NO_CAPTURED_DATA}; --refine on matches the views that hold data" if no_data else
                f"kept: the best ray's predicted relative std is {100 / np.sqrt(best):.2g} %")
    print(f"wrote {out}: {summary['views']} view depth maps, {summary['points']} points in "
          f"{out / 'points.ply'}; {100 * summary['confident_fraction']:.0f}% of the written views' rays "
          f"{kept} (motion: {motion['motion_source']})")
    if truth is not None:
        from .evaluate import pair_errors
        from .trajectory import Trajectory

        est = Trajectory.from_relative(ts[i:i + 2], M[None])
        sub = Trajectory(ts[i:i + 2], truth.T_world_rig[i:i + 2]) if len(truth) == n else None
        if sub is not None:
            err = pair_errors(est, sub)
            print(f"  motion vs groundtruth: translation {100 * float(err.t_rel[0]):.2f}%, "
                  f"rotation {100 * float(err.w_rel[0]):.2f}%")
    if unsync:
        print("  warning: " + unsync + (SYNC_AS_IF_TOGETHER if not correct else
                                        "; the pair was resampled again with each camera where it captured its "
                                        "image (docs/motion.md, \"Unsynchronised cameras\")"))
    return 0
