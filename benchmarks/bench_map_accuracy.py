"""Accuracy of the EMVS map on the simulated sliders, written as the paper's Table 2.

For ``slider_close`` and ``slider_far`` (simulated with ``evfuse simulate`` into
``runs/<name>`` if not there yet: ~15 min each on 2 cores), six one-second windows [k, k + 1] s,
k = 0..5, are mapped with the paper's slider settings (adaptive threshold kernel 15, c 7) and
scored against the exact depth of each reference view: mean absolute error (cm, as Table 2),
median error, the share of map points within 1 % and 5 % of the true depth, and N1. Also the
wall time of mapping a 2-second window. Results are printed and written to
``benchmarks/results/map_accuracy.json``.

Run: ``.venv/bin/python benchmarks/bench_map_accuracy.py [--scenes slider_close,slider_far]``.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

from fusion.map.emvs import DepthMapParams, DSIParams
from fusion.map.mapping import MapParams, map_sequence

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results"
DEPTH_RANGE = {"slider_close": (0.15, 0.6), "slider_far": (0.3, 1.5)}
PAPER_TABLE2_CM = "the paper's Table 2 gives 0.5-2.3 cm on the real sequences (whole pipeline)"


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", default="slider_close,slider_far")
    parser.add_argument("--planes", type=int, default=100)
    args = parser.parse_args(argv)
    report: dict = {"windows": {}, "timing_2s": {}}
    for name in args.scenes.split(","):
        folder = ROOT / "runs" / name
        if not (folder / "sequence.json").is_file():
            subprocess.run([sys.executable, "-m", "fusion.cli", "simulate", name, "--out",
                            str(folder), "--overwrite"], check=True, cwd=ROOT)
        low, high = DEPTH_RANGE[name]
        rows = []
        for k in range(6):
            params = MapParams(DSIParams(low, high, planes=args.planes),
                               DepthMapParams(kernel=15, c=7.0), t0=float(k), t1=float(k + 1))
            result = map_sequence(folder, params, progress=False)
            errors = result.info.get("errors", {})
            rows.append({"window": [k, k + 1], "N1": result.n1, **errors,
                         "events": result.info["events_used"]})
        report["windows"][name] = rows
        params = MapParams(DSIParams(low, high, planes=args.planes),
                           DepthMapParams(kernel=15, c=7.0), t0=2.0, t1=4.0)
        start = time.perf_counter()
        result = map_sequence(folder, params, progress=False)
        report["timing_2s"][name] = {"wall_s": time.perf_counter() - start,
                                     "events": result.info["events_used"],
                                     "dsi_mev_per_s": result.info["dsi_mev_per_s"]}
    print("\nMean absolute depth error of the semi-dense map (cm), one-second windows "
          f"({PAPER_TABLE2_CM})")
    print(f"{'sequence':>13} " + " ".join(f"{'w' + str(k + 1):>6}" for k in range(6))
          + f" {'mean':>6}")
    for name, rows in report["windows"].items():
        maes = [r.get("mae_cm", float("nan")) for r in rows]
        print(f"{name:>13} " + " ".join(f"{m:>6.2f}" for m in maes)
              + f" {sum(maes) / len(maes):>6.2f}")
    print("\nPer window: N1, median error (cm), completeness, precision (share of the N1 points "
          "within 1 % / 5 % of the exact surface; none where there is no surface)")
    nan = float("nan")
    for name, rows in report["windows"].items():
        for r in rows:
            print(f"{name:>13} {r['window']}  N1 {r['N1']:>6}  median "
                  f"{r.get('median_cm', nan):.2f}  completeness "
                  f"{100 * r.get('completeness', nan):5.1f} %  precision 1 % "
                  f"{100 * r.get('precision_1pct', nan):5.1f} %  5 % "
                  f"{100 * r.get('precision_5pct', nan):5.1f} %  events {r['events']}")
    for name, t in report["timing_2s"].items():
        print(f"{name}: 2-second window mapped in {t['wall_s']:.1f} s ({t['events']} events, "
              f"DSI {t['dsi_mev_per_s']:.2f} Mev/s)")
    RESULTS.mkdir(exist_ok=True)
    (RESULTS / "map_accuracy.json").write_text(json.dumps(report, indent=2))
    print(f"written to {RESULTS / 'map_accuracy.json'}")
    return report


if __name__ == "__main__":
    main()
