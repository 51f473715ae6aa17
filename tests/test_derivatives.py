"""Plenoptic derivatives: filter kernels, exactness on linear fields, accuracy on sinusoids,
validity masks and short axes."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.ndimage import correlate1d

from polycam.derivatives import FILTERS, correlate_axis, derivative_noise, plenoptic_derivatives
from polycam.lightfield import Axis, LightFieldGrid

from tolerances import DERIV_LINEAR_ATOL, DERIV_NOISE_VAR_REL, DERIV_SINE_REL_FS5


def grid(nx=9, ny=7, nu=20, nv=16, faces=("+z",)) -> LightFieldGrid:
    ax = lambda lo, hi, n: Axis(lo, hi, n) if n > 1 else Axis(0.0, 0.0, 1)  # noqa: E731
    return LightFieldGrid.cube(list(faces), f=60.0, z_pi=0.05, x=ax(-0.04, 0.04, nx),
                               y=ax(-0.03, 0.03, ny), u=ax(-30, 30, nu), v=ax(-20, 20, nv))


def coords(g: LightFieldGrid):
    y, x, v, u = np.meshgrid(g.y.values, g.x.values, g.v.values, g.u.values, indexing="ij")
    return x, y, u, v


@pytest.mark.parametrize("name", sorted(FILTERS))
@pytest.mark.parametrize("axis", range(5))
def test_correlate_axis_matches_scipy(rng, name, axis):
    a = rng.random((2, 9, 8, 13, 17)).astype(np.float32)
    for taps in (FILTERS[name].prefilter, FILTERS[name].derivative):
        ours = correlate_axis(a, taps, axis)
        ref = correlate1d(a, taps.astype(np.float32), axis=axis, mode="nearest")
        assert np.allclose(ours, ref, atol=1e-6)


def test_correlate_axis_short_axis(rng):
    a = rng.random((3, 2, 3)).astype(np.float32)      # shorter than the 5-tap support
    taps = FILTERS["fs5"].prefilter
    assert np.allclose(correlate_axis(a, taps, 1), correlate1d(a, taps.astype(np.float32), 1,
                                                               mode="nearest"), atol=1e-6)


def test_filter_pairs_are_normalised():
    for fp in FILTERS.values():
        k = np.arange(-fp.radius, fp.radius + 1)
        assert np.isclose(fp.prefilter.sum(), 1.0)
        assert np.isclose(np.sum(k * fp.derivative), 1.0)
        assert np.isclose(fp.derivative.sum(), 0.0)


@pytest.mark.parametrize("filters", ["central", "fs3", "fs5", {"x": "fs3", "y": "fs3"}])
def test_linear_lightfield_exact(filters):
    g = grid(faces=("+z", "-x"))
    x, y, u, v = coords(g)
    a = np.array([2.0, -3.0, 0.01, 0.02])
    L0 = (0.5 + a[0] * x + a[1] * y + a[2] * u + a[3] * v)[None].repeat(2, 0).astype(np.float32)
    L1 = L0 + np.float32(0.25)
    d = plenoptic_derivatives(L0, L1, g, filters=filters)
    m = d.valid
    for arr, want in ((d.Lx, a[0]), (d.Ly, a[1]), (d.Lu, a[2]), (d.Lv, a[3]), (d.Lt, 0.25)):
        assert arr.shape == g.shape
        assert np.max(np.abs(arr[:, m] - want)) < DERIV_LINEAR_ATOL * max(abs(want), 1.0)


def test_sinusoid_fs5_beats_central_differences():
    """L_u of sin(k u) is k cos(k u) times the prefilter's gain P(k) (L_t carries the same
    gain, so motion is unbiased): fs5 matches that to < 1% at 0.5 rad/sample."""
    g = grid(nu=64, nv=8)
    x, y, u, v = coords(g)
    w = 0.5                                            # rad per sample along u
    k = w / g.u.step
    L = np.sin(k * u)[None].astype(np.float32)
    errs = {}
    for name in ("central", "fs5"):
        p = FILTERS[name].prefilter
        r = np.arange(-(len(p) // 2), len(p) // 2 + 1)
        gain = float(np.sum(p * np.cos(w * r)))
        truth = k * np.cos(k * u) * gain
        d = plenoptic_derivatives(L, L, g, filters=name)
        m = d.valid & (np.abs(truth) > 0.5 * k * gain)
        errs[name] = np.max(np.abs(d.Lu[0][m] / truth[m] - 1))
    assert errs["fs5"] < DERIV_SINE_REL_FS5
    assert errs["fs5"] < errs["central"] / 3


def test_valid_mask_borders():
    g = grid(nx=9, ny=7, nu=20, nv=16)
    L = np.zeros(g.shape, np.float32)
    d = plenoptic_derivatives(L, L, g, filters={"x": "fs3", "y": "fs3", "u": "fs5", "v": "fs5"})
    assert d.valid.shape == (7, 9, 16, 20)
    assert d.valid.sum() == (7 - 2) * (9 - 2) * (16 - 4) * (20 - 4)
    assert not d.valid[0].any() and not d.valid[:, :, :, 1].any() and d.valid[1, 1, 2, 2]


def test_single_viewpoint_axis_is_not_differentiated(rng):
    g = grid(nx=1, ny=1)
    L0 = rng.random(g.shape).astype(np.float32)
    d = plenoptic_derivatives(L0, L0, g)
    assert d.differentiated == {"x": False, "y": False, "u": True, "v": True}
    assert not d.Lx.any() and not d.Ly.any()
    assert d.valid.shape == (1, 1, 16, 20) and d.valid.any()


def test_time_derivative_is_symmetric(rng):
    """Spatial derivatives are those of the mean frame, so swapping frames flips only L_t."""
    g = grid()
    L0 = rng.random(g.shape).astype(np.float32)
    L1 = rng.random(g.shape).astype(np.float32)
    a = plenoptic_derivatives(L0, L1, g)
    b = plenoptic_derivatives(L1, L0, g)
    for name in ("Lx", "Ly", "Lu", "Lv"):
        assert np.allclose(getattr(a, name), getattr(b, name), atol=1e-5)
    assert np.allclose(a.Lt, -b.Lt, atol=1e-6)


@pytest.mark.parametrize("axis", range(5))
def test_min_filter_axis_matches_scipy(rng, axis):
    from scipy.ndimage import minimum_filter1d

    from polycam.derivatives import min_filter_axis

    a = rng.random((2, 5, 6, 7, 9)).astype(np.float32)
    for r in (1, 2):
        assert np.array_equal(min_filter_axis(a, r, axis),
                              minimum_filter1d(a, 2 * r + 1, axis=axis, mode="nearest"))


@pytest.mark.parametrize("shape,filters", [
    ((7, 9, 16, 20), "fs5"), ((9, 9, 13, 17), {"x": "fs3", "y": "fs3"}), ((1, 1, 16, 20), "fs5"),
    ((9, 9, 3, 5), "fs5"), ((5, 5, 12, 12), "central")])
def test_fused_kernels_match_reference(rng, shape, filters):
    from polycam.derivatives import plenoptic_derivatives_reference

    ny, nx, nv, nu = shape
    g = grid(nx=nx, ny=ny, nu=nu, nv=nv, faces=("+z", "-x"))
    L0 = rng.random(g.shape).astype(np.float32)
    L1 = rng.random(g.shape).astype(np.float32)
    a = plenoptic_derivatives(L0, L1, g, filters=filters)
    b = plenoptic_derivatives_reference(L0, L1, g, filters=filters)
    for name in ("Lx", "Ly", "Lu", "Lv", "Lt"):
        ref = getattr(b, name)
        assert np.max(np.abs(getattr(a, name) - ref)) <= 1e-5 * max(1.0, np.abs(ref).max())
    assert np.array_equal(a.valid, b.valid) and a.differentiated == b.differentiated


@pytest.mark.parametrize("smoothing", [None, "uv2"])
def test_derivative_noise_matches_the_derivatives_of_noise(smoothing):
    """derivative_noise: the variance of L_x .. L_t of two frames of white noise (with an
    optional (u, v) pre-smoothing, as polycam.scales applies), per unit of the grid's steps."""
    g = LightFieldGrid.cube(["+z"], f=60.0, z_pi=0.0, x=Axis(-0.04, 0.04, 9), y=Axis(-0.04, 0.04, 9),
                            u=Axis(-31.5, 31.5, 64), v=Axis(-31.5, 31.5, 64))
    filters = {"x": "fs3", "y": "fs3", "u": "fs5", "v": "fs5"}
    rng = np.random.default_rng(11)
    sigma = 0.01
    frames = [rng.normal(0.0, sigma, g.shape).astype(np.float32) for _ in range(2)]
    taps = {}
    if smoothing:
        taps = {"u": np.array([0.25, 0.5, 0.25]), "v": np.array([0.25, 0.5, 0.25])}
        frames = [correlate_axis(correlate_axis(a, taps["u"].astype(np.float32), 4), taps["v"].astype(np.float32), 3)
                  for a in frames]
    d = plenoptic_derivatives(*frames, g, filters=filters)
    v = np.broadcast_to(d.valid, g.shape)
    measured = np.array([np.mean(getattr(d, k)[v].astype(np.float64) ** 2) for k in ("Lx", "Ly", "Lu", "Lv", "Lt")])
    predicted = derivative_noise(sigma ** 2, g, filters, taps)
    np.testing.assert_allclose(measured, predicted, rtol=DERIV_NOISE_VAR_REL)
    assert not np.any(derivative_noise(0.0, g, filters))
