"""Depth from plenoptic derivatives: differential stereo and motion (paper Eq. 6–7).

On a Lambertian surface a face's light field is locally
``L(x, y, u, v) = τ(x + λ u, y + λ v)`` with ``λ = Z / f``, where ``Z`` [m] is the
depth of the surface point along the face's z axis measured from the focal plane
Π (``z = z_pi``). Hence (Eq. 6, our derivation; NOTES.md's ``L_u / (f L_x)`` drops a
factor f² — units show it)::

    L_u = λ L_x,   L_v = λ L_y                      (differential stereo)

and, with a known ray motion δ = (δx, δy, δu, δv) of the frame pair (Eq. 5 rows),
substituting Eq. 6 into ``L_t + L_x δx + L_y δy + L_u δu + L_v δv = 0`` in its two
ways gives the two motion-based estimates of Eq. 7::

    λ (L_t + L_u δu + L_v δv) = −(L_u δx + L_v δy)     (directional: L_x = L_u / λ)
    λ (L_x δu + L_y δv) = −(L_t + L_x δx + L_y δy)     (positional: L_u = λ L_x)

All four are linear in λ: ``a_i λ = b_i`` (:func:`depth_equations`). They are fused
per ray by weighted least squares over a small (u, v) neighbourhood
(prefilter-weighted sums of ``a²`` and ``a b``): ``λ = Σ a b / Σ a²``. The
confidence is ``λ² / var(λ)``, var(λ) from what one depth leaves unexplained in the window
(large at occlusion boundaries, where two depths mix) and from the sensor noise's share
(large in textureless areas): it ranks the rays by how precise their depth is (docs/depth.md,
"Fusion and confidence"), and so ranks last the background rays beside a silhouette, to which
the foreground's edge lends its depth ("Occlusion boundaries"). :func:`depth_from_derivatives`
fuses the two stereo equations and the positional motion equation (the directional one has the noisy
``L_t`` on its left side); :mod:`polycam.scales` compares all four to choose the
derivative scales (paper Sect. 4.1); :mod:`polycam.depth_refine` refines the fused depth by
matching the views that hold captured data (Eq. 6's linearisation is biased where the cameras are
samples of disparity apart). :func:`confident_mask` and
:func:`depth_points` turn a depth map into a point cloud (file writing is in
:mod:`polycam.depth_io`; this module does no I/O).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .derivatives import FILTERS, Derivatives, correlate_axis
from .errors import InputError
from .geometry import T_inverse, rt_from_T
from .lightfield import LightFieldGrid

__all__ = ["DepthMap", "EQUATIONS", "DEPTH_FILTERS", "CONFIDENCE_FLOOR", "MIN_W", "NO_CAPTURED_DATA",
           "depth_equations", "equation_noise",
           "window_sum", "window_weight_energy", "depth_from_derivatives", "depth_of_pair", "grey_frame",
           "confident_mask", "view_mask", "depth_points"]

DEPTH_FILTERS = {"x": "fs3", "y": "fs3", "u": "fs5", "v": "fs5"}
"""Derivative filters for depth (the motion solver's defaults; 9 viewpoints leave 7 valid with fs3)."""

EQUATIONS = ("stereo_x", "stereo_y", "motion_dir", "motion_pos")
"""Names of the four depth equations of Eq. 6–7, in the order of :func:`depth_equations`."""

MIN_W = 0.5
"""Light-field confidence W above which a ray holds captured data (below: a view filled between
cameras, or no data): :func:`confident_mask` keeps only such rays."""

NO_CAPTURED_DATA = ("hold no captured data (light-field confidence W > 0.5), only views filled between cameras "
                    "(a stereo pair's cameras are its end views, outside the depth filters' support)")
"""Why views without a ray above :data:`MIN_W` give no depth (the CLIs' explanation)."""

CONFIDENCE_FLOOR = 1e-6
"""The smallest relative variance of λ the confidence grants (float32 sums resolve no
less): confidence ≤ 1e6."""


@dataclass(frozen=True)
class DepthMap:
    """Per-ray depth of a light-field frame pair (arrays of dims (F, Ny, Nx, Nv, Nu))."""

    Z: np.ndarray
    """[m] depth along each face's z axis from its focal plane Π (NaN where unknown)."""
    confidence: np.ndarray
    """λ² / var(λ) ≥ 0, the depth's squared ratio to its uncertainty from the fusion window's
    misfit and sensor noise (1 / relative variance; at most 1 / :data:`CONFIDENCE_FLOOR`;
    0 = no estimate); dimensionless, so comparable across frame pairs and derivative scales."""
    consistency: np.ndarray
    """In [0, 1]: fraction of the equations' energy explained by one depth."""

    def range_along_ray(self, grid: LightFieldGrid) -> np.ndarray:
        """[m] distance from each ray's origin on Π to the surface, ``Z |(u, v, f)| / f``."""
        out = np.empty_like(self.Z)
        for k, face in enumerate(grid.faces):
            v, u = np.meshgrid(grid.v.values, grid.u.values, indexing="ij")
            out[k] = self.Z[k] * (np.sqrt(u * u + v * v + face.f ** 2) / face.f)[None, None]
        return out


def _ray_flow(grid: LightFieldGrid, k: int, p_face: np.ndarray):
    """First-order flow (δx, δy, δu, δv) of face k's rays for face-frame (t, ω), each
    broadcastable to (Ny, Nx, Nv, Nu)."""
    face = grid.faces[k]
    f, Z = face.f, face.z_pi
    y = grid.y.values[:, None, None, None]
    x = grid.x.values[None, :, None, None]
    v = grid.v.values[None, None, :, None]
    u = grid.u.values[None, None, None, :]
    tx, ty, tz, wx, wy, wz = p_face
    dx = tx - u / f * tz - u * y / f * wx + (u * x / f + Z) * wy - y * wz
    dy = ty - v / f * tz - (v * y / f + Z) * wx + v * x / f * wy + x * wz
    du = -u * v / f * wx + (u * u / f + f) * wy - v * wz
    dv = -(v * v / f + f) * wx + u * v / f * wy + u * wz
    return dx, dy, du, dv


def window_sum(a: np.ndarray, window: int) -> np.ndarray:
    """Prefilter-weighted local sum of a (F, Ny, Nx, Nv, Nu) array over (u, v): the fs5
    prefilter applied ``window // 2`` times along u and v (0 or 1 = no smoothing)."""
    taps = FILTERS["fs5"].prefilter
    out = np.ascontiguousarray(a, dtype=np.float32)
    for _ in range(max(0, window // 2)):
        out = correlate_axis(correlate_axis(out, taps, 3), taps, 4)
    return out


def _face_flows(grid: LightFieldGrid, T_prev_next: np.ndarray):
    """Per face: :func:`_ray_flow` of the rays' motion ``T_prev_next⁻¹`` (the rig motion
    ``T_rig0_rig1`` (4, 4)) in the face's frame."""
    G = T_inverse(np.asarray(T_prev_next, float))          # the rays' motion
    rt = rt_from_T(G)
    p_rig = np.concatenate([rt[3:], rt[:3]])
    for k, face in enumerate(grid.faces):
        R = np.asarray(face.R_rig_face, float)
        yield _ray_flow(grid, k, np.concatenate([R.T @ p_rig[:3], R.T @ p_rig[3:]]))


def equation_noise(grid: LightFieldGrid, noise: np.ndarray, T_prev_next: np.ndarray | None = None,
                   equations: tuple[str, ...] = EQUATIONS) -> dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """The sensor noise's second moments ``(var a, cov(a, b), var b)`` of the ``equations`` of
    :func:`depth_equations` (same names; the motion ones need ``T_prev_next``), each
    broadcastable to (F, Ny, Nx, Nv, Nu):
    ``noise`` (5,) the variances of L_x, L_y, L_u, L_v, L_t
    (:func:`polycam.derivatives.derivative_noise`), whose noises are uncorrelated (each
    axis's derivative taps are odd, its prefilter even; L_t is of the frames' difference,
    the others of their mean)."""
    vx, vy, vu, vv, vt = (float(n) for n in noise)
    F = len(grid.faces)
    const = lambda c: np.full((F, 1, 1, 1, 1), c)                      # noqa: E731
    out = {}
    if "stereo_x" in equations:
        out["stereo_x"] = (const(vx), const(0.0), const(vu))
    if "stereo_y" in equations:
        out["stereo_y"] = (const(vy), const(0.0), const(vv))
    motion = [e for e in equations if e.startswith("motion")]
    if T_prev_next is None or not motion:
        return out
    flows = list(_face_flows(grid, T_prev_next))

    def stack(f):
        return np.stack([np.broadcast_to(f(*fl), grid.shape[1:]) for fl in flows])

    if "motion_dir" in motion:          # a = L_t + L_u δu + L_v δv, b = −(L_u δx + L_v δy)
        out["motion_dir"] = (stack(lambda dx, dy, du, dv: vt + du * du * vu + dv * dv * vv),
                             stack(lambda dx, dy, du, dv: -(du * dx * vu + dv * dy * vv)),
                             stack(lambda dx, dy, du, dv: dx * dx * vu + dy * dy * vv))
    if "motion_pos" in motion:          # a = L_x δu + L_y δv, b = −(L_t + L_x δx + L_y δy)
        out["motion_pos"] = (stack(lambda dx, dy, du, dv: du * du * vx + dv * dv * vy),
                             stack(lambda dx, dy, du, dv: -(du * dx * vx + dv * dy * vy)),
                             stack(lambda dx, dy, du, dv: vt + dx * dx * vx + dy * dy * vy))
    return out


def depth_equations(der: Derivatives, grid: LightFieldGrid,
                    T_prev_next: np.ndarray | None = None) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """The depth equations ``a λ = b`` (λ = Z / f) per ray: name → (a, b), each
    (F, Ny, Nx, Nv, Nu) float32, names from :data:`EQUATIONS`.

    Without ``T_prev_next`` (the rig motion ``T_rig0_rig1``) only the two stereo
    equations are returned.
    """
    out = {"stereo_x": (der.Lx, der.Lu), "stereo_y": (der.Ly, der.Lv)}
    if T_prev_next is None:
        return out
    a_dir = np.empty_like(der.Lx)
    b_dir = np.empty_like(der.Lx)
    a_pos = np.empty_like(der.Lx)
    b_pos = np.empty_like(der.Lx)
    for k, (dx, dy, du, dv) in enumerate(_face_flows(grid, T_prev_next)):
        Lx, Ly, Lu, Lv, Lt = der.Lx[k], der.Ly[k], der.Lu[k], der.Lv[k], der.Lt[k]
        a_dir[k] = Lt + Lu * du + Lv * dv
        b_dir[k] = -(Lu * dx + Lv * dy)
        a_pos[k] = Lx * du + Ly * dv
        b_pos[k] = -(Lt + Lx * dx + Ly * dy)
    out["motion_dir"] = (a_dir, b_dir)
    out["motion_pos"] = (a_pos, b_pos)
    return out


def window_weight_energy(window: int) -> float:
    """Σ w² of :func:`window_sum`'s normalised 2-D weights (Σ w = 1): the variance of a
    window-weighted mean of unit-variance white noise, ~1 / the window's effective number of
    samples (0.052 for the default window 4: ~19 samples); 1 without smoothing."""
    taps = np.array([1.0])
    for _ in range(max(0, window // 2)):
        taps = np.convolve(taps, np.asarray(FILTERS["fs5"].prefilter, float))
    return float(np.sum(taps * taps) ** 2)


def _fuse(sums: list[tuple[np.ndarray, np.ndarray, np.ndarray]], valid: np.ndarray, window: int,
          grid: LightFieldGrid, min_confidence: float,
          noise: list[tuple[np.ndarray, np.ndarray, np.ndarray]] | None = None) -> DepthMap:
    """DepthMap from per-ray sums (a², a b, b²) of the equations to fuse; ``noise``: their
    noise moments (:func:`equation_noise`), taken out of the window sums (errors in
    variables: the noise energy of a in Σ a² would shrink λ = Σ a b / Σ a² towards 0)
    and counted in the confidence.

    The confidence is λ² / var(λ) with var(λ) from the window: its misfit energy
    ``Σb² − (Σab)² / Σa²`` (the part one depth does not explain: two depths mixed, model error)
    plus the noise's share, ``κ Σ var(b − λ a)`` with κ = :func:`window_weight_energy`, over the
    explained energy ``(Σab)² / Σa²`` = λ² Σa²."""
    aa = sum(s[0] for s in sums)
    ab = sum(s[1] for s in sums)
    bb = sum(s[2] for s in sums)
    Saa = window_sum(aa * valid, window)
    Sab = window_sum(ab * valid, window)
    Sbb = window_sum(bb * valid, window)
    N = None
    if noise:
        N = [window_sum(np.broadcast_to(sum(n[i] for n in noise), valid.shape) * valid, window) for i in range(3)]
        Saa -= N[0]
        Sab -= N[1]
        Sbb -= N[2]
    with np.errstate(divide="ignore", invalid="ignore"):
        lam = np.where(Saa > 0, Sab / Saa, np.nan)
        # energy explained by the best single depth: (Σab)² / (Σa² Σb²) ∈ [0, 1]
        consistency = np.where((Saa > 0) & (Sbb > 0), (Sab * Sab) / (Saa * Sbb), 0.0)
    consistency = np.clip(np.nan_to_num(consistency), 0.0, 1.0).astype(np.float32)
    # confidence = λ² / var(λ) = explained / (misfit + κ × the noise energy of b − λ a)
    explained = consistency * np.maximum(Sbb, 0.0)
    unexplained = (1.0 - consistency) * np.maximum(Sbb, 0.0)
    if N is not None:
        lam0 = np.nan_to_num(lam)
        noise_r = np.maximum(N[2] - 2 * lam0 * N[1] + lam0 * lam0 * N[0], 0.0)
        unexplained += np.float32(window_weight_energy(window)) * noise_r
    with np.errstate(divide="ignore", invalid="ignore"):
        confidence = np.where(explained > 0, explained / np.maximum(unexplained, CONFIDENCE_FLOOR * explained), 0.0)
    confidence = (np.nan_to_num(confidence) * (valid > 0)).astype(np.float32)
    Z = np.empty_like(lam, dtype=np.float32)
    for k, face in enumerate(grid.faces):
        Z[k] = lam[k] * face.f
    Z = np.where(confidence > min_confidence, Z, np.nan).astype(np.float32)
    return DepthMap(Z=Z, confidence=confidence, consistency=consistency)


def depth_from_derivatives(der: Derivatives, grid: LightFieldGrid, *,
                           T_prev_next: np.ndarray | None = None, window: int = 4,
                           min_confidence: float = 0.0,
                           equations: tuple[str, ...] = ("stereo_x", "stereo_y", "motion_pos"),
                           valid: np.ndarray | None = None, noise: np.ndarray | None = None) -> DepthMap:
    """Per-ray depth from the plenoptic derivatives of a frame pair.

    ``der``: :func:`~polycam.derivatives.plenoptic_derivatives` of frames (L0, L1).
    ``T_prev_next``: (4, 4) rig motion ``T_rig0_rig1`` (e.g. from
    :func:`~polycam.motion.estimate_motion`); with it the motion equations of Eq. 7
    join the two stereo equations, without it only Eq. 6 is used (one frame's
    structure suffices). ``window``: neighbourhood size in (u, v) samples for the
    fusion. ``equations``: which of :data:`EQUATIONS` to fuse (motion ones are
    skipped without ``T_prev_next``). ``valid``: optional extra mask broadcastable
    to (F, Ny, Nx, Nv, Nu) (e.g. the border of a pre-smoothing). Rays with
    confidence ≤ ``min_confidence`` get ``Z = NaN``. ``noise``: (5,) the sensor noise's
    variances in L_x, L_y, L_u, L_v, L_t (:func:`polycam.derivatives.derivative_noise`);
    its expected energy is taken out of the fused sums, without which noise in the
    positional derivatives biases the depth towards the rig (at σ = 4 grey levels by ~16 %
    on the paper's spheres at 4 m; docs/depth.md), and its share of var(λ) joins the
    confidence's. None: no correction, and the confidence counts only the window's misfit.
    On a linear array (``grid.single_view_axis``) the positional motion equation reads the
    unmeasured L_x (or L_y) as 0, so the directional one (no positional derivative) takes its
    place.
    """
    unknown = [e for e in equations if e not in EQUATIONS]
    if unknown:
        raise ValueError(f"unknown depth equation(s) {unknown}; expected some of {EQUATIONS}")
    if grid.single_view_axis and "motion_pos" in equations:
        equations = tuple(dict.fromkeys("motion_dir" if e == "motion_pos" else e for e in equations))
    eqs = depth_equations(der, grid, T_prev_next if any(e.startswith("motion") for e in equations) else None)
    sums = []
    for name in equations:
        if name in eqs:
            a, b = eqs[name]
            sums.append((a * a, a * b, b * b))
    moments = None
    if noise is not None and np.any(np.asarray(noise) > 0):
        names = tuple(name for name in equations if name in eqs)
        en = equation_noise(grid, noise, T_prev_next, names)
        moments = [en[name] for name in names]
    m = np.broadcast_to(der.valid, der.Lx.shape)
    if valid is not None:
        m = m & np.broadcast_to(valid, der.Lx.shape)
    return _fuse(sums, m.astype(np.float32), window, grid, min_confidence, moments)


def grey_frame(L: np.ndarray) -> np.ndarray:
    """A frame (F, Ny, Nx, Nv, Nu) float32, its trailing colour axis (if any) averaged."""
    L = np.asarray(L)
    return np.ascontiguousarray(L.mean(axis=-1) if L.ndim == 6 else L, dtype=np.float32)


def depth_of_pair(L0: np.ndarray, L1: np.ndarray, grid: LightFieldGrid,
                  T_prev_next: np.ndarray | None = None, *, window: int = 4,
                  filters: str | dict = DEPTH_FILTERS, noise_var: float | None = None) -> DepthMap:
    """Single-scale depth of the frame pair (L0, L1), each (F, Ny, Nx, Nv, Nu) (a trailing
    colour axis is averaged): :func:`depth_from_derivatives` of their plenoptic
    derivatives with the rig motion ``T_prev_next`` (4, 4) ``T_rig0_rig1`` (None: stereo only),
    corrected for the sensor noise of variance ``noise_var`` per sample (None: estimated
    from the frames, :func:`polycam.motion_weights.frame_noise_variance`; 0: no correction)."""
    from .derivatives import derivative_noise, plenoptic_derivatives
    from .motion_weights import frame_noise_variance

    g0, g1 = grey_frame(L0), grey_frame(L1)
    for name, g in (("L0", g0), ("L1", g1)):
        if g.shape != tuple(grid.shape):
            raise InputError(f"depth: {name} has dims {g.shape}, but the grid is {tuple(grid.shape)} "
                             "(F, Ny, Nx, Nv, Nu)")
        if not np.all(np.isfinite(g)):
            raise InputError(f"depth: {name} has NaN or infinite samples (set them, with W = 0, before)")
    if T_prev_next is not None:
        T = np.asarray(T_prev_next, float)
        if T.shape != (4, 4) or not np.all(np.isfinite(T)):
            raise InputError(f"depth: T_prev_next must be a finite (4, 4) transform, got dims {T.shape}")
    if int(window) != window or window < 1:
        raise InputError(f"depth: window must be an integer >= 1, got {window}")
    if noise_var is not None and not 0.0 <= noise_var < math.inf:
        raise InputError(f"depth: noise_var must be >= 0 and finite, got {noise_var}")
    der = plenoptic_derivatives(g0, g1, grid, filters=filters)
    if noise_var is None:
        noise_var = frame_noise_variance(g0, g1, grid)
    return depth_from_derivatives(der, grid, T_prev_next=T_prev_next, window=window,
                                  noise=derivative_noise(noise_var, grid, filters))


def confident_mask(dm: DepthMap, *, keep: float = 0.5, W: np.ndarray | None = None,
                   min_W: float = MIN_W, max_rel_std: float | None = None) -> np.ndarray:
    """(F, Ny, Nx, Nv, Nu) bool: rays with a finite positive depth whose confidence is in
    the best ``keep`` fraction of the rays with any confidence (and, with the light
    field's confidence ``W`` of the same dims, ``W > min_W``). ``max_rel_std``: instead of
    the fraction, the rays whose depth's predicted relative standard deviation (1 / √confidence)
    is at most this (e.g. 0.05; docs/depth.md: the prediction holds to ~1.3x down to ~3 %)."""
    conf = dm.confidence
    if W is not None:
        conf = conf * (np.asarray(W) > min_W)
    if max_rel_std is not None:
        if not max_rel_std > 0:
            raise ValueError(f"max_rel_std must be > 0, got {max_rel_std}")
        thr = 1.0 / float(max_rel_std) ** 2
    else:
        pos = conf[conf > 0]
        thr = float(np.quantile(pos, 1.0 - keep)) if pos.size else np.inf
    return (conf >= thr) & (conf > 0) & np.isfinite(dm.Z) & (dm.Z > 0)


def view_mask(grid: LightFieldGrid, views: int | None = None, faces=None) -> np.ndarray:
    """(F, Ny, Nx) bool selecting the central ``views x views`` viewpoints (None: all
    viewpoints) of the faces with indices in ``faces`` (None: every face)."""
    F, Ny, Nx = grid.shape[:3]
    m = np.zeros((F, Ny, Nx), bool)
    fs = list(range(F)) if faces is None else list(faces)
    if views is None:
        m[fs] = True
        return m
    h = int(views) // 2
    jc, ic = Ny // 2, Nx // 2
    for k in fs:
        m[k, max(0, jc - h):min(Ny, jc + h + 1), max(0, ic - h):min(Nx, ic + h + 1)] = True
    return m


def depth_points(dm: DepthMap, grid: LightFieldGrid, mask: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Surface points of the rays selected by ``mask`` (bool, broadcastable to
    (F, Ny, Nx, Nv, Nu)).

    Returns ``p_rig`` (N, 3) [m]: ray origin + range × unit direction in the rig frame of
    the pair's first frame, and ``index`` (N,) int64 flat indices of those rays into the
    (F, Ny, Nx, Nv, Nu) arrays (e.g. to pick their intensities), ordered by face, y, x, v, u.
    """
    m = np.broadcast_to(mask, dm.Z.shape) & np.isfinite(dm.Z)
    rng_ray = dm.range_along_ray(grid)
    pts = []
    for k in range(len(grid.faces)):
        mk = m[k]
        if not mk.any():
            continue
        rays = grid.face_rays(k)
        pts.append(rays.origins[mk] + rays.directions[mk] * rng_ray[k][mk][:, None])
    index = np.flatnonzero(m.reshape(-1))
    p = np.concatenate(pts) if pts else np.zeros((0, 3))
    return p, index
