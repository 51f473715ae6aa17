"""COLMAP text models (``cameras.txt``, ``images.txt``) and rig configs ↔ mrcal cameramodels.

Lens models: COLMAP ``SIMPLE_PINHOLE``/``PINHOLE`` ↔ ``LENSMODEL_PINHOLE``;
``SIMPLE_RADIAL`` (f, cx, cy, k), ``RADIAL`` (f, cx, cy, k1, k2) and ``OPENCV``
(fx, fy, cx, cy, k1, k2, p1, p2) → ``LENSMODEL_OPENCV4``; ``FULL_OPENCV`` ↔
``LENSMODEL_OPENCV8``; ``LENSMODEL_OPENCV4`` → ``OPENCV`` and ``LENSMODEL_OPENCV5``
→ ``FULL_OPENCV`` (k4..k6 = 0). Other models (fisheye, splined) raise
:class:`~polycam.errors.InputError`: there is no exact equivalent.

Pixel convention: COLMAP puts the centre of the top-left pixel at (0.5, 0.5),
mrcal at (0, 0), so ``cx_colmap = cx_mrcal + 0.5`` (same for cy).

Poses: ``images.txt`` holds ``cam_from_world`` (QW QX QY QZ TX TY TZ); the imported
models' reference frame is COLMAP's world (``rt_cam_ref = cam_from_world``).
Rig configs (``rig_config.json``, what ``colmap rig_configurator`` and
``pycolmap.read_rig_config`` read) express every sensor in the frame of the
reference sensor, COLMAP's rig frame: ``cam_from_rig = T_cam_i_cam_ref``.
"""

from __future__ import annotations

import json
import logging
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from polycam.errors import FormatError, InputError
from polycam.geometry import R_from_quat, T_from_Rt, T_from_rt, T_inverse, quat_from_R, rt_from_T
from polycam.rig import MAX_IMAGE_SIDE
from polycam.tomlio import atomic_write_text

__all__ = [
    "ColmapCamera",
    "ColmapImage",
    "read_colmap_text",
    "colmap_to_mrcal",
    "mrcal_to_colmap",
    "import_colmap_text",
    "write_colmap_text",
    "rig_config",
    "write_rig_config",
]

log = logging.getLogger(__name__)

_NPARAMS = {"SIMPLE_PINHOLE": 3, "PINHOLE": 4, "SIMPLE_RADIAL": 4, "RADIAL": 5, "OPENCV": 8, "FULL_OPENCV": 12}


@dataclass(frozen=True)
class ColmapCamera:
    """One ``cameras.txt`` row."""

    camera_id: int
    model: str
    width: int
    height: int
    params: np.ndarray
    """COLMAP parameters (pixel centre of the top-left pixel at 0.5)."""


@dataclass(frozen=True)
class ColmapImage:
    """One ``images.txt`` image (its pose; the 2-D points are not kept)."""

    image_id: int
    name: str
    camera_id: int
    T_cam_world: np.ndarray
    """(4, 4) COLMAP's cam_from_world."""


def _data_lines(path: Path) -> list[tuple[int, str]]:
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise FormatError(path, "no such file") from None
    except (OSError, UnicodeDecodeError) as e:
        raise FormatError(path, f"cannot read ({e})") from None
    return [(n + 1, ln) for n, ln in enumerate(text.split("\n"))]


def read_colmap_text(model_dir: str | os.PathLike) -> tuple[dict[int, ColmapCamera], list[ColmapImage]]:
    """Parse ``cameras.txt`` and ``images.txt`` of a COLMAP text model folder."""
    d = Path(model_dir)
    cams: dict[int, ColmapCamera] = {}
    p = d / "cameras.txt"
    for n, ln in _data_lines(p):
        s = ln.strip()
        if not s or s.startswith("#"):
            continue
        f = s.split()
        try:
            cid, model, w, h = int(f[0]), f[1], int(f[2]), int(f[3])
            params = np.array([float(v) for v in f[4:]])
        except (ValueError, IndexError):
            raise FormatError(p, f"expected 'CAMERA_ID MODEL WIDTH HEIGHT PARAMS...', got {s[:60]!r}",
                              f"line {n}") from None
        if model not in _NPARAMS:
            raise FormatError(p, f"camera {cid}: model {model} has no mrcal equivalent (supported: "
                                 f"{', '.join(_NPARAMS)})", f"line {n}")
        if params.size != _NPARAMS[model]:
            raise FormatError(p, f"{model} needs {_NPARAMS[model]} parameters, got {params.size}", f"line {n}")
        if not (1 <= w <= MAX_IMAGE_SIDE and 1 <= h <= MAX_IMAGE_SIDE):
            raise FormatError(p, f"camera {cid}: WIDTH and HEIGHT must be 1..{MAX_IMAGE_SIDE}, got {w} x {h}",
                              f"line {n}")
        if not np.all(np.isfinite(params)):
            raise FormatError(p, f"camera {cid}: non-finite parameter", f"line {n}")
        nf = 1 if model in ("SIMPLE_PINHOLE", "SIMPLE_RADIAL", "RADIAL") else 2     # focal lengths first
        if not np.all(params[:nf] > 0):
            raise FormatError(p, f"camera {cid}: focal length must be > 0, got {params[:nf].tolist()}", f"line {n}")
        if cid in cams:
            raise FormatError(p, f"camera {cid} is listed twice", f"line {n}")
        cams[cid] = ColmapCamera(cid, model, w, h, params)
    images: list[ColmapImage] = []
    p = d / "images.txt"
    lines = [(n, ln) for n, ln in _data_lines(p) if not ln.startswith("#")]
    # two lines per image: the pose line, then the (possibly empty) 2-D points line
    seen_ids: set[int] = set()
    seen_names: set[str] = set()
    i = 0
    while i < len(lines):
        n, ln = lines[i]
        s = ln.strip()
        if not s:
            i += 1
            continue
        f = s.split(maxsplit=9)
        try:
            iid = int(f[0])
            qw, qx, qy, qz, tx, ty, tz = (float(v) for v in f[1:8])
            cid, name = int(f[8]), f[9]
        except (ValueError, IndexError):
            raise FormatError(p, "expected 'IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME'", f"line {n}") from None
        if cid not in cams:
            raise FormatError(p, f"image {name!r} refers to camera {cid}, which cameras.txt lacks", f"line {n}")
        if iid in seen_ids or name in seen_names:
            raise FormatError(p, f"image {iid if iid in seen_ids else repr(name)} is listed twice", f"line {n}")
        seen_ids.add(iid)
        seen_names.add(name)
        q = np.array([qx, qy, qz, qw])
        if not np.all(np.isfinite([qw, qx, qy, qz, tx, ty, tz])):
            raise FormatError(p, f"pose of image {name!r}: non-finite value", f"line {n}")
        if not np.isclose(np.linalg.norm(q), 1.0, atol=1e-3):
            raise FormatError(p, f"quaternion of image {name!r} is not a unit quaternion", f"line {n}")
        T = T_from_Rt(R_from_quat(q / np.linalg.norm(q)), np.array([tx, ty, tz]))
        images.append(ColmapImage(iid, name, cid, T))
        i += 2
    return cams, images


def colmap_to_mrcal(cam: ColmapCamera) -> tuple[str, np.ndarray]:
    """(mrcal lens model, intrinsics) of a COLMAP camera (pixel convention converted)."""
    p = np.asarray(cam.params, float)
    m = cam.model
    if m == "SIMPLE_PINHOLE":
        lens, intr = "LENSMODEL_PINHOLE", [p[0], p[0], p[1], p[2]]
    elif m == "PINHOLE":
        lens, intr = "LENSMODEL_PINHOLE", list(p[:4])
    elif m == "SIMPLE_RADIAL":
        lens, intr = "LENSMODEL_OPENCV4", [p[0], p[0], p[1], p[2], p[3], 0.0, 0.0, 0.0]
    elif m == "RADIAL":
        lens, intr = "LENSMODEL_OPENCV4", [p[0], p[0], p[1], p[2], p[3], p[4], 0.0, 0.0]
    elif m == "OPENCV":
        lens, intr = "LENSMODEL_OPENCV4", list(p[:8])
    elif m == "FULL_OPENCV":
        lens, intr = "LENSMODEL_OPENCV8", list(p[:12])
    else:
        raise InputError(f"COLMAP camera {cam.camera_id}: model {m} has no mrcal equivalent "
                         f"(supported: {', '.join(_NPARAMS)})")
    intr = np.array(intr, float)
    intr[2:4] -= 0.5
    return lens, intr


def mrcal_to_colmap(lensmodel: str, intrinsics: np.ndarray) -> tuple[str, np.ndarray]:
    """(COLMAP model name, params) of mrcal intrinsics (pixel convention converted)."""
    i = np.array(intrinsics, float)
    i[2:4] += 0.5
    if lensmodel == "LENSMODEL_PINHOLE":
        return "PINHOLE", i[:4]
    if lensmodel == "LENSMODEL_OPENCV4":
        return "OPENCV", i[:8]
    if lensmodel == "LENSMODEL_OPENCV5":
        return "FULL_OPENCV", np.concatenate([i[:9], np.zeros(3)])
    if lensmodel == "LENSMODEL_OPENCV8":
        return "FULL_OPENCV", i[:12]
    raise InputError(f"{lensmodel} has no COLMAP equivalent (export needs LENSMODEL_PINHOLE or "
                     "LENSMODEL_OPENCV4/5/8; calibrate with --lensmodel opencv8)")


def import_colmap_text(model_dir: str | os.PathLike) -> dict:
    """Image name → mrcal.cameramodel (rt_cam_ref = cam_from_world) of a COLMAP text model."""
    import mrcal

    cams, images = read_colmap_text(model_dir)
    if not images:
        raise FormatError(Path(model_dir) / "images.txt", "no images")
    out = {}
    for im in sorted(images, key=lambda im: im.name):
        c = cams[im.camera_id]
        lens, intr = colmap_to_mrcal(c)
        out[im.name] = mrcal.cameramodel(intrinsics=(lens, intr), imagersize=np.array([c.width, c.height]),
                                         rt_cam_ref=rt_from_T(im.T_cam_world))
    return out


def write_colmap_text(models: dict, out: str | os.PathLike) -> list[Path]:
    """``cameras.txt``, ``images.txt`` (poses only, no 2-D points) and an empty ``points3D.txt``.

    models: name → mrcal model; each becomes one camera and one image named ``name``
    whose cam_from_world is the model's ``rt_cam_ref`` (world = the models' reference).
    """
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    cl = ["# Camera list with one line of data per camera:", "#   CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]",
          f"# Number of cameras: {len(models)}"]
    il = ["# Image list with two lines of data per image:",
          "#   IMAGE_ID, QW, QX, QY, QZ, TX, TY, TZ, CAMERA_ID, NAME", "#   POINTS2D[] as (X, Y, POINT3D_ID)",
          f"# Number of images: {len(models)}, mean observations per image: 0"]
    for k, (name, m) in enumerate(models.items(), start=1):
        model, params = mrcal_to_colmap(*m.intrinsics())
        W, H = (int(v) for v in m.imagersize())
        cl.append(f"{k} {model} {W} {H} " + " ".join(f"{v:.12g}" for v in params))
        T = T_from_rt(m.rt_cam_ref())
        qx, qy, qz, qw = quat_from_R(T[:3, :3])
        if qw < 0:
            qx, qy, qz, qw = -qx, -qy, -qz, -qw
        t = T[:3, 3]
        il.append(f"{k} {qw:.15g} {qx:.15g} {qy:.15g} {qz:.15g} {t[0]:.15g} {t[1]:.15g} {t[2]:.15g} {k} {name}")
        il.append("")
    files = [out / "cameras.txt", out / "images.txt", out / "points3D.txt"]
    atomic_write_text(files[0], "\n".join(cl) + "\n")
    atomic_write_text(files[1], "\n".join(il) + "\n")
    atomic_write_text(files[2], "# 3D point list with one line of data per point:\n"
                                "#   POINT3D_ID, X, Y, Z, R, G, B, ERROR, TRACK[] as (IMAGE_ID, POINT2D_IDX)\n")
    return files


def rig_config(models: dict, *, prefixes: dict[str, str] | None = None, ref: str | None = None,
               with_intrinsics: bool = True) -> list[dict]:
    """A COLMAP rig config (JSON-ready list with one rig) of a calibrated rig.

    models: camera id → mrcal model (rt_cam_ref = T_cam_rig).
    prefixes: camera id → COLMAP image prefix (default ``"<cam>/"``).
    ref: the reference sensor (default the first camera).
    """
    cams = list(models)
    ref = ref if ref is not None else cams[0]
    T_ref_rig = T_from_rt(models[ref].rt_cam_ref())
    entries = []
    for cam in cams:
        e: dict = {"image_prefix": (prefixes or {}).get(cam, f"{cam}/")}
        if cam == ref:
            e["ref_sensor"] = True
        else:
            T_cam_ref = T_from_rt(models[cam].rt_cam_ref()) @ T_inverse(T_ref_rig)
            qx, qy, qz, qw = quat_from_R(T_cam_ref[:3, :3])
            e["cam_from_rig_rotation"] = [float(v) for v in (qw, qx, qy, qz)]
            e["cam_from_rig_translation"] = [float(v) for v in T_cam_ref[:3, 3]]
        if with_intrinsics:
            name, params = mrcal_to_colmap(*models[cam].intrinsics())
            e["camera_model_name"] = name
            e["camera_params"] = [float(v) for v in params]
        entries.append(e)
    return [{"cameras": entries}]


def write_rig_config(models: dict, path: str | os.PathLike, **kwargs) -> Path:
    """Write :func:`rig_config` as JSON (``pycolmap.read_rig_config`` reads it)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_text(path, json.dumps(rig_config(models, **kwargs), indent=2) + "\n")
    return path
