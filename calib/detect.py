"""Board corner detection: ChArUco (OpenCV 5 ``CharucoDetector``) and chessboards,
gathered per session into mrcal's ``observations_board`` layout.

mrcal wants every board observation as an array of dims (H, W, 3): one
``(x, y, weight)`` row per inner chessboard corner, ``H = rows - 1`` corner rows
and ``W = cols - 1`` corner columns, in the same order as the ChArUco corner ids
(row by row, x fastest: :meth:`polycam.board.Board.object_points`). A corner that
was not seen has weight -1 (mrcal ignores it). Weights of seen corners follow
mrgingham's convention: ``1 / 2**level`` where ``level`` is the pyramid level the
corner was detected at (0: full resolution; 1: a half-resolution retry for images
where nothing was found at full resolution, e.g. a slightly blurred board).

Partial ChArUco views are kept when they have at least ``min_corners`` corners
spanning at least two corner rows and two corner columns (so the PnP seed is
well posed); smaller partial views are counted as ``too few corners``. This is
the deliberate threshold the issue asks for: mrcal itself never sees weak
partial boards, because we drop them here. Plain chessboards are found whole or
not at all (``cv2.findChessboardCornersSB``); their labelling is made consistent
across cameras by putting the first corner at the upper left of the image
(fine for forward-looking arrays; use ChArUco boards for anything else).

**Corner refinement.** OpenCV's ChArUco corners are refined once more with ``cv2.cornerSubPix`` in a
window that stays inside the white margin between a corner and the markers of its neighbouring
squares (:data:`SUBPIX_MARGIN_SHARE` of that margin, measured in pixels at the view's corner
spacing): a larger window takes in the markers' edges, whose gradients pull the corner. On the
demo's rendered board views (squares ~23 px, margins ~3 px) OpenCV's own corners sat 0.016 px per
corner index outward from the board's centre (RMS 0.151 px against the true projections), which
the solve absorbed as focal lengths 0.46 % long (mrcal predicted 0.09 %); with a 5 x 5 window the
RMS is 0.117 px, the outward drift gone and the focal lengths within 0.01 % (7 x 7: −0.66 %, the
markers again; docs/calibration.md, which also has where large squares gain nothing).

Images without a usable board are counted per camera under one of the reasons
:data:`SKIP_REASONS` (``no board``, ``blurred``, ``wrong board``, ``too few
corners``: markers or a few corners but no usable view) and logged as a warning naming the camera and the files.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from polycam.board import Board
from polycam.errors import InputError

__all__ = [
    "SUBPIX_MARGIN_SHARE",
    "SKIP_REASONS",
    "Detection",
    "BoardObservations",
    "detect_board",
    "detect_session",
    "sharpness",
]

log = logging.getLogger(__name__)

SKIP_REASONS = ("no board", "blurred", "wrong board", "too few corners")
"""Why an image contributed no board observation."""

Progress = Callable[[int, int], None]

SUBPIX_MARGIN_SHARE = 0.8
"""Share of the white margin beside a ChArUco corner (``(square_length − marker_length) / 2``, in
pixels at the view's 10th-percentile corner spacing) that the final ``cornerSubPix`` half-window
may span, which is at least 2 px (see the module docstring)."""


def _cv2():
    import cv2  # lazily: keeps `polycam --help` fast

    return cv2


@dataclass(frozen=True)
class Detection:
    """The board corners found in one image (or why none were usable)."""

    ids: np.ndarray
    """(K,) int: ChArUco corner ids (= index into Board.object_points()), increasing."""
    q: np.ndarray
    """(K, 2) float64 [px] corner positions (pixel centres at integers)."""
    weight: np.ndarray
    """(K,) float64 relative weight of each corner (1 / 2**pyramid level)."""
    reason: str | None = None
    """None when usable, else one of :data:`SKIP_REASONS`."""
    markers: int = 0
    """Number of ArUco markers found (ChArUco only)."""

    @property
    def ok(self) -> bool:
        return self.reason is None


def sharpness(gray: np.ndarray) -> float:
    """Variance of the Laplacian of a grey image scaled to [0, 1] (a focus measure)."""
    cv2 = _cv2()
    g = np.asarray(gray, np.float32)
    g = g / (65535.0 if gray.dtype == np.uint16 else 255.0)
    return float(cv2.Laplacian(g, cv2.CV_32F, ksize=3).var())


def _to_gray8(image: np.ndarray) -> np.ndarray:
    """(H, W) uint8 grey from a grey or RGB, 8- or 16-bit image."""
    img = np.asarray(image)
    if img.ndim == 3:
        img = img.mean(axis=2)
    if img.dtype == np.uint16:
        img = img / 257.0
    return np.clip(np.rint(img), 0, 255).astype(np.uint8) if img.dtype != np.uint8 else img


def _spans_grid(ids: np.ndarray, board: Board) -> bool:
    """True if corner ids cover >= 2 corner rows and >= 2 corner columns (not collinear)."""
    w = board.cols - 1
    return len(np.unique(ids % w)) >= 2 and len(np.unique(ids // w)) >= 2


class _Detector:
    """Reusable OpenCV detector objects for one board."""

    def __init__(self, board: Board):
        cv2 = _cv2()
        self.board = board
        self.n_markers = (board.cols * board.rows) // 2
        if board.type == "charuco":
            params = cv2.aruco.DetectorParameters()
            params.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX
            cparams = cv2.aruco.CharucoParameters()
            cparams.tryRefineMarkers = True
            self.charuco = cv2.aruco.CharucoDetector(board.cv2_board(), cparams, params)

    def _charuco(self, gray: np.ndarray):
        corners, ids, _mcorners, mids = self.charuco.detectBoard(gray)
        nm = 0 if mids is None else len(mids)
        if ids is None or len(ids) == 0:
            return None, None, nm, mids
        return corners.reshape(-1, 2).astype(float), ids.ravel().astype(int), nm, mids

    def refine(self, gray: np.ndarray, q: np.ndarray, ids: np.ndarray) -> np.ndarray:
        """ChArUco corners q (n, 2) [px] with ids (n,) refined in a window inside the markers' margin
        (:data:`SUBPIX_MARGIN_SHARE`), at least 5 x 5 px (a 3 x 3 window is too noisy: 0.36 px RMS
        on the demo's views); a corner that would move by more than the half-window keeps its place."""
        cv2 = _cv2()
        w = self.board.cols - 1
        at = {int(i): k for k, i in enumerate(ids)}
        spacing = [np.hypot(*(q[at[int(i) + step]] - q[k])) for k, i in enumerate(ids)
                   for step in (1, w) if int(i) + step in at and (step == w or (int(i) + 1) % w)]
        if not spacing:
            return q
        margin = 0.5 * (self.board.square_length - self.board.marker_length) / self.board.square_length
        half = max(2, int(SUBPIX_MARGIN_SHARE * margin * float(np.percentile(spacing, 10))))
        pts = np.ascontiguousarray(q, np.float32).reshape(-1, 1, 2)
        cv2.cornerSubPix(gray, pts, (half, half), (-1, -1),
                         (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_COUNT, 50, 1e-3))
        r = pts.reshape(-1, 2).astype(float)
        moved = np.hypot(*(r - q).T) > half
        r[moved] = q[moved]
        return r

    def _chessboard(self, gray: np.ndarray):
        cv2 = _cv2()
        size = (self.board.cols - 1, self.board.rows - 1)
        flags = cv2.CALIB_CB_NORMALIZE_IMAGE | cv2.CALIB_CB_ACCURACY
        ok, corners = cv2.findChessboardCornersSB(gray, size, flags=flags)
        if not ok:
            return None, None
        q = corners.reshape(-1, 2).astype(float)
        if np.dot(q[-1] - q[0], (1.0, 1.0)) < 0:      # first corner at the image's upper left
            q = q[::-1].copy()
        return q, np.arange(q.shape[0])

    def detect(self, image: np.ndarray, min_corners: int) -> Detection:
        cv2 = _cv2()
        gray = _to_gray8(image)
        first = None
        for level in (0, 1):
            g = gray if level == 0 else cv2.resize(gray, (gray.shape[1] // 2, gray.shape[0] // 2),
                                                   interpolation=cv2.INTER_AREA)
            nm, foreign = 0, 0
            if self.board.type == "charuco":
                q, ids, nm, mids = self._charuco(g)
                if mids is not None:
                    foreign = int(np.count_nonzero(np.asarray(mids).ravel() >= self.n_markers))
            else:
                q, ids = self._chessboard(g)
            if q is not None:
                if level == 1:
                    q = (q + 0.5) * 2.0 - 0.5   # half-resolution pixel centres → full resolution
                if self.board.type == "charuco":
                    q = self.refine(gray, q, ids)
                order = np.argsort(ids)
                ids, q = ids[order], q[order]
                if len(ids) >= min_corners and _spans_grid(ids, self.board):
                    return Detection(ids, q, np.full(ids.shape, 1.0 / 2**level), markers=nm)
            if level == 0:
                first = (q, ids, nm, foreign)
        # nothing usable at either resolution: say why, from the full-resolution attempt
        q, ids, nm, foreign = first
        if nm >= 4 and 2 * foreign >= nm:       # mostly markers this board cannot have
            return Detection(np.zeros(0, int), np.zeros((0, 2)), np.zeros(0), reason="wrong board", markers=nm)
        if q is not None:
            return Detection(ids, q, np.ones(ids.shape), reason="too few corners", markers=nm)
        if nm > 0:
            return Detection(np.zeros(0, int), np.zeros((0, 2)), np.zeros(0), reason="too few corners", markers=nm)
        return Detection(np.zeros(0, int), np.zeros((0, 2)), np.zeros(0), reason="no board")


def detect_board(image: np.ndarray, board: Board, *, min_corners: int = 8) -> Detection:
    """Find ``board``'s corners in one image.

    image: (H, W) grey or (H, W, 3) RGB, uint8 or uint16.
    min_corners: smallest partial ChArUco view kept (>= 6 for the PnP seed).
    """
    return _Detector(board).detect(image, max(int(min_corners), 6))


@dataclass
class BoardObservations:
    """Every usable board view of a session, in mrcal's layout (sorted by frame, then camera)."""

    board: Board
    cameras: list[str]
    """Camera ids; ``icam`` indexes this list."""
    imagersizes: np.ndarray
    """(C, 2) int [px] width, height of each camera."""
    observations: np.ndarray
    """(N, H, W, 3) float64 ``(x, y, weight)`` per corner; weight < 0: not seen."""
    indices_frame_camera: np.ndarray
    """(N, 2) int32 ``(iframe, icam)``; iframe indexes the session's frames."""
    paths: list[str]
    """(N,) image file of each observation."""
    counts: dict[str, dict[str, int]] = field(default_factory=dict)
    """Camera id → {"images", "used", and each of SKIP_REASONS} image counts."""
    skipped: dict[str, dict[str, list[str]]] = field(default_factory=dict)
    """Camera id → reason → image files that gave no observation."""
    found_markers: bool = False
    """True if any ArUco marker of the board's dictionary was found anywhere."""

    @property
    def object_spacing(self) -> float:
        return float(self.board.square_length)

    def subset(self, keep: np.ndarray) -> "BoardObservations":
        """The observations with ``keep`` (N,) bool True (same counts)."""
        keep = np.asarray(keep, bool)
        return BoardObservations(self.board, self.cameras, self.imagersizes, self.observations[keep],
                                 self.indices_frame_camera[keep],
                                 [p for p, k in zip(self.paths, keep) if k], self.counts, self.skipped,
                                 self.found_markers)


def _grid_observation(det: Detection, board: Board) -> np.ndarray:
    """(H, W, 3) mrcal observation array of one detection."""
    H, W = board.rows - 1, board.cols - 1
    obs = np.full((H * W, 3), -1.0)
    obs[det.ids, :2] = det.q
    obs[det.ids, 2] = det.weight
    return obs.reshape(H, W, 3)


def _diagnose_dictionary(image: np.ndarray, board: Board) -> str | None:
    """Name of another common ArUco dictionary whose markers appear in ``image``, if any."""
    cv2 = _cv2()
    gray = _to_gray8(image)
    for name in ("DICT_4X4_50", "DICT_5X5_100", "DICT_6X6_250", "DICT_7X7_250", "DICT_ARUCO_ORIGINAL",
                 "DICT_APRILTAG_36h11"):
        if name == board.dictionary:
            continue
        det = cv2.aruco.ArucoDetector(cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, name)))
        _, ids, _ = det.detectMarkers(gray)
        if ids is not None and len(ids) >= 4:
            return name
    return None


def detect_session(session, board: Board, *, cameras: list[str] | None = None, min_corners: int = 8,
                   blur_ratio: float = 0.3, progress: Progress | None = None) -> BoardObservations:
    """Detect ``board`` in every image of every camera of an open session.

    session: a :class:`polycam.session.Session`.
    cameras: subset of camera ids (default all, in session order).
    blur_ratio: an image without a board whose :func:`sharpness` is below
        ``blur_ratio`` times its camera's median is counted as ``blurred``.
    Frames are the session's ``frames.csv`` rows, so simultaneous views share
    an ``iframe``. Raises :class:`InputError` if the board is found nowhere
    (naming a dictionary that does appear, if any).
    """
    cams = list(cameras) if cameras is not None else list(session.cameras)
    det = _Detector(board)
    min_corners = max(int(min_corners), 6)
    col = {c: session.cameras.index(c) for c in cams}
    n_frames = len(session)
    total = n_frames * len(cams)
    obs, idx, paths = [], [], []
    counts = {c: {"images": 0, "used": 0, **{r: 0 for r in SKIP_REASONS}} for c in cams}
    skipped: dict[str, dict[str, list[str]]] = {c: {r: [] for r in SKIP_REASONS} for c in cams}
    sharp: dict[str, list[tuple[str, float, bool]]] = {c: [] for c in cams}
    found_markers = False
    first_image = None
    done = 0
    for i in range(n_frames):
        for icam, cam in enumerate(cams):
            ns = int(session.cam_timestamps[i, col[cam]])
            done += 1
            if ns < 0:
                continue
            path = session.image_path(cam, ns)
            image = session.read_image(cam, ns)
            if first_image is None:
                first_image = image
            d = det.detect(image, min_corners)
            counts[cam]["images"] += 1
            found_markers |= d.markers > 0 or d.ok
            rel = str(path.relative_to(session.path)) if path.is_relative_to(session.path) else str(path)
            if d.ok:
                counts[cam]["used"] += 1
                obs.append(_grid_observation(d, board))
                idx.append((i, icam))
                paths.append(str(path))
                sharp[cam].append((rel, sharpness(_to_gray8(image)), True))
            else:
                reason = d.reason
                s = sharpness(_to_gray8(image)) if reason == "no board" else np.nan
                sharp[cam].append((rel, s, False))
                if reason != "no board":
                    counts[cam][reason] += 1
                    skipped[cam][reason].append(rel)
            if progress is not None:
                progress(done, total)
    # blurred vs no board, relative to each camera's median sharpness
    for cam in cams:
        vals = np.array([s for _, s, _ in sharp[cam] if np.isfinite(s)] or [np.nan])
        med = float(np.nanmedian(vals)) if np.any(np.isfinite(vals)) else np.nan
        for rel, s, ok in sharp[cam]:
            if ok or not np.isfinite(s):
                continue
            reason = "blurred" if np.isfinite(med) and s < blur_ratio * med else "no board"
            counts[cam][reason] += 1
            skipped[cam][reason].append(rel)
    for cam in cams:
        for reason in SKIP_REASONS:
            files = skipped[cam][reason]
            if files:
                shown = ", ".join(files[:3]) + (f", ... ({len(files)} in all)" if len(files) > 3 else "")
                log.warning("%s: %d of %d images skipped (%s): %s", cam, len(files), counts[cam]["images"],
                            reason, shown)
    if not obs:
        hint = ""
        if board.type == "charuco" and not found_markers and first_image is not None:
            other = _diagnose_dictionary(first_image, board)
            if other:
                hint = f"; markers of {other} were found: check the board file's dictionary"
        wrong = sum(counts[c]["wrong board"] for c in cams)
        if wrong and not hint:
            hint = (f"; {wrong} images show markers that do not fit a {board.cols}x{board.rows} board "
                    "(check squares / dictionary in the board file)")
        where = f" ({board.path})" if board.path is not None else ""
        raise InputError(f"{session.path}: no usable {board.type} board{where} in any image of "
                         f"{', '.join(cams)}{hint}")
    H, W = board.rows - 1, board.cols - 1
    imagersizes = np.array([session.image_size(c) for c in cams], dtype=np.int32)
    return BoardObservations(board=board, cameras=cams, imagersizes=imagersizes,
                             observations=np.ascontiguousarray(np.stack(obs).reshape(-1, H, W, 3)),
                             indices_frame_camera=np.array(idx, dtype=np.int32).reshape(-1, 2),
                             paths=paths, counts=counts, skipped=skipped, found_markers=found_markers)
