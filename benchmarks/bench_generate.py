"""What ``evfuse generate`` gets out of a machine: a 12-job sweep run serially in one process and
on local Dask clusters of several worker/thread splits, in one run; the scheduler's overhead
per job; and, from the measured per-job costs, what a 1,000-sequence dataset costs on 1, 8
and 64 workers.

**The sweep** (:func:`sweep_text`): slider_close, boxes_6dof and the ``sphere`` bench family x
two contrasts x two seeds = 12 jobs, each 0.1 s of simulated time at 120x90 (``--quick``: 0.05 s
at 64x48), every output of simulate (events h5 + txt, the motion ground truth).

**Each configuration** is the whole ``evfuse generate SWEEP --out DIR`` command, run as a
process as a user runs it (process start, imports, the cluster's start and every worker's
first kernel compilation included, as they are in a real run), into a fresh folder:
``--workers 0`` (serial, in the one process, no Dask), the default local cluster (one
single-threaded worker per core), and the other splits of :func:`configurations`. Reported:
wall seconds, jobs per hour, simulated seconds per wall hour; the start (process launch to
the first job's start in ``runs.log``) and the jobs per hour from the first job's start to the
last one's end (what a long dataset sees once the workers are up); and the mean of the jobs' own
wall seconds (``manifest.csv``'s ``wall_s``: one job in a worker, set-up to last file).
Every configuration's output hashes are compared with the serial run's (they must be equal).

**Scheduler overhead**: 1,000 empty tasks through the default cluster (submit to result,
wall seconds per task), and the rewrite of a 1,000-row manifest (``generate`` rewrites it
after each job).

**On paper**: a 1,000-job dataset of this sweep's jobs on W workers, from the default
cluster's measured mean job seconds and overheads: ``1000 (job + overhead) / W + start``;
and the same for 10-s sequences at 240x180 from the README's cost of ``evfuse simulate`` per
simulated second (an input, said so), to show where the time goes at scale. These are
arithmetic, not measurements: they assume W cores that each run one worker as fast as one
core of this machine, and a file system that keeps up.

Run: ``python -m benchmarks.bench_generate [--quick]`` (on the shared 2-core machine: about
4 minutes, ``--quick`` about 2). Written to ``benchmarks/results/generate.json``. Timings only;
nothing is asserted (the hashes are compared and reported).

**The estimates** (``--estimates``): ``--dry-run``'s estimate of each job
(:func:`sim.dataset.estimate_jobs`) against the job's measured wall seconds (``manifest.csv``'s
``wall_s``), on 4 procedural tabletop seeds of ``sweeps/tabletop.toml`` (240x180, 2 s, its
drawn contrast, lambda and noise). Each is its own process, as a user runs them: the dry run,
then ``generate --workers 0``. Written to ``benchmarks/results/generate_estimates.json``: each
job's estimate, its terms, the measured seconds and the relative error, and whether every probed
job's error is within :data:`sim.dataset.ESTIMATE_ERROR` (the bound ``--dry-run`` states); the
error of the sweep's total; the error each seed would have had from the mean of the others (what
a seed that is not probed gets in a larger sweep); and each job's
frame render (``timings_s``' ``frame_motion + frame_edges + render``) beside its event render
(``event_render``). About 3 minutes.

**Warm workers** (``--warm``): issue 36's per-job start-up, before and after. Six 0.05-s
slider_close jobs at 48x36 on a 2-worker local cluster (:func:`sim.dataset.generate`), each run
into a fresh Dr.Jit kernel cache (``DRJIT_CACHE_DIR``, empty) and again with the cache it
filled: with ``warm=False`` (each worker's first job pays the imports, the variant and its
kernels) and ``warm=True`` (each worker warmed once as it starts,
:func:`sim.dataset.warm_worker`). Reported: each job's own wall seconds (``manifest.csv``'s
``wall_s``), the first job of each worker against the others (the start-up a job pays), the
whole ``generate`` call, and the cache's file count after each run (a second run that finds the
first's kernels adds none). Written to ``benchmarks/results/generate_warm.json``. About 3
minutes.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
RESULTS = ROOT / "benchmarks" / "results"
SIMULATE_S_PER_SIMULATED_S = 25.0
"""The cost of one 240x180 6-DoF simulated second on one core of this machine, s (issue 24's
figure, ``evfuse run boxes_6dof --t0 3.5 --t1 5.5``): the input of the 10-s projection."""


def sweep_text(quick: bool) -> str:
    """The benchmark's 12-job sweep."""
    sensor, t1 = ("64x48", 0.05) if quick else ("120x90", 0.1)
    return f"""name = "bench_generate"
seeds = [1, 2]

[[scenes]]
name = "slider_close"

[[scenes]]
name = "boxes_6dof"

[[scenes]]
family = "sphere"
radius = 0.3

[grid]
sensor = "{sensor}"
t0 = 0.0
t1 = {t1}
contrast = [0.2, 0.3]
"""


def configurations(cores: int) -> list[tuple[str, list[str]]]:
    """(label, flags) of each run: serial, the default cluster, other splits."""
    runs = [("serial in-process", ["--workers", "0"]),
            (f"default cluster ({cores} x 1)", []),
            ("1 worker x 1 thread", ["--workers", "1", "--threads", "1"]),
            (f"1 worker x {cores} threads", ["--workers", "1", "--threads", str(cores)])]
    if cores > 1:
        runs.append((f"{2 * cores} workers x 1 thread", ["--workers", str(2 * cores)]))
    return runs


def run_generate(sweep: Path, out: Path, flags: list[str]) -> dict:
    """One ``evfuse generate`` process: its wall seconds and the manifest's rows."""
    from sim.dataset import read_manifest

    command = [sys.executable, "-m", "fusion.cli", "generate", str(sweep), "--out", str(out),
               "--quiet", *flags]
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    launch, clock = time.time(), time.perf_counter()
    done = subprocess.run(command, env=env, capture_output=True, text=True)
    wall = time.perf_counter() - clock
    if done.returncode != 0:
        raise RuntimeError(f"{' '.join(command)} failed:\n{done.stderr[-2000:]}")
    times = {}
    for line in (out / "runs.log").read_text().splitlines():
        event, _, _, stamp = line.split()[:4]
        times.setdefault(event, []).append(float(stamp.removeprefix("t=")))
    return {"wall_s": wall, "rows": read_manifest(out),
            "start_s": min(times["start"]) - launch,
            "span_s": max(times["done"]) - min(times["start"])}


def scheduler_overhead(tasks: int = 1000) -> dict:
    """Seconds per empty task through the default local cluster, and per manifest rewrite."""
    from distributed import Client, LocalCluster

    from sim.dataset import default_cluster_size, write_manifest

    workers, threads = default_cluster_size()
    with LocalCluster(n_workers=workers, threads_per_worker=threads, processes=True,
                      dashboard_address=None, silence_logs=50) as cluster, \
            Client(cluster) as client:
        client.gather(client.map(abs, range(-20, 0), pure=False))              # warm
        clock = time.perf_counter()
        futures = client.map(abs, range(-tasks, 0), pure=False)
        client.gather(futures)
        per_task = (time.perf_counter() - clock) / tasks
    rows = [{"job_id": f"job-{i}", "path": f"jobs/job-{i}", "status": "done", "seed": i,
             "contrast": 0.2, "events": 123456, "output_hash": "0" * 64} for i in range(1000)]
    with tempfile.TemporaryDirectory() as tmp:
        clock = time.perf_counter()
        for _ in range(5):
            write_manifest(tmp, rows, ["contrast"])
        manifest = (time.perf_counter() - clock) / 5
    return {"task_s": per_task, "manifest_1000_rows_s": manifest}


def projection(job_s: float, overhead_s: float, start_s: float,
               workers=(1, 8, 64)) -> list[dict]:
    """Hours for 1,000 jobs of ``job_s`` seconds each (plus ``overhead_s``) on W workers."""
    return [{"workers": w, "hours": (1000 * (job_s + overhead_s) / w + start_s) / 3600}
            for w in workers]


FRAME_RENDER = ("frame_motion", "frame_edges", "render")
"""``timings_s``' keys of the frames' renders (their motion and edge looks included): what the
issue compares with the event render."""
FRAME_STAGE = ("frame_setup", "depth", "exposure_control", "frame_motion", "frame_edges",
               "render", "frame_sensor", "write")
"""Every ``timings_s`` key of the frame stage."""
ESTIMATE_SEEDS = 4
"""Tabletop seeds (0, 1, ...) whose estimates ``--estimates`` checks."""


def estimates_sweep() -> str:
    """``sweeps/tabletop.toml`` cut to :data:`ESTIMATE_SEEDS` seeds at 240x180."""
    text = (ROOT / "sweeps" / "tabletop.toml").read_text()
    text = text.replace("seeds = { first = 0, count = 200 }",
                        f"seeds = {{ first = 0, count = {ESTIMATE_SEEDS} }}")
    text = text.replace('sensor = ["240x180", "346x260"]', 'sensor = "240x180"')
    assert f"count = {ESTIMATE_SEEDS}" in text and 'sensor = "240x180"' in text
    return text


def check_estimates() -> dict:
    """``--dry-run``'s estimates against the jobs' measured wall seconds (module docstring)."""
    from sim.dataset import ESTIMATE_ERROR

    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    with tempfile.TemporaryDirectory(prefix="bench-estimates-") as tmp:
        sweep = Path(tmp) / "tabletop4.toml"
        sweep.write_text(estimates_sweep())
        dump = Path(tmp) / "estimates.json"
        code = ("import json, sys; from sim.dataset import estimate_jobs, load_sweep; "
                "rows = estimate_jobs(load_sweep(sys.argv[1])); "
                "json.dump(rows, open(sys.argv[2], 'w'))")
        clock = time.perf_counter()
        subprocess.run([sys.executable, "-c", code, str(sweep), str(dump)], env=env,
                       check=True, capture_output=True, text=True)
        dry_run_s = time.perf_counter() - clock
        estimated = {row["job_id"]: row for row in json.loads(dump.read_text())}
        run = run_generate(sweep, Path(tmp) / "out", ["--workers", "0"])
        timings = {row["job_id"]: json.loads((Path(tmp) / "out" / row["path"] /
                                              "sequence.json").read_text())["timings_s"]
                   for row in run["rows"]}
    jobs = []
    for row in run["rows"]:
        estimate = estimated[row["job_id"]]
        spent = timings[row["job_id"]]
        frames_s = sum(spent.get(k, 0.0) for k in FRAME_RENDER)
        jobs.append({"job_id": row["job_id"], "seed": row["seed"], "noise": row.get("noise"),
                     "lam": row.get("lam"), "events": row["events"],
                     "estimate_s": estimate["estimate_s"], "probed": estimate["probed"],
                     "parts": estimate["parts"], "spread_s": estimate["spread_s"],
                     "measured_s": row["wall_s"],
                     "error": estimate["estimate_s"] / row["wall_s"] - 1,
                     "frame_render_s": frames_s, "event_render_s": spent["event_render"],
                     "frames_s": sum(spent.get(k, 0.0) for k in FRAME_STAGE)})
        j = jobs[-1]
        print(f"{j['job_id']:<26} estimate {j['estimate_s']:6.1f} s "
              f"({'probed' if j['probed'] else 'mean of probed seeds'}), measured "
              f"{j['measured_s']:6.1f} s: {100 * j['error']:+.1f} % | frame render "
              f"{j['frame_render_s']:.2f} s, event render {j['event_render_s']:.2f} s",
              flush=True)
    worst = max(abs(j["error"]) for j in jobs if j["probed"])
    # A seed that is not probed gets the probed seeds' mean: each seed against the others'.
    for j in jobs:
        others = [k["estimate_s"] for k in jobs if k is not j]
        j["mean_of_others_s"] = sum(others) / len(others)
        j["mean_of_others_error"] = j["mean_of_others_s"] / j["measured_s"] - 1
    total_error = sum(j["estimate_s"] for j in jobs) / sum(j["measured_s"] for j in jobs) - 1
    print(f"dry run {dry_run_s:.1f} s; largest error of a probed job {100 * worst:.1f} % "
          f"(bound {100 * ESTIMATE_ERROR:.0f} %: "
          f"{'held' if worst <= ESTIMATE_ERROR else 'BROKEN'}); total {100 * total_error:+.1f} "
          "%; each seed from the others' mean: "
          + ", ".join(f"{100 * j['mean_of_others_error']:+.0f} %" for j in jobs))
    frames_under = all(j["frame_render_s"] <= j["event_render_s"] for j in jobs)
    print(f"frame render <= event render on every job: {frames_under}")
    result = {"sweep": "sweeps/tabletop.toml, seeds 0-3, 240x180, 2 s", "dry_run_s": dry_run_s,
              "frame_render_under_event_render": frames_under,
              "generate_wall_s": run["wall_s"], "jobs": jobs, "largest_error": worst,
              "total_error": total_error,
              "bound": ESTIMATE_ERROR, "within_bound": worst <= ESTIMATE_ERROR,
              "machine": "shared 2-core machine; llvm_ad_rgb"}
    RESULTS.mkdir(exist_ok=True)
    (RESULTS / "generate_estimates.json").write_text(json.dumps(result, indent=2))
    print(f"written to {RESULTS / 'generate_estimates.json'}")
    return result


WARM_SWEEP = """name = "warm"
seeds = [1, 2, 3, 4, 5, 6]

[[scenes]]
name = "slider_close"

[grid]
sensor = "48x36"
t0 = 0.0
t1 = 0.05
"""


def warm_workers() -> dict:
    """Per-job start-up on 2 workers, cold and warmed workers, cold and filled kernel cache
    (module docstring, ``--warm``)."""
    from sim.dataset import generate, read_manifest

    runs = []
    with tempfile.TemporaryDirectory(prefix="bench-warm-") as tmp:
        sweep = Path(tmp) / "warm.toml"
        sweep.write_text(WARM_SWEEP)
        for warm in (False, True):
            cache = Path(tmp) / f"cache-{warm}"
            cache.mkdir()
            os.environ["DRJIT_CACHE_DIR"] = str(cache)          # the workers inherit it
            for cache_state in ("empty", "filled"):
                out = Path(tmp) / f"out-{warm}-{cache_state}"
                result = generate(sweep, out, workers=2, threads=1, warm=warm,
                                  report=lambda line: None)
                rows = read_manifest(out)
                pids = {}
                for line in (out / "runs.log").read_text().splitlines():
                    event, job_id, pid = line.split()[:3]
                    if event == "start":
                        pids.setdefault(pid, []).append(job_id)
                firsts = {jobs[0] for jobs in pids.values()}
                first = [float(r["wall_s"]) for r in rows if r["job_id"] in firsts]
                later = [float(r["wall_s"]) for r in rows if r["job_id"] not in firsts]
                runs.append({"warm": warm, "cache": cache_state, "generate_s": result.wall_s,
                             "first_job_s": sum(first) / len(first),
                             "later_job_s": sum(later) / len(later) if later else None,
                             "job_s": [float(r["wall_s"]) for r in rows],
                             "warm_s": [w.get("warm_s") for w in result.workers],
                             "cache_files": len(os.listdir(cache)),
                             "hashes": [r["output_hash"] for r in rows]})
                r = runs[-1]
                print(f"warm={warm!s:<5} cache {cache_state:<6}: generate {r['generate_s']:5.1f} s"
                      f", first job of a worker {r['first_job_s']:5.2f} s, later jobs "
                      f"{r['later_job_s'] or 0:5.2f} s, workers' warm-up "
                      f"{', '.join(f'{w:.1f}' for w in r['warm_s'] if w is not None) or '-'} s,"
                      f" kernel cache {r['cache_files']} files", flush=True)
        os.environ.pop("DRJIT_CACHE_DIR")
    same = all(r["hashes"] == runs[0]["hashes"] for r in runs)
    print(f"same bytes in every run: {same}")
    result = {"machine": "shared 2-core machine, loaded by other sessions; llvm_ad_rgb",
              "sweep": WARM_SWEEP, "runs": runs, "same_hashes": same}
    RESULTS.mkdir(exist_ok=True)
    (RESULTS / "generate_warm.json").write_text(json.dumps(result, indent=2))
    print(f"written to {RESULTS / 'generate_warm.json'}")
    return result


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="64x48, 0.05 s jobs")
    parser.add_argument("--estimates", action="store_true",
                        help="only check --dry-run's estimates against real tabletop jobs")
    parser.add_argument("--warm", action="store_true",
                        help="only measure the per-job start-up with and without warm workers")
    args = parser.parse_args(argv)
    if args.estimates:
        return check_estimates()
    if args.warm:
        return warm_workers()
    from sim.dataset import default_cluster_size, parse_sweep

    cores = default_cluster_size()[0]
    text = sweep_text(args.quick)
    jobs = parse_sweep(text).jobs
    simulated = sum(float(j.params["t1"]) - float(j.params["t0"]) for j in jobs)
    rows = []
    with tempfile.TemporaryDirectory(prefix="bench-generate-") as tmp:
        sweep = Path(tmp) / "sweep.toml"
        sweep.write_text(text)
        hashes = None
        for label, flags in configurations(cores):
            out = Path(tmp) / f"out{len(rows)}"
            run = run_generate(sweep, out, flags)
            mine = [r["output_hash"] for r in run["rows"]]
            hashes = hashes or mine
            job_s = [float(r["wall_s"]) for r in run["rows"]]
            rows.append({"config": label, "flags": " ".join(flags) or "(default)",
                         "wall_s": run["wall_s"], "jobs_per_hour": 3600 * len(jobs) / run["wall_s"],
                         "simulated_s_per_hour": 3600 * simulated / run["wall_s"],
                         "start_s": run["start_s"], "span_s": run["span_s"],
                         "steady_jobs_per_hour": 3600 * len(jobs) / run["span_s"],
                         "mean_job_s": sum(job_s) / len(job_s),
                         "same_hashes_as_serial": mine == hashes})
            r = rows[-1]
            print(f"{label:<26} {r['wall_s']:6.1f} s  {r['jobs_per_hour']:6.0f} jobs/h  "
                  f"{r['simulated_s_per_hour']:6.1f} sim s/h | start {r['start_s']:5.1f} s, "
                  f"first start to last done {r['span_s']:5.1f} s: "
                  f"{r['steady_jobs_per_hour']:6.0f} jobs/h | mean job {r['mean_job_s']:.2f} s"
                  f" | same bytes: {mine == hashes}", flush=True)
            shutil.rmtree(out)
    overhead = scheduler_overhead()
    print(f"scheduler: {1e3 * overhead['task_s']:.2f} ms per empty task; manifest of 1,000 rows "
          f"rewritten in {1e3 * overhead['manifest_1000_rows_s']:.1f} ms")
    default = rows[1]
    fastest = max(rows, key=lambda r: r["jobs_per_hour"])
    per_job_overhead = overhead["task_s"] + overhead["manifest_1000_rows_s"]
    start_s = default["start_s"]
    paper = {
        "this_sweep": projection(default["mean_job_s"], per_job_overhead, max(start_s, 0.0)),
        "ten_s_240x180": projection(10 * SIMULATE_S_PER_SIMULATED_S, per_job_overhead,
                                    max(start_s, 0.0)),
    }
    steadiest = max(rows, key=lambda r: r["steady_jobs_per_hour"])
    print(f"default vs fastest ({fastest['config']}): "
          f"{100 * (default['jobs_per_hour'] / fastest['jobs_per_hour'] - 1):+.1f} % end to end;"
          f" first start to last done vs the fastest so ({steadiest['config']}): "
          f"{100 * (default['steady_jobs_per_hour'] / steadiest['steady_jobs_per_hour'] - 1):+.1f}"
          " %")
    for name, table in paper.items():
        print(f"1,000 jobs ({name}): " + ", ".join(f"{r['workers']} workers {r['hours']:.2f} h"
                                                   for r in table))
    result = {"quick": args.quick, "cores": cores, "jobs": len(jobs),
              "simulated_s": simulated, "machine": "shared 2-core machine, loaded by other "
              "sessions; llvm_ad_rgb", "rows": rows, "overhead": overhead,
              "start_s": start_s, "paper": paper,
              "default_vs_fastest": default["jobs_per_hour"] / fastest["jobs_per_hour"] - 1,
              "default_vs_fastest_steady": default["steady_jobs_per_hour"]
              / steadiest["steady_jobs_per_hour"] - 1}
    RESULTS.mkdir(exist_ok=True)
    (RESULTS / "generate.json").write_text(json.dumps(result, indent=2))
    print(f"written to {RESULTS / 'generate.json'}")
    return result


if __name__ == "__main__":
    main()
