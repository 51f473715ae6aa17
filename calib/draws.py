"""Camera models drawn from a board calibration's own uncertainty (mrcal's covariance).

A calibration's error is the same in every frame pair, so neither the motion solver's residuals
nor its pyramid levels see it (docs/motion.md, "How far to trust the covariance"). To count it,
:func:`calibration_covariance` reads the joint covariance of every camera's intrinsics and of its
pose relative to the solve's reference camera from the models' ``optimization_inputs`` (the
cameramodels of ``polycam calibrate``'s board path keep them; :func:`calib.state_covariance`, at
the solve's own inlier RMS as the corner noise), and :func:`drawn_models` turns a standard-normal
vector into one plausible set of models: each camera's intrinsics moved by its share of the draw,
its pose relative to the reference camera moved likewise while the rig frame keeps its relation to
the reference camera (the draw is the calibration's *relative* error; the rig frame's own
alignment is a convention, not a measurement). ``polycam motion --calib-draws`` re-resamples and
re-solves a session with such draws (:mod:`polycam.calib_draws_cli`).

Models without ``optimization_inputs`` (COLMAP's, a rig file's nominal ones) have no covariance:
:class:`~polycam.errors.InputError`. No file I/O.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from polycam.errors import InputError

from .board_solve import _mrcal, board_rms_px, state_covariance

__all__ = ["CalibrationCovariance", "calibration_covariance", "covariance_factor", "drawn_models"]


@dataclass(frozen=True)
class CalibrationCovariance:
    """The joint covariance of a board calibration's cameras (see the module docstring)."""

    cameras: tuple[str, ...]
    """Camera ids, in the order of :attr:`intrinsics` / :attr:`extrinsics`."""
    covariance: np.ndarray
    """(N, N) covariance of the state entries below, in their own units (intrinsics: mrcal's lens
    parameters [px, unitless]; poses: ``rt_cam_ref`` of the solve, [rad] then [m])."""
    intrinsics: tuple[slice, ...]
    """Per camera: its intrinsics' rows of :attr:`covariance`."""
    lens_parameters: np.ndarray
    """(n,) int which of a camera's lens parameters those rows are (all of them, or without the
    4 core parameters where the solve locked the core, as for a splined model)."""
    extrinsics: tuple[slice | None, ...]
    """Per camera: the 6 rows of its ``rt_cam_ref`` (pose relative to the solve's reference camera),
    None for the reference camera itself."""
    rt_cam_ref: np.ndarray
    """(C, 6) each camera's solved pose relative to the reference camera (zeros for the reference)."""
    noise_px: float
    """[px] the corner noise per coordinate the covariance assumes (the solve's inlier RMS)."""

    @property
    def dim(self) -> int:
        """N, the length of the standard-normal vector :func:`drawn_models` takes."""
        return self.covariance.shape[0]


def calibration_covariance(models: dict) -> CalibrationCovariance:
    """The joint covariance of the calibration that produced ``models`` (camera id → mrcal
    cameramodel, all from one board solve: ``polycam calibrate``'s mrcal path).

    Raises InputError when a model has no ``optimization_inputs`` or the models come from
    different solves (a model's lens parameters differ from its solve's).
    """
    mrcal = _mrcal()
    cams = tuple(models)
    if not cams:
        raise InputError("calibration draws: no camera models")
    bare = [c for c in cams if models[c].icam_intrinsics() is None]     # (cheaper than decoding each
    if bare:                                                                # model's optimization_inputs)
        raise InputError(f"camera {bare[0]}: its model has no optimisation record (a board calibration's "
                         "optimization_inputs), so the calibration's uncertainty is unknown")
    inputs = models[cams[0]].optimization_inputs()
    n_intr = mrcal.num_intrinsics_optimization_params(**inputs)
    n_lens = inputs["intrinsics"].shape[1]
    core, rest = inputs.get("do_optimize_intrinsics_core", True), inputs.get("do_optimize_intrinsics_distortions", True)
    params = np.array([k for k in range(n_lens) if (core if k < 4 else rest)], dtype=np.int64)
    if len(params) != n_intr:
        raise InputError(f"camera {cams[0]}: cannot map the solve's {n_intr} lens states onto the "
                         f"{n_lens} parameters of {inputs['lensmodel']}")
    rows, intr, extr, rt = [], [], [], []
    for c in cams:
        m = models[c]
        ic = m.icam_intrinsics()
        if not 0 <= ic < inputs["intrinsics"].shape[0] or m.intrinsics()[0] != inputs["lensmodel"] \
                or not np.allclose(m.intrinsics()[1], inputs["intrinsics"][ic], rtol=1e-9, atol=1e-9):
            raise InputError(f"camera {c}: its model is not from the same board calibration as camera {cams[0]}'s")
        i0 = mrcal.state_index_intrinsics(ic, **inputs)
        intr.append(slice(len(rows), len(rows) + n_intr))
        rows += range(i0, i0 + n_intr)
        ie = mrcal.corresponding_icam_extrinsics(ic, **inputs)
        if ie < 0:
            extr.append(None)
            rt.append(np.zeros(6))
        else:
            e0 = mrcal.state_index_extrinsics(ie, **inputs)
            extr.append(slice(len(rows), len(rows) + 6))
            rows += range(e0, e0 + 6)
            rt.append(np.asarray(inputs["rt_cam_ref"][ie], float))
    noise = board_rms_px(inputs)
    cov = state_covariance(inputs, noise, np.array(rows))
    return CalibrationCovariance(cameras=cams, covariance=cov, intrinsics=tuple(intr), lens_parameters=params,
                                 extrinsics=tuple(extr), rt_cam_ref=np.stack(rt), noise_px=noise)


def drawn_models(models: dict, cov: CalibrationCovariance, z: np.ndarray, factor: np.ndarray | None = None) -> dict:
    """One set of camera models drawn from the calibration's uncertainty: ``models`` moved by
    ``δ = chol(cov.covariance) z`` (``z``: (N,) standard normal; ``-z`` gives the antithetic draw).

    Each camera's solved lens parameters get its intrinsics' share of δ; its pose relative to the solve's
    reference camera, ``rt_cam_ref``, gets its extrinsics' share, and its rig-frame pose follows:
    ``T_cam_rig' = T(rt_cam_ref + δ) · T(rt_cam_ref)⁻¹ · T_cam_rig`` (the rig frame stays where it is
    relative to the reference camera). ``factor``: (N, N) :func:`covariance_factor`'s factor of the
    covariance, to reuse over draws (default: computed here). Returns camera id → new mrcal cameramodel (no
    optimisation record: the draw is not a solve).
    """
    mrcal = _mrcal()
    z = np.asarray(z, float)
    if z.shape != (cov.dim,):
        raise ValueError(f"z must be ({cov.dim},), got {z.shape}")
    if factor is None:
        factor = covariance_factor(cov)
    d = factor @ z
    out = {}
    for k, c in enumerate(cov.cameras):
        m = models[c]
        lens, p = m.intrinsics()
        rt = m.rt_cam_ref()
        if cov.extrinsics[k] is not None:
            r0 = cov.rt_cam_ref[k]
            rt = mrcal.compose_rt(r0 + d[cov.extrinsics[k]], mrcal.invert_rt(r0), rt)
        p = np.array(p, float)
        p[cov.lens_parameters] += d[cov.intrinsics[k]]
        out[c] = mrcal.cameramodel(intrinsics=(lens, p), imagersize=m.imagersize(), rt_cam_ref=rt)
    return out


def covariance_factor(cov: CalibrationCovariance) -> np.ndarray:
    """(N, N) a factor L with ``L Lᵀ = cov.covariance``: the Cholesky factor, computed on the
    correlation matrix (the entries mix px², rad² and m²) with the smallest diagonal loading that
    factors one that is only positive semi-definite in floating point; the symmetric square root
    as the last resort."""
    C = 0.5 * (cov.covariance + cov.covariance.T)
    s = np.sqrt(np.clip(np.diag(C), 0.0, None))
    s = np.where(s > 0, s, 1.0)
    R = C / s[:, None] / s[None, :]
    for eps in (0.0, 1e-12, 1e-9, 1e-6):
        try:
            return s[:, None] * np.linalg.cholesky(R + eps * np.eye(len(R)))
        except np.linalg.LinAlgError:
            continue
    w, V = np.linalg.eigh(C)
    return V * np.sqrt(np.clip(w, 0.0, None))
