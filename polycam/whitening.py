"""Generalised least squares for the motion solver: whitening of the Eq. 5 rows.

The derivative prefilters correlate sensor noise across neighbouring samples; with
:attr:`~polycam.motion_options.MotionOptions.whiten` the solver (:mod:`polycam.motion`)
re-solves at the finest level with its rows multiplied by the inverse of that noise
covariance ⊗ₐ K_a K_aᵀ (one banded Cholesky factor per axis, with a ridge
``whiten_floor``). This module holds the factors (``_whitening_factor(s)``), the banded
forward substitution along one axis (``_forward_lines``), two kernels that run over a block of
the box's v rows at a time (the weighted rows, built on the row coefficients of
:mod:`polycam.eq5` and whitened along u, y and x while one v row of every view is in cache; then
along v, with the rows before the block carried over, and the whitened tile sums, same layout as
:func:`polycam.eq5._accumulate`'s) and the whitened noise gain that scales the expected noise
energy. The passes commute (⊗ₐ C_a⁻¹), so their order is the one that keeps each pass's inner
loop on contiguous floats; the blocks bound the rows held at once (``_V_BLOCK``). Measurements:
docs/motion_log.md, "Noise", and docs/motion.md, "Speed and memory".
"""

from __future__ import annotations

import functools
import math

import numba
import numpy as np

from .derivatives import FilterPair
from .eq5 import _NACC, _eq5_coefficients, _unit_scales, _view_origin, _weight_unit

__all__: list[str] = []


@functools.lru_cache(maxsize=32)
def _whitening_factor(taps: tuple, n: int, floor: float = 0.0) -> np.ndarray:
    """(n, n) lower Cholesky factor C of K Kᵀ + floor I, K the (n, n + 2r) Toeplitz correlation
    matrix of the prefilter ``taps`` (2r+1,) restricted to n interior outputs: K Kᵀ is the noise
    covariance (per unit variance) that the prefilter gives n neighbouring samples along one
    axis; ``floor`` caps the gain of C⁻¹ at the frequencies the prefilter removes. K Kᵀ is
    banded Toeplitz (the taps' autocorrelation), so C is banded with bandwidth 2r."""
    t = np.asarray(taps, float)
    r = len(t) // 2
    ac = np.array([float(np.dot(t[:len(t) - d], t[d:])) for d in range(2 * r + 1)])
    KK = np.zeros((n, n))
    for d in range(min(2 * r + 1, n)):
        idx = np.arange(n - d)
        KK[idx, idx + d] = ac[d]
        KK[idx + d, idx] = ac[d]
    return np.linalg.cholesky(KK + floor * np.eye(n))


@numba.njit(cache=True, inline="always")
def _forward_lines(X, C, bw):
    """X (n, B) ← C⁻¹ X along axis 0 in place (float64 arithmetic, stored as X's dtype; X's trailing
    axis contiguous: the inner loop vectorises); C (n, n) lower triangular with bandwidth bw
    (banded forward substitution; bw < 0: the axis is not whitened)."""
    if bw < 0:
        return
    n, B = X.shape
    for j in range(n):
        inv = 1.0 / C[j, j]
        for k in range(max(0, j - bw), j):
            c = C[j, k]
            for b in range(B):
                X[j, b] -= c * X[k, b]
        for b in range(B):
            X[j, b] *= inv


@numba.njit(parallel=True, cache=True)
def _weighted_rows_block(Lx, Ly, Lu, Lv, Lt, dsc, base, fc, xs, ys, us, vs, z_pi, f, p, kind, inv_sc, box, vo,
                         Cy, bwy, Cx, bwx, Cu, bwu, q0, q1, off, R, Wb):
    """Rows sqrt(w) (c, b) of face ``fc``'s rays in the box rows q0 <= qv < q1 of ``box`` (box
    indices along v) into the slabs R[off + qv − q0] (each (n_u, n_y, n_x, 7)), whitened along u,
    y and x (C_u⁻¹, C_y⁻¹, C_x⁻¹: factors ``Cu``, ``Cy``, ``Cx`` of bandwidths ``bwu``, ``bwy``,
    ``bwx``; < 0: not whitened), and their weights w into Wb[off + qv − q0] (n_u, n_y, n_x): c the
    Eq. 5 coefficients (face frame), b = −L_t, w = base weight × the IRLS weight (``kind`` 1
    Tukey, 2 Huber, 0 none) of the residual at p (face frame) normalised by 1 / inv_sc, as
    :func:`~polycam.eq5._accumulate_view` weights them. Lx .. Lt (scales ``dsc``), base: view
    origin ``vo`` (:mod:`polycam.eq5`). Parallel over the rows; in a slab's layout the three
    passes' inner loops run over contiguous floats."""
    ny = box[1] - box[0]
    nx = box[3] - box[2]
    nu = box[7] - box[6]
    inv_f = 1.0 / f
    for qv in numba.prange(q0, q1):
        T = R[off + qv - q0]
        Wt = Wb[off + qv - q0]
        jv = box[4] + qv
        v = vs[jv]
        for jj in range(ny):
            j = box[0] + jj
            y = ys[j]
            ja = j - vo[0]
            for ii in range(nx):
                i = box[2] + ii
                x = xs[i]
                ia = i - vo[1]
                sc = dsc[fc, ja, ia]
                for qu in range(nu):
                    iu = box[6] + qu
                    wi = np.float64(base[fc, ja, ia, jv, iu]) * np.float64(_weight_unit(base))
                    g0 = np.float64(np.float32(Lx[fc, ja, ia, jv, iu]) * sc[0])
                    g1 = np.float64(np.float32(Ly[fc, ja, ia, jv, iu]) * sc[1])
                    g2 = np.float64(np.float32(Lu[fc, ja, ia, jv, iu]) * sc[2])
                    g3 = np.float64(np.float32(Lv[fc, ja, ia, jv, iu]) * sc[3])
                    b = -np.float64(np.float32(Lt[fc, ja, ia, jv, iu]) * sc[4])
                    c2, c3, c4, c5 = _eq5_coefficients(g0, g1, g2, g3, x, y, us[iu], v, z_pi, f, inv_f)
                    if kind != 0 and wi > 0.0:
                        r = g0 * p[0] + g1 * p[1] + c2 * p[2] + c3 * p[3] + c4 * p[4] + c5 * p[5] - b
                        zz = abs(r) * inv_sc
                        if kind == 1:
                            wi *= (1.0 - zz * zz) ** 2 if zz < 1.0 else 0.0
                        else:
                            wi *= 1.0 if zz <= 1.0 else 1.0 / zz
                    if not wi > 0.0:
                        wi = 0.0
                    Wt[qu, jj, ii] = wi
                    sw = math.sqrt(wi)
                    z = T[qu, jj, ii]
                    z[0] = sw * g0
                    z[1] = sw * g1
                    z[2] = sw * c2
                    z[3] = sw * c3
                    z[4] = sw * c4
                    z[5] = sw * c5
                    z[6] = sw * b
        _forward_lines(T.reshape(nu, ny * nx * 7), Cu, bwu)
        for qu in range(nu):
            _forward_lines(T[qu].reshape(ny, nx * 7), Cy, bwy)
            for jj in range(ny):
                _forward_lines(T[qu, jj], Cx, bwx)


@numba.njit(parallel=True, cache=True)
def _whiten_v_sums_block(R, Wb, Cv, bwv, q0, q1, off, v0, u0, tile, acc):
    """The slabs R[off + qv − q0] (n_u, n_y, n_x, 7) of box rows q0 <= qv < q1 ← C_v⁻¹ along v in
    place (row qv of the factor ``Cv``; the bandwidth ``bwv`` rows before it are the slabs before
    it in R, already whitened; < 0: not whitened), and their sums added to acc (n_tv, n_tu, 29)
    per (u, v) tile (of the face's full (v, u) index, ``tile`` samples; the box starts at (v0,
    u0)): the 21 entries of Σ z_c z_cᵀ, Σ z_c z_b (6), Σ z_b², and Σ w of the weights Wb.
    Parallel over the tile columns (each task owns its column of acc)."""
    nu = R.shape[1]
    m_ray = R.shape[2] * R.shape[3]
    n_tu = acc.shape[1]
    for tu in numba.prange(n_tu):
        lo = max(tu * tile - u0, 0)
        hi = min((tu + 1) * tile - u0, nu)
        if lo >= hi:
            continue
        for qv in range(q0, q1):
            s = off + qv - q0
            X = R[s].reshape(nu, m_ray * 7)
            if bwv >= 0:
                inv = 1.0 / Cv[qv, qv]
                for k in range(max(0, qv - bwv), qv):
                    c = Cv[qv, k]
                    Xk = R[s - (qv - k)].reshape(nu, m_ray * 7)
                    for qu in range(lo, hi):
                        for e in range(m_ray * 7):
                            X[qu, e] -= c * Xk[qu, e]
                for qu in range(lo, hi):
                    for e in range(m_ray * 7):
                        X[qu, e] *= inv
            a = acc[(v0 + qv) // tile, tu]
            Z = R[s]
            W = Wb[s]
            for qu in range(lo, hi):
                for jj in range(Z.shape[1]):
                    for ii in range(Z.shape[2]):
                        z = Z[qu, jj, ii]
                        k = 0
                        for m in range(6):
                            zm = np.float64(z[m])
                            for r in range(m, 6):
                                a[k] += zm * z[r]
                                k += 1
                        for m in range(6):
                            a[21 + m] += np.float64(z[m]) * z[6]
                        a[27] += np.float64(z[6]) * z[6]
                        a[28] += W[qu, jj, ii]


_V_BLOCK = 16
"""Box rows (along v) whose rows :func:`_whitened_sums` holds at once (plus the v factor's
bandwidth before them): the rows of a whole face would be ~7 floats per ray."""

_NOT_WHITENED = (np.zeros((1, 1)), -1)
"""(factor, bandwidth) of an axis that is not whitened (the kernels skip a negative bandwidth)."""


def _whitening_factors(filters: dict, radius: dict, box: np.ndarray, floor: float = 0.0) -> list:
    """Per box axis (y, x, v, u): (C_a, bandwidth) of the axis' prefilter on the box's length,
    or :data:`_NOT_WHITENED` where the axis is not filtered (radius 0) or the box is empty. An
    axis with one sample in the box is whitened by the scalar factor sqrt(Σ taps²), as
    :func:`_whitened_noise_gain` assumes (the solver's expected noise energy)."""
    out = []
    for ax, name in enumerate(("y", "x", "v", "u")):
        n = int(box[2 * ax + 1] - box[2 * ax])
        if radius[name] == 0 or n <= 0:
            out.append(_NOT_WHITENED)
            continue
        taps = tuple(float(t) for t in filters[name].prefilter)
        out.append((_whitening_factor(taps, n, floor), 2 * radius[name]))
    return out


def _whitened_sums(der: tuple, base: np.ndarray, vals: list, zs: np.ndarray, fs: np.ndarray,
                   P: np.ndarray, kind: int, inv_sc: float, box: np.ndarray, factors: list,
                   tile: int, vo: np.ndarray | None = None, dsc: np.ndarray | None = None) -> np.ndarray:
    """Tile sums (F, 1, n_tiles, 29) as :func:`~polycam.eq5._accumulate` returns them, but of the *whitened*
    rows: per face, z = (⊗ₐ C_a)⁻¹ sqrt(w) (c, b) over the box (C_a C_aᵀ = K_a K_aᵀ, the noise
    covariance of the prefiltered temporal difference up to 2σ²), so that Σ z_c z_cᵀ =
    Aᵀ W^½ Σ⁻¹ W^½ A: generalised least squares. der: (Lx, Ly, Lu, Lv, Lt) (F, Ny, Nx, Nv, Nu);
    base: base weights of the same dims (float32, or int16 units: :mod:`polycam.eq5`); P (F, 6): p
    in each face's frame (IRLS residuals); ``factors``: per box axis, :func:`_whitening_factors`;
    ``vo``: the arrays' view origin (:mod:`polycam.eq5`; None: they hold every view); ``dsc``:
    the derivatives' scales when they are int16 scaled views (:mod:`polycam.eq5`; None: float32)."""
    F, Nv, Nu = base.shape[0], base.shape[3], base.shape[4]
    vo = _view_origin(*base.shape[1:3]) if vo is None else vo
    dsc = _unit_scales(base.shape) if dsc is None else dsc
    n = [int(box[2 * a + 1] - box[2 * a]) for a in range(4)]
    nt = (-(-Nv // tile), -(-Nu // tile))
    acc = np.zeros((F, 1, nt[0] * nt[1], _NACC))
    if min(n) <= 0:
        return acc
    ny, nx, nv, nu = n
    (Cy, by), (Cx, bx), (Cv, bv), (Cu, bu) = factors
    off = max(bv, 0)                                  # slabs kept from the previous block for the v pass
    block = max(_V_BLOCK, off)
    R = np.empty((off + block, nu, ny, nx, 7), np.float32)     # the rows in float32 (half the memory);
    Wb = np.empty((off + block, nu, ny, nx), np.float32)       # arithmetic and sums in float64
    xs, ys, us, vs = vals
    for k in range(F):
        a = np.zeros(nt + (_NACC,))
        p = np.ascontiguousarray(P[k], dtype=np.float64)
        for q0 in range(0, nv, block):
            q1 = min(q0 + block, nv)
            _weighted_rows_block(*der, dsc, base, k, xs, ys, us, vs, float(zs[k]), float(fs[k]), p, kind,
                                 float(inv_sc), box, vo, Cy, by, Cx, bx, Cu, bu, q0, q1, off, R, Wb)
            _whiten_v_sums_block(R, Wb, Cv, bv, q0, q1, off, int(box[4]), int(box[6]), int(tile), a)
            if off and q1 < nv:                        # the last rows whitened: the next block's history
                R[:off] = R[block:block + off]
        acc[k, 0] = a.reshape(-1, _NACC)
    return acc


def _whitened_noise_gain(fp: FilterPair, n: int, floor: float = 0.0, derivative: bool = True) -> float:
    """Mean over n interior samples of diag(C⁻¹ D Dᵀ C⁻ᵀ), D, C the derivative's (or with
    ``derivative=False`` the prefilter's) Toeplitz matrix and the whitening factor
    (:func:`_whitening_factor`) of the pair ``fp``: the whitened variance of the filtered unit
    white noise along that axis (per sample step; Σ d² unwhitened; 1 for the prefilter
    without floor)."""
    taps = tuple(float(t) for t in fp.prefilter)
    return _noise_gain(taps, tuple(float(t) for t in fp.derivative) if derivative else taps, n, floor)


@functools.lru_cache(maxsize=64)
def _noise_gain(prefilter: tuple, taps: tuple, n: int, floor: float) -> float:
    """:func:`_whitened_noise_gain` of the filter ``taps`` (2r+1,) whitened by ``prefilter``'s
    factor (cached: the solver asks for the same few axes at every whitened solve)."""
    r = len(prefilter) // 2
    C = _whitening_factor(prefilter, n, floor)
    D = np.zeros((n, n + 2 * r))
    for i in range(n):
        D[i, i:i + 2 * r + 1] = taps
    X = np.linalg.solve(C, D)
    return float(np.sum(X * X) / n)
