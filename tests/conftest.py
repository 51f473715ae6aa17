"""Shared fixtures: paths, seeded RNGs and the location of ../shared/data."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[1]
SHARED_DATA = REPO.parent / "shared" / "data"


@pytest.fixture
def rng() -> np.random.Generator:
    return np.random.default_rng(12345)


@pytest.fixture
def repo() -> Path:
    return REPO


def shared_data(name: str) -> Path:
    """Path to a data set under ../shared/data, or skip the test with the reason."""
    p = SHARED_DATA / name
    if not p.exists():
        pytest.skip(f"shared data set {name!r} not found at {p}")
    return p


def mock_grid_rig_text(name: str, width: int, height: int, rows: int = 3, cols: int = 3,
                       pitch: float = 0.02) -> str:
    """A small planar mock rig (room scene, smooth motion, light noise) as rig-file text."""
    return f"""[rig]
name = "{name}"
[defaults]
driver = "mock"
width = {width}
height = {height}
fps = 30
pixel_format = "GREY"
fov_deg = 60
[grid]
rows = {rows}
cols = {cols}
pitch = {pitch}
[mock]
scene = "room"
motion = "smooth"
seed = 1
noise = 0.004
"""


def assert_one_line_error(capsys, code: int, *fragments: str) -> None:
    """A CLI call made in-process returned ``code`` 1 with exactly one stderr line
    ``polycam: error: ...`` containing every fragment."""
    err = capsys.readouterr().err
    assert code == 1, err
    lines = [l for l in err.splitlines() if l.strip()]
    assert len(lines) == 1 and lines[0].startswith("polycam: error: "), err
    for frag in fragments:
        assert frag in lines[0], err
