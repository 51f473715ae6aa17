"""The resampling stage's verb: ``polycam resample SESSION --calib DIR --out LF.zarr [--grid GRID.toml]
[--sync-motion TRAJ.tum]``.

Registered by :func:`add_parsers` (polycam/cli.py discovers this module). Nothing
heavy is imported at module level; the handler imports what it needs after the
user's files have been checked. docs/resample.md documents the options.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from polycam.cliargs import nonneg_int as _nonneg_int
from polycam.cliargs import positive_float as _positive_float
from polycam.cliargs import positive_int as _positive_int

__all__ = ["add_parsers", "cmd_resample"]


def add_parsers(sub) -> None:
    """Add the ``resample`` verb to the ``polycam`` sub-command parsers."""
    p = sub.add_parser("resample", help="push-pull a session's frames onto the two-plane light field",
                       description="Resample every frame of a recorded session onto a two-plane light-field "
                                   "grid (push-pull after Gortler et al. 1996) and write a light-field store "
                                   "with the confidence W. See docs/resample.md.")
    p.add_argument("session", metavar="SESSION", help="recorded session folder")
    p.add_argument("--calib", metavar="CALIB_DIR",
                   help="folder of <camera>.cameramodel files (default: SESSION/calib)")
    p.add_argument("--out", required=True, metavar="LF.zarr", help="output light-field store")
    p.add_argument("--grid", metavar="GRID.toml",
                   help="sample grid (default: chosen from the rig: views at and between the cameras, "
                        "directions over their fields of view)")
    p.add_argument("--uv-step", type=_positive_float, default=None, metavar="PX",
                   help="automatic grid: direction spacing in camera pixels (default 1)")
    p.add_argument("--xy-oversample", type=_positive_int, default=None, metavar="N",
                   help="automatic grid: viewpoints per camera spacing along x and y (default 2: a view at every "
                        "camera and one between neighbouring cameras, filled by --view-fill)")
    p.add_argument("--view-fill", choices=("depth", "pushpull"), default="depth",
                   help="views no camera measured: filled along the disparity of a plane sweep (default) or "
                        "by the pull-push alone (depth-free, several times faster)")
    p.add_argument("--scheduler", metavar="ADDRESS",
                   help="dask.distributed scheduler to use (e.g. tcp://host:8786); default: a local "
                        "cluster of --workers processes (in-process for tiny jobs)")
    p.add_argument("--workers", type=_nonneg_int, default=None, metavar="N",
                   help="local worker processes (default: one per core; 0 = resample in this process)")
    p.add_argument("--sync-motion", metavar="TRAJ.tum",
                   help="cameras that are not synchronised: resample each frame with every camera where it "
                        "captured its image, its share of this trajectory's motion (T_world_rig at the frame "
                        "times, e.g. polycam motion SESSION's output); a splat geometry per frame")
    p.add_argument("--overwrite", action="store_true", help="replace an existing output store")
    p.set_defaults(func=cmd_resample)


def cmd_resample(args: argparse.Namespace) -> int:
    from polycam.cli import _progress
    from polycam.errors import InputError
    from polycam.lightfield import load_grid

    grid = load_grid(args.grid) if args.grid else None   # user files first: fail before heavy work
    session = Path(args.session)
    if not (session / "session.toml").is_file():
        raise InputError(f"{session}: not a session folder (no session.toml)")
    if args.calib is not None and not Path(args.calib).is_dir():
        raise InputError(f"{args.calib}: no such calibration folder")
    if args.grid is not None and (args.uv_step is not None or args.xy_oversample is not None):
        raise InputError("resample: --uv-step and --xy-oversample choose the automatic grid; not with --grid")
    if args.scheduler is not None and args.workers is not None:
        raise InputError("resample: give either --scheduler or --workers, not both")
    capture_motion = None
    source = session
    if args.sync_motion is not None:
        from polycam.geometry import T_inverse
        from polycam.session import open_session
        from polycam.trajectory import poses_at_times, read_tum

        traj = read_tum(args.sync_motion)
        source = open_session(session)              # opened once: resample_session takes it as it is
        try:
            T_world_rig = poses_at_times(traj, source.timestamps_ns)
        except ValueError as e:
            raise InputError(f"{args.sync_motion}: {e}") from None
        capture_motion = T_inverse(T_world_rig[:-1]) @ T_world_rig[1:]          # T_prev_next per pair
    from .pipeline import resample_session
    from .resampler import ResampleOptions

    scheduler = args.scheduler
    if scheduler is None and args.workers == 0:
        scheduler = "sync"
    with _progress(f"resampling {session.name}", None) as advance:   # total: set by the first callback
        s = resample_session(source, args.out, calib_dir=args.calib, grid=grid, uv_step_px=args.uv_step or 1.0,
                             xy_oversample=args.xy_oversample or 2, options=ResampleOptions(view_fill=args.view_fill),
                             scheduler=scheduler, workers=args.workers or None, overwrite=args.overwrite,
                             capture_motion=capture_motion, progress=advance)
    F, Ny, Nx, Nv, Nu = s.grid.shape
    print(f"wrote {s.path}: {s.frames} frames, {F} face(s) ({' '.join(f.name for f in s.grid.faces)}), "
          f"{Ny}x{Nx} views of {Nv}x{Nu} directions"
          + (f", {s.channels} channels" if s.channels > 1 else "")
          + f"; mean confidence W {s.mean_W:.2f}")
    print(f"  {s.cameras} cameras, {s.rays_per_frame / 1e6:.2f} M rays per frame; geometry "
          f"{s.seconds_geometry:.1f} s, frames {s.seconds_frames:.1f} s ({s.scheduler})"
          + (f"; {s.missing_images} missing image(s)" if s.missing_images else "")
          + (f"; {s.empty_frames} empty frame(s)" if s.empty_frames else ""))
    if s.cameras_moved_to_capture:
        print(f"  each frame resampled with every camera where it captured its image (its share of "
              f"{args.sync_motion}'s motion)" + (f"; {s.sync_warning}" if s.sync_warning else
                                                 "; the session's cameras were synchronised already"))
    elif s.sync_warning:
        from polycam.session import SYNC_AS_IF_TOGETHER

        print("  warning: " + s.sync_warning + SYNC_AS_IF_TOGETHER)
    return 0
