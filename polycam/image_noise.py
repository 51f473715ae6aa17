"""A camera image's sensor noise, estimated from the image alone.

The motion solver estimates the noise of the light field's samples from second differences
across the views (:func:`polycam.motion_weights.frame_noise_variance`). On a resampled camera
array that reads the scene's parallax between the cameras too, and the resampled samples carry
less noise than the cameras' pixels (push-pull averages them), so neither figure is the
cameras' sensor noise. This module estimates that from each camera image on its own.

Method (after Immerkær, *Fast noise variance estimation*, CVIU 1996, with a higher-order mask and
restricted to weakly textured blocks as Liu, Tanaka and Okutomi do for their patch-based
estimator, 2013): the image's response to the separable mask ``N = a aᵀ``, ``a = [1, −4, 6, −4, 1]``
(the fourth difference; Immerkær's is the second, [1, −2, 1]), has variance ``70² σ²`` for white
noise of std σ and removes intensity polynomials up to the third degree, so texture of low and
middle frequencies adds less than to the second difference (on the densely textured 160 x 120
images of a small test rig the noise-free floor 1.06 → 0.71 grey levels). Texture still adds, so
the response's mean square is taken over ``block`` x ``block`` blocks, and only over the
``fraction`` of blocks whose gradient (Sobel, after a Gaussian of σ = 2 pixels, which leaves little
of the noise in it) is lowest; blocks with a pixel at the image's own minimum or maximum value are
left out first (clipped, saturated or black regions carry no noise). The estimate includes
quantisation (8-bit rounding alone: 0.29 grey levels) and the weak texture left in the chosen
blocks. Measured on this project's rendered camera images (8-bit; docs/motion.md "The cameras'
sensor noise"): 0.14–0.53 grey levels without noise on 320 x 240 and 640 x 480 images, 0.71 on
160 x 120; 1.02–1.13 at 1 grey level (1.23 on 160 x 120); within 2.5 % from 2 grey levels on; on
real photos with 1 / 2 / 4 grey levels added within 5.7 / 3.2 / 2.1 % of their own estimate combined
with it (tests/test_image_noise.py).

Dims: ``image`` (H, W) or (H, W, C) in its own units (8-bit grey levels, or values in [0, 1] as
:func:`resample.resampler.normalise_image` gives them); the estimate is in the same units, the
root mean of the channels' variances. No I/O.
"""

from __future__ import annotations

import math

import numpy as np
from scipy import ndimage

__all__ = ["image_noise_sigma", "NOISE_BLOCK", "NOISE_FRACTION"]

NOISE_BLOCK = 8
"""Side [pixels] of the blocks over which the mask's response is averaged."""
NOISE_FRACTION = 0.1
"""Fraction of the unclipped blocks, those with the weakest gradient, that the estimate averages."""
_SMOOTH_SIGMA = 2.0          # [pixels] Gaussian before the gradient that ranks the blocks
_MIN_BLOCKS = 4              # the fewest blocks averaged (fewer unclipped ones: no estimate, NaN)
_MASK = np.array([1.0, -4.0, 6.0, -4.0, 1.0])   # a: the fourth difference
_MASK_ENERGY = 70.0 ** 2     # Σ N² = (Σ a²)²: the response's variance per unit noise variance


def _channel_variance(img: np.ndarray, block: int, fraction: float) -> float:
    """σ² of one (H, W) float32 channel; NaN when too few blocks."""
    H, W = img.shape
    r = len(_MASK) // 2                          # the border the mask's reflection reaches
    h, w = (H - 2 * r) // block, (W - 2 * r) // block
    if h * w == 0:
        return math.nan
    resp = ndimage.correlate1d(ndimage.correlate1d(img, _MASK, axis=0, mode="reflect"), _MASK, axis=1,
                               mode="reflect")
    smooth = ndimage.gaussian_filter(img, _SMOOTH_SIGMA, mode="reflect")
    grad = np.hypot(ndimage.sobel(smooth, axis=0, mode="reflect"), ndimage.sobel(smooth, axis=1, mode="reflect"))

    def blocks(a: np.ndarray) -> np.ndarray:     # interior (H − 2r, W − 2r) → (h, block, w, block)
        return a[r:r + h * block, r:r + w * block].reshape(h, block, w, block)

    energy = np.mean(np.square(blocks(resp)), axis=(1, 3)).ravel() / _MASK_ENERGY
    rank = np.mean(blocks(grad), axis=(1, 3)).ravel()
    px = blocks(img)
    clipped = ((px <= img.min()) | (px >= img.max())).any(axis=(1, 3)).ravel()
    energy, rank = energy[~clipped], rank[~clipped]
    if energy.size < _MIN_BLOCKS:
        return math.nan
    k = min(energy.size, max(_MIN_BLOCKS, int(fraction * energy.size)))
    chosen = np.argpartition(rank, k - 1)[:k]
    return float(np.mean(energy[chosen]))


def image_noise_sigma(image: np.ndarray, *, block: int = NOISE_BLOCK, fraction: float = NOISE_FRACTION) -> float:
    """The sensor noise's standard deviation in ``image`` (H, W) or (H, W, C), in the image's
    units (module docstring): the root mean of the channels' estimates. NaN when the image has
    fewer than ``_MIN_BLOCKS`` unclipped blocks to average (small, or clipped nearly everywhere)
    or a channel holds non-finite values.

    block: block side [pixels]; fraction: the share of the unclipped blocks, weakest gradient
    first, averaged."""
    a = np.asarray(image)
    if a.ndim == 2:
        a = a[:, :, None]
    if a.ndim != 3 or a.shape[2] < 1:
        raise ValueError(f"image_noise_sigma: an (H, W) or (H, W, C) image, got shape {np.shape(image)}")
    if not 0.0 < fraction <= 1.0 or block < 2:
        raise ValueError(f"image_noise_sigma: block {block} (>= 2), fraction {fraction} (in (0, 1])")
    variances = []
    for c in range(a.shape[2]):
        ch = np.asarray(a[:, :, c], np.float32)
        if not np.all(np.isfinite(ch)):
            return math.nan
        variances.append(_channel_variance(ch, block, fraction))
    return float(math.sqrt(np.mean(variances)))
