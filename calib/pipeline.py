"""``polycam calibrate`` as a library call: session in, calibration folder out.

:func:`calibrate_session` opens a session, runs the board (mrcal) or target-free
(COLMAP) method, writes one ``<cam>.cameramodel`` per camera (rt_cam_ref =
T_cam_rig) and a report into ``out``, and optionally exports (COLMAP rig config,
Kalibr camchain, OpenCV YAML) and a ray table.
"""

from __future__ import annotations

import logging
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

from polycam.board import Board, load_board
from polycam.errors import InputError

__all__ = ["METHODS", "EXPORT_FORMATS", "CalibrationRun", "calibrate_session", "export_calibration"]

log = logging.getLogger(__name__)

METHODS = ("mrcal", "colmap")
EXPORT_FORMATS = ("colmap", "kalibr", "opencv")

Progress = Callable[[int, int], None]


@dataclass
class CalibrationRun:
    """What :func:`calibrate_session` did."""

    out: Path
    models: dict
    """Camera id → mrcal.cameramodel (rt_cam_ref = T_cam_rig)."""
    method: str
    rms_px: float
    """[px] RMS reprojection error (per coordinate)."""
    report: dict = field(default_factory=dict)
    result: object = None
    """The method's own result (:class:`calib.board_solve.BoardCalibration` or
    :class:`calib.colmap.ColmapCalibration`)."""
    files: list[Path] = field(default_factory=list)


def export_calibration(models: dict, out: str | os.PathLike, formats: list[str] | tuple[str, ...]) -> list[Path]:
    """Write the requested exports (:data:`EXPORT_FORMATS`) of ``models`` into ``out``."""
    from . import export

    out = Path(out)
    files = []
    for f in formats:
        if f == "colmap":
            files += export.write_colmap_rig(models, out / "colmap")
        elif f == "kalibr":
            files.append(export.write_kalibr_camchain(models, out / "camchain.yaml"))
        elif f == "opencv":
            files.append(export.write_opencv_yaml(models, out / "opencv.yaml"))
        else:
            raise InputError(f"unknown export format {f!r} (choose from {', '.join(EXPORT_FORMATS)})")
    return files


def calibrate_session(session_path: str | os.PathLike, out: str | os.PathLike, *, board: Board | str | None = None,
                      method: str = "mrcal", lensmodel: str = "opencv8", min_corners: int = 8,
                      board_warp: bool = True, plots: bool = True, uncertainty: bool = True,
                      exports: tuple[str, ...] = (), rays: bool = False, overwrite: bool = False,
                      colmap_options: dict | None = None, progress: Progress | None = None) -> CalibrationRun:
    """Calibrate every camera of a session into ``out`` (see the module docstring).

    board: a Board or a BOARD.toml path; required for ``method="mrcal"``; for
        ``"colmap"`` optional (then it fixes metric scale instead of the rig file).
    lensmodel: mrcal lens model for the board path (:data:`calib.board_solve.LENSMODEL_CHOICES`).
    min_corners: smallest partial ChArUco view kept.
    colmap_options: keyword arguments for :func:`calib.colmap.calibrate_colmap`.
    """
    from polycam.session import open_session

    from .io import prepare_output_dir, write_corners_vnl, write_models

    if method not in METHODS:
        raise InputError(f"unknown calibration method {method!r} (choose from {', '.join(METHODS)})")
    if isinstance(board, (str, os.PathLike)):
        board = load_board(board)
    if method == "mrcal" and board is None:
        raise InputError("the mrcal (board) method needs a board file (--board BOARD.toml)")
    session = open_session(session_path)
    created = not Path(out).exists()
    out = prepare_output_dir(out, overwrite=overwrite)
    try:
        if method == "mrcal":
            from .board_solve import calibrate_board
            from .detect import detect_session

            obs = detect_session(session, board, min_corners=min_corners, progress=progress)
            cal = calibrate_board(obs, session.rig, lensmodel=lensmodel, board_warp=board_warp)
        else:
            from .colmap import calibrate_colmap

            cal = calibrate_colmap(session, board=board, **(colmap_options or {}))
    except BaseException:
        if created and out.is_dir() and not any(out.iterdir()):    # a failed calibration leaves no empty folder
            out.rmdir()
        raise
    if method == "mrcal":
        from .report import write_report

        files = write_models(cal.models, out)
        files.append(write_corners_vnl(out / "corners.vnl", cal.observations.observations,
                                       cal.observations.paths))
        report = write_report(cal, out, plots=plots, uncertainty=uncertainty)
        files += [out / "report.toml", out / "report.md"]
        run = CalibrationRun(out=out, models=cal.models, method=method, rms_px=cal.rms_px, report=report,
                             result=cal, files=files)
    else:
        from .colmap import write_colmap_report

        files = write_models(cal.models, out)
        report = write_colmap_report(cal, out)
        files += [out / "report.toml", out / "report.md"]
        run = CalibrationRun(out=out, models=cal.models, method=method, rms_px=cal.rms_px, report=report,
                             result=cal, files=files)
    if exports:
        run.files += export_calibration(run.models, out, exports)
    if rays:
        from .rays import write_ray_table

        run.files += write_ray_table(run.models, out / "rays")
    return run
