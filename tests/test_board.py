"""Calibration boards: BOARD.toml validation, OpenCV-identical corners, rendered-image mapping."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from polycam.board import Board, load_board
from polycam.errors import FormatError
from tolerances import BOARD_CORNER_PX, BOARD_POINTS_ATOL

CHARUCO = """
[board]
type = "charuco"
squares = [5, 7]
square_length = 0.04
marker_length = 0.03
dictionary = "DICT_5X5_100"
"""


def _board_file(tmp_path, text):
    p = tmp_path / "board.toml"
    p.write_text(text)
    return p


def _map(H, XY):
    """Board points (N, 2) [m] → pixels (N, 2) through H_image_board (3, 3)."""
    return XY @ H[:2, :2].T + H[:2, 2]


def test_sample_board_file(repo):
    b = load_board(repo / "rigs" / "boards" / "charuco_5x7.toml")
    assert b == Board("charuco", (5, 7), 0.04, 0.03, "DICT_5X5_100", b.path)
    assert b.num_corners == 24
    assert b.size_m == pytest.approx((0.2, 0.28))


@pytest.mark.parametrize("squares", [(5, 7), (6, 4), (4, 4), (7, 5)])
def test_object_points_match_opencv(squares):
    b = Board("charuco", squares, 0.035, 0.026, "DICT_4X4_50")
    cv_board = b.cv2_board()
    assert isinstance(cv_board, cv2.aruco.CharucoBoard)
    assert not cv_board.getLegacyPattern()
    P = b.object_points()
    assert P.shape == (b.num_corners, 3) and P.dtype == np.float64
    np.testing.assert_allclose(P, cv_board.getChessboardCorners(), atol=BOARD_POINTS_ATOL, rtol=0)


def test_chessboard_points_and_no_cv2_board():
    b = Board("chessboard", (4, 3), 0.1)
    assert b.cv2_board() is None
    np.testing.assert_allclose(b.object_points(), [[0.1, 0.1, 0], [0.2, 0.1, 0], [0.3, 0.1, 0],
                                                   [0.1, 0.2, 0], [0.2, 0.2, 0], [0.3, 0.2, 0]])


@pytest.mark.parametrize("squares", [(5, 7), (6, 4)])
def test_render_mapping_detected_charuco(squares):
    """ChArUco corners found in the rendered image sit where H_image_board puts them."""
    b = Board("charuco", squares, 0.04, 0.03, "DICT_5X5_100")
    image, H = b.render(100, 0.5)
    m = 50
    assert image.dtype == np.uint8 and image.shape == (squares[1] * 100 + 2 * m, squares[0] * 100 + 2 * m)
    np.testing.assert_allclose(H, [[2500, 0, m - 0.5], [0, 2500, m - 0.5], [0, 0, 1]])
    corners, ids, _, _ = cv2.aruco.CharucoDetector(b.cv2_board()).detectBoard(image)
    assert ids is not None and ids.size == b.num_corners
    q = _map(H, b.object_points()[ids.ravel(), :2])
    err = np.linalg.norm(corners.reshape(-1, 2) - q, axis=1)
    assert err.max() < BOARD_CORNER_PX, err.max()


def test_render_square_colours_and_margin():
    """Square (i, j) is black when i + j is even; its centre maps to a pixel of that colour."""
    for kind, extra in (("charuco", dict(marker_length=0.02, dictionary="DICT_4X4_50")), ("chessboard", {})):
        b = Board(kind, (4, 3), 0.04, **extra)
        image, H = b.render(20, 1.0)
        assert image.shape == (3 * 20 + 40, 4 * 20 + 40)
        assert np.all(image[:20] == 255) and np.all(image[:, -20:] == 255)  # white margins
        # a point 1 mm inside each corner of every square (away from the markers)
        for j in range(3):
            for i in range(4):
                for dx, dy in ((0.001, 0.001), (0.039, 0.039)):
                    u, v = _map(H, np.array([[i * 0.04 + dx, j * 0.04 + dy]]))[0]
                    want = 0 if (i + j) % 2 == 0 else 255
                    assert image[int(round(v)), int(round(u))] == want, (kind, i, j)
        # square edges fall on pixel edges: (X, Y) = (0.04, 0.02) is at u = 20 + 20 - 0.5
        u, v = _map(H, np.array([[0.04, 0.02]]))[0]
        assert (u, v) == (39.5, 29.5)
        assert image[30, 39] == 0 and image[30, 40] == 255


def test_render_chessboard_detected():
    b = Board("chessboard", (6, 5), 0.03)
    image, H = b.render(40, 1.0)
    found, corners = cv2.findChessboardCorners(image, (5, 4))
    assert found
    criteria = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 50, 1e-4)
    corners = cv2.cornerSubPix(image, corners, (5, 5), (-1, -1), criteria)
    q = _map(H, b.object_points()[:, :2])
    d = np.linalg.norm(corners.reshape(-1, 1, 2) - q[None], axis=2)
    assert d.min(axis=1).max() < BOARD_CORNER_PX  # every detected corner is a predicted one


def test_render_arguments():
    b = Board("chessboard", (3, 3), 0.1)
    with pytest.raises(ValueError, match="pixels_per_square"):
        b.render(10.5, 0.5)
    with pytest.raises(ValueError, match="margin_squares"):
        b.render(10, -1)


@pytest.mark.parametrize("edit, substrings", [
    (("square_length = 0.04", "square_length = 0.04\nthickness = 3"), ["[board].thickness", "unknown key"]),
    (("[board]\n", "[extra]\nx = 1\n[board]\n"), ["extra", "unknown key"]),
    (('type = "charuco"', 'type = "circles"'), ["[board].type", "charuco, chessboard"]),
    (("squares = [5, 7]", "squares = [5]"), ["[board].squares", "list of 2 integers"]),
    (("squares = [5, 7]", "squares = [5.5, 7]"), ["[board].squares", "integers"]),
    (("squares = [5, 7]", "squares = [1, 7]"), ["[board].squares", "at least 2"]),
    (("square_length = 0.04", 'square_length = "4cm"'), ["[board].square_length", "number"]),
    (("square_length = 0.04", "square_length = -0.04"), ["[board].square_length", "> 0"]),
    (("marker_length = 0.03", "marker_length = 0.04"), ["[board].marker_length", "smaller than square_length"]),
    (("marker_length = 0.03\n", ""), ["[board].marker_length", "missing"]),
    (('dictionary = "DICT_5X5_100"', 'dictionary = "DICT_5X5"'), ["[board].dictionary", "unknown"]),
    (('dictionary = "DICT_5X5_100"', 'dictionary = "getPredefinedDictionary"'), ["[board].dictionary"]),
    (("squares = [5, 7]", "squares = [15, 15]"), ["[board].dictionary", "has 100 markers", "needs 112"]),
])
def test_board_errors(tmp_path, edit, substrings):
    old, new = edit
    assert old in CHARUCO
    p = _board_file(tmp_path, CHARUCO.replace(old, new))
    with pytest.raises(FormatError) as e:
        load_board(p)
    msg = str(e.value)
    assert str(p) in msg, msg
    for s in substrings:
        assert s in msg, msg


def test_chessboard_file(tmp_path):
    text = '[board]\ntype = "chessboard"\nsquares = [9, 6]\nsquare_length = 0.025\n'
    b = load_board(_board_file(tmp_path, text))
    assert (b.type, b.squares, b.marker_length, b.dictionary) == ("chessboard", (9, 6), None, None)
    with pytest.raises(FormatError, match=r"\[board\].dictionary: only used by type = \"charuco\""):
        load_board(_board_file(tmp_path, text + 'dictionary = "DICT_4X4_50"\n'))


def test_large_board_fits_a_large_dictionary(tmp_path):
    p = _board_file(tmp_path, CHARUCO.replace("[5, 7]", "[11, 11]").replace("DICT_5X5_100", "DICT_5X5_250"))
    assert load_board(p).cv2_board().getIds().size == 60
