"""Benchmark: linear arrays (one viewpoint along x or y) against the 2-D array they are cut from.

Data: the paper's Sect. 5 set-up of ``bench_motion.py`` (:mod:`polycam.synth`'s textured spheres,
six faces, f = 60, 9 x 9 views 1 cm apart, 64 x 64 directions, 3 x 3 rays per sample), random
motions of 1.5 cm and 0.2 deg. The linear arrays are the 2-D array's middle row (one viewpoint
along y) and middle column (one along x): the same rays, so the comparison isolates what the
missing axis costs (docs/motion.md, "Linear arrays"). Optionally with Gaussian sensor noise of
``--noise`` grey levels (of 255) per sample, the same draw for every array.

Prints per distance and noise level the median relative error of t and of ω (vector errors,
median over the motions), the errors over the reported std (RMS over the axes and motions), the
solve time per pair, and each linear array's errors as a ratio to the 2-D array's (this run).
Usage::

    .venv/bin/python benchmarks/bench_linear.py [--distances 4 8] [--motions 3] [--noise 0 2]
        [--faces all|+z]
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
from polycam.lightfield import Axis  # noqa: E402
from polycam.motion import estimate_motion  # noqa: E402
from polycam.synth import LightFieldRenderer, default_lightfield_grid, spheres_scene  # noqa: E402

ARRAYS = ("9 x 9", "1 x 9 (row)", "9 x 1 (column)")
"""The 2-D array and the two linear arrays cut from it (rows x columns of viewpoints)."""


def cut(grid, L: np.ndarray, name: str):
    """(grid, frame) of array ``name`` from the 2-D ``grid`` and its frame ``L`` (F, Ny, Nx, Nv, Nu):
    the middle row keeps y = its value (one viewpoint along y), the middle column likewise x."""
    if name.startswith("9 x 9"):
        return grid, L
    if "row" in name:
        j = grid.y.count // 2
        return replace(grid, y=Axis(float(grid.y.values[j]), float(grid.y.values[j]), 1)), L[:, j:j + 1]
    i = grid.x.count // 2
    return replace(grid, x=Axis(float(grid.x.values[i]), float(grid.x.values[i]), 1)), L[:, :, i:i + 1]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--distances", type=float, nargs="+", default=[4.0, 8.0], help="scene distances [m]")
    ap.add_argument("--motions", type=int, default=3, help="random motions per distance")
    ap.add_argument("--noise", type=float, nargs="+", default=[0.0, 2.0], help="sensor noise [grey levels of 255]")
    ap.add_argument("--faces", default="all", help="'all' (six faces) or one face such as +z")
    args = ap.parse_args()

    grid = default_lightfield_grid(args.faces)
    print(f"## Linear arrays cut from {grid.y.count} x {grid.x.count} views ({len(grid.faces)} face(s), "
          f"{grid.v.count} x {grid.u.count} directions, supersample 3); |t| = 1.5 cm, |w| = 0.2 deg; "
          f"{args.motions} motion(s) per distance\n")
    print("| D [m] | noise [grey levels] | array | med err t | med err w | errors / std | time/pair [s] "
          "| t / 2-D | w / 2-D |")
    print("|---|---|---|---|---|---|---|---|---|")
    for D in args.distances:
        ren = LightFieldRenderer(spheres_scene(D, seed=0), grid, 3)
        L0 = ren.render(np.eye(4))
        rng = np.random.default_rng(int(D * 1000))
        motions = [random_motion(rng, 0.015, np.radians(0.2)) for _ in range(args.motions)]
        frames = [ren.render(M) for M in motions]
        for sigma in args.noise:
            noise = np.random.default_rng([int(D * 1000), int(sigma * 100)])
            draws = [(L0 + noise.normal(0.0, sigma / 255.0, L0.shape).astype(np.float32),
                      L1 + noise.normal(0.0, sigma / 255.0, L1.shape).astype(np.float32)) for L1 in frames]
            ref = None
            for name in ARRAYS:
                et, ew, z, times = [], [], [], []
                for M, (a, b) in zip(motions, draws):
                    g, A = cut(grid, a, name)
                    _, B = cut(grid, b, name)
                    t0 = time.perf_counter()
                    res = estimate_motion(np.ascontiguousarray(A), np.ascontiguousarray(B), g)
                    times.append(time.perf_counter() - t0)
                    est, tru = params(res.T_prev_next), params(M)
                    et.append(np.linalg.norm(est[:3] - tru[:3]) / np.linalg.norm(tru[:3]))
                    ew.append(np.linalg.norm(est[3:] - tru[3:]) / np.linalg.norm(tru[3:]))
                    z.append((est - tru) / res.std)
                t, w = float(np.median(et)), float(np.median(ew))
                ref = (t, w) if ref is None else ref
                zr = float(np.sqrt(np.mean(np.square(z))))
                print(f"| {D:g} | {sigma:g} | {name} | {100 * t:.3f}% | {100 * w:.3f}% | {zr:.2f} "
                      f"| {np.mean(times):.2f} | {t / ref[0]:.1f}x | {w / ref[1]:.1f}x |", flush=True)


if __name__ == "__main__":
    main()
