import numpy as np
import pytest

from polycam.errors import InputError
from polycam.evaluate import ate_rmse, pair_errors
from polycam.geometry import T_from_rt
from polycam.trajectory import Trajectory


def traj(rts):
    ts = np.arange(len(rts), dtype=np.int64) * 33_000_000
    return Trajectory.from_relative(ts, T_from_rt(np.asarray(rts[1:], float)))


def test_identical_trajectories_have_zero_error():
    rts = [[0] * 6] + [[0.01, -0.002, 0.003, 0.001, 0.0, 0.004]] * 4
    a = traj(rts)
    e = pair_errors(a, a)
    assert np.allclose(e.t_err, 0) and np.allclose(e.w_err, 0, atol=1e-7)
    assert ate_rmse(a, a) == pytest.approx(0.0, abs=1e-12)


def test_known_errors():
    # mrcal rt order: rotation vector, then translation
    true = traj([[0] * 6] + [[0, 0, 0, 0, 0, 0.01]] * 3)
    est = traj([[0] * 6] + [[0, 0, 0.001, 0, 0, 0.0101]] * 3)
    e = pair_errors(est, true)
    assert np.allclose(e.t_rel, 0.01, atol=1e-9)
    assert np.allclose(e.w_err, 0.001, atol=1e-9)
    assert ate_rmse(est, true) > 0


def test_mismatched_lengths_are_an_input_error():
    a = traj([[0] * 6] * 3)
    b = traj([[0] * 6] * 4)
    with pytest.raises(InputError, match="same timestamps"):
        pair_errors(a, b)


def test_error_plot_draws_the_reported_std_where_finite(tmp_path, monkeypatch):
    """errors.png: bars of each pair's error, marks of the norm of its reported std (none
    where a pair is unobservable: infinite std)."""
    import matplotlib.axes

    from polycam.plots import plot_pair_errors

    true = traj([[0] * 6] + [[0, 0, 0, 0, 0, 0.01]] * 3)
    est = traj([[0] * 6] + [[0, 0, 0.001, 0, 0, 0.0101]] * 3)
    std = np.full((3, 6), 1e-4)
    std[1] = np.inf
    marks = []
    plot = matplotlib.axes.Axes.plot
    monkeypatch.setattr(matplotlib.axes.Axes, "plot",
                        lambda self, x, y, *a, **k: marks.append(np.asarray(y)) or plot(self, x, y, *a, **k))
    plot_pair_errors(tmp_path / "errors.png", pair_errors(est, true), std)
    assert (tmp_path / "errors.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    t_marks, w_marks = marks
    np.testing.assert_allclose(t_marks[[0, 2]], np.sqrt(3) * 1e-4 * 1e3)    # mm
    np.testing.assert_allclose(w_marks[[0, 2]], np.degrees(np.sqrt(3) * 1e-4))
    assert np.isnan(t_marks[1]) and np.isnan(w_marks[1])


def test_error_over_std_is_the_median_ratio_of_the_norms():
    from polycam.evaluate import error_over_std

    true = traj([[0] * 6] + [[0, 0, 0, 0, 0, 0.01]] * 4)
    est = traj([[0] * 6] + [[0, 0, 0.001, 0, 0, 0.0101]] * 4)     # t off by 0.1 mm, r by 1 mrad
    err = pair_errors(est, true)
    std = np.full((4, 6), 1e-4 / np.sqrt(3))                       # norms 0.1 mm and 0.1 mrad
    std[2] = np.inf                                                 # an unobservable pair: left out
    k_t, k_r = error_over_std(err, std)
    assert k_t == pytest.approx(1.0, rel=1e-6) and k_r == pytest.approx(10.0, rel=1e-6)
    assert all(np.isnan(k) for k in error_over_std(err, np.full((4, 6), np.inf)))


def test_error_plot_greys_the_failed_pairs(tmp_path, monkeypatch):
    """errors.png with ``solved``: the failed pairs' bars are grey and the titles' medians are of
    the solved pairs ('no pair solved' without any)."""
    import matplotlib.axes

    from polycam.plots import plot_pair_errors

    true = traj([[0] * 6] + [[0, 0, 0, 0, 0, 0.01]] * 3)
    est = traj([[0] * 6, [0, 0, 0, 0, 0, 0.0101], [0, 0, 0, 0, 0, 0], [0, 0, 0, 0, 0, 0.0102]])
    bars, titles = [], []
    bar, title = matplotlib.axes.Axes.bar, matplotlib.axes.Axes.set_title
    monkeypatch.setattr(matplotlib.axes.Axes, "bar",
                        lambda self, x, h, *a, **k: bars.append((list(x), k.get("color"))) or bar(self, x, h, *a, **k))
    monkeypatch.setattr(matplotlib.axes.Axes, "set_title",
                        lambda self, t, *a, **k: titles.append(t) or title(self, t, *a, **k))
    plot_pair_errors(tmp_path / "errors.png", pair_errors(est, true), solved=np.array([True, False, True]))
    assert ([0, 2], "tab:blue") in bars and ([1], "0.75") in bars
    assert titles[0] == "median 1.50% of the true motion (2 solved pairs)"     # not the failed pair's 100 %
    bars.clear(), titles.clear()
    plot_pair_errors(tmp_path / "none.png", pair_errors(est, true), solved=np.zeros(3, bool))
    assert titles == ["no pair solved"] * 2 and all(c == "0.75" for _, c in bars)
