"""Camera models (mrcal ``cameramodel``) and their per-pixel rays in the rig frame.

Every cameramodel's reference frame is the rig frame: ``rt_cam_ref`` is
``T_cam_rig`` (SPEC.md, docs/conventions.md). Pixel centres are at integer
coordinates (mrcal's convention).
"""

from __future__ import annotations

import math
import os
from pathlib import Path

import numpy as np

from .errors import FormatError
from .geometry import T_inverse, rt_from_T, T_from_rt
from .rays import RayBundle
from .rig import CameraSpec

__all__ = [
    "nominal_cameramodel",
    "load_cameramodel",
    "write_cameramodel",
    "T_rig_cam_of",
    "pixel_grid",
    "camera_rays",
]


def _mrcal():
    import mrcal  # imported lazily: heavy, and the CLI's --help must stay instant

    return mrcal


def nominal_cameramodel(cam: CameraSpec, T_rig_cam: np.ndarray | None = None):
    """A ``mrcal.cameramodel`` for a rig camera from its nominal settings.

    Pinhole with the camera's ``fov_deg`` unless ``cam.lens`` names a
    cameramodel: then that lens model and distortion, with the focal length
    rescaled so the horizontal field of view of a pinhole would be ``fov_deg``
    and the principal point moved with it onto the new imager.

    T_rig_cam: (4, 4) pose to store (default: the rig file's nominal pose).
    """
    mrcal = _mrcal()
    W, H = cam.width, cam.height
    f_new = (W / 2.0) / math.tan(math.radians(cam.fov_deg) / 2.0)
    if cam.lens is None:
        lensmodel = "LENSMODEL_PINHOLE"
        intrinsics = np.array([f_new, f_new, (W - 1) / 2.0, (H - 1) / 2.0])
    else:
        src = load_cameramodel(cam.lens)
        lensmodel, intr = src.intrinsics()
        intrinsics = np.array(intr, dtype=float)
        W0, H0 = src.imagersize()
        k = f_new / intrinsics[0]
        intrinsics[0] *= k
        intrinsics[1] *= k
        intrinsics[2] = (intrinsics[2] - (W0 - 1) / 2.0) * k + (W - 1) / 2.0
        intrinsics[3] = (intrinsics[3] - (H0 - 1) / 2.0) * k + (H - 1) / 2.0
    T = cam.T_rig_cam if T_rig_cam is None else T_rig_cam
    return mrcal.cameramodel(intrinsics=(lensmodel, intrinsics), imagersize=np.array([W, H]),
                             rt_cam_ref=rt_from_T(T_inverse(T)))


def load_cameramodel(path: str | os.PathLike):
    """Read a ``.cameramodel`` file with mrcal's parser (no eval); errors name the file."""
    mrcal = _mrcal()
    path = Path(path)
    if not path.is_file():
        raise FormatError(path, "no such cameramodel file")
    try:
        model = mrcal.cameramodel(str(path))
    except Exception as e:  # mrcal raises plain Exceptions for malformed models
        msg = str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__
        msg = msg.split(". Errors for each attempt")[0]     # mrcal lists every parser it tried
        raise FormatError(path, f"not a valid mrcal cameramodel ({msg})") from None
    _check_model_values(path, model)
    return model


def _check_model_values(path: Path, model) -> None:
    """:class:`FormatError` naming ``path`` for values mrcal's parser accepts but no camera has:
    non-finite intrinsics or pose, a focal length (every mrcal lens model's first two intrinsics,
    fx, fy [pixels]) that is not positive, an imager without pixels."""
    _, intrinsics = model.intrinsics()
    intrinsics = np.asarray(intrinsics, float)
    if not np.all(np.isfinite(intrinsics)):
        raise FormatError(path, "intrinsics: non-finite value")
    if intrinsics.size < 2 or not np.all(intrinsics[:2] > 0):
        raise FormatError(path, f"intrinsics: focal lengths (fx, fy) must be > 0, got {intrinsics[:2].tolist()}")
    if not np.all(np.isfinite(model.rt_cam_ref())):
        raise FormatError(path, "extrinsics: non-finite value")
    if not np.all(np.asarray(model.imagersize()) > 0):
        raise FormatError(path, f"imagersize: must be > 0, got {np.asarray(model.imagersize()).tolist()}")


def write_cameramodel(model, path: str | os.PathLike) -> Path:
    """Write an mrcal cameramodel atomically (temporary name, then ``os.replace``)."""
    path = Path(path)
    tmp = path.with_name(f".tmp-{os.getpid()}-{path.name}")
    try:
        model.write(str(tmp))
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    return path


def T_rig_cam_of(model) -> np.ndarray:
    """(4, 4) ``T_rig_cam`` of a cameramodel whose reference frame is the rig."""
    return T_inverse(T_from_rt(model.rt_cam_ref()))


def pixel_grid(width: int, height: int, supersample: int = 1) -> np.ndarray:
    """Pixel coordinates q of dims (height, width, S, 2) with S = supersample**2.

    With ``supersample`` > 1 the S points are a regular sub-grid covering each
    pixel's square footprint ``[i - 0.5, i + 0.5]`` (pixel centres at integers).
    """
    s = int(supersample)
    off = (np.arange(s) + 0.5) / s - 0.5
    ox, oy = np.meshgrid(off, off, indexing="xy")
    offs = np.stack([ox.ravel(), oy.ravel()], axis=-1)
    xs, ys = np.meshgrid(np.arange(width, dtype=float), np.arange(height, dtype=float), indexing="xy")
    q = np.stack([xs, ys], axis=-1)[:, :, None, :] + offs[None, None, :, :]
    return q


def camera_rays(model, q: np.ndarray | None = None) -> RayBundle:
    """Rays in the rig frame of pixels ``q`` (..., 2) of a cameramodel.

    Default q: every pixel centre, giving dims (H, W). Directions come from
    ``mrcal.unproject`` (so lens distortion is exact); the origin of every ray
    is the camera centre. Pixels the lens model cannot unproject get NaN.
    """
    mrcal = _mrcal()
    lensmodel, intrinsics = model.intrinsics()
    if q is None:
        W, H = model.imagersize()
        q = pixel_grid(int(W), int(H))[:, :, 0, :]
    q = np.ascontiguousarray(q, dtype=float)
    d_cam = mrcal.unproject(q, lensmodel, intrinsics, normalize=True)
    T_rig_cam = T_rig_cam_of(model)
    d_rig = d_cam @ T_rig_cam[:3, :3].T
    o_rig = np.broadcast_to(T_rig_cam[:3, 3], d_rig.shape)
    return RayBundle(o_rig, d_rig, frame="rig")
