"""Rig design study: speed of searching designs, and predicted vs measured errors.

Run: ``.venv/bin/python benchmarks/bench_design.py [--rigs 100] [--accuracy]``

Measures, in one run on this machine (room scene at 4 m, image noise 0.01 per pixel,
directions every 1.5 deg, the defaults of ``polycam design``):

- **search**: predicted errors (no solver runs) for ``--rigs`` candidate designs — planar
  arrays of 1x1 to 5x5 cameras, 1-4 cm pitch, 60 or 90 deg webcams of 320x240 or
  640x480, and cubes of 1x1 to 3x3 arrays — with renderings shared between rigs that
  share cameras (the issue's target: 100 rigs in under a minute);
- **baselines** on a subset of the same rigs: the same predictions without shared
  rendering, and the real solver on 3 pairs x 3 noise draws (what measuring every
  candidate would cost); the ratios say what the analytic prediction and the sharing buy;
- with ``--accuracy``: predicted 1-σ and measured errors of the example rigs in rigs/
  (as ``polycam design rigs/*.toml`` reports them), the measured error split into the
  systematic part (the solver on the noise-free pairs) and the noise scatter;
- with ``--bias``: where the systematic error of a single-face array comes from — the
  solver's error on one noise-free pair of rigs/webcam3x3.toml with one ingredient of
  the pipeline changed at a time (docs/design.md discusses the table).

Timings include everything after a warm-up (numba compilation excluded); the machine is
shared, so other processes can slow any row.
"""

from __future__ import annotations

import argparse
import itertools
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from polycam import design as dz  # noqa: E402
from polycam.rig import CameraSpec, load_rig  # noqa: E402


def camera(width: int, height: int, fov: float) -> CameraSpec:
    return CameraSpec(id="c", driver="mock", device=None, width=width, height=height, fps=30.0,
                      pixel_format="GREY", position=np.zeros(3), rotation=np.zeros(3), fov_deg=fov)


def candidates(n: int) -> list:
    """n candidate rigs: planar arrays and cubes of arrays (deterministic order)."""
    rigs = []
    for (w, h), fov, size, pitch in itertools.product(((320, 240), (640, 480)), (60.0, 90.0), (1, 2, 3, 4, 5),
                                                      (0.01, 0.02, 0.03, 0.04)):
        if size == 1 and pitch != 0.01:
            continue
        rigs.append(dz.planar_array_rig(size, size, pitch, camera(w, h, fov),
                                        name=f"a{size}x{size}-{pitch * 100:g}cm-{fov:g}deg-{w}"))
    for size, pitch in itertools.product((1, 2, 3), (0.02, 0.03, 0.04)):
        rigs.append(dz.cube_array_rig(size, pitch, camera(320, 240, 90.0), name=f"cube{size}x{size}-{pitch * 100:g}cm"))
    rigs.append(dz.cube_array_rig(1, 0.02, camera(320, 240, 90.0), half=0.0, name="sphere6"))
    while len(rigs) < n:                                       # more pitches if asked for more
        k = len(rigs)
        rigs.append(dz.planar_array_rig(3, 3, 0.005 * (k % 9 + 1), camera(320, 240, 70.0), name=f"extra{k}"))
    return rigs[:n]


def timed(fn):
    t0 = time.perf_counter()
    out = fn()
    return time.perf_counter() - t0, out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rigs", type=int, default=100)
    ap.add_argument("--baseline", type=int, default=10, help="rigs in the baseline rows (default 10)")
    ap.add_argument("--accuracy", action="store_true", help="also predicted vs measured for rigs/*.toml")
    ap.add_argument("--bias", action="store_true", help="only the systematic-error decomposition (webcam3x3)")
    args = ap.parse_args()
    if args.bias:
        return bias_table()

    rigs = candidates(args.rigs)
    pred = dz.DesignOptions(measure=False)
    # warm-up: compile every kernel once (one array, one cube, one single camera)
    dz.design_study([dz.planar_array_rig(3, 3, 0.02, camera(160, 120, 60.0)), dz.single_camera_rig(camera(160, 120, 60.0)),
                     dz.cube_array_rig(2, 0.02, camera(160, 120, 90.0))], dz.DesignOptions(uv_step_deg=5.0, pairs=1, draws=1))

    renderer = dz.SourceRenderer(dz._scene(pred), pred.supersample)
    t_search, results = timed(lambda: dz.design_study(rigs, pred, renderer=renderer))

    # baselines: every rig renders its own viewpoints; the real solver on every (n / m)-th rig
    scene = renderer.scene
    t_unshared, _ = timed(lambda: [dz.evaluate_rig(r, pred, renderer=dz.SourceRenderer(scene, pred.supersample))
                                   for r in rigs])
    sub = rigs[:: max(1, len(rigs) // args.baseline)][: args.baseline]
    t_shared, _ = timed(lambda: dz.design_study(sub, pred))
    meas = dz.DesignOptions(measure=True, pairs=3, draws=3)
    t_measure, _ = timed(lambda: dz.design_study(sub, meas))

    n, m = len(rigs), len(sub)
    print(f"design search: {n} candidate rigs (planar 1x1-5x5, 1-4 cm, 60/90 deg, 320x240/640x480; cubes), "
          "room at 4 m, noise 0.01, directions every 1.5 deg")
    print(f"viewpoint images rendered once and reused: {renderer.rendered} rendered, {renderer.reused} reused "
          f"({renderer.reused / max(renderer.rendered + renderer.reused, 1):.0%})")
    print()
    print(f"{'what':<58} {'rigs':>5} {'total [s]':>10} {'per rig [s]':>12} {'ratio':>7}")
    print(f"{'predicted errors, shared rendering (the search)':<58} {n:>5} {t_search:>10.1f} {t_search / n:>12.3f} "
          f"{'1.0':>7}")
    print(f"{'  baseline: no shared rendering':<58} {n:>5} {t_unshared:>10.1f} {t_unshared / n:>12.3f} "
          f"{t_unshared / t_search:>7.2f}")
    print(f"{'predicted errors, subset':<58} {m:>5} {t_shared:>10.1f} {t_shared / m:>12.3f} {'1.0':>7}")
    print(f"{'  baseline: measure with the real solver (3 pairs x 3 draws)':<58} {m:>5} {t_measure:>10.1f} "
          f"{t_measure / m:>12.3f} {t_measure / t_shared:>7.1f}")
    print()
    print(f"target: {n} rigs predicted in under 60 s -> {'met' if t_search < 60 else 'NOT met'} ({t_search:.1f} s)")
    best = sorted(results, key=lambda r: r.prediction.std_t)[:5]
    print("best 5 by predicted translation error: " + ", ".join(
        f"{r.name} ({r.prediction.std_t * 1e3:.3g} mm, {r.prediction.std_w * 1e3:.3g} mrad)" for r in best))

    if args.accuracy:
        names = ["single", "webcam3x3", "webcam5x5", "oak_array", "cube6x3x3"]
        ex = [load_rig(REPO / "rigs" / f"{k}.toml") for k in names]
        t_acc, res = timed(lambda: dz.design_study(ex, dz.DesignOptions(measure=True, pairs=3, draws=3)))
        print()
        print(f"example rigs, predicted 1-σ vs measured RMS per frame pair (|t| = 5 mm, |ω| = 0.2 deg; "
              f"{t_acc:.0f} s)")
        print(f"{'rig':<11} {'class':<24} {'std_t':>8} {'err_t':>8} {'bias_t':>8} {'scat_t':>8} {'std_w':>8} "
              f"{'err_w':>8} {'bias_w':>8} {'scat_w':>8} {'misfit':>6}  unobservable / ambiguity")
        print(f"{'':<11} {'':<24} {'[mm]':>8} {'[mm]':>8} {'[mm]':>8} {'[mm]':>8} {'[mrad]':>8} {'[mrad]':>8} "
              f"{'[mrad]':>8} {'[mrad]':>8}")
        for r in res:
            p, mm = r.prediction, r.measurement

            def f(v):
                return "inf" if np.isinf(v) else ("-" if np.isnan(v) else f"{v * 1e3:.3g}")

            print(f"{r.name:<11} {r.features['class']:<24} {f(p.std_t):>8} {f(mm.err_t):>8} {f(mm.bias_t):>8} "
                  f"{f(mm.scatter_t):>8} {f(p.std_w):>8} {f(mm.err_w):>8} {f(mm.bias_w):>8} {f(mm.scatter_w):>8} "
                  f"{p.misfit:>6.2f}  "
                  f"{' '.join(p.unobservable) or '-'} / {p.ambiguity or '-'}")
    return 0


def bias_table() -> int:
    """The solver's error on noise-free pairs of rigs/webcam3x3.toml (one face, 3x3 webcams, 4 cm
    pitch: the t~w ambiguity of a small field of view), one pipeline ingredient changed at a time."""
    import dataclasses

    from polycam.geometry import T_from_Rt, r_from_R
    from polycam.motion import MotionOptions, estimate_motion

    rig = load_rig(REPO / "rigs" / "webcam3x3.toml")
    opts = dz.DesignOptions(pairs=3)
    motions = dz.pair_motions(3, opts.step_t, opts.step_r_deg, opts.seed)
    renderers: dict = {}
    base = MotionOptions()

    def run(i, *, uv=1.5, ss=2, xyo=2, solver=base, motion=None, start_at_truth=False, pitch=None):
        r = rig if pitch is None else dz.planar_array_rig(3, 3, pitch, rig.cameras[0])
        s = dz.design_grid(r, uv_step_deg=uv, xy_oversample=xyo)
        rend = renderers.setdefault(ss, dz.SourceRenderer(dz._scene(opts), ss))
        M = motions[i] if motion is None else motion
        W = None if s.all_data else s.W
        res = estimate_motion(s.assemble(rend.render(s, np.eye(4))), s.assemble(rend.render(s, M)), s.grid,
                              W0=W, W1=W, options=solver, T_init=M if start_at_truth else None)
        e = np.r_[res.t - M[:3, 3], res.r - r_from_R(M[:3, :3])]
        # a pair the solver flags (e.g. 3 viewpoints per axis: no ray's filter support stays
        # inside the grid once frame 2 moves) has no estimate to compare
        return np.linalg.norm(e[:3]), np.linalg.norm(e[3:]), res.reason if res.unobservable else ""

    t0 = time.perf_counter()
    pred = dz.evaluate_rig(rig, dz.DesignOptions(measure=False, pairs=1)).prediction
    rows = []
    for i in (1, 2):
        M = motions[i]
        rows += [
            (i, "default pipeline (uv 1.5 deg, supersample 2, xy_oversample 2, 6-tap warp)", run(i)),
            (i, "  solver started at the true motion", run(i, start_at_truth=True)),
            (i, "  no robust weights (and no discontinuity weight, as by default)",
             run(i, solver=dataclasses.replace(base, robust="none"))),
            (i, "  discontinuity weight (smooth_c_resampled 0.5: before session 44)",
             run(i, solver=dataclasses.replace(base, smooth_c_resampled=0.5))),
            (i, "  5x stronger discontinuity rejection (smooth_c_resampled 0.1)",
             run(i, solver=dataclasses.replace(base, smooth_c_resampled=0.1))),
            (i, "  4-tap (cubic) warp in (u, v)", run(i, solver=dataclasses.replace(base, uv_taps=4))),
            (i, "  supersample 4 (less aliasing)", run(i, ss=4)),
            (i, "  directions every 0.75 deg", run(i, uv=0.75)),
            (i, "  no interpolated viewpoints (xy_oversample 1)", run(i, xyo=1)),
            (i, "  pitch 1 cm instead of 4 (less parallax per view)", run(i, pitch=0.01)),
            (i, "  translation only (warp interpolates in x, y only)",
             run(i, motion=T_from_Rt(np.eye(3), M[:3, 3]))),
            (i, "  rotation only (warp interpolates in u, v only)",
             run(i, motion=T_from_Rt(M[:3, :3], np.zeros(3)))),
        ]
    print(f"systematic error of the solver on noise-free pairs of webcam3x3 (room at 4 m, |t| = 5 mm, |w| = 0.2 deg; "
          f"{time.perf_counter() - t0:.0f} s)")
    print(f"predicted noise 1-σ at noise 0.01 for comparison: {pred.std_t * 1e3:.3g} mm, {pred.std_w * 1e3:.3g} mrad "
          f"({pred.ambiguity or 'no ambiguity'})")
    print(f"{'pair':>4}  {'variant':<76} {'|t err| [mm]':>12} {'|w err| [mrad]':>14}")
    for i, label, (et, ew, failed) in rows:
        if failed:
            print(f"{i:>4}  {label:<76} {'fails:':>12} {failed.split(':')[0]}")
        else:
            print(f"{i:>4}  {label:<76} {et * 1e3:>12.3f} {ew * 1e3:>14.3f}")
    if any(r[2][2] for r in rows):
        print("fails: the solver flags the pair unobservable; its reason in full:",
              next(r[2][2] for r in rows if r[2][2]))
    return 0


if __name__ == "__main__":
    sys.exit(main())
