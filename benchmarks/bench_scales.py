"""Scale selection (paper Sect. 4.1): does choosing the derivative scales where the four
depth estimates of Eq. 7 agree improve motion and depth?

Run: ``.venv/bin/python benchmarks/bench_scales.py [--quick] [--motions N] [--distances 4 8 12 16]``

Set-up (paper Sect. 5, as benchmarks/bench_motion.py): six faces, f = 60, 9 x 9 views
1 cm apart, 64 x 64 directions per face (3 x 3 rays averaged per sample), unit spheres
at distance D; seeded motions |t| = 1.5 cm, |ω| = 0.2 deg.

Motion: :func:`polycam.motion.estimate_motion` with the default options against
:func:`polycam.scales.estimate_motion_scale_selected` (default options inside the loop,
per-face scales, up to 2 rounds). Errors are |est − true| / |true| of the t and ω
vectors, median over the motions.

Depth: for the first motion, with the true motion (so only the depth step is
measured) and with the default solver's estimate. Truth: the ray tracer's hit distance
of each ray (``trace_rays(...).distance``). Evaluated on the central view of every face
(what ``polycam depth --views central`` writes): each method keeps its most confident
half of those rays (as the verb does); the table gives the median and 90th percentile
of |range / true − 1| over the kept rays, and the kept fraction of the central view.
Methods: every fixed scale of :data:`polycam.scales.SCALE_LADDER` (``xy0_uv0`` is the
single-scale default of ``polycam depth``) and the scale-selected depth per face and
per 16 x 16 (u, v) region. The machine (2 cores) was shared: times are indicative.
"""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(REPO / "benchmarks"))

from bench_motion import params, random_motion  # noqa: E402
from polycam.depth import confident_mask, depth_from_derivatives  # noqa: E402
from polycam.motion import estimate_motion  # noqa: E402
from polycam.scales import (MOTION_SCALES, SCALE_LADDER, Scale, depth_scale_selected,  # noqa: E402
                            ScaleTracker, estimate_motion_scale_selected, scale_derivatives)
from polycam.synth import LightFieldRenderer, default_lightfield_grid, spheres_scene  # noqa: E402
from polycam.synth.raycast import trace_rays  # noqa: E402
from polycam.depth_refine import grid_positions, refine_depth  # noqa: E402


def vec_err(est: np.ndarray, tru: np.ndarray) -> tuple[float, float]:
    return (float(np.linalg.norm(est[:3] - tru[:3]) / np.linalg.norm(tru[:3])),
            float(np.linalg.norm(est[3:] - tru[3:]) / np.linalg.norm(tru[3:])))


def depth_row(dm, grid, truth_c, jc, ic) -> tuple[float, float, float]:
    """(median, p90 of |range/true - 1|, kept fraction) on the central views."""
    keep = confident_mask(dm)
    rng = dm.range_along_ray(grid)
    k = keep[:, jc, ic] & np.isfinite(truth_c)
    rel = np.abs(rng[:, jc, ic][k] / truth_c[k] - 1)
    if not rel.size:
        return float("nan"), float("nan"), 0.0
    return float(np.median(rel)), float(np.quantile(rel, 0.9)), float(np.mean(k))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--quick", action="store_true", help="D = 4 and 16 m, one motion, supersample 2")
    ap.add_argument("--motions", type=int, default=2)
    ap.add_argument("--distances", type=float, nargs="+", default=[4.0, 8.0, 12.0, 16.0])
    ap.add_argument("--directions", type=int, default=64, help="(u, v) samples per axis (smoke runs: fewer)")
    ap.add_argument("--depth-only", action="store_true", help="skip the scale-selected motion (depth tables only)")
    ap.add_argument("--motion-only", action="store_true", help="skip the depth tables")
    ap.add_argument("--refine", action="store_true",
                    help="also refine the single-scale and the face-selected depth on every view's samples "
                         "(polycam.depth_refine, every view a source; docs/depth.md)")
    ap.add_argument("--motion-scales", default=None, metavar="NAMES",
                    help="candidates of the motion loop, e.g. xy2_uv0,xy0_uv0 (default MOTION_SCALES)")
    ap.add_argument("--tracker", action="store_true",
                    help="scale-selected motion as estimate_trajectory(scale_selection=True) runs it: "
                         "polycam.scales.ScaleTracker, (u, v) candidates capped by the disparity")
    a = ap.parse_args()
    distances = [4.0, 16.0] if a.quick else a.distances
    mscales = MOTION_SCALES if a.motion_scales is None else tuple(
        Scale(*(int(p[2:]) for p in n.split("_"))) for n in a.motion_scales.split(","))
    n_mot = 1 if a.quick else a.motions
    ss = 2 if a.quick else 3
    grid = default_lightfield_grid("all", directions=a.directions)
    F, Ny, Nx, Nv, Nu = grid.shape
    jc, ic = Ny // 2, Nx // 2
    print(f"# bench_scales: six faces, f = 60, {Ny}x{Nx} views, {Nv}x{Nu} directions, supersample {ss}, "
          f"{n_mot} motion(s) per D (|t| = 1.5 cm, |w| = 0.2 deg); machine shared\n")
    motion_rows, depth_rows = [], []
    for D in distances:
        scene = spheres_scene(D, seed=0)
        ren = LightFieldRenderer(scene, grid, ss)
        L0 = ren.render(np.eye(4))
        rng = np.random.default_rng(int(D * 1000))
        motions = [random_motion(rng, 0.015, np.radians(0.2)) for _ in range(n_mot)]
        frames = [ren.render(M) for M in motions]
        errs = {"default": [], "scale-selected": []}
        times = {"default": [], "scale-selected": []}
        chosen = []
        est_first = None
        for M, L1 in zip(motions, frames):
            tru = params(M)
            t0 = time.process_time()
            r = estimate_motion(L0, L1, grid)
            times["default"].append(time.process_time() - t0)
            errs["default"].append(vec_err(params(r.T_prev_next), tru))
            if est_first is None:
                est_first = r.T_prev_next
            if a.depth_only:
                continue
            t0 = time.process_time()
            if a.tracker:
                tracker = ScaleTracker(grid)
                res = tracker.estimate(L0, L1)
                selection = tracker.selection
            else:
                out = estimate_motion_scale_selected(L0, L1, grid, scales=mscales)
                res, selection = out.result, out.selection
            times["scale-selected"].append(time.process_time() - t0)
            errs["scale-selected"].append(vec_err(params(res.T_prev_next), tru))
            chosen.append(",".join(sorted(set(x.name for x in selection.face_scales()))))
        for name in errs:
            if not errs[name]:
                continue
            e = np.array(errs[name])
            motion_rows.append(f"| {D:g} | {name} | {100 * np.median(e[:, 0]):.2f}% | {100 * np.median(e[:, 1]):.2f}% "
                               f"| {np.median(times[name]):.1f} | {' / '.join(chosen) if name != 'default' else ''} |")
            print(motion_rows[-1], flush=True)
        if a.motion_only:
            continue
        # depth: central views, truth from the tracer
        rays = grid.rays()
        truth_c = trace_rays(scene, type(rays)(rays.origins[:, jc, ic], rays.directions[:, jc, ic],
                                               frame="rig")).distance
        truth_c = np.where(np.isfinite(truth_c), truth_c, np.nan)
        for label, Mdepth in (("true motion", motions[0]), ("estimated motion", est_first)):
            for sc in SCALE_LADDER:
                der, ok = scale_derivatives(L0, frames[0], grid, sc)
                dm = depth_from_derivatives(der, grid, T_prev_next=Mdepth, valid=ok)
                med, p90, kept = depth_row(dm, grid, truth_c, jc, ic)
                tag = " (single scale)" if sc.xy == 0 and sc.uv == 0 else ""
                if tag:
                    single = dm
                depth_rows.append(f"| {D:g} | {label} | fixed {sc.name}{tag} | {100 * med:.2f}% | {100 * p90:.1f}% "
                                  f"| {100 * kept:.0f}% |")
                print(depth_rows[-1], flush=True)
            sel_region = None
            for per in ("region", "face"):
                given = None if sel_region is None else replace(sel_region, region_choice=None)
                dm, sel = depth_scale_selected(L0, frames[0], grid, Mdepth, per=per, selection=given)
                sel_region = sel_region or sel
                med, p90, kept = depth_row(dm, grid, truth_c, jc, ic)
                if per == "region":
                    counts = np.bincount(sel.region_choice.ravel(), minlength=len(sel.scales))
                    what = ", ".join(f"{sel.scales[i].name} {c}" for i, c in enumerate(counts) if c)
                else:
                    what = ",".join(sorted(set(x.name for x in sel.face_scales())))
                depth_rows.append(f"| {D:g} | {label} | selected per {per} ({what}) | {100 * med:.2f}% "
                                  f"| {100 * p90:.1f}% | {100 * kept:.0f}% |")
                print(depth_rows[-1], flush=True)
            if a.refine:
                targets = np.zeros(grid.shape[:3], bool)
                targets[:, jc, ic] = True
                every = grid_positions(grid, np.ones((Ny, Nx), bool))
                for name, start in (("single scale", single), ("selected per face", dm)):
                    r = refine_depth(L0, grid, start.Z, sources=every, targets=targets)
                    med, p90, kept = depth_row(r, grid, truth_c, jc, ic)
                    depth_rows.append(f"| {D:g} | {label} | {name}, refined on every view | {100 * med:.2f}% "
                                      f"| {100 * p90:.1f}% | {100 * kept:.0f}% |")
                    print(depth_rows[-1], flush=True)
    print("\n## Motion: default solver vs scale-selected feedback loop\n")
    print("| D [m] | method | med err t | med err w | CPU s/pair | scales chosen (per face) |")
    print("|---|---|---|---|---|---|")
    print("\n".join(motion_rows))
    print("\n## Depth on the central views vs the traced distance (first motion)\n")
    print("| D [m] | motion used | derivative scales | median rel err | p90 rel err | kept |")
    print("|---|---|---|---|---|---|")
    print("\n".join(depth_rows))


if __name__ == "__main__":
    main()
