#!/bin/bash
# Issue 23's GPU figures in one short run on a lent GPU machine (`cuda_ad_rgb`), most wanted first,
# each step under its own time limit so that a cut-off run still brings back what it finished.
#
# Here, once:   ../shared/gpu/make_site.sh .gpu && echo /.gpu/ >> .git/info/exclude
# There (the device tool runs it from the repository root, carrying ".gpu"):
#               bash benchmarks/gpu_check.sh            # STEPS="1 2 3" to choose steps
# It writes under $OUT (default /tmp/gpu_check): each run's sequence.json, the logs, and
# summary.txt, a table of the event camera's stages (sequence.json's timings_s, seconds) beside
# the goals (slider_close 0.2 s: event camera <= 0.4 s at 240x180, <= 10 s at 1280x720).
#
# Steps: 1 slider_close 0.2 s at 240x180, per-pixel sampler, twice (the second is warm);
#        2 boxes_6dof 0.05 s from 3.5 s, twice; 3 slider_close 0.2 s at 1280x720 ("hd"), twice;
#        4 bench_convergence.py --quick --edge-spp 16; 5 the test suite on 14 workers.
# Without a GPU it runs on whatever variant evfuse picks (it says which): a dry run of the script.
set -uo pipefail
OUT=${OUT:-/tmp/gpu_check}
STEPS=${STEPS:-"1 2 3 4 5"}
mkdir -p "$OUT"
if [ -f .gpu/site.tar.xz ]; then                       # Mitsuba, Dr.Jit, OpenEXR (make_site.sh)
  mkdir -p /tmp/site && tar xJf .gpu/site.tar.xz -C /tmp/site
  export PYTHONPATH=/tmp/site:$PWD
else
  export PYTHONPATH=$PWD${PYTHONPATH:+:$PYTHONPATH}
fi
PY=${PYTHON:-python3}                                  # the project's venv where there is one
if [ -z "${PYTHON:-}" ] && [ -x .venv/bin/python ] && [ ! -f .gpu/site.tar.xz ]; then
  PY=.venv/bin/python
fi
{ nvidia-smi --query-gpu=name,memory.total --format=csv,noheader 2>/dev/null || echo "no GPU"
  "$PY" -c "import mitsuba, drjit; print('mitsuba', mitsuba.__version__, 'drjit', drjit.__version__)"
} | tee "$OUT/env.txt"

run() {   # run NAME LIMIT_S COMMAND...: the command's output in NAME.log, its status in NAME.rc
  local name=$1 limit=$2; shift 2
  local tick=$SECONDS
  timeout "$limit" "$@" >"$OUT/$name.log" 2>&1
  echo $? >"$OUT/$name.rc"
  echo "$name: exit $(cat "$OUT/$name.rc") in $((SECONDS - tick)) s" | tee -a "$OUT/steps.txt"
}

simulate_twice() {   # simulate_twice NAME LIMIT_S ARGS...: cold, then warm; keeps sequence.json
  local name=$1 limit=$2; shift 2
  for pass in cold warm; do
    rm -rf "/tmp/gpu_check_runs/$name-$pass"
    run "$name-$pass" "$limit" "$PY" -m fusion.cli simulate "$@" --no-motion-truth --sampler pixel \
      --out "/tmp/gpu_check_runs/$name-$pass"
    cp "/tmp/gpu_check_runs/$name-$pass/sequence.json" "$OUT/$name-$pass.json" 2>/dev/null
  done
}

for step in $STEPS; do
  case $step in
    1) simulate_twice slider 120 slider_close --duration 0.2 --seed 3 ;;
    2) simulate_twice boxes 120 boxes_6dof --start 3.5 --duration 0.05 ;;
    3) hd=$("$PY" -c "from benchmarks.bench_host import _scene
print(_scene('slider_close', 'hd')[1])" 2>/dev/null | tail -1)   # its camera preset "hd"
       simulate_twice hd 240 "$hd" --duration 0.2 --seed 3 ;;
    4) run convergence 240 "$PY" benchmarks/bench_convergence.py --quick --edge-spp 16 ;;
    5) run tests 300 "$PY" -m pytest -q -n 14 -p no:cacheprovider tests ;;
    *) echo "unknown step $step" >&2 ;;
  esac
done

"$PY" - "$OUT" <<'EOF' | tee "$OUT/summary.txt"
import json, sys
from pathlib import Path
out = Path(sys.argv[1])
goals = {"slider": 0.4, "hd": 10.0}
print(f"{'run':<12} {'variant':<12} {'events':>10} {'render':>7} {'emulate':>8} {'sample':>7} "
      f"{'camera':>7}  goal")
for path in sorted(out.glob("*-warm.json")) + sorted(out.glob("*-cold.json")):
    record = json.loads(path.read_text())
    t = record["timings_s"]
    camera = t["event_render"] + t["emulate"] + t["event_sample"]
    name = path.stem.rsplit("-", 1)[0]
    goal = goals.get(name)
    verdict = "" if goal is None else f"<= {goal} s {'PASS' if camera <= goal else 'FAIL'}"
    print(f"{path.stem:<12} {record['render']['variant']:<12} {record['events']['count']:>10,} "
          f"{t['event_render']:7.2f} {t['emulate']:8.2f} {t['event_sample']:7.2f} "
          f"{camera:7.2f}  {verdict}")
EOF
