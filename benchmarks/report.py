"""The benchmark page of the documentation: tables and plots from ``benchmarks/results/*.json``.

``python -m benchmarks.report --out DIR [--results benchmarks/results]`` writes
``DIR/benchmarks.md`` and its plots, ``DIR/img/bench-*.png`` (linked relative to the page). One
section per benchmark it knows (:data:`SECTIONS`): what the benchmark measures and the command
that makes its file, how this file was made (from ``provenance.json``, written by
:mod:`benchmarks.record`, while the file's hash still matches), tables formatted from the JSON,
and plots. A known file that is missing gets a short note naming the command that makes it; a
file the report does not know is listed with its keys; a file that cannot be parsed is named
with the error. Every figure on the page comes from the JSON: none is written here by hand.

``make docs`` runs it as ``python -m benchmarks.report --out docs/generated``.
"""

from __future__ import annotations

import argparse
import json
import math
import re
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path

from matplotlib.figure import Figure

from benchmarks.bench_convergence import BLOCK_GOAL, COUNT_GOAL
from benchmarks.record import PROVENANCE, file_hash

__all__ = ["SECTIONS", "Section", "main", "write_report"]

ROOT = Path(__file__).resolve().parent.parent
RESULTS = ROOT / "benchmarks" / "results"
PAGE = "benchmarks.md"
IMAGES = "img"
PREFIX = "bench-"
"""Plots are ``DIR/img/bench-*.png``; earlier ones of that name are removed before writing."""
DPI = 100
WIDTH_IN = 8.0
"""Plots are 800 pixels wide."""

Table = tuple[Sequence[str], list[Sequence[str]]]
"""A Markdown table: the header, then the rows, every cell already formatted."""


@dataclass(frozen=True)
class Plot:
    """One figure of a section: its file name (without the prefix) and its alt text."""

    name: str
    alt: str
    figure: Figure


@dataclass(frozen=True)
class Section:
    """A benchmark the report knows: its results file and how to show it.

    Attributes
    ----------
    file : str
        The file's name in the results folder.
    title : str
        The section's heading.
    what : str
        One or two sentences: what the benchmark measures (Markdown).
    command : str
        The command that makes the file (its usual form).
    tables : callable
        ``tables(data) -> list of (caption, Table)``.
    plots : callable
        ``plots(data) -> list of Plot``.
    """

    file: str
    title: str
    what: str
    command: str
    tables: Callable[[object], list[tuple[str, Table]]]
    plots: Callable[[object], list[Plot]]


# ---------------------------------------------------------------------------------- formatting

def _num(value, digits: int = 2) -> str:
    """A number with ``digits`` decimals (thousands separated), '-' for None, 'inf' as such."""
    if value is None:
        return "-"
    if isinstance(value, bool):
        return "yes" if value else "no"
    if isinstance(value, int):
        return f"{value:,}"
    if math.isinf(value) or math.isnan(value):
        return str(value)
    return f"{value:,.{digits}f}"


def _sig(value, digits: int = 3) -> str:
    """A number to ``digits`` significant figures (no exponent below a million)."""
    if value is None:
        return "-"
    if value == 0 or math.isinf(value) or math.isnan(value):
        return str(value) if value else "0"
    decimals = max(0, digits - 1 - math.floor(math.log10(abs(value))))
    return f"{value:,.{decimals}f}"


def _pct(fraction, digits: int = 1, sign: bool = False) -> str:
    """A fraction as a percentage."""
    if fraction is None:
        return "-"
    return f"{100 * fraction:{'+' if sign else ''}.{digits}f} %"


def _millions(value) -> str:
    return "-" if value is None else "0" if value == 0 else f"{value / 1e6:.2f} M"


def _window(pair) -> str:
    """A window (start, end), seconds, as the scripts print it: ``3.5-3.55``."""
    return f"{round(pair[0], 6):g}-{round(pair[1], 6):g}"


def _verdict(ok) -> str:
    return "-" if ok is None else ("PASS" if ok else "FAIL")


def _cell(text: str) -> str:
    return str(text).replace("|", "\\|").replace("\n", " ")


_NUMERIC = re.compile(r"^[-+]?[\d,.]+( ?(%|ms|s|M|dB|x))?$|^-$")


def markdown_table(table: Table) -> str:
    """A Markdown table; columns of numbers right-aligned, the others left-aligned."""
    header, rows = table
    numeric = [k > 0 and bool(rows) and all(_NUMERIC.match(str(r[k]).strip()) for r in rows)
               for k in range(len(header))]
    lines = ["| " + " | ".join(_cell(h) for h in header) + " |",
             "|" + "|".join("---:" if n else ":---" for n in numeric) + "|"]
    lines += ["| " + " | ".join(_cell(c) for c in row) + " |" for row in rows]
    return "\n".join(lines)


def _figure(height_in: float = 4.5, ncols: int = 1) -> tuple[Figure, list]:
    figure = Figure(figsize=(WIDTH_IN, max(height_in, 3.0)), dpi=DPI, layout="constrained")
    axes = figure.subplots(1, ncols, squeeze=False)[0]
    for ax in axes:
        ax.grid(True, alpha=0.3)
        ax.set_axisbelow(True)
    return figure, list(axes)


def _spans_decades(values: Iterable[float], ratio: float = 20.0) -> bool:
    """Whether positive values span at least ``ratio`` (then a log axis reads better)."""
    positive = [v for v in values if v is not None and v > 0]
    return bool(positive) and max(positive) / min(positive) >= ratio


def _hbars(ax, labels: list[str], series: dict[str, list[float]], xlabel: str,
           log: bool = False, values: str | None = None) -> None:
    """Grouped horizontal bars: one group a label, one bar a series (None: no bar).

    ``log``: a log axis, with dots instead of bars (a bar's length means nothing there).
    ``values``: a format for each bar's value written at its end (e.g. ``"{:.1f}"``).
    """
    n = len(series)
    height = 0.8 / max(n, 1)
    for k, (name, vs) in enumerate(series.items()):
        ys = [i + (k - (n - 1) / 2) * height for i in range(len(labels))]
        pairs = [(y, v) for y, v in zip(ys, vs, strict=True) if v is not None]
        if not pairs:
            continue
        if log:
            ax.plot([p[1] for p in pairs], [p[0] for p in pairs], "o", color=f"C{k}",
                    label=name)
        else:
            bars = ax.barh([p[0] for p in pairs], [p[1] for p in pairs], height=height,
                           color=f"C{k}", label=name)
            if values is not None:
                ax.bar_label(bars, [values.format(p[1]) for p in pairs], padding=3,
                             fontsize="small")
    ax.set_yticks(range(len(labels)), labels)
    ax.set_ylim(len(labels) - 0.5, -0.5)
    ax.set_xlabel(xlabel)
    if log:
        ax.set_xscale("log")
    else:
        if values is not None:
            ax.margins(x=0.12)                 # room for the values, before the limits are set
        ax.set_xlim(left=0)
    if n > 1:                                   # below the plot: never over a bar
        ax.figure.legend(loc="outside lower center", ncols=n, fontsize="small")


# ------------------------------------------------------------- simulate_cost.json (cost table)

COST_STAGES = ("setup", "frames", "event render", "emulate", "event write", "per-event depth",
               "motion truth", "other")
"""``bench_sampling.py``'s stages, in its order (``STAGES`` and ``other``)."""


def _cost_stages(row: dict) -> list[str]:
    extra = [k for k in row["stages_s"] if k not in COST_STAGES]
    return [k for k in COST_STAGES if k in row["stages_s"]] + extra


def _cost_tables(rows: list[dict]) -> list[tuple[str, Table]]:
    stages = _cost_stages(rows[0]) if rows else list(COST_STAGES)
    header = ["scene", "size", "sampler", "window s", "wall s / simulated s", "w/o start",
              "events"] + [f"{s} %" for s in stages]
    body = [[r["scene"], r["size"], r["sampler"], _window(r["window_s"]),
             _num(r["wall_per_sim_s"], 1), _num(r["steady_per_sim_s"], 1), _num(r["events"])]
            + [_num(100 * r["shares"].get(s, 0.0), 1) for s in stages] for r in rows]
    variants = sorted({r.get("variant", "-") for r in rows})
    return [(f"Wall seconds per simulated second and each stage's share of the wall time "
             f"(variant {', '.join(variants)}).", (header, body))]


def _cost_plots(rows: list[dict]) -> list[Plot]:
    if not rows:
        return []
    sizes = list(dict.fromkeys(r["size"] for r in rows))
    stages = _cost_stages(rows[0])
    height = 1.2 + 0.45 * max(sum(r["size"] == s for r in rows) for s in sizes)
    figure, axes = _figure(height, len(sizes))
    colours = {s: f"C{k}" for k, s in enumerate(stages)}
    for ax, size in zip(axes, sizes, strict=True):
        mine = [r for r in rows if r["size"] == size]
        labels = [f"{r['scene']}\n{r['sampler']}" for r in mine]
        left = [0.0] * len(mine)
        for stage in stages:
            widths = [r["stages_s"].get(stage, 0.0) / (r["window_s"][1] - r["window_s"][0])
                      for r in mine]
            ax.barh(range(len(mine)), widths, left=left, color=colours[stage], label=stage)
            left = [a + b for a, b in zip(left, widths, strict=True)]
        ax.set_yticks(range(len(mine)), labels, fontsize="small")
        ax.invert_yaxis()
        ax.set_xlim(0, None)
        ax.set_xlabel("wall time per simulated second (s/s)")
        ax.set_title(f"{size}")
    handles, names = axes[0].get_legend_handles_labels()
    figure.legend(handles, names, loc="outside lower center", ncols=4, fontsize="small")
    figure.suptitle("evfuse simulate: cost per stage")
    return [Plot("simulate-cost", "evfuse simulate: wall seconds per simulated second, stacked by "
                 "stage, per scene and sampler", figure)]


# -------------------------------------------------------------------- host.json (bench_host.py)

def _host_tables(data: dict) -> list[tuple[str, Table]]:
    rows = data["rows"]
    stages = list(dict.fromkeys(k for r in rows for k in r["stages_s"]))
    header = ["case", "size", "variant", "blocks", "event render s", "emulate s",
              "event sample s", "ms / block"] + [f"`{s}` s" for s in stages]
    body = [[r["case"], f"{r['shape'][1]}x{r['shape'][0]}", r.get("variant", "-"),
             _num(r["blocks"]), _num(r["event_render_s"]), _num(r["emulate_s"]),
             _num(r["event_sample_s"]), _num(r["event_sample_ms_per_block"], 1)]
            + [_num(r["stages_s"].get(s), 3) for s in stages] for r in rows]
    negative = [f"{r['case']} ({_num(v, 3)} s)" for r in rows
                for k, v in r["stages_s"].items() if k == "rest" and v < 0]
    note = (f" `rest` is negative for {', '.join(negative)}: the timed stages sum to more than "
            "`event_sample` there, and the plot leaves it out." if negative else "")
    return [("The per-pixel sampler's host stages inside `simulate` (seconds over the window)."
             + note, (header, body))]


def _host_plots(data: dict) -> list[Plot]:
    rows = data["rows"]
    if not rows:
        return []
    stages = list(dict.fromkeys(k for r in rows for k in r["stages_s"]))
    figure, (ax,) = _figure(2.2 + 0.7 * len(rows))
    left = [0.0] * len(rows)
    for k, stage in enumerate(stages):
        widths = [max(1e3 * r["stages_s"].get(stage, 0.0) / r["blocks"], 0.0) for r in rows]
        ax.barh(range(len(rows)), widths, left=left, color=f"C{k % 10}",
                label=stage.lstrip("_"))                  # matplotlib hides "_" labels
        left = [a + b for a, b in zip(left, widths, strict=True)]
    ax.set_yticks(range(len(rows)),
                  [f"{r['case']}\n{r['shape'][1]}x{r['shape'][0]}" for r in rows])
    ax.invert_yaxis()
    ax.margins(x=0.03)
    ax.set_xlim(left=0)
    ax.set_xlabel("host time per block (ms)")
    ax.plot([1e3 * r["event_sample_s"] / r["blocks"] for r in rows], range(len(rows)), "|",
            color="black", markersize=40, markeredgewidth=2, label="event_sample (measured total)")
    ax.set_title("Per-pixel sampler: host time per block, by stage")
    handles, names = ax.get_legend_handles_labels()
    figure.legend(handles, names, loc="outside lower center", ncols=4, fontsize="small",
                  markerscale=0.3)
    return [Plot("host", "per-pixel sampler host time per block by stage", figure)]


# --------------------------------------------------------- convergence*.json (against 256 spp)

def _sweep_points(row: dict) -> list[dict]:
    """A convergence row's runs against its reference: each event_spp's, then the reference's."""
    points = row.get("event_spp_sweep") or [
        {"event_spp": row["event_spp"], "run": row["default"], "agreement": row["agreement"]}]
    reference = {"count_error": 0.0, "worst_block_error": 0.0,
                 "count": row["reference"]["events"]}
    return points + [{"event_spp": row["reference_spp"], "run": row["reference"],
                      "agreement": reference, "is_reference": True}]


def _convergence_tables(rows: list[dict]) -> list[tuple[str, Table]]:
    header = ["scene", "window s", "sampler", "events: default / reference", "count",
              "worst block (its events; blocks)", "frames PSNR", "pixel samples",
              "event render s", "goals: count, blocks, frames"]
    body = []
    for r in rows:
        a, d = r["agreement"], r["default"]
        psnr = "-" if r["frame_psnr_db"] is None else f"{_num(r['frame_psnr_db'], 1)} dB"
        body.append([r["scene"], _window(r["window_s"]), d["sampler"],
                     f"{_num(a['count'])} / {_num(a['reference_count'])}",
                     _pct(a["count_error"], sign=True),
                     f"{_pct(a['worst_block_error'])} ({_num(a['worst_block_events'])}; "
                     f"{a['blocks']})", psnr, _millions(d["pixel_samples"]),
                     _num(d["event_render_s"]),
                     ", ".join(_verdict(r["pass"].get(k)) for k in ("count", "blocks",
                                                                     "frames"))])
    spps = sorted({r["event_spp"] for r in rows})
    refs = sorted({r["reference_spp"] for r in rows})
    tables = [(f"The defaults (event camera at {', '.join(map(str, spps))} samples per pixel) "
               f"against the reference at {', '.join(map(str, refs))}.", (header, body))]
    swept = [r for r in rows if r.get("event_spp_sweep")]
    if swept:
        header = ["scene", "window s", "event spp", "events", "count", "worst block",
                  "pixel samples", "event render s"]
        body = []
        for r in swept:
            for p in _sweep_points(r):
                a = p["agreement"]
                label = (f"{p['event_spp']} (reference)" if p.get("is_reference") else
                         f"{p['event_spp']} (default)" if p.get("is_default") else
                         str(p["event_spp"]))
                body.append([r["scene"], _window(r["window_s"]), label,
                             _num(p["run"]["events"]),
                             "-" if p.get("is_reference") else _pct(a["count_error"], sign=True),
                             "-" if p.get("is_reference") else _pct(a["worst_block_error"]),
                             _millions(p["run"]["pixel_samples"]),
                             _num(p["run"]["event_render_s"])])
        tables.append(("Events against the event camera's samples per pixel (`--event-spp`), "
                       "each against the same reference. The reference runs first, with no "
                       "warm-up run of its own: its event-render seconds may include the "
                       "kernels' tracing and compilation.", (header, body)))
    return tables


def _convergence_plots(rows: list[dict]) -> list[Plot]:
    if not rows:
        return []
    figure, (left, right) = _figure(4.6 + 0.15 * ((len(rows) + 2) // 4), 2)
    blocks = []
    scenes = list(dict.fromkeys(r["scene"] for r in rows))
    seen: dict[str, int] = {}
    for r in rows:
        colour = f"C{scenes.index(r['scene']) % 10}"
        style = ("o-", "s--", "^:", "d-.")[seen.get(r["scene"], 0) % 4]  # a scene's windows
        seen[r["scene"]] = seen.get(r["scene"], 0) + 1
        points = [p for p in _sweep_points(r) if not p.get("is_reference")]
        xs = [p["event_spp"] for p in points]
        label = f"{r['scene']} {_window(r['window_s'])} s"
        left.plot(xs, [100 * p["agreement"]["count_error"] for p in points], style,
                  color=colour, label=label)
        worst = [100 * p["agreement"]["worst_block_error"] for p in points]
        blocks += worst
        right.plot(xs, worst, style, color=colour, label=label)
    reference = sorted({r["reference_spp"] for r in rows})
    ticks = sorted({p["event_spp"] for r in rows for p in _sweep_points(r)})
    left.axhline(0.0, color="black", linewidth=0.8)
    for ax in (left, right):
        ax.set_xscale("log", base=2)
        ax.set_xticks(ticks, [str(t) for t in ticks])
        ax.set_xlim(ticks[0] / 1.5, ticks[-1] * 1.5)
        ax.minorticks_off()
        ax.set_xlabel("event camera samples per pixel")
        for spp in reference:
            ax.axvline(spp, color="grey", linestyle=":", linewidth=1)
    left.axhspan(-100 * COUNT_GOAL, 100 * COUNT_GOAL, color="green", alpha=0.08,
                 label=f"goal: within {100 * COUNT_GOAL:g} %")
    right.axhline(100 * BLOCK_GOAL, color="green", linestyle="--", linewidth=1,
                  label=f"goal: {100 * BLOCK_GOAL:g} %")
    if _spans_decades(blocks):
        # Log above 1 %, linear below: a block error of exactly 0 stays on the plot.
        right.set_yscale("symlog", linthresh=1.0, linscale=0.5)
        steps = [0, 0.5, 1, 2, 5, 10, 20, 50, 100, 200, 500, 1000]
        high = max(blocks)
        right.set_yticks([v for v in steps if v <= high * 2],
                         [f"{v:g}" for v in steps if v <= high * 2])
        right.minorticks_off()
        right.set_ylim(0, high * 1.5)
    else:
        right.set_ylim(0, None)
    name = "/".join(map(str, reference))
    left.set_ylabel(f"event count vs the {name}-spp reference (%)")
    log = ", log above 1 %" if _spans_decades(blocks) else ""
    right.set_ylabel(f"worst 16x16 block error (%{log})")
    left.set_title("Event count error")
    right.set_title("Worst block (>= 100 reference events)")
    handles, names = left.get_legend_handles_labels()
    more, more_names = right.get_legend_handles_labels()
    goal = [(h, n) for h, n in zip(more, more_names, strict=True) if n.startswith("goal")]
    figure.legend(handles + [h for h, _ in goal], names + [n for _, n in goal],
                  loc="outside lower center", ncols=4, fontsize="x-small")
    figure.suptitle(f"Events against samples per pixel (dotted: the {name}-spp reference)")
    return [Plot("events-vs-spp", "event count error and worst block error against the event "
                 "camera's samples per pixel", figure)]


# --------------------------------------------------------- sampling.json (samplers' agreement)

def _sampling_tables(rows: list[dict]) -> list[tuple[str, Table]]:
    header = ["scene", "size", "window s", "sampler", "whole-frame renders", "pixel samples",
              "events", "wall s", "count", "worst block", "dt median / p95 us"]
    body = []
    for r in rows:
        for key in ("pixel", "frame"):
            run = r[key]
            a = run.get("agreement")
            body.append([r["scene"], r["resolution"], _window(r["window_s"]), key,
                         _num(run["full_renders"]), _millions(run["pixel_samples"]),
                         _num(run["events"]), _num(run["wall_s"], 1),
                         "-" if a is None else _pct(a["count_error"], 2, sign=True),
                         "-" if a is None else _pct(a["worst_block_error"]),
                         "-" if a is None else
                         f"{_sig(a['dt_median_us'], 2)} / {_sig(a['dt_p95_us'], 2)}"])
    return [("Each sampler over the same window; agreement against the frame sampler at "
             "lam / 4 (the reference) where it was run.", (header, body))]


def _sampling_plots(rows: list[dict]) -> list[Plot]:
    if not rows:
        return []
    labels = [f"{r['scene']} {r['resolution']}\n{_window(r['window_s'])} s" for r in rows]
    series = {key: [r[key]["wall_s"] for r in rows] for key in ("pixel", "frame")}
    figure, (ax,) = _figure(1.2 + 0.55 * len(rows))
    values = series["pixel"] + series["frame"]
    log = _spans_decades(values)
    _hbars(ax, labels, {"per-pixel sampler": series["pixel"], "frame sampler": series["frame"]},
           "event camera wall time (s, rendering + emulation + writing)", log=log,
           values=None if log else "{:.1f}")
    ax.tick_params(axis="y", labelsize="small")
    ax.set_title("Event camera wall time per window: per-pixel vs frame sampler")
    return [Plot("sampling", "event camera wall time per window, per-pixel against frame "
                 "sampler", figure)]


# ------------------------------------------------------------------------------- render.json

def _render_tables(data: dict) -> list[tuple[str, Table]]:
    header = ["resolution", "variant", "spp", "bare mi.render ms", "evfuse lum + depth ms",
              "overhead"]
    body = [[r["resolution"], r["variant"], _num(r["spp"]), _num(r["bare_ms"]),
             _num(r["evfuse_ms"]), _pct(r["overhead"], sign=True)] for r in data["rows"]]
    return [(f"Scene {data['scene']}, {data['frames']} frames, the best of the alternating runs.",
             (header, body))]


def _render_plots(data: dict) -> list[Plot]:
    rows = data["rows"]
    figure, (ax,) = _figure(1.5 + 0.8 * len(rows))
    _hbars(ax, [f"{r['resolution']}\n{r['spp']} spp" for r in rows],
           {"bare mi.render": [r["bare_ms"] for r in rows],
            "evfuse luminance + depth": [r["evfuse_ms"] for r in rows]},
           "time per frame (ms)", values="{:.1f}")
    ax.set_title(f"Render time per frame, {data['scene']}")
    return [Plot("render", "render time per frame, bare mi.render against evfuse", figure)]


# ------------------------------------------------------------------------------- shader.json

def _shader_tables(data: dict) -> list[tuple[str, Table]]:
    rows = [
        [f"luminance() of {_num(data['samples'])} scattered samples",
         f"{_num(data['luminance_ms'])} ms"],
        [f"luminance() of {_num(data['block_samples'])} samples sorted by pixel within "
         f"{1e3 * data['block_window_s']:g} ms", f"{_num(data['luminance_block_ms'], 1)} ms"],
        ["frame()", f"{_num(data['frame_ms'])} ms"],
        ["Renderer.luminance (mi.render), same spp", f"{_num(data['mi_render_ms'])} ms"],
        ["64 spp: mean of frame() / mean of mi.render", _num(data["mean_ratio"], 4)],
        ["64 spp: median per-pixel relative difference, frame() vs mi.render",
         _pct(data["median_relative"], 2)],
        ["64 spp: the same, mi.render vs mi.render at another seed",
         _pct(data["median_relative_other_seed"], 2)],
    ]
    return [(f"{data['scene']} at {data['resolution']}, {data['variant']}, {data['spp']} spp, "
             "warm.", (["measure", "value"], rows))]


# ---------------------------------------------------------------------- events_vs_esim.json

def _esim_tables(data: dict) -> list[tuple[str, Table]]:
    summary = data["summary"]
    if data["esim_py"] is None:
        return [(f"esim_py was absent ({data['esim_py_absent_because']}): evfuse alone.",
                 (["sensor", "events", "evfuse Mev/s", "1 thread Mev/s"],
                  [[size, _num(e["events"]), _num(e["evfuse_mev_per_s"]),
                    _num(e["evfuse_1t_mev_per_s"])] for size, e in summary.items()]))]
    header = ["sensor", "events", "esim_py Mev/s", "evfuse Mev/s", "evfuse / esim_py (min-max)",
              "1 thread / esim_py (min-max)", "same events", "largest time difference"]
    body = []
    for size, e in summary.items():
        r, r1, c = e["evfuse_over_esim"], e["evfuse_1t_over_esim"], e["events_check"]
        same = c["esim_events"] == c["evfuse_events"] and c["same_pixels_and_polarities"]
        body.append([size, _num(e["events"]), _num(e["esim_py_mev_per_s"]),
                     _num(e["evfuse_mev_per_s"]),
                     f"{_num(r['median'])}x ({_num(r['min'])}-{_num(r['max'])})",
                     f"{_num(r1['median'])}x ({_num(r1['min'])}-{_num(r1['max'])})",
                     _num(same), f"{_num(c['max_time_difference_ns'])} ns"])
    return [(f"Medians of {data['reps']} repetitions, evfuse on {data['threads']} threads; each "
             "ratio is one repetition's esim_py wall time over evfuse's, with the lowest and "
             "highest.", (header, body))]


# ------------------------------------------------------------------------------- events.json

def _events_tables(data: dict) -> list[tuple[str, Table]]:
    anchor = data["anchor"]
    header = ["sensor", "events / frame", "evfuse Mev/s", "ms / frame",
              f"{anchor['tool']} Mev/s (anchor)", "evfuse / anchor, measured beside"]
    body = [[r["size"], _num(r["events_per_frame"], 0), _num(r["mev_per_s"]),
             _num(r["ms_per_frame"], 3), _num(r["esim_py_mev_per_s"], 1),
             f"{_num(r['ratio_vs_anchor_measured_beside'], 1)}x"] for r in data["throughput"]]
    tables = [(f"Emulation throughput (moving texture, 2.5 px a frame, C = 0.2). The anchor's "
               f"figures and the last column come from {anchor['source']}: quote the last "
               f"column, not this run over the anchor.", (header, body))]
    ref = data["reference"]
    tables.append(("The compiled emulator against a per-pixel Python loop of the same model "
                   "(its speed ratio is a regression guard, not a speed claim).",
                   (["events", "identical", "Python loop s", "compiled ms", "guard ratio"],
                    [[_num(ref["events"]), _num(ref["identical"]), _num(ref["python_loop_s"], 3),
                      _num(1e3 * ref["compiled_s"]), f"{_sig(ref['guard_ratio'], 2)}x"]])))
    stream = data["streaming"]
    if stream:
        files = sorted({k for s in stream for k in s["file_bytes"]})
        tables.append(("Streaming a 640x480 sequence to disk: peak resident memory against "
                       "the simulated duration.",
                       (["seconds", "events", "wall s", "peak RSS MiB"]
                        + [f"{f} MiB" for f in files],
                        [[_num(s["seconds"], 1), _num(s["events"]), _num(s["wall_s"], 1),
                          _num(s["peak_rss_mib"], 0)]
                         + [_num(s["file_bytes"].get(f, 0) / 2**20, 0) for f in files]
                         for s in stream])))
    if data.get("scenes"):
        tables.append(("The event camera's time on built-in scenes.",
                       (["scene", "sampler", "seconds", "events", "renders", "render s",
                         "emulate s", "write s", "emulate share"],
                        [[r["scene"], r.get("sampler", "-"), _num(r["duration_s"], 2),
                          _num(r["events"]), _num(r["event_renders"]), _num(r["render_s"]),
                          _num(r["emulate_s"], 3), _num(r["write_s"], 3),
                          _pct(r["emulate_share"])] for r in data["scenes"]])))
    return tables


def _events_plots(data: dict) -> list[Plot]:
    rows = data["throughput"]
    if not rows:
        return []
    figure, (left, right) = _figure(3.6, 2)
    labels = [r["size"] for r in rows]
    bars = left.bar(labels, [r["mev_per_s"] for r in rows], color="C0")
    left.bar_label(bars, [_num(r["mev_per_s"], 1) for r in rows], padding=2, fontsize="small")
    left.set_ylabel("events per second (millions)")
    left.set_xlabel("sensor")
    left.set_title("Throughput (this run)")
    bars = right.bar(labels, [r["ms_per_frame"] for r in rows], color="C1")
    right.bar_label(bars, [_sig(r["ms_per_frame"], 2) for r in rows], padding=2,
                    fontsize="small")
    right.set_ylabel("time per frame (ms)")
    right.set_xlabel("sensor")
    right.set_title("Time per frame (this run)")
    for ax in (left, right):
        ax.margins(y=0.12)
    figure.suptitle("Event emulation, frames in memory, both cores")
    return [Plot("events-throughput", "event emulation throughput and time per frame per "
                 "sensor size", figure)]


# --------------------------------------------------------------------------------- emvs.json

def _emvs_tables(data: dict) -> list[tuple[str, Table]]:
    anchor = data["anchor"]

    def span(pair, digits=2):
        return "-" if pair is None else f"{_num(pair[0], digits)}-{_num(pair[1], digits)}"

    header = ["DSI", "events", "threads", "evfuse Mev/s", f"{anchor['tool']} Mev/s (anchor)",
              "evfuse / anchor, measured beside", "guard Mev/s", "guard ratio"]
    body = [[r["dsi"], r["events"], _num(r["threads"]), _num(r["mev_per_s"]),
             span(r["anchor_mev_per_s"], 1), span(r["ratio_vs_anchor_measured_beside"]),
             _num(r["guard_mev_per_s"]), _num(r["guard_ratio"])] for r in data["dsi"]]
    tables = [(f"DSI construction. The anchor's figures come from {anchor['source']}; the "
               f"guard is a {data['guard']}.", (header, body))]
    if data.get("window_2s"):
        tables.append(("`map_sequence` on a 2-s window.",
                       (["sequence", "threads", "wall s", "events", "DSI s", "DSI Mev/s",
                         "depth map s"],
                        [[r["sequence"], _num(r["threads"]), _num(r["wall_s"]),
                          _num(r["events"]), _num(r["dsi_s"]), _num(r["dsi_mev_per_s"]),
                          _num(r["depth_map_s"])] for r in data["window_2s"]])))
    return tables


def _emvs_plots(data: dict) -> list[Plot]:
    rows = data["dsi"]
    if not rows:
        return []
    groups = list(dict.fromkeys((r["dsi"], r["events"]) for r in rows))
    threads = sorted({r["threads"] for r in rows})
    value = {(r["dsi"], r["events"], r["threads"]): r["mev_per_s"] for r in rows}
    figure, (ax,) = _figure(1.5 + 0.6 * len(groups))
    _hbars(ax, [f"{d}\n{'events on edges' if e == 'edges' else f'{e} events'}"
                for d, e in groups],
           {f"{t} thread{'s' if t > 1 else ''}": [value.get((d, e, t)) for d, e in groups]
            for t in threads}, "events per second (millions)", values="{:.2f}")
    ax.set_title("DSI construction throughput (this run)")
    return [Plot("emvs", "DSI construction throughput by DSI size, events and threads", figure)]


# ---------------------------------------------------------------------------- bench_fill.json

FILL_STAGES = (("segment_ms", "segment"), ("select_ms", "select"), ("fill_idw_ms", "fill (IDW)"),
               ("fill_gaussian_ms", "fill (Gaussian)"), ("fill_exponential_ms", "fill (exp(-d))"),
               ("total_idw_ms", "total (IDW)"))


def _fill_tables(rows: list[dict]) -> list[tuple[str, Table]]:
    header = ["size", "threads", "map points", "regions (selected)"] + [
        f"{label} ms" for _, label in FILL_STAGES]
    body = [[r["size"], _num(r["threads"]), _num(r["map_points"]),
             f"{_num(r['regions'])} ({_num(r['selected'])})"]
            + [_sig(r[key]) for key, _ in FILL_STAGES] for r in rows]
    return [("Median time of each filling stage on the synthetic piecewise-planar frame.",
             (header, body))]


def _pixels(size: str) -> int:
    width, height = (int(v) for v in size.split("x"))
    return width * height


def _fill_plots(rows: list[dict]) -> list[Plot]:
    if not rows:
        return []
    figure, (ax,) = _figure(4.5)
    threads = sorted({r["threads"] for r in rows})
    values = []
    for k, (key, label) in enumerate(FILL_STAGES[:3]):
        for t, style in zip(threads, ("o-", "s--", "^:"), strict=False):
            mine = sorted((r for r in rows if r["threads"] == t), key=lambda r: _pixels(r["size"]))
            ys = [r[key] for r in mine]
            values += ys
            ax.plot([_pixels(r["size"]) / 1e6 for r in mine], ys, style, color=f"C{k}",
                    label=f"{label}, {t} thread{'s' if t > 1 else ''}")
    ax.set_xscale("log")
    if _spans_decades(values):
        ax.set_yscale("log")
    sizes = sorted({r["size"] for r in rows}, key=_pixels)
    ax.set_xticks([_pixels(s) / 1e6 for s in sizes], sizes)
    ax.minorticks_off()
    ax.set_xlabel("image size (pixels, log scale)")
    ax.set_ylabel("median time (ms)")
    ax.set_title("Map filling: time per stage against image size (the fill is most of it)")
    ax.legend(fontsize="x-small", ncols=2)
    return [Plot("fill", "map filling time per stage against image size", figure)]


def _fill_methods_tables(rows: list[dict]) -> list[tuple[str, Table]]:
    sizes = sorted({r["size"] for r in rows}, key=_pixels)
    methods = list(dict.fromkeys(r["method"] for r in rows))
    cell = {(r["method"], r["size"]): r for r in rows}

    def show(r):
        if r is None:
            return "-"
        return "skipped" if r.get("ms") is None else f"{_sig(r['ms'])} ms"

    return [("Every filling method, one core, median.",
             (["method"] + sizes, [[m] + [show(cell.get((m, s))) for s in sizes]
                                   for m in methods]))]


def _fill_methods_plots(rows: list[dict]) -> list[Plot]:
    sizes = sorted({r["size"] for r in rows}, key=_pixels)
    methods = list(dict.fromkeys(r["method"] for r in rows))
    if not methods:
        return []
    cell = {(r["method"], r["size"]): r.get("ms") for r in rows}
    figure, (ax,) = _figure(1.2 + 0.32 * len(methods) * max(1, len(sizes)) / 2)
    series = {s: [cell.get((m, s)) for m in methods] for s in sizes}
    values = [v for vs in series.values() for v in vs if v is not None]
    _hbars(ax, methods, series, "median time (ms)", log=_spans_decades(values))
    ax.set_title("Filling methods, one core")
    return [Plot("fill-methods", "median time of every filling method per image size", figure)]


# ------------------------------------------------------------------------------ generate.json

def _generate_tables(data: dict) -> list[tuple[str, Table]]:
    header = ["configuration", "flags", "wall s", "jobs / h", "simulated s / h", "start s",
              "steady jobs / h", "mean job s", "same bytes as serial"]
    body = [[r["config"], f"`{r['flags']}`", _num(r["wall_s"], 1), _num(r["jobs_per_hour"], 0),
             _num(r["simulated_s_per_hour"], 1), _num(r["start_s"], 1),
             _num(r["steady_jobs_per_hour"], 0), _num(r["mean_job_s"]),
             _num(r["same_hashes_as_serial"])] for r in data["rows"]]
    tables = [(f"{data['jobs']} jobs, {_sig(data['simulated_s'])} simulated seconds, "
               f"{data['cores']} cores{' (--quick)' if data.get('quick') else ''}.",
               (header, body))]
    paper = data.get("paper", {})
    if paper:
        workers = sorted({p["workers"] for t in paper.values() for p in t})
        table = {(name, p["workers"]): p["hours"] for name, t in paper.items() for p in t}
        tables.append(("Arithmetic, not a measurement: hours for a 1,000-job dataset on W "
                       "workers, from the measured overheads and a job's cost: this sweep's "
                       "measured mean job (`this_sweep`), or 10 s at 240x180 at the cost per "
                       "simulated second that `bench_generate.py` takes as an input "
                       "(`ten_s_240x180`, not measured in this run).",
                       (["projection"] + [f"{w} worker{'s' if w != 1 else ''}"
                                          for w in workers],
                        [[name] + [_sig(table.get((name, w))) for w in workers]
                         for name in paper])))
    return tables


def _generate_plots(data: dict) -> list[Plot]:
    rows = data["rows"]
    if not rows:
        return []
    figure, (ax,) = _figure(1.5 + 0.5 * len(rows))
    _hbars(ax, [r["config"] for r in rows],
           {"end to end": [r["jobs_per_hour"] for r in rows],
            "first job start to last job end": [r["steady_jobs_per_hour"] for r in rows]},
           "jobs per hour", values="{:,.0f}")
    ax.set_title("evfuse generate: throughput per cluster configuration")
    return [Plot("generate", "evfuse generate throughput per configuration", figure)]


# --------------------------------------------------------------------- generate_estimates.json

def _estimate_tables(data: dict) -> list[tuple[str, Table]]:
    header = ["job", "noise", "lambda", "events", "estimate s", "how", "frames s", "events s",
              "setup s", "measured s", "error", "from the others' mean", "frame render s",
              "event render s"]
    body = []
    for j in data["jobs"]:
        parts = j["parts"] or {}
        body.append([j["job_id"], str(j.get("noise")), _num(j.get("lam"), 2),
                     _num(j.get("events"), 0), _num(j["estimate_s"], 1),
                     "probed" if j["probed"] else "mean of probed seeds",
                     _num(parts.get("frames"), 1), _num(parts.get("events"), 1),
                     _num(sum(parts.get(k, 0.0) for k in ("draw", "setup", "compile")), 1),
                     _num(j["measured_s"], 1), f"{100 * j['error']:+.1f} %",
                     f"{100 * j['mean_of_others_error']:+.0f} %"
                     if "mean_of_others_error" in j else "",
                     _num(j.get("frame_render_s"), 2), _num(j.get("event_render_s"), 2)])
    verdict = "held" if data["within_bound"] else "broken"
    total = data.get("total_error")
    total = f"; the sweep's total {100 * total:+.1f} %" if total is not None else ""
    return [(f"{data['sweep']}; dry run {_num(data['dry_run_s'], 1)} s. Largest error of a "
             f"probed job {100 * data['largest_error']:.1f} %{total}, against the stated bound "
             f"{100 * data['bound']:.0f} % ({verdict}). Frame render (motion, edges and "
             "shading of the frames) at most the event render on every job: "
             f"{_num(data.get('frame_render_under_event_render'))}.", (header, body))]


# ----------------------------------------------------------------------------- noise_time.json

def _noise_time_tables(data: dict) -> list[tuple[str, Table]]:
    header = ["cause", "events", "distinct times", "on the 10-ms grid", "at t = 0"]
    body = [[r["cause"], _num(r["events"], 0), _num(r["distinct_times"], 0),
             _num(r["on_grid"], 0), _num(r["at_zero"], 0)] for r in data["causes"]]
    ks = data["first_leak_ks"]
    return [(f"{data['scene']}. First leak time of {ks['pixels']} pixels against the model's "
             f"uniform law: KS D = {ks['D']:.4f}, p = {ks['p']:.3f}. Goal: {data['goal']} "
             f"({'met' if data['goal_met'] else 'not met'}).", (header, body))]


# -------------------------------------------------------------------- procedural_exposure.json

def _procedural_exposure_tables(data: dict) -> list[tuple[str, Table]]:
    low, high = data["goal_mean_grey"]
    job = data["job"]
    header = ["family", "seed", "frames", "mean grey", "frame means", "99th percentile",
              "exposure ms", f"within [{low:g}, {high:g}]"]
    body = [[r["family"], _num(r["seed"]), _num(r["frames"]), _num(r["mean_grey"], 1),
             f"{_num(r['frame_mean_min'], 1)}-{_num(r['frame_mean_max'], 1)}",
             _num(r["p99_grey"], 0),
             f"{_num(r['exposure_ms'][0])}-{_num(r['exposure_ms'][1])}",
             _num(low <= r["mean_grey"] <= high)] for r in data["rows"]]
    return [(f"Generator version {data['generator_version']}; each sequence simulated as a "
             f"dataset job: {job['sensor']}, `{job['frame_sensor']}`, {_sig(job['start'])}-"
             f"{_sig(job['end'])} s, every frame; grey levels of 255.", (header, body))]


# ------------------------------------------------------------------------------------ sections

SECTIONS: tuple[Section, ...] = (
    Section("simulate_cost.json", "Cost of evfuse simulate, stage by stage",
            "The whole `evfuse simulate` command run as a process (the defaults), per scene, "
            "sensor size and sampler, after a run that fills the kernel cache: wall seconds per "
            "simulated second, without the one-off start, and each stage's share "
            "(`sequence.json`'s `timings_s`; `other` is the process start, imports, scene "
            "parsing, rig and index files, which a long run amortises). The bars are each "
            "stage's wall seconds per simulated second.",
            "python -m benchmarks.bench_sampling --quick", _cost_tables, _cost_plots),
    Section("convergence.json", "Events against samples per pixel",
            "Each scene and window simulated at the defaults and as a reference at 256 samples "
            "per pixel (events and frames), with the ideal event camera: the default's event "
            "count error and worst 16x16 block against the reference, its frames' PSNR, and "
            "with `--event-spp` the event camera at other samples per pixel against the same "
            "reference. The full run covers boxes_6dof, poster_6dof, dynamic_6dof, "
            "complex_heightfield and garden_wall at two times each; `--scenes` and `--first` "
            "pick some (the rows say which ran).",
            "python -m benchmarks.bench_convergence --event-spp 1,4,16,64",
            _convergence_tables, _convergence_plots),
    Section("convergence_quick.json", "Events against samples per pixel, quick",
            "The same benchmark's `--quick` subset: shorter windows on fewer scenes.",
            "python -m benchmarks.bench_convergence --quick --event-spp 1,4,16,64",
            _convergence_tables, _convergence_plots),
    Section("sampling.json", "The samplers' agreement",
            "Each window simulated with the per-pixel sampler and with the frame sampler "
            "(lam 0.5), and with the frame sampler at lam / 4 as the reference: whole-frame "
            "renders, pixel samples, events, the event camera's wall time, and each "
            "sampler's agreement with the reference.",
            "python -m benchmarks.bench_sampling --agreement", _sampling_tables,
            _sampling_plots),
    Section("host.json", "The per-pixel sampler's host time per block",
            "`simulate` in-process with a timer around each host stage of the per-pixel "
            "sampler; `rest` is `event_sample` less the timed stages.",
            "python -m benchmarks.bench_host", _host_tables, _host_plots),
    Section("render.json", "Render time against a bare mi.render",
            "Render time per frame (luminance and depth) against a bare `mi.render` loop on "
            "the same scene and view, in the same process; the overhead is evfuse / bare - 1.",
            "python -m benchmarks.bench_render", _render_tables, _render_plots),
    Section("shader.json", "The event shader",
            "`EventShader` rendering scattered samples at their own times and whole frames, "
            "against `mi.render` at the same samples per pixel, and their agreement at 64.",
            "python -m benchmarks.bench_shader", _shader_tables, lambda data: []),
    Section("events.json", "Event emulation",
            "The emulator's throughput on the ESIM authors' input (frames in memory), its "
            "events against a per-pixel Python loop of the same model, and streaming to disk "
            "with bounded memory.",
            "python -m benchmarks.bench_events", _events_tables, _events_plots),
    Section("events_vs_esim.json", "Event emulation beside esim_py",
            "`emulate_events` and esim_py (ESIM's emulator built from its sources) on the same "
            "frames in one run, alternating, with their events compared.",
            "python -m benchmarks.bench_esim --esim DIR", _esim_tables, lambda data: []),
    Section("emvs.json", "DSI construction (EMVS)",
            "Million events per second of building the disparity space image on 1 and 2 "
            "threads, for uniformly random events and events on edges.",
            "python -m benchmarks.bench_emvs", _emvs_tables, _emvs_plots),
    Section("bench_fill.json", "Map filling stages",
            "The three filling stages (segment, select, fill) on a synthetic piecewise-planar "
            "frame with a semi-dense map on its outlines, median of the repeats.",
            "python -m benchmarks.bench_fill", _fill_tables, _fill_plots),
    Section("bench_fill_methods.json", "Filling methods",
            "Every registered filling method on the same inputs, one core, median of the "
            "repeats after an untimed call.",
            "python -m benchmarks.bench_fill", _fill_methods_tables, _fill_methods_plots),
    Section("generate.json", "Dataset generation",
            "A 12-job sweep through `evfuse generate`, serially and on local Dask clusters of "
            "several worker/thread splits, as a user runs it.",
            "python -m benchmarks.bench_generate --quick", _generate_tables, _generate_plots),
    Section("noise_time.json", "When noise events fire",
            "A static scene with the realistic noise preset: leak, shot and hot-pixel events "
            "against the 10-ms render grid.",
            "python -m benchmarks.bench_noise_time", _noise_time_tables, lambda data: []),
    Section("generate_estimates.json", "Dataset generation: how good --dry-run's estimates are",
            "`evfuse generate --dry-run`'s estimate of each job against its measured wall "
            "seconds, on procedural tabletops, each command its own process.",
            "python -m benchmarks.bench_generate --estimates", _estimate_tables,
            lambda data: []),
    Section("procedural_exposure.json", "Exposure of procedural scenes",
            "The mean grey of the DAVIS240C APS frames of procedural scenes (`tabletop` and "
            "`room`, seeds 0-7) as a dataset job writes them, against the goal of 40-215 of "
            "255 (auto-exposure aims at 102).",
            "python -m benchmarks.bench_procedural_exposure", _procedural_exposure_tables,
            lambda data: []),
)
"""The benchmarks the page shows, in its order."""


# ------------------------------------------------------------------------------------ the page

def _provenance_line(entry: dict | None, digest: str, section: Section) -> str:
    if entry is None or entry.get("sha256") != digest:
        return (f"Made by `{section.command}` (its usual form; no record of the run that wrote "
                f"this file: run it through `python -m benchmarks.record -- ...` to keep one).")
    load = entry.get("load_average_at_start") or []
    changes = (", with uncommitted changes" if entry.get("uncommitted_changes") else
               "" if entry.get("uncommitted_changes") is False else ", tree state unknown")
    status = "" if entry.get("exit_status") == 0 else f", exit status {entry.get('exit_status')}"
    return (f"Recorded {entry.get('date', '?')} by `{entry.get('command', '?')}`: "
            f"{_num(entry.get('wall_s'), 0)} s "
            f"wall on {entry.get('cores', '?')} cores ({entry.get('machine', '?')}), load "
            f"average {_num(load[0], 1) if load else '?'} at the start, commit "
            f"`{entry.get('commit') or '?'}`{changes}{status}.")


def _keys(data) -> str:
    if isinstance(data, dict):
        return "an object with keys " + ", ".join(f"`{k}`" for k in data)
    if isinstance(data, list):
        keys = list(dict.fromkeys(k for row in data if isinstance(row, dict) for k in row))
        return (f"a list of {len(data)} rows" + (" with keys " + ", ".join(f"`{k}`" for k in keys)
                                                  if keys else ""))
    return f"a {type(data).__name__}"


def write_report(results: Path = RESULTS, out: Path = Path("docs/generated")) -> Path:
    """Write ``out/benchmarks.md`` and its plots ``out/img/bench-*.png`` from ``results``.

    Parameters
    ----------
    results : Path
        Folder of the benchmarks' JSON files (``benchmarks/results``); it may be missing.
    out : Path
        Folder to write into (made if missing).

    Returns
    -------
    Path
        The page.
    """
    results, out = Path(results), Path(out)
    images = out / IMAGES
    images.mkdir(parents=True, exist_ok=True)
    for old in images.glob(f"{PREFIX}*.png"):
        old.unlink()
    provenance_path = results / PROVENANCE
    provenance = {}
    if provenance_path.is_file():
        try:
            provenance = json.loads(provenance_path.read_text())
        except json.JSONDecodeError:
            provenance = {}
    known = {s.file for s in SECTIONS}
    lines = ["# Benchmarks", "",
             "Generated by `python -m benchmarks.report` from `benchmarks/results/*.json`: "
             "every table and plot on this page is formatted from those files, none is "
             "written by hand. Timings depend on the machine and on what else ran on it; "
             "each section says how its file was made. Ratios and counts measured within one "
             "run (overheads against a baseline in the same process, event counts against a "
             "reference) carry over between machines better than seconds do.", ""]
    for section in SECTIONS:
        path = results / section.file
        lines += [f"## {section.title}", "", section.what, ""]
        if not path.is_file():
            lines += ["!!! note \"Not recorded\"",
                      f"    No `{section.file}` in the results: `{section.command}` makes it.",
                      ""]
            continue
        try:
            data = json.loads(path.read_text())
        except (json.JSONDecodeError, UnicodeDecodeError) as error:
            lines += ["!!! warning \"Unreadable\"",
                      f"    `{section.file}` could not be parsed ({error}); `{section.command}` "
                      f"makes it again.", ""]
            continue
        lines += [f"`{section.file}`. " + _provenance_line(provenance.get(section.file),
                                                          file_hash(path), section), ""]
        try:
            tables = section.tables(data)
            plots = section.plots(data)
        except (KeyError, TypeError, IndexError, ValueError, AttributeError,
                ZeroDivisionError) as error:
            lines += ["!!! warning \"Unexpected structure\"",
                      f"    `{section.file}` is not in the structure this page knows "
                      f"({type(error).__name__}: {error}); it holds {_keys(data)}.", ""]
            continue
        for caption, table in tables:
            lines += [caption, "", markdown_table(table), ""]
        for plot in plots:
            name = f"{PREFIX}{Path(section.file).stem}-{plot.name}.png"
            plot.figure.savefig(images / name, dpi=DPI)
            lines += [f"![{plot.alt}]({IMAGES}/{name})", ""]
    others = sorted(p for p in results.glob("*.json") if p.name not in known
                    and p.name != PROVENANCE) if results.is_dir() else []
    if others:
        lines += ["## Other results", "",
                  "Files in the results folder that this page does not show yet:", ""]
        for path in others:
            try:
                what = _keys(json.loads(path.read_text()))
            except (json.JSONDecodeError, UnicodeDecodeError) as error:
                what = f"not parsable ({error})"
            lines.append(f"- `{path.name}`: {what}.")
        lines.append("")
    page = out / PAGE
    page.write_text("\n".join(lines))
    return page


def main(argv=None) -> Path:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, required=True,
                        help="folder for benchmarks.md and img/ (e.g. docs/generated)")
    parser.add_argument("--results", type=Path, default=RESULTS,
                        help="folder of the benchmarks' JSON files (default benchmarks/results)")
    args = parser.parse_args(argv)
    if args.results.exists() and not args.results.is_dir():
        parser.error(f"--results: expected a folder of JSON files, got the file {args.results}")
    page = write_report(args.results, args.out)
    print(f"written {page}")
    return page


if __name__ == "__main__":
    main()
