"""Fast camera images of a moving planar board in front of a static background.

A board session (:func:`polycam.synth.synth_board_session`) renders the same static
room from the same rig pose in every frame; only one textured rectangle (the board)
moves. :class:`BoardRenderer` therefore traces the background once per camera
(:class:`~polycam.synth.render.CameraArrayRenderer`'s rays, the scene without the
board) and, per frame, classifies every pixel by its sub-sample rays:

- no sub-ray meets the board: the cached background value;
- every sub-ray meets the board in front of everything the pixel's sub-rays see
  (nearer than the smallest background hit distance over them): the board's
  shaded texture, computed by a numba kernel (ray → plane intersection, bilinear
  texture lookup, the ray caster's own arithmetic and Lambertian shading);
- anything else (the board's outline, a board behind background geometry): traced
  by the ray caster with the board in the scene.

The result equals :meth:`CameraArrayRenderer.render` of the scene with the board
(same rays, same arithmetic), at a fraction of the cost: the room is no longer traced
per frame.
"""

from __future__ import annotations

import dataclasses
import math

import numba
import numpy as np
from numba import njit, prange

from .raycast import _EPS_T, _direction_world, _origin_world, _texture, trace_indexed
from .render import CameraArrayRenderer
from .scenes import Scene

__all__ = ["BoardRenderer"]

_MISS, _BOARD, _MIXED = 0, 1, 2
_CHUNK = 1024               # pixels per task of the parallel loop


@njit(parallel=True, fastmath=False, cache=True)
def _board_kernel(orig, dirs, oidx, R, tr, bg_rad, bg_tmin,
                  ro, rex, rey, rb, ruv, ti, tex_kind, tex_param, wave_start, waves, max_waves,
                  img_start, img_shape, img_data, light, shade, rad_out, state_out):
    """Per pixel b (dirs (B, S, 3) float32 rig-frame sub-ray directions, oidx (B,) origin index):
    rad_out[b] = background or board radiance; state_out[b] = _MISS, _BOARD or _MIXED (the
    caller traces _MIXED pixels). R, tr: T_world_rig; ro, rex, rey (3,) the board's world pose,
    rb (4,) its (s, t) bounds, ruv (2, 3) its texture map, ti its texture index."""
    B = dirs.shape[0]
    S = dirs.shape[1]
    n0 = rex[1] * rey[2] - rex[2] * rey[1]
    n1 = rex[2] * rey[0] - rex[0] * rey[2]
    n2 = rex[0] * rey[1] - rex[1] * rey[0]
    nchunk = (B + _CHUNK - 1) // _CHUNK
    for c in prange(nchunk):
        tmp = np.empty(max(max_waves, 1))
        for b in range(c * _CHUNK, min((c + 1) * _CHUNK, B)):
            _board_pixel(b, S, orig, dirs, oidx, R, tr, bg_rad, bg_tmin, n0, n1, n2, ro, rex, rey, rb, ruv, ti,
                         tex_kind, tex_param, wave_start, waves, tmp, img_start, img_shape, img_data, light, shade,
                         rad_out, state_out)


@njit(inline="always", fastmath=False, cache=True)
def _board_pixel(b, S, orig, dirs, oidx, R, tr, bg_rad, bg_tmin, n0, n1, n2, ro, rex, rey, rb, ruv, ti,
                 tex_kind, tex_param, wave_start, waves, tmp, img_start, img_shape, img_data, light, shade,
                 rad_out, state_out):
    """One pixel of :func:`_board_kernel`."""
    a = oidx[b]
    o0, o1, o2 = _origin_world(R, tr, orig, a)
    hits = 0
    misses = 0
    acc = 0.0
    for si in range(S):
        d0, d1, d2 = _direction_world(R, dirs, b, si)
        nn = d0 * d0 + d1 * d1 + d2 * d2
        if not (nn > 0.0 and nn < np.inf):
            misses += 1                     # unusable direction: contributes 0 with or without the board
            continue
        nn = math.sqrt(nn)
        d0 /= nn
        d1 /= nn
        d2 /= nn
        den = n0 * d0 + n1 * d1 + n2 * d2
        if abs(den) < 1e-12:
            misses += 1
            continue
        t = (n0 * (ro[0] - o0) + n1 * (ro[1] - o1) + n2 * (ro[2] - o2)) / den
        if t <= _EPS_T:
            misses += 1
            continue
        w0 = o0 + t * d0 - ro[0]
        w1 = o1 + t * d1 - ro[1]
        w2 = o2 + t * d2 - ro[2]
        s = w0 * rex[0] + w1 * rex[1] + w2 * rex[2]
        q = w0 * rey[0] + w1 * rey[1] + w2 * rey[2]
        if s < rb[0] or s > rb[1] or q < rb[2] or q > rb[3]:
            misses += 1
            continue
        if not t < bg_tmin[b]:
            break                           # background geometry may be in front: trace the pixel
        hits += 1
        # the ray caster's rectangle shading, same operations (see raycast._trace_range)
        p0 = o0 + t * d0
        p1 = o1 + t * d1
        p2 = o2 + t * d2
        w0 = p0 - ro[0]
        w1 = p1 - ro[1]
        w2 = p2 - ro[2]
        ls = w0 * rex[0] + w1 * rex[1] + w2 * rex[2]
        lq = w0 * rey[0] + w1 * rey[1] + w2 * rey[2]
        su = ruv[0, 0] * ls + ruv[0, 1] * lq + ruv[0, 2]
        sv = ruv[1, 0] * ls + ruv[1, 1] * lq + ruv[1, 2]
        m0, m1, m2 = n0, n1, n2
        if m0 * d0 + m1 * d1 + m2 * d2 > 0.0:
            m0 = -m0
            m1 = -m1
            m2 = -m2
        alb = _texture(ti, ls, lq, 0.0, su, sv, tex_kind, tex_param, wave_start, waves, tmp,
                       img_start, img_shape, img_data)
        lam = m0 * light[0] + m1 * light[1] + m2 * light[2]
        if lam < 0.0:
            lam = 0.0
        acc += alb * (shade[0] + shade[1] * lam)
    if misses == S:
        rad_out[b] = bg_rad[b]
        state_out[b] = _MISS
    elif hits == S:
        rad_out[b] = acc / S
        state_out[b] = _BOARD
    else:
        state_out[b] = _MIXED


def _without_rect(scene: Scene, k: int) -> Scene:
    """``scene`` with rectangle ``k`` removed (textures kept)."""
    keep = np.arange(scene.rect_origin.shape[0]) != k
    return dataclasses.replace(
        scene, rect_origin=np.ascontiguousarray(scene.rect_origin[keep]),
        rect_ex=np.ascontiguousarray(scene.rect_ex[keep]), rect_ey=np.ascontiguousarray(scene.rect_ey[keep]),
        rect_bounds=np.ascontiguousarray(scene.rect_bounds[keep]), rect_uv=np.ascontiguousarray(scene.rect_uv[keep]),
        rect_texture=np.ascontiguousarray(scene.rect_texture[keep]))


class BoardRenderer:
    """Every camera of a static rig watching rectangle ``rect`` of ``scene`` move (see the module
    docstring); images equal :class:`CameraArrayRenderer`'s of the scene with the rectangle at
    that pose.

    rig, models, supersample: as :class:`CameraArrayRenderer`.
    scene: the scene including the rectangle (its texture, bounds and texture map are used;
        its pose is given per frame).
    rect: index of the moving rectangle in ``scene``.
    T_world_rig: (4, 4) the rig's (fixed) pose; the background is traced once from it.
    """

    def __init__(self, rig, models: dict | None, scene: Scene, rect: int, T_world_rig: np.ndarray,
                 supersample: int = 1):
        self.scene = scene
        self.rect = int(rect)
        self.T_world_rig = np.array(T_world_rig, float)
        self.cameras = CameraArrayRenderer(rig, models, scene, supersample)
        cr = self.cameras
        bg = _without_rect(scene, self.rect)
        self._bg_rad = trace_indexed(bg, cr._origins, cr._dirs, cr._index, self.T_world_rig).radiance
        # smallest background hit distance over each pixel's sub-rays (one camera at a time: memory)
        S = cr._dirs.shape[1]
        self._bg_tmin = np.empty(cr._dirs.shape[0])
        for sl in cr._slices.values():
            d = cr._dirs[sl].reshape(-1, 1, 3)
            t = trace_indexed(bg, cr._origins, d, np.repeat(cr._index[sl], S), self.T_world_rig).distance
            # NaN (unprojectable sub-ray): contributes 0 with or without the board, never occludes it
            self._bg_tmin[sl] = np.where(np.isnan(t), np.inf, t).reshape(-1, S).min(axis=1)
        self.mixed_fraction = 0.0
        """Fraction of the pixels the last :meth:`render` had to trace."""

    def render(self, T_world_rect: np.ndarray) -> dict[str, np.ndarray]:
        """Camera id → (H, W) float32 radiance in [0, 1] with the rectangle at ``T_world_rect`` (4, 4)."""
        cr = self.cameras
        sc = self.scene.with_rect_pose(self.rect, T_world_rect)
        k = self.rect
        args = sc.kernel_args()
        tex = args[17:25]                        # tex_kind ... img_data
        light, shade = args[26], args[27]
        R = np.ascontiguousarray(self.T_world_rig[:3, :3])
        tr = np.ascontiguousarray(self.T_world_rig[:3, 3])
        n = cr._dirs.shape[0]
        rad = np.empty(n, np.float32)
        state = np.empty(n, np.int8)
        prev = numba.set_parallel_chunksize(4096)
        try:
            _board_kernel(cr._origins, cr._dirs, cr._index, R, tr, self._bg_rad, self._bg_tmin,
                          np.ascontiguousarray(sc.rect_origin[k]), np.ascontiguousarray(sc.rect_ex[k]),
                          np.ascontiguousarray(sc.rect_ey[k]), np.ascontiguousarray(sc.rect_bounds[k]),
                          np.ascontiguousarray(sc.rect_uv[k]), np.int64(sc.rect_texture[k]), *tex,
                          light, shade, rad, state)
        finally:
            numba.set_parallel_chunksize(prev)
        mixed = np.flatnonzero(state == _MIXED)
        self.mixed_fraction = mixed.size / max(n, 1)
        if mixed.size:
            rad[mixed] = trace_indexed(sc, cr._origins, cr._dirs[mixed], cr._index[mixed], self.T_world_rig).radiance
        return {cid: rad[cr._slices[cid]].reshape(cr._sizes[cid]) for cid in cr.ids}
