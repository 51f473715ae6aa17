"""MotionOptions from KEY=VALUE strings (the CLI's ``--option``)."""

from __future__ import annotations

import math
from dataclasses import replace

import pytest

from polycam.errors import InputError
from polycam.motion_options import NOISY, PRESETS, MotionOptions, changed_options, options_from_strings


def test_values_take_their_fields_types():
    opts = options_from_strings(["smooth_c=0", "eiv=ON", "whiten=on", "levels=2", "depth_gate_misfit=inf",
                                 "symmetric=no", "robust=huber"])
    assert opts.smooth_c == 0.0 and isinstance(opts.smooth_c, float)
    assert opts.eiv is True and opts.symmetric is False and opts.whiten == "on" and opts.robust == "huber"
    assert opts.levels == 2 and isinstance(opts.levels, int) and math.isinf(opts.depth_gate_misfit)
    assert changed_options(opts) == {"levels": 2, "robust": "huber", "smooth_c": 0.0, "eiv": True,
                                     "depth_gate_misfit": math.inf, "whiten": "on"}
    assert changed_options(options_from_strings([])) == {}


def test_filters_by_name_or_per_axis_and_later_items_win():
    assert options_from_strings(["filters=fs5"]).filters == "fs5"
    opts = options_from_strings(["filters=x:central, y:fs3,u:fs5,v:fs5", "levels=1", "levels=2"])
    assert opts.filters == {"x": "central", "y": "fs3", "u": "fs5", "v": "fs5"} and opts.levels == 2
    base = MotionOptions(eiv=True, levels=1)
    assert options_from_strings(["levels=3"], base) == MotionOptions(eiv=True, levels=3)


def test_presets_and_options_on_top_of_them():
    """``--preset noisy`` is the noise options of docs/motion.md; ``--option`` items override it."""
    assert PRESETS == {"default": MotionOptions(), "noisy": NOISY}
    assert changed_options(NOISY) == {"smooth_c": 0.0, "eiv": True, "model_weight": True, "model_weight_gain": 8.0,
                                      "depth_pool_views": True, "whiten": "on", "uv_taps": 14}
    assert options_from_strings(["uv_taps=6", "levels=2"], NOISY) == replace(NOISY, uv_taps=6, levels=2)


@pytest.mark.parametrize("item, fragment", [
    ("nope=1", "--option nope: not a solver option"), ("eiv=maybe", "expected true or false"),
    ("levels=2.5", "expected an integer"), ("tol=x", "expected a number"), ("tol=nan", "nan"),
    ("robust=bogus", "robust must be"), ("uv_taps=3", "uv_taps must be"), ("filters=foo", "unknown filter 'foo'"),
    ("filters=q:fs3", "axis:name pairs"), ("smooth_c", "expected KEY=VALUE"), ("levels=0", "levels"),
    ("smooth_c_resampled=-1", "smooth_c_resampled must be"),
])
def test_bad_items_give_one_line_naming_them(item, fragment):
    with pytest.raises(InputError) as e:
        options_from_strings(["eiv=true", item])
    assert fragment in str(e.value) and "\n" not in str(e.value)


def test_frames_with_confidences_take_smooth_c_resampled():
    """``for_frames``: with confidences W the discontinuity constant is ``smooth_c_resampled``."""
    opts = MotionOptions()
    assert opts.for_frames(False) is opts and opts.for_frames(True) == replace(opts, smooth_c=0.0)
    assert opts.smooth_c == 0.5 and opts.smooth_c_resampled == 0.0
    on = options_from_strings(["smooth_c_resampled=0.5"])
    assert on.for_frames(True) is on and on.for_frames(False) is on
    assert NOISY.for_frames(True) is NOISY         # already without the weight
