"""The ``polycam design`` verb: compare rig designs for egomotion (SPEC.md, docs/design.md).

Registered by :func:`add_parsers` (listed in ``polycam.cli.STAGE_CLIS``). Nothing
heavy is imported at module level, so ``polycam --help`` stays instant.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from .cliargs import number as _number

__all__ = ["add_parsers", "cmd_design"]


def _sweep(text: str) -> tuple[float, ...] | None:
    """``auto`` (None: 0.5, 1, 2 and 4 times --distance), ``none`` or comma-separated distances [m]."""
    t = text.strip().lower()
    if t == "auto":
        return None
    if t == "none":
        return ()
    try:
        vals = tuple(float(v) for v in t.split(",") if v.strip())
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected auto, none or distances like 2,4,8; got {text!r}") from None
    if not vals or any(not v > 0 for v in vals):
        raise argparse.ArgumentTypeError(f"distances must be > 0, got {text!r}")
    return vals


def add_parsers(sub) -> None:
    pos_f = _number(float, 0.0, True)
    nonneg_f = _number(float, 0.0, False)
    pos_i = _number(int, 1, False)
    p = sub.add_parser(
        "design", help="compare rig designs for egomotion: predicted and measured motion errors",
        description="For each rig: synthesise frame pairs, predict the 1-sigma motion errors of the plenoptic "
                    "solver's linear model at the given image noise, measure the real solver's errors, and "
                    "name weak and unobservable motion directions. Writes DIR/summary.csv, tables and plots.")
    p.add_argument("rigs", nargs="+", metavar="RIG.toml", help="rig files to compare")
    p.add_argument("--out", required=True, metavar="DIR", help="output folder")
    p.add_argument("--scene", choices=("room", "spheres"), default="room",
                   help="synthetic scene, the same for every rig (default room)")
    p.add_argument("--distance", type=pos_f, default=4.0, metavar="D",
                   help="scene distance [m] (room: far wall; spheres: nearest surface; default 4)")
    p.add_argument("--noise", type=pos_f, default=0.01, metavar="SIGMA",
                   help="image noise std per camera pixel in [0, 1] grey units (default 0.01)")
    p.add_argument("--step-t", type=nonneg_f, default=0.005, help="translation per frame pair [m] (default 0.005)")
    p.add_argument("--step-r", type=nonneg_f, default=0.2, help="rotation per frame pair [deg] (default 0.2)")
    p.add_argument("--pairs", type=pos_i, default=3, help="representative frame pairs per rig (default 3)")
    p.add_argument("--draws", type=pos_i, default=3, help="noise draws per pair for the measurement (default 3)")
    p.add_argument("--no-measure", action="store_true",
                   help="predictions only (fast: for searching many designs)")
    p.add_argument("--uv-step", type=pos_f, default=1.5, metavar="DEG",
                   help="direction sampling of the design light field [deg] (default 1.5)")
    p.add_argument("--xy-oversample", type=pos_i, default=2, help="viewpoints per camera spacing (default 2)")
    p.add_argument("--supersample", type=pos_i, default=2, help="k x k rays per light-field sample (default 2)")
    p.add_argument("--sweep", type=_sweep, default=None, metavar="auto|none|D1,D2,...",
                   help="scene distances for the error-against-distance plot (predictions; "
                        "default auto = 0.5, 1, 2, 4 x --distance)")
    p.add_argument("--hierarchy", action="store_true",
                   help="add the paper's four reference designs built from the first rig's camera: one camera, "
                        "six sharing a centre, a 3x3 array and six 3x3 arrays on a cube")
    p.add_argument("--seed", type=int, default=0, help="seed of scene, motions and noise (default 0)")
    p.add_argument("--no-plots", action="store_true", help="write the tables only")
    p.add_argument("--overwrite", action="store_true", help="replace the results of an earlier run in DIR")
    p.set_defaults(func=cmd_design)


def cmd_design(args: argparse.Namespace) -> int:
    from polycam.errors import InputError
    from polycam.rig import load_rig

    rigs = [load_rig(path) for path in args.rigs]     # user files first: fail before heavy work
    out = Path(args.out)
    if out.exists() and not out.is_dir():
        raise InputError(f"{out}: exists and is not a folder")
    if (out / "summary.csv").exists() and not args.overwrite:
        raise InputError(f"{out}: already holds a design study (summary.csv); pass --overwrite to replace it")

    from polycam.cli import _progress
    from polycam.design import DesignOptions, design_study, hierarchy_rigs
    from polycam.design_report import write_design_report

    if args.hierarchy:
        from polycam.gridrules import camera_spacing

        cam = rigs[0].cameras[0]
        pitch = camera_spacing(rigs[0].positions) or 0.02
        rigs += hierarchy_rigs(cam, pitch=pitch)
    names = [r.name for r in rigs]
    seen: dict[str, int] = {}
    for i, r in enumerate(rigs):           # make rig names unique (two files may share a [rig] name)
        if names.count(r.name) > 1:
            seen[r.name] = seen.get(r.name, 0) + 1
            rigs[i] = _renamed(r, f"{r.name}#{seen[r.name]}")
    sweep = args.sweep if args.sweep is not None else tuple(args.distance * k for k in (0.5, 1.0, 2.0, 4.0))
    opts = DesignOptions(scene=args.scene, distance=args.distance, noise=args.noise, step_t=args.step_t,
                         step_r_deg=args.step_r, pairs=args.pairs, draws=args.draws, measure=not args.no_measure,
                         uv_step_deg=args.uv_step, xy_oversample=args.xy_oversample, supersample=args.supersample,
                         sweep=sweep, seed=args.seed)
    with _progress(f"evaluating {len(rigs)} rig design(s)", len(rigs)) as advance:
        results = design_study(rigs, opts, progress=advance)
    write_design_report(results, out, opts, plots=not args.no_plots)
    _print_table(results)
    print(f"wrote {out / 'summary.csv'} and the tables and plots beside it (see {out / 'report.md'})")
    return 0


def _renamed(rig, name: str):
    import dataclasses

    return dataclasses.replace(rig, name=name)


def _print_table(results) -> None:
    import math

    def f(v, s):
        return "inf" if math.isinf(v) else ("-" if math.isnan(v) else f"{v * s:.3g}")

    w = max([len(r.name) for r in results] + [3])
    print(f"{'rig':<{w}}  cams faces  std_t[mm] err_t[mm] std_w[mrad] err_w[mrad]  unobservable")
    for r in results:
        p, m = r.prediction, r.measurement
        print(f"{r.name:<{w}}  {r.features['cameras']:>4} {r.features['faces']:>5}  {f(p.std_t, 1e3):>9} "
              f"{f(m.err_t if m else math.nan, 1e3):>9} {f(p.std_w, 1e3):>11} {f(m.err_w if m else math.nan, 1e3):>11}"
              f"  {' '.join(p.unobservable) or '-'}")
