"""Calibration boards: ``BOARD.toml`` (SPEC.md), their corner coordinates and a printable image.

``[board]`` has ``type`` (``charuco`` | ``chessboard``), ``squares = [cols, rows]``,
``square_length`` [m] and, for ChArUco, ``marker_length`` [m] and
``dictionary`` (an OpenCV ArUco name such as ``DICT_5X5_100``).

Board frame (OpenCV's, docs/conventions.md): origin at the outer corner of the
first (top-left, black) square, x along the columns, y along the rows, z = 0 on
the board (z points into the board, away from a camera that sees it upright).
The inner chessboard corners are at ``((i + 1) s, (j + 1) s, 0)`` for column
``i < cols - 1`` and row ``j < rows - 1``, ordered row by row (i fastest): exactly
``cv2.aruco.CharucoBoard(...).getChessboardCorners()``, whose index is the
ChArUco corner id. The ChArUco layout is OpenCV's default (non-legacy) one.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import NamedTuple

import numpy as np

from .tomlio import Table, load_toml

__all__ = ["BOARD_TYPES", "Board", "BoardImage", "load_board", "aruco_dictionary_names"]

BOARD_TYPES = ("charuco", "chessboard")


def _cv2():
    import cv2  # lazily: keeps `polycam --help` fast

    return cv2


def aruco_dictionary_names() -> list[str]:
    """The predefined OpenCV ArUco dictionary names (``DICT_4X4_50``, ...)."""
    aruco = _cv2().aruco
    return sorted(n for n in dir(aruco) if n.startswith("DICT_") and isinstance(getattr(aruco, n), int))


def _dictionary_size(name: str) -> int:
    cv2 = _cv2()
    return int(cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, name)).bytesList.shape[0])


class BoardImage(NamedTuple):
    """A rendered board (:meth:`Board.render`); unpacks as ``image, H_image_board``."""

    image: np.ndarray
    """(H, W) uint8: 0 = black, 255 = white (margins white)."""
    H_image_board: np.ndarray
    """(3, 3) float64 affine map: ``[u, v, 1] = H_image_board @ [X, Y, 1]`` from board-frame
    metres to image pixels (pixel centres at integers)."""


@dataclass(frozen=True)
class Board:
    """A validated calibration board (see the module docstring for its frame)."""

    type: str
    """``"charuco"`` or ``"chessboard"``."""
    squares: tuple[int, int]
    """``(cols, rows)``: number of squares along x and along y."""
    square_length: float
    """[m] side of one chessboard square."""
    marker_length: float | None = None
    """[m] side of the ArUco markers (ChArUco only)."""
    dictionary: str | None = None
    """OpenCV ArUco dictionary name, e.g. ``DICT_5X5_100`` (ChArUco only)."""
    path: Path | None = None
    """The file it was read from (None when built in code)."""

    @property
    def cols(self) -> int:
        return int(self.squares[0])

    @property
    def rows(self) -> int:
        return int(self.squares[1])

    @property
    def num_corners(self) -> int:
        """Number of inner chessboard corners, ``(cols - 1) (rows - 1)``."""
        return (self.cols - 1) * (self.rows - 1)

    @property
    def size_m(self) -> tuple[float, float]:
        """``(width, height)`` [m] of the squared area of the board."""
        return self.cols * self.square_length, self.rows * self.square_length

    def cv2_board(self):
        """``cv2.aruco.CharucoBoard`` with OpenCV's default (non-legacy) layout, or None for a chessboard."""
        if self.type != "charuco":
            return None
        cv2 = _cv2()
        dictionary = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, self.dictionary))
        board = cv2.aruco.CharucoBoard((self.cols, self.rows), float(self.square_length),
                                       float(self.marker_length), dictionary)
        board.setLegacyPattern(False)
        return board

    def object_points(self) -> np.ndarray:
        """(N, 3) float64 [m] inner chessboard corners in the board frame, z = 0.

        N = (cols - 1)(rows - 1), row by row (x fastest); index = ChArUco corner id.
        Identical to ``cv2_board().getChessboardCorners()``.
        """
        s = float(self.square_length)
        i, j = np.meshgrid(np.arange(1, self.cols), np.arange(1, self.rows), indexing="xy")
        return np.stack([i.ravel() * s, j.ravel() * s, np.zeros(i.size)], axis=-1)

    def render(self, pixels_per_square: int, margin_squares: float = 0.5) -> BoardImage:
        """A printable / texturable image of the board and its board→image mapping.

        The squares are ``p = pixels_per_square`` pixels wide and the white
        margin is ``m = round(margin_squares * p)`` pixels on every side, so the
        image is ``(rows p + 2 m, cols p + 2 m)`` pixels (H, W). With pixel
        centres at integer coordinates, pixel ``(u, v)`` covers
        ``[u - 0.5, u + 0.5] x [v - 0.5, v + 0.5]`` and a board-frame point
        ``(X, Y)`` [m] is at::

            u = X * p / square_length + m - 0.5
            v = Y * p / square_length + m - 0.5

        i.e. ``[u, v, 1] = H_image_board @ [X, Y, 1]``. The board origin (outer
        corner of the top-left square) lies on the pixel edge at
        ``(m - 0.5, m - 0.5)``; inner corner ``(i + 1, j + 1) s`` on the edge
        at ``((i + 1) p + m - 0.5, ...)``. A ray tracer maps a hit ``(X, Y)``
        through ``H_image_board`` and samples the image there (bilinearly, say);
        points beyond the image are white paper or off the board.

        ChArUco images come from ``cv2.aruco.CharucoBoard.generateImage`` (markers
        with a one-bit border); a plain chessboard has a black top-left square like
        OpenCV's ChArUco layout. Choose ``p`` large enough for the markers'
        bits to be a few pixels each (e.g. p >= 40 for 5x5 markers).
        """
        p = int(pixels_per_square)
        if p != pixels_per_square or p < 2:
            raise ValueError(f"pixels_per_square must be an integer >= 2, got {pixels_per_square!r}")
        if not margin_squares >= 0:
            raise ValueError(f"margin_squares must be >= 0, got {margin_squares!r}")
        m = int(round(margin_squares * p))
        W, H = self.cols * p, self.rows * p
        if self.type == "charuco":
            inner = self.cv2_board().generateImage((W, H), marginSize=0, borderBits=1)
        else:
            jj, ii = np.meshgrid(np.arange(H) // p, np.arange(W) // p, indexing="ij")
            inner = np.where((ii + jj) % 2 == 0, 0, 255).astype(np.uint8)
        image = np.pad(np.asarray(inner, dtype=np.uint8), m, mode="constant", constant_values=255)
        k = p / float(self.square_length)
        H_image_board = np.array([[k, 0.0, m - 0.5], [0.0, k, m - 0.5], [0.0, 0.0, 1.0]])
        return BoardImage(image, H_image_board)


def load_board(path: str | os.PathLike) -> Board:
    """Read and validate a ``BOARD.toml``; errors name the file and the field."""
    path = Path(path)
    doc = load_toml(path)
    top = Table(path, "", doc)
    b = top.subtable("board")
    top.finish()
    kind = b.choice("type", BOARD_TYPES)
    cols, rows = b.vector("squares", 2, integer=True)
    if cols < 2 or rows < 2:
        raise b.error("squares", f"need at least 2 squares in each direction, got {[cols, rows]}")
    square = b.number("square_length", min=0.0, open_min=True)
    marker = dictionary = None
    if kind == "charuco":
        marker = b.number("marker_length", min=0.0, open_min=True)
        if not marker < square:
            raise b.error("marker_length", f"must be smaller than square_length ({square}), got {marker}")
        dictionary = b.get("dictionary", str)
        names = aruco_dictionary_names()
        if dictionary not in names:
            raise b.error("dictionary", f"unknown OpenCV ArUco dictionary {dictionary!r} "
                                        f"(e.g. DICT_4X4_50, DICT_5X5_100, DICT_6X6_250)")
        needed, have = (cols * rows) // 2, _dictionary_size(dictionary)
        if needed > have:
            raise b.error("dictionary", f"{dictionary} has {have} markers but a {cols}x{rows} ChArUco "
                                        f"board needs {needed}")
    else:
        for key in ("marker_length", "dictionary"):
            if b.has(key):
                raise b.error(key, 'only used by type = "charuco"')
    b.finish()
    return Board(type=kind, squares=(int(cols), int(rows)), square_length=float(square),
                 marker_length=marker, dictionary=dictionary, path=path)
