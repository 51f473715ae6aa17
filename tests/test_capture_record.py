"""Mock driver and recorder end to end: sessions, statistics, fault injection, replay determinism."""

from __future__ import annotations

import errno
import threading
import tomllib
from pathlib import Path

import numpy as np
import pytest

from capture import CaptureError, MockSource, ReplaySource, pattern_sequence, record, rig_source
from capture.source import CameraLost, Frame
from polycam.rig import load_rig
from polycam.session import SessionWriter, open_session

from tolerances import CAPTURE_JITTER_STD_REL


def make_rig(tmp_path: Path, *, rows=2, cols=2, w=64, h=48, fmt="GREY", fps=30, scene="pattern",
             mock: str = "") -> "Rig":
    p = tmp_path / "rig.toml"
    p.write_text(f"""
[rig]
name = "t{rows}x{cols}"
[defaults]
driver = "mock"
width = {w}
height = {h}
fps = {fps}
pixel_format = "{fmt}"
[grid]
rows = {rows}
cols = {cols}
pitch = 0.02
[mock]
scene = "{scene}"
motion = "static"
seed = 3
{mock}
""")
    return load_rig(p)


def stats_of(path: Path) -> dict:
    return tomllib.loads((path / "capture_stats.toml").read_text())


def test_mock_end_to_end_writes_a_complete_session(tmp_path):
    rig = make_rig(tmp_path)
    res = record(MockSource(rig, realtime=False), rig, tmp_path / "s", frames=12)
    assert res.status == "complete" and res.stopped_by == "frames"
    s = open_session(tmp_path / "s")
    assert s.status == "complete" and len(s) == 12
    assert np.all(s.cam_timestamps >= 0)
    np.testing.assert_array_equal(s.timestamps_ns, np.round(np.arange(12) * 1e9 / 30).astype(np.int64))
    for i in range(12):  # each image is the frame its sequence number says
        assert all(pattern_sequence(img) == i for img in s.read_frame(i).values())
    st = stats_of(tmp_path / "s")
    assert st["capture"]["multiframes"] == 12 and st["capture"]["written"] == 12
    assert st["capture"]["dropped_total"] == 0
    assert st["camera"]["cam00"]["received"] == 12
    assert st["driver"]["mock"]["scene"] == "pattern"


@pytest.mark.parametrize("fmt, dtype, ndim", [("Y16", np.uint16, 2), ("RGB", np.uint8, 3), ("MJPG", np.uint8, 3)])
def test_mock_pixel_formats(tmp_path, fmt, dtype, ndim):
    rig = make_rig(tmp_path, rows=1, cols=2, fmt=fmt)
    record(MockSource(rig, realtime=False), rig, tmp_path / "s", frames=3)
    img = open_session(tmp_path / "s").read_frame(2)["cam01"]
    assert img.dtype == dtype and img.ndim == ndim and pattern_sequence(img) == 2
    if fmt == "MJPG":               # JPEG-compressed and decoded, as a webcam's: close to the grey frame, not equal
        (tmp_path / "g").mkdir()
        grey_rig = make_rig(tmp_path / "g", rows=1, cols=2, fmt="GREY")
        record(MockSource(grey_rig, realtime=False), grey_rig, tmp_path / "g" / "s", frames=3)
        grey = open_session(tmp_path / "g" / "s").read_frame(2)["cam01"].astype(int)
        diff = np.abs(img.astype(int) - grey[:, :, None])
        assert 0 < diff.mean() < 3 and diff.max() > 10


def test_mock_renders_the_synth_room(tmp_path):
    rig = make_rig(tmp_path, rows=1, cols=2, w=32, h=24, scene="room", mock="noise = 0.01")
    res = record(MockSource(rig, realtime=False), rig, tmp_path / "s", frames=2)
    imgs = open_session(tmp_path / "s").read_frame(1)
    assert res.stats.written == 2
    assert all(img.std() > 1.0 for img in imgs.values())  # a textured room, not a blank image


def test_mock_is_reproducible(tmp_path):
    rig = make_rig(tmp_path, mock="noise = 0.02\njitter_ms = 2.0\ndrop_rate = 0.1")

    def run():
        src = MockSource(rig, realtime=False, frames=20)
        src.start()
        out = []
        while not src.finished:
            out += src.read(0.0)
        return [(f.cam_id, f.timestamp_ns, f.sequence, f.image.tobytes()) for f in out]

    assert run() == run()


def test_drops_and_jitter_are_counted(tmp_path):
    rig = make_rig(tmp_path, rows=2, cols=3, mock="jitter_ms = 3.0\ndrop_rate = 0.2")
    res = record(MockSource(rig, realtime=False, frames=200), rig, tmp_path / "s")
    assert res.stopped_by == "end of source"
    src = MockSource(rig, realtime=False, frames=200)
    src.start()
    frames = []
    while not src.finished:
        frames += src.read(0.0)
    for cam, c in res.stats.per_camera.items():
        seqs = [f.sequence for f in frames if f.cam_id == cam]
        assert c.received == len(seqs)
        assert c.dropped == (seqs[-1] - seqs[0] + 1) - len(seqs)  # sequence gaps
        assert 0.1 < c.dropped / 200 < 0.3
    st = stats_of(tmp_path / "s")
    assert st["capture"]["dropped_total"] == sum(c["dropped"] + c["late"] for c in st["camera"].values())
    # jitter: spread of a complete multi-frame of 6 cameras with 3 ms jitter
    resid = [f.timestamp_ns - round(f.sequence * 1e9 / 30) for f in frames]
    assert np.std(resid) / 3e6 == pytest.approx(1.0, abs=CAPTURE_JITTER_STD_REL)
    sp = res.stats.spread_percentiles_ms()
    assert 3.0 < sp["p50"] < 12.0 and sp["max"] <= res.stats.tolerance_ns / 1e6


def test_disconnected_camera_is_missing_from_then_on(tmp_path):
    rig = make_rig(tmp_path, mock="[mock.disconnect_after]\ncam01 = 5")
    res = record(MockSource(rig, realtime=False), rig, tmp_path / "s", frames=10)
    assert res.status == "complete"
    s = open_session(tmp_path / "s")
    col = s.cameras.index("cam01")
    assert np.all(s.cam_timestamps[:5, col] >= 0) and np.all(s.cam_timestamps[5:, col] == -1)
    assert np.all(np.delete(s.cam_timestamps, col, axis=1) >= 0)
    st = stats_of(tmp_path / "s")["camera"]["cam01"]
    assert st["lost_after_frames"] == 5 and "disconnect" in st["lost"] and st["missing"] == 5


def test_strict_stops_when_a_camera_is_lost(tmp_path):
    rig = make_rig(tmp_path, mock="[mock.disconnect_after]\ncam02 = 4")
    with pytest.raises(CaptureError, match="cam02 was lost") as e:
        record(MockSource(rig, realtime=False), rig, tmp_path / "s", frames=50, strict=True)
    s = open_session(tmp_path / "s")
    assert s.status == "complete" and 4 <= len(s) < 50
    assert e.value.result.stopped_by == "camera lost: cam02"


class DiskFull(SessionWriter):
    """A SessionWriter whose disk fills up after `budget` images."""

    budget = 10

    def write_image(self, cam_id, timestamp_ns, image):
        with self._locks[cam_id]:
            if DiskFull.budget <= 0:
                raise OSError(errno.ENOSPC, "No space left on device", str(self.path / cam_id / "data"))
            DiskFull.budget -= 1
        return super().write_image(cam_id, timestamp_ns, image)


def test_writer_error_stops_cleanly_with_a_readable_incomplete_session(tmp_path):
    rig = make_rig(tmp_path)
    DiskFull.budget = 10  # 2.5 multi-frames of 4 images
    with pytest.raises(CaptureError, match="No space left on device") as e:
        record(MockSource(rig, realtime=False), rig, tmp_path / "s", frames=100, writer_factory=DiskFull)
    assert "status incomplete" in str(e.value)
    s = open_session(tmp_path / "s")
    assert s.status == "incomplete" and len(s) == 2
    st = stats_of(tmp_path / "s")
    assert st["capture"]["stopped_by"] == "writer error" and "No space" in st["capture"]["error"]
    assert sum(c["unwritten"] for c in st["camera"].values()) >= 4


def test_full_queue_with_a_live_source_reports_overflow(tmp_path):
    """A live source never waits for the writer: what does not fit is counted, not lost silently."""
    rig = make_rig(tmp_path)
    gate = threading.Event()

    class Slow(SessionWriter):
        def write_frame(self, *a, **k):
            gate.wait(5)
            return super().write_frame(*a, **k)

    src = MockSource(rig, realtime=False)
    src.realtime = True  # a simulated clock that behaves like a live camera for the queue
    threading.Timer(1.0, gate.set).start()
    res = record(src, rig, tmp_path / "s", frames=40, queue_frames=2, writer_factory=Slow)
    overflow = sum(c.overflow for c in res.stats.per_camera.values())
    assert overflow > 0 and overflow % 4 == 0
    assert res.stats.written + overflow // 4 == 40
    assert len(open_session(tmp_path / "s")) == res.stats.written


def test_stop_event_ends_a_capture_cleanly(tmp_path):
    rig = make_rig(tmp_path)
    stop = threading.Event()
    seen = []

    def on_update(stats):
        seen.append(stats.written)
        if stats.multiframes >= 5:
            stop.set()

    res = record(MockSource(rig, realtime=False), rig, tmp_path / "s", stop_event=stop, on_update=on_update,
                 update_interval=0.01)
    assert res.stopped_by == "interrupted" and res.status == "complete"
    assert open_session(tmp_path / "s").status == "complete"


def test_realtime_mock_loses_unread_frames_as_sequence_gaps(tmp_path):
    rig = make_rig(tmp_path, rows=1, cols=1)
    now = [0]
    src = MockSource(rig, realtime=True, buffers=3, clock=lambda: now[0],
                     sleep=lambda s: now.__setitem__(0, now[0] + int(s * 1e9)))
    src.start()
    now[0] += int(10.5 * 1e9 / 30)  # the application was busy for 10 frame periods
    got = src.read(0.0)
    assert [f.sequence for f in got] == [8, 9, 10]  # only the last `buffers` frames survived
    nxt = src.read(1.0)  # sleeps (simulated) until the next frame
    assert [f.sequence for f in nxt] == [11]


def test_seconds_limit_uses_frame_timestamps(tmp_path):
    rig = make_rig(tmp_path, rows=1, cols=2)
    res = record(MockSource(rig, realtime=False), rig, tmp_path / "s", seconds=0.5)
    assert res.stopped_by == "seconds" and res.stats.written == 15


def test_replay_rerecords_bit_identical_frames_and_timestamps(tmp_path):
    rig = make_rig(tmp_path, rows=2, cols=2, mock="noise = 0.02\njitter_ms = 4.0\ndrop_rate = 0.15\n"
                   "[mock.disconnect_after]\ncam03 = 20")
    record(MockSource(rig, realtime=False), rig, tmp_path / "a", frames=30)
    a = open_session(tmp_path / "a")
    res = record(ReplaySource(tmp_path / "a"), a.rig, tmp_path / "b")
    assert res.stopped_by == "end of source"
    b = open_session(tmp_path / "b")
    np.testing.assert_array_equal(a.timestamps_ns, b.timestamps_ns)
    np.testing.assert_array_equal(a.cam_timestamps, b.cam_timestamps)
    for cam in a.cameras:
        for t in a.image_timestamps(cam):
            np.testing.assert_array_equal(a.read_image(cam, t), b.read_image(cam, t))
            assert a.image_path(cam, t).read_bytes() == b.image_path(cam, t).read_bytes()
    assert (tmp_path / "a" / "frames.csv").read_bytes() == (tmp_path / "b" / "frames.csv").read_bytes()
    # gaps of the original show again as drops (sequence numbers rebuilt from timestamps)
    orig = stats_of(tmp_path / "a")["camera"]
    assert res.stats.per_camera["cam00"].dropped == orig["cam00"]["dropped"]


def test_replay_in_real_time_keeps_recorded_timestamps(tmp_path):
    rig = make_rig(tmp_path, rows=1, cols=2)
    record(MockSource(rig, realtime=False), rig, tmp_path / "a", frames=6)
    now = [100.0]
    src = ReplaySource(tmp_path / "a", realtime=True, clock=lambda: now[0],
                       sleep=lambda s: now.__setitem__(0, now[0] + s))
    src.start()
    got = []
    while not src.finished:
        got += [(now[0], f) for f in src.read(1.0)]
    t0 = got[0][1].timestamp_ns
    for wall, f in got:  # each frame is delivered when its recorded time has come
        assert wall - 100.0 == pytest.approx((f.timestamp_ns - t0) / 1e9, abs=1e-6)


def test_rig_replay_driver_maps_session_cameras(tmp_path):
    rig = make_rig(tmp_path, rows=1, cols=2)
    record(MockSource(rig, realtime=False), rig, tmp_path / "a", frames=4)
    p = tmp_path / "replay.toml"
    p.write_text("""
[rig]
name = "swapped"
[defaults]
driver = "replay"
width = 64
height = 48
[[camera]]
id = "left"
device = "a#cam01"
position = [0.0, 0.0, 0.0]
[[camera]]
id = "right"
device = "a#cam00"
position = [0.02, 0.0, 0.0]
""")
    rig2 = load_rig(p)
    res = record(rig_source(rig2, realtime=False), rig2, tmp_path / "b")
    a, b = open_session(tmp_path / "a"), open_session(tmp_path / "b")
    assert res.stats.written == 4
    np.testing.assert_array_equal(b.cam_timestamps[:, 0], a.cam_timestamps[:, 1])
    t = b.image_timestamps("left")[2]
    np.testing.assert_array_equal(b.read_image("left", t), a.read_image("cam01", t))


def test_source_frames_from_unknown_cameras_are_refused(tmp_path):
    rig = make_rig(tmp_path, rows=1, cols=1)
    src = MockSource(rig, realtime=False)
    src.cameras = ("nope",)
    with pytest.raises(CaptureError, match="not in the rig"):
        record(src, rig, None, frames=1)


def test_items_types():
    f = Frame("a", 1, 0, np.zeros((1, 1), np.uint8))
    lost = CameraLost("a", "gone")
    assert f.cam_id == lost.cam_id


def test_a_failing_driver_leaves_an_incomplete_readable_session(tmp_path):
    rig = make_rig(tmp_path)

    class Broken(MockSource):
        def read(self, timeout):
            if self._next[0] >= 3:
                raise CaptureError("camera cam00: OAK delivered 10x10, the rig asks for 64x48")
            return super().read(timeout)

    with pytest.raises(CaptureError, match="OAK delivered"):
        record(Broken(rig, realtime=False), rig, tmp_path / "s")
    s = open_session(tmp_path / "s")
    assert s.status == "incomplete" and len(s) >= 2
    assert stats_of(tmp_path / "s")["capture"]["stopped_by"] == "source error"


def test_free_running_cameras_whose_clocks_drift_apart(tmp_path):
    """[mock] clock_ppm: each camera's clock off by up to 0.5 % (a long capture's drift in 300 frames), its
    images show its own moments: recorded with free_running, every frame's images were captured within
    about a period (tracking alone would group each camera's i-th image, their clocks ~1.3 periods apart by
    the end), each camera's images in order, none twice; the session's capture times (the running median
    restarted where a camera moved to its next image) are each image's true moment within the jitter's
    share; the source reports the option."""
    from capture.mock import pattern_sequence

    rig = make_rig(tmp_path, rows=1, cols=5, mock="sync_spread_ms = 8.0\njitter_ms = 2.0\nclock_ppm = 5000.0")
    src = MockSource(rig, realtime=False, frames=300)
    assert src.info()["mock"]["clock_ppm"] == 5000.0
    res = record(src, rig, tmp_path / "s", frames=298, free_running=True)
    assert res.stats.complete >= 285
    s = open_session(tmp_path / "s")
    P = 1e9 / 30
    seq = np.full(s.cam_timestamps.shape, -1)
    for f in range(len(s)):
        for k, img in enumerate(s.read_frame(f).values()):
            if img is not None:
                seq[f, k] = pattern_sequence(img)
    for k in range(seq.shape[1]):
        got = seq[seq[:, k] >= 0, k]
        assert np.all(np.diff(got) > 0)
    has = seq >= 0
    truth = np.array([[src._nominal(k, i) for k, i in enumerate(row)] for row in seq], np.float64)
    truth[~has] = np.nan
    assert np.nanmax(np.nanmax(truth, axis=1) - np.nanmin(truth, axis=1)) < 1.25 * P
    assert np.abs(s.capture_times_ns()[has] - truth[has]).max() < 2.5e6
    assert np.sqrt(np.mean((s.capture_times_ns()[has] - truth[has]) ** 2)) < 1e6
    drift = np.array([src._nominal(k, 299) - src._nominal(k, 0) for k in range(5)])
    assert np.ptp(drift) > 1.2 * P


def test_free_running_cameras_at_other_frame_rates(tmp_path, capsys):
    """A rig of 30 fps cameras with one at 25 and one at 15 fps ([[camera]] fps), free-running: recorded,
    each image goes to the frame nearest in time (none late, within a period), and the session's capture
    times follow each camera's own clock (polycam.session.capture_times: the 25 fps camera's offset from
    the frames' times saws through a period, and a running median of it is 10 ms off); polycam info
    names the slower cameras."""
    from capture.mock import pattern_sequence
    from polycam.session import capture_times

    cams = "".join(f"""
[[camera]]
id = "c{k}"
position = [{0.02 * k}, 0, 0]
fps = {fps}
""" for k, fps in enumerate((30, 30, 30, 15, 25)))
    (tmp_path / "rig.toml").write_text(f"""
[rig]
name = "mixed"
[defaults]
driver = "mock"
width = 64
height = 48
{cams}
[mock]
scene = "pattern"
motion = "static"
seed = 3
sync_spread_ms = 8.0
jitter_ms = 2.0
""")
    rig = load_rig(tmp_path / "rig.toml")
    src = MockSource(rig, realtime=False, frames=300)
    res = record(src, rig, tmp_path / "s", frames=250, free_running=True)
    assert not any(c.late for c in res.stats.per_camera.values())
    s = open_session(tmp_path / "s")
    seq = np.full(s.cam_timestamps.shape, -1)
    for f in range(len(s)):
        for k, img in enumerate(s.read_frame(f).values()):
            if img is not None:
                seq[f, k] = pattern_sequence(img)
    has = seq >= 0
    assert has[:, 4].sum() > 200 and has[:, 3].sum() == 125
    truth = np.array([[src._nominal(k, i) for k, i in enumerate(row)] for row in seq], np.float64)
    spans = np.where(has, truth, np.nan)
    assert np.nanmax(np.nanmax(spans, axis=1) - np.nanmin(spans, axis=1)) < 1e9 / 30
    err = s.capture_times_ns()[has] - truth[has]
    assert np.sqrt(np.mean(err ** 2)) < 0.8e6 and np.abs(err).max() < 2.5e6
    as_one_rate = capture_times(s.frame_times_ns(), s.cam_timestamps)[:, 4]
    assert np.sqrt(np.mean((as_one_rate - truth[:, 4])[has[:, 4]] ** 2)) > 5e6
    from polycam.cli import main

    capsys.readouterr()
    assert main(["info", str(tmp_path / "s")]) == 0
    assert "2 cameras (c3, c4) at 25/15 fps against 30: missing from some frames" in capsys.readouterr().out


def test_no_free_running_hint_for_places_a_slower_camera_leaves_empty():
    """Two 30 fps cameras and one at 15 fps, frames spread to the tolerance: the 15 fps camera is missing
    from every other multi-frame by its rate (a third of all places), which is not the free-running
    pattern the hint names; the same empty places with every camera at 30 fps are."""
    from capture.display import free_running_hint
    from capture.stats import CaptureStats

    def run(slow_fps: float) -> str:
        st = CaptureStats(["a", "b", "c"], 33_000_000)
        for i in range(60):
            t = 1_000_000_000 + i * 33_333_333
            st.frame("a", t, i)
            st.frame("b", t + 30_000_000, i)
            if slow_fps == 30 or i % 2 == 0:
                st.frame("c", t, i if slow_fps == 30 else i // 2)
            st.multiframe(t, 30_000_000, ("c",) if i % 2 else ())
        return free_running_hint(st)

    assert run(15.0) == ""
    assert "--free-running" in run(30.0)


def test_free_running_cameras_are_grouped_by_their_phases(tmp_path):
    """Cameras at their own phases over a whole frame period ([mock] sync_spread_ms 16 at 30 Hz) with
    jittery timestamps (2 ms) are split across multi-frames by the default tolerance (half a period), and
    the summary says what to do; with free_running each camera's phase is tracked: one image per camera
    per frame (a tolerance of nearly a period, 31 ms, left 26-43 of 58 complete at this jitter)."""
    from capture.display import summary

    rig = make_rig(tmp_path, rows=1, cols=5, mock="sync_spread_ms = 16.0\njitter_ms = 2.0")
    split = record(MockSource(rig, realtime=False, frames=30), rig, tmp_path / "a", frames=30)
    assert split.stats.complete < 10
    text = summary(split.stats, "a", split.status)
    assert "hint: " in text and "--free-running" in text
    whole = record(MockSource(rig, realtime=False, frames=30), rig, tmp_path / "b", frames=29, free_running=True)
    assert whole.stats.complete >= 28 and sum(c.late for c in whole.stats.per_camera.values()) <= 2
    assert "hint" not in summary(whole.stats, "b", whole.status)
    s = open_session(tmp_path / "b")
    phase = (s.capture_times_ns() - s.frame_times_ns()[:, None])[s.cam_timestamps.min(axis=1) >= 0]
    assert np.abs(phase - np.median(phase, axis=0)).max() < 2e6 and np.ptp(np.median(phase, axis=0)) > 20e6
    # the split session regrouped by replay (the command line): every image was recorded
    from polycam.cli import main

    assert main(["replay", str(tmp_path / "a"), "--out", str(tmp_path / "c"), "--free-running", "--no-display"]) == 0
    regrouped = open_session(tmp_path / "c")
    assert len(regrouped) < len(open_session(tmp_path / "a"))
    assert (regrouped.cam_timestamps >= 0).all(axis=1).sum() >= len(regrouped) - 1     # the last: the ends
