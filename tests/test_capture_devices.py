"""Device discovery: V4L2 nodes mapped to USB buses, bandwidth warnings, starter rig; hardware tests."""

from __future__ import annotations

import glob
import os
from pathlib import Path
from types import SimpleNamespace

import pytest

from capture.devices import BUS_BUDGET, bus_warnings, camera_bandwidth, discover, starter_rig, usb_devices
from capture.fake_depthai import FakeOak, make_fake_depthai
from capture.fake_v4l2 import FakeCamera, FakeV4L2
from polycam.rig import load_rig


class FakeUsbCore:
    """pyusb's usb.core.find over fake devices."""

    def __init__(self, devs):
        self.devs = devs

    def find(self, find_all=False):
        return iter(self.devs)


def usbdev(bus, addr, ports, speed, vendor=0x046D, product=0x0825, video=True):
    intf = SimpleNamespace(bInterfaceClass=0x0E if video else 0x03)

    class D(SimpleNamespace):
        def __iter__(self):
            return iter([[intf]])

    return D(bus=bus, address=addr, port_numbers=ports, speed=speed, idVendor=vendor, idProduct=product)


def sysfs_tree(root: Path, node: str, bus: int, dev: int) -> None:
    usbdir = root / "devices" / f"usb{bus}" / f"{bus}-{dev}"
    (usbdir / f"{bus}-{dev}:1.0").mkdir(parents=True)
    (usbdir / "busnum").write_text(f"{bus}\n")
    (usbdir / "devnum").write_text(f"{dev}\n")
    cls = root / "class" / "video4linux" / node
    cls.mkdir(parents=True)
    os.symlink(usbdir / f"{bus}-{dev}:1.0", cls / "device")


def test_bus_warning_when_cameras_share_a_usb2_bus():
    need = camera_bandwidth(640, 480, 30, "YUYV")  # 18.4 MB/s
    usb = [usbdev(1, 1, (), 3), usbdev(2, 1, (), 4)]
    usb = usb_devices(FakeUsbCore(usb))
    cams = [{"name": f"c{i}", "bus": 1, "bandwidth": need} for i in range(3)]
    w = bus_warnings(cams, usb)
    assert len(w) == 1 and "USB bus 1" in w[0] and "55.3 MB/s" in w[0]
    assert bus_warnings(cams[:2], usb) == []
    assert bus_warnings([{**c, "bus": 2} for c in cams], usb) == []  # a USB 3 bus carries them
    assert BUS_BUDGET[3] < 3 * need < BUS_BUDGET[4]


def test_discover_maps_nodes_to_buses_and_checks_a_rig(tmp_path):
    k = FakeV4L2([FakeCamera(path=str(tmp_path / "video0")), FakeCamera(path=str(tmp_path / "video2"))])
    sysfs = tmp_path / "sys"
    sysfs_tree(sysfs, "video0", 1, 4)
    sysfs_tree(sysfs, "video2", 1, 5)
    core = FakeUsbCore([usbdev(1, 1, (), 3, video=False), usbdev(1, 4, (1,), 3), usbdev(1, 5, (2,), 3),
                        usbdev(3, 2, (1,), 4, vendor=0x03E7, product=0xF63B, video=False)])
    dai = make_fake_depthai([FakeOak("OAK1")])
    rig = tmp_path / "rig.toml"
    rig.write_text(f"""
[rig]
name = "two"
[defaults]
driver = "v4l2"
width = 640
height = 480
fps = 30
pixel_format = "YUYV"
[[camera]]
id = "a"
device = "{tmp_path / 'video0'}"
position = [0.0, 0.0, 0.0]
[[camera]]
id = "b"
device = "{tmp_path / 'video2'}"
position = [0.05, 0.0, 0.0]
[[camera]]
id = "c"
device = "{tmp_path / 'video2'}"
position = [0.1, 0.0, 0.0]
""")
    found = discover(load_rig(rig), v4l2_paths=[str(tmp_path / "video0"), str(tmp_path / "video2")], v4l2_sys=k,
                     dai=dai, usb_core=core, sysfs=sysfs)
    assert [(n["usb_bus"], n["usb_address"]) for n in found["v4l2"]] == [(1, 4), (1, 5)]
    assert found["depthai"][0]["id"] == "OAK1"
    assert any(d["oak"] for d in found["usb"])
    assert len(found["warnings"]) == 1 and "a, b, c" in found["warnings"][0]
    text = starter_rig(found, name="found")
    p = tmp_path / "starter.toml"
    p.write_text(text)
    r = load_rig(p)
    assert [c.driver for c in r.cameras] == ["v4l2", "v4l2", "depthai", "depthai"]
    assert r.cameras[0].pixel_format == "GREY" and (r.cameras[0].width, r.cameras[0].height) == (640, 480)
    assert r.cameras[2].device == "OAK1/CAM_B"


def test_usb_topology_without_a_backend_is_empty():
    class NoBackend:
        def find(self, find_all=False):
            raise RuntimeError("No backend available")

    assert usb_devices(NoBackend()) == []


# ----------------------------------------------------------------------------- real hardware

def _v4l2_nodes() -> list[str]:
    return sorted(glob.glob("/dev/video*"))


@pytest.mark.hardware
@pytest.mark.skipif(not _v4l2_nodes(), reason="no V4L2 device (/dev/video*)")
def test_hardware_v4l2_lists_and_streams(tmp_path):
    import numpy as np

    from capture.v4l2 import V4L2Source, list_v4l2_devices
    from polycam.rig import CameraSpec

    nodes = list_v4l2_devices()
    assert nodes, "a /dev/video* node exists but none is a capture device"
    n = nodes[0]
    fmt = next(f for f in n["formats"] if f["fourcc"] in ("GREY", "YUYV", "MJPG"))
    m = fmt["modes"][0]
    cam = CameraSpec(id="hw", driver="v4l2", device=n["path"], width=m["width"], height=m["height"],
                     fps=m["fps"][0], pixel_format=fmt["fourcc"], position=np.zeros(3), rotation=np.zeros(3))
    src = V4L2Source([cam])
    src.start()
    try:
        frames = []
        for _ in range(50):
            frames += src.read(1.0)
            if len(frames) >= 10:
                break
    finally:
        src.stop()
    ts = [f.timestamp_ns for f in frames]
    assert len(frames) >= 10 and all(b > a for a, b in zip(ts, ts[1:]))
    import time

    assert abs(ts[-1] - time.monotonic_ns()) < 5e9  # kernel timestamps are CLOCK_MONOTONIC


def _oaks() -> list:
    try:
        from capture.oak import list_depthai_devices

        return list_depthai_devices()
    except Exception:  # noqa: BLE001
        return []


@pytest.mark.hardware
@pytest.mark.skipif(not _oaks(), reason="no OAK device")
def test_hardware_oak_streams_host_synced_frames():
    import time

    import numpy as np

    from capture.oak import DepthAISource
    from polycam.rig import CameraSpec

    cam = CameraSpec(id="oak", driver="depthai", device="CAM_B", width=640, height=400, fps=30.0,
                     pixel_format="GREY", position=np.zeros(3), rotation=np.zeros(3))
    src = DepthAISource([cam])
    src.start()
    try:
        frames = []
        for _ in range(100):
            frames += src.read(0.5)
            if len(frames) >= 10:
                break
    finally:
        src.stop()
    assert len(frames) >= 10
    assert abs(frames[-1].timestamp_ns - time.monotonic_ns()) < 5e9
