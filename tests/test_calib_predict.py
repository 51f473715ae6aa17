"""mrcal's predicted camera-pose uncertainty of a calibration design, before any rendering
(calib.truth_problem, calib.predicted_extrinsics_sigma), and the sparse covariance of
calib.extrinsics_uncertainty."""

from __future__ import annotations

import numpy as np

from test_calib import _exact_problem
from tolerances import CALIB_PREDICT_REL, CALIB_TRUTH_RESIDUAL_PX


def _dense_uncertainty(inputs: dict, noise_px: float) -> np.ndarray:
    """The covariance of extrinsics_uncertainty with a dense inverse (the reference)."""
    import mrcal

    _, _, J, _ = mrcal.optimizer_callback(**inputs, no_factorization=True)
    J = J.toarray()
    Jo = J[:mrcal.num_measurements_boards(**inputs)]
    inv = np.linalg.inv(J.T @ J)
    n_ext = inputs["rt_cam_ref"].shape[0]
    i0 = mrcal.state_index_extrinsics(0, **inputs)
    sl = slice(i0, i0 + 6 * n_ext)
    scale = np.ones(J.shape[1])
    mrcal.unpack_state(scale, **inputs)
    cov = noise_px**2 * (inv[sl] @ Jo.T @ Jo @ inv[:, sl]) * np.outer(scale[sl], scale[sl])
    out = np.zeros((n_ext + 1, 2))
    for k in range(n_ext):
        b = cov[6 * k:6 * k + 6, 6 * k:6 * k + 6]
        out[k + 1] = np.sqrt(np.trace(b[:3, :3])), np.sqrt(np.trace(b[3:, 3:]))
    return out


def test_truth_problem_predicts_the_solved_uncertainty(tmp_path):
    """At the truth the residuals vanish; the predicted sigmas equal the dense reference and
    match those of a real solve of noisy observations of the same poses."""
    import mrcal

    from calib import calibrate_board, extrinsics_uncertainty, predicted_extrinsics_sigma, truth_problem
    from calib.synthetic import synthetic_observations

    rig, board, true, poses = _exact_problem(tmp_path, "opencv8")
    inputs = truth_problem(true, board, poses, lensmodel="LENSMODEL_OPENCV8")
    x = mrcal.optimizer_callback(**inputs, no_factorization=True)[1]
    assert np.abs(x[:mrcal.num_measurements_boards(**inputs)]).max() <= CALIB_TRUTH_RESIDUAL_PX
    pred = predicted_extrinsics_sigma(true, board, poses, 0.2, lensmodel="LENSMODEL_OPENCV8")
    np.testing.assert_allclose(pred, _dense_uncertainty(inputs, 0.2), rtol=1e-6, atol=1e-12)
    assert pred.shape == (3, 2) and np.all(pred[0] == 0) and np.all(pred[1:] > 0)
    obs = synthetic_observations(true, board, poses, noise_px=0.2, rng=np.random.default_rng(1))
    cal = calibrate_board(obs, rig, lensmodel="opencv8", valid_region=False, outlier_rejection=False)
    solved = extrinsics_uncertainty(cal.optimization_inputs, 0.2)
    np.testing.assert_allclose(pred[1:], solved[1:], rtol=CALIB_PREDICT_REL)
