"""The numba ray caster behind every synthetic image and light field.

One parallel kernel traces batches of rays against a :class:`~polycam.synth.scenes.Scene`
(spheres in a uniform grid walked by 3-D DDA, axis-aligned boxes, textured
rectangles, a sky) and returns Lambertian radiance in [0, 1]. Radiance depends
only on the surface point hit (or, for the sky, on the direction), never on the
viewpoint, so plenoptic brightness constancy holds exactly.

Rays come in the rig frame and are moved into the world by ``T_world_rig``
inside the kernel, so per-camera / per-face ray sets can be cached and reused
for every frame. Rays are given as origins ``(A, 3)`` and direction sets
``(B, S, 3)`` — S sub-sample directions whose radiance is averaged (box-filter
anti-aliasing) — in one of two layouts (dims documented on :func:`trace_outer`,
:func:`trace_indexed` and :func:`trace_rays`):

- outer: every origin ``a`` combined with every direction set ``b`` (light-field
  faces: A = Ny*Nx viewpoints, B = Nv*Nu directions);
- indexed: direction set ``b`` starts at origin ``origin_index[b]`` (all cameras of
  a rig in one call; one ray per origin for :func:`trace_rays`).

See docs/conventions.md for frames.
"""

from __future__ import annotations

import math

import numba
import numpy as np
from numba import njit, prange

from ..rays import RayBundle

__all__ = ["trace_rays", "trace_outer", "trace_indexed", "TraceResult"]

_EPS_T = 1e-9          # [m] smallest accepted hit distance (avoids self-hits at origins on surfaces)
_TWO_PI = 2.0 * math.pi
_INV_TWO_PI = 1.0 / _TWO_PI
_INF = np.inf


@njit(inline="always", fastmath=False, cache=True)
def _fcos(x):
    """cos(x) to ~1e-10 absolute: branch-free quarter-period reduction and a degree-14
    Taylor polynomial.

    About twice as fast as libm's cos in the texture loop; deterministic, so the
    textures it defines are exactly reproducible.
    """
    y = x * _INV_TWO_PI
    z = abs(y - math.floor(y + 0.5))          # in [0, 0.5]
    s = 1.0 - 2.0 * (z > 0.25)               # cos(2 pi z) = -cos(2 pi (0.5 - z))
    z = min(z, 0.5 - z)
    w = _TWO_PI * z
    w2 = w * w
    p = -1.0 / 87178291200.0
    p = p * w2 + 1.0 / 479001600.0
    p = p * w2 - 1.0 / 3628800.0
    p = p * w2 + 1.0 / 40320.0
    p = p * w2 - 1.0 / 720.0
    p = p * w2 + 1.0 / 24.0
    p = p * w2 - 0.5
    p = p * w2 + 1.0
    return s * p


@njit(inline="always", fastmath=False, cache=True)
def _texture(ti, p0, p1, p2, s, t, tex_kind, tex_param, wave_start, waves, tmp,
             img_start, img_shape, img_data):
    """Albedo in [0, 1] of texture ``ti``: solid waves at point p, or an image at (s, t) pixels.

    tmp: scratch (>= waves per texture,) so the wave loop vectorises (the sum then runs in
    a fixed order: results do not depend on SIMD width).
    """
    if ti < 0:
        return 0.5
    if tex_kind[ti] == 0:
        # unsigned indices: no negative-index wraparound, so the loop vectorises
        w0 = np.uint64(wave_start[ti])
        nw = np.uint64(wave_start[ti + 1] - wave_start[ti])
        for w in range(nw):
            j = w0 + np.uint64(w)
            tmp[w] = waves[4, j] * _fcos(waves[0, j] * p0 + waves[1, j] * p1 + waves[2, j] * p2 + waves[3, j])
        acc = 0.0
        for w in range(nw):
            acc += tmp[w]
        sharp = tex_param[ti, 2]
        if sharp > 0.0:                       # soft threshold into (-1, 1), slope sharp at 0
            acc = sharp * acc / math.sqrt(1.0 + (sharp * acc) ** 2)
        a = tex_param[ti, 0] + tex_param[ti, 1] * acc
    else:
        # Bilinear image lookup; (s, t) = (column, row) in pixels, centres at integers.
        h = img_shape[ti, 0]
        wd = img_shape[ti, 1]
        base = img_start[ti]
        if s < 0.0:
            s = 0.0
        if t < 0.0:
            t = 0.0
        if s > wd - 1.0:
            s = wd - 1.0
        if t > h - 1.0:
            t = h - 1.0
        c0 = int(math.floor(s))
        r0 = int(math.floor(t))
        c1 = c0 + 1 if c0 + 1 < wd else c0
        r1 = r0 + 1 if r0 + 1 < h else r0
        fs = s - c0
        ft = t - r0
        a = ((1.0 - ft) * ((1.0 - fs) * img_data[base + r0 * wd + c0] + fs * img_data[base + r0 * wd + c1])
             + ft * ((1.0 - fs) * img_data[base + r1 * wd + c0] + fs * img_data[base + r1 * wd + c1]))
    if a < 0.0:
        a = 0.0
    elif a > 1.0:
        a = 1.0
    return a


@njit(inline="always", fastmath=False, cache=True)
def _hit_sphere(o0, o1, o2, d0, d1, d2, c0, c1, c2, r):
    """Smallest t > eps with |o + t d - c| = r (unit d), or inf."""
    q0 = o0 - c0
    q1 = o1 - c1
    q2 = o2 - c2
    b = q0 * d0 + q1 * d1 + q2 * d2
    cc = q0 * q0 + q1 * q1 + q2 * q2 - r * r
    disc = b * b - cc
    if disc < 0.0:
        return _INF
    sq = math.sqrt(disc)
    t = -b - sq
    if t > _EPS_T:
        return t
    t = -b + sq
    if t > _EPS_T:
        return t
    return _INF


@njit(inline="always", fastmath=False, cache=True)
def _slab(o0, o1, o2, i0, i1, i2, lo0, lo1, lo2, hi0, hi1, hi2):
    """Branch-free ray/axis-aligned-box entry and exit distances (t_near, t_far); a miss
    when t_near > t_far. (i0, i1, i2) = 1/d, with 1e300 standing in for 1/0."""
    ta = (lo0 - o0) * i0
    tb = (hi0 - o0) * i0
    tn = min(ta, tb)
    tf = max(ta, tb)
    ta = (lo1 - o1) * i1
    tb = (hi1 - o1) * i1
    tn = max(tn, min(ta, tb))
    tf = min(tf, max(ta, tb))
    ta = (lo2 - o2) * i2
    tb = (hi2 - o2) * i2
    tn = max(tn, min(ta, tb))
    tf = min(tf, max(ta, tb))
    return tn, tf


@njit(inline="always", fastmath=False, cache=True)
def _dda_init(o, d, lo, h, n, tn):
    """Start cell, step, first boundary crossing and crossing period along one grid axis."""
    c = int(math.floor((o + tn * d - lo) / h))
    if c < 0:
        c = 0
    if c > n - 1:
        c = n - 1
    if d > 0.0:
        return c, 1, (lo + (c + 1) * h - o) / d, h / d
    if d < 0.0:
        return c, -1, (lo + c * h - o) / d, -h / d
    return c, 0, _INF, _INF


@njit(inline="always", fastmath=False, cache=True)
def _origin_world(R, tr, orig, a):
    """World-frame origin ``R @ orig[a] + tr`` of a rig-frame ray origin (three floats)."""
    o0 = R[0, 0] * orig[a, 0] + R[0, 1] * orig[a, 1] + R[0, 2] * orig[a, 2] + tr[0]
    o1 = R[1, 0] * orig[a, 0] + R[1, 1] * orig[a, 1] + R[1, 2] * orig[a, 2] + tr[1]
    o2 = R[2, 0] * orig[a, 0] + R[2, 1] * orig[a, 1] + R[2, 2] * orig[a, 2] + tr[2]
    return o0, o1, o2


@njit(inline="always", fastmath=False, cache=True)
def _direction_world(R, dirs, b, si):
    """World-frame direction ``R @ dirs[b, si]`` (float64, not normalised; three floats)."""
    e0 = dirs[b, si, 0]
    e1 = dirs[b, si, 1]
    e2 = dirs[b, si, 2]
    d0 = R[0, 0] * e0 + R[0, 1] * e1 + R[0, 2] * e2
    d1 = R[1, 0] * e0 + R[1, 1] * e1 + R[1, 2] * e2
    d2 = R[2, 0] * e0 + R[2, 1] * e1 + R[2, 2] * e2
    return d0, d1, d2


@njit(fastmath=False, cache=True)
def _trace_range(k0, k1, orig, dirs, oidx, outer, R, tr,
                 sph_c, sph_r, sph_tex, g_lo, g_cell, g_dims, g_start, g_items,
                 box_lo, box_hi, box_tex,
                 rect_o, rect_ex, rect_ey, rect_bounds, rect_uv, rect_tex,
                 tex_kind, tex_param, wave_start, waves, max_waves, img_start, img_shape, img_data,
                 sky_tex, light, shade,
                 rad_out, t_out, id_out):
    """Trace rays k0 <= k < k1 (serially): one call per chunk keeps argument passing out of
    the per-ray cost. Writes the mean radiance over sub-samples, and the distance and
    primitive id of sub-sample 0."""
    B = dirs.shape[0]
    S = dirs.shape[1]
    tmp = np.empty(max(max_waves, 1))
    a = k0 // B if outer else oidx[k0]      # origin and direction indices of ray k0
    b = k0 - a * B if outer else k0
    for ray in range(k0, k1):
        o0, o1, o2 = _origin_world(R, tr, orig, a)
        acc = 0.0
        t0 = np.nan
        pid0 = np.int64(-2)
        for si in range(S):
            d0, d1, d2 = _direction_world(R, dirs, b, si)
            nn = d0 * d0 + d1 * d1 + d2 * d2
            if nn > 0.0 and nn < _INF:           # NaN / unprojectable directions contribute 0
                nn = math.sqrt(nn)
                d0 /= nn
                d1 /= nn
                d2 /= nn
                i0 = 1.0 / d0 if d0 != 0.0 else 1e300
                i1 = 1.0 / d1 if d1 != 0.0 else 1e300
                i2 = 1.0 / d2 if d2 != 0.0 else 1e300
                best = _INF
                kind = -1      # 0 sphere, 1 box, 2 rectangle
                idx = -1
                nsph = sph_c.shape[0]
                nbox = box_lo.shape[0]
                nrect = rect_o.shape[0]

                # Rectangles (few; brute force).
                for k in range(nrect):
                    n0 = rect_ex[k, 1] * rect_ey[k, 2] - rect_ex[k, 2] * rect_ey[k, 1]
                    n1 = rect_ex[k, 2] * rect_ey[k, 0] - rect_ex[k, 0] * rect_ey[k, 2]
                    n2 = rect_ex[k, 0] * rect_ey[k, 1] - rect_ex[k, 1] * rect_ey[k, 0]
                    den = n0 * d0 + n1 * d1 + n2 * d2
                    if abs(den) < 1e-12:
                        continue
                    t = (n0 * (rect_o[k, 0] - o0) + n1 * (rect_o[k, 1] - o1) + n2 * (rect_o[k, 2] - o2)) / den
                    if t <= _EPS_T or t >= best:
                        continue
                    w0 = o0 + t * d0 - rect_o[k, 0]
                    w1 = o1 + t * d1 - rect_o[k, 1]
                    w2 = o2 + t * d2 - rect_o[k, 2]
                    s = w0 * rect_ex[k, 0] + w1 * rect_ex[k, 1] + w2 * rect_ex[k, 2]
                    q = w0 * rect_ey[k, 0] + w1 * rect_ey[k, 1] + w2 * rect_ey[k, 2]
                    if s < rect_bounds[k, 0] or s > rect_bounds[k, 1] or q < rect_bounds[k, 2] or q > rect_bounds[k, 3]:
                        continue
                    best = t
                    kind = 2
                    idx = k

                # Axis-aligned boxes (few; brute force). Seen from outside: entry face; from inside: exit face.
                for k in range(nbox):
                    tn, tf = _slab(o0, o1, o2, i0, i1, i2, box_lo[k, 0], box_lo[k, 1], box_lo[k, 2],
                                   box_hi[k, 0], box_hi[k, 1], box_hi[k, 2])
                    t = tn if tn > _EPS_T else tf
                    if tn <= tf and t > _EPS_T and t < best:
                        best = t
                        kind = 1
                        idx = k

                # Spheres: uniform grid walked by 3-D DDA, or brute force when there is no grid.
                ncell = g_dims[0] * g_dims[1] * g_dims[2]
                if nsph > 0 and ncell == 0:
                    for k in range(nsph):
                        t = _hit_sphere(o0, o1, o2, d0, d1, d2, sph_c[k, 0], sph_c[k, 1], sph_c[k, 2], sph_r[k])
                        if t < best:
                            best = t
                            kind = 0
                            idx = k
                elif nsph > 0:
                    h = g_cell[0]
                    nx = g_dims[0]
                    ny = g_dims[1]
                    nz = g_dims[2]
                    tn, tf = _slab(o0, o1, o2, i0, i1, i2, g_lo[0], g_lo[1], g_lo[2],
                                   g_lo[0] + nx * h, g_lo[1] + ny * h, g_lo[2] + nz * h)
                    if tn < 0.0:
                        tn = 0.0
                    if tn <= tf and tn < best:
                        ix, sx, mx, dx = _dda_init(o0, d0, g_lo[0], h, nx, tn)
                        iy, sy, my, dy = _dda_init(o1, d1, g_lo[1], h, ny, tn)
                        iz, sz, mz, dz = _dda_init(o2, d2, g_lo[2], h, nz, tn)
                        while True:
                            cell = ix + nx * (iy + ny * iz)
                            for j in range(g_start[cell], g_start[cell + 1]):
                                k = g_items[j]
                                t = _hit_sphere(o0, o1, o2, d0, d1, d2, sph_c[k, 0], sph_c[k, 1], sph_c[k, 2], sph_r[k])
                                if t < best:
                                    best = t
                                    kind = 0
                                    idx = k
                            if mx <= my and mx <= mz:
                                if best <= mx or mx > tf:
                                    break
                                ix += sx
                                if ix < 0 or ix >= nx:
                                    break
                                mx += dx
                            elif my <= mz:
                                if best <= my or my > tf:
                                    break
                                iy += sy
                                if iy < 0 or iy >= ny:
                                    break
                                my += dy
                            else:
                                if best <= mz or mz > tf:
                                    break
                                iz += sz
                                if iz < 0 or iz >= nz:
                                    break
                                mz += dz

                if kind < 0:
                    # Sky: a smooth function of the world direction only.
                    val = _texture(sky_tex, d0, d1, d2, 0.0, 0.0, tex_kind, tex_param, wave_start, waves, tmp,
                                   img_start, img_shape, img_data)
                    pid = -1
                else:
                    p0 = o0 + best * d0
                    p1 = o1 + best * d1
                    p2 = o2 + best * d2
                    s = 0.0
                    q = 0.0
                    if kind == 0:
                        x0 = p0 - sph_c[idx, 0]     # texture in the sphere's own frame
                        x1 = p1 - sph_c[idx, 1]
                        x2 = p2 - sph_c[idx, 2]
                        n0 = x0 / sph_r[idx]
                        n1 = x1 / sph_r[idx]
                        n2 = x2 / sph_r[idx]
                        ti = sph_tex[idx]
                        pid = idx
                    elif kind == 1:
                        # the face hit: the box plane nearest to the hit point
                        bax = 0
                        gap = min(abs(p0 - box_lo[idx, 0]), abs(p0 - box_hi[idx, 0]))
                        g = min(abs(p1 - box_lo[idx, 1]), abs(p1 - box_hi[idx, 1]))
                        if g < gap:
                            gap = g
                            bax = 1
                        g = min(abs(p2 - box_lo[idx, 2]), abs(p2 - box_hi[idx, 2]))
                        if g < gap:
                            bax = 2
                        n0 = 1.0 if bax == 0 else 0.0
                        n1 = 1.0 if bax == 1 else 0.0
                        n2 = 1.0 if bax == 2 else 0.0
                        ti = box_tex[idx]
                        x0 = p0
                        x1 = p1
                        x2 = p2
                        pid = nsph + idx
                    else:
                        n0 = rect_ex[idx, 1] * rect_ey[idx, 2] - rect_ex[idx, 2] * rect_ey[idx, 1]
                        n1 = rect_ex[idx, 2] * rect_ey[idx, 0] - rect_ex[idx, 0] * rect_ey[idx, 2]
                        n2 = rect_ex[idx, 0] * rect_ey[idx, 1] - rect_ex[idx, 1] * rect_ey[idx, 0]
                        w0 = p0 - rect_o[idx, 0]
                        w1 = p1 - rect_o[idx, 1]
                        w2 = p2 - rect_o[idx, 2]
                        ls = w0 * rect_ex[idx, 0] + w1 * rect_ex[idx, 1] + w2 * rect_ex[idx, 2]
                        lq = w0 * rect_ey[idx, 0] + w1 * rect_ey[idx, 1] + w2 * rect_ey[idx, 2]
                        s = rect_uv[idx, 0, 0] * ls + rect_uv[idx, 0, 1] * lq + rect_uv[idx, 0, 2]
                        q = rect_uv[idx, 1, 0] * ls + rect_uv[idx, 1, 1] * lq + rect_uv[idx, 1, 2]
                        ti = rect_tex[idx]
                        x0 = ls
                        x1 = lq
                        x2 = 0.0
                        pid = nsph + nbox + idx
                    # The normal of the side facing the ray (inside-facing walls, two-sided rectangles).
                    if n0 * d0 + n1 * d1 + n2 * d2 > 0.0:
                        n0 = -n0
                        n1 = -n1
                        n2 = -n2
                    alb = _texture(ti, x0, x1, x2, s, q, tex_kind, tex_param, wave_start, waves, tmp,
                                   img_start, img_shape, img_data)
                    lam = n0 * light[0] + n1 * light[1] + n2 * light[2]
                    if lam < 0.0:
                        lam = 0.0
                    val = alb * (shade[0] + shade[1] * lam)
                    if shade[2] > 0.0 and lam > 0.0:
                        # Phong highlight: the light mirrored about the normal, against the direction
                        # back along the ray; view-dependent, so a surface point differs between views
                        c = -((2.0 * lam * n0 - light[0]) * d0 + (2.0 * lam * n1 - light[1]) * d1
                              + (2.0 * lam * n2 - light[2]) * d2)
                        if c > 0.0:
                            val += shade[2] * c ** shade[3]
                acc += val
                if si == 0:
                    t0 = best
                    pid0 = pid
        rad_out[ray] = acc / S
        t_out[ray] = t0
        id_out[ray] = pid0
        b += 1
        if outer:
            if b == B:
                b = 0
                a += 1
        elif b < B:
            a = oidx[b]


_CHUNK = 256                # rays per task of the parallel loop
_SERIAL_MAX_RAYS = 8192     # batches up to this many rays (x sub-samples) run on the calling thread


@njit(parallel=True, fastmath=False, cache=True)
def _trace_kernel(orig, dirs, oidx, outer, R, tr,
                  sph_c, sph_r, sph_tex, g_lo, g_cell, g_dims, g_start, g_items,
                  box_lo, box_hi, box_tex,
                  rect_o, rect_ex, rect_ey, rect_bounds, rect_uv, rect_tex,
                  tex_kind, tex_param, wave_start, waves, max_waves, img_start, img_shape, img_data,
                  sky_tex, light, shade,
                  rad_out, t_out, id_out):
    """Trace all rays, in parallel over chunks of :data:`_CHUNK` rays (see :func:`_trace_range`)."""
    n = orig.shape[0] * dirs.shape[0] if outer else dirs.shape[0]
    nchunk = (n + _CHUNK - 1) // _CHUNK
    for c in prange(nchunk):
        k0 = np.int64(c) * _CHUNK
        k1 = min(k0 + _CHUNK, n)
        _trace_range(k0, k1, orig, dirs, oidx, outer, R, tr,
                     sph_c, sph_r, sph_tex, g_lo, g_cell, g_dims, g_start, g_items,
                     box_lo, box_hi, box_tex,
                     rect_o, rect_ex, rect_ey, rect_bounds, rect_uv, rect_tex,
                     tex_kind, tex_param, wave_start, waves, max_waves, img_start, img_shape, img_data,
                     sky_tex, light, shade,
                     rad_out, t_out, id_out)


class TraceResult:
    """What :func:`trace_rays` / :func:`trace_outer` return (dims ``*B`` of the ray batch)."""

    __slots__ = ("radiance", "distance", "primitive")

    def __init__(self, radiance: np.ndarray, distance: np.ndarray, primitive: np.ndarray):
        self.radiance = radiance
        """(*B,) float32 in [0, 1]: mean radiance over the sub-sample directions."""
        self.distance = distance
        """(*B,) float64 [m]: distance along the (first sub-sample) ray to the hit; inf for sky,
        NaN for an unprojectable direction."""
        self.primitive = primitive
        """(*B,) int32: id of the primitive hit (spheres, then boxes, then rectangles); -1 sky,
        -2 unprojectable."""


def _run(scene, orig, dirs, oidx, T_world_rig):
    """Checks, one compiled signature (C-contiguous writable arrays of fixed dtypes), and
    the kernel call. ``oidx`` None: outer layout; else (B,) origin index per direction set."""
    T = np.asarray(T_world_rig, dtype=np.float64)
    if T.shape != (4, 4):
        raise ValueError("T_world_rig must be (4, 4)")
    R = np.require(T[:3, :3], np.float64, ["C", "W"])
    tr = np.require(T[:3, 3], np.float64, ["C", "W"])
    orig = np.require(orig, np.float64, ["C", "W"])
    dirs = np.require(dirs, np.float32, ["C", "W"])
    if orig.ndim != 2 or orig.shape[1] != 3:
        raise ValueError("origins must be (A, 3)")
    if dirs.ndim != 3 or dirs.shape[2] != 3:
        raise ValueError("directions must be (B, S, 3)")
    outer = oidx is None
    if outer:
        oidx = np.zeros(0, np.int64)
        n = orig.shape[0] * dirs.shape[0]
    else:
        oidx = np.require(oidx, np.int64, ["C", "W"])
        n = dirs.shape[0]
        if oidx.shape != (n,) or (n and (oidx.min() < 0 or oidx.max() >= orig.shape[0])):
            raise ValueError("origin_index must be (B,) indices into the origins")
    args = tuple(np.require(a, a.dtype, ["C", "W"]) if isinstance(a, np.ndarray) else a
                 for a in scene.kernel_args())
    rad = np.empty(n, np.float32)
    dist = np.empty(n, np.float64)
    pid = np.empty(n, np.int32)
    if n * dirs.shape[1] <= _SERIAL_MAX_RAYS:
        # Small batches: no parallel region (its start-up latency would dominate).
        _trace_range(0, n, orig, dirs, oidx, outer, R, tr, *args, rad, dist, pid)
        return rad, dist, pid
    # Dynamic scheduling (a few chunks per grab) keeps both cores busy even when ray costs
    # vary across the image or another process holds a core.
    prev = numba.set_parallel_chunksize(4)
    try:
        _trace_kernel(orig, dirs, oidx, outer, R, tr, *args, rad, dist, pid)
    finally:
        numba.set_parallel_chunksize(prev)
    return rad, dist, pid


def trace_outer(scene, origins_rig: np.ndarray, directions_rig: np.ndarray,
                T_world_rig: np.ndarray) -> TraceResult:
    """Trace every origin with every direction set.

    origins_rig: (A, 3) [m] ray origins in the rig frame.
    directions_rig: (B, S, 3) directions in the rig frame, stored as float32 (normalised
        inside; NaN marks an unusable direction, which contributes 0); the S sub-samples
        of each b are averaged.
    T_world_rig: (4, 4) pose of the rig in the scene's world frame.
    Returns a :class:`TraceResult` with dims (A, B).
    """
    origins_rig = np.asarray(origins_rig, dtype=np.float64).reshape(-1, 3)
    rad, dist, pid = _run(scene, origins_rig, directions_rig, None, T_world_rig)
    A, B = origins_rig.shape[0], np.shape(directions_rig)[0]
    return TraceResult(rad.reshape(A, B), dist.reshape(A, B), pid.reshape(A, B))


def trace_indexed(scene, origins_rig: np.ndarray, directions_rig: np.ndarray, origin_index: np.ndarray,
                  T_world_rig: np.ndarray) -> TraceResult:
    """Trace direction set ``b`` from origin ``origin_index[b]``.

    origins_rig: (A, 3) [m] ray origins in the rig frame (e.g. camera centres).
    directions_rig: (B, S, 3) as for :func:`trace_outer`.
    origin_index: (B,) int index into ``origins_rig`` per direction set.
    Returns a :class:`TraceResult` with dims (B,).
    """
    return TraceResult(*_run(scene, origins_rig, directions_rig, origin_index, T_world_rig))


def trace_rays(scene, rays: RayBundle, T_world_rig: np.ndarray | None = None) -> TraceResult:
    """Trace a bundle of rays (one direction each).

    rays: origins and directions of dims (*B, 3); broadcast against each other (directions
        are rounded to float32, like every ray the caster takes).
        They are taken to be in the rig frame, placed in the world by ``T_world_rig``
        (default identity: the rays are already in the world frame).
    Returns a :class:`TraceResult` with dims (*B).
    """
    shape = rays.shape
    o = np.broadcast_to(rays.origins, shape + (3,)).reshape(-1, 3)
    d = np.broadcast_to(rays.directions, shape + (3,)).reshape(-1, 1, 3)
    T = np.eye(4) if T_world_rig is None else T_world_rig
    rad, dist, pid = _run(scene, o, d, np.arange(o.shape[0]), T)
    return TraceResult(rad.reshape(shape), dist.reshape(shape), pid.reshape(shape))
