"""Depth (paper Eq. 6-7) under sensor noise: the noise correction of the fused sums against
the uncorrected fusion, measured in the same run.

Run: ``.venv/bin/python benchmarks/bench_depth_noise.py [--distance 4] [--faces +z]
[--sigmas 0 1 2 4 8] [--blur 0.8]``

Set-up (benchmarks/bench_noise.py's blurred set-up): the paper's unit spheres at D = 4 m,
f = 60, 9 x 9 viewpoints 1 cm apart, 64 x 64 directions (3 x 3 rays per sample), a Gaussian
optics blur of 0.8 samples along u and v of every view (before the pixel integration,
``LightFieldRenderer(psf=)``; session 26), a quarter of the seeded motion
(|t| = 3.8 mm, |ω| = 0.05°). White Gaussian noise of σ grey levels (of 255) on both frames,
one seeded draw per level. Depth: :func:`polycam.depth.depth_of_pair` with the true motion,
uncorrected (``noise_var=0``, the fusion before session 19) and corrected (the noise
estimated from the frames, the default). Truth: the ray tracer's disparity ρ of each
sample's centre ray, ``Z = f / ρ``. The table gives the median ``Z / Z_true`` over the most
confident half of the rays (:func:`polycam.depth.confident_mask`, what ``polycam depth``
writes) and over every ray with an estimate, the median relative error on the confident
half, and the estimated sensor noise; the last line, the ratio of the two fusions' median
depth bias over the noisy levels (baseline / corrected).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(REPO / "benchmarks"))

from bench_noise import setup  # noqa: E402  (the frames, motion and true disparity of the noise bench)

from polycam.depth import confident_mask, depth_of_pair  # noqa: E402
from polycam.motion_weights import frame_noise_variance  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--distance", type=float, default=4.0, help="[m] the spheres' distance")
    ap.add_argument("--faces", default="+z", help="a face name, or 'all'")
    ap.add_argument("--sigmas", type=float, nargs="+", default=[0.0, 1.0, 2.0, 4.0, 8.0],
                    help="noise levels [grey levels of 255]")
    ap.add_argument("--blur", type=float, default=0.8, help="optics PSF along u, v [samples], before the pixel integration")
    args = ap.parse_args()

    grid, L0, L1, M, rho = setup(args.faces, args.distance, 3, 64, args.blur, 0.25, True)
    f = np.array([face.f for face in grid.faces])[:, None, None, None, None]
    with np.errstate(divide="ignore"):
        Z_true = np.where(rho > 0, f / rho, np.nan)
    print(f"\n## depth under noise: spheres at {args.distance:g} m, faces {args.faces}, {grid.shape} rays, "
          f"blur {args.blur:g}, true motion\n")
    print("| σ [grey] | fusion | estimated σ [grey] | median Z / Z_true, confident half | "
          "every ray with an estimate | median abs err, confident half |")
    print("|---|---|---|---|---|---|")
    bias = {"uncorrected": [], "corrected": []}
    rng = np.random.default_rng(5)
    for s in args.sigmas:
        sig = s / 255.0
        a = (L0 + rng.normal(0.0, sig, L0.shape)).astype(np.float32) if s > 0 else L0
        b = (L1 + rng.normal(0.0, sig, L1.shape)).astype(np.float32) if s > 0 else L1
        est = frame_noise_variance(a, b, grid)
        for name, nv in (("uncorrected", 0.0), ("corrected", est)):
            dm = depth_of_pair(a, b, grid, M, noise_var=nv)
            ok = np.isfinite(dm.Z) & np.isfinite(Z_true)
            conf = confident_mask(dm) & ok
            r_conf = float(np.median(dm.Z[conf] / Z_true[conf]))
            r_all = float(np.median(dm.Z[ok] / Z_true[ok]))
            err = float(np.median(np.abs(dm.Z[conf] / Z_true[conf] - 1.0)))
            if s > 0:
                bias[name].append(abs(r_conf - 1.0))
            print(f"| {s:g} | {name} | {255 * np.sqrt(est):.2f} | {r_conf:.4f} | {r_all:.4f} | {100 * err:.2f}% |",
                  flush=True)
    if bias["corrected"]:
        ratio = float(np.mean(bias["uncorrected"]) / max(np.mean(bias["corrected"]), 1e-12))
        print(f"\nmean |median Z / Z_true − 1| over σ > 0, confident half: uncorrected "
              f"{100 * np.mean(bias['uncorrected']):.2f}%, corrected {100 * np.mean(bias['corrected']):.2f}% "
              f"(baseline / corrected: {ratio:.1f}x)")


if __name__ == "__main__":
    main()
