"""Capture: camera drivers behind one frame-source interface, timestamp synchronisation
into multi-frames, and crash-safe recording of sessions (SPEC.md; docs/capture.md).

Drivers: :mod:`capture.v4l2` (USB webcams, direct ioctls), :mod:`capture.oak`
(DepthAI v3 / Luxonis OAK), :mod:`capture.mock` (the synthetic world of
``polycam synth``), :mod:`capture.replay` (a recorded session). Hardware SDKs
are imported only inside their drivers. Faithful fakes of the kernel and SDK
boundaries (:mod:`capture.fake_v4l2`, :mod:`capture.fake_depthai`) let every
path run without hardware.
"""

from .drivers import rig_source
from .mock import MockSource, PatternRenderer, pattern_sequence
from .recorder import CaptureResult, record
from .replay import ReplaySource
from .source import CameraLost, CaptureError, CompositeSource, Frame, FrameSource
from .stats import STATS_FILE, CameraStats, CaptureStats
from .sync import MultiFrame, Synchronizer, default_tolerance_ns

__all__ = [
    "Frame", "CameraLost", "FrameSource", "CompositeSource", "CaptureError",
    "MultiFrame", "Synchronizer", "default_tolerance_ns",
    "CameraStats", "CaptureStats", "STATS_FILE",
    "MockSource", "PatternRenderer", "pattern_sequence", "ReplaySource", "rig_source",
    "record", "CaptureResult",
]
