"""Reader for the HCI 4D Light Field Benchmark's 9 x 9-view scenes (real test data).

The HCI benchmark (Honauer, Johannsen, Kondermann, Goldluecke, ACCV 2016; licence
CC BY-NC-SA 4.0, never copied into this repository) stores a scene as 81 RGB PNG
views ``input_Cam000.png`` … ``input_Cam080.png``, row-major over a 9 x 9 camera
grid, plus ground-truth disparity of the centre view as PFM files
(``gt_disp_lowres.pfm``). Its ``parameters.cfg`` (baseline, focal length, focus
distance) is not needed: everything here is in **grid units**.

Grid units and the light-field grid
-----------------------------------
One face ``+z`` (rig frame = face frame: x right, y down, z forward), ``z_pi = 0``:

- ``x = column − 4``, ``y = row − 4`` of the camera grid (view spacing 1; Cam index
  ``i`` is row ``i // 9``, column ``i % 9``);
- ``u = p − (W − 1)/2``, ``v = q − (H − 1)/2`` for pixel column ``p`` and row ``q``
  (pixel spacing 1; with ``downsample = k`` each sample is the mean of a k x k pixel
  block and sits at the block's centre, so the step is k, still in full-resolution
  pixels).

The data then satisfy exactly what a translated rig gives: the views with column
indices 1..8 are the views 0..7 of the same rig moved by one view spacing along +x
(``L1(x, y, u, v) = L0(x + 1, y, u, v)``), likewise rows along +y.

The HCI cameras are focused (shifted sensors): a point on the zero-disparity
plane has the same pixel in every view. Read as a two-plane light field with
parallel directions ``(u, v, f)``, that plane lies at infinity and a scene point
whose image moves by ``d`` pixels per view step along +x (and +y) — the
benchmark's disparity, measured here: ``p(column c) = p(centre) − d (c − 4)``,
positive d for points nearer than the focus plane — lies at the depth

    Z = f / d   [view spacings, from the camera plane along +z]

(``u = f (X − x)/Z`` so ``∂u/∂x = −f/Z = −d``). Points beyond the focus plane have
``d < 0``, i.e. a negative depth in this sheared reading; translations are
unaffected (they depend on the positional derivatives only), rotations would be
those of the sheared light field. ``f`` only scales depth and the rotation terms;
the default is the benchmark's nominal camera (100 mm lens on a 35 mm sensor
imaged on 512 pixels: 1462.86 px), which this copy of the data cannot confirm.

Images become grey with OpenCV's BT.601 weights and are scaled to [0, 1].
"""

from __future__ import annotations

import logging
import os
from pathlib import Path

import numpy as np

from .errors import FormatError
from .lightfield import Axis, LightFieldGrid

__all__ = [
    "HCI_VIEWS",
    "HCI_NOMINAL_F",
    "hci_view_name",
    "load_hci_lightfield",
    "read_pfm",
    "disparity_to_depth",
]

log = logging.getLogger(__name__)

HCI_VIEWS = 9
"""Views per row and per column of an HCI scene."""

HCI_NOMINAL_F = 100.0 / 35.0 * 512.0
"""Nominal focal length [px] of the HCI benchmark cameras (100 mm lens, 35 mm sensor, 512 px)."""


def hci_view_name(row: int, col: int) -> str:
    """File name of the view at camera-grid ``row``, ``col`` (row-major ``input_CamNNN.png``)."""
    return f"input_Cam{row * HCI_VIEWS + col:03d}.png"


def _read_view(path: Path, downsample: int) -> np.ndarray:
    """(H // k, W // k) float32 grey image in [0, 1], k x k block means."""
    import cv2

    if not path.is_file():
        raise FormatError(path, "missing view image")
    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise FormatError(path, "not a readable PNG image")
    if img.dtype == np.uint8:
        scale = 255.0
    elif img.dtype == np.uint16:
        scale = 65535.0
    else:
        raise FormatError(path, f"unsupported sample type {img.dtype} (expected 8 or 16 bit)")
    if img.ndim == 3 and img.shape[2] == 4:
        img = img[..., :3]
    if img.ndim == 3 and img.shape[2] == 3:
        img = cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)
    elif img.ndim != 2:
        raise FormatError(path, f"unsupported image layout {img.shape}")
    g = img.astype(np.float32) / np.float32(scale)
    k = int(downsample)
    if k > 1:
        H, W = (g.shape[0] // k) * k, (g.shape[1] // k) * k
        if H == 0 or W == 0:
            raise FormatError(path, f"image {g.shape[1]}x{g.shape[0]} is smaller than downsample {k}")
        g = g[:H, :W].reshape(H // k, k, W // k, k).mean(axis=(1, 3), dtype=np.float32)
    return g


def _pixel_axis(n_full: int, k: int) -> Axis:
    """Centred pixel coordinates of the n_full // k block centres (step k, full-resolution pixels)."""
    n = n_full // k
    c = (n_full - 1) / 2.0
    first = (k - 1) / 2.0 - c
    return Axis(first, first + (n - 1) * k, n)


def load_hci_lightfield(folder: str | os.PathLike, *, downsample: int = 1,
                        f: float = HCI_NOMINAL_F) -> tuple[np.ndarray, LightFieldGrid]:
    """An HCI scene as a grey light field on a one-face grid in grid units (module docstring).

    folder: directory with ``input_Cam000.png`` … ``input_Cam080.png``.
    downsample: k >= 1; each direction sample is the mean of a k x k pixel block.
    f: plane separation in full-resolution pixels (scales depth and rotation only).
    Returns ``L`` (1, 9, 9, Nv, Nu) float32 in [0, 1] (``L[face, row, col, v, u]``) and its
    :class:`LightFieldGrid`. Raises :class:`FormatError` for a missing folder or a missing,
    unreadable or differently sized view.
    """
    folder = Path(folder)
    k = int(downsample)
    if k < 1:
        raise ValueError(f"downsample must be >= 1, got {downsample}")
    if not f > 0:
        raise ValueError(f"f must be > 0, got {f}")
    if not folder.is_dir():
        raise FormatError(folder, "not a directory with HCI views (input_Cam000.png ...)")
    L = None
    full = None
    for row in range(HCI_VIEWS):
        for col in range(HCI_VIEWS):
            path = folder / hci_view_name(row, col)
            g = _read_view(path, k)
            if L is None:
                import cv2

                h, w = cv2.imread(str(path), cv2.IMREAD_UNCHANGED).shape[:2]
                full = (h, w)
                L = np.empty((1, HCI_VIEWS, HCI_VIEWS) + g.shape, np.float32)
            elif g.shape != L.shape[3:]:
                raise FormatError(path, f"image size differs from {hci_view_name(0, 0)} "
                                  f"({g.shape[1] * k}x{g.shape[0] * k} vs {L.shape[4] * k}x{L.shape[3] * k})")
            L[0, row, col] = g
    half = (HCI_VIEWS - 1) / 2.0
    views = Axis(-half, half, HCI_VIEWS)
    grid = LightFieldGrid.cube(["+z"], f=float(f), z_pi=0.0, x=views, y=views,
                               u=_pixel_axis(full[1], k), v=_pixel_axis(full[0], k))
    log.info("HCI light field %s: %s, downsample %d", folder, L.shape, k)
    return L, grid


def _pfm_tokens(data: bytes, n: int) -> tuple[list[bytes], int]:
    """The first n whitespace-separated header tokens and the offset just after the
    single whitespace byte that ends the last one."""
    tokens: list[bytes] = []
    i = 0
    while len(tokens) < n:
        while i < len(data) and data[i:i + 1].isspace():
            i += 1
        j = i
        while j < len(data) and not data[j:j + 1].isspace():
            j += 1
        if j == i or j >= len(data):
            break
        tokens.append(data[i:j])
        i = j
    return tokens, i + 1


def read_pfm(path: str | os.PathLike) -> np.ndarray:
    """A PFM image (portable float map) as float32, rows top to bottom.

    Returns (H, W) for ``Pf`` (grey) or (H, W, 3) for ``PF`` (colour). The header's
    scale sets the byte order (negative: little endian). Raises :class:`FormatError`
    for a missing file, a bad header or a short data block.
    """
    path = Path(path)
    if not path.is_file():
        raise FormatError(path, "missing PFM file")
    data = path.read_bytes()
    tokens, off = _pfm_tokens(data, 4)
    if len(tokens) < 4 or tokens[0] not in (b"Pf", b"PF"):
        raise FormatError(path, "not a PFM file (expected a 'Pf' or 'PF' header)")
    try:
        w, h, scale = int(tokens[1]), int(tokens[2]), float(tokens[3])
    except ValueError:
        raise FormatError(path, "bad PFM header (width, height and scale must be numbers)") from None
    if w <= 0 or h <= 0 or scale == 0 or not np.isfinite(scale):
        raise FormatError(path, f"bad PFM header: size {w}x{h}, scale {scale}")
    ch = 3 if tokens[0] == b"PF" else 1
    n = w * h * ch
    if len(data) - off < 4 * n:
        raise FormatError(path, f"PFM data too short: {len(data) - off} bytes for {w}x{h}x{ch} floats")
    a = np.frombuffer(data, dtype="<f4" if scale < 0 else ">f4", count=n, offset=off)
    a = a.reshape((h, w, ch) if ch == 3 else (h, w))[::-1]
    return np.ascontiguousarray(a, dtype=np.float32)


def disparity_to_depth(disparity: np.ndarray, f: float = HCI_NOMINAL_F) -> np.ndarray:
    """Depth ``Z = f / d`` [view spacings] of the sheared two-plane reading (module
    docstring) from HCI disparity ``d`` [full-resolution px per view]; inf where d = 0."""
    d = np.asarray(disparity, dtype=np.float64)
    with np.errstate(divide="ignore"):
        return np.where(d != 0, f / np.where(d != 0, d, 1.0), np.inf)
