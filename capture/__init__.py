"""Capture: camera drivers behind one frame-source interface, timestamp synchronisation
into multi-frames, and crash-safe recording of sessions (SPEC.md; docs/capture.md).

Drivers: :mod:`capture.v4l2` (USB webcams, direct ioctls), :mod:`capture.oak`
(DepthAI v3 / Luxonis OAK), :mod:`capture.mock` (the synthetic world of
``polycam synth``), :mod:`capture.replay` (a recorded session). Hardware SDKs
are imported only inside their drivers. Faithful fakes of the kernel and SDK
boundaries (:mod:`capture.fake_v4l2`, :mod:`capture.fake_depthai`) let every
path run without hardware.
"""

__all__ = [
    "Frame", "CameraLost", "FrameSource", "CompositeSource", "CaptureError",
    "MultiFrame", "Synchronizer", "default_tolerance_ns",
    "CameraStats", "CaptureStats", "STATS_FILE",
    "MockSource", "PatternRenderer", "pattern_sequence", "ReplaySource", "rig_source",
    "record", "CaptureResult",
]

_WHERE = {
    "Frame": "source", "CameraLost": "source", "FrameSource": "source", "CompositeSource": "source",
    "CaptureError": "source", "MultiFrame": "sync", "Synchronizer": "sync", "default_tolerance_ns": "sync",
    "CameraStats": "stats", "CaptureStats": "stats", "STATS_FILE": "stats", "MockSource": "mock",
    "PatternRenderer": "mock", "pattern_sequence": "mock", "ReplaySource": "replay", "rig_source": "drivers",
    "record": "recorder", "CaptureResult": "recorder",
}


def __getattr__(name: str):
    """Lazy imports, so ``polycam --help`` (which imports capture.cli) stays light."""
    if name in _WHERE:
        import importlib

        value = getattr(importlib.import_module(f".{_WHERE[name]}", __name__), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
