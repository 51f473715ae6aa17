"""The main job on the built-in mock rig, end to end (``polycam demo``, ``make demo``).

Runs what the project has, on synthetic data with exact ground truth:

1. a camera-array session of the default 5x5 mock rig (``rigs/mock5x5.toml``)
   moving through the textured room, with its true calibration;
2. a six-face light-field sequence of the paper's sphere scene (rendered
   straight onto the two-plane grid: the resampling stage will produce it from
   the session once it lands);
3. the plenoptic egomotion of every frame pair, integrated into a TUM
   trajectory and compared with the ground truth.

Library code: it reports through ``echo`` (the CLI passes ``print``) and a
progress-bar factory, and logs nothing else.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Callable

import numpy as np

__all__ = ["DEFAULT_RIG", "run_demo"]

DEFAULT_RIG = Path(__file__).resolve().parents[1] / "rigs" / "mock5x5.toml"


def run_demo(out: Path, *, rig_path: Path = DEFAULT_RIG, frames: int = 5,
             progress_factory: Callable | None = None, echo: Callable[[str], None] = lambda s: None) -> dict:
    """Run the demo into folder ``out``; returns a summary dict (also echoed)."""
    from contextlib import nullcontext

    from .errors import InputError
    from .evaluate import ate_rmse, pair_errors
    from .lfstore import open_lightfield
    from .motion import estimate_trajectory
    from .motion_report import write_motion_report
    from .rig import load_rig
    from .session import open_session
    from .synth import default_lightfield_grid, synth_lightfield, synth_session
    from .trajectory import write_tum

    def bar(desc: str, total: int):
        return progress_factory(desc, total) if progress_factory else nullcontext(None)

    if not rig_path.is_file():
        raise InputError(f"{rig_path}: the default mock rig file is missing (run from a polycam checkout)")
    out.mkdir(parents=True, exist_ok=True)
    summary: dict = {}

    rig = load_rig(rig_path)
    t0 = time.perf_counter()
    with bar(f"1/3 session ({len(rig.cameras)} cameras)", frames) as adv:
        synth_session(rig, out / "session", frames=frames, overwrite=True, progress=adv)
    s = open_session(out / "session")
    summary["session"] = {"cameras": len(s.cameras), "frames": len(s), "seconds": time.perf_counter() - t0}
    echo(f"session   {out / 'session'}: {len(s.cameras)} cameras x {len(s)} frames of "
         f"{rig.cameras[0].width}x{rig.cameras[0].height} ({summary['session']['seconds']:.1f} s), "
         f"true calibration in calib/")

    grid = default_lightfield_grid("all")
    t0 = time.perf_counter()
    with bar("2/3 light field (6 faces)", frames) as adv:
        synth_lightfield(out / "lightfield.zarr", grid=grid, scene="spheres", distance=6.0, frames=frames,
                         seed=1, overwrite=True, progress=adv)
    lf = open_lightfield(out / "lightfield.zarr")
    F, Ny, Nx, Nv, Nu = lf.grid.shape
    summary["lightfield"] = {"rays_per_frame": lf.grid.num_rays, "seconds": time.perf_counter() - t0}
    echo(f"light field {out / 'lightfield.zarr'}: {F} faces x {Ny}x{Nx} views x {Nv}x{Nu} directions "
         f"= {lf.grid.num_rays / 1e6:.1f} M rays/frame ({summary['lightfield']['seconds']:.1f} s)")

    t0 = time.perf_counter()
    with bar("3/3 plenoptic motion", len(lf) - 1) as adv:
        traj, results = estimate_trajectory(lf, progress=adv)
    seconds = time.perf_counter() - t0
    write_tum(out / "trajectory.tum", traj)
    written = write_motion_report(out / "report", results, traj, lf.groundtruth(), lf.timestamps_ns)
    err = pair_errors(traj, lf.groundtruth())
    summary["motion"] = {
        "pairs": len(results), "failed": sum(1 for r in results if not r),
        "median_t_rel": float(np.median(err.t_rel)), "median_w_rel": float(np.median(err.w_rel)),
        "ate_m": ate_rmse(traj, lf.groundtruth()), "seconds_per_pair": seconds / max(len(results), 1),
    }
    m = summary["motion"]
    echo(f"motion    {out / 'trajectory.tum'}: {m['pairs']} frame pairs, {m['failed']} failed, "
         f"{m['seconds_per_pair']:.2f} s per pair")
    echo(f"          median error per pair: translation {100 * m['median_t_rel']:.2f}% of "
         f"{1000 * float(np.median(err.t_true)):.1f} mm, rotation {100 * m['median_w_rel']:.2f}% of "
         f"{np.degrees(float(np.median(err.w_true))):.3f} deg; ATE {1000 * m['ate_m']:.3f} mm")
    echo(f"          report: {out / 'report'} ({', '.join(written)})")
    echo(f"          compare: evo_ape tum {out / 'lightfield.zarr' / 'groundtruth.tum'} {out / 'trajectory.tum'}")
    return summary
