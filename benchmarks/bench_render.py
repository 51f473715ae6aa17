"""Ray-caster throughput: camera-array frames and six-face light fields, vs a numpy baseline.

Run: ``.venv/bin/python benchmarks/bench_render.py [--repeat N]``

Measures, in one run on this machine:

- the 5x5 mock rig (rigs/mock5x5.toml, 320x240 per camera) looking into the room
  scene: render-only frames/s at supersample 1 and 2 (k x k rays per pixel), and
  end to end (render + 8-bit PNG session writing) at supersample 1;
- a six-face 9x9x64x64 light field of the spheres scene (D = 8 m) at supersample 1 and 2;
- a straightforward numpy baseline: every ray tested against every sphere
  (vectorised over rays x spheres), nearest hit shaded with the same texture and
  light, on a subset of the same light-field rays; its radiance is checked against
  the numba caster's and its rays/s gives the speed-up ratio.

Timings are the best of ``--repeat`` runs after a warm-up (numba compile excluded); the
machine is shared, so other processes can slow any row (the 1-thread row shows the
per-core rate).
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from polycam.rig import load_rig  # noqa: E402
from polycam.synth import (CameraArrayRenderer, LightFieldRenderer, default_lightfield_grid,  # noqa: E402
                           lightfield_face_rays, room_scene, smooth_trajectory, spheres_scene, synth_session,
                           trace_outer)


def best_time(fn, repeat: int) -> float:
    fn()                                   # warm-up (and numba compile / cache load)
    ts = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        ts.append(time.perf_counter() - t0)
    return min(ts)


def numpy_spheres(scene, o: np.ndarray, d: np.ndarray) -> np.ndarray:
    """Baseline: brute-force nearest sphere for rays o (3,), d (N, 3) unit, then the same
    Lambertian shading and solid texture (libm cos), sky where nothing is hit."""
    c = scene.sphere_centres                                   # (Ns, 3)
    r = scene.sphere_radii
    q = o[None, :] - c                                         # (Ns, 3)
    b = d @ q.T                                                # (N, Ns)
    cc = np.sum(q * q, axis=1) - r * r                         # (Ns,)
    disc = b * b - cc[None, :]
    sq = np.sqrt(np.where(disc >= 0, disc, np.nan))
    t = -b - sq
    t = np.where(t > 1e-9, t, -b + sq)
    t = np.where((disc >= 0) & (t > 1e-9), t, np.inf)
    k = np.argmin(t, axis=1)
    tk = t[np.arange(len(d)), k]
    hit = np.isfinite(tk)
    tx = scene.textures
    out = np.empty(len(d))
    # sky
    s_idx = scene.sky_texture
    w0, w1 = tx.wave_start[s_idx], tx.wave_start[s_idx + 1]
    W = tx.waves[:, w0:w1]
    S = np.cos(d @ W[:3] + W[3]) @ W[4]
    out[:] = np.clip(tx.param[s_idx, 0] + tx.param[s_idx, 1] * S, 0, 1)
    # spheres: gather each hit's waves (all spheres have the same wave count)
    kh = k[hit]
    p = o + tk[hit, None] * d[hit] - c[kh]                     # point in the sphere's frame
    n = p / r[kh, None]
    ti = scene.sphere_texture[kh]
    nw = int(tx.wave_start[1] - tx.wave_start[0])
    idx = tx.wave_start[ti][:, None] + np.arange(nw)[None, :]
    Wk = tx.waves[:, idx]                                      # (5, Nh, nw)
    S = np.sum(Wk[4] * np.cos(np.einsum("hj,jhw->hw", p, Wk[:3]) + Wk[3]), axis=1)
    sharp = tx.param[ti, 2]
    S = np.where(sharp > 0, sharp * S / np.sqrt(1 + (sharp * S) ** 2), S)
    alb = np.clip(tx.param[ti, 0] + tx.param[ti, 1] * S, 0, 1)
    nd = np.sum(n * d[hit], axis=1)
    n = np.where(nd[:, None] > 0, -n, n)
    lam = np.maximum(n @ scene.light, 0)
    out[hit] = alb * (scene.ambient + scene.diffuse * lam)
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=5)
    args = ap.parse_args()
    import numba

    rows = []
    rig = load_rig(REPO / "rigs" / "mock5x5.toml")
    room = room_scene(4.0, seed=1)
    T = smooth_trajectory(2, step_t=0.01, step_r_deg=0.3, seed=1).T_world_rig[1]
    n_pix = sum(c.width * c.height for c in rig.cameras)
    for ss in (1, 2):
        r = CameraArrayRenderer(rig, None, room, supersample=ss)
        dt = best_time(lambda: r.render(T), args.repeat)
        rows.append((f"5x5 rig 320x240, room, render, supersample {ss}", n_pix * ss * ss, dt))
        if ss == 1:
            threads = numba.get_num_threads()
            numba.set_num_threads(1)
            dt = best_time(lambda: r.render(T), args.repeat)
            numba.set_num_threads(threads)
            rows.append(("  the same on 1 thread", n_pix, dt))

    with tempfile.TemporaryDirectory() as tmp:
        frames = 5

        def session():
            synth_session(rig, Path(tmp) / "s", frames=frames, supersample=1, overwrite=True, threads=2)

        dt = best_time(session, 1) / frames
        rows.append(("5x5 rig 320x240, room, session incl. PNG writing, ss 1", n_pix, dt))

    spheres = spheres_scene(8.0, seed=1)
    grid = default_lightfield_grid("all")
    for ss in (1, 2):
        lr = LightFieldRenderer(spheres, grid, supersample=ss)
        dt = best_time(lambda: lr.render(np.eye(4)), args.repeat)
        rows.append((f"light field 6x9x9x64x64, spheres D=8, supersample {ss}", grid.num_rays * ss * ss, dt))

    # numpy baseline on a subset of the light-field rays (face +z, centre view)
    o, d = lightfield_face_rays(grid, 0, 1)
    o = o[len(o) // 2]
    d = d[:, 0].astype(np.float64)
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    sub = d[:: max(1, len(d) // 4096)][:4096]
    ref = trace_outer(spheres, o[None], sub[:, None, :].astype(np.float32), np.eye(4)).radiance[0]
    base = numpy_spheres(spheres, o, sub)
    agree = np.abs(base - ref).max()
    dt_np = best_time(lambda: numpy_spheres(spheres, o, sub), args.repeat)
    dt_nb = best_time(lambda: trace_outer(spheres, o[None], sub[:, None, :].astype(np.float32), np.eye(4)),
                      args.repeat)
    rows.append((f"numpy brute force, {len(spheres.sphere_radii)} spheres ({len(sub)} rays)", len(sub), dt_np))
    rows.append((f"numba caster, same {len(sub)} rays", len(sub), dt_nb))

    print(f"cores: {os.cpu_count()}, numba threads: {numba.get_num_threads()} "
          f"({numba.threading_layer()}), numpy {np.__version__}, numba {numba.__version__}")
    print(f"{'case':60s} {'rays/frame':>11s} {'s/frame':>9s} {'Mrays/s':>9s} {'frames/s':>9s}")
    for name, n, dt in rows:
        print(f"{name:60s} {n:11d} {dt:9.4f} {n / dt / 1e6:9.2f} {1.0 / dt:9.2f}")
    lf_rate = rows[4][1] / rows[4][2]
    print(f"numpy baseline agrees with the caster to {agree:.2e} (max abs radiance)")
    print(f"speed-up vs numpy brute force: same rays {dt_np / dt_nb:.0f}x; "
          f"full light-field rate vs numpy rate {lf_rate / (len(sub) / dt_np):.0f}x")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
