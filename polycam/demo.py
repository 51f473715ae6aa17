"""The main job on the built-in mock rig, end to end (``polycam demo``, ``make demo``).

The demo is :func:`polycam.run.run_chain` on ``rigs/mock5x5.toml`` (a 5x5 array of
320x240 grey cameras, 2 cm apart, in a textured room), with exact ground truth:

1. a calibration-board session of the (slightly perturbed) true rig, recorded through
   the capture stage from the mock driver showing the board;
2. mrcal board calibration (the calibration stage);
3. a motion session of the same rig, recorded the same way, with its ground truth;
4. resampling onto the two-plane light field (views at the cameras) with the
   *calibrated* models;
5. plenoptic egomotion of every frame pair, compared with the ground truth;
6. per-ray depth, compared with the ray tracer's true depth, and a point cloud;
7. a report folder (``OUT/report``) with every picture.

Like :mod:`polycam.run` (which imports the stages lazily), this is CLI-layer
orchestration. It reports through ``echo`` (the CLI passes ``print``) and a
progress-bar factory, and logs nothing else.
"""

from __future__ import annotations

from pathlib import Path
from typing import Callable

__all__ = ["DEFAULT_RIG", "run_demo"]

DEFAULT_RIG = Path(__file__).resolve().parents[1] / "rigs" / "mock5x5.toml"


def run_demo(out: Path, *, rig_path: Path = DEFAULT_RIG, frames: int = 5, board_frames: int = 25,
             progress_factory: Callable | None = None, echo: Callable[[str], None] = lambda s: None) -> dict:
    """Run the demo into folder ``out``; returns the chain's summary dict (also echoed)."""
    from .errors import InputError
    from .run import RunOptions, run_chain

    if not Path(rig_path).is_file():
        raise InputError(f"{rig_path}: the default mock rig file is missing (run from a polycam checkout)")
    out = Path(out)
    summary = run_chain(rig_path, out, options=RunOptions(frames=frames, board_frames=board_frames),
                        progress_factory=progress_factory, echo=echo)
    echo(f"compare   evo_ape tum {out / 'session' / 'groundtruth.tum'} {out / 'trajectory.tum'}")
    return summary
