"""A camera image's sensor noise estimated from the image alone (polycam.image_noise): the
project's rendered camera images with known noise, clipped regions, colour, a real photo with
noise added, a session's cameras and resampled samples (resample.stream.SessionLightField), and JPEG
images, which give no estimate (MJPG cameras are left out)."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from polycam.image_noise import image_noise_sigma
from polycam.rig import load_rig
from conftest import REPO, shared_data
from tolerances import IMAGE_NOISE_RTOL, IMAGE_NOISE_LOW_RTOL, IMAGE_NOISE_REAL_RTOL


@pytest.fixture(scope="module")
def radiance() -> dict[str, np.ndarray]:
    """Noise-free radiance in [0, 1] of one camera of two example rigs, rendered by the project's
    renderer: the 5 x 5 array's 320 x 240 camera in the room, and a 320 x 240 camera of the nested
    cube, whose images hold clipped black regions."""
    from polycam.cameras import nominal_cameramodel
    from polycam.synth import CameraArrayRenderer, scene_for_rig, trajectory_for_rig

    out = {}
    for name in ("mock5x5", "cube6x3x3"):
        rig = load_rig(REPO / "rigs" / f"{name}.toml")
        cam = rig.cameras[0]
        sub = dataclasses.replace(rig, cameras=(cam,))
        renderer = CameraArrayRenderer(sub, {cam.id: nominal_cameramodel(cam)}, scene_for_rig(sub, seed=1), 2)
        T = trajectory_for_rig(sub, 2, seed=1).T_world_rig[1]
        out[name] = renderer.render(T)[cam.id]
    return out


def _grey(rad: np.ndarray, sigma_grey: float, seed: int) -> np.ndarray:
    """8-bit image of ``rad`` with Gaussian noise of ``sigma_grey`` grey levels, rounded."""
    from polycam.synth import quantize

    return quantize(rad, 8, sigma_grey / 255.0, np.random.default_rng(seed))


@pytest.mark.parametrize("name", ["mock5x5", "cube6x3x3"])
@pytest.mark.parametrize("sigma", [1.0, 2.0, 4.0])
def test_noise_of_rendered_camera_images(radiance, name, sigma):
    est = image_noise_sigma(_grey(radiance[name], sigma, seed=int(10 * sigma)))
    truth = math.hypot(sigma, 1.0 / math.sqrt(12.0))       # the noise and the rounding
    rtol = IMAGE_NOISE_LOW_RTOL if sigma < 2 else IMAGE_NOISE_RTOL
    assert abs(est / truth - 1.0) < rtol, (name, sigma, est)


def test_clipped_regions_are_left_out(radiance):
    # the cube's camera sees black (clipped at 0) around its scene: flat, so first in line by the
    # gradient, but without noise; left out, the estimate holds at 4 grey levels
    img = _grey(radiance["cube6x3x3"], 4.0, seed=3)
    assert np.mean(img == 0) > 0.02
    assert abs(image_noise_sigma(img) / math.hypot(4.0, 12 ** -0.5) - 1.0) < IMAGE_NOISE_RTOL
    # half the frame saturated: the same noise from the other half
    sat = img.copy()
    sat[:, : sat.shape[1] // 2] = 255
    assert abs(image_noise_sigma(sat) / image_noise_sigma(img[:, img.shape[1] // 2:]) - 1.0) < IMAGE_NOISE_RTOL


def test_units_colour_and_bad_input(radiance):
    img = _grey(radiance["mock5x5"], 2.0, seed=1)
    assert image_noise_sigma(img.astype(np.float32) / 255.0) == pytest.approx(image_noise_sigma(img) / 255.0, rel=1e-6)
    # colour: the root mean of the channels' variances
    rgb = np.stack([_grey(radiance["mock5x5"], s, seed=k) for k, s in enumerate((1.0, 2.0, 4.0))], axis=2)
    per = [image_noise_sigma(rgb[:, :, c]) for c in range(3)]
    assert image_noise_sigma(rgb) == pytest.approx(math.sqrt(np.mean(np.square(per))), rel=1e-9)
    assert math.isnan(image_noise_sigma(img[:12, :12]))            # too few blocks
    nan = img.astype(np.float32)
    nan[5, 5] = np.nan
    assert math.isnan(image_noise_sigma(nan))
    with pytest.raises(ValueError, match="image_noise_sigma"):
        image_noise_sigma(np.zeros(5))


def test_noise_added_to_real_photos():
    # real photos carry their own noise σ0: with σ added the estimate is √(σ0² + σ²)
    cv2 = pytest.importorskip("cv2")
    kettle = shared_data("lumigraph-kettle")
    for path in sorted((kettle / "images").iterdir())[:2]:
        img = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
        s0 = image_noise_sigma(img)
        for add in (2.0, 4.0):
            noisy = np.clip(np.rint(img + np.random.default_rng(7).normal(0.0, add, img.shape)), 0, 255)
            est = image_noise_sigma(noisy.astype(np.uint8))
            assert abs(est / math.hypot(s0, add) - 1.0) < IMAGE_NOISE_REAL_RTOL, (path.name, add, s0, est)


def test_session_cameras_and_resampled_samples(tmp_path):
    # a row of three 160 x 120 cameras with 2 grey levels of noise, and the same session without
    # noise: their resampled frames differ by the resampled noise, whose RMS the session's
    # sample_noise_sigma predicts from the cameras' estimate and one probe
    from polycam.synth import synth_session
    from resample.stream import NOISE_CAMERAS_PER_FRAME, SessionLightField
    from conftest import mock_grid_rig_text

    (tmp_path / "rig.toml").write_text(mock_grid_rig_text("noise1x3", 160, 120, rows=1, cols=3))
    rig = load_rig(tmp_path / "rig.toml")
    sigma = 2.0 / 255.0
    noisy = SessionLightField(synth_session(rig, tmp_path / "noisy", frames=2, seed=1, noise=sigma))
    clean = SessionLightField(synth_session(rig, tmp_path / "clean", frames=2, seed=1, noise=0.0), grid=noisy.grid)
    assert math.isnan(noisy.camera_noise_sigma) and math.isnan(noisy.sample_noise_sigma())   # nothing read yet
    L, W = noisy.frame(0).copy(), noisy.weights(0).copy()
    noisy.frame(1)
    assert len(noisy.camera_noise) == 2 * min(NOISE_CAMERAS_PER_FRAME, 3)
    truth = math.hypot(sigma, 1.0 / (255.0 * math.sqrt(12.0)))
    assert abs(noisy.camera_noise_sigma / truth - 1.0) < IMAGE_NOISE_LOW_RTOL
    has = W > 0
    measured = float(np.sqrt(np.mean(np.square(L[has] - clean.frame(0)[has], dtype=np.float64))))
    predicted = noisy.sample_noise_sigma()
    assert 0.1 * truth < measured < 0.9 * truth            # push-pull averages pixels
    assert abs(predicted / measured - 1.0) < IMAGE_NOISE_LOW_RTOL, (predicted * 255, measured * 255)
    assert noisy.frames_resampled == 2                       # the probe used the last frame, not counted
    quiet = SessionLightField(tmp_path / "noisy", grid=noisy.grid, camera_noise=False)   # (the calibration draws')
    quiet.frame(0)
    assert not quiet.camera_noise and math.isnan(quiet.sample_noise_sigma())


def test_jpeg_images_do_not_carry_their_noise(radiance):
    # why MJPG cameras are left out (resample.resampler.COMPRESSED_FORMATS): JPEG quantises away the
    # noise of the flat blocks the estimate reads, so the same image reads a fraction of its noise
    # (and at high quality and much noise, JPEG's own block edges push it above)
    cv2 = pytest.importorskip("cv2")

    def reads(sigma: float, quality: int) -> float:
        img = _grey(radiance["mock5x5"], sigma, seed=int(10 * sigma))
        ok, data = cv2.imencode(".jpg", img, [cv2.IMWRITE_JPEG_QUALITY, quality])
        return image_noise_sigma(cv2.imdecode(data, cv2.IMREAD_UNCHANGED)) / math.hypot(sigma, 12 ** -0.5)

    assert all(reads(s, q) < 0.7 for q in (90, 80) for s in (1.0, 2.0, 4.0))     # measured 0.22-0.65
    assert reads(1.0, 95) < 0.6 and reads(4.0, 95) > 1.05                        # 0.41, 1.13


def test_mjpg_cameras_give_no_estimate(tmp_path):
    # a session whose rig records MJPG: no camera's image is estimated, polycam resample records no
    # figure (and counts the cameras it left out), and polycam info / motion say why instead
    import contextlib
    import io

    from polycam.cli import main
    from polycam.lfstore import open_lightfield
    from polycam.session import open_session
    from polycam.synth import synth_session
    from resample.pipeline import resample_session
    from resample.stream import SessionLightField
    from conftest import mock_grid_rig_text

    text = mock_grid_rig_text("mjpg1x3", 160, 120, rows=1, cols=3).replace('pixel_format = "GREY"',
                                                                          'pixel_format = "MJPG"')
    (tmp_path / "rig.toml").write_text(text)
    session = synth_session(load_rig(tmp_path / "rig.toml"), tmp_path / "s", frames=2, seed=1, noise=2.0 / 255.0)
    img = open_session(session).read_frame(0)["cam00"]     # JPEG round trip at the rig's mjpg_quality (90)
    assert img.ndim == 3 and image_noise_sigma(img) < 0.6 * 2.0
    lf = SessionLightField(session)
    lf.frame(0), lf.frame(1)
    assert lf.compressed_cameras == 3 and not lf.camera_noise and lf.camera_noise_images == 0
    summary = resample_session(session, tmp_path / "lf.zarr", scheduler="sync")
    assert math.isnan(summary.camera_noise_sigma) and summary.compressed_cameras == 3
    assert open_lightfield(tmp_path / "lf.zarr").camera_noise_images == 0
    for argv in (["info", str(session)], ["motion", str(session), "--out", str(tmp_path / "t.tum")]):
        out = io.StringIO()
        with contextlib.redirect_stdout(out):
            assert main(argv) == 0
        text = out.getvalue()
        assert "sensor noise is not estimated: they record MJPG" in text, (argv[0], text)
        assert "grey levels in the cameras' images" not in text and "in the first frame's images" not in text
    # a mixed rig (the OAK-D Lite with its colour camera on MJPG): the grey cameras' figure, and the line
    # names the one left out
    oak = (REPO / "rigs" / "oak_d_lite.toml").read_text()
    assert oak.count('pixel_format = "RGB"') == 1
    (tmp_path / "oak.toml").write_text(oak.replace('pixel_format = "RGB"', 'pixel_format = "MJPG"'))
    mixed = synth_session(load_rig(tmp_path / "oak.toml"), tmp_path / "m", frames=2, seed=1)
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        assert main(["info", str(mixed)]) == 0
    line = next(l for l in out.getvalue().splitlines() if "sensor noise" in l)
    assert "median over 2 cameras; 1 MJPG camera left out" in line, line
    lf = SessionLightField(mixed)
    lf.frame(0), lf.frame(1)
    assert lf.compressed_cameras == 1 and {c for _, c in lf.camera_noise} <= {"left", "right"}
