"""polycam.filter_response: the derivative filters' gain, and a linear array's ρ̂ corrected for the
view filter's share of it (docs/motion.md, "Linear arrays")."""

from __future__ import annotations

import numpy as np
import pytest

import polycam.motion as pm
from polycam.derivatives import FILTERS, plenoptic_derivatives
from polycam.eq5 import _rho_store, _scaled_views, depth_rho, rho_values
from polycam.filter_response import derivative_gain, divide_rho_by_gain, linear_rho_gain, window_rms_frequency
from polycam.lightfield import Axis, LightFieldGrid
from polycam.motion_options import MotionOptions

from tolerances import FILTER_GAIN_ATOL, LINEAR_RHO_FS3_BIAS_MIN, LINEAR_RHO_GAIN_ATOL, LINEAR_RHO_INT16_RTOL

SOLVER_FILTERS = {"x": "fs3", "y": "fs3", "u": "fs5", "v": "fs5"}


def test_derivative_gain_closed_forms():
    """R(ω) = Σ d_k sin kω / (ω Σ p_k cos kω): 1 at ω = 0; central differences sin ω / ω; fs3
    overshoots (sin ω over ω times its prefilter's response); fs5 within 0.7 % up to 1 rad per sample."""
    w = np.array([0.0, 0.3, 1.0, 2.0])
    np.testing.assert_allclose(derivative_gain(FILTERS["central"], w), [1.0, *(np.sin(w[1:]) / w[1:])],
                               atol=FILTER_GAIN_ATOL)
    p = FILTERS["fs3"].prefilter
    fs3 = np.sin(w[1:]) / (w[1:] * (p[1] + 2 * p[0] * np.cos(w[1:])))
    np.testing.assert_allclose(derivative_gain(FILTERS["fs3"], w), [1.0, *fs3], atol=FILTER_GAIN_ATOL)
    assert derivative_gain(FILTERS["fs3"], np.array(1.0)) == pytest.approx(1.067, abs=1e-3)
    assert np.all(np.abs(derivative_gain(FILTERS["fs5"], np.linspace(0, 1, 11)) - 1) < 0.007)


def _row(views: int = 9, directions: int = 48, spacing: float = 0.015, f: float = 60.0,
         column: bool = False) -> LightFieldGrid:
    """A linear array on one face: ``views`` viewpoints along x (along y for a column)."""
    half = spacing * (views - 1) / 2
    du = 2 * f / directions
    uv = Axis(-f + du / 2, f - du / 2, directions)
    one, many = Axis(0.0, 0.0, 1), Axis(-half, half, views)
    return LightFieldGrid.cube(["+z"], f=f, z_pi=half, x=one if column else many, y=many if column else one,
                               u=uv, v=uv)


def _sine_plane(grid: LightFieldGrid, Z: float, omega: float, column: bool) -> np.ndarray:
    """(1, Ny, Nx, Nv, Nu): a plane Z [m] in front of the face plane with one sinusoid of ``omega``
    rad per sample along u (along v for a column), constant along the other direction: view to
    view it moves by k = (f / Z) step_x / step_u samples (paper Eq. 6)."""
    f = grid.faces[0].f
    y, x, v, u = np.meshgrid(grid.y.values, grid.x.values, grid.v.values, grid.u.values, indexing="ij")
    s = (y + Z * v / f) if column else (x + Z * u / f)
    step = grid.v.step if column else grid.u.step
    a = omega * f / (Z * step)                            # rad per metre on the plane
    return (0.5 + 0.3 * np.sin(a * s + 0.4))[None].astype(np.float32)


def _box(shape: tuple, column: bool) -> np.ndarray:
    """ρ̂'s box (8,) on a linear array: the views fs3 leaves valid, the directions fs5 leaves."""
    F, Ny, Nx, Nv, Nu = shape
    return np.array([1, Ny - 1, 0, 1, 2, Nv - 2, 2, Nu - 2] if column else [0, 1, 1, Nx - 1, 2, Nv - 2, 2, Nu - 2],
                    np.int64)


def _kernel_rho(L: np.ndarray, grid: LightFieldGrid, column: bool) -> np.ndarray:
    """The solver's ρ̂ of a linear array (polycam.eq5.depth_rho, noise-free), every view."""
    D = plenoptic_derivatives(L, L, grid, filters=SOLVER_FILTERS)
    box = _box(L.shape, column)
    q, dsc = _scaled_views([D.Lx, D.Ly, D.Lu, D.Lv, D.Lt], box)
    out = np.full(L.shape, np.nan, np.float32)
    depth_rho(q, np.ones(L.shape, np.float32), box, np.array([1e-4, 1e-4, 0.0, 0.0]), out, dsc=dsc,
              linear="x" if column else "y")
    return out


@pytest.mark.parametrize("column", [False, True], ids=["row", "column"])
def test_linear_rho_gain_removes_the_view_filters_share(column):
    """A sinusoid of 1 rad per sample along u seen 0.72 samples apart from view to view: fs3 across
    the views reads L_x, so ρ̂, high by R_fs3(0.72) = 3.4 % (over fs5's own 0.6 % along u); divided by
    the gain ρ̂ keeps only fs5's share, 1 / R_fs5(1)."""
    grid = _row(column=column)
    Z, omega = 0.5, 1.0
    rho = grid.faces[0].f / Z
    steps = (grid.y.step, grid.v.step) if column else (grid.x.step, grid.u.step)
    k = rho * steps[0] / steps[1]
    assert k == pytest.approx(0.72, abs=0.01)
    L = _sine_plane(grid, Z, omega, column)
    est = _kernel_rho(L, grid, column)
    has = np.isfinite(est)
    assert has.sum() > 1000
    ratio = np.median(est[has]) / rho
    fs3, fs5 = (float(derivative_gain(FILTERS[n], np.array(w))) for n, w in (("fs3", k * omega), ("fs5", omega)))
    assert ratio - 1 > LINEAR_RHO_FS3_BIAS_MIN and ratio == pytest.approx(fs3 / fs5, abs=LINEAR_RHO_GAIN_ATOL)
    b = _box(L.shape, column)
    inside = np.zeros(L.shape, bool)
    inside[:, b[0]:b[1], b[2]:b[3], b[4]:b[5], b[6]:b[7]] = True
    view = "y" if column else "x"
    omega = window_rms_frequency(L, inside, np.array([0, 0, *L.shape[1:3]]), L.shape[1:3],
                                 {a: FILTERS[n] for a, n in SOLVER_FILTERS.items()}, view)
    assert np.nanmedian(omega[has]) == pytest.approx(1.0, abs=0.01)      # ω R_fs5(ω) = 0.994
    gain = linear_rho_gain(est, omega, steps, FILTERS["fs3"])
    assert gain.shape == est.shape and np.all(gain[~has] == 1.0)
    assert np.median(est[has] / gain[has]) / rho == pytest.approx(1.0 / fs5, abs=LINEAR_RHO_GAIN_ATOL)
    # the solver's form: its int16 ρ̂ divided in place, each view re-quantised
    q, sc = np.empty(est.shape, np.int16), np.empty(est.shape[:3], np.float32)
    _rho_store(est, q, sc, b)
    divide_rho_by_gain(q, sc, omega, steps, FILTERS["fs3"])
    np.testing.assert_allclose(rho_values(q, sc)[has], (est / gain)[has], rtol=LINEAR_RHO_INT16_RTOL)
    assert np.isnan(rho_values(q, sc)[~has]).all()


def test_solver_divides_a_linear_arrays_rho_by_the_gain(monkeypatch):
    """The solver's ρ̂ on a linear array (recorded after _Solver._depth_rho) is the kernel's divided
    by the gain: on the sinusoid above it reads within fs5's share of ρ, where without the gain
    (``MotionOptions.linear_gain`` False) it reads fs3's 3.4 % high."""
    grid = _row()
    L = _sine_plane(grid, 0.5, 1.0, False)
    seen = {}
    orig = pm._Solver._depth_rho

    def record(self, *a, **k):
        out = orig(self, *a, **k)
        if self.level == 0:
            seen["rho"] = rho_values(self.rho, self.rho_sc)
        return out

    monkeypatch.setattr(pm._Solver, "_depth_rho", record)
    rho = grid.faces[0].f / 0.5
    fs5 = float(derivative_gain(FILTERS["fs5"], np.array(1.0)))
    pm.estimate_motion(L, L, grid)
    with_gain = np.nanmedian(seen["rho"]) / rho
    pm.estimate_motion(L, L, grid, options=MotionOptions(linear_gain=False))
    without = np.nanmedian(seen["rho"]) / rho
    assert with_gain == pytest.approx(1.0 / fs5, abs=LINEAR_RHO_GAIN_ATOL)
    assert without - 1 > LINEAR_RHO_FS3_BIAS_MIN
