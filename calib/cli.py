"""``polycam calibrate``: registered by polycam/cli.py's stage discovery.

Nothing heavy is imported here at module level, so ``polycam --help`` stays instant.
"""

from __future__ import annotations

import argparse

from polycam.cliargs import number

__all__ = ["add_parsers", "cmd_calibrate"]

_LENSMODELS = ("opencv4", "opencv5", "opencv8", "splined")
_EXPORTS = ("colmap", "kalibr", "opencv")


def _exports(text: str) -> list[str]:
    names = [n.strip() for n in text.split(",") if n.strip()]
    bad = [n for n in names if n not in _EXPORTS]
    if not names or bad:
        raise argparse.ArgumentTypeError(f"expected a comma-separated list of {', '.join(_EXPORTS)}, got {text!r}")
    return names


def add_parsers(sub) -> None:
    p = sub.add_parser(
        "calibrate", help="board (mrcal) or target-free (COLMAP) calibration into rig-frame cameramodels",
        description="Calibrate every camera of a session: one mrcal .cameramodel per camera "
                    "(rt_cam_ref = T_cam_rig) plus report.toml / report.md / plots in --out. "
                    "See docs/calibration.md.")
    p.add_argument("session", nargs="?", help="session folder (omit with --from-colmap)")
    p.add_argument("--board", help="BOARD.toml (required for --method mrcal; with colmap it fixes metric scale)")
    p.add_argument("--out", required=True, help="output calibration folder CALIB_DIR")
    p.add_argument("--method", choices=("mrcal", "colmap"), default="mrcal",
                   help="mrcal: board calibration (default); colmap: target-free structure from motion")
    p.add_argument("--lensmodel", default="opencv8",
                   help=f"mrcal lens model: {', '.join(_LENSMODELS)} or a full LENSMODEL_... name "
                        "(default opencv8)")
    p.add_argument("--min-corners", type=number(int, 6, why="PnP needs 6 corners"), default=8,
                   help="smallest partial ChArUco view kept (default 8)")
    p.add_argument("--no-board-warp", action="store_true", help="assume a perfectly flat board")
    p.add_argument("--no-plots", action="store_true", help="skip the report's plots")
    p.add_argument("--no-uncertainty", action="store_true", help="skip projection-uncertainty maps (faster)")
    p.add_argument("--export", type=_exports, default=[],
                   help="also write colmap (rig_config.json + text model), kalibr (camchain.yaml) and/or "
                        "opencv (opencv.yaml), comma-separated")
    p.add_argument("--rays", action="store_true", help="also write the per-pixel ray table CALIB_DIR/rays/")
    p.add_argument("--from-colmap", metavar="MODEL_DIR",
                   help="import an existing COLMAP text model (cameras.txt, images.txt) instead of solving")
    p.add_argument("--max-image-size", type=int, default=1600,
                   help="colmap: downscale images for feature extraction to at most this size (default 1600)")
    p.add_argument("--overwrite", action="store_true", help="replace an existing calibration folder")
    p.set_defaults(func=cmd_calibrate)


def cmd_calibrate(args: argparse.Namespace) -> int:
    from polycam.errors import InputError

    if args.from_colmap:
        from .colmap_text import import_colmap_text
        from .io import prepare_output_dir, write_models

        models = import_colmap_text(args.from_colmap)
        out = prepare_output_dir(args.out, overwrite=args.overwrite)
        named = {_safe_name(k): m for k, m in models.items()}
        write_models(named, out)
        if args.export:
            from .pipeline import export_calibration

            export_calibration(named, out, args.export)
        if args.rays:
            from .rays import write_ray_table

            write_ray_table(named, out / "rays")
        print(f"imported {len(named)} cameras from {args.from_colmap} into {out}")
        return 0
    if not args.session:
        raise InputError("calibrate: give a SESSION folder (or --from-colmap MODEL_DIR)")
    board = None
    if args.board:
        from polycam.board import load_board

        board = load_board(args.board)        # user files first: fail before heavy work
    elif args.method == "mrcal":
        raise InputError("calibrate: --board BOARD.toml is required for --method mrcal")
    from polycam.cli import _progress

    from .pipeline import calibrate_session

    with _progress(f"calibrating {args.session}", None) as advance:
        run = calibrate_session(args.session, args.out, board=board, method=args.method,
                                lensmodel=args.lensmodel, min_corners=args.min_corners,
                                board_warp=not args.no_board_warp, plots=not args.no_plots,
                                uncertainty=not args.no_uncertainty, exports=tuple(args.export),
                                rays=args.rays, overwrite=args.overwrite,
                                colmap_options={"max_image_size": args.max_image_size}, progress=advance)
    print(f"calibrated {len(run.models)} cameras ({run.method}): RMS {run.rms_px:.3f} px; "
          f"models and report in {run.out}")
    return 0


def _safe_name(name: str) -> str:
    """A COLMAP image name as a file stem: path separators and spaces become '_', extension dropped."""
    stem = name.rsplit(".", 1)[0] if "." in name else name
    return "".join(ch if ch.isalnum() or ch in "-_." else "_" for ch in stem)
