"""Camera models drawn from a board calibration's own uncertainty (calib.draws) and the
calibration's share of the motion covariance (polycam.calib_spread; `--calib-draws` end to end is
in tests/test_run.py)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from polycam.errors import InputError

from test_calib import _exact_problem
from tolerances import CALIB_DRAWS_FACTOR_REL, CALIB_UNCERTAINTY_DRAWS, CALIB_UNCERTAINTY_RATIO

NOISE_PX = 0.3


def _calibrate(rig, board, true, poses, seed: int):
    from calib import calibrate_board
    from calib.synthetic import synthetic_observations

    obs = synthetic_observations(true, board, poses, noise_px=NOISE_PX, rng=np.random.default_rng(seed))
    return calibrate_board(obs, rig, lensmodel="opencv4", valid_region=False, board_warp=False,
                           outlier_rejection=False)


def test_calibration_covariance_predicts_the_scatter_of_repeated_calibrations(tmp_path):
    """The joint covariance read from the models: its pose blocks are extrinsics_uncertainty's, its
    noise the solve's RMS, and its lens-parameter block predicts how the focal lengths and centres
    of calibrations of the same board poses scatter over noise draws."""
    from calib import extrinsics_uncertainty
    from calib.draws import calibration_covariance

    rig, board, true, poses = _exact_problem(tmp_path, "pinhole")
    cams = list(true)
    errors, predicted = [], []
    for seed in range(CALIB_UNCERTAINTY_DRAWS):
        cal = _calibrate(rig, board, true, poses, seed)
        cc = calibration_covariance(cal.models)
        assert cc.cameras == tuple(cal.models) and cc.dim == 3 * 8 + 2 * 6      # OPENCV4: 8 lens parameters
        assert cc.extrinsics[0] is None and all(cc.extrinsics[1:])
        assert 0.8 * NOISE_PX < cc.noise_px < 1.05 * NOISE_PX
        if seed == 0:
            sigma = extrinsics_uncertainty(cal.optimization_inputs, cc.noise_px)
            for k in range(1, len(cams)):
                b = cc.covariance[cc.extrinsics[k], cc.extrinsics[k]]
                np.testing.assert_allclose([math.sqrt(np.trace(b[:3, :3])), math.sqrt(np.trace(b[3:, 3:]))],
                                           sigma[k], rtol=1e-9)
        for k, c in enumerate(cams):
            p = cal.models[c].intrinsics()[1]
            p_true = true[c].intrinsics()[1]
            errors.append(p[:4] - p_true[:4])                                   # fx, fy, cx, cy [px]
            predicted.append(np.sqrt(np.diag(cc.covariance)[cc.intrinsics[k]][:4]))
    errors, predicted = np.array(errors), np.array(predicted)
    for axis in range(4):
        ratio = math.sqrt(np.mean(errors[:, axis] ** 2)) / math.sqrt(np.mean(predicted[:, axis] ** 2))
        assert 1 / CALIB_UNCERTAINTY_RATIO <= ratio <= CALIB_UNCERTAINTY_RATIO, (axis, ratio)


def test_drawn_models_move_the_solved_parameters_by_the_draw(tmp_path):
    """A draw moves each camera's lens parameters and its pose relative to the solve's reference
    camera by exactly its share of δ = L z (L Lᵀ the covariance); z = 0 gives the models back; the
    reference camera keeps its rig-frame pose."""
    import mrcal

    from calib.draws import calibration_covariance, covariance_factor, drawn_models

    rig, board, true, poses = _exact_problem(tmp_path, "pinhole")
    cal = _calibrate(rig, board, true, poses, 0)
    models = cal.models
    cc = calibration_covariance(models)
    L = covariance_factor(cc)
    s = np.sqrt(np.diag(cc.covariance))                     # compared as correlations (mixed units)
    np.testing.assert_allclose((L @ L.T) / np.outer(s, s), cc.covariance / np.outer(s, s), rtol=0,
                               atol=CALIB_DRAWS_FACTOR_REL)
    same = drawn_models(models, cc, np.zeros(cc.dim))
    for c in models:
        np.testing.assert_allclose(same[c].intrinsics()[1], models[c].intrinsics()[1], rtol=0, atol=1e-12)
        np.testing.assert_allclose(same[c].rt_cam_ref(), models[c].rt_cam_ref(), rtol=0, atol=1e-12)
    z = np.random.default_rng(5).standard_normal(cc.dim)
    for sign in (1.0, -1.0):
        d = L @ (sign * z)
        drawn = drawn_models(models, cc, sign * z, L)
        ref = [c for k, c in enumerate(cc.cameras) if cc.extrinsics[k] is None][0]
        np.testing.assert_allclose(drawn[ref].rt_cam_ref(), models[ref].rt_cam_ref(), rtol=0, atol=1e-12)
        for k, c in enumerate(cc.cameras):
            assert drawn[c].optimization_inputs() is None
            np.testing.assert_allclose(drawn[c].intrinsics()[1] - models[c].intrinsics()[1], d[cc.intrinsics[k]],
                                       rtol=1e-9, atol=1e-12)
            if cc.extrinsics[k] is not None:
                # the drawn pose relative to the reference camera (whose rig pose did not move)
                rt_rel = mrcal.compose_rt(drawn[c].rt_cam_ref(), mrcal.invert_rt(drawn[ref].rt_cam_ref()))
                np.testing.assert_allclose(rt_rel, cc.rt_cam_ref[k] + d[cc.extrinsics[k]], rtol=0, atol=1e-10)
    with pytest.raises(ValueError, match="z must be"):
        drawn_models(models, cc, np.zeros(cc.dim + 1))


def test_models_without_a_calibration_covariance_are_refused(tmp_path):
    """Nominal models (no optimisation record) and models of two different solves: an InputError
    naming the camera."""
    from calib.draws import calibration_covariance

    rig, board, true, poses = _exact_problem(tmp_path, "pinhole")
    with pytest.raises(InputError, match="no optimisation record"):
        calibration_covariance(true)
    a = _calibrate(rig, board, true, poses, 0).models
    b = _calibrate(rig, board, true, poses, 1).models
    cams = list(a)
    mixed = {cams[0]: a[cams[0]], **{c: b[c] for c in cams[1:]}}
    with pytest.raises(InputError, match=f"camera {cams[1]}: its model is not from the same board calibration"):
        calibration_covariance(mixed)
    with pytest.raises(InputError, match="no camera models"):
        calibration_covariance({})


def _pair(index: int):
    from polycam.motion import PairResult

    T = np.eye(4)
    T[:3, 3] = (0.01 * (index + 1), 0.0, 0.0)
    C = np.diag([1e-8] * 3 + [1e-8] * 3)
    return PairResult(index=index, T_prev_next=T, covariance=C, covariance_noise=C.copy(), covariance_iid=C.copy(),
                      sigma=1.0, condition=1.0, inlier_fraction=1.0, num_rays=100, iterations=1)


def test_antithetic_covariance_cancels_the_second_order_and_skips_failed_draws():
    """x(±δ) = J δ + Q(δ, δ): the half-differences are exactly J δ, so the covariance is
    Σ (J z)(J z)ᵀ / K whatever Q; a failed re-solve (NaN) leaves that draw out of that pair only."""
    from polycam.calib_spread import antithetic_covariance

    rng = np.random.default_rng(3)
    K, P, N = 5, 3, 4
    J = rng.standard_normal((P, 6, N))
    Q = rng.standard_normal((P, 6, N, N))
    z = rng.standard_normal((K, N))
    x = lambda d: np.einsum("pin,n->pi", J, d) + np.einsum("pimn,m,n->pi", Q, d, d)    # noqa: E731
    plus = np.stack([x(zk) for zk in z])
    minus = np.stack([x(-zk) for zk in z])
    plus[1, 2] = np.nan                                        # draw 1 failed on pair 2
    C, n = antithetic_covariance(plus, minus)
    assert C.shape == (P, 6, 6) and list(n) == [K, K, K - 1]
    for p in range(P):
        keep = [k for k in range(K) if not (p == 2 and k == 1)]
        d = np.stack([J[p] @ z[k] for k in keep])
        np.testing.assert_allclose(C[p], d.T @ d / len(keep), rtol=1e-10, atol=1e-14)
    plus[:, 0] = np.nan
    C, n = antithetic_covariance(plus, minus)
    assert n[0] == 0 and np.all(np.isnan(C[0])) and np.all(np.isfinite(C[1]))
    with pytest.raises(ValueError, match="plus and minus"):
        antithetic_covariance(plus, minus[:, :2])


def test_with_calibration_adds_the_share_to_the_covariance():
    """with_calibration: covariance + C, kept apart as covariance_calibration (calibration_std's
    source); a pair without a finite C and a failed pair's vector (NaN) are left as they were."""
    from dataclasses import replace

    from polycam.calib_spread import calibration_std, pair_vectors, with_calibration

    results = [_pair(0), _pair(1), replace(_pair(2), reason="unobservable: t_x")]
    assert np.all(np.isnan(pair_vectors(results)[2])) and pair_vectors(results)[1, 0] == pytest.approx(0.02)
    C = np.stack([np.diag([4e-8] * 6), np.full((6, 6), np.nan), np.diag([9e-8] * 6)])
    out = with_calibration(results, C)
    np.testing.assert_allclose(out[0].std, np.sqrt(5e-8))
    np.testing.assert_allclose(out[0].covariance_noise, results[0].covariance_noise)
    assert out[1] is results[1] and out[1].covariance_calibration is None
    std = calibration_std(out)
    np.testing.assert_allclose(std[0], 2e-4)
    np.testing.assert_allclose(std[2], 3e-4)
    assert np.all(np.isnan(std[1]))
    with pytest.raises(ValueError, match="C must be"):
        with_calibration(results, C[:2])


def test_calibration_line_reports_the_share_and_the_draws_that_counted():
    """The CLI's line: the calibration's std per pair and its share of the reported std (medians), how
    many draws a pair was re-solved in when some failed, and a plain line when none was."""
    from polycam.calib_draws_cli import calibration_line
    from polycam.calib_spread import with_calibration

    results = with_calibration([_pair(0), _pair(1)], np.stack([np.diag([3e-8] * 6)] * 2))
    line = calibration_line(results, 4, 3, 12.3)
    assert line.startswith("calibration: 4 draws from its uncertainty (8 re-solves, 12 s; a pair solved in only 3 of them)")
    # per axis: calibration √3e-8 = 1.732e-4 m of a total √4e-8; norm √3 · 1.732e-4 m = 0.300 mm, share √(3/4) = 87 %
    assert "its std per pair 0.300 mm" in line and "87% / 87% of the reported std" in line, line
    assert "only" not in calibration_line(results, 4, 4, 1.0)
    assert calibration_line([_pair(0)], 2, 0, 1.0) == "calibration: 2 draws, no pair re-solved (1 s)"


def test_sampling_change_is_added_as_its_outer_product():
    """sampling_change_covariance: d dᵀ of the two samplings' change, NaN where either solve failed;
    with_view_sampling adds it and keeps it as covariance_sampling (view_sampling_std reads |d| back)."""
    from polycam.calib_spread import pair_vectors, sampling_change_covariance, view_sampling_std, with_view_sampling

    results = [_pair(0), _pair(1), _pair(2)]
    nominal = pair_vectors(results)
    other = nominal.copy()
    d = np.array([3e-4, -1e-4, 0.0, 2e-5, 0.0, -4e-5])
    other[0] -= d
    other[2] = np.nan                                   # the second sampling failed on pair 2
    C = sampling_change_covariance(nominal, other)
    np.testing.assert_allclose(C[0], np.outer(d, d))
    np.testing.assert_array_equal(C[1], 0.0)
    assert np.all(np.isnan(C[2]))
    out = with_view_sampling(results, C)
    np.testing.assert_allclose(out[0].covariance, results[0].covariance + np.outer(d, d))
    assert out[2] is results[2] and out[2].covariance_sampling is None
    std = view_sampling_std(out)
    np.testing.assert_allclose(std[0], np.abs(d), atol=1e-15)
    assert np.all(np.isnan(std[2]))
    with pytest.raises(ValueError, match="nominal and other"):
        sampling_change_covariance(nominal, other[:2])


def test_sampling_line_reports_the_change_against_the_std_before():
    """The CLI's line: the change's norms per pair and their share of the std before it was added (medians),
    how many pairs moved by more than twice that std, and the pairs it could not measure."""
    from polycam.calib_spread import with_view_sampling
    from polycam.sampling_check_cli import sampling_line

    results = [_pair(0), _pair(1), _pair(2)]
    before = np.stack([r.std for r in results])          # 1e-4 per axis: norms 0.173 mm, 9.9 mdeg
    d = [np.full(6, 0.5e-4), np.full(6, 3e-4), np.full(6, np.nan)]
    line = sampling_line(with_view_sampling(results, np.stack([np.outer(x, x) for x in d])), before, 3,
                         (1, 7, 7, 30, 40), 5.2)
    assert line.startswith("second view sampling (3 views per camera spacing, 7x7 views, 5 s): the estimates moved by "
                           "0.303 mm, 17.37 mdeg per pair (median), 175% / 175% of the std before; 1 of 2 pairs by "
                           "more than twice it; 1 pair(s) not solved on it"), line
    assert "no pair solved on it" in sampling_line(results, before, 3, (1, 7, 7, 30, 40), 1.0)

