"""The model-validity weight of the motion solver (polycam.motion_weights.model_error_weights)."""

from __future__ import annotations

import numpy as np
import pytest

from polycam.motion_weights import _box_sums, model_error_weights
from tolerances import MOTION_MODEL_WEIGHT_ATOL


def _clipped_window_sums(a: np.ndarray, half: tuple) -> np.ndarray:
    """Brute force: the sums of a (F, ny, nx, nv, nu) over ±half (y, x, v, u), clipped at the ends."""
    pad = [(0, 0)] + [(h, h) for h in half]
    p = np.pad(a.astype(np.float64), pad)
    out = np.zeros(a.shape)
    for dy in range(2 * half[0] + 1):
        for dx in range(2 * half[1] + 1):
            for dv in range(2 * half[2] + 1):
                for du in range(2 * half[3] + 1):
                    out += p[:, dy:dy + a.shape[1], dx:dx + a.shape[2], dv:dv + a.shape[3], du:du + a.shape[4]]
    return out


def test_box_sums_are_the_clipped_window_sums():
    rng = np.random.default_rng(0)
    a = rng.random((2, 5, 4, 7, 9)).astype(np.float32)
    ref = _clipped_window_sums(a, (1, 1, 2, 2))
    _box_sums(a, (1, 1, 2, 2))
    np.testing.assert_allclose(a, ref, rtol=1e-6)


@pytest.mark.parametrize("gain", [1.0, 8.0])
def test_model_error_weights_find_model_error_and_leave_noise_alone(gain):
    """Residuals of pure noise (scale s) keep their weights; a patch with a model error of
    3 s on every ray gets s² / (s² + κ (1 + 9 − 1.5) s²) (κ: ``gain``); zero weights and rays
    outside the box stay as they were."""
    rng = np.random.default_rng(1)
    F, ny, nx, nv, nu, m = 1, 5, 5, 24, 24, 2                 # box: all views, (u, v) inset by m
    s = 0.01
    r = rng.normal(0.0, s, (F, ny, nx, nv, nu))
    r[:, :, :, 6:18, 6:18] += 3 * s
    res = np.abs(r).astype(np.float32)                          # the solver passes |r|
    base = np.full((F, ny, nx, nv + 2 * m, nu + 2 * m), 16384, np.int16)
    base[0, 2, 2, m + 20, m + 3] = 0
    w = (base[:, :, :, m:-m, m:-m] > 0).astype(np.float32)
    box = np.array([0, ny, 0, nx, m, m + nv, m, m + nu])
    before = base.copy()
    model_error_weights(res, w, base, box, s, gain=gain)
    ratio = base[:, :, :, m:-m, m:-m] / 16384.0
    clean = np.ones((nv, nu), bool)
    clean[3:21, 3:21] = False                                   # the patch and its window's reach
    assert np.mean(ratio[..., clean] == 1.0) > 0.9
    assert np.mean(ratio[..., clean]) > 0.97
    core = ratio[:, 1:-1, 1:-1, 8:16, 8:16]                     # whole windows inside the patch
    np.testing.assert_allclose(np.median(core), 1 / (1 + gain * (10 - 1.5)), atol=MOTION_MODEL_WEIGHT_ATOL)
    assert base[0, 2, 2, m + 20, m + 3] == 0
    np.testing.assert_array_equal(base[:, :, :, :m], before[:, :, :, :m])
    np.testing.assert_array_equal(base[..., -m:], before[..., -m:])


def test_model_error_weights_need_a_scale():
    res = np.ones((1, 3, 3, 8, 8), np.float32)
    w = np.ones_like(res)
    base = np.full((1, 3, 3, 8, 8), 100, np.int16)
    model_error_weights(res, w, base, np.array([0, 3, 0, 3, 0, 8, 0, 8]), 0.0)
    assert np.all(base == 100)
