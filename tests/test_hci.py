"""HCI light-field reader (polycam.hci) and the one-view shift on the real antinous scene."""

from __future__ import annotations

import dataclasses
import struct

import cv2
import numpy as np
import pytest

from polycam.errors import FormatError
from polycam.hci import HCI_VIEWS, disparity_to_depth, hci_view_name, load_hci_lightfield, read_pfm
from polycam.lightfield import Axis
from polycam.motion import estimate_motion

from conftest import shared_data
from tolerances import HCI_SHIFT_R_MAX_RAD, HCI_SHIFT_T_ABS

W, H = 8, 6


def _view_value(row: int, col: int) -> int:
    return 10 * row + col + 5


def _write_folder(path, width=W, height=H):
    """81 RGB views whose grey level encodes (row, col), plus a horizontal ramp in the left half."""
    path.mkdir(exist_ok=True)
    for r in range(HCI_VIEWS):
        for c in range(HCI_VIEWS):
            img = np.full((height, width, 3), _view_value(r, c), np.uint8)
            img[:, : width // 2] += np.arange(width // 2, dtype=np.uint8)[None, :, None]
            assert cv2.imwrite(str(path / hci_view_name(r, c)), img)
    return path


def _pfm_bytes(a: np.ndarray, little: bool = True, kind: bytes = b"Pf") -> bytes:
    h, w = a.shape[:2]
    rows = np.ascontiguousarray(a[::-1], dtype="<f4" if little else ">f4")
    return kind + b"\n" + f"{w} {h}\n".encode() + (b"-1.0\n" if little else b"1.0\n") + rows.tobytes()


def test_reader_layout_and_grid(tmp_path):
    folder = _write_folder(tmp_path / "scene")
    L, grid = load_hci_lightfield(folder, f=100.0)
    assert L.shape == (1, 9, 9, H, W) and L.dtype == np.float32
    assert grid.shape == L.shape
    ramp = np.r_[np.arange(W // 2), np.zeros(W - W // 2)]
    for r, c in ((0, 0), (0, 8), (3, 5), (8, 0), (8, 8)):
        expect = (_view_value(r, c) + ramp) / 255.0
        np.testing.assert_allclose(L[0, r, c], np.broadcast_to(expect, (H, W)), atol=1e-7)
    assert grid.x == Axis(-4.0, 4.0, 9) and grid.y == Axis(-4.0, 4.0, 9)
    assert grid.u == Axis(-3.5, 3.5, W) and grid.v == Axis(-2.5, 2.5, H)
    face = grid.faces[0]
    assert face.name == "+z" and face.f == 100.0 and face.z_pi == 0.0
    np.testing.assert_array_equal(face.R_rig_face, np.eye(3))


def test_reader_downsample_block_means(tmp_path):
    folder = _write_folder(tmp_path / "scene")
    L1, _ = load_hci_lightfield(folder)
    L2, grid = load_hci_lightfield(folder, downsample=2)
    assert L2.shape == (1, 9, 9, H // 2, W // 2)
    expect = L1.reshape(1, 9, 9, H // 2, 2, W // 2, 2).mean(axis=(4, 6))
    np.testing.assert_allclose(L2, expect, atol=1e-7)
    # block centres in full-resolution pixels, step 2
    assert grid.u == Axis(-3.0, 3.0, W // 2) and grid.v == Axis(-2.0, 2.0, H // 2)


def test_pfm_round_trip(tmp_path):
    a = np.arange(12, dtype=np.float32).reshape(3, 4) * 0.5 - 2.0
    for little in (True, False):
        p = tmp_path / f"d{little}.pfm"
        p.write_bytes(_pfm_bytes(a, little))
        np.testing.assert_array_equal(read_pfm(p), a)
    c = np.arange(24, dtype=np.float32).reshape(2, 4, 3)
    p = tmp_path / "c.pfm"
    p.write_bytes(_pfm_bytes(c, kind=b"PF"))
    np.testing.assert_array_equal(read_pfm(p), c)


def test_disparity_to_depth():
    Z = disparity_to_depth(np.array([2.0, -0.5, 0.0]), f=100.0)
    np.testing.assert_array_equal(Z, [50.0, -200.0, np.inf])


@pytest.mark.parametrize("problem", ["missing", "garbage", "size"])
def test_reader_bad_views(tmp_path, problem):
    folder = _write_folder(tmp_path / "scene")
    bad = folder / hci_view_name(4, 4)
    if problem == "missing":
        bad.unlink()
    elif problem == "garbage":
        bad.write_bytes(b"not a png at all")
    else:
        assert cv2.imwrite(str(bad), np.zeros((H + 2, W, 3), np.uint8))
    with pytest.raises(FormatError) as e:
        load_hci_lightfield(folder)
    msg = str(e.value)
    assert "input_Cam040.png" in msg and "\n" not in msg


def test_reader_missing_folder(tmp_path):
    with pytest.raises(FormatError, match="not a directory"):
        load_hci_lightfield(tmp_path / "nope")


@pytest.mark.parametrize("content", [b"P6\n4 3\n255\n", b"Pf\n4 x\n-1\n", b"Pf\n4 3\n0\n",
                                     b"Pf\n4 3\n-1\n" + b"\0" * 20, b""])
def test_pfm_bad_files(tmp_path, content):
    p = tmp_path / "bad.pfm"
    p.write_bytes(content)
    with pytest.raises(FormatError) as e:
        read_pfm(p)
    assert "bad.pfm" in str(e.value) and "\n" not in str(e.value)
    with pytest.raises(FormatError, match="missing"):
        read_pfm(tmp_path / "absent.pfm")


def test_real_one_view_shift_along_x():
    """Columns 1..8 are columns 0..7 of the rig moved by one view spacing along +x."""
    folder = shared_data("hci-antinous")
    L, grid = load_hci_lightfield(folder, downsample=8)
    g8 = dataclasses.replace(grid, x=Axis(-3.5, 3.5, 8))
    res = estimate_motion(L[:, :, 0:8], L[:, :, 1:9], g8)
    assert res.ok, res.reason
    assert np.linalg.norm(res.t - [1.0, 0.0, 0.0]) < HCI_SHIFT_T_ABS
    assert np.linalg.norm(res.r) < HCI_SHIFT_R_MAX_RAD
