"""Calibration folders: one mrcal ``<cam>.cameramodel`` per camera (rt_cam_ref = T_cam_rig)
plus the report, written so that no file is ever half-written.

``CALIB_DIR`` layout (docs/calibration.md)::

    CALIB_DIR/
      cam00.cameramodel ...   mrcal cameramodels (board path: with optimization_inputs)
      corners.vnl             board path: the detections, mrcal's corners vnlog
                              ("# filename x y weight", "-" for unseen corners)
      report.toml, report.md, plots/
"""

from __future__ import annotations

import logging
import os
from pathlib import Path

import numpy as np

from polycam.cameras import load_cameramodel, write_cameramodel
from polycam.errors import FormatError, InputError
from polycam.tomlio import atomic_write_text

__all__ = ["prepare_output_dir", "write_cameramodel", "write_models", "load_models", "write_corners_vnl"]

log = logging.getLogger(__name__)

_OWN = {".cameramodel", ".vnl", ".toml", ".md", ".yaml", ".json", ".txt", ".npz", ".png"}


def prepare_output_dir(path: str | os.PathLike, *, overwrite: bool = False) -> Path:
    """Create ``path`` for a calibration; an existing non-empty folder needs ``overwrite``
    and must look like a calibration folder (only files polycam writes there)."""
    p = Path(path)
    if p.exists():
        if not p.is_dir():
            raise InputError(f"{p}: exists and is not a folder")
        entries = list(p.iterdir())
        if entries and not overwrite:
            raise InputError(f"{p}: folder exists and is not empty (choose a new folder or pass --overwrite)")
        strange = [e.name for e in entries if e.is_file() and e.suffix not in _OWN]
        if strange:
            raise InputError(f"{p}: refusing to write into a folder holding {strange[0]!r} (not a calibration)")
    p.mkdir(parents=True, exist_ok=True)
    return p


def write_models(models: dict, out: str | os.PathLike) -> list[Path]:
    """Write ``<cam>.cameramodel`` for every camera id → model; returns the paths."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    return [write_cameramodel(m, out / f"{cam}.cameramodel") for cam, m in models.items()]


def load_models(path: str | os.PathLike, cameras: list[str] | None = None) -> dict:
    """Camera id → mrcal cameramodel from a calibration folder (default: every ``*.cameramodel``)."""
    d = Path(path)
    if not d.is_dir():
        raise FormatError(d, "no such calibration folder")
    if cameras is None:
        cameras = sorted(p.stem for p in d.glob("*.cameramodel") if not p.name.startswith("."))
        if not cameras:
            raise FormatError(d, "no .cameramodel files in the calibration folder")
    return {c: load_cameramodel(d / f"{c}.cameramodel") for c in cameras}


def write_corners_vnl(path: str | os.PathLike, observations: np.ndarray, paths: list[str]) -> Path:
    """mrcal's corners cache: one ``filename x y weight`` row per corner (``- -`` when unseen).

    observations: (N, H, W, 3) mrcal board observations; paths: (N,) image files.
    """
    lines = ["# filename x y weight"]
    for obs, p in zip(observations, paths):
        for x, y, w in obs.reshape(-1, 3):
            lines.append(f"{p} - - -" if w <= 0 else f"{p} {x:.4f} {y:.4f} {w:g}")
    atomic_write_text(path, "\n".join(lines) + "\n")
    return Path(path)
