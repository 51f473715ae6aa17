"""The mock driver: a simulated camera array that behaves like real hardware.

It renders the rig's ``[mock]`` table (SPEC.md, rig file):

- ``scene``: ``room`` / ``spheres`` are ray traced with
  :class:`polycam.synth.CameraArrayRenderer` at the rig's nominal camera models
  along the ``motion`` trajectory (:func:`polycam.synth.trajectory_for_rig`);
  ``pattern`` is a cheap moving test pattern for throughput tests: a seeded
  random-grey checkerboard (40 px squares) that drifts on a circle, seen by
  each camera with a parallax shift proportional to its position in the rig.
  In every ``pattern`` image the first 32 pixels of row 0 encode the frame's
  sequence number in binary (pixel k is 255 when bit k is set, else 0; for
  ``Y16`` 65535), so tests can check which frame an image is
  (:func:`pattern_sequence`).
- ``noise``: Gaussian grey-level noise (std in [0, 1] units), seeded per camera
  and frame.
- ``jitter_ms``: Gaussian jitter (std [ms]) of each frame's timestamp around the
  nominal ``start + i / fps`` (the image stays that of the nominal time).
- ``sync_spread_ms``: free-running cameras: camera k's frames come at ``start + o_k + i / fps``, its
  constant offset ``o_k`` uniform in ±``sync_spread_ms`` (seeded by ``seed`` and the camera's index in
  the rig), and (``room`` / ``spheres``) show the scene at that moment
  (:func:`polycam.trajectory.pose_at`); ``start`` is then ``sync_spread_ms`` later, so that no
  timestamp comes before it. A board session ignores it (the board holds each pose for a frame).
- ``clock_ppm``: free-running cameras' clocks: camera k's frame period is ``(1 + e_k 1e-6) / fps``, its
  ``e_k`` uniform in ±``clock_ppm`` (seeded as above), so the cameras' phases drift apart over a long
  capture as real webcams' do; its images show the scene at those moments. A board session ignores it.
- ``drop_rate``: each frame is lost with this probability; its sequence number
  is used up, so the gap shows as a drop.
- ``disconnect_after``: camera id → frame count after which that camera
  reports :class:`~capture.source.CameraLost` and delivers nothing more.

- ``board`` (a constructor argument; ``polycam capture --mock-board``): instead of
  the scene, a static rig watches a calibration board moved through seeded poses.
- ``models`` (constructor argument): the camera models rendered with (default the
  rig file's nominal ones).

:meth:`MockSource.write_truth` adds a recorded session's ground truth
(``groundtruth.tum``, ``calib/``, and for a board ``board_poses.tum``).

Every random choice comes from a stream seeded by ``[mock] seed``, the camera's
index and the frame index, so a run is reproducible.

Pacing: in real time (default) frame i of a camera becomes available at
``start + i / fps`` on ``time.monotonic_ns`` and carries that (jittered)
timestamp. Like a camera with ``buffers`` kernel buffers, frames not read
within ``buffers`` frame periods are lost (sequence gap). With
``realtime=False`` the clock is simulated (timestamps start at
``start_ns``, default 0) and frames come as fast as they are read, with no loss.
"""

from __future__ import annotations

import dataclasses
import heapq
import logging
import math
import os
import time
from pathlib import Path
from typing import Any, Callable

import numpy as np

from polycam.rig import MJPG_QUALITY, CameraSpec, MockSpec, Rig

from .source import CameraLost, CaptureError, Frame, FrameSource, Item

__all__ = ["MockSource", "PatternRenderer", "pattern_sequence", "to_pixel_format"]

log = logging.getLogger(__name__)

_SALT_DROP, _SALT_JITTER, _SALT_NOISE, _SALT_PATTERN, _SALT_SYNC, _SALT_CLOCK = 41, 42, 43, 44, 45, 46
_CODE_BITS = 32


def to_pixel_format(grey: np.ndarray, pixel_format: str, mjpg_quality: int = MJPG_QUALITY) -> np.ndarray:
    """An 8-bit grey image (H, W) in a rig pixel format: ``GREY`` → (H, W) uint8,
    ``Y16`` → (H, W) uint16 (x 257), ``RGB``/``YUYV`` → (H, W, 3) uint8 RGB, ``MJPG`` → the same
    after a JPEG round trip at ``mjpg_quality`` (:func:`polycam.synth.mjpg_frame`), as a webcam's."""
    if pixel_format == "GREY":
        return grey
    if pixel_format == "Y16":
        return grey.astype(np.uint16) * np.uint16(257)
    if pixel_format == "MJPG":
        from polycam.synth import mjpg_frame

        return mjpg_frame(grey, mjpg_quality)
    return np.repeat(grey[:, :, None], 3, axis=2)


def pattern_sequence(image: np.ndarray) -> int:
    """The sequence number encoded in a ``pattern`` image (row 0, first 32 pixels)."""
    row = np.asarray(image)[0, :_CODE_BITS]
    if row.ndim == 2:
        row = row[:, 0]
    half = 32768 if row.dtype == np.uint16 else 128
    bits = (row >= half).astype(np.int64)
    return int(np.sum(bits << np.arange(_CODE_BITS)))


class PatternRenderer:
    """The ``pattern`` scene: a drifting random-grey checkerboard with per-camera parallax.

    image(cam index, t [s], sequence) → (H, W) uint8.
    """

    SQUARE = 40          # [px] checker square
    DRIFT_PX = 24.0      # [px] radius of the circular drift
    DRIFT_PERIOD = 4.0   # [s]
    PARALLAX_PX_PER_M = 400.0  # [px/m] shift per metre of camera offset in the rig

    def __init__(self, cams: list[CameraSpec], seed: int, noise: float):
        self.cams = cams
        W = max(c.width for c in cams)
        H = max(c.height for c in cams)
        pos = np.stack([c.position for c in cams])
        self._shift = np.rint(pos[:, :2] * self.PARALLAX_PX_PER_M).astype(int)
        span = np.abs(self._shift).max(initial=0)
        m = int(self.DRIFT_PX) + 2 + int(span)
        self._margin = m
        rng = np.random.default_rng([seed, _SALT_PATTERN])
        ny = (H + 2 * m) // self.SQUARE + 2
        nx = (W + 2 * m) // self.SQUARE + 2
        levels = rng.integers(30, 226, size=(ny, nx)).astype(np.uint8)
        tex = np.repeat(np.repeat(levels, self.SQUARE, axis=0), self.SQUARE, axis=1)
        self._tex = np.ascontiguousarray(tex[:H + 2 * m, :W + 2 * m])
        self.noise = float(noise)
        self._noise_field = None
        if self.noise > 0:
            nrng = np.random.default_rng([seed, _SALT_NOISE])
            self._noise_field = np.rint(nrng.normal(0.0, self.noise * 255.0, size=(2 * H, 2 * W))
                                        ).astype(np.int16)
        self._seed = seed

    def image(self, k: int, t_s: float, sequence: int) -> np.ndarray:
        cam = self.cams[k]
        a = 2.0 * np.pi * t_s / self.DRIFT_PERIOD
        dx = int(round(self.DRIFT_PX * np.cos(a))) + self._shift[k, 0]
        dy = int(round(self.DRIFT_PX * np.sin(a))) + self._shift[k, 1]
        y0, x0 = self._margin + dy, self._margin + dx
        img = self._tex[y0:y0 + cam.height, x0:x0 + cam.width].copy()
        if self._noise_field is not None:
            rng = np.random.default_rng([self._seed, _SALT_NOISE, k, sequence])
            oy = int(rng.integers(0, cam.height))
            ox = int(rng.integers(0, cam.width))
            n = self._noise_field[oy:oy + cam.height, ox:ox + cam.width]
            img = np.clip(img.astype(np.int16) + n, 0, 255).astype(np.uint8)
        bits = (int(sequence) >> np.arange(_CODE_BITS)) & 1
        nb = min(_CODE_BITS, cam.width)
        img[0, :nb] = (bits[:nb] * 255).astype(np.uint8)
        return img


class _RayTraced:
    """``room`` / ``spheres``: all cameras rendered at one rig pose per nominal frame time;
    with a board: a static rig (at the world origin) watching the board at one pose per
    nominal frame time, in front of an object-free room."""

    def __init__(self, rig: Rig, cams: list[CameraSpec], mock: MockSpec, frames: int, supersample: int,
                 models: dict | None = None, board: Any = None):
        from polycam.cameras import nominal_cameramodel
        from polycam.synth import (CameraArrayRenderer, board_poses, frames_of, room_scene, scene_for_rig,
                                   static_trajectory, trajectory_for_rig)

        sub = dataclasses.replace(rig, cameras=tuple(cams))
        missing = [c.id for c in cams if models is not None and c.id not in models]
        if missing:
            raise CaptureError(f"mock: no camera model given for {', '.join(missing)}")
        self.models = {c.id: (models[c.id] if models is not None else nominal_cameramodel(c)) for c in cams}
        self.board = board
        self.ids = [c.id for c in cams]
        if board is None:
            self.motion = trajectory_for_rig(sub, frames, seed=mock.seed, margin=1)   # a period beyond the
            self.trajectory = frames_of(self.motion, 1)                              # frames both ways
            self.scene = scene_for_rig(sub, seed=mock.seed)
            self.board_poses = None
        else:
            self.trajectory = self.motion = static_trajectory(frames, float(cams[0].fps))
            self.board_poses = board_poses(board, self.models, frames, seed=mock.seed, cam_ids=self.ids)
            background = room_scene(max(mock.distance, 2.0), seed=mock.seed, n_spheres=0, n_boxes=0)
            self.scene, self._rect = _board_scene(board, self.models, self.board_poses, background)
        self.period_ns = 1e9 / float(cams[0].fps)
        self.renderer = CameraArrayRenderer(sub, self.models, self.scene, supersample)
        self._cache: tuple[int, dict] | None = None

    def index(self, t_rel_ns: int) -> int:
        """The trajectory (or board pose) index shown at ``t_rel_ns`` after the start."""
        return min(max(int(round(t_rel_ns / self.period_ns)), 0), len(self.trajectory) - 1)

    def pose_at(self, t_rel_ns: float) -> np.ndarray:
        """(4, 4) ``T_world_rig`` at ``t_rel_ns`` after the start, between the trajectory's poses
        (:func:`polycam.trajectory.pose_at`): within a frame period beyond its ends the rig's motion
        goes on (its poses a period before and after, :func:`polycam.synth.smooth_trajectory`'s
        ``margin``: an unsynchronised camera's first and last frames), farther the pose holds still."""
        from polycam.trajectory import pose_at

        ts = self.trajectory.timestamps_ns
        t = int(ts[0]) + float(t_rel_ns)
        return pose_at(self.motion, min(max(t, ts[0] - self.period_ns), ts[-1] + self.period_ns))

    def radiance_at(self, k: int, t_rel_ns: float) -> np.ndarray:
        """Camera k's radiance at its own moment ``t_rel_ns`` (an unsynchronised camera's)."""
        return self.renderer.render_camera(self.ids[k], self.pose_at(t_rel_ns))

    def radiance(self, k: int, i: int) -> np.ndarray:
        if self._cache is None or self._cache[0] != i:
            scene = None if self.board_poses is None else self.scene.with_rect_pose(self._rect, self.board_poses[i])
            self._cache = (i, self.renderer.render(self.trajectory.T_world_rig[i], scene))
        return self._cache[1][self.ids[k]]


def _board_scene(board, models: dict, poses: np.ndarray, background):
    """``background`` with the board's image as a two-sided textured rectangle at
    ``poses[0]`` (T_rig_board (N, 4, 4)) → (scene, rectangle index). The texture has at
    least two texels per pixel of the finest camera at the board's closest distance."""
    from polycam.cameras import T_rig_cam_of

    centres = np.stack([T_rig_cam_of(m)[:3, 3] for m in models.values()])             # (C, 3)
    closest = float(np.min(np.linalg.norm(poses[:, None, :3, 3] - centres[None], axis=-1)))
    fx = max(float(m.intrinsics()[1][0]) for m in models.values())
    texels = int(np.clip(np.ceil(2.0 * fx * board.square_length / max(closest, 1e-3)), 40, 240))
    image, H_image_board = board.render(texels, 0.5)
    border = round(0.5 * texels) / texels * board.square_length                 # [m] white margin
    w, h = board.size_m
    return background.with_image_rect(image, poses[0], (-border, w + border, -border, h + border),
                                      np.asarray(H_image_board)[:2])


class MockSource(FrameSource):
    """Simulated cameras (see the module docstring).

    rig: the rig (its ``[mock]`` table; defaults of :class:`~polycam.rig.MockSpec` without one).
    cameras: the cameras to simulate (default every camera of the rig).
    realtime: pace frames on the monotonic clock (else a simulated clock, no loss).
    frames: stop each camera after this many frames (default: run until stopped).
    buffers: frames a camera holds before unread ones are lost (real-time only).
    supersample: rays per pixel side for ``room``/``spheres``.
    trajectory_frames: length of the ``room``/``spheres`` trajectory (or of the board's
        pose sequence) when ``frames`` is not given (the pose holds still after its end).
    models: camera id → mrcal cameramodel to render each camera with (``room``,
        ``spheres``, board), e.g. :func:`polycam.synth.true_cameramodels` of a perturbed
        rig; default the rig file's nominal models.
    board: a :class:`polycam.board.Board`: instead of the ``[mock]`` scene the cameras
        see this calibration board moved through :func:`polycam.synth.board_poses` (seeded
        by ``[mock] seed``) in front of an object-free room, the rig standing still at
        the world origin (a board session for ``polycam calibrate``).

    After a recording of a ray-traced scene, :meth:`write_truth` adds the ground truth
    to the session (``groundtruth.tum``, ``calib/``, for a board ``board_poses.tum``).
    """

    driver = "mock"

    def __init__(self, rig: Rig, cameras: list[CameraSpec] | None = None, *, realtime: bool = True,
                 frames: int | None = None, start_ns: int = 0, buffers: int = 4, supersample: int = 1,
                 trajectory_frames: int = 900, models: dict | None = None, board: Any = None,
                 clock: Callable[[], int] = time.monotonic_ns, sleep: Callable[[float], None] = time.sleep):
        self.rig = rig
        self.cams = list(cameras if cameras is not None else rig.cameras)
        if not self.cams:
            raise CaptureError(f"{rig.path or rig.name}: no cameras for the mock driver")
        self.cameras = tuple(c.id for c in self.cams)
        self.mock = rig.mock if rig.mock is not None else MockSpec()
        self.realtime = bool(realtime)
        self.frames = frames
        self.start_ns = int(start_ns)
        self.buffers = max(1, int(buffers))
        self.supersample = supersample
        self.trajectory_frames = trajectory_frames
        self.models = models
        self.board = board
        if board is not None and self.mock.scene == "pattern":
            raise CaptureError(f"{rig.path or rig.name}: a mock board needs a ray-traced [mock] scene, not 'pattern'")
        self._shown: dict[tuple[str, int], int] = {}     # (camera id, timestamp) → [ns] moment shown (from start)
        self._clock = clock
        self._sleep = sleep
        self._started = False
        self.finished = False
        self._renderer: Any = None

    # -- life cycle

    def start(self) -> None:
        if self._started:
            return
        m = self.mock
        if m.scene == "pattern":
            self._renderer = PatternRenderer(self.cams, m.seed, m.noise)
        else:
            n = self.frames if self.frames is not None else self.trajectory_frames
            self._renderer = _RayTraced(self.rig, self.cams, m, max(int(n), 1), self.supersample,
                                        models=self.models, board=self.board)
        idx = {c.id: i for i, c in enumerate(self.rig.cameras)}
        self._rig_index = [idx.get(c.id, i) for i, c in enumerate(self.cams)]
        spread = m.sync_spread_ms if self.board is None else 0.0
        self._offset = [int(round(np.random.default_rng([m.seed, _SALT_SYNC, r]).uniform(-spread, spread) * 1e6))
                        if spread > 0 else 0 for r in self._rig_index]      # [ns] each camera's capture phase
        self._t0 = (self._clock() + 1_000_000 if self.realtime else self.start_ns) + int(math.ceil(spread * 1e6))
        ppm = m.clock_ppm if self.board is None else 0.0
        rate = [1.0 + np.random.default_rng([m.seed, _SALT_CLOCK, r]).uniform(-ppm, ppm) * 1e-6 if ppm > 0 else 1.0
                for r in self._rig_index]                                   # each camera's clock against the host's
        self._period = [1e9 / float(c.fps) * q for c, q in zip(self.cams, rate)]
        self._own_moment = [bool(o) or ppm > 0 for o in self._offset]    # images at the camera's own moment
        self._unsynced = any(self._own_moment)
        self._next = [0] * len(self.cams)            # next frame index per camera
        self._last_ts = [-1] * len(self.cams)
        self._gone = [False] * len(self.cams)
        self._drop_rng = [np.random.default_rng([m.seed, _SALT_DROP, r]) for r in self._rig_index]
        self._jit_rng = [np.random.default_rng([m.seed, _SALT_JITTER, r]) for r in self._rig_index]
        self._started = True
        log.info("mock: %d cameras, scene %s, %s", len(self.cams), "board" if self.board is not None else m.scene,
                 "real time" if self.realtime else "as fast as possible")

    def stop(self) -> None:
        self._started = False

    def info(self) -> dict[str, Any]:
        m = self.mock
        return {"mock": {"scene": "board" if self.board is not None else m.scene, "motion": m.motion, "seed": m.seed, "noise": m.noise,
                         "jitter_ms": m.jitter_ms, "sync_spread_ms": m.sync_spread_ms, "clock_ppm": m.clock_ppm, "drop_rate": m.drop_rate,
                         "realtime": self.realtime}}

    # -- frames

    def _nominal(self, k: int, i: int) -> int:
        return self._t0 + self._offset[k] + int(round(i * self._period[k]))

    def _due(self, now: int | None) -> list[tuple[int, int, int]]:
        """(nominal time, camera k, frame i) of the frames to deliver now, in time order."""
        events: list[tuple[int, int, int]] = []
        for k in range(len(self.cams)):
            if self._gone[k]:
                continue
            i = self._next[k]
            if self.frames is not None and i >= self.frames:
                continue
            events.append((self._nominal(k, i), k, i))
        if not events:
            return []
        if now is None:  # simulated clock: the earliest nominal time, all cameras sharing it
            t = min(e[0] for e in events)
            return sorted(e for e in events if e[0] == t)
        out: list[tuple[int, int, int]] = []
        for _, k, i in events:
            # frames whose time has come; those older than `buffers` periods were overwritten
            last = int((now - self._t0 - self._offset[k]) // self._period[k])
            if self.frames is not None:
                last = min(last, self.frames - 1)
            first = max(i, last - self.buffers + 1)
            for j in range(first, last + 1):
                out.append((self._nominal(k, j), k, j))
            if first > i:
                self._skip(k, i, first)
        heapq.heapify(out)
        return [heapq.heappop(out) for _ in range(len(out))]

    def _skip(self, k: int, i: int, first: int) -> None:
        """Frames i..first-1 of camera k were never read: lost (their draws still consumed)."""
        for _ in range(i, first):
            self._drop_rng[k].random()
            self._jit_rng[k].normal()
        self._next[k] = first

    def read(self, timeout: float) -> list[Item]:
        if not self._started:
            raise RuntimeError("MockSource.read before start")
        if self.realtime:
            due = self._due(self._clock())
            if not due:
                nxt = [self._nominal(k, self._next[k]) for k in range(len(self.cams)) if not self._gone[k]
                       and (self.frames is None or self._next[k] < self.frames)]
                if not nxt:
                    self.finished = True
                    return []
                wait = (min(nxt) - self._clock()) / 1e9
                if wait > timeout:
                    if timeout > 0:
                        self._sleep(timeout)
                    return []
                if wait > 0:
                    self._sleep(wait)
                due = self._due(self._clock())
        else:
            due = self._due(None)
            if not due:
                self.finished = True
                return []
        return [it for ev in due if (it := self._make(*ev)) is not None]

    def _make(self, t_nom: int, k: int, i: int) -> Item | None:
        cam = self.cams[k]
        m = self.mock
        self._next[k] = i + 1
        limit = m.disconnect_after.get(cam.id)
        if limit is not None and i >= limit:
            self._gone[k] = True
            last = self._last_ts[k]
            return CameraLost(cam.id, "disconnected (mock disconnect_after)", last if last >= 0 else None)
        drop = self._drop_rng[k].random() < m.drop_rate
        jit = self._jit_rng[k].normal() * m.jitter_ms * 1e6
        if drop:
            return None
        ts = max(int(round(t_nom + jit)), self._last_ts[k] + 1, 0)
        self._last_ts[k] = ts
        t_rel = t_nom - self._t0
        if isinstance(self._renderer, PatternRenderer):
            grey = self._renderer.image(k, t_rel / 1e9, i)
        else:
            from polycam.synth import quantize

            self._shown[(cam.id, ts)] = t_rel
            rad = (self._renderer.radiance_at(k, t_rel) if self._own_moment[k] else
                   self._renderer.radiance(k, self._renderer.index(t_rel)))
            rng = np.random.default_rng([m.seed, _SALT_NOISE, self._rig_index[k], i]) if m.noise > 0 else None
            if cam.pixel_format == "Y16":
                return Frame(cam.id, ts, i, quantize(rad, 16, m.noise, rng))
            grey = quantize(rad, 8, m.noise, rng)
        return Frame(cam.id, ts, i, to_pixel_format(grey, cam.pixel_format, m.mjpg_quality))

    # -- ground truth

    @property
    def has_truth(self) -> bool:
        """True for the ray-traced scenes (``room``, ``spheres``, a board), which know
        their camera models and poses exactly; False for ``pattern``."""
        return self.board is not None or self.mock.scene != "pattern"

    def write_truth(self, session_path: str | os.PathLike) -> list[str]:
        """Add the ground truth to a session recorded from this source; returns the files written.

        - ``groundtruth.tum``: ``T_world_rig`` of the pose each frame shows, at the
          frame's timestamp (world = the rig at the trajectory's start; a board session's
          rig stands still at the origin); with ``sync_spread_ms`` or ``clock_ppm``, the rig at the median of the
          moments its cameras captured the frame (as the frame's timestamp: the lower median, of the
          cameras at the fastest frame rate);
        - ``calib/<cam>.cameramodel``: the models the cameras were rendered with;
        - with a board: ``board_poses.tum`` (``T_rig_board`` per frame, as
          :func:`polycam.synth.synth_board_session` writes it) and ``board.toml`` (a copy
          of the board file, when the board was read from one).

        Like a synthetic session, a mock session then carries its true trajectory and
        calibration. Raises :class:`CaptureError` for the ``pattern`` scene or a session
        whose frames this source did not deliver.
        """
        from polycam.cameras import write_cameramodel
        from polycam.session import open_session
        from polycam.tomlio import atomic_write_text
        from polycam.trajectory import Trajectory, tum_text, write_tum

        if not self.has_truth or not isinstance(self._renderer, _RayTraced):
            raise CaptureError("mock: the 'pattern' scene has no ground truth (or the source never started)")
        sess = open_session(session_path)
        r = self._renderer
        poses = np.empty(len(sess), np.int64)
        T_world_rig = np.empty((len(sess), 4, 4))
        cams = list(sess.cameras)
        slower = sess.other_rate
        for f in range(len(sess)):
            moments = [(self._shown.get((c, int(ts))), o) for c, ts, o in zip(cams, sess.cam_timestamps[f], slower)
                       if ts >= 0]
            shown = [t for t, _ in moments if t is not None]
            if not shown:
                raise CaptureError(f"{sess.path}: frame {f} was not delivered by this mock source")
            own = sorted([t for t, o in moments if t is not None and not o] or shown)   # as the frame's
            poses[f] = r.index(shown[0])                                                # timestamp
            T_world_rig[f] = (r.pose_at(float(own[(len(own) - 1) // 2])) if self._unsynced else
                              r.trajectory.T_world_rig[poses[f]])
        path = Path(session_path)
        write_tum(path / "groundtruth.tum", Trajectory(sess.timestamps_ns.copy(), T_world_rig))
        written = ["groundtruth.tum"]
        (path / "calib").mkdir(exist_ok=True)
        for c, model in r.models.items():
            write_cameramodel(model, path / "calib" / f"{c}.cameramodel")
        written.append(f"calib/ ({len(r.models)} models)")
        if r.board_poses is not None:
            atomic_write_text(path / "board_poses.tum", tum_text(sess.timestamps_ns, r.board_poses[poses]))
            written.append("board_poses.tum")
            src = getattr(self.board, "path", None)
            if src is not None and Path(src).is_file():
                atomic_write_text(path / "board.toml", Path(src).read_text())
                written.append("board.toml")
        log.info("mock: ground truth of %d frames written to %s", len(sess), path)
        return written
