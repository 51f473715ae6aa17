"""Exports of a calibration (camera id → mrcal model, rt_cam_ref = T_cam_rig) for other tools.

- :func:`write_colmap_rig`: ``colmap/rig_config.json`` (+ ``cameras.txt``,
  ``images.txt`` with one image per camera at its rig pose) — see
  :mod:`calib.colmap_text` for the conventions.
- :func:`write_kalibr_camchain`: Kalibr ``camchain.yaml`` (``pinhole`` +
  ``radtan``; so only LENSMODEL_PINHOLE / LENSMODEL_OPENCV4 models), with
  ``T_cn_cnm1`` from each camera to the next and, as a polycam extra key,
  ``T_cam_rig``. Kalibr and mrcal share the pixel-centre convention.
- :func:`write_opencv_yaml`: an OpenCV ``FileStorage`` YAML with, per camera,
  ``camera_matrix`` (3x3), ``distortion_coefficients`` (1xN, OpenCV order
  k1 k2 p1 p2 [k3 [k4 k5 k6]]), ``image_size`` [w, h], ``R_cam_rig`` (3x3) and
  ``t_cam_rig`` (3x1) [m]; read with ``cv2.FileStorage``.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from polycam.errors import InputError
from polycam.geometry import T_from_rt, T_inverse
from polycam.tomlio import atomic_write_text

from .colmap_text import write_colmap_text, write_rig_config

__all__ = ["write_colmap_rig", "write_kalibr_camchain", "write_opencv_yaml", "opencv_intrinsics",
           "read_opencv_yaml"]

_OPENCV_NDIST = {"LENSMODEL_PINHOLE": 0, "LENSMODEL_OPENCV4": 4, "LENSMODEL_OPENCV5": 5,
                 "LENSMODEL_OPENCV8": 8}


def opencv_intrinsics(model) -> tuple[np.ndarray, np.ndarray]:
    """(K (3, 3), dist (N,)) in OpenCV's convention of an mrcal pinhole/OPENCVn model."""
    lens, intr = model.intrinsics()
    if lens not in _OPENCV_NDIST:
        raise InputError(f"{lens} has no OpenCV equivalent (export needs LENSMODEL_PINHOLE or "
                         "LENSMODEL_OPENCV4/5/8)")
    fx, fy, cx, cy = intr[:4]
    K = np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])
    return K, np.array(intr[4:4 + _OPENCV_NDIST[lens]], float)


def write_colmap_rig(models: dict, out: str | os.PathLike) -> list[Path]:
    """``out/rig_config.json`` plus a COLMAP text model of the rig's cameras at their rig poses."""
    out = Path(out)
    files = write_colmap_text({f"{cam}/rig.png": m for cam, m in models.items()}, out)
    files.append(write_rig_config(models, out / "rig_config.json"))
    return files


def _yaml_matrix(T: np.ndarray, indent: str) -> str:
    return "\n".join(f"{indent}- [" + ", ".join(f"{v:.12g}" for v in row) + "]" for row in T)


def write_kalibr_camchain(models: dict, path: str | os.PathLike) -> Path:
    """Kalibr ``camchain.yaml`` (see the module docstring)."""
    lines = ["# Kalibr camera chain written by polycam calibrate (T_cam_rig is a polycam extra)"]
    prev = None
    for k, (cam, m) in enumerate(models.items()):
        lens, intr = m.intrinsics()
        if lens not in ("LENSMODEL_PINHOLE", "LENSMODEL_OPENCV4"):
            raise InputError(f"{cam}: {lens} cannot be written as Kalibr pinhole-radtan (use --lensmodel "
                             "opencv4 for a Kalibr export)")
        dist = list(intr[4:8]) if lens == "LENSMODEL_OPENCV4" else [0.0] * 4
        W, H = (int(v) for v in m.imagersize())
        T_cam_rig = T_from_rt(m.rt_cam_ref())
        lines += [f"cam{k}:", "  camera_model: pinhole",
                  "  intrinsics: [" + ", ".join(f"{v:.12g}" for v in intr[:4]) + "]",
                  "  distortion_model: radtan",
                  "  distortion_coeffs: [" + ", ".join(f"{v:.12g}" for v in dist) + "]",
                  f"  resolution: [{W}, {H}]", f"  rostopic: /{cam}/image_raw"]
        if prev is not None:
            lines += ["  T_cn_cnm1:", _yaml_matrix(T_cam_rig @ T_inverse(prev), "  ")]
        lines += ["  T_cam_rig:", _yaml_matrix(T_cam_rig, "  ")]
        prev = T_cam_rig
    path = Path(path)
    atomic_write_text(path, "\n".join(lines) + "\n")
    return path


def write_opencv_yaml(models: dict, path: str | os.PathLike) -> Path:
    """OpenCV FileStorage YAML (see the module docstring); written via a temporary file."""
    import cv2

    path = Path(path)
    tmp = path.with_name(f".tmp-{os.getpid()}-{path.name}")
    try:
        fs = cv2.FileStorage(str(tmp), cv2.FILE_STORAGE_WRITE | cv2.FILE_STORAGE_FORMAT_YAML)
        fs.startWriteStruct("cameras", cv2.FileNode_SEQ)
        for cam in models:
            fs.write("", cam)
        fs.endWriteStruct()
        for cam, m in models.items():
            K, dist = opencv_intrinsics(m)
            T = T_from_rt(m.rt_cam_ref())
            fs.startWriteStruct(cam, cv2.FileNode_MAP)
            fs.write("image_size", np.array([int(v) for v in m.imagersize()], np.int32).reshape(1, 2))
            fs.write("camera_matrix", K)
            fs.write("distortion_coefficients", dist.reshape(1, -1) if dist.size else np.zeros((1, 0)))
            fs.write("R_cam_rig", T[:3, :3])
            fs.write("t_cam_rig", T[:3, 3].reshape(3, 1))
            fs.endWriteStruct()
        fs.release()
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    return path


def read_opencv_yaml(path: str | os.PathLike) -> dict:
    """Camera id → mrcal model from :func:`write_opencv_yaml`'s file."""
    import cv2
    import mrcal

    from polycam.geometry import T_from_Rt, rt_from_T

    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    try:
        node = fs.getNode("cameras")
        cams = [node.at(i).string() for i in range(node.size())]
        out = {}
        for cam in cams:
            n = fs.getNode(cam)
            W, H = (int(v) for v in n.getNode("image_size").mat().ravel())
            K = n.getNode("camera_matrix").mat()
            d = n.getNode("distortion_coefficients").mat()
            d = np.zeros(0) if d is None else d.ravel()
            lens = {0: "LENSMODEL_PINHOLE", 4: "LENSMODEL_OPENCV4", 5: "LENSMODEL_OPENCV5",
                    8: "LENSMODEL_OPENCV8"}[d.size]
            intr = np.concatenate([[K[0, 0], K[1, 1], K[0, 2], K[1, 2]], d])
            T = T_from_Rt(n.getNode("R_cam_rig").mat(), n.getNode("t_cam_rig").mat().ravel())
            out[cam] = mrcal.cameramodel(intrinsics=(lens, intr), imagersize=np.array([W, H]), rt_cam_ref=rt_from_T(T))
        return out
    finally:
        fs.release()

