"""``evfuse generate`` on Dask (:mod:`sim.dataset`): a real LocalCluster gives the same bytes as
the jobs run one by one in this process; a worker killed mid-job and a generate interrupted
mid-job both end with the same dataset, no job run twice to completion; a job whose scene
cannot render is recorded with its error while the others complete."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

from sim.dataset import generate, load_sweep, output_hash, read_manifest
from sim.output import OutputError
from sim.validation import ParameterError

ROOT = Path(__file__).resolve().parent.parent
TINY = ROOT / "sweeps" / "tiny.toml"
# Two jobs: a short one, then one long enough (~2.5 s here) to be stopped in the middle.
LONG = """seeds = [5]

[[scenes]]
name = "slider_close"

[grid]
sensor = "128x96"
t1 = [0.05, 0.5]
"""
CONTRACT = ("job_id", "path", "status", "error", "scene", "seed", "attempts", "events",
            "frames", "renders", "pixel_samples", "duration_s", "wall_s", "output_hash",
            "evfuse_version", "mitsuba_version", "drjit_version", "numpy_version")
QUIET = {"report": lambda line: None}


def _tree(folder: Path) -> dict[str, bytes]:
    """A dataset's job files (relative path -> bytes), ``sequence.json`` without timings."""
    files = {}
    for path in sorted((folder / "jobs").rglob("*")):
        if path.is_file():
            data = path.read_bytes()
            if path.name == "sequence.json":
                record = json.loads(data)
                record.pop("timings_s")
                data = json.dumps(record, sort_keys=True).encode()
            files[path.relative_to(folder).as_posix()] = data
    return files


def _runs(folder: Path) -> list[list[str]]:
    return [line.split() for line in (folder / "runs.log").read_text().splitlines()]


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    """Both sweeps run one by one in this process (no Dask)."""
    root = tmp_path_factory.mktemp("reference")
    long_sweep = root / "long.toml"
    long_sweep.write_text(LONG)
    generate(TINY, root / "tiny", workers=0, **QUIET)
    generate(long_sweep, root / "long", workers=0, **QUIET)
    return root


def test_a_local_cluster_writes_the_bytes_of_in_process_runs(reference, tmp_path):
    out = tmp_path / "tiny"
    result = generate(TINY, out, workers=2, threads=1, **QUIET)
    assert result.cluster == "LocalCluster 2 x 1 thread"
    assert (result.ran, result.failed, result.skipped) == (4, 0, 0)
    mine, theirs = _tree(out), _tree(reference / "tiny")
    assert sorted(mine) == sorted(theirs) and len(mine) > 40
    different = [name for name in mine if mine[name] != theirs[name]]
    assert not different
    rows = read_manifest(out)
    assert [r["job_id"] for r in rows] == [j.job_id for j in load_sweep(TINY).jobs]
    assert all(set(CONTRACT) <= set(r) for r in rows)
    assert {r["status"] for r in rows} == {"done"} and {r["attempts"] for r in rows} == {1}
    assert [r["output_hash"] for r in rows] == [r["output_hash"] for r in
                                                read_manifest(reference / "tiny")]
    for row in rows:
        assert row["output_hash"] == output_hash(out / row["path"])
        assert int(row["events"]) > 0 and float(row["duration_s"]) == 0.05
    pytest.importorskip("pyarrow")
    import pyarrow.parquet as pq

    table = pq.read_table(out / "manifest.parquet").to_pylist()
    assert [r["output_hash"] for r in table] == [r["output_hash"] for r in rows]
    assert (out / "sweep.toml").read_bytes() == TINY.read_bytes()


def _default_sigint() -> None:
    """In a child before exec: SIGINT handled by default and not blocked."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)
    signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})


def _stop_when_checkpointed(out: Path, job_id: str, stop) -> threading.Thread:
    """A thread that waits for the job's first checkpoint and then calls ``stop(pid)`` with the
    process that runs it (read from runs.log), waiting up to 290 s (under the callers' 300-s
    limit) for the checkpoint and for the job's start line."""
    def watch():
        checkpoint = out / "jobs" / f"{job_id}.partial" / ".checkpoint" / "checkpoint.json"
        deadline = time.monotonic() + 290
        while time.monotonic() < deadline:
            starts = [r for r in _runs(out) if r[:2] == ["start", job_id]] \
                if checkpoint.is_file() and (out / "runs.log").is_file() else []
            if starts:
                stop(int(starts[-1][2].split("=")[1]))
                return
            time.sleep(0.01)
    thread = threading.Thread(target=watch, daemon=True)
    thread.start()
    return thread


def test_gpu_shares_are_met_by_a_local_clusters_workers(reference, tmp_path):
    """``gpu`` (``--gpu-per-job``) asks each job for a share of a worker's ``GPU`` resource; a
    local cluster's workers declare one each, so the jobs run (no GPU is needed to schedule
    them: they render on this machine's variant) and write the in-process bytes; a share of
    more than the one GPU a local worker has is refused, not left waiting forever."""
    out = tmp_path / "tiny"
    result = generate(TINY, out, workers=2, threads=1, gpu=0.5, **QUIET)
    assert (result.ran, result.failed) == (4, 0)
    assert [r["output_hash"] for r in read_manifest(out)] == \
        [r["output_hash"] for r in read_manifest(reference / "tiny")]
    with pytest.raises(ParameterError, match="share one GPU"):
        generate(TINY, tmp_path / "two", workers=2, gpu=2.0, **QUIET)


def test_warm_workers_share_one_kernel_cache_and_write_the_in_process_bytes(reference, tmp_path,
                                                                            monkeypatch):
    """Each worker is warmed once as it starts (the variant, the imports, a few milliseconds of
    the first job) and every worker reads and fills the one Dr.Jit kernel cache of
    ``DRJIT_CACHE_DIR``: a second dataset's workers find kernels the first's compiled, and
    compile fewer. (Some kernels, those with a devirtualised call such as Mitsuba's
    ``Shape::compute_surface_interaction``, hash differently in each process and are compiled
    again: the cache grows on every run; a kernel without one is found again:
    ``tests/test_generate_workers.py``.) The bytes are the in-process ones."""
    cache = tmp_path / "kernels"
    monkeypatch.setenv("DRJIT_CACHE_DIR", str(cache))
    first = generate(TINY, tmp_path / "first", workers=2, threads=1, **QUIET)
    assert (first.ran, first.failed) == (4, 0) and len(first.workers) == 2
    assert {w["kernel_cache"] for w in first.workers} == {str(cache)}
    assert all(w["warm_error"] == "" and w["warm_s"] > 0 for w in first.workers)
    assert {w["variant"] for w in first.workers} == {r["render"]["variant"] for r in (
        json.loads((tmp_path / "first" / row["path"] / "sequence.json").read_text())
        for row in first.rows)}
    assert _tree(tmp_path / "first") == _tree(reference / "tiny")
    compiled = len(os.listdir(cache))
    assert compiled > 10
    second = generate(TINY, tmp_path / "second", workers=2, threads=1, **QUIET)
    assert second.failed == 0
    assert len(os.listdir(cache)) - compiled < compiled        # 17 and 27 of 59 and 49 seen


def test_a_killed_workers_job_runs_again_from_its_checkpoint(reference, tmp_path):
    sweep = tmp_path / "long.toml"
    sweep.write_text(LONG)
    long_id = load_sweep(sweep).jobs[1].job_id
    out = tmp_path / "killed"
    killed = []
    watcher = _stop_when_checkpointed(
        out, long_id, lambda pid: (killed.append(pid), os.kill(pid, signal.SIGKILL)))
    result = generate(sweep, out, workers=1, threads=1, **QUIET)
    watcher.join(1)
    assert killed, "the job finished before it could be killed"
    assert killed[0] != os.getpid()                      # a worker, not this process
    assert result.failed == 0 and _tree(out) == _tree(reference / "long")
    runs = [r for r in _runs(out) if r[1] == long_id]
    assert [r[0] for r in runs] == ["start", "start", "done"]
    assert runs[-1][-1] == "resumed=True" and runs[-1][2] != f"pid={killed[0]}"
    assert read_manifest(out)[1]["attempts"] == 2


def test_an_interrupted_generate_resumes_to_the_same_dataset(reference, tmp_path):
    sweep = tmp_path / "long.toml"
    sweep.write_text(LONG)
    short_id, long_id = (job.job_id for job in load_sweep(sweep).jobs)
    out = tmp_path / "interrupted"
    command = [sys.executable, "-m", "fusion.cli", "generate", str(sweep), "--out", str(out),
               "--workers", "0", "--quiet"]
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    # SIGINT at its default and unblocked in the child, whatever the test process has: an
    # ignored or blocked SIGINT is handed down through exec (ignored, Python installs no
    # KeyboardInterrupt handler). In a fresh clone's CI on two pytest-xdist workers, after
    # other tests, the child twice ran on to its end (exit 0); which test left SIGINT so in
    # the worker was not traced.
    process = subprocess.Popen(command, cwd=tmp_path, env=env, stdout=subprocess.PIPE,
                               stderr=subprocess.PIPE, text=True, preexec_fn=_default_sigint)
    watcher = _stop_when_checkpointed(out, long_id,
                                      lambda pid: os.kill(process.pid, signal.SIGINT))
    _, err = process.communicate(timeout=300)
    watcher.join(1)
    assert process.returncode == 130, err
    rows = {r["job_id"]: r for r in read_manifest(out)}     # a true manifest, mid-dataset
    assert rows[short_id]["status"] == "done" and rows[long_id]["status"] == "pending"
    assert not (out / "jobs" / long_id).exists()
    with pytest.raises(OutputError, match="not empty"):
        generate(sweep, out, workers=0, **QUIET)              # neither resume nor overwrite
    other = tmp_path / "other.toml"
    other.write_text(LONG.replace("[5]", "[6]"))
    with pytest.raises(OutputError, match="another sweep"):
        generate(other, out, workers=0, resume=True, **QUIET)
    result = generate(sweep, out, workers=0, resume=True, **QUIET)
    assert (result.ran, result.skipped, result.failed) == (1, 1, 0)
    assert _tree(out) == _tree(reference / "long")
    done = [r[1] for r in _runs(out) if r[0] == "done"]
    assert sorted(done) == sorted([short_id, long_id])      # each job completed once
    assert [r for r in _runs(out) if r[0] == "done" and r[1] == long_id][0][-1] == "resumed=True"


def test_a_job_that_cannot_render_is_recorded_and_the_others_complete(reference, tmp_path):
    scene = (ROOT / "scenes" / "slider_close.toml").read_text()
    scene = scene.replace('name = "slider_close"', 'name = "broken"')
    (tmp_path / "broken.toml").write_text(scene + '\n[[objects]]\nname = "lump"\ntype = "mesh"\n'
                                          'path = "lump.obj"\ncenter = [0.0, 0.3, 0.0]\n')
    (tmp_path / "lump.obj").write_text("v 1 2\nf 1 2 3 4\n")          # not a mesh
    sweep = tmp_path / "sweep.toml"
    sweep.write_text(TINY.read_text().replace("seeds = [1, 2]", "seeds = [1]")
                     .replace('family = "sphere"\nradius = 0.3', 'file = "broken.toml"'))
    out = tmp_path / "failing"
    result = generate(sweep, out, workers=1, retries=1, **QUIET)
    assert (result.ran, result.failed) == (1, 1)
    good, bad = read_manifest(out)
    assert good["status"] == "done" and good["error"] is None
    assert good["output_hash"] == read_manifest(reference / "tiny")[0]["output_hash"]
    assert bad["status"] == "failed" and bad["attempts"] == 2         # tried, retried once
    assert "lump.obj" in bad["error"] and "\n" not in bad["error"]
    assert bad["output_hash"] is None and not (out / bad["path"]).exists()
    # The failed row keeps the schema's types in the Parquet copy too.
    assert _parquet_schema(out) == _parquet_schema(reference / "tiny", out)


def _parquet_schema(folder: Path, like: Path | None = None) -> dict[str, str]:
    """Column -> Arrow type of ``manifest.parquet`` (the columns of ``like``'s, if given)."""
    pq = pytest.importorskip("pyarrow.parquet")
    schema = pq.read_schema(folder / "manifest.parquet")
    names = pq.read_schema((like or folder) / "manifest.parquet").names
    return {name: str(schema.field(name).type) for name in names if name in schema.names}


def test_the_manifest_keeps_its_types_through_resume(reference, tmp_path):
    """``--resume`` reloads the finished jobs' rows from ``manifest.csv``: the Parquet copy
    keeps the schema of a fresh run (numbers stay int64 and float64, an all-empty ``error``
    column stays a string column), the CSV its bytes, and the rows their types."""
    import shutil

    out = tmp_path / "tiny"
    shutil.copytree(reference / "tiny", out)
    fresh_csv = (out / "manifest.csv").read_bytes()
    fresh = _parquet_schema(out)
    result = generate(TINY, out, workers=0, resume=True, **QUIET)
    assert (result.ran, result.skipped) == (0, 4)
    assert (out / "manifest.csv").read_bytes() == fresh_csv
    assert _parquet_schema(out) == fresh
    assert {k: fresh[k] for k in ("seed", "attempts", "events", "frames", "renders",
                                  "pixel_samples", "duration_s", "wall_s", "error",
                                  "contrast")} == {
        "seed": "int64", "attempts": "int64", "events": "int64", "frames": "int64",
        "renders": "int64", "pixel_samples": "int64", "duration_s": "double",
        "wall_s": "double", "error": "string", "contrast": "double"}
    pq = pytest.importorskip("pyarrow.parquet")
    assert pq.read_table(out / "manifest.parquet").to_pylist() == read_manifest(out)
    row = read_manifest(out)[0]
    assert isinstance(row["events"], int) and isinstance(row["wall_s"], float)
    assert row["error"] is None


def test_a_manifest_cell_not_of_its_columns_type_is_refused(reference, tmp_path):
    import shutil

    out = tmp_path / "tiny"
    shutil.copytree(reference / "tiny", out)
    rows = read_manifest(out)
    text = (out / "manifest.csv").read_text()
    (out / "manifest.csv").write_text(text.replace(f",{rows[2]['events']},", ",many,", 1))
    with pytest.raises(ParameterError, match=r"manifest.csv:4: events 'many'; expected an "
                                             r"integer"):
        read_manifest(out)


def test_a_worker_with_two_threads_runs_its_jobs_one_at_a_time(reference, tmp_path):
    """Two simulations at once in one interpreter fail (Mitsuba's and Dr.Jit's state is
    process-wide); a 2-thread worker must give the serial bytes, every job at its first try."""
    out = tmp_path / "threads"
    result = generate(TINY, out, workers=1, threads=2, retries=0, **QUIET)
    assert result.failed == 0
    assert _tree(out) == _tree(reference / "tiny")
    assert {r["attempts"] for r in read_manifest(out)} == {1}


def test_dry_run_lists_every_job_with_a_probed_cost_and_writes_nothing(tmp_path, capsys):
    from fusion.cli import main

    assert main(["generate", str(TINY), "--dry-run", "--out", str(tmp_path / "d")]) == 0
    out = capsys.readouterr().out
    for job in load_sweep(TINY).jobs:
        line = next(line for line in out.splitlines() if job.job_id in line)
        seconds = float(line.split("~")[1].split(" s")[0])
        assert 0 < seconds < 120, line
    assert "total: ~" in out and not (tmp_path / "d").exists()
    assert main(["generate", str(TINY)]) == 2                     # no --out
    assert "--out DIR" in capsys.readouterr().err


def test_dry_run_probes_a_few_seeds_of_a_procedural_scene_and_gives_the_others_their_spread():
    """Five tabletop seeds: three probed (spread over the seeds, each its own estimate from
    three warm windows, frames counted per frame), the other two the mean of those, with
    their spread; the report says which is which and states the measured error bound."""
    from sim.dataset import ESTIMATE_ERROR, estimate_jobs, estimate_report, parse_sweep

    sweep = parse_sweep('seeds = [0, 1, 2, 3, 4]\n[[scenes]]\nprocedural = "tabletop"\n'
                        '[grid]\nsensor = "48x36"\nt1 = 0.3\ncontrast = 0.25\n')
    rows = estimate_jobs(sweep, probe_seconds=0.05, probe_seeds=3)
    assert [row["probed"] for row in rows] == [True, False, True, False, True]
    probed = [row for row in rows if row["probed"]]
    assert len({round(row["estimate_s"], 6) for row in probed}) == 3     # each seed its own
    for row in rows:
        parts = row["parts"]
        assert row["estimate_s"] == pytest.approx(sum(parts.values()))
        assert row["duration_s"] == pytest.approx(0.3) and parts["frames"] > 0
        assert parts["events"] > 0 and parts["setup"] > 0 and parts["draw"] > 0
    for row in rows[1::2]:
        low, high = row["spread_s"]
        costs = [p["estimate_s"] for p in probed]
        assert low == pytest.approx(min(costs)) and high == pytest.approx(max(costs))
        assert row["estimate_s"] == pytest.approx(sum(costs) / 3)
    text = estimate_report(sweep, rows)
    assert text.count("mean of probed seeds") == 2 and f"within {ESTIMATE_ERROR:.0%}" in text
    assert "spread" in text


def test_the_stated_estimate_error_is_the_benchmarks():
    """``--dry-run`` states :data:`sim.dataset.ESTIMATE_ERROR`; the committed result of
    ``benchmarks/bench_generate.py --estimates`` checked that bound on real jobs."""
    from sim.dataset import ESTIMATE_ERROR

    result = json.loads((ROOT / "benchmarks" / "results" / "generate_estimates.json")
                        .read_text())
    assert result["bound"] == ESTIMATE_ERROR and result["within_bound"]
    errors = [abs(job["error"]) for job in result["jobs"] if job["probed"]]
    assert len(errors) >= 4 and max(errors) == pytest.approx(result["largest_error"])
    assert max(errors) <= ESTIMATE_ERROR


def test_a_procedural_scene_is_drawn_from_the_seed_and_its_scene_file_resimulates_it(
        tmp_path):
    """``procedural = "tabletop"`` draws the job's scene from its seed
    (:func:`sim.scene.procedural.tabletop_scene`); the job folder's ``scene.toml``, simulated
    again alone with the job's parameters, gives the same events and frames (the DAVIS240C's
    APS, its exposure chosen by auto-exposure up to the file's ``max_exposure``)."""
    from sim.scene import parse_scene
    from sim.scene.procedural import tabletop_scene

    grid = ('[grid]\nsensor = "48x36"\nt1 = 0.05\ncontrast = 0.25\n'
            'frame_sensor = "davis240c_aps"\n')
    sweep = tmp_path / "procedural.toml"
    sweep.write_text(f'seeds = [3]\n[[scenes]]\nprocedural = "tabletop"\n{grid}')
    result = generate(sweep, tmp_path / "drawn", workers=0, **QUIET)
    assert result.failed == 0
    folder = tmp_path / "drawn" / result.rows[0]["path"]
    text = (folder / "scene.toml").read_text()
    drawn = tabletop_scene(3)                                  # the same seed, the same file
    body = [line for line in drawn.splitlines() if not line.startswith("seed =")]
    assert text.splitlines() == ["seed = 3", *body]
    assert parse_scene(text).seed == 3
    again = tmp_path / "again.toml"
    again.write_text(f'seeds = [3]\n[[scenes]]\nfile = "{folder / "scene.toml"}"\n{grid}')
    redo = generate(again, tmp_path / "again", workers=0, **QUIET)
    other = tmp_path / "again" / redo.rows[0]["path"]
    for name in ("events.txt", "images.txt", "depthmaps.txt", "groundtruth.txt", "calib.txt"):
        assert (other / name).read_bytes() == (folder / name).read_bytes(), name
    assert sorted(p.name for p in (other / "images").iterdir()) == \
        sorted(p.name for p in (folder / "images").iterdir())
    for image in (folder / "images").iterdir():
        assert (other / "images" / image.name).read_bytes() == image.read_bytes()
    frames = json.loads((folder / "sequence.json").read_text())["frames"]
    assert frames["max_exposure"] == 0.04 and len(frames["exposures_s"]) == frames["count"] >= 1
    assert frames == json.loads((other / "sequence.json").read_text())["frames"]


def test_the_dataset_card_reads_a_generated_dataset(reference, tmp_path):
    """``evfuse dataset`` on what ``evfuse generate`` wrote (sweeps/tiny.toml): values equal to
    an ulp (the jobs' durations) once broke its histograms."""
    import shutil

    from sim.dataset import open_dataset, write_card

    folder = tmp_path / "tiny"
    shutil.copytree(reference / "tiny", folder)
    summary = write_card(folder)
    assert (folder / "card.md").is_file() and summary.text()
    dataset = open_dataset(folder)
    assert len(dataset) >= 4 and len(dataset[0].events) > 0


def test_the_output_hash_is_independent_of_where_evfuse_is_installed(reference, tmp_path):
    """A built-in scene's job records the worker's install path (``sequence.json``'s
    ``scene.source``, the ``.evfuse`` marker's inputs): two workers installed in different
    folders write the same job with the same hash, and any other change still changes it."""
    import shutil

    job = next((reference / "tiny" / "jobs").glob("slider_close-*"))
    moved = tmp_path / job.name
    shutil.copytree(job, moved)
    for name in ("sequence.json", ".evfuse"):
        path = moved / name
        text = path.read_text()
        assert "scenes/slider_close.toml" in text
        path.write_text(text.replace(str(ROOT), "/elsewhere/evfuse"))
    assert output_hash(moved) == output_hash(job)
    record = json.loads((moved / "sequence.json").read_text())
    record["seed"] = record["seed"] + 1
    (moved / "sequence.json").write_text(json.dumps(record))
    assert output_hash(moved) != output_hash(job)


def test_an_interrupted_overwrite_leaves_the_old_dataset_and_resumes(reference, tmp_path,
                                                                     monkeypatch):
    """Issue 39 (1): the new dataset is built in <out>.partial and swapped in when complete."""
    import shutil

    import sim.dataset._run as run_module
    from sim.output import CLAIM, MARKER

    out = shutil.copytree(reference / "tiny", tmp_path / "D")
    before = {p.relative_to(out).as_posix(): p.read_bytes() for p in out.rglob("*")
              if p.is_file()}
    sweep = tmp_path / "long.toml"
    sweep.write_text(LONG)
    real_run_job, calls = run_module.run_job, []

    def second_job_interrupted(*args, **kwargs):
        calls.append(args)
        if len(calls) == 2:
            raise KeyboardInterrupt
        return real_run_job(*args, **kwargs)

    monkeypatch.setattr(run_module, "run_job", second_job_interrupted)
    with pytest.raises(KeyboardInterrupt):
        generate(sweep, out, workers=0, overwrite=True, **QUIET)
    after = {p.relative_to(out).as_posix(): p.read_bytes() for p in out.rglob("*")
             if p.is_file()}
    assert after == before                                   # the old dataset, untouched
    partial = tmp_path / "D.partial"
    assert (partial / "sweep.toml").read_text() == LONG and not (partial / CLAIM).exists()
    monkeypatch.setattr(run_module, "run_job", real_run_job)
    result = generate(sweep, out, workers=0, overwrite=True, resume=True, **QUIET)
    assert (result.ran, result.skipped, result.failed) == (1, 1, 0)
    assert _tree(out) == _tree(reference / "long") and not partial.exists()
    assert (out / "sweep.toml").read_text() == LONG and not (out / CLAIM).exists()
    assert "manifest.csv" in json.loads((out / MARKER).read_text())["files"]
