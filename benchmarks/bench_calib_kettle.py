"""Real photos: the lumigraph kettle (28 photos, 1280x960, MIT) — import its COLMAP
model, reconstruct it afresh with the COLMAP path (:func:`calib.reconstruct_images`:
SIFT, exhaustive matching, incremental mapping), and report how well the two agree:
camera centres after a similarity alignment (relative to the size of the camera
cloud) and camera orientations after the same alignment.

The stored model names the photos "2021-05-19 20.23.45.jpg" while the files are
"20.23.45.jpg" (matched by the time part), and the photos are ~1265x949, not the
model's 1280x960: they were cropped/resized after that model was made, so only
poses compare cleanly. Features are extracted on images downscaled to --max-image-size (default 1024 px,
to keep the run short on 2 cores); one SIMPLE_RADIAL camera per image, as in the stored model.
The baseline for the time ratio is the import of the stored model (same run).

Run: ``python benchmarks/bench_calib_kettle.py [--max-image-size 1024] [--work DIR]``.
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
KETTLE = REPO.parent / "shared" / "data" / "lumigraph-kettle"


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--max-image-size", type=int, default=1024)
    ap.add_argument("--camera-mode", default="PER_IMAGE", choices=("SINGLE", "PER_IMAGE"))
    ap.add_argument("--work", default="/tmp/polycam-bench-kettle")
    args = ap.parse_args()
    if not KETTLE.is_dir():
        print(f"kettle data not found at {KETTLE}: skipped")
        return 0
    from calib import import_colmap_text, reconstruct_images
    from calib.align import fit_similarity, rotation_angle
    from calib.colmap import reconstruction_poses
    from polycam.geometry import T_from_rt

    t = time.perf_counter()
    stored = import_colmap_text(KETTLE)
    t_import = time.perf_counter() - t
    t = time.perf_counter()
    rec, _ = reconstruct_images(KETTLE / "images", args.work, camera_mode=args.camera_mode,
                                camera_model="SIMPLE_RADIAL", max_image_size=args.max_image_size)
    t_rec = time.perf_counter() - t
    new = reconstruction_poses(rec)
    # the stored model calls the photos "2021-05-19 20.23.45.jpg"; the files are "20.23.45.jpg"
    stored = {n.split(" ")[-1]: m for n, m in stored.items()}
    names = sorted(set(new) & set(stored))
    T_old = np.stack([T_from_rt(stored[n].rt_cam_ref()) for n in names])      # cam_from_world
    T_new = np.stack([new[n] for n in names])
    C_old = np.einsum("nji,nj->ni", T_old[:, :3, :3], -T_old[:, :3, 3])
    C_new = np.einsum("nji,nj->ni", T_new[:, :3, :3], -T_new[:, :3, 3])
    s, R, tr = fit_similarity(C_new, C_old)
    C_al = s * C_new @ R.T + tr
    extent = float(np.sqrt(np.mean(np.sum((C_old - C_old.mean(axis=0)) ** 2, axis=1))))
    cerr = np.linalg.norm(C_al - C_old, axis=1)
    R_pred = T_new[:, :3, :3] @ R.T                                  # new cam_from_world in the old world
    rerr = np.degrees(rotation_angle(np.einsum("nij,nkj->nik", R_pred, T_old[:, :3, :3])))
    cam = next(iter(rec.cameras.values()))
    f_old = np.median([m.intrinsics()[1][0] / m.imagersize()[0] for m in stored.values()])   # per image width
    import cv2

    w_file = cv2.imread(str(KETTLE / "images" / names[0])).shape[1]
    print(f"kettle: {len(stored)} images in the stored model, {len(new)} registered afresh "
          f"({len(names)} in common); SIFT on images downscaled to <= {args.max_image_size} px")
    print(f"{'quantity':44s} {'value':>10s}")
    print(f"{'camera centres, RMS after similarity [% of extent]':44s} {100 * math.sqrt(np.mean(cerr**2)) / extent:10.3f}")
    print(f"{'camera centres, worst [% of extent]':44s} {100 * cerr.max() / extent:10.3f}")
    print(f"{'orientations, RMS [deg]':44s} {math.sqrt(np.mean(rerr**2)):10.4f}")
    print(f"{'orientations, worst [deg]':44s} {rerr.max():10.4f}")
    print(f"{'focal/width, new / stored (median)':44s} {cam.params[0] / cam.width / f_old:10.4f}")
    print(f"(the photos are {w_file} px wide, the stored model says {int(next(iter(stored.values())).imagersize()[0])}: "
          "they were cropped or resized after that model was made, so intrinsics compare only roughly)")
    print(f"{'reprojection error, new model (mean) [px]':44s} {rec.compute_mean_reprojection_error():10.3f}")
    print(f"{'time: reconstruct [s]':44s} {t_rec:10.1f}")
    print(f"{'time: import stored model [s] (baseline)':44s} {t_import:10.3f}")
    print(f"ratio reconstruct / import: {t_rec / max(t_import, 1e-9):.0f}x")
    return 0


if __name__ == "__main__":
    sys.exit(main())
