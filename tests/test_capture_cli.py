"""`polycam capture`, `replay` and `devices` in a subprocess: crash safety, Ctrl-C, errors."""

from __future__ import annotations

import signal
import subprocess
import sys
import time
import tomllib
from pathlib import Path

import numpy as np

from polycam.rig import load_rig
from polycam.session import open_session

REPO = Path(__file__).resolve().parents[1]


def rig_file(tmp_path: Path, extra: str = "") -> Path:
    p = tmp_path / "rig.toml"
    p.write_text(f"""
[rig]
name = "cli2x2"
[defaults]
driver = "mock"
width = 160
height = 120
fps = 30
[grid]
rows = 2
cols = 2
pitch = 0.02
[mock]
scene = "pattern"
motion = "static"
{extra}
""")
    return p


def polycam(*args: str, timeout: float = 120) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "polycam.cli", *args], capture_output=True, text=True, cwd=REPO,
                          timeout=timeout)


def start(*args: str) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "polycam.cli", *args], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, cwd=REPO)


def wait_for_frames(path: Path, n: int, proc: subprocess.Popen, timeout: float = 60.0) -> None:
    t_end = time.monotonic() + timeout
    while time.monotonic() < t_end:
        f = path / "frames.csv"
        if f.exists() and f.read_text().count("\n") > n:
            return
        if proc.poll() is not None:
            raise AssertionError(f"capture ended early: {proc.communicate()}")
        time.sleep(0.05)
    proc.kill()
    raise AssertionError("no frames recorded in time")


def test_capture_and_replay_verbs(tmp_path):
    rig = rig_file(tmp_path)
    res = polycam("capture", "--rig", str(rig), "--out", str(tmp_path / "s"), "--frames", "8", "--fast")
    assert res.returncode == 0, res.stderr
    assert "8 multi-frames from 4 cameras" in res.stdout and "status complete" in res.stdout
    s = open_session(tmp_path / "s")
    assert len(s) == 8 and s.status == "complete"
    assert tomllib.loads((tmp_path / "s" / "capture_stats.toml").read_text())["capture"]["written"] == 8
    res = polycam("replay", str(tmp_path / "s"), "--out", str(tmp_path / "r"))
    assert res.returncode == 0, res.stderr
    r = open_session(tmp_path / "r")
    np.testing.assert_array_equal(r.cam_timestamps, s.cam_timestamps)
    res = polycam("replay", str(tmp_path / "s"))       # played, not written: the count is of those played
    assert res.returncode == 0 and f"replayed {tmp_path / 's'}: 8 multi-frames" in res.stdout
    assert "wrote" not in res.stdout


def test_killed_capture_leaves_a_readable_incomplete_session(tmp_path):
    out = tmp_path / "s"
    p = start("capture", "--rig", str(rig_file(tmp_path)), "--out", str(out), "--seconds", "60")
    wait_for_frames(out, 10, p)
    p.send_signal(signal.SIGKILL)
    p.communicate(timeout=10)
    assert p.returncode == -signal.SIGKILL
    s = open_session(out)
    assert s.status == "incomplete" and len(s) >= 10
    for i in (0, len(s) - 1):
        assert all(img is not None for img in s.read_frame(i).values())


def test_ctrl_c_stops_cleanly_and_marks_the_session_complete(tmp_path):
    out = tmp_path / "s"
    p = start("capture", "--rig", str(rig_file(tmp_path)), "--out", str(out))
    wait_for_frames(out, 5, p)
    p.send_signal(signal.SIGINT)
    stdout, stderr = p.communicate(timeout=30)
    assert p.returncode == 0, stderr
    assert "stopped by interrupted" in stdout
    s = open_session(out)
    assert s.status == "complete" and len(s) >= 5
    st = tomllib.loads((out / "capture_stats.toml").read_text())
    assert st["capture"]["stopped_by"] == "interrupted" and st["capture"]["written"] == len(s)


def test_strict_capture_exits_1_with_one_line(tmp_path):
    rig = rig_file(tmp_path, "[mock.disconnect_after]\ncam01 = 3")
    res = polycam("capture", "--rig", str(rig), "--out", str(tmp_path / "s"), "--frames", "20", "--fast",
                  "--strict", "--no-display")
    assert res.returncode == 1
    errors = [l for l in res.stderr.splitlines() if l.startswith("polycam: error:")]
    assert len(errors) == 1 and "cam01 was lost" in errors[0] and "Traceback" not in res.stderr
    assert open_session(tmp_path / "s").status == "complete"


def test_capture_user_errors_are_one_line(tmp_path):
    res = polycam("capture", "--rig", str(tmp_path / "nope.toml"), "--out", str(tmp_path / "s"))
    assert res.returncode == 1 and res.stderr.strip().startswith("polycam: error:") and "nope.toml" in res.stderr
    bad = tmp_path / "v.toml"
    bad.write_text('[rig]\nname = "v"\n[[camera]]\nid = "a"\ndriver = "v4l2"\ndevice = "/dev/video99"\n'
                   'position = [0.0, 0.0, 0.0]\n')
    res = polycam("capture", "--rig", str(bad), "--out", str(tmp_path / "s2"), "--frames", "2")
    assert res.returncode == 1 and "/dev/video99" in res.stderr and "Traceback" not in res.stderr
    assert not (tmp_path / "s2").exists()  # no empty session left behind
    res = polycam("capture", "--rig", str(bad), "--out", "x", "--frames", "2", "--seconds", "1")
    assert res.returncode == 2


def test_devices_prints_a_loadable_starter_rig(tmp_path):
    res = polycam("devices")
    assert res.returncode == 0 and "V4L2 video-capture nodes" in res.stdout
    res = polycam("devices", "--rig-template", str(tmp_path / "starter.toml"))
    assert res.returncode == 0
    rig = load_rig(tmp_path / "starter.toml")
    assert rig.cameras


def test_help_stays_light():
    code = ("import sys, argparse; import capture.cli as c; c.add_parsers(argparse.ArgumentParser().add_subparsers()); "
            "print(sorted(m for m in ('depthai','usb','cv2','numpy','capture.recorder','capture.v4l2') "
            "if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=REPO)
    assert out.stdout.strip() == "[]"
