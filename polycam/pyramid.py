"""The coarse-to-fine pyramid of a light-field frame pair for the motion solver.

Each coarser level smooths with the binomial [1 4 6 4 1]/16 and keeps every second sample
along (u, v) while at least 32 samples remain, and with
:attr:`~polycam.motion_options.MotionOptions.pyramid_xy` also along (x, y) while the halved
axis still leaves valid derivative samples; the grid's axes are halved with it, so every
level is a :class:`~polycam.lightfield.LightFieldGrid` (conventions: docs/conventions.md).
``_pyramid`` returns the levels finest first, each a ``_Level`` (grid, the two frames and
their confidences).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numba
import numpy as np

from .derivatives import correlate_axis
from .lightfield import Axis, LightFieldGrid
from .motion_options import MotionOptions

__all__: list[str] = []


@numba.njit(parallel=True, cache=True)
def _downsample_uv_kernel(a, taps, out):
    """out[n, i, j] = Σ_s taps[s] Σ_t taps[t] a[n, clamp(2i + s − 2), clamp(2j + t − 2)] for
    a (N, Nv, Nu) view stack: the binomial smoothing of both axes, evaluated only at the
    kept samples (clamped borders, float32 sums in the order of :func:`correlate_axis`)."""
    N, Nv, Nu = a.shape
    Nv2 = out.shape[1]
    Nu2 = out.shape[2]
    for n in numba.prange(N):
        row = np.empty(Nu, np.float32)
        src = a[n]
        for i in range(Nv2):
            row[:] = 0.0
            for s in range(5):
                r = src[min(max(2 * i + s - 2, 0), Nv - 1)]
                w = taps[s]
                for u in range(Nu):
                    row[u] += w * r[u]
            o = out[n, i]
            for j in range(Nu2):
                acc = np.float32(0.0)
                for t in range(5):
                    acc += taps[t] * row[min(max(2 * j + t - 2, 0), Nu - 1)]
                o[j] = acc


_BINOMIAL = np.array([1, 4, 6, 4, 1], np.float32) / 16
"""The pyramid's smoothing filter along each halved axis (also the motion solver's blur of a grid too
small for a coarser level: ``polycam.motion._blur_uv``)."""


def _downsample(a: np.ndarray, axes: tuple[int, ...], alloc=None) -> np.ndarray:
    """Binomial [1 4 6 4 1]/16 smoothing then every second sample along ``axes`` of a (..., Ny, Nx, Nv, Nu)
    array. ``alloc(shape)``: where to put the result of (v, u) together, a float32 C array of
    those dims or None (a new one)."""
    taps = _BINOMIAL
    out = np.ascontiguousarray(a, dtype=np.float32)
    if tuple(axes) == (out.ndim - 2, out.ndim - 1):            # (v, u) together: one pass
        Nv, Nu = out.shape[-2:]
        shape = out.shape[:-2] + ((Nv - 1) // 2 + 1, (Nu - 1) // 2 + 1)
        res = None if alloc is None else alloc(shape)
        res = np.empty(shape, np.float32) if res is None else res
        _downsample_uv_kernel(out.reshape(-1, Nv, Nu), taps, res.reshape((-1,) + res.shape[-2:]))
        return res
    for ax in axes:
        out = correlate_axis(out, taps, ax)
        sl = [slice(None)] * out.ndim
        sl[ax] = slice(None, None, 2)
        out = np.ascontiguousarray(out[tuple(sl)])
    return out


def _half_axis(a: Axis) -> Axis:
    n = (a.count - 1) // 2 + 1
    return Axis(a.min, a.min + (n - 1) * 2 * a.step, n)


@dataclass
class _Level:
    grid: LightFieldGrid
    L0: np.ndarray      # (F, Ny, Nx, Nv, Nu) float32
    L1: np.ndarray
    W0: np.ndarray | None
    W1: np.ndarray | None
    views: dict = field(default_factory=dict)
    """Facts about the viewpoints (e.g. the cameras' stride), shared by the levels that keep
    the finest level's (x, y) sampling."""
    noise_var: float | None = None
    """The frames' sensor-noise variance per sample once estimated
    (:func:`polycam.motion_weights._noise_variance`; the frames of a level do not change)."""


def _pyramid(L0, L1, W0, W1, grid: LightFieldGrid, opts: MotionOptions, pairs_radius: dict,
             alloc=None) -> list[_Level]:
    """Levels finest first: ``opts.levels`` of them at most (:func:`_add_level`).
    ``alloc``: as :func:`_downsample`'s (the motion solver lends idle work memory)."""
    levels = [_Level(grid, L0, L1, W0, W1)]
    for _ in range(opts.levels - 1):
        if not _add_level(levels, opts, pairs_radius, alloc):
            break
    return levels


def _add_level(levels: list[_Level], opts: MotionOptions, pairs_radius: dict, alloc=None) -> bool:
    """Append the next coarser level to ``levels`` (finest first); False when no axis can be
    halved. (u, v) are halved while ≥ 32 samples remain; (x, y) only with ``pyramid_xy`` and
    while the halved axis still leaves valid derivative samples."""
    g = levels[-1].grid
    axes, kw = [], {}
    for name, ax_idx in (("v", 3), ("u", 4)):
        a = getattr(g, name)
        if a.count >= 32:
            axes.append(ax_idx)
            kw[name] = _half_axis(a)
    if opts.pyramid_xy:
        for name, ax_idx in (("y", 1), ("x", 2)):
            a = getattr(g, name)
            if (a.count - 1) // 2 + 1 >= 2 * pairs_radius[name] + 3:
                axes.append(ax_idx)
                kw[name] = _half_axis(a)
    if not axes:
        return False
    ng = replace(g, **kw)
    prev = levels[-1]

    def ds(a, axes=tuple(sorted(axes))):
        return None if a is None else _downsample(a, axes, alloc)

    same_views = 1 not in axes and 2 not in axes
    levels.append(_Level(ng, ds(prev.L0), ds(prev.L1), ds(prev.W0), ds(prev.W1),
                         prev.views if same_views else {}))
    return True
