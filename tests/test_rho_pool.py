"""ρ̂ pooled over the views (polycam.rho_pool): empirical-Bayes shrinkage per direction."""

import numpy as np
import pytest

from polycam.rho_pool import pool_over_views
from tolerances import RHO_POOL_GAIN_MAX, RHO_POOL_KEEP_REL, RHO_POOL_VAR_CORRELATED_REL, RHO_POOL_VAR_REL

SHAPE = (2, 7, 7, 24, 24)        # faces, views (y, x), directions (v, u)


def _field(rng, across_views: float = 0.0):
    """True ρ (SHAPE): smooth over the directions, the same for every view, plus
    ``across_views`` x a random offset per view at the directions u >= 12 (views that see
    different depths there, as at a silhouette)."""
    F, ny, nx, Nv, Nu = SHAPE
    base = 8.0 + np.sin(np.arange(Nu) / 4.0)[None, None, None, None, :] + np.cos(np.arange(Nv) / 5.0)[None, None, None, :, None]
    rho = np.broadcast_to(base, SHAPE).copy()
    rho[..., 12:] += across_views * rng.normal(0, 1, (F, ny, nx, 1, 1))
    return rho


def test_noise_is_pooled_away_where_the_views_see_one_depth():
    """Independent noise of 1.5x ρ per ray (the 8 m / 32 grey-level case) around a ρ shared by
    the views: the pooled ρ̃ is as good as the views' mean (its error ~ 1 / √49 of the
    noise), and the variance it reports matches its actual error."""
    rng = np.random.default_rng(3)
    true = _field(rng)
    sd = 12.0 * (1.0 + 0.5 * rng.random(SHAPE))                # var differs per ray (texture)
    noisy = true + rng.normal(0, 1, SHAPE) * sd
    noisy[:, 0, 3, 5] = np.nan                                  # rays without ρ̂ stay without
    out = pool_over_views(noisy, sd * sd)
    err = out.rho - true
    assert np.isnan(out.rho[:, 0, 3, 5]).all() and np.isnan(out.var[:, 0, 3, 5]).all()
    ok = np.isfinite(err)
    raw = np.sqrt(np.mean((noisy - true)[ok] ** 2))
    pooled = np.sqrt(np.mean(err[ok] ** 2))
    assert pooled < raw / 4.0                                   # measured: raw / 5.1 (ideal: / 7)
    assert np.nanmedian(out.gain) < RHO_POOL_GAIN_MAX
    assert abs(np.mean(out.var[ok]) / np.mean(err[ok] ** 2) - 1.0) < RHO_POOL_VAR_REL
    assert abs(out.q * 49 - 1.0) < 0.5                          # independent views: var ρ̄ = mean var / n


def test_a_depth_that_differs_across_the_views_is_kept():
    """Where the views see different depths (offsets 20x the noise), ρ̂ stays (g ≈ 1); where
    they see one depth the noise is pooled away as before."""
    rng = np.random.default_rng(4)
    true = _field(rng, across_views=3.0)
    noisy = true + rng.normal(0, 0.15, SHAPE)
    out = pool_over_views(noisy, np.full(SHAPE, 0.15 ** 2))
    kept = out.rho[..., 12:] - noisy[..., 12:]
    assert np.sqrt(np.mean(kept ** 2)) < RHO_POOL_KEEP_REL * 0.15
    assert np.nanmin(out.gain[..., 12:]) > 0.9
    one = out.rho[..., :12] - true[..., :12]
    assert np.sqrt(np.mean(one ** 2)) < 0.15 / 4.0


def test_correlated_noise_across_neighbouring_views_is_measured_not_assumed():
    """Noise shared by neighbouring views (a 3 x 3 box across the views; the solver's window
    and filters correlate neighbouring views too) leaves the views' mean noisier than
    mean var / n: the factor q, measured from two halves of the views, sees it (7x the
    independent value here), the pooled ρ̃ still gains, and the variance it reports is of the
    right size (measured 0.68x: the halves still share a little noise and the count scaling
    is only right for independent views, rho_pool's docstring)."""
    rng = np.random.default_rng(5)
    true = _field(rng)
    w = rng.normal(0, 1, (SHAPE[0], SHAPE[1] + 2, SHAPE[2] + 2) + SHAPE[3:])
    n = sum(w[:, dy:dy + SHAPE[1], dx:dx + SHAPE[2]] for dy in range(3) for dx in range(3)) / 3.0
    noisy = true + 4.0 * n
    out = pool_over_views(noisy, np.full(SHAPE, 16.0))
    err = out.rho - true
    assert out.q * 49 > 3.0                                     # measured 5.4 (the truth: 7.0)
    assert abs(np.mean(out.var) / np.mean(err ** 2) - 1.0) < RHO_POOL_VAR_CORRELATED_REL
    assert np.sqrt(np.mean(err ** 2)) < 4.0 / 2.0               # measured 4 / 2.4


def test_too_few_rays_or_views_keep_their_rho():
    """A direction with fewer than 4 rays, or fewer than 3 columns of views (no two halves
    apart to measure the mean's noise), keeps ρ̂ unchanged (g = 1)."""
    rng = np.random.default_rng(6)
    rho = rng.normal(8, 2, SHAPE)
    rho[:, :, 3:] = np.nan                                       # columns 0, 1, 2 only
    rho[:, 2:, :, 0, 0] = np.nan                                 # 4 rays at direction (0, 0)
    rho[:, 1:, :, 0, 1] = np.nan                                 # 2 rays at (0, 1)
    out = pool_over_views(rho, np.full(SHAPE, 4.0))
    assert np.array_equal(out.rho[:, :, :, 0, 1], rho[:, :, :, 0, 1].astype(np.float32), equal_nan=True)
    assert not np.allclose(out.rho[:, :2, :2, 0, 0], rho[:, :2, :2, 0, 0])
    one = rho[:, :, :2]
    same = pool_over_views(one, np.full(one.shape, 4.0))
    assert np.isnan(same.q) and np.array_equal(same.rho, one.astype(np.float32), equal_nan=True)
    with pytest.raises(ValueError, match="same 5 dims"):
        pool_over_views(rho, np.ones(SHAPE[1:]))
