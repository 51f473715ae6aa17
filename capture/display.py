"""The live capture display (per-camera fps, drops, sync spread) and the end-of-run summary.

On a terminal, :class:`LiveDisplay` redraws a rich table on stderr; otherwise
it writes one status line to stderr every ``interval`` seconds. The summary
is plain text for stdout.
"""

from __future__ import annotations

import sys
import time

from .stats import CaptureStats

__all__ = ["LiveDisplay", "summary", "free_running_hint", "FREE_RUNNING_MISSING"]


def _table(stats: CaptureStats, title: str):
    from rich.table import Table

    snap = stats.snapshot()
    sp = snap["spread_ms"]
    t = Table(title=title, caption=f"multi-frames {snap['multiframes']} (written {snap['written']}, "
              f"complete {snap['complete']}) · spread p50 {sp['p50']:.2f} ms p99 {sp['p99']:.2f} ms · "
              f"writer queue {snap['queue']}/{snap['queue_size']} · {snap['duration_s']:.1f} s",
              title_justify="left", caption_justify="left")
    for col in ("camera", "fps", "frames", "dropped", "late", "overflow", "missing", "state"):
        t.add_column(col, justify="left" if col in ("camera", "state") else "right")
    for cam, c in snap["cameras"].items():
        bad = c["dropped"] + c["late"] + c["overflow"]
        t.add_row(cam, f"{c['fps']:.1f}", str(c["received"]), str(c["dropped"]), str(c["late"]),
                  str(c["overflow"]), str(c["missing"]),
                  f"[red]lost: {c['lost']}[/red]" if c["lost"] else ("[yellow]drops[/yellow]" if bad else "ok"))
    return t


class LiveDisplay:
    """Callable for :func:`capture.recorder.record`'s ``on_update``; use as a context manager."""

    def __init__(self, title: str, enabled: bool = True, interval: float = 5.0, stream=None):
        self.title = title
        self.stream = stream if stream is not None else sys.stderr
        self.tty = enabled and self.stream.isatty()
        self.enabled = enabled
        self.interval = interval
        self._live = None
        self._last = 0.0

    def __enter__(self) -> "LiveDisplay":
        if self.tty:
            from rich.console import Console
            from rich.live import Live

            self._live = Live(console=Console(file=self.stream), refresh_per_second=4, transient=False)
            self._live.__enter__()
        return self

    def __call__(self, stats: CaptureStats) -> None:
        if not self.enabled:
            return
        if self._live is not None:
            self._live.update(_table(stats, self.title))
            return
        now = time.monotonic()
        if now - self._last >= self.interval:
            self._last = now
            s = stats.snapshot()
            fps = [c["fps"] for c in s["cameras"].values()]
            drops = sum(c["dropped"] + c["late"] + c["overflow"] for c in s["cameras"].values())
            print(f"{self.title}: {s['written']} frames written, fps {min(fps, default=0):.1f}-"
                  f"{max(fps, default=0):.1f}, drops {drops}, spread p99 {s['spread_ms']['p99']:.2f} ms",
                  file=self.stream, flush=True)

    def __exit__(self, *exc) -> None:
        if self._live is not None:
            self._live.__exit__(*exc)
            self._live = None


def summary(stats: CaptureStats, where: str, status: str, recorded: bool = True) -> str:
    """End-of-run text: totals, drops, spread percentiles, problem cameras. ``recorded``: the
    multi-frames were written (else played only, as a replay without ``--out``: the count is of
    those played)."""
    sp = stats.spread_percentiles_ms()
    count = stats.written if recorded else stats.multiframes
    lines = [f"{where}: {count} multi-frames from {len(stats.cameras)} cameras in "
             f"{stats.duration_s:.1f} s (stopped by {stats.stopped_by}; status {status})",
             f"  complete multi-frames {stats.complete}/{stats.multiframes}; sync spread p50 {sp['p50']:.3f} ms, "
             f"p90 {sp['p90']:.3f} ms, p99 {sp['p99']:.3f} ms, max {sp['max']:.3f} ms "
             f"(tolerance {stats.tolerance_ns / 1e6:.2f} ms)",
             f"  frames lost: {stats.total_dropped} (driver drops, late, queue overflow, unwritten)"]
    for cam, c in stats.per_camera.items():
        bad = c.dropped + c.late + c.overflow + c.unwritten
        if bad or c.missing or c.lost:
            what = [f"{c.received} received", f"{c.recorded} recorded", f"{c.fps:.2f} fps"]
            for name in ("dropped", "late", "overflow", "unwritten", "missing"):
                if getattr(c, name):
                    what.append(f"{getattr(c, name)} {name}")
            if c.lost:
                what.append(f"lost after {c.lost_after_frames} frames ({c.lost})")
            lines.append(f"  {cam}: " + ", ".join(what))
    hint = free_running_hint(stats)
    if hint:
        lines.append("  hint: " + hint)
    return "\n".join(lines)


FREE_RUNNING_MISSING = 0.1
"""Share of the cameras' places in the multi-frames left empty from which :func:`free_running_hint`
speaks (with few frames lost and the spread at the tolerance)."""


def free_running_hint(stats: CaptureStats) -> str:
    """'' or why many multi-frames are incomplete although few frames were lost: cameras that free-run
    at their own phases, spread over more than the tolerance, are split across multi-frames (their
    grouping: ``--free-running``, :class:`capture.sync.Synchronizer`'s ``period_ns``). The places a
    slower camera leaves empty by its rate (its delivered fps against the fastest's) do not count."""
    cams = list(stats.per_camera.values())
    slots = stats.multiframes * len(cams)
    top = max((c.fps for c in cams), default=0.0)
    by_rate = sum(stats.multiframes * (1.0 - c.fps / top) for c in cams if 0 < c.fps < top) if top > 0 else 0.0
    missing = sum(c.missing for c in cams) - by_rate
    lost = sum(c.dropped + c.late + c.overflow + c.unwritten for c in cams)
    if len(cams) < 2 or slots == 0 or missing < FREE_RUNNING_MISSING * slots or missing < 2 * lost:
        return ""
    if stats.spread_percentiles_ms()["p90"] < 0.7 * stats.tolerance_ns / 1e6:
        return ""
    return (f"{100 * missing / slots:.0f}% of the cameras' places in the multi-frames are empty though "
            f"{lost} frames were lost, and the spread reaches the tolerance: the cameras seem to free-run "
            f"at their own phases; --free-running groups one image per camera per frame period, following "
            f"each camera's phase (a recorded session: polycam replay SESSION --out SESSION2 --free-running; "
            f"docs/capture.md, \"Synchronisation\")")
