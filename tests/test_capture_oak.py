"""DepthAI driver against a fake SDK, and the fake checked against the installed depthai."""

from __future__ import annotations

import datetime as dt
import inspect

import numpy as np
import pytest

from capture.fake_depthai import FakeOak, make_fake_depthai
from capture.mock import pattern_sequence
from capture.oak import DepthAIControls, DepthAISource, list_depthai_devices, parse_device
from capture.recorder import record
from capture.source import CaptureError, Frame
from polycam.rig import CameraSpec, Rig
from polycam.session import open_session


def spec(i: int, device: str, fmt="GREY", w=320, h=200) -> CameraSpec:
    return CameraSpec(id=f"cam{i:02d}", driver="depthai", device=device, width=w, height=h, fps=30.0,
                      pixel_format=fmt, position=np.array([0.05 * i, 0, 0]), rotation=np.zeros(3))


def source(cams, oaks, **kw):
    dai = make_fake_depthai(oaks)
    return DepthAISource(cams, dai=dai, sleep=dai.sleep, clock=dai.clock, realtime=False, **kw), dai


def frames_of(src, n_reads=10):
    out = []
    for _ in range(n_reads):
        out += src.read(0.1)
    return out


def test_fake_sdk_surface_exists_in_the_real_depthai():
    dai = pytest.importorskip("depthai")
    fake = make_fake_depthai([FakeOak()])
    used = {
        "Device": ["getAllAvailableDevices", "setExternalFrameSyncRole", "close", "getDeviceId"],
        "DeviceInfo": ["getDeviceId", "name", "state"],
        "Pipeline": ["create", "start", "stop", "isRunning"],
        "MessageQueue": ["tryGet", "get", "QueueException", "getMaxSize", "isClosed"],
        "ImgFrame": ["getCvFrame", "getFrame", "getTimestamp", "getTimestampDevice", "getSequenceNum",
                     "getWidth", "getHeight", "getType", "Type", "getExposureTime"],
        "CameraControl": ["setManualExposure", "setManualWhiteBalance", "setFrameSyncMode", "FrameSyncMode"],
    }
    for cls, names in used.items():
        for n in names:
            assert hasattr(getattr(fake, cls), n) or n in ("name", "state"), (cls, n)
            assert hasattr(getattr(dai, cls), n), (cls, n)
    for n in ("build", "requestOutput", "initialControl"):
        assert hasattr(dai.node.Camera, n) and hasattr(fake.node.Camera, n)
    assert hasattr(dai.Node.Output, "createOutputQueue")
    for enum_name, members in (("ImgFrame.Type", ["GRAY8", "RGB888i"]), ("CameraBoardSocket", ["CAM_A", "CAM_B", "CAM_C"]),
                               ("CameraControl.FrameSyncMode", ["OUTPUT", "INPUT"]),
                               ("ExternalFrameSyncRole", ["MASTER", "SLAVE"]),
                               ("CameraExposureOffset", ["START", "MIDDLE", "END"])):
        real, fk = dai, fake
        for part in enum_name.split("."):
            real, fk = getattr(real, part), getattr(fk, part)
        for m in members:
            assert hasattr(real, m) and hasattr(fk, m), (enum_name, m)
    # keyword names the driver passes exist in the real signatures (pybind docstrings)
    assert "sensorFps" in dai.node.Camera.build.__doc__
    assert "type" in dai.node.Camera.requestOutput.__doc__ and "fps" in dai.node.Camera.requestOutput.__doc__
    assert "maxSize" in dai.Node.Output.createOutputQueue.__doc__ and "blocking" in dai.Node.Output.createOutputQueue.__doc__
    assert "timedelta" in dai.ImgFrame.getTimestamp.__doc__
    assert "offset: depthai.CameraExposureOffset" in dai.ImgFrame.getTimestamp.__doc__
    fake_sig = inspect.signature(fake.node.Camera.requestOutput)
    assert {"size", "type", "fps"} <= set(fake_sig.parameters)


def test_parse_device():
    assert parse_device("ABC/CAM_B") == ("ABC", "CAM_B")
    assert parse_device("CAM_A") == (None, "CAM_A")
    with pytest.raises(CaptureError):
        parse_device(None)


def test_hardware_synced_sensors_share_timestamps():
    oak = FakeOak("AAA")
    src, dai = source([spec(0, "AAA/CAM_B"), spec(1, "AAA/CAM_C"), spec(2, "AAA/CAM_A", "RGB")], [oak])
    src.start()
    frames = [f for f in frames_of(src) if isinstance(f, Frame)]
    by_seq: dict[int, set] = {}
    for f in frames:
        by_seq.setdefault(f.sequence, set()).add(f.timestamp_ns)
        assert pattern_sequence(f.image) == f.sequence
    assert all(len(ts) == 1 for ts in by_seq.values())  # one FSYNC pulse for all sensors
    rgb = next(f for f in frames if f.cam_id == "cam02")
    assert rgb.image.shape == (200, 320, 3)
    assert src.info()["depthai"]["AAA"]["sync"] == "hardware"
    cams = dai.state.opened[0]
    src.stop()
    assert cams.closed


def test_timestamps_are_host_synced_nanoseconds():
    src, dai = source([spec(0, "CAM_B")], [FakeOak()])
    src.start()
    f = frames_of(src, 3)[0]
    assert f.timestamp_ns % 1000 == 0
    assert abs(f.timestamp_ns - dai.state.now_ns) < 0.2e9  # on the host clock, not the device's
    assert f.timestamp_ns == (1000 * 10**9 + 50_000_000 + (f.timestamp_ns - 1000 * 10**9 - 50_000_000))


def test_timestamps_are_the_middle_of_the_exposure():
    # DepthAI stamps the end of a frame's exposure; the driver takes the middle, the moment the image
    # shows: FSYNC'd sensors whose auto exposures differ are stamped that far apart
    oak = FakeOak(auto_exposure_us={"CAM_A": 20_000, "CAM_C": 4_001})
    src, dai = source([spec(0, "CAM_B"), spec(1, "CAM_C"), spec(2, "CAM_A", "RGB")], [oak])
    src.start()
    stamps: dict[int, dict[str, int]] = {}
    for f in frames_of(src):
        if isinstance(f, Frame):
            stamps.setdefault(f.sequence, {})[f.cam_id] = f.timestamp_ns
    full = [t for t in stamps.values() if len(t) == 3]
    assert full and all(t["cam00"] - t["cam02"] == 5_000_000 and t["cam01"] - t["cam00"] == 3_000_000
                        for t in full)          # 20000 / 2 - 10000 / 2, 10000 / 2 - 4001 // 2 [µs] (DepthAI's halving)
    # a manual exposure moves every stamp back by half of it from the same end
    ends = {}
    for exposure in (8_000, 20_000):
        src, _ = source([spec(0, "CAM_B")], [FakeOak()], controls=DepthAIControls(exposure_us=exposure, iso=100))
        src.start()
        ends[exposure] = frames_of(src, 3)[0].timestamp_ns
    assert ends[8_000] - ends[20_000] == 6_000_000


def test_software_sync_when_external_sync_is_refused(caplog):
    oaks = [FakeOak("AAA", "1.1"), FakeOak("BBB", "1.2", fsync=False)]
    src, _ = source([spec(0, "AAA/CAM_B"), spec(1, "BBB/CAM_B")], oaks)
    src.start()
    assert "no external frame sync" in caplog.text
    assert src.info()["depthai"]["BBB"]["sync"] == "software"
    src2, _ = source([spec(0, "AAA/CAM_B"), spec(1, "BBB/CAM_B")], oaks, sync="hardware")
    with pytest.raises(CaptureError, match="external frame sync refused"):
        src2.start()


def test_external_sync_aligns_devices():
    oaks = [FakeOak("AAA", "1.1"), FakeOak("BBB", "1.2", seed=5)]
    src, dai = source([spec(0, "AAA/CAM_B"), spec(1, "BBB/CAM_B")], oaks)
    src.start()
    roles = [d.role for d in dai.state.opened]
    assert roles == [dai.ExternalFrameSyncRole.MASTER, dai.ExternalFrameSyncRole.SLAVE]
    frames = [f for f in frames_of(src) if isinstance(f, Frame)]
    a = {f.sequence: f.timestamp_ns for f in frames if f.cam_id == "cam00"}
    b = {f.sequence: f.timestamp_ns for f in frames if f.cam_id == "cam01"}
    assert all(a[s] == b[s] for s in set(a) & set(b))


def test_device_selection_errors():
    oaks = [FakeOak("AAA", "1.1"), FakeOak("BBB", "1.2")]
    with pytest.raises(CaptureError, match="2 are connected"):
        source([spec(0, "CAM_B")], oaks)[0].start()
    with pytest.raises(CaptureError, match="'CCC' not found"):
        source([spec(0, "CCC/CAM_B")], oaks)[0].start()
    with pytest.raises(CaptureError, match="no OAK device found"):
        source([spec(0, "CAM_B")], [])[0].start()
    with pytest.raises(CaptureError, match="not found on device"):
        source([spec(0, "AAA/CAM_D")], oaks)[0].start()
    with pytest.raises(CaptureError, match="GREY or RGB"):
        DepthAISource([spec(0, "CAM_B", "Y16")])


def test_manual_controls_reach_the_sensors():
    src, dai = source([spec(0, "CAM_A", "RGB"), spec(1, "CAM_B")], [FakeOak()],
                      controls=DepthAIControls(exposure_us=8000, iso=200, white_balance=5000))
    src.start()
    pipe_cams = {c.socket.name: c.initialControl for c in src.devices[0].pipeline.cameras}
    assert pipe_cams["CAM_A"].exposure == (8000, 200) and pipe_cams["CAM_A"].white_balance == 5000
    assert pipe_cams["CAM_B"].exposure == (8000, 200) and pipe_cams["CAM_B"].white_balance is None


def test_slow_host_loses_frames_as_sequence_gaps():
    src, dai = source([spec(0, "CAM_B")], [FakeOak()], queue_size=4)
    src.start()
    dai.sleep(0.05 + 11 / 30)  # host busy: 10-11 frames produced, the queue keeps the newest 4
    seqs = [f.sequence for f in src.read(0.0)]
    assert seqs[0] >= 6 and seqs == list(range(seqs[0], seqs[0] + 4))
    assert src.read(0.1)[0].sequence == seqs[-1] + 1


def test_lost_device_reports_its_cameras_and_recording_continues(tmp_path):
    oaks = [FakeOak("AAA", "1.1"), FakeOak("BBB", "1.2", disconnect_after=6)]
    cams = [spec(0, "AAA/CAM_B"), spec(1, "AAA/CAM_C"), spec(2, "BBB/CAM_B")]
    src, _ = source(cams, oaks)
    res = record(src, Rig("oaks", tuple(cams)), tmp_path / "s", frames=15)
    s = open_session(tmp_path / "s")
    assert len(s) == 15 and s.status == "complete"
    st = res.stats.per_camera["cam02"]
    assert st.lost and "OAK device lost" in st.lost and st.received == 6
    assert (s.cam_timestamps[:, 2] >= 0).sum() == 6


def test_list_devices():
    dai = make_fake_depthai([FakeOak("AAA", "1.1")])
    assert list_depthai_devices(dai) == [{"id": "AAA", "name": "1.1", "state": "X_LINK_UNBOOTED"}]


def test_timedelta_conversion_is_exact():
    from capture.oak import _ns

    assert _ns(dt.timedelta(days=2, seconds=3, microseconds=7)) == (2 * 86400 + 3) * 10**9 + 7000


def test_the_oak_d_lite_rig_file_records_from_one_device():
    """rigs/oak_d_lite.toml (one OAK-D Lite: a linear array of its three sensors) opens one device
    by the name in its camera entries and delivers its three sensors in hardware sync."""
    from pathlib import Path

    from polycam.rig import load_rig

    rig = load_rig(Path(__file__).resolve().parents[1] / "rigs" / "oak_d_lite.toml")
    cams = list(rig.cameras)
    assert [c.device for c in cams] == ["oak/CAM_B", "oak/CAM_A", "oak/CAM_C"]
    src, dai = source(cams, [FakeOak("18443010D1E4A71200", name="oak")])
    src.start()
    frames = [f for f in frames_of(src) if isinstance(f, Frame)]
    src.stop()
    assert {f.cam_id for f in frames} == {"left", "rgb", "right"}
    by_seq: dict[int, set] = {}
    for f in frames:
        by_seq.setdefault(f.sequence, set()).add(f.timestamp_ns)
    assert all(len(ts) == 1 for ts in by_seq.values())
    assert next(f for f in frames if f.cam_id == "rgb").image.shape == (480, 640, 3)
