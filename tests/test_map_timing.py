"""map.json's DSI throughput excludes numba's compilation and says so (issue 11, item 13)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

# Two maps of the same window in one fresh interpreter: the first call is the cold one, where
# numba compiles the DSI kernels (or loads them from its cache) and starts its threads.
_TWO_MAPS = """
import json, sys
from fusion import DSIParams, MapParams, map_sequence
params = MapParams(DSIParams(0.5, 2.0))
out = []
for _ in range(2):
    info = map_sequence(sys.argv[1], params, progress=False).info
    out.append({"timing": info["dsi_timing"], "rate": info["dsi_mev_per_s"],
                "used": info["events_used"], **info["timings"]})
print(json.dumps(out))
"""


def test_dsi_rate_of_a_cold_map_excludes_compilation(plane_sequence):
    done = subprocess.run([sys.executable, "-c", _TWO_MAPS, str(plane_sequence)], cwd=ROOT,
                          capture_output=True, text=True, check=True)
    cold, warm = json.loads(done.stdout.strip().splitlines()[-1])
    for run in (cold, warm):
        assert "excludes compilation" in run["timing"] and "dsi_compile_s" in run["timing"]
        assert run["dsi_compile_s"] >= 0.0 and run["dsi_s"] > 0.0
        # The rate is the events over the timed votes only, not over the compilation.
        assert abs(run["rate"] - run["used"] / run["dsi_s"] / 1e6) <= 1e-9 * run["rate"]
    # In a fresh process loading or compiling the kernels (>= 0.2 s even from numba's cache)
    # costs more than voting this small window (~0.05 s), and it is reported on its own...
    assert cold["dsi_compile_s"] > cold["dsi_s"]
    # ...so the cold call's DSI time is close to the warm call's, not 10x it as when the
    # compilation was inside it (0.47 s against 0.05 s on this window). The slack absorbs noise.
    assert cold["dsi_s"] < 3 * warm["dsi_s"] + 0.1
