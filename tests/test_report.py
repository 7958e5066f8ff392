"""The figures of vdad reproduce (vdad.report): readable, labelled, nothing clipped."""

import matplotlib
import numpy as np
import pytest

from vdad import report
from vdad.reproduce import TRACE, parameter, plan

matplotlib.use("Agg")

SIZES = {"pendulum": lambda a: a.get("n_bodies", 20),
         "hanging_dogs": lambda a: 16 * a.get("n_dogs", 100), "falling_character": lambda a: 29}


def _rows(configs, seed=0):
    """Results of every shape the writers meet: errors from 0 over three decades,
    speed-ups from 0.02 to 40, one diverged run."""
    rng = np.random.default_rng(seed)
    out = []
    for k, c in enumerate(configs):
        joints = SIZES[c["scene"]](c["scene_args"])
        dca = c["method"] == "dca"
        err = 0.0 if dca or k % 5 == 0 else float(10 ** rng.uniform(-2, 1.5))
        active = joints if dca else float(rng.integers(0, joints + 1))
        t = np.linspace(0.0, 1.0, 5)
        out.append({"config": c, "ms_per_step": 0.01 + 0.001 * active,
                    "reference_ms_per_step": 0.02 * joints, "speedup": 10 ** rng.uniform(-1.7, 1.6),
                    "active_joints": active, "node_visits": 2 * active, "joints": joints,
                    "steps": 50, "failure": "diverged" if k == 3 else "",
                    "error": {m: {"mean": err, "max": 2 * err, "sum": 5 * err} for m in TRACE[1:]},
                    "trace": {"t": t.tolist(), **{m: (err * t).tolist() for m in TRACE[1:]}}})
    return out


@pytest.fixture
def figures(monkeypatch):
    """The figures the writers save, with their titles, drawn but kept open."""
    saved = []

    def keep(plt, fig, title, path):
        fig.suptitle(title)
        fig.canvas.draw()
        saved.append((title, fig))
        return path

    monkeypatch.setattr(report, "_save", keep)
    yield saved
    import matplotlib.pyplot as plt

    plt.close("all")


def test_symlog_ticks_run_from_zero_to_the_largest_value():
    assert report.symlog_ticks(50, 1.0) == [0, 1, 2, 5, 10, 20, 50]
    assert report.symlog_ticks(3.4, 0.1) == [0, 0.1, 0.2, 0.5, 1, 3.4]
    assert report.symlog_ticks(0.05, 0.1) == [0, 0.05]
    wide = report.symlog_ticks(3e5, 1.0)                  # one tick a decade past two
    assert wide == [0, 1, 10, 100, 1e3, 1e4, 1e5, 3e5]


@pytest.mark.parametrize("name", ["figure8", "figure9", "speed_vs_error"])
def test_figures_name_their_scene_label_their_points_and_clip_none(name, figures, tmp_path):
    rows = _rows(plan(True)[name])
    getattr(report, f"write_{name}")(rows, tmp_path)
    assert figures
    for title, fig in figures:
        scenes = {r["config"]["scene"] for r in rows}
        assert any(f"{s} (" in title and " bodies)" in title for s in scenes), title
        for ax in fig.axes:
            for axis in (ax.xaxis, ax.yaxis):            # values can be read off each axis
                lo, hi = sorted(axis.get_view_interval())
                shown = [t for t in axis.get_majorticklocs() if lo <= t <= hi]
                assert len(shown) >= 3, (title, ax.get_xlabel(), ax.get_ylabel())
            legend = ax.get_legend()                      # no entry without a line
            if legend is not None:                        # (long labels wrapped)
                drawn = {line.get_label() for line in ax.get_lines() if len(line.get_xdata())}
                entries = {t.get_text().replace("\n", " ") for t in legend.get_texts()}
                assert entries <= drawn, title
            x0, x1 = sorted(ax.get_xlim())
            y0, y1 = sorted(ax.get_ylim())
            for line in ax.get_lines():
                if line.get_linestyle() == "--":          # reference lines span the axes
                    continue
                x = np.asarray(line.get_xdata(), float)
                y = np.asarray(line.get_ydata(), float)
                ok = np.isfinite(x) & np.isfinite(y)
                if ax.get_xscale() == "log":
                    ok &= x > 0
                if ax.get_yscale() == "log":
                    ok &= y > 0
                assert np.all((x[ok] > x0) & (x[ok] < x1) & (y[ok] > y0) & (y[ok] < y1)), title
    if name == "speed_vs_error":                          # each point names its parameter
        title, fig = figures[0]
        ax = fig.axes[0]
        labels = {t.get_text() for t in ax.texts}
        runs = [r for r in rows if r["config"]["scene"] in title and not r["failure"]
                and r["config"]["method"] != "dca"]
        assert {report._num(parameter(r["config"])) for r in runs} <= labels
