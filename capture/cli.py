"""The capture stage's verbs: ``polycam capture``, ``polycam replay``, ``polycam devices``.

Registered by :func:`add_parsers` (polycam/cli.py discovers this module).
Nothing heavy is imported at module level; handlers import what they need.
docs/capture.md documents the options.
"""

from __future__ import annotations

import argparse
import signal
import sys
import threading
from contextlib import contextmanager
from pathlib import Path

from polycam.cliargs import nonneg_int as _nonneg_int
from polycam.cliargs import positive_float as _positive_float
from polycam.cliargs import positive_int as _positive_int

__all__ = ["add_parsers", "cmd_capture", "cmd_replay", "cmd_devices"]


@contextmanager
def _stop_on_signals():
    """Ctrl-C (SIGINT) and SIGTERM set the yielded event (a clean stop); a second Ctrl-C aborts."""
    stop = threading.Event()
    previous = {}

    def handler(signum, frame):
        if stop.is_set() and signum == signal.SIGINT:
            raise KeyboardInterrupt
        stop.set()

    for sig in (signal.SIGINT, signal.SIGTERM):
        try:
            previous[sig] = signal.signal(sig, handler)
        except ValueError:  # not the main thread
            pass
    try:
        yield stop
    finally:
        for sig, h in previous.items():
            signal.signal(sig, h)


def _limits(p: argparse.ArgumentParser) -> None:
    g = p.add_mutually_exclusive_group()
    g.add_argument("--frames", type=_positive_int, help="stop after N synchronised multi-frames")
    g.add_argument("--seconds", type=_positive_float, help="stop after S seconds of frames")


def _recording(p: argparse.ArgumentParser) -> None:
    p.add_argument("--overwrite", action="store_true", help="replace an existing session folder")
    p.add_argument("--strict", action="store_true",
                   help="stop (exit 1) when a camera is lost instead of recording it as missing")
    sync = p.add_mutually_exclusive_group()
    sync.add_argument("--tolerance-ms", type=_positive_float,
                      help="max timestamp spread of a multi-frame [ms] (default: half a frame period)")
    sync.add_argument("--free-running", action="store_true",
                      help="cameras without a common trigger: one image per camera per frame period, each "
                           "camera's phase tracked (drifting clocks and slower cameras too; docs/capture.md)")
    p.add_argument("--queue", type=_positive_int, default=32, help="writer queue length [multi-frames] (default 32)")
    p.add_argument("--png-threads", type=_positive_int, default=3, help="PNG encoding and writing threads (default 3)")
    p.add_argument("--no-display", action="store_true", help="no live display")


def add_parsers(sub) -> None:
    """Add the ``capture``, ``replay`` and ``devices`` verbs to polycam's subparsers."""
    pc = sub.add_parser("capture", help="record a session from a rig (V4L2, DepthAI, mock or replay cameras)",
                        description="Record a session (SPEC.md) from the cameras of a rig file. Without "
                        "--frames/--seconds it runs until Ctrl-C, which stops cleanly.")
    pc.add_argument("--rig", required=True, help="rig file RIG.toml")
    pc.add_argument("--out", required=True, help="output session folder")
    _limits(pc)
    _recording(pc)
    pc.add_argument("--fast", action="store_true",
                    help="mock and replay cameras run as fast as they can be recorded (simulated clock)")
    pc.add_argument("--buffers", type=_positive_int, default=4, help="driver buffers per camera (default 4)")
    pc.add_argument("--auto-controls", action="store_true",
                    help="leave auto exposure / gain / white balance on (default: fixed and equal)")
    pc.add_argument("--exposure", type=_positive_int,
                    help="V4L2 exposure (EXPOSURE_ABSOLUTE, 100 µs units); OAK: exposure in µs")
    pc.add_argument("--gain", type=_nonneg_int, help="V4L2 gain (device units)")
    pc.add_argument("--iso", type=_positive_int, default=400, help="OAK sensitivity with --exposure (default 400)")
    pc.add_argument("--white-balance", type=_positive_int, help="white-balance temperature [K]")
    pc.add_argument("--sync", choices=("auto", "hardware", "software"), default="auto",
                    help="OAK frame sync (default auto: hardware where supported)")
    pc.add_argument("--mock-board", metavar="BOARD.toml",
                    help="mock cameras show this calibration board moving in front of the static rig "
                         "(a board session for `polycam calibrate`) instead of the [mock] scene")
    pc.set_defaults(func=cmd_capture)

    pr = sub.add_parser("replay", help="play a recorded session back as a live rig (optionally re-recording it)",
                        description="Play SESSION back through the same frame-source interface as a live "
                        "rig: frames are regrouped by timestamp and the capture statistics printed. With "
                        "--out the replay is recorded into a new session (bit-identical frames and timestamps).")
    pr.add_argument("session", help="session folder to play back")
    pr.add_argument("--out", help="record the replay into this session folder")
    pr.add_argument("--realtime", action="store_true", help="pace frames like the recording (default: as fast as possible)")
    pr.add_argument("--speed", type=_positive_float, default=1.0, help="real-time speed factor (default 1)")
    _limits(pr)
    _recording(pr)
    pr.set_defaults(func=cmd_replay)

    pd = sub.add_parser("devices", help="list connected cameras (V4L2, OAK, USB buses) and print a starter rig file")
    pd.add_argument("--rig", help="check this rig's cameras against the USB bus bandwidth")
    pd.add_argument("--rig-template", nargs="?", const="-", metavar="FILE",
                    help="print a starter rig file for what is connected (or write it to FILE)")
    pd.set_defaults(func=cmd_devices)


def _run(source, rig, out, args, title: str) -> int:
    from .display import LiveDisplay, summary
    from .recorder import record

    tol = int(round(args.tolerance_ms * 1e6)) if args.tolerance_ms else None
    with _stop_on_signals() as stop, LiveDisplay(title, enabled=not args.no_display) as display:
        result = record(source, rig, out, frames=args.frames, seconds=args.seconds, strict=args.strict,
                        overwrite=args.overwrite, tolerance_ns=tol, free_running=args.free_running,
                        queue_frames=args.queue,
                        png_threads=args.png_threads, stop_event=stop, on_update=display)
    where = f"wrote {out}" if out is not None else f"replayed {title}"
    print(summary(result.stats, where, result.status, recorded=out is not None))
    if out is not None:
        print(f"  statistics in {Path(out) / 'capture_stats.toml'}")
    return 0


def cmd_capture(args: argparse.Namespace) -> int:
    from polycam.rig import load_rig

    rig = load_rig(args.rig)  # user files first
    mock_kwargs = {}
    if args.mock_board:
        from polycam.board import load_board
        from polycam.errors import InputError

        if not any(c.driver == "mock" for c in rig.cameras):
            raise InputError(f"--mock-board: {args.rig} has no mock cameras")
        mock_kwargs["board"] = load_board(args.mock_board)
    from .drivers import rig_source
    from .oak import DepthAIControls
    from .v4l2 import Controls

    fixed = not args.auto_controls
    source = rig_source(rig, realtime=not args.fast, buffers=args.buffers,
                        v4l2_controls=Controls(fixed=fixed, exposure=args.exposure, gain=args.gain,
                                               white_balance=args.white_balance),
                        depthai_controls=DepthAIControls(fixed=fixed, exposure_us=args.exposure, iso=args.iso,
                                                         white_balance=args.white_balance),
                        depthai_sync=args.sync, **mock_kwargs)
    code = _run(source, rig, args.out, args, f"capture {rig.name}")
    from .mock import MockSource

    if isinstance(source, MockSource) and source.has_truth:
        print(f"  ground truth (mock): {', '.join(source.write_truth(args.out))}")
    return code


def cmd_replay(args: argparse.Namespace) -> int:
    from polycam.session import open_session

    session = open_session(args.session)  # validates first
    from .replay import ReplaySource

    source = ReplaySource(session, realtime=args.realtime, speed=args.speed)
    return _run(source, session.rig, args.out, args, str(args.session))


def cmd_devices(args: argparse.Namespace) -> int:
    rig = None
    if args.rig:
        from polycam.rig import load_rig

        rig = load_rig(args.rig)
    from .devices import discover, starter_rig

    found = discover(rig)
    if args.rig_template:
        text = starter_rig(found)
        if args.rig_template == "-":
            print(text, end="")
        else:
            from polycam.tomlio import atomic_write_text

            atomic_write_text(args.rig_template, text)
            print(f"wrote starter rig {args.rig_template}", file=sys.stderr)
        return 0
    print(format_devices(found))
    return 0


def format_devices(found: dict) -> str:
    """The human-readable listing of :func:`capture.devices.discover`'s result."""
    lines = []
    nodes = found["v4l2"]
    lines.append(f"V4L2 video-capture nodes: {len(nodes) or 'none'}")
    for n in nodes:
        usb = f", USB bus {n['usb_bus']} device {n['usb_address']}" if n.get("usb_bus") is not None else ""
        lines.append(f"  {n['path']}: {n['card']} [{n['driver']}] {n['bus_info']}{usb}")
        for f in n["formats"]:
            modes = ", ".join(f"{m['width']}x{m['height']}@{'/'.join(f'{r:g}' for r in m['fps'])}"
                              for m in f["modes"])
            lines.append(f"    {f['fourcc']:4} ({f['description']}): {modes}")
    oaks = found["depthai"]
    lines.append(f"DepthAI (OAK) devices: {len(oaks) or 'none'}")
    for d in oaks:
        lines.append(f"  {d['id']} name {d['name'] or '-'} ({d['state']})")
    usb = found["usb"]
    if usb:
        lines.append("USB devices:")
        for d in sorted(usb, key=lambda d: (d["bus"], d["ports"])):
            port = ".".join(map(str, d["ports"])) or "root"
            tag = " [OAK]" if d["oak"] else (" [camera]" if d["camera"] else "")
            lines.append(f"  bus {d['bus']} port {port} addr {d['address']}: {d['vendor']:04x}:{d['product']:04x} "
                         f"{d['speed_mbps']:g} Mb/s{tag}")
    else:
        lines.append("USB topology: unavailable (pyusb needs libusb) or no devices")
    for w in found["warnings"]:
        lines.append(f"warning: {w}")
    return "\n".join(lines)
