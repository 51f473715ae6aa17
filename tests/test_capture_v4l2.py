"""V4L2 driver: struct layouts vs the kernel header, and the driver against a faithful fake kernel."""

from __future__ import annotations

import ctypes
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

import capture.v4l2 as V
from capture.fake_v4l2 import FakeCamera, FakeV4L2
from capture.mock import pattern_sequence
from capture.recorder import record
from capture.source import CameraLost, CaptureError, Frame
from polycam.rig import CameraSpec, Rig
from polycam.session import open_session

HEADER = Path("/usr/include/linux/videodev2.h")


def spec(i: int, fmt="GREY", w=640, h=480, fps=30.0, device=None) -> CameraSpec:
    return CameraSpec(id=f"cam{i:02d}", driver="v4l2", device=device or f"/dev/video{2 * i}", width=w, height=h,
                      fps=fps, pixel_format=fmt, position=np.array([0.03 * i, 0, 0]), rotation=np.zeros(3))


def read_all(src, n_reads: int) -> list:
    out = []
    for _ in range(n_reads):
        out += src.read(0.1)
    return out


@pytest.mark.skipif(shutil.which("cc") is None or not HEADER.exists(), reason="needs a C compiler and videodev2.h")
def test_struct_layouts_and_ioctl_numbers_match_the_kernel_header(tmp_path):
    structs = ["v4l2_capability", "v4l2_fmtdesc", "v4l2_frmsizeenum", "v4l2_frmivalenum", "v4l2_pix_format",
               "v4l2_format", "v4l2_streamparm", "v4l2_control", "v4l2_queryctrl", "v4l2_requestbuffers",
               "v4l2_buffer"]
    offsets = [("v4l2_buffer", f) for f in ("timestamp", "timecode", "sequence", "memory", "m", "length",
                                            "request_fd")] + [("v4l2_format", "fmt"), ("v4l2_streamparm", "parm"),
                                                              ("v4l2_queryctrl", "default_value")]
    consts = [n for n in dir(V) if n.startswith(("VIDIOC_", "V4L2_CID_", "V4L2_BUF_FLAG_", "V4L2_CAP_"))]
    src = ["#include <stdio.h>", "#include <stddef.h>", "#include <linux/videodev2.h>", "int main(void){"]
    src += [f'printf("size {s} %zu\\n", sizeof(struct {s}));' for s in structs]
    src += [f'printf("off {s}.{f} %zu\\n", offsetof(struct {s}, {f}));' for s, f in offsets]
    src += [f'printf("const {c} %lu\\n", (unsigned long)({c}));' for c in consts]
    src += ["return 0;}"]
    (tmp_path / "v.c").write_text("\n".join(src))
    subprocess.run(["cc", "-o", str(tmp_path / "v"), str(tmp_path / "v.c")], check=True)
    out = subprocess.run([str(tmp_path / "v")], capture_output=True, text=True, check=True).stdout
    for line in out.splitlines():
        kind, name, value = line.split()
        if kind == "size":
            got = ctypes.sizeof(getattr(V, name))
        elif kind == "off":
            s, f = name.split(".")
            got = getattr(getattr(V, s), f).offset
        else:
            got = getattr(V, name)
        assert got == int(value), name
    for rig_fmt, code in (("GREY", "GREY"), ("Y16", "Y16 "), ("YUYV", "YUYV"), ("MJPG", "MJPG"), ("RGB", "RGB3")):
        assert V.PIXEL_FORMAT_FOURCC[rig_fmt] == V.fourcc(code)


def test_streams_frames_with_kernel_timestamps_and_sequence_numbers():
    k = FakeV4L2([FakeCamera(path="/dev/video0")])
    src = V.V4L2Source([spec(0)], sys=k)
    src.start()
    frames = read_all(src, 10)
    assert [f.sequence for f in frames] == list(range(10))
    ts = np.array([f.timestamp_ns for f in frames])
    np.testing.assert_array_equal(np.diff(ts) // 1000, np.round(np.diff(ts) / 1000))  # µs resolution
    assert np.all(np.abs(np.diff(ts) - 1e9 / 30) <= 1000)
    assert all(pattern_sequence(f.image) == f.sequence and f.image.shape == (480, 640) for f in frames)
    names = [n for n, _ in k.calls]
    order = ["VIDIOC_QUERYCAP", "VIDIOC_S_FMT", "VIDIOC_S_PARM", "VIDIOC_REQBUFS", "VIDIOC_QUERYBUF",
             "VIDIOC_QBUF", "VIDIOC_STREAMON", "VIDIOC_DQBUF"]
    assert [names.index(n) for n in order] == sorted(names.index(n) for n in order)
    src.stop()
    names = [n for n, _ in k.calls]
    assert names[-2:] == ["VIDIOC_STREAMOFF", "VIDIOC_REQBUFS"]
    assert k.cameras["/dev/video0"].open_fds == 0


def test_padded_rows_and_every_pixel_format():
    cams = [spec(0, "GREY", 100, 60), spec(1, "YUYV", 100, 60), spec(2, "MJPG", 100, 60), spec(3, "RGB", 100, 60),
            spec(4, "Y16", 100, 60)]
    modes = {"GREY": {(100, 60): [30.0]}, "YUYV": {(100, 60): [30.0]}, "MJPG": {(100, 60): [30.0]},
             "RGB3": {(100, 60): [30.0]}, "Y16": {(100, 60): [30.0]}}
    k = FakeV4L2([FakeCamera(path=c.device, modes=modes, stride_align=64) for c in cams])
    src = V.V4L2Source(cams, sys=k)
    src.start()
    frames = {f.cam_id: f for f in read_all(src, 6) if isinstance(f, Frame)}
    src.stop()
    grey = frames["cam00"].image
    assert grey.shape == (60, 100) and pattern_sequence(grey) == frames["cam00"].sequence
    assert frames["cam01"].image.shape == (60, 100, 3)
    np.testing.assert_array_equal(frames["cam03"].image[:, :, 1], frames["cam03"].image[:, :, 0])
    assert frames["cam04"].image.dtype == np.uint16 and pattern_sequence(frames["cam04"].image) >= 0
    assert frames["cam02"].image.shape == (60, 100, 3)  # JPEG decoded
    for cam in ("cam01", "cam02", "cam03"):  # all carry the same grey picture
        seq = frames[cam].sequence
        assert abs(int(frames[cam].image[30, 50, 0]) - int(frames["cam00"].image[30, 50])) < 12 or \
            seq != frames["cam00"].sequence


def test_controls_are_fixed_and_equal_on_every_camera():
    cams = [spec(0), spec(1)]
    fakes = [FakeCamera(path=c.device) for c in cams]
    fakes[0].controls[V.V4L2_CID_EXPOSURE_ABSOLUTE]["value"] = 333
    fakes[1].controls[V.V4L2_CID_EXPOSURE_ABSOLUTE]["value"] = 120
    k = FakeV4L2(fakes)
    src = V.V4L2Source(cams, sys=k, controls=V.Controls(gain=40))
    src.start()
    for f in fakes:  # auto off (the fake refuses manual values while auto is on, like uvcvideo)
        c = f.controls
        assert c[V.V4L2_CID_EXPOSURE_AUTO]["value"] == V.V4L2_EXPOSURE_MANUAL
        assert c[V.V4L2_CID_AUTOGAIN]["value"] == 0 and c[V.V4L2_CID_AUTO_WHITE_BALANCE]["value"] == 0
        assert c[V.V4L2_CID_EXPOSURE_ABSOLUTE]["value"] == 333  # the first camera's value, everywhere
        assert c[V.V4L2_CID_GAIN]["value"] == 40
    info = src.info()["v4l2"]
    assert info["cam00"]["exposure"] == info["cam01"]["exposure"] == 333
    src.stop()


def test_start_of_exposure_timestamps_move_to_its_middle(caplog):
    # uvcvideo stamps the start of the exposure (TSTAMP_SRC_SOE): with the controls' manual exposure
    # (100 µs units) the driver moves each stamp to the exposure's middle, as the OAK driver's; with
    # automatic exposure (unknown) and for end-of-frame stamps it leaves them
    def first_stamp(tstamp_src, controls):
        k = FakeV4L2([FakeCamera(tstamp_src=tstamp_src)])
        src = V.V4L2Source([spec(0)], sys=k, controls=controls)
        src.start()
        ts = read_all(src, 3)[0].timestamp_ns
        src.stop()
        return ts

    caplog.set_level("INFO", logger="capture.v4l2")
    eof = first_stamp("EOF", V.Controls(exposure=100))
    assert "stamps the end of each frame" in caplog.text
    assert first_stamp("SOE", V.Controls(exposure=100)) - eof == 5_000_000
    assert first_stamp("SOE", V.Controls(exposure=333)) - eof == 16_650_000
    assert first_stamp("SOE", V.Controls(fixed=False)) == eof


def test_auto_controls_are_left_alone():
    f = FakeCamera()
    k = FakeV4L2([f])
    src = V.V4L2Source([spec(0)], sys=k, controls=V.Controls(fixed=False))
    src.start()
    assert f.controls[V.V4L2_CID_EXPOSURE_AUTO]["value"] == 3
    assert not any(n == "VIDIOC_S_CTRL" for n, _ in k.calls)
    src.stop()


def test_lost_and_corrupt_frames_are_sequence_gaps():
    k = FakeV4L2([FakeCamera(lose={3, 4}, corrupt={7})])
    src = V.V4L2Source([spec(0)], sys=k)
    src.start()
    seqs = [f.sequence for f in read_all(src, 12)]
    assert seqs[:8] == [0, 1, 2, 5, 6, 8, 9, 10]


def test_a_slow_reader_loses_frames_once_buffers_run_out():
    k = FakeV4L2([FakeCamera()])
    src = V.V4L2Source([spec(0)], sys=k, buffers=3)
    src.start()
    assert [f.sequence for f in src.read(0.1)] == [0]
    k.advance(10 / 30)  # busy for ten frame periods: three buffers fill, the rest is lost
    got = [f.sequence for f in src.read(0.0)]
    assert got == [1, 2, 3]
    assert [f.sequence for f in src.read(0.1)] == [11]


def test_unplugged_camera_is_reported_lost_and_the_others_continue():
    cams = [spec(0), spec(1)]
    k = FakeV4L2([FakeCamera(path=cams[0].device, unplug_after=5), FakeCamera(path=cams[1].device)])
    src = V.V4L2Source(cams, sys=k)
    src.start()
    items = read_all(src, 20)
    lost = [it for it in items if isinstance(it, CameraLost)]
    assert len(lost) == 1 and lost[0].cam_id == "cam00" and "No such device" in lost[0].reason
    assert sum(1 for it in items if isinstance(it, Frame) and it.cam_id == "cam00") == 5
    assert sum(1 for it in items if isinstance(it, Frame) and it.cam_id == "cam01") >= 15
    src.stop()


def test_format_the_device_cannot_give_is_a_clear_error():
    k = FakeV4L2([FakeCamera()])
    with pytest.raises(CaptureError, match="asked for 800x600 GREY, the device gives 640x480"):
        V.V4L2Source([spec(0, w=800, h=600)], sys=k).start()
    with pytest.raises(CaptureError, match="pixel format Y16 not offered"):
        V.V4L2Source([spec(0, "Y16")], sys=k).start()
    with pytest.raises(CaptureError, match="asked for 25 fps"):
        V.V4L2Source([spec(0, fps=25.0)], sys=k).start()
    with pytest.raises(CaptureError, match="cannot open"):
        V.V4L2Source([spec(0, device="/dev/video7")], sys=k).start()
    assert k.cameras["/dev/video0"].open_fds == 0  # everything closed again


def test_non_monotonic_driver_timestamps_fall_back_to_dequeue_time(caplog):
    k = FakeV4L2([FakeCamera(monotonic=False)])
    src = V.V4L2Source([spec(0)], sys=k)
    src.start()
    f = src.read(0.1)[0]
    assert f.timestamp_ns == k.now_ns
    assert "not CLOCK_MONOTONIC" in caplog.text


def test_record_a_session_from_fake_webcams(tmp_path):
    cams = [spec(0, w=320, h=240), spec(1, w=320, h=240)]
    k = FakeV4L2([FakeCamera(path=c.device, phase_ns=3_000_000 * i, lose={4} if i else set())
                  for i, c in enumerate(cams)])
    rig = Rig("webcams", tuple(cams))
    res = record(V.V4L2Source(cams, sys=k, realtime=False), rig, tmp_path / "s", frames=20)
    s = open_session(tmp_path / "s")
    assert len(s) == 20 and s.status == "complete"
    assert res.stats.per_camera["cam01"].dropped == 1
    assert np.all(np.abs(s.cam_timestamps[s.cam_timestamps[:, 1] >= 0, 1]
                         - s.cam_timestamps[s.cam_timestamps[:, 1] >= 0, 0]) == 3_000_000)
    assert (s.cam_timestamps[:, 1] == -1).sum() == 1


def test_list_devices_reports_formats_sizes_and_rates():
    k = FakeV4L2([FakeCamera(path="/dev/video0"), FakeCamera(path="/dev/video2", card="Other")])
    found = V.list_v4l2_devices(["/dev/video0", "/dev/video1", "/dev/video2"], sys=k)
    assert [d["path"] for d in found] == ["/dev/video0", "/dev/video2"]
    grey = found[0]["formats"][0]
    assert grey["fourcc"] == "GREY"
    assert grey["modes"][0] == {"width": 640, "height": 480, "fps": [30.0, 15.0]}
    assert [f["fourcc"] for f in found[1]["formats"]] == ["GREY", "YUYV", "MJPG"]


def test_kernel_semantics_of_the_fake():
    """The fake refuses what the kernel refuses (so the driver is tested against real rules)."""
    k = FakeV4L2([FakeCamera()])
    d = V.V4L2Device("/dev/video0", k)
    d.open()
    d.set_format("GREY", 640, 480)
    d.start(2)
    with pytest.raises(OSError) as e:  # format change while buffers exist
        d.set_format("GREY", 320, 240)
    assert e.value.errno == 16  # EBUSY
    with pytest.raises(OSError) as e:  # buffer already queued
        d.queue(0)
    assert e.value.errno == 22  # EINVAL
    assert d.dequeue() is None  # EAGAIN: nothing captured yet
    d.close()
