"""When noise events fire: leak and shot noise of a static scene, against the render grid.

A static scene (``complex_sphere`` with its camera at rest, 96x72, 1 s) simulated with the
``realistic`` noise preset fires only noise: leak events (each pixel's reference drifting down
at about 0.1 Hz), background activity (Poisson, about 0.1-0.4 Hz) and hot pixels. The renders
of a static scene fall on a 10-ms grid (the event camera's minimum rate). Reported per cause:
the events, how many distinct times they fall on, how many lie on the 10-ms grid and at t = 0,
and a Kolmogorov-Smirnov test of the first leak time of each pixel that leaks, which the model
makes uniform on the window (a uniform initial phase and a drift of mean rate; ``P(t_1 <= t) =
rate t``). The goal (issue 38): more than 90 % of leak events on distinct times, under 10 % on
the grid.

Run: ``python -m benchmarks.bench_noise_time`` (about 10 s). Written to
``benchmarks/results/noise_time.json``.
"""

from __future__ import annotations

import argparse
import json
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
RESULTS = ROOT / "benchmarks" / "results"
GRID_NS = 10_000_000
DURATION = 1.0


def static_scene_text() -> str:
    """``complex_sphere`` at rest: 96x72 (fx = fy = 80), 1 s, its camera's velocity zero."""
    text = (ROOT / "scenes" / "complex_sphere.toml").read_text()
    replaced = (text.replace('name = "complex_sphere"', 'name = "static_sphere"', 1)
                .replace("duration = 4.0", f"duration = {DURATION}", 1)
                .replace("velocity = [0.1, 0.0, -0.025]", "velocity = [0.0, 0.0, 0.0]", 1)
                .replace('preset = "davis240c"', "width = 96\nheight = 72\nfx = 80.0\n"
                         "fy = 80.0\ncx = 48.0\ncy = 36.0", 1))
    assert replaced.count("[0.0, 0.0, 0.0]") >= 1 and "width = 96" in replaced
    return replaced


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.parse_args(argv)
    from scipy import stats

    from sim.events import EventParams
    from sim.noise import CAUSES, noise_preset
    from sim.scene import parse_scene
    from sim.sequence import load_sequence
    from sim.simulate import simulate

    scene = parse_scene(static_scene_text(), "<static_sphere>")
    with tempfile.TemporaryDirectory(prefix="bench-noise-time-") as tmp:
        result = simulate(scene, Path(tmp) / "seq", progress=False, event_formats=("h5",),
                          events=EventParams(seed=scene.seed, noise=noise_preset("realistic")))
        labels = load_sequence(Path(tmp) / "seq").event_labels()
    rows = []
    for code, name in CAUSES.items():
        mine = labels[labels["cause"] == code]
        t = mine["t"].astype(np.int64)
        row = {"cause": name, "events": len(t), "distinct_times": int(len(np.unique(t))),
               "on_grid": int(np.count_nonzero(t % GRID_NS == 0)),
               "at_zero": int(np.count_nonzero(t == 0))}
        if len(t):
            row["distinct_share"] = row["distinct_times"] / len(t)
            row["grid_share"] = row["on_grid"] / len(t)
        rows.append(row)
        print(f"{name:<10} {len(t):6d} events on {row['distinct_times']:6d} distinct times, "
              f"{row['on_grid']} on the 10-ms grid, {row['at_zero']} at t = 0", flush=True)
    leak = labels[labels["cause"] == 2]
    pixel = leak["y"].astype(np.int64) * scene.camera.width + leak["x"]
    firsts = np.array([leak["t"][pixel == p].min() for p in np.unique(pixel)]) * 1e-9
    ks = stats.kstest(firsts / DURATION, "uniform")
    print(f"first leak time of {len(firsts)} pixels against uniform on [0, {DURATION} s]: "
          f"KS D = {ks.statistic:.4f}, p = {ks.pvalue:.3f}")
    leak_row = rows[2]
    goal = leak_row["events"] > 0 and leak_row["distinct_share"] > 0.9 and \
        leak_row["grid_share"] < 0.1
    out = {"scene": "complex_sphere at rest, 96x72, 1 s, realistic noise",
           "sampler": result.sampler if hasattr(result, "sampler") else None,
           "causes": rows, "first_leak_ks": {"pixels": len(firsts), "D": ks.statistic,
                                             "p": ks.pvalue},
           "goal": ">90 % of leak events on distinct times, <10 % on the 10-ms grid",
           "goal_met": bool(goal)}
    RESULTS.mkdir(exist_ok=True)
    (RESULTS / "noise_time.json").write_text(json.dumps(out, indent=2))
    print(f"goal {'met' if goal else 'NOT met'}; written to {RESULTS / 'noise_time.json'}")
    return out


if __name__ == "__main__":
    main()
