"""What is connected: V4L2 nodes, OAK devices, the USB bus topology, and a starter rig file.

:func:`discover` gathers:

- V4L2 video-capture nodes with their formats, sizes and rates
  (:func:`capture.v4l2.list_v4l2_devices`), each mapped to its USB bus and
  device through sysfs (``/sys/class/video4linux/videoN/device`` → the USB
  interface → ``busnum``/``devnum``);
- OAK devices (:func:`capture.oak.list_depthai_devices`);
- every USB device via pyusb (bus, address, port path, speed, ids; cameras are
  devices with a video-class interface or the Movidius/Luxonis vendor id).

:func:`bus_warnings` adds up the bandwidth the cameras need per USB bus and
warns when a bus cannot carry it. Budgets (estimates): USB 2.0 high speed
allows at most 80 % of 480 Mb/s for isochronous video, i.e. 48 MB/s per bus;
USB 3 SuperSpeed 80 % of 4 Gb/s of payload (5 Gb/s, 8b/10b), 400 MB/s; full
speed 1.2 MB/s. A camera needs ``width · height · bytes per pixel · fps``
(GREY 1, YUYV 2, Y16 2, RGB 3; MJPG counted at 1/5 of YUYV) — with a rig
file, for the rig's modes; otherwise for the node's largest uncompressed mode
at its highest rate.

:func:`starter_rig` writes a rig file (SPEC.md) for what was found, to edit
(camera positions are placeholders).

Hardware access (pyusb, depthai, ioctls, sysfs) happens only here and in the
drivers; every boundary can be injected for tests.
"""

from __future__ import annotations

import logging
import os
from pathlib import Path
from typing import Any

from polycam.rig import Rig

__all__ = ["discover", "usb_devices", "bus_warnings", "starter_rig", "camera_bandwidth", "BUS_BUDGET"]

log = logging.getLogger(__name__)

SPEED_MBPS = {1: 1.5, 2: 12.0, 3: 480.0, 4: 5000.0, 5: 10000.0}
"""pyusb speed code → signalling rate [Mb/s]."""
BUS_BUDGET = {1: 0.15e6, 2: 1.2e6, 3: 48e6, 4: 400e6, 5: 800e6}
"""pyusb speed code → bytes/s of camera payload a bus can carry (estimates; module docstring)."""
_BYTES_PER_PIXEL = {"GREY": 1.0, "Y16": 2.0, "YUYV": 2.0, "RGB": 3.0, "RGB3": 3.0, "MJPG": 0.4}
_MOVIDIUS_VENDOR = 0x03E7
_VIDEO_CLASS = 0x0E


def camera_bandwidth(width: int, height: int, fps: float, pixel_format: str) -> float:
    """Bytes per second a camera streams."""
    return width * height * _BYTES_PER_PIXEL.get(pixel_format, 2.0) * fps


def usb_devices(usb_core=None) -> list[dict[str, Any]]:
    """Every USB device: bus, address, ports, speed code, speed_mbps, vendor, product, camera flag.
    [] when pyusb has no backend (libusb missing) or is not installed."""
    if usb_core is None:
        try:
            import usb.core as usb_core
        except ImportError:
            log.info("pyusb is not installed: no USB topology")
            return []
    try:
        devs = list(usb_core.find(find_all=True))
    except Exception as e:  # noqa: BLE001 - NoBackendError, USBError: report, do not fail
        log.info("USB topology unavailable: %s", e)
        return []
    out = []
    for d in devs:
        video = False
        try:
            for cfg in d:
                for intf in cfg:
                    if intf.bInterfaceClass == _VIDEO_CLASS:
                        video = True
        except Exception:  # noqa: BLE001 - descriptors may be unreadable without permissions
            pass
        speed = int(getattr(d, "speed", 0) or 0)
        out.append({"bus": int(d.bus), "address": int(d.address),
                    "ports": tuple(getattr(d, "port_numbers", None) or ()),
                    "speed": speed, "speed_mbps": SPEED_MBPS.get(speed, 0.0),
                    "vendor": int(d.idVendor), "product": int(d.idProduct),
                    "camera": video or int(d.idVendor) == _MOVIDIUS_VENDOR,
                    "oak": int(d.idVendor) == _MOVIDIUS_VENDOR})
    return out


def _usb_of_node(path: str, sysfs: Path) -> tuple[int, int] | None:
    """(bus, device address) of a V4L2 node's USB device, from sysfs; None if not USB."""
    name = Path(os.path.realpath(path)).name
    link = sysfs / "class" / "video4linux" / name / "device"
    try:
        p = Path(os.path.realpath(link))
    except OSError:
        return None
    for d in (p, *p.parents):
        if (d / "busnum").is_file() and (d / "devnum").is_file():
            try:
                return int((d / "busnum").read_text()), int((d / "devnum").read_text())
            except (OSError, ValueError):
                return None
    return None


def _largest_mode(node: dict) -> tuple[int, int, float, str] | None:
    best = None
    for f in node["formats"]:
        code = f["fourcc"]
        for m in f["modes"]:
            fps = max(m["fps"], default=0.0)
            bw = camera_bandwidth(m["width"], m["height"], fps, code)
            if best is None or bw > best[0]:
                best = (bw, (m["width"], m["height"], fps, code))
    return best[1] if best else None


def bus_warnings(cameras: list[dict[str, Any]], usb: list[dict[str, Any]]) -> list[str]:
    """Warnings for USB buses whose cameras need more than the bus can carry.

    cameras: dicts with ``name``, ``bus`` (int or None) and ``bandwidth`` [B/s].
    usb: :func:`usb_devices` entries (for the speed of each bus: its fastest device;
    a root hub reports the bus speed).
    """
    speed: dict[int, int] = {}
    for d in usb:
        speed[d["bus"]] = max(speed.get(d["bus"], 0), d["speed"])
    need: dict[int, list[dict]] = {}
    for c in cameras:
        if c.get("bus") is not None:
            need.setdefault(c["bus"], []).append(c)
    out = []
    for bus, cams in sorted(need.items()):
        total = sum(c["bandwidth"] for c in cams)
        budget = BUS_BUDGET.get(speed.get(bus, 3), BUS_BUDGET[3])
        if total > budget:
            names = ", ".join(c["name"] for c in cams)
            out.append(f"USB bus {bus} ({SPEED_MBPS.get(speed.get(bus, 3), 480):g} Mb/s) carries {len(cams)} "
                       f"camera(s) needing {total / 1e6:.1f} MB/s but can take about {budget / 1e6:.0f} MB/s "
                       f"({names}): expect dropped frames; spread the cameras over more buses (controllers), "
                       "use MJPG or lower the rate or size")
    return out


def discover(rig: Rig | None = None, *, v4l2_paths: list[str] | None = None, v4l2_sys=None, dai=None,
             usb_core=None, sysfs: str | os.PathLike = "/sys") -> dict[str, Any]:
    """Everything :mod:`capture.devices` reports (see the module docstring).

    Returns ``{"v4l2": [...], "depthai": [...], "usb": [...], "warnings": [...]}``; each V4L2
    entry gains ``usb_bus`` / ``usb_address`` when sysfs maps it to a USB device.
    With ``rig``, bandwidths are those of the rig's V4L2 cameras (matched by device path).
    """
    from .oak import list_depthai_devices
    from .v4l2 import list_v4l2_devices

    nodes = list_v4l2_devices(v4l2_paths, sys=v4l2_sys)
    oaks = list_depthai_devices(dai)
    usb = usb_devices(usb_core)
    sysfs = Path(sysfs)
    for n in nodes:
        loc = _usb_of_node(n["path"], sysfs)
        n["usb_bus"], n["usb_address"] = loc if loc else (None, None)
    cams = []
    if rig is not None:
        real = {os.path.realpath(n["path"]): n for n in nodes}
        for c in rig.cameras:
            if c.driver != "v4l2" or not c.device:
                continue
            n = real.get(os.path.realpath(c.device))
            cams.append({"name": c.id, "bus": n["usb_bus"] if n else None,
                         "bandwidth": camera_bandwidth(c.width, c.height, c.fps, c.pixel_format)})
    else:
        for n in nodes:
            mode = _largest_mode(n)
            if mode:
                cams.append({"name": n["path"], "bus": n["usb_bus"], "bandwidth": camera_bandwidth(*mode)})
    oak_buses = [d for d in usb if d["oak"]]
    for d in oak_buses:  # an OAK streams compressed or raw frames; count one 1280x800 GREY at 30 fps per sensor pair
        cams.append({"name": f"OAK {d['bus']}-{'.'.join(map(str, d['ports']))}", "bus": d["bus"],
                     "bandwidth": camera_bandwidth(1280, 800, 30.0, "GREY") * 2})
    return {"v4l2": nodes, "depthai": oaks, "usb": usb, "warnings": bus_warnings(cams, usb)}


def _pick_mode(node: dict) -> tuple[str, int, int, float] | None:
    """A sensible default mode: GREY > YUYV > MJPG, 640x480 if offered, 30 fps if offered."""
    fmts = {f["fourcc"]: f for f in node["formats"]}
    for code, rig_fmt in (("GREY", "GREY"), ("YUYV", "YUYV"), ("MJPG", "MJPG")):
        f = fmts.get(code)
        if not f or not f["modes"]:
            continue
        modes = f["modes"]
        m = next((m for m in modes if (m["width"], m["height"]) == (640, 480)), modes[0])
        fps = 30.0 if any(abs(r - 30.0) < 0.01 for r in m["fps"]) else max(m["fps"], default=30.0)
        return rig_fmt, m["width"], m["height"], fps
    return None


def starter_rig(found: dict[str, Any], name: str = "my_rig", pitch: float = 0.05) -> str:
    """A rig file (TOML text) for the cameras in ``found`` (:func:`discover`); a mock 2x2 rig
    when nothing is connected. Positions are placeholders along +x, ``pitch`` [m] apart."""
    lines = ["# Starter rig file written by `polycam devices --rig-template`.",
             "# Edit each camera's position [m] (and rotation, the axis-angle vector [rad] of R_rig_cam)",
             "# to match the physical array; see SPEC.md \"Rig file\" and docs/capture.md.",
             "[rig]", f'name = "{name}"', ""]
    cams = []
    for n in found.get("v4l2", []):
        mode = _pick_mode(n)
        if mode is None:
            continue
        fmt, w, h, fps = mode
        cams.append(("v4l2", n["path"], fmt, w, h, fps, f'{n["card"]} ({n["bus_info"]})'))
    for d in found.get("depthai", []):
        for sock in ("CAM_B", "CAM_C"):
            cams.append(("depthai", f'{d["id"]}/{sock}', "GREY", 640, 400, 30.0,
                         f"OAK {d['id']} {sock} (mono pair of an OAK-D; adjust to the sensors it has)"))
    if not cams:
        lines += ["# No camera found: a mock 2x2 array (driver = \"mock\") to try the pipeline.",
                  "[defaults]", 'driver = "mock"', "width = 320", "height = 240", "fps = 30",
                  'pixel_format = "GREY"', "", "[grid]", "rows = 2", "cols = 2", f"pitch = {pitch:g}", "",
                  "[mock]", 'scene = "pattern"', 'motion = "static"', "seed = 0", ""]
        return "\n".join(lines)
    width = max(2, len(str(len(cams) - 1)))
    x0 = -(len(cams) - 1) * pitch / 2
    for i, (driver, dev, fmt, w, h, fps, what) in enumerate(cams):
        lines += [f"# {what}", "[[camera]]", f'id = "cam{i:0{width}d}"', f'driver = "{driver}"',
                  f'device = "{dev}"', f"width = {w}", f"height = {h}", f"fps = {fps:g}",
                  f'pixel_format = "{fmt}"', f"position = [{x0 + i * pitch:.4f}, 0.0, 0.0]", ""]
    return "\n".join(lines)
