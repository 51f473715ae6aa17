"""Resampling: quality against a direct render, speed against a kd-tree baseline, and real photos.

Run: ``.venv/bin/python benchmarks/bench_resample.py [--quick] [--out DIR] [--repeat N] [--perturb-position-mm MM]``

**Quality.** A session of an irregular 5x5 rig from :func:`polycam.synth.synth_session`:
320x240 grey cameras 2 cm apart, 60 deg, a real lens (the OPENCV8 model
``../shared/data/mrcal-models/cam0.opencv8.cameramodel`` rescaled to the imager, as
``lens =`` in a rig file does), camera rotations of 2 deg std per axis and focal
lengths of 1% std (``true_cameramodels``; ``--perturb-position-mm``: camera centres off
the rig file too, as in ``polycam run``), 8-bit images of the textured room moving
smoothly; the true models are the calibration. It is resampled onto the automatic
grid (9x9 views: one at every camera and one half-way; one (u, v) step per pixel) with
the default settings (the views between cameras filled along the disparity of a plane
sweep, :mod:`resample.viewfill`) and with the pull-push alone (``view_fill="pushpull"``:
depth-free), and compared with the same grid rendered directly
(:func:`polycam.synth.render_lightfield`, 4x4 rays per cell) at the same poses:

- PSNR at the viewpoints where cameras sit, over the samples with W > 0.5 (target >= 40 dB);
- PSNR half-way between cameras (along x, along y and diagonally), over the samples
  whose neighbouring camera views have W > 0.5, against linearly interpolating the
  directly rendered neighbouring views (the depth-free limit; target: no worse);
- the plenoptic motion (:func:`polycam.motion.estimate_trajectory`) from the resampled
  light field and from the direct one, per-pair errors against the ground truth
  (target: resampled within 2x the direct error), on the 9x9 grid (default settings
  through ``resample_session`` and a store, and pull-push alone) and on a grid with
  views only where the cameras are (5x5).

**Speed.** Rays per second per frame once the geometry is built (sparse product +
pull-push, one frame in memory, best and median of ``--repeat``, wall and CPU time:
the machine is shared, so wall time depends on the other jobs), against a scipy
``cKDTree`` inverse-distance baseline on the same frame (tree over the scattered
samples in grid-step units, 8 nearest samples per cell, weights 1/d², both cores),
with the PSNR of both against the direct render per region (where the cameras
measured, holes in the camera views, views between cameras, everything). The default (camera views
re-centred onto their grid views, ``ViewFillOptions.recentre``) is also run without re-centring: the
PSNR at the cameras, the time per frame and the motion, which differ only with
``--perturb-position-mm`` (cameras on their views need no re-centring). Also the whole ``resample_session``
(PNG reading, zarr writing) in-process and on a local dask cluster of 2 workers, on
a longer session (the rendered frames repeated).

**Real data.** The 28 photos of ``../shared/data/lumigraph-kettle`` through their
COLMAP model (:func:`calib.import_colmap_text`), an unstructured lumigraph: the rig
frame is put at the mean camera centre looking along the mean viewing direction, the
photos are scaled back to the model's 1280x960 (they were resized after the model was
made) and then to 1/4 of that, and resampled (RGB) onto the automatic grid (one view
per camera spacing, one direction per 2 pixels). PNGs of
views (and their W) go to ``--out`` (not part of the repository).

The machine has 2 cores and may be shared with other jobs; timings say what this run saw.
One frame is timed with 1 and with 2 numba threads (``numba.set_num_threads``), best and
median wall time and CPU time; the CPU time of the single-threaded run is the figure least
disturbed by other jobs (an idle 2-core machine runs a frame in a bit over half of it). The
first frame's time (numba's compiled code loaded from its cache, or compiled) is reported
apart. As in the ``polycam`` command, OpenMP threads wait passively (``OMP_WAIT_POLICY``).
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")     # as the polycam command does (before numba loads)

import numpy as np  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
SHARED = REPO.parent / "shared" / "data"
LENS = SHARED / "mrcal-models" / "cam0.opencv8.cameramodel"
KETTLE = SHARED / "lumigraph-kettle"


def _psnr(a: np.ndarray, b: np.ndarray, mask: np.ndarray) -> float:
    return float(10 * np.log10(1.0 / np.mean((a[mask].astype(np.float64) - b[mask]) ** 2)))


def _rig_file(tmp: Path) -> Path:
    lens = f'lens = "{LENS}"\n' if LENS.is_file() else ""
    if not lens:
        print(f"note: {LENS} not found; the cameras are pinholes (no real lens distortion)")
    p = tmp / "irregular5x5.toml"
    p.write_text(f"""[rig]
name = "irregular5x5"
[defaults]
driver = "mock"
width = 320
height = 240
fps = 30
pixel_format = "GREY"
fov_deg = 60
{lens}
[grid]
rows = 5
cols = 5
pitch = 0.02
[mock]
scene = "room"
motion = "smooth"
seed = 1
noise = 0.0
step_t = 0.005
step_r_deg = 0.2
""")
    return p


class _Direct:
    """A light-field sequence in memory, shaped like a store for the motion solver."""

    def __init__(self, grid, frames, timestamps_ns, weights=None):
        self.grid = grid
        self._frames = frames
        self._weights = weights
        self.timestamps_ns = timestamps_ns

    def frame(self, t):
        return self._frames[t]

    def weights(self, t):
        return None if self._weights is None else self._weights[t]


def _time_frames(rs, frame, repeat: int, threads: int | None = None) -> tuple[list[float], list[float]]:
    """Wall and CPU seconds of ``repeat`` resamplings of one frame on ``threads`` numba threads
    (default: all), after a warm-up (numba cache, buffers)."""
    import numba

    numba.set_num_threads(threads or numba.config.NUMBA_NUM_THREADS)
    rs.resample_into(frame)
    times, cpu = [], []
    for _ in range(repeat):
        t, c = time.perf_counter(), time.process_time()
        rs.resample_into(frame)
        times.append(time.perf_counter() - t)
        cpu.append(time.process_time() - c)
    return times, cpu


def _kdtree_baseline(models, grid, pixels: np.ndarray, k: int = 8):
    """Inverse-distance weighting of the k nearest scattered samples per cell (grid-step units)."""
    from scipy.spatial import cKDTree

    from resample.geometry import camera_layout, ray_samples

    lay = camera_layout(models)
    smp = ray_samples(models, grid, lay, margin=0.5)          # the same scattered samples
    t0 = time.perf_counter()
    tree = cKDTree(smp.coord)
    F, Ny, Nx, Nv, Nu = grid.shape
    cells = np.stack(np.meshgrid(np.arange(Ny), np.arange(Nx), np.arange(Nv), np.arange(Nu), indexing="ij"),
                     axis=-1).reshape(-1, 4).astype(float)
    d, idx = tree.query(cells, k=k, workers=-1)
    w = 1.0 / np.maximum(d, 1e-3) ** 2
    vals = pixels[smp.pixel[idx]]
    L = (np.sum(w * vals, axis=1) / np.sum(w, axis=1)).astype(np.float32).reshape(grid.shape)
    return L, time.perf_counter() - t0


def quality_and_speed(args, work: Path) -> dict:
    from polycam.evaluate import pair_errors
    from polycam.lfstore import open_lightfield
    from polycam.motion import estimate_trajectory
    from polycam.rig import load_rig
    from polycam.session import open_session
    from polycam.synth import LightFieldRenderer, scene_for_rig, synth_session
    from resample import ResampleOptions, Resampler, ViewFillOptions, auto_grid, resample_session

    rig = load_rig(_rig_file(work))
    frames = 3 if args.quick else 4
    t = time.perf_counter()
    synth_session(rig, work / "session", frames=frames, seed=1, supersample=2, bit_depth=8,
                  perturb_position_m=args.perturb_position_mm / 1e3,
                  perturb_rotation_deg=2.0, perturb_focal_frac=0.01, overwrite=True)
    print(f"session: {len(rig.cameras)} cameras x {frames} frames of 320x240 rendered in "
          f"{time.perf_counter() - t:.1f} s")
    s = open_session(work / "session")
    models = s.calibration()
    grid = auto_grid(models)
    F, Ny, Nx, Nv, Nu = grid.shape
    print(f"grid: {Ny}x{Nx} views ({grid.x.step * 100:.2f} cm apart), {Nv}x{Nu} directions, "
          f"f = {grid.faces[0].f:.1f}: {grid.num_rays / 1e6:.2f} M samples per frame")

    t = time.perf_counter()
    rs = Resampler(models, grid)
    t_geo = time.perf_counter() - t
    geo = rs.geometry
    rs_pp = Resampler(models, grid, options=ResampleOptions(view_fill="pushpull"), geometry=geo)
    rs_nr = Resampler(models, grid, options=ResampleOptions(fill=ViewFillOptions(recentre=False)), geometry=geo)
    n_rc = len(rs.fill_plan().recentre) if rs.fill_plan().recentre is not None else 0
    print(f"camera views re-centred onto their grid views (ViewFillOptions.recentre): {n_rc}")
    print(f"geometry: {t_geo:.1f} s, {geo.num_samples / 1e6:.2f} M samples, {geo.nnz / 1e6:.1f} M weights, "
          f"{100 * geo.linear_fraction:.1f}% local-linear cells")

    # --- direct renders of every frame (the reference)
    sc = scene_for_rig(s.rig, seed=1)
    rend = LightFieldRenderer(sc, grid, supersample=4)
    gt = s.groundtruth()
    t = time.perf_counter()
    direct = [rend.render(gt.T_world_rig[i]) for i in range(frames)]
    print(f"direct render: {frames} frames in {time.perf_counter() - t:.1f} s")

    # --- quality, frame by frame
    fr0 = s.read_frame(0)
    t = time.perf_counter()
    rs.resample(fr0)
    t_cold = time.perf_counter() - t
    t = time.perf_counter()
    rs_pp.resample(fr0)
    t_cold_pp = time.perf_counter() - t
    print(f"first frame (numba's compiled kernels loaded from its cache, or compiled on a first run): default "
          f"{t_cold:.1f} s, then pull-push alone {t_cold_pp:.1f} s")
    rows = []
    resampled, resampled_pp, resampled_nr = [], [], []
    for i in range(frames):
        r = rs.resample(s.read_frame(i))
        r_pp = rs_pp.resample(s.read_frame(i))
        r_nr = rs_nr.resample(s.read_frame(i))
        resampled.append(r)
        resampled_pp.append(r_pp)
        resampled_nr.append(r_nr)
        ref = direct[i]
        at_cam = np.zeros(grid.shape, bool)
        at_cam[:, ::2, ::2] = True
        good = at_cam & (r.W > 0.5)
        row = {"cam": _psnr(r.L, ref, good), "cam_cov": good.sum() / at_cam.sum(), "cam_nr": _psnr(r_nr.L, ref, good)}
        for name, sl_a, sl_m, sl_b in [
            ("mid-x", (slice(None), slice(0, None, 2), slice(0, -1, 2)), (slice(None), slice(0, None, 2), slice(1, None, 2)),
             (slice(None), slice(0, None, 2), slice(2, None, 2))),
            ("mid-y", (slice(None), slice(0, -1, 2), slice(0, None, 2)), (slice(None), slice(1, None, 2), slice(0, None, 2)),
             (slice(None), slice(2, None, 2), slice(0, None, 2))),
        ]:
            ok = (r.W[sl_a] > 0.5) & (r.W[sl_b] > 0.5)
            lin = 0.5 * (ref[sl_a] + ref[sl_b])
            row[name] = (_psnr(r.L[sl_m], ref[sl_m], ok), _psnr(lin, ref[sl_m], ok), _psnr(r_pp.L[sl_m], ref[sl_m], ok))
        # diagonal centres of four cameras
        c = [(slice(None), slice(a, -1 if a == 0 else None, 2), slice(b, -1 if b == 0 else None, 2))
             for a in (0, 2) for b in (0, 2)]
        sl_m = (slice(None), slice(1, None, 2), slice(1, None, 2))
        ok = np.logical_and.reduce([r.W[cc] > 0.5 for cc in c])
        lin = 0.25 * sum(ref[cc] for cc in c)
        row["centre"] = (_psnr(r.L[sl_m], ref[sl_m], ok), _psnr(lin, ref[sl_m], ok), _psnr(r_pp.L[sl_m], ref[sl_m], ok))
        rows.append(row)

    print("\nQuality vs the direct render (PSNR [dB]; between cameras: resampled (default, depth-aware fill) / "
          "linear interpolation of the direct neighbours / resampled with the pull-push alone)")
    print("| frame | at cameras, W > 0.5 (share of samples) | the same without re-centring | half-way along x | "
          "half-way along y | centre of 4 |")
    print("| --- | --- | --- | --- | --- | --- |")
    for i, row in enumerate(rows):
        print(f"| {i} | {row['cam']:.2f} ({100 * row['cam_cov']:.0f}%) | {row['cam_nr']:.2f} | "
              + " | ".join(f"{row[k][0]:.2f} / {row[k][1]:.2f} / {row[k][2]:.2f}" for k in ("mid-x", "mid-y", "centre"))
              + " |")
    cam_min = min(r["cam"] for r in rows)
    mid_margin = min(r[k][0] - r[k][1] for r in rows for k in ("mid-x", "mid-y", "centre"))
    print(f"target PSNR >= 40 dB at the cameras: worst frame {cam_min:.2f} dB -> "
          f"{'met' if cam_min >= 40 else 'NOT met'}")
    print(f"target between cameras no worse than interpolated direct views: worst margin {mid_margin:+.2f} dB -> "
          f"{'met' if mid_margin >= 0 else 'NOT met'}")

    # --- speed: one frame, geometry built, on 1 thread and on all
    import numba

    fr = s.read_frame(0)
    nmax = numba.config.NUMBA_NUM_THREADS
    load0 = os.getloadavg()[0]
    speed = {}
    for th in sorted({1, nmax}):
        for name, r_ in (("default", rs), ("norecentre", rs_nr), ("pushpull", rs_pp)):
            speed[name, th] = _time_frames(r_, fr, args.repeat, th)
    numba.set_num_threads(nmax)
    load1 = os.getloadavg()[0]
    pix, _ = rs.pixels(fr)
    pixels = pix[:, 0].copy()
    print(f"\nbaseline: cKDTree inverse distance on {geo.num_samples / 1e6:.2f} M samples, 8 neighbours per cell ...")
    L_kd, t_kd = _kdtree_baseline(models, grid, pixels)
    ref = direct[0]
    r0 = resampled[0]
    at_cam = np.zeros(grid.shape, bool)
    at_cam[:, ::2, ::2] = True
    regions = [("at cameras, W > 0.5", at_cam & (r0.W > 0.5)), ("holes at cameras", at_cam & (r0.W <= 0.5)),
               ("between cameras", ~at_cam), ("all samples", np.ones(grid.shape, bool))]
    rays = rs.num_pixels
    print(f"\nSpeed per frame once the geometry is built (frame 0, {rays / 1e6:.2f} M input rays; best and median of "
          f"{args.repeat}; load average {load0:.1f} -> {load1:.1f} on {os.cpu_count()} cores)")
    print("| method | threads | wall s best / median | CPU s best | M input rays / s: wall best / median | "
          "M rays / CPU-second |")
    print("| --- | --- | --- | --- | --- | --- |")
    labels = {"default": "polycam default (push-pull + depth-aware view fill, camera views re-centred)",
              "norecentre": "the same without re-centring the camera views", "pushpull": "polycam push-pull alone"}
    for (name, th), (times, cpu) in speed.items():
        b, m = min(times), float(np.median(times))
        print(f"| {labels[name]} | {th} | {b:.3f} / {m:.3f} | {min(cpu):.3f} | {rays / b / 1e6:.1f} / "
              f"{rays / m / 1e6:.1f} | {rays / min(cpu) / 1e6:.1f} |")
    print(f"| cKDTree IDW (k = 8), tree + query + weights | all | {t_kd:.2f} | | {rays / t_kd / 1e6:.2f} | |")
    best = min(speed["default", nmax][0])
    med = float(np.median(speed["default", nmax][0]))
    best1 = min(speed["default", 1][0])
    cpu1 = min(speed["default", 1][1])
    print(f"DEFAULT PATH: {rays / best / 1e6:.1f} M input rays/s per frame (best wall, {nmax} threads; median "
          f"{rays / med / 1e6:.1f}), {rays / best1 / 1e6:.1f} M rays/s on 1 thread, {rays / cpu1 / 1e6:.1f} M rays per "
          f"CPU-second (1 thread: {1000 * cpu1:.0f} ms CPU per frame); {t_kd / best:.0f}x the cKDTree baseline "
          f"(same run)")
    print("\nPSNR [dB] vs the direct render, frame 0 (share of the samples)")
    print("| region | share | polycam default | polycam push-pull alone | cKDTree IDW |")
    print("| --- | --- | --- | --- | --- |")
    for name, m in regions:
        print(f"| {name} | {100 * m.mean():.0f}% | {_psnr(r0.L, ref, m):.2f} | {_psnr(resampled_pp[0].L, ref, m):.2f} | "
              f"{_psnr(L_kd, ref, m):.2f} |")
    measured_ok = _psnr(r0.L, ref, regions[0][1]) >= _psnr(L_kd, ref, regions[0][1])
    print(f"speed-up vs cKDTree (default, {nmax} threads): {t_kd / best:.0f}x (best), {t_kd / med:.0f}x (median). "
          f"Targets: >= 20 M rays/s (default): {'met' if rays / best >= 20e6 else 'NOT met'} at best wall in this run, "
          f"{'met' if rays / med >= 20e6 else 'NOT met'} at median (load average {load0:.1f} -> {load1:.1f}; the target "
          f"is for an idle machine: see the CPU figure); >= 10x faster at equal or better PSNR where the cameras "
          f"measured: {'met' if t_kd / med >= 10 and measured_ok else 'NOT met'}")

    # --- whole sessions: PNG reading, zarr writing; a longer session (the frames repeated)
    long = _long_session(s, work / "session-long", 6 if args.quick else 24)
    print(f"\nWhole session (resample_session on {len(open_session(long))} frames of the same rig, including "
          "PNG decoding and zarr writing)")
    print("| scheduler | frames | geometry [s] | frames [s] | frames / s | M input rays / s |")
    print("| --- | --- | --- | --- | --- | --- |")
    for sched, workers in (("sync", None), ("local", 2)):
        out = work / f"lf-long-{sched}.zarr"
        summ = resample_session(long, out, scheduler=sched, workers=workers, overwrite=True)
        fps = summ.frames / summ.seconds_frames
        print(f"| {summ.scheduler} | {summ.frames} | {summ.seconds_geometry:.1f} | {summ.seconds_frames:.1f} | "
              f"{fps:.2f} | {fps * rays / 1e6:.1f} |")

    # --- motion from the resampled and the direct light fields
    summ = resample_session(work / "session", work / "lf.zarr", scheduler="sync", overwrite=True)
    lf = open_lightfield(summ.path)
    direct_store = _Direct(grid, direct, s.timestamps_ns)
    motion_rows = [("9x9 views, default (depth-aware fill; resample_session, store)", lf, direct_store),
                   ("9x9 views, pull-push alone (depth-free)",
                    _Direct(grid, [r.L for r in resampled_pp], s.timestamps_ns, [r.W for r in resampled_pp]),
                    direct_store),
                   ("9x9 views, without re-centring the camera views",
                    _Direct(grid, [r.L for r in resampled_nr], s.timestamps_ns, [r.W for r in resampled_nr]),
                    direct_store)]
    grid_c = auto_grid(models, xy_oversample=1)
    rs_c = Resampler(models, grid_c)
    rend_c = LightFieldRenderer(sc, grid_c, supersample=4)
    res_c = [rs_c.resample(s.read_frame(i)) for i in range(frames)]
    motion_rows.append((f"{grid_c.y.count}x{grid_c.x.count} views (at the cameras)",
                        _Direct(grid_c, [r.L for r in res_c], s.timestamps_ns, [r.W for r in res_c]),
                        _Direct(grid_c, [rend_c.render(gt.T_world_rig[i]) for i in range(frames)], s.timestamps_ns)))
    print(f"\nPlenoptic motion ({frames - 1} frame pairs; median per-pair errors vs ground truth, "
          f"|t| ~ 5 mm, |w| ~ 0.2 deg per pair)")
    print("| grid | direct render: t / w error | resampled: t / w error | resampled / direct: t / w | s per pair |")
    print("| --- | --- | --- | --- | --- |")
    direct_errors = {}
    for name, res_store, dir_store in motion_rows:
        t = time.perf_counter()
        traj_r, _ = estimate_trajectory(res_store)
        t_pair = (time.perf_counter() - t) / (frames - 1)
        if id(dir_store) not in direct_errors:
            direct_errors[id(dir_store)] = pair_errors(estimate_trajectory(dir_store)[0], gt)
        e_r, e_d = pair_errors(traj_r, gt), direct_errors[id(dir_store)]
        rt = float(np.median(e_r.t_rel) / max(np.median(e_d.t_rel), 1e-12))
        rw = float(np.median(e_r.w_rel) / max(np.median(e_d.w_rel), 1e-12))
        print(f"| {name} | {100 * np.median(e_d.t_rel):.2f}% / {100 * np.median(e_d.w_rel):.2f}% | "
              f"{100 * np.median(e_r.t_rel):.2f}% / {100 * np.median(e_r.w_rel):.2f}% | {rt:.2f}x / {rw:.2f}x "
              f"({'within' if max(rt, rw) <= 2 else 'NOT within'} 2x) | {t_pair:.0f} |")
    print("(between cameras the direct render has real views; the pull-push alone fills them depth-free, the "
          "default along the disparity of a plane sweep)")
    return {"cam_psnr": cam_min}


def _long_session(s, path: Path, frames: int) -> Path:
    """A session of ``frames`` frames cycling through the frames of session ``s`` (same images)."""
    from polycam.session import SessionWriter

    with SessionWriter(path, s.rig, overwrite=True) as w:
        for cam, m in s.calibration().items():
            w.write_calibration(cam, m)
        cache = [s.read_frame(i) for i in range(len(s))]
        for i in range(frames):
            w.add_frame(1_000_000 + i * 33_333_333, cache[i % len(cache)])
    return path


def _kettle_rig_frame(models: dict) -> dict:
    """Re-express COLMAP-world models in a rig frame at the mean camera centre whose z axis is
    the mean viewing direction (x from the mean image x axis, made orthogonal)."""
    import mrcal

    from polycam.cameras import T_rig_cam_of
    from polycam.geometry import T_from_Rt, T_inverse, rt_from_T

    T = {n: T_rig_cam_of(m) for n, m in models.items()}           # T_world_cam
    z = np.mean([t[:3, 2] for t in T.values()], axis=0)
    z /= np.linalg.norm(z)
    x = np.mean([t[:3, 0] for t in T.values()], axis=0)
    x -= z * (x @ z)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    c = np.mean([t[:3, 3] for t in T.values()], axis=0)
    T_world_rig = T_from_Rt(np.stack([x, y, z], axis=1), c)
    out = {}
    for n, m in models.items():
        T_rig_cam = T_inverse(T_world_rig) @ T[n]
        out[n] = mrcal.cameramodel(intrinsics=m.intrinsics(), imagersize=m.imagersize(),
                                   rt_cam_ref=rt_from_T(T_inverse(T_rig_cam)))
    return out


def _scaled(model, k: float):
    """The model of the image scaled by k (pixel centres at integers: c' = (c + 0.5) k - 0.5)."""
    import mrcal

    lens, intr = model.intrinsics()
    intr = np.array(intr, float)
    intr[:2] *= k
    intr[2:4] = (intr[2:4] + 0.5) * k - 0.5
    W, H = model.imagersize()
    return mrcal.cameramodel(intrinsics=(lens, intr), imagersize=np.array([round(W * k), round(H * k)]),
                             rt_cam_ref=model.rt_cam_ref())


def kettle(args, out: Path) -> None:
    import cv2

    from calib import import_colmap_text
    from resample import Resampler, auto_grid

    if not KETTLE.is_dir():
        print(f"\nkettle data not found at {KETTLE}: skipped")
        return
    stored = import_colmap_text(KETTLE)
    files = {p.name: p for p in (KETTLE / "images").glob("*.jpg")}
    k = 0.25
    models, images = {}, {}
    for name, m in stored.items():
        fname = name.split(" ")[-1]              # the model says "2021-05-19 20.23.45.jpg"
        if fname not in files:
            continue
        W, H = (int(v) for v in m.imagersize())
        img = cv2.imread(str(files[fname]), cv2.IMREAD_COLOR)[:, :, ::-1]
        img = cv2.resize(img, (W, H), interpolation=cv2.INTER_AREA)              # back to the model's size
        img = cv2.resize(img, (round(W * k), round(H * k)), interpolation=cv2.INTER_AREA)
        cam = fname.removesuffix(".jpg")
        models[cam] = _scaled(m, k)
        images[cam] = np.ascontiguousarray(img)
    models = _kettle_rig_frame(models)
    # a view per camera spacing and a direction per 2 pixels: 6 M samples x RGB
    grid = auto_grid(models, uv_step_px=2.0, xy_oversample=1)
    F, Ny, Nx, Nv, Nu = grid.shape
    t = time.perf_counter()
    rs = Resampler(models, grid, channels=3)
    t_geo = time.perf_counter() - t
    t = time.perf_counter()
    r = rs.resample(images)
    t_frame = time.perf_counter() - t
    print(f"\nKettle (unstructured lumigraph): {len(models)} photos at {images[next(iter(images))].shape[1]}x"
          f"{images[next(iter(images))].shape[0]}, grid {Ny}x{Nx} views x {Nv}x{Nu} directions (RGB); geometry "
          f"{t_geo:.1f} s, resample {t_frame:.2f} s; W > 0.5 on {100 * np.mean(r.W > 0.5):.0f}% of the samples")
    out.mkdir(parents=True, exist_ok=True)
    # a mosaic of views across the grid (rows along y, columns along x), W as a strip below each
    picks_y = np.unique(np.linspace(0, Ny - 1, min(Ny, 4)).round().astype(int))
    picks_x = np.unique(np.linspace(0, Nx - 1, min(Nx, 5)).round().astype(int))
    tiles = []
    for j in picks_y:
        row = []
        for i in picks_x:
            view = np.clip(r.L[0, j, i], 0, 1)
            w = r.W[0, j, i]
            shaded = view * (0.35 + 0.65 * w[..., None])            # low confidence shows dark
            row.append(np.pad(shaded, ((2, 2), (2, 2), (0, 0)), constant_values=1.0))
        tiles.append(np.concatenate(row, axis=1))
    mosaic = (np.concatenate(tiles, axis=0) * 255).astype(np.uint8)
    cv2.imwrite(str(out / "kettle_views.png"), mosaic[:, :, ::-1])
    # three photos, each next to the grid view its optical axis passes through
    from polycam.cameras import T_rig_cam_of

    pairs = []
    z_pi = grid.faces[0].z_pi
    for cam in list(models)[::10][:3]:
        T = T_rig_cam_of(models[cam])
        a = T[:3, 2]
        c = T[:3, 3] + (z_pi - T[2, 3]) / a[2] * a
        i = int(np.clip(round((c[0] - grid.x.min) / max(grid.x.step, 1e-12)), 0, Nx - 1))
        j = int(np.clip(round((c[1] - grid.y.min) / max(grid.y.step, 1e-12)), 0, Ny - 1))
        view = (np.clip(r.L[0, j, i], 0, 1) * 255).astype(np.uint8)
        photo = images[cam]
        h = view.shape[0]
        photo = cv2.resize(photo, (round(photo.shape[1] * h / photo.shape[0]), h))
        pairs.append(np.concatenate([photo, np.full((h, 4, 3), 255, np.uint8), view], axis=1))
    wmax = max(p.shape[1] for p in pairs)
    pairs = [np.pad(p, ((0, 4), (0, wmax - p.shape[1]), (0, 0)), constant_values=255) for p in pairs]
    cv2.imwrite(str(out / "kettle_photo_vs_view.png"), np.concatenate(pairs, axis=0)[:, :, ::-1])
    print(f"views written to {out / 'kettle_views.png'} (grid views, darker = lower W) and "
          f"{out / 'kettle_photo_vs_view.png'} (photo | the grid view on its optical axis)")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="3 frames instead of 4")
    ap.add_argument("--repeat", type=int, default=7, help="timed repetitions per frame (default 7)")
    ap.add_argument("--out", default=os.path.join(tempfile.gettempdir(), "polycam-bench-resample"),
                    help="folder for the PNGs and the work files")
    ap.add_argument("--skip-kettle", action="store_true")
    ap.add_argument("--perturb-position-mm", type=float, default=0.0,
                    help="std of the camera centres' offsets from the rig file [mm] (polycam run's rig: 1; "
                         "default 0: the cameras on the grid views)")
    args = ap.parse_args()
    out = Path(args.out)
    work = out / "work"
    work.mkdir(parents=True, exist_ok=True)
    print(f"machine: {os.cpu_count()} cores, load average {os.getloadavg()[0]:.1f} at the start")
    quality_and_speed(args, work)
    if not args.skip_kettle:
        kettle(args, out)
    print(f"load average {os.getloadavg()[0]:.1f} at the end")
    return 0


if __name__ == "__main__":
    sys.exit(main())
