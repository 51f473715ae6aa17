"""One frame source for a whole rig: each camera's ``driver`` picks its source.

:func:`rig_source` groups the rig's cameras by driver (and replay cameras by
session) and returns one :class:`~capture.source.FrameSource` (a
:class:`~capture.source.CompositeSource` when the rig mixes drivers). Nothing
touches a device until ``start()``.
"""

from __future__ import annotations

from typing import Any

from polycam.rig import Rig

from .source import CompositeSource, FrameSource

__all__ = ["rig_source"]


def rig_source(rig: Rig, *, realtime: bool = True, v4l2_controls=None, depthai_controls=None,
               depthai_sync: str = "auto", buffers: int = 4, v4l2_sys=None, dai=None,
               replay_speed: float = 1.0, supersample: int = 1, **mock_kwargs: Any) -> FrameSource:
    """The frame source of a rig.

    realtime: pace mock and replay cameras in real time (live drivers always are).
    v4l2_controls: :class:`capture.v4l2.Controls`; depthai_controls:
        :class:`capture.oak.DepthAIControls`; depthai_sync: ``auto``/``hardware``/``software``.
    v4l2_sys / dai: kernel and SDK boundaries (tests inject fakes).
    mock_kwargs: passed to :class:`capture.mock.MockSource` (e.g. ``frames``).
    """
    by_driver: dict[str, list] = {}
    for cam in rig.cameras:
        by_driver.setdefault(cam.driver, []).append(cam)
    sources: list[FrameSource] = []
    if "mock" in by_driver:
        from .mock import MockSource

        sources.append(MockSource(rig, by_driver["mock"], realtime=realtime, supersample=supersample,
                                  buffers=buffers, **mock_kwargs))
    if "v4l2" in by_driver:
        from .v4l2 import V4L2Source

        sources.append(V4L2Source(by_driver["v4l2"], controls=v4l2_controls, buffers=buffers, sys=v4l2_sys))
    if "depthai" in by_driver:
        from .oak import DepthAISource

        kw = {} if dai is None else {"dai": dai}
        sources.append(DepthAISource(by_driver["depthai"], controls=depthai_controls, sync=depthai_sync, **kw))
    if "replay" in by_driver:
        from .replay import ReplaySource, parse_replay_device

        base = rig.path.parent if rig.path is not None else None
        sessions: dict[str, dict[str, str]] = {}
        for cam in by_driver["replay"]:
            path, src = parse_replay_device(cam.device, cam.id, base)
            sessions.setdefault(str(path), {})[cam.id] = src
        for path, mapping in sessions.items():
            sources.append(ReplaySource(path, mapping, realtime=realtime, speed=replay_speed))
    if len(sources) == 1:
        return sources[0]
    return CompositeSource(sources)
