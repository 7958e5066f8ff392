"""Tables, figures and the Markdown report of :func:`vdad.reproduce.reproduce`.

Every writer takes the experiment's rows (a run's result with its ``config``)
and the output folder, and returns the files it wrote: Markdown and CSV tables,
PNG figures (matplotlib, loaded here only), and ``report.md`` that sets the
numbers beside the paper's (Kim 2008 Table 1, Figures 6, 8 and 9).
"""

from __future__ import annotations

import csv
import textwrap
from pathlib import Path

import numpy as np

from .reproduce import CURVES, FAMILIES, PAPER, TRACE, curve, family, parameter

MEASURES = (("mean_px", "mean screen displacement (px)"),
            ("differing_pixels", "differing pixels per frame"))


def write_csv(path, header, rows) -> Path:
    """A CSV file with ``header`` and ``rows`` (lists); returns its path."""
    with open(path, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(header)
        w.writerows(rows)
    return Path(path)


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _save(plt, fig, title, path):
    """Title, lay out, write and close ``fig``; returns ``path``."""
    fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return Path(path)


def _legend_beside(ax):
    """The legend to the right of ``ax``, outside it, where it hides no point; long
    labels wrapped, so that it does not squeeze the panels."""
    handles, labels = ax.get_legend_handles_labels()
    ax.legend(handles, [textwrap.fill(label, 48) for label in labels], fontsize=7,
              loc="upper left", bbox_to_anchor=(1.02, 1.0), borderaxespad=0.0)


def _scene_label(rows, scene=None):
    """``"pendulum (300 bodies)"``: the scene of ``rows`` (of ``scene`` if given) and
    its size, the joints of its runs (one joint per body)."""
    mine = [r for r in rows if scene is None or r["config"]["scene"] == scene]
    name = scene or mine[0]["config"]["scene"]
    sizes = sorted({r["joints"] for r in mine if r.get("joints")})
    return f"{name} ({'/'.join(str(n) for n in sizes)} bodies)" if sizes else name


def symlog_ticks(hi, linthresh):
    """Ticks of a symlog axis from 0 to ``hi`` (> 0) linear below ``linthresh``: 0,
    then 1, 2 and 5 times each power of ten from ``linthresh`` (every power once
    there are more than two decades) below ``hi``, then ``hi``."""
    ticks, decade = [0.0], linthresh
    steps = (1, 2, 5) if np.log10(max(hi, linthresh) / linthresh) <= 2 else (1,)
    while decade < hi:
        ticks += [k * decade for k in steps if k * decade < 0.5 * hi]
        decade *= 10
    return ticks + [float(hi)]


def _readable(ax, x=None, y=None):
    """Ticks people can read on ``ax`` (call it after plotting): a symlog axis named
    by ``x``/``y`` as ``("symlog", values)`` is linear from 0 up to the power of ten
    at or below the smallest positive value (within 1e-3 .. 1) and gets the ticks
    of :func:`symlog_ticks` up to the largest; a ``("log",)`` axis gets ticks at 1,
    2, 3 and 5 per decade (each digit within less than a decade, 1, 2, 5 past two,
    one a decade past five), or those given as ``("log", ticks)``; ticks are
    labelled as plain numbers. A linear axis gets about eight ticks. Every point
    keeps a margin from the edges; a log axis over a single value spans a decade
    around it."""
    from matplotlib import ticker

    plain = ticker.FuncFormatter(lambda v, _: f"{v:.3g}")
    for axis, spec in ((ax.xaxis, x), (ax.yaxis, y)):
        if spec is None:
            axis.set_major_locator(ticker.MaxNLocator(nbins=8))
            continue
        if spec[0] == "symlog":
            values = np.asarray([v for v in spec[1] if np.isfinite(v) and v > 0], float)
            linthresh = 10.0 ** np.clip(np.floor(np.log10(values.min())), -3, 0) if len(
                values) else 1.0
            (ax.set_xscale if axis is ax.xaxis else ax.set_yscale)(
                "symlog", linthresh=linthresh, linscale=0.5)
            hi = values.max() if len(values) else linthresh
            axis.set_major_locator(ticker.FixedLocator(symlog_ticks(hi, linthresh)))
            (ax.set_xlim if axis is ax.xaxis else ax.set_ylim)(     # 0 and hi inside
                -0.3 * linthresh, 1.5 * max(hi, linthresh))
        else:
            lim = ax.dataLim.intervalx if axis is ax.xaxis else ax.dataLim.intervaly
            if 0 < lim[0] and lim[1] <= lim[0] * (1 + 1e-9):   # one value: a decade
                (ax.set_xlim if axis is ax.xaxis else ax.set_ylim)(lim[0] / 3, lim[1] * 3)
            (ax.set_xscale if axis is ax.xaxis else ax.set_yscale)("log")
            span = np.log10(lim[1] / lim[0]) if 0 < lim[0] <= lim[1] < np.inf else 3.0
            subs = (np.arange(1.0, 10.0) if span < 1 else (1.0, 2.0, 3.0, 5.0) if span < 2
                    else (1.0, 2.0, 5.0) if span < 5 else (1.0,))
            axis.set_major_locator(ticker.FixedLocator(spec[1]) if len(spec) > 1 else
                                   ticker.LogLocator(subs=subs, numticks=40))
        axis.set_minor_locator(ticker.NullLocator())
        axis.set_major_formatter(plain)
    ax.margins(0.06)


def _label_points(ax, xs, ys, values, color):
    """Each point of a family labelled with its swept parameter."""
    for x, y, v in zip(xs, ys, values, strict=True):
        if np.isfinite(x) and np.isfinite(y):
            ax.annotate(_num(v), (x, y), textcoords="offset points", xytext=(3, 4),
                        fontsize=6, color=color)


def _err(row, measure="mean_px", stat="mean"):
    value = row["error"][measure][stat]
    return np.nan if value is None else value


def _num(x, digits=3):
    if x is None or (isinstance(x, float) and not np.isfinite(x)):
        return "-"
    return f"{x:.{digits}g}"


def _minus(x, y):
    return None if x is None else x - y


def _failed(row):
    return f"diverged at step {row['steps'] + 1}" if row["failure"] else ""


def _table(header, rows):
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    return lines + ["| " + " | ".join(str(c) for c in r) + " |" for r in rows]


# --- Table 1 ---------------------------------------------------------------------------

def table1(rows):
    """Header and rows of Table 1 (20-body pendulum), ours beside the paper's."""
    header = ["method", "threshold", "ms/step", "speed-up over DCA", "active joints",
              "mean px error", "differing px/frame", "paper ms", "paper active joints",
              "paper speed-up"]
    out = []
    for r in rows:
        m = r["config"]["method"]
        paper = PAPER["table1"].get(m)
        out.append([curve(r["config"]), _num(parameter(r["config"])), _num(r["ms_per_step"]),
                    _num(r["speedup"]), _num(r["active_joints"]), _num(_err(r)),
                    _num(_err(r, "differing_pixels")),
                    *(("-",) * 3 if paper is None else
                      (paper[0], paper[1], _num(PAPER["table1"]["dca"][0] / paper[0])))])
    return header, out


def write_table1(rows, out):
    header, body = table1(rows)
    md = Path(out) / "table1.md"
    md.write_text("\n".join(["# Table 1: 20-body pendulum", ""] + _table(header, body)) + "\n")
    return [md, write_csv(Path(out) / "table1.csv", header, body)]


# --- Figures 8 and 9 -------------------------------------------------------------------

def _sweep_figure(rows, out, name, x_of, xlabel, title):
    """Active joints, time per step and measured mean screen error against
    ``x_of(config)`` per view method and pixels rule (:data:`CURVES`)."""
    plt = _pyplot()
    dca = [r for r in rows if r["config"]["method"] == "dca"]
    header = ["method", xlabel, "active joints", "node visits", "ms/step", "DCA ms/step",
              "speed-up", "mean px error", "differing px/frame", "failure"]
    table = []
    fig, axes = plt.subplots(1, 3, figsize=(15, 4))
    for m in CURVES:
        mine = sorted((r for r in rows if curve(r["config"]) == m),
                      key=lambda r: x_of(r["config"]))
        if not mine:                             # a family this figure does not run
            continue
        for r in mine:
            table.append([m, x_of(r["config"]), r["active_joints"], r["node_visits"],
                          r["ms_per_step"], r["reference_ms_per_step"], r["speedup"], _err(r),
                          _err(r, "differing_pixels"), _failed(r)])
        ok = [r for r in mine if not r["failure"]]
        bad = [r for r in mine if r["failure"]]
        for ax, key in zip(axes, ("active_joints", "ms_per_step", None), strict=True):
            value = _err if key is None else (lambda r, key=key: r[key])
            line, = ax.plot([x_of(r["config"]) for r in ok], [value(r) for r in ok], "o-",
                            label=m)
            if bad:
                ax.plot([x_of(r["config"]) for r in bad], [value(r) for r in bad], "x",
                        color=line.get_color(), label=f"{m} (diverged)")
    joints = max([r["joints"] or 1 for r in rows] + [1])
    axes[0].axhline(joints, color="k", ls="--", lw=1, label="all joints")
    reference = [r["ms_per_step"] for r in dca if r["ms_per_step"] is not None]
    label = "full DCA"
    if not reference:               # each run's own full-DCA reference, timed beside it
        reference = [r["reference_ms_per_step"] for r in rows
                     if r["reference_ms_per_step"] is not None]
        label = "full DCA (median of the runs' references)"
    if reference:
        axes[1].axhline(float(np.median(reference)), color="k", ls="--", lw=1, label=label)
    xs = sorted({x_of(r["config"]) for r in rows if r["config"]["method"] != "dca"})
    # log axes: the active joints and the times span decades, and the reference
    # lines (all joints, the DCA) would squeeze linear curves into a tenth
    _readable(axes[0], ("log", xs), ("symlog", [1.0, joints]))   # from no joint to all
    _readable(axes[1], ("log", xs), ("log",))
    errors = [_err(r) for r in rows if r["config"]["method"] != "dca"]
    _readable(axes[2], ("log", xs), ("symlog", [e for e in errors if e is not None]))
    for ax, ylabel in zip(axes, ("active joints (0, then log)", "ms per step (log)",
                                 "mean screen error, px (0, then log)"), strict=True):
        ax.set_xlabel(xlabel)
        ax.set_ylabel(ylabel)
        ax.legend(fontsize=8)
    png = _save(plt, fig, title.format(scene=_scene_label(rows)), Path(out) / f"{name}.png")
    return [png, write_csv(Path(out) / f"{name}.csv", header, table)]


def write_figure8(rows, out):
    return _sweep_figure(rows, out, "figure8", lambda c: c["options"]["threshold"],
                         "error threshold", "Figure 8: {scene} against the threshold")


def write_figure9(rows, out):
    return _sweep_figure(rows, out, "figure9", lambda c: c["scene_args"]["camera_distance"],
                         "viewer distance (m)", "Figure 9: {scene} against the viewer's distance")


# --- Figure 6: 100 hanging dogs --------------------------------------------------------

def dogs_table(rows):
    header = ["method", "threshold", "ms/step", "speed-up over DCA", "active joints",
              "active internal joints", "internal joints", "mean px error",
              "differing px/frame"]
    out = []
    for r in rows:
        n_dogs = r["config"]["scene_args"].get("n_dogs", 100)
        out.append([r["config"]["method"], _num(parameter(r["config"])), _num(r["ms_per_step"]),
                    _num(r["speedup"]), _num(r["active_joints"]),
                    _num(_minus(r["active_joints"], n_dogs)), r["joints"] - n_dogs,
                    _num(_err(r)),
                    _num(_err(r, "differing_pixels"))])
    return header, out


def write_dogs(rows, out):
    header, body = dogs_table(rows)
    p = PAPER["dogs"]
    md = Path(out) / "dogs.md"
    md.write_text("\n".join(
        ["# Figure 6: 100 hanging dogs", "",
         f"Paper: {p['active_joints']} of {p['joints']} internal joints active on average, "
         f"{p['ms_per_frame']} ms per frame (C++, 2008).", ""] + _table(header, body)) + "\n")
    return [md, write_csv(Path(out) / "dogs.csv", header, body)]


# --- speed against measured error ------------------------------------------------------

def _scenes(rows):
    return list(dict.fromkeys(r["config"]["scene"] for r in rows))


def write_speed_vs_error(rows, out):
    plt = _pyplot()
    header = ["scene", "method", "family", "parameter", "steps", "ms/step", "DCA ms/step",
              "speed-up", "active joints", "joints", "mean px (mean)", "mean px (max)",
              "mean px (sum)", "max px (max)", "differing px (mean)", "differing px (sum)",
              "failure"]
    table = [[r["config"]["scene"], r["config"]["method"], family(r["config"]),
              parameter(r["config"]), r["steps"], r["ms_per_step"],
              r["reference_ms_per_step"], r["speedup"], r["active_joints"], r["joints"],
              _err(r), _err(r, "mean_px", "max"), _err(r, "mean_px", "sum"),
              _err(r, "max_px", "max"),
              _err(r, "differing_pixels"), _err(r, "differing_pixels", "sum"), _failed(r)]
             for r in rows]
    frames = [[r["config"]["scene"], family(r["config"]), parameter(r["config"]), *values]
              for r in rows for values in zip(*(r["trace"][k] for k in TRACE), strict=True)]
    files = [write_csv(Path(out) / "speed_vs_error.csv", header, table),
             write_csv(Path(out) / "error_over_time.csv", ["scene", "family", "parameter",
                                                           *TRACE], frames)]
    for scene in _scenes(rows):
        mine = [r for r in rows if r["config"]["scene"] == scene]
        fig, axes = plt.subplots(1, 2, figsize=(13.5, 4.2))
        for ax, (measure, label) in zip(axes, MEASURES, strict=True):
            for f in FAMILIES:
                runs = sorted((r for r in mine if family(r["config"]) == f
                               and not r["failure"]), key=lambda r: parameter(r["config"]))
                if runs:                                # joined along the swept parameter
                    xs, ys = [_err(r, measure) for r in runs], [r["speedup"] for r in runs]
                    line, = ax.plot(xs, ys, "o-", label=f, ms=4)
                    _label_points(ax, xs, ys, [parameter(r["config"]) for r in runs],
                                  line.get_color())
            bad = [r for r in mine if r["failure"]]
            if bad:
                ax.plot([_err(r, measure) for r in bad], [r["speedup"] for r in bad], "kx",
                        label="diverged (until then)")
            ax.axhline(1.0, color="k", ls="--", lw=1)
            errors = [_err(r, measure) for r in mine]
            speedups = [r["speedup"] for r in mine if r["speedup"] and r["speedup"] > 0]
            wide = bool(speedups) and max(speedups) > 10 * min(speedups)   # log past a decade
            _readable(ax, ("symlog", errors), ("log",) if wide else None)
            ax.set_xlabel(label + ", mean over frames (0, then log)")
            ax.set_ylabel("speed-up over full DCA" + (" (log)" if wide else ""))
        _legend_beside(axes[1])
        files += [_save(plt, fig, f"{_scene_label(mine)}: speed-up against measured visual "
                             "error (points: threshold, distance or sleep speed)",
                        Path(out) / f"speed_vs_error_{scene}.png"),
                  _write_error_over_time(mine, out, scene, plt)]
    return files


def _write_error_over_time(rows, out, scene, plt):
    """The error over time of each family's run of median error."""
    fig, axes = plt.subplots(1, 2, figsize=(13.5, 4.2))
    for f in FAMILIES:
        mine = sorted((r for r in rows if family(r["config"]) == f), key=lambda r: _err(r))
        if not mine:
            continue
        r = mine[len(mine) // 2]
        for ax, (measure, label) in zip(axes, MEASURES, strict=True):
            ax.plot(r["trace"]["t"], [np.nan if v is None else v for v in r["trace"][measure]],
                    label=f"{f} at {_num(parameter(r['config']))}")
            ax.set_xlabel("simulated time (s)")
            ax.set_ylabel(label)
    for ax in axes:
        _readable(ax)
    _legend_beside(axes[1])
    return _save(plt, fig, f"{_scene_label(rows)}: visual error over time (each family's "
                 "median run)",
                 Path(out) / f"error_over_time_{scene}.png")


def best_under(rows, limit, measure="mean_px"):
    """{family: (speed-up, parameter)} of the fastest run of each family whose mean
    ``measure`` stays within ``limit``, that did not diverge and whose speed-up
    was measured."""
    best = {}
    for r in rows:
        if (r["failure"] or r["config"]["method"] == "dca" or not _err(r, measure) <= limit
                or r["speedup"] is None or not np.isfinite(r["speedup"])):
            continue
        f = family(r["config"])
        if f not in best or r["speedup"] > best[f][0]:
            best[f] = (r["speedup"], parameter(r["config"]))
    return best


def decreasing(xs, ys, slack=0.0):
    """Whether ``ys`` never rises by more than ``slack`` (relative) as ``xs`` grows,
    and ends below where it starts."""
    ys = np.asarray([y for _, y in sorted(zip(xs, ys, strict=True))], float)
    return bool(np.all(np.diff(ys) <= slack * np.abs(ys[:-1])) and ys[-1] < ys[0])


# --- the report ------------------------------------------------------------------------

def _trend_lines(rows, x_of, what):
    lines = []
    for m in CURVES:
        if not any(curve(r["config"]) == m for r in rows):
            continue
        mine = [r for r in rows if curve(r["config"]) == m and not r["failure"]]
        failed = sum(1 for r in rows if curve(r["config"]) == m and r["failure"])
        if len(mine) < 2:
            lines.append(f"- {m}: fewer than two runs finished ({failed} diverged).")
            continue
        xs = [x_of(r["config"]) for r in mine]
        a = decreasing(xs, [r["active_joints"] for r in mine], 0.02)
        v = decreasing(xs, [r["node_visits"] for r in mine], 0.02)
        t = decreasing(xs, [r["ms_per_step"] for r in mine], 0.10)
        lo, hi = min(mine, key=lambda r: x_of(r["config"])), max(mine, key=lambda r:
                                                                  x_of(r["config"]))
        lines.append(
            f"- {m}: as {what} grows from {_num(x_of(lo['config']))} to "
            f"{_num(x_of(hi['config']))}, active joints go {_num(lo['active_joints'])} -> "
            f"{_num(hi['active_joints'])} ({'decreasing, as the paper' if a else 'not monotone'})"
            f", node visits per step {_num(lo['node_visits'])} -> {_num(hi['node_visits'])} "
            f"({'decreasing' if v else 'not monotone'}), "
            f"ms per step {_num(lo['ms_per_step'])} -> {_num(hi['ms_per_step'])} "
            f"({'decreasing' if t else 'not monotone'}), mean screen error "
            f"{_num(_err(lo))} -> {_num(_err(hi))} px; {failed} run(s) diverged.")
    return lines


def write_report(rows, out, quick):
    out = Path(out)
    lines = ["# vdad reproduction of Kim, Redon and Kim 2008", "",
             ("Quick run (`vdad reproduce --quick`): short runs and thin sweeps; the trends, "
              "not the values, are meant." if quick else
              "Full run (`vdad reproduce`)."),
             "Every run is measured beside a full-DCA reference from the same initial state, "
             "forces, time step and integrator, timed in the same process; visual error: "
             "(a) screen displacement of surface points, (b) pixels whose rendered body "
             "differs (the paper's §3 measure).", ""]
    if "table1" in rows:
        header, body = table1(rows["table1"])
        lines += ["## Table 1: 20-body pendulum", ""] + _table(header, body) + [
            "", "The paper's pendulum has 19 joints; ours has 20 (its first joint holds it "
            "to the world). The paper does not give its threshold: several are shown.", ""]
    for name, x_of, what, title in (
            ("figure8", lambda c: c["options"]["threshold"], "the threshold",
             "Figure 8: against the error threshold"),
            ("figure9", lambda c: c["scene_args"]["camera_distance"], "the viewer's distance",
             "Figure 9: against the viewer's distance")):
        if name in rows:
            lines += [f"## {title} (300-body pendulum)", "", f"![{name}]({name}.png)", "",
                      "The paper gives only the trend (monotone decrease); ours:", ""]
            lines += _trend_lines(rows[name], x_of, what) + [""]
    if "dogs" in rows:
        header, body = dogs_table(rows["dogs"])
        p = PAPER["dogs"]
        lines += ["## Figure 6: 100 hanging dogs", "",
                  f"Paper: {p['active_joints']} of {p['joints']} internal joints active, "
                  f"{p['ms_per_frame']} ms per frame.", ""] + _table(header, body) + [""]
    if "speed_vs_error" in rows:
        lines += ["## Speed against measured visual error", ""]
        sve = rows["speed_vs_error"]
        for scene in _scenes(sve):
            mine = [r for r in sve if r["config"]["scene"] == scene]
            lines += [f"### {scene}", "", f"![speed]({'speed_vs_error_' + scene}.png)",
                      f"![error over time]({'error_over_time_' + scene}.png)", ""]
            for limit in (1.0, 10.0):
                best = best_under(mine, limit)
                if not best:
                    lines.append(f"- No simplified run stays within {limit:g} px mean "
                                 f"displacement.")
                    continue
                ranked = sorted(best.items(), key=lambda kv: -kv[1][0])
                lines.append(f"- Within {limit:g} px mean displacement, fastest: " + "; ".join(
                    f"{f} {s:.2f}x (at {_num(p)})" for f, (s, p) in ranked) + ".")
            failed = [r for r in mine if r["failure"]]
            if failed:
                lines.append("- Diverged: " + "; ".join(
                    f"{family(r['config'])} at {_num(parameter(r['config']))} "
                    f"({_failed(r)})" for r in failed) + ".")
            lines.append("")
    path = out / "report.md"
    path.write_text("\n".join(lines) + "\n")
    return [path]
