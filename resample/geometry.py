"""Which camera pixels feed which light-field cells, with what weight (built once per calibration and grid).

Every pixel's ray (rig frame, ``polycam.cameras.camera_rays``: ``mrcal.unproject`` of
the pixel centre) is intersected with the two planes of each face it points into
(SPEC.md): in face coordinates, with ``o`` the camera centre and ``d`` the
direction (``d_z > 0``),

    x = o_x + (z_pi - o_z) d_x / d_z,   y = o_y + (z_pi - o_z) d_y / d_z,
    u = f d_x / d_z,                     v = f d_y / d_z,

giving a scattered sample at fractional grid indices ``(iy, ix, iv, iu)``.

**Splat kernel.** A separable tent ``K = Π_a max(0, 1 - |i_a - c_a| / r_a)`` with
half-widths ``r_a`` in grid steps (``radius_xy``, ``radius_uv``; 1 = multilinear
splatting onto the 2^4 surrounding cells). An axis with a single sample is
collapsed (every sample lands on it with weight 1). Entries with ``K <
min_weight`` are dropped.

**Local-linear correction** (``linear=True``, the default). Plain splatting
(``Σ K L / Σ K``) reproduces constants only: it returns the light field at the
kernel-weighted centroid of the samples, not at the cell. With irregular
samples that is a blur and a shift. Instead each cell fits ``L ≈ a + b · (i - c)``
to its samples by least squares with weights ``K`` (the fit's slopes get a tiny
ridge ``ridge · Σ K`` so that a direction with no spread, e.g. all samples from
one camera centre on the focal plane, gets slope 0) and keeps ``a``. The fit is
linear in the samples, so it is still one row of weights per cell (the
"equivalent kernel"): they sum to 1 and reproduce any light field linear in
(x, y, u, v) exactly wherever the fit is determined. Where a fit would amplify
noise (``Σ |weights| > max_gain``, e.g. extrapolating off the edge of the data),
that cell falls back to plain splatting.

The result, :class:`SplatGeometry`, is a sparse matrix ``S`` (cells × input
pixels, CSR) and the per-cell kernel sums ``w0 = Σ K`` (the push-pull weight, in
samples). Resampling a frame is then ``x0 = S @ pixels`` plus the pyramid
(:mod:`resample.pushpull`).
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from functools import cached_property

import numba
import numpy as np

from polycam.cameras import camera_rays
from polycam.lightfield import LightFieldGrid

__all__ = ["KernelOptions", "CameraLayout", "Samples", "SplatGeometry", "camera_layout", "ray_samples",
           "build_geometry", "splat"]

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class KernelOptions:
    """How samples are splatted onto the grid (see the module docstring)."""

    radius_xy: float = 1.0
    """Tent half-width along x and y [grid steps]."""
    radius_uv: float = 1.0
    """Tent half-width along u and v [grid steps]."""
    linear: bool = True
    """Local-linear correction (exact for light fields linear in x, y, u, v)."""
    ridge: float = 1e-8
    """Ridge on the fitted slopes, relative to the cell's kernel sum: it only decides the
    slopes the samples leave free (e.g. along x when all come from one camera centre on
    the focal plane), which then come out 0."""
    max_gain: float = 4.0
    """A cell whose local-linear weights have ``Σ |w| >`` this falls back to plain splatting."""
    min_weight: float = 1e-3
    """Kernel weights below this are dropped."""

    def __post_init__(self) -> None:
        if not (self.radius_xy > 0 and self.radius_uv > 0):
            raise ValueError("kernel radii must be > 0")
        if self.max_gain < 1 or self.ridge < 0 or not 0 <= self.min_weight < 1:
            raise ValueError("max_gain >= 1, ridge >= 0 and 0 <= min_weight < 1 are required")


@dataclass(frozen=True)
class CameraLayout:
    """Where each camera's pixels sit in the flat input vector of a frame."""

    ids: tuple[str, ...]
    """Camera ids, in input order."""
    sizes: tuple[tuple[int, int], ...]
    """(H, W) [px] per camera."""
    offsets: np.ndarray
    """(N + 1,) int64: camera i's pixels are ``offsets[i]:offsets[i+1]`` (row-major H x W)."""

    @property
    def num_pixels(self) -> int:
        return int(self.offsets[-1])


def camera_layout(models: dict, ids: list[str] | None = None) -> CameraLayout:
    """The input layout of cameras ``ids`` (default: all models, in order)."""
    ids = list(models) if ids is None else list(ids)
    sizes = []
    for c in ids:
        W, H = (int(v) for v in models[c].imagersize())
        sizes.append((H, W))
    offsets = np.zeros(len(ids) + 1, np.int64)
    offsets[1:] = np.cumsum([h * w for h, w in sizes])
    return CameraLayout(tuple(ids), tuple(sizes), offsets)


@dataclass(frozen=True)
class Samples:
    """Scattered light-field samples of the camera pixels: one per (pixel, face it points into)."""

    pixel: np.ndarray
    """(S,) int64 index into the flat input vector (:class:`CameraLayout`)."""
    face: np.ndarray
    """(S,) int32 face index."""
    coord: np.ndarray
    """(S, 4) float64 fractional grid indices ``(iy, ix, iv, iu)`` (array axis order)."""


def _fractional(values: np.ndarray, axis) -> np.ndarray:
    if axis.count == 1:
        return np.zeros_like(values)
    return (values - axis.min) / axis.step


def ray_samples(models: dict, grid: LightFieldGrid, layout: CameraLayout, *,
                margin: float = 1.0) -> Samples:
    """Intersect every pixel ray of the cameras in ``layout`` with the planes of every face.

    A pixel feeds face k when its direction has a positive face-z component and its
    fractional indices lie within ``margin`` steps of the grid (count-1 axes always match).
    Pixels that cannot be unprojected (NaN) feed nothing.
    """
    pix, face, coord = [], [], []
    shape = np.array([grid.y.count, grid.x.count, grid.v.count, grid.u.count], float)
    for ci, cam in enumerate(layout.ids):
        rays = camera_rays(models[cam])
        H, W = layout.sizes[ci]
        o = np.asarray(rays.origins, float).reshape(-1, 3)
        d = np.asarray(rays.directions, float).reshape(-1, 3)
        base = np.arange(H * W, dtype=np.int64) + layout.offsets[ci]
        good = np.all(np.isfinite(d), axis=1)
        for k, fc in enumerate(grid.faces):
            R = np.asarray(fc.R_rig_face, float)
            of = o @ R
            df = d @ R
            with np.errstate(invalid="ignore", divide="ignore"):
                ok = good & (df[:, 2] > 1e-9)
                inv = np.where(ok, 1.0 / np.where(ok, df[:, 2], 1.0), 0.0)
                s = (fc.z_pi - of[:, 2]) * inv
                x = of[:, 0] + s * df[:, 0]
                y = of[:, 1] + s * df[:, 1]
                u = fc.f * df[:, 0] * inv
                v = fc.f * df[:, 1] * inv
            c = np.stack([_fractional(y, grid.y), _fractional(x, grid.x),
                          _fractional(v, grid.v), _fractional(u, grid.u)], axis=1)
            inside = ok & np.all((c > -margin) & (c < shape - 1 + margin), axis=1)
            pix.append(base[inside])
            face.append(np.full(int(inside.sum()), k, np.int32))
            coord.append(c[inside])
    if not pix:
        return Samples(np.zeros(0, np.int64), np.zeros(0, np.int32), np.zeros((0, 4)))
    return Samples(np.concatenate(pix), np.concatenate(face), np.concatenate(coord))


# ----------------------------------------------------------------------------- numba kernels


@numba.njit(cache=True, inline="always")
def _support(c, r, n):
    """First cell and count of cells with a positive tent weight along one axis."""
    if n == 1:
        return 0, 1
    lo = int(math.floor(c - r)) + 1
    hi = int(math.ceil(c + r)) - 1
    if lo < 0:
        lo = 0
    if hi > n - 1:
        hi = n - 1
    if hi < lo:
        return 0, 0
    return lo, hi - lo + 1


@numba.njit(cache=True, inline="always")
def _tent(c, i, r, n):
    if n == 1:
        return 1.0
    t = 1.0 - abs(c - i) / r
    return t if t > 0.0 else 0.0


@numba.njit(cache=True)
def _count_rows(face, coord, dims, radii, min_w, counts):
    """counts[cell] += number of samples whose kernel reaches the cell."""
    Ny, Nx, Nv, Nu = dims[1], dims[2], dims[3], dims[4]
    for s in range(face.shape[0]):
        c0, c1, c2, c3 = coord[s, 0], coord[s, 1], coord[s, 2], coord[s, 3]
        l0, n0 = _support(c0, radii[0], Ny)
        l1, n1 = _support(c1, radii[1], Nx)
        l2, n2 = _support(c2, radii[2], Nv)
        l3, n3 = _support(c3, radii[3], Nu)
        fbase = face[s] * Ny
        for a in range(l0, l0 + n0):
            ka = _tent(c0, a, radii[0], Ny)
            for b in range(l1, l1 + n1):
                kb = ka * _tent(c1, b, radii[1], Nx)
                for e in range(l2, l2 + n2):
                    ke = kb * _tent(c2, e, radii[2], Nv)
                    row = ((fbase + a) * Nx + b) * Nv + e
                    for g in range(l3, l3 + n3):
                        k = ke * _tent(c3, g, radii[3], Nu)
                        if k >= min_w and k > 0.0:
                            counts[row * Nu + g] += 1


@numba.njit(cache=True)
def _fill_rows(face, coord, dims, radii, min_w, cursor, sample_of):
    """sample_of[cursor[cell]++] = s for every (sample, cell) pair (rows in sample order)."""
    Ny, Nx, Nv, Nu = dims[1], dims[2], dims[3], dims[4]
    for s in range(face.shape[0]):
        c0, c1, c2, c3 = coord[s, 0], coord[s, 1], coord[s, 2], coord[s, 3]
        l0, n0 = _support(c0, radii[0], Ny)
        l1, n1 = _support(c1, radii[1], Nx)
        l2, n2 = _support(c2, radii[2], Nv)
        l3, n3 = _support(c3, radii[3], Nu)
        fbase = face[s] * Ny
        for a in range(l0, l0 + n0):
            ka = _tent(c0, a, radii[0], Ny)
            for b in range(l1, l1 + n1):
                kb = ka * _tent(c1, b, radii[1], Nx)
                for e in range(l2, l2 + n2):
                    ke = kb * _tent(c2, e, radii[2], Nv)
                    row = ((fbase + a) * Nx + b) * Nv + e
                    for g in range(l3, l3 + n3):
                        k = ke * _tent(c3, g, radii[3], Nu)
                        if k >= min_w and k > 0.0:
                            cell = row * Nu + g
                            sample_of[cursor[cell]] = s
                            cursor[cell] += 1


@numba.njit(cache=True)
def _solve_spd(N, rhs, n):
    """Solve N x = rhs for a small symmetric positive definite N (Cholesky, in place copies)."""
    L = np.zeros((n, n))
    for i in range(n):
        for j in range(i + 1):
            s = N[i, j]
            for k in range(j):
                s -= L[i, k] * L[j, k]
            if i == j:
                if s <= 0.0:
                    return False, rhs
                L[i, i] = math.sqrt(s)
            else:
                L[i, j] = s / L[j, j]
    y = np.zeros(n)
    for i in range(n):
        s = rhs[i]
        for k in range(i):
            s -= L[i, k] * y[k]
        y[i] = s / L[i, i]
    x = np.zeros(n)
    for i in range(n - 1, -1, -1):
        s = y[i]
        for k in range(i + 1, n):
            s -= L[k, i] * x[k]
        x[i] = s / L[i, i]
    return True, x


_MOMENT_TOL = 1e-6
"""A cell's fit counts as determined when the first moments of its equivalent kernel,
``Σ w_s (i_s - c) / r`` per axis, are below this (they vanish for an exact linear fit)."""


@numba.njit(cache=True, parallel=True)
def _row_weights(indptr, sample_of, coord, dims, radii, linear, ridge, max_gain, pixel, indices, data, wsum,
                 nlinear, determined):
    """Per cell: kernel sum, the equivalent-kernel weights of its samples (computed in float64, written
    to ``data`` as float32) with their input pixels (``indices[j] = pixel[sample_of[j]]``, int32) and
    whether the local-linear fit is determined (exact for linear light fields). Writing the final
    arrays here, not through float64 / int64 copies of every entry, keeps the build's memory traffic
    (and its first-touch page faults) to a third."""
    Ny, Nx, Nv, Nu = dims[1], dims[2], dims[3], dims[4]
    nrows = indptr.shape[0] - 1
    for cell in numba.prange(nrows):
        j0, j1 = indptr[cell], indptr[cell + 1]
        if j1 == j0:
            wsum[cell] = 0.0
            continue
        g = cell % Nu
        rest = cell // Nu
        e = rest % Nv
        rest //= Nv
        b = rest % Nx
        a = (rest // Nx) % Ny
        w = np.empty(j1 - j0)                  # the cell's weights, float64 until written out
        centre = np.array([a, b, e, g], np.float64)
        n_ax = np.array([Ny, Nx, Nv, Nu])
        N = np.zeros((5, 5))
        phi = np.zeros(5)
        ksum = 0.0
        for j in range(j0, j1):
            s = sample_of[j]
            k = 1.0
            phi[0] = 1.0
            for ax in range(4):
                k *= _tent(coord[s, ax], centre[ax], radii[ax], n_ax[ax])
                phi[ax + 1] = (coord[s, ax] - centre[ax]) / radii[ax] if n_ax[ax] > 1 else 0.0
            w[j - j0] = k
            ksum += k
            if linear:
                for p in range(5):
                    for q in range(p + 1):
                        N[p, q] += k * phi[p] * phi[q]
        wsum[cell] = ksum
        done = False
        if linear:
            for p in range(5):
                for q in range(p):
                    N[q, p] = N[p, q]
            for p in range(1, 5):
                N[p, p] += ridge * ksum
            rhs = np.zeros(5)
            rhs[0] = 1.0
            ok, gvec = _solve_spd(N, rhs, 5)
            if ok:
                gain = 0.0
                for j in range(j0, j1):
                    s = sample_of[j]
                    dot = gvec[0]
                    for ax in range(4):
                        if n_ax[ax] > 1:
                            dot += gvec[ax + 1] * (coord[s, ax] - centre[ax]) / radii[ax]
                    gain += abs(w[j - j0] * dot)
                if gain <= max_gain:
                    for ax in range(4):
                        phi[ax + 1] = 0.0           # reused: first moments of the equivalent kernel
                    for j in range(j0, j1):
                        s = sample_of[j]
                        dot = gvec[0]
                        for ax in range(4):
                            if n_ax[ax] > 1:
                                dot += gvec[ax + 1] * (coord[s, ax] - centre[ax]) / radii[ax]
                        w[j - j0] = w[j - j0] * dot
                        for ax in range(4):
                            if n_ax[ax] > 1:
                                phi[ax + 1] += w[j - j0] * (coord[s, ax] - centre[ax]) / radii[ax]
                    done = True
                    nlinear[cell] = 1
                    worst = 0.0
                    for ax in range(4):
                        worst = max(worst, abs(phi[ax + 1]))
                    if worst <= _MOMENT_TOL:
                        determined[cell] = 1
        if not done:
            for j in range(j0, j1):
                w[j - j0] = w[j - j0] / ksum
        for j in range(j0, j1):
            data[j] = w[j - j0]
            indices[j] = pixel[sample_of[j]]


@numba.njit(cache=True, parallel=True)
def _csr_matvec(rows, rptr, indices, data, x, out):
    """out[rows[r], :] = Σ_j data[j] x[indices[j], :] over the entries rptr[r]..rptr[r+1] of
    the non-empty rows (x: (P, C); out: (nrows, C); the other rows are not touched)."""
    C = x.shape[1]
    for r in numba.prange(rows.shape[0]):
        j0, j1 = rptr[r], rptr[r + 1]
        q = rows[r]
        for c in range(C):
            acc = np.float32(0.0)
            for j in range(j0, j1):
                acc += data[j] * x[indices[j], c]
            out[q, c] = acc


@numba.njit(cache=True, parallel=True)
def _csr_matvec1(rows, rptr, indices, data, x, out):
    """:func:`_csr_matvec` for a single channel (x: (P,); out: (nrows,))."""
    for r in numba.prange(rows.shape[0]):
        acc = np.float32(0.0)
        for j in range(rptr[r], rptr[r + 1]):
            acc += data[j] * x[indices[j]]
        out[rows[r]] = acc


# ----------------------------------------------------------------------------- geometry


@dataclass(frozen=True, eq=False)
class SplatGeometry:
    """The sparse splat of one camera layout onto one grid (see the module docstring)."""

    grid: LightFieldGrid
    layout: CameraLayout
    kernel: KernelOptions
    indptr: np.ndarray
    """(F*Ny*Nx*Nv*Nu + 1,) int64 CSR row pointers (rows = cells in array order)."""
    indices: np.ndarray
    """(nnz,) int32 input-pixel index of each entry."""
    data: np.ndarray
    """(nnz,) float32 weight of each entry (a row sums to 1 where the cell has samples)."""
    w0: np.ndarray
    """(F, Ny, Nx, Nv, Nu) float32 kernel sum per cell [samples]: the push-pull weight."""
    determined: np.ndarray
    """(F, Ny, Nx, Nv, Nu) bool: the cell's local-linear fit is pinned down by its samples (they
    spread around it in (u, v), and in (x, y) unless they all sit at the cell's (x, y)), so a
    light field linear in (x, y, u, v) is reproduced exactly there."""
    num_samples: int
    """Scattered samples (pixel, face) that reached the grid."""
    linear_fraction: float
    """Fraction of reached cells that use the local-linear weights (others: plain splat)."""

    @property
    def nnz(self) -> int:
        return int(self.data.shape[0])

    @cached_property
    def nonempty_rows(self) -> tuple[np.ndarray, np.ndarray]:
        """The rows with entries, (R,) int64 ascending, and their entries' pointers (R + 1,)
        int64 (row ``rows[r]`` holds entries ``ptr[r]..ptr[r + 1]``). Most cells
        get no sample (the views between cameras), and skipping them keeps the per-frame
        product from reading the full row-pointer array. Not pickled (rebuilt on first use)."""
        rows = np.flatnonzero(np.diff(self.indptr))
        ptr = np.append(self.indptr[rows], self.indptr[-1])
        return rows, ptr

    def __getstate__(self):
        state = self.__dict__.copy()
        state.pop("nonempty_rows", None)
        return state

    def to_scipy(self):
        """The splat as a ``scipy.sparse.csr_array`` (cells × input pixels)."""
        from scipy.sparse import csr_array

        return csr_array((self.data, self.indices, self.indptr),
                         shape=(self.indptr.shape[0] - 1, self.layout.num_pixels))


def build_geometry(models: dict, grid: LightFieldGrid, *, ids: list[str] | None = None,
                   kernel: KernelOptions | None = None) -> SplatGeometry:
    """Build the sparse splat of cameras ``ids`` (default all ``models``) onto ``grid``."""
    kernel = kernel or KernelOptions()
    layout = camera_layout(models, ids)
    margin = max(kernel.radius_xy, kernel.radius_uv)
    smp = ray_samples(models, grid, layout, margin=margin)
    return _geometry_from_samples(grid, layout, kernel, smp)


def _geometry_from_samples(grid: LightFieldGrid, layout: CameraLayout, kernel: KernelOptions,
                           smp: Samples) -> SplatGeometry:
    dims = np.array(grid.shape, np.int64)
    ncells = int(np.prod(dims))
    radii = np.array([kernel.radius_xy, kernel.radius_xy, kernel.radius_uv, kernel.radius_uv], float)
    coord = np.ascontiguousarray(smp.coord, np.float64)
    counts = np.zeros(ncells, np.int64)
    _count_rows(smp.face, coord, dims, radii, kernel.min_weight, counts)
    indptr = np.zeros(ncells + 1, np.int64)
    np.cumsum(counts, out=indptr[1:])
    nnz = int(indptr[-1])
    if layout.num_pixels >= 2**31:
        raise ValueError("more than 2^31 input pixels per frame are not supported")
    sample_of = np.empty(nnz, np.int32 if smp.pixel.shape[0] < 2**31 else np.int64)
    cursor = indptr[:-1].copy()
    _fill_rows(smp.face, coord, dims, radii, kernel.min_weight, cursor, sample_of)
    indices = np.empty(nnz, np.int32)
    data = np.empty(nnz, np.float32)
    wsum = np.zeros(ncells, np.float64)
    nlin = np.zeros(ncells, np.int8)
    det = np.zeros(ncells, np.int8)
    _row_weights(indptr, sample_of, coord, dims, radii, kernel.linear, kernel.ridge, kernel.max_gain,
                 smp.pixel, indices, data, wsum, nlin, det)
    del sample_of
    reached = int(np.count_nonzero(counts))
    geo = SplatGeometry(grid=grid, layout=layout, kernel=kernel, indptr=indptr, indices=indices,
                        data=data, w0=wsum.astype(np.float32).reshape(grid.shape),
                        determined=det.astype(bool).reshape(grid.shape), num_samples=int(smp.pixel.shape[0]),
                        linear_fraction=float(nlin.sum()) / reached if reached else 0.0)
    log.info("splat geometry: %d pixels -> %d samples -> %d cells reached of %d, %d entries "
             "(%.1f per sample), %.1f%% local-linear", layout.num_pixels, geo.num_samples, reached, ncells,
             nnz, nnz / max(geo.num_samples, 1), 100 * geo.linear_fraction)
    return geo


def splat(geo: SplatGeometry, pixels: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
    """``S @ pixels``: pixels (P,) or (P, C) float32 → (F, Ny, Nx, Nv, Nu[, C]) float32."""
    x = np.ascontiguousarray(pixels, np.float32)
    nrows = geo.indptr.shape[0] - 1
    if x.ndim == 1:
        o = np.zeros(nrows, np.float32) if out is None else out.reshape(nrows)
        if out is not None:
            o.fill(0.0)                 # (empty rows; a memset is cheaper than the rows' own loop)
        _csr_matvec1(*geo.nonempty_rows, geo.indices, geo.data, x, o)
        return o.reshape(geo.grid.shape)
    o = np.zeros((nrows, x.shape[1]), np.float32) if out is None else out.reshape(nrows, x.shape[1])
    if out is not None:
        o.fill(0.0)
    _csr_matvec(*geo.nonempty_rows, geo.indices, geo.data, x, o)
    return o.reshape(*geo.grid.shape, x.shape[1])
