"""``evfuse generate``: a sweep's jobs run on Dask distributed into a dataset folder
(:func:`generate`).

Each job is one :func:`sim.simulate.simulate` in a worker (:func:`sim.dataset.run_job`: the
library call; a worker keeps its interpreter, imports and compiled kernels between jobs). By
default a :class:`distributed.LocalCluster` of one single-threaded worker process per core
(see :func:`default_cluster_size`); ``scheduler`` sends the same jobs to an existing cluster;
``workers=0`` runs them one by one in this process, without Dask.

Nothing is lost: the manifest is rewritten as each job finishes; a complete job folder is never
run again (``resume``); a job interrupted inside a worker resumes from its checkpoint where it
runs again; Dask runs a killed worker's job elsewhere; a job that raises is retried
(``retries``), then recorded as failed with its one-line error while the others go on.
"""

from __future__ import annotations

import os
import shutil
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from sim._summary import summary_repr
from sim.dataset._jobs import JOBS_FOLDER, RUNS_LOG, Job, run_job
from sim.dataset._manifest import job_record, read_manifest, write_manifest
from sim.dataset._sweep import Sweep, load_sweep
from sim.dataset._workers import KERNEL_CACHE_ENV, device_name, kernel_cache_dir, worker_plugin
from sim.output import (
    MARKER,
    OutputError,
    check_output_dir,
    claim_folder,
    list_written_files,
    partial_dir,
    release_claim,
    swap_in,
    write_marker,
)
from sim.validation import ParameterError
from sim.variant import active_variant

__all__ = ["SWEEP_COPY", "GenerateResult", "default_cluster_size", "generate"]

SWEEP_COPY = "sweep.toml"
"""``DIR/sweep.toml``: a byte copy of the sweep file, which ``resume`` compares."""


@dataclass(frozen=True)
class GenerateResult:
    """What :func:`generate` did.

    Attributes
    ----------
    out : Path
        The dataset folder.
    rows : list of dict
        The manifest's rows, in the sweep's job order.
    ran, skipped, failed : int
        Jobs simulated by this call, already complete (``resume``), failed.
    wall_s : float
        Seconds of this call from the first job submitted to the last finished.
    cluster : str
        How the jobs ran (``in-process``, ``LocalCluster 2 x 1 thread``, the scheduler).
    workers : tuple of dict
        Each Dask worker's warm-up (:func:`sim.dataset._workers.warm_worker`: ``variant``,
        ``device``, ``kernel_cache``, ``kernel_cache_files``, ``warm_s``, ``warm_error``);
        in process, this process's variant and device alone; empty when no job ran.
    """

    out: Path
    rows: list[dict]
    ran: int
    skipped: int
    failed: int
    wall_s: float
    cluster: str
    workers: tuple[dict, ...] = ()

    __repr__ = summary_repr


def default_cluster_size() -> tuple[int, int]:
    """The default local cluster: ``(workers, threads per worker)`` = (cores, 1).

    One single-threaded process per core: two simulations cannot share an interpreter
    (Mitsuba's and Dr.Jit's state is process-wide; :func:`sim.dataset.run_job` runs one at a
    time per process, so a worker's extra threads only wait), and each job's renders already
    use Dr.Jit's thread pool while its emulator runs on one core. Each local worker's Dr.Jit
    pool is its share of the cores (cores // workers), so that the workers' render threads do
    not oversubscribe them. Measured against the other splits by
    ``benchmarks/bench_generate.py`` (README, "Datasets")."""
    return _cores(), 1


def _one_line(error: BaseException) -> str:
    text = f"{type(error).__name__}: {error}".strip().splitlines()
    return (text[0] if text else type(error).__name__)[:400]


def _prepare(sweep: Sweep, out: Path, resume: bool, overwrite: bool) -> Path:
    """Create (or check, with ``resume``) the dataset folder, its marker and sweep copy, and
    claim it for this process (:func:`sim.output.claim_folder`); return the folder to fill.

    A new dataset is filled in place (``out``); one that replaces a complete ``out``
    (``overwrite``) is built in ``<out>.partial`` beside it, and swapped in by :func:`_finish`
    only when all its jobs have run, so that an interrupted overwrite leaves the old dataset
    untouched (``resume`` continues ``<out>.partial`` when there is one)."""
    inputs = [sweep.source] if not sweep.source.startswith("<") else []
    inputs += [job.scene["path"] for job in sweep.jobs if "path" in job.scene]
    partial = partial_dir(out)
    if resume:
        started = partial if (partial / SWEEP_COPY).is_file() else out
        if started == partial:
            check_output_dir(out, overwrite, inputs)
        if not (started / MARKER).is_file() or not (started / SWEEP_COPY).is_file():
            raise OutputError(f"{{resume}}: {ParameterError.literal(out)} is not a dataset "
                              "folder evfuse generate started (no .evfuse marker or "
                              f"{SWEEP_COPY}); drop {{resume}} to start it", resume="resume")
        if (started / SWEEP_COPY).read_bytes() != sweep.text.encode():
            raise OutputError(f"{{resume}}: {ParameterError.literal(out)} was generated from "
                              f"another sweep ({started / SWEEP_COPY} differs from "
                              f"{ParameterError.literal(sweep.source)}); resume with the same "
                              "sweep file, or use {overwrite}", resume="resume",
                              overwrite="overwrite")
        claim_folder(started, out, "evfuse generate")
        return started
    check_output_dir(out, overwrite, inputs)
    if out.exists() and any(out.iterdir()):     # overwrite: build beside it, swap in when done
        if partial.exists():
            shutil.rmtree(partial)              # evfuse's, unclaimed (check_output_dir)
        work = partial
    else:
        work = out
    work.mkdir(parents=True, exist_ok=True)
    claim_folder(work, out, "evfuse generate")
    write_marker(work, "evfuse generate", inputs)
    (work / SWEEP_COPY).write_bytes(sweep.text.encode())
    return work


def _finish(work: Path, out: Path) -> None:
    """List the files of the complete dataset ``work`` in its marker, swap it in for ``out``
    if it was built beside it, and release the claim."""
    list_written_files(work)
    if work == out:
        release_claim(out)
    else:
        swap_in(work, out)


def _attempts(out: Path) -> dict[str, int]:
    """Each job's ``start`` lines in ``runs.log``."""
    counts: dict[str, int] = {}
    try:
        lines = (out / RUNS_LOG).read_text().splitlines()
    except FileNotFoundError:
        return counts
    for line in lines:
        parts = line.split()
        if len(parts) >= 2 and parts[0] == "start":
            counts[parts[1]] = counts.get(parts[1], 0) + 1
    return counts


def _row(job: Job, status: str, record: dict | None = None, error: str = "") -> dict:
    return {"job_id": job.job_id, "path": f"{JOBS_FOLDER}/{job.job_id}", "status": status,
            "error": error, "scene": job.label, "seed": job.seed, **job.params,
            **(record or {})}


def _client(scheduler: str | None, workers: int | None, threads: int | None,
            gpu: float | None = None, warm_job: Job | None = None, variant: str | None = None,
            warm: bool = True):
    """A Dask client, the cluster it made (None for ``scheduler``) and its description. With
    ``gpu`` each local worker declares ``GPU = 1`` (this machine's GPU, shared by them), so that
    the jobs' requests are met; a remote cluster's workers declare their own. Every worker is
    warmed once as it starts (``warm``, with ``warm_job``:
    :func:`sim.dataset._workers.worker_plugin`); a local cluster's workers share one Dr.Jit
    kernel cache (:func:`sim.dataset._workers.kernel_cache_dir`) and split the cores."""
    from distributed import Client, LocalCluster

    if scheduler is not None:
        client = Client(scheduler)
        client.register_plugin(worker_plugin(None, warm_job, variant, warm))
        return client, None, f"scheduler {scheduler}"
    n, t = default_cluster_size()
    n, t = workers or n, threads or t
    cluster = LocalCluster(n_workers=n, threads_per_worker=t, processes=True,
                           dashboard_address=":0" if _has_bokeh() else None, silence_logs=40,
                           resources={"GPU": 1.0} if gpu else None,
                           env={KERNEL_CACHE_ENV: str(kernel_cache_dir())})
    client = Client(cluster)
    client.register_plugin(worker_plugin(max(1, _cores() // n), warm_job, variant, warm))
    return client, cluster, f"LocalCluster {n} x {t} thread{'s' * (t > 1)}"


def _cores() -> int:
    """The cores this process may run on."""
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else \
        (os.cpu_count() or 1)


def _warm_records(client) -> tuple[dict, ...]:
    """Each worker's warm-up record (:func:`sim.dataset._workers.warm_worker`); none where the
    workers cannot be asked (the jobs run all the same)."""
    try:
        records = client.run(lambda dask_worker: getattr(dask_worker, "evfuse_warm", None))
    except Exception:
        return ()
    return tuple(record for record in records.values() if record)


def _has_bokeh() -> bool:
    """Whether Dask's dashboard can be served (it needs bokeh)."""
    import importlib.util

    return importlib.util.find_spec("bokeh") is not None


def generate(sweep: str | Path | Sweep, out: str | Path, *, scheduler: str | None = None,
             workers: int | None = None, threads: int | None = None, resume: bool = False,
             overwrite: bool = False, retries: int = 1, variant: str | None = None,
             gpu: float | None = None, profile: bool = False, warm: bool = True,
             report: Callable[[str], None] | None = None) -> GenerateResult:
    """Run a sweep's jobs into a dataset folder.

    Parameters
    ----------
    sweep : str, Path or Sweep
        A sweep file (:func:`sim.dataset.load_sweep`) or a loaded one.
    out : str or Path
        The dataset folder: ``.evfuse``, ``sweep.toml``, ``jobs/<job_id>/`` (sequence
        folders), ``manifest.csv`` (+ ``manifest.parquet`` with pyarrow), ``runs.log``.
    scheduler : str, optional
        Address of a running Dask scheduler (``tcp://head:8786``); default a
        :class:`distributed.LocalCluster` of :func:`default_cluster_size`.
    workers, threads : int, optional
        The local cluster's worker processes and threads per worker. ``workers=0`` runs the
        jobs one by one in this process, without Dask.
    resume : bool
        Continue the dataset in ``out`` (its ``sweep.toml`` must be this sweep's bytes):
        complete jobs are kept, interrupted ones resume from their checkpoint, failed ones are
        tried again.
    overwrite : bool
        Replace ``out`` if evfuse wrote it (its marker, listing every file it holds): the new
        dataset is built in ``<out>.partial`` and swapped in once all its jobs have run; the
        old one stays untouched until then (``resume`` continues an interrupted one).
    retries : int
        Times a job that raises is tried again (Dask's ``retries``) before it is recorded as
        failed.
    variant : str, optional
        Mitsuba variant of every job (default: simulate's choice on each worker).
    gpu : float, optional
        Each job's share of a worker's ``GPU`` resource (e.g. 1/16: sixteen jobs per GPU);
        a remote cluster's workers must declare it (``dask worker --resources GPU=1``), a local
        cluster's workers each declare ``GPU = 1`` (the one GPU they share; a share <= 1).
        None: none asked.
    profile : bool
        Each job's sequence folder also gets ``profile.json`` (:mod:`sim.profile`).
    warm : bool
        Warm each Dask worker once as it starts, before its first job (the variant, the
        imports and a few milliseconds of the first job's scene:
        :func:`sim.dataset._workers.warm_worker`); False leaves that to each worker's first
        job.
    report : callable, optional
        Called with each progress line (default: stderr; a tqdm bar on a terminal).

    Returns
    -------
    GenerateResult

    Raises
    ------
    OutputError
        ``out`` exists without ``resume``/``overwrite``; with ``resume``, not a dataset or
        another sweep's.
    SweepError
        The sweep file is invalid.
    """
    sweep = sweep if isinstance(sweep, Sweep) else load_sweep(sweep)
    out = Path(out).absolute()
    if retries < 0:
        raise ParameterError(f"{{retries}} {retries}: expected an integer >= 0",
                             retries="retries")
    if gpu is not None and not 0 < gpu:
        raise ParameterError(f"{{gpu}} {gpu}: expected a share of a GPU > 0", gpu="gpu")
    if gpu is not None and scheduler is None and gpu > 1:
        raise ParameterError(f"{{gpu}} {gpu}: a local cluster's workers share one GPU; expected "
                             "a share <= 1 (more GPUs a job: use a cluster, {scheduler})",
                             gpu="gpu", scheduler="scheduler")
    if scheduler is not None and (workers is not None or threads is not None):
        raise ParameterError("{workers} and {threads} size a local cluster; with {scheduler} "
                             "the cluster's workers are its own (start them with `dask worker "
                             "ADDRESS --nworkers N --nthreads 1`)", workers="workers",
                             threads="threads", scheduler="scheduler")
    work = _prepare(sweep, out, resume, overwrite)
    try:
        params = list(sweep.parameters)
        done = {row["job_id"]: row for row in (read_manifest(work) if resume and
                                               (work / "manifest.csv").is_file() else [])}
        rows: dict[str, dict] = {}
        todo: list[Job] = []
        for job in sweep.jobs:
            folder = work / JOBS_FOLDER / job.job_id
            old = done.get(job.job_id, {})
            if folder.is_dir() and old.get("status") == "done":
                rows[job.job_id] = {**old, **_row(job, "done")}
            elif folder.is_dir() and not job.generated:
                rows[job.job_id] = {**_row(job, "done", job_record(folder)),
                                    "attempts": _attempts(work).get(job.job_id, 0)}
            else:
                rows[job.job_id] = _row(job, "pending")
                todo.append(job)
        write_manifest(work, list(rows.values()), params)
        progress = _Progress(len(sweep.jobs), len(sweep.jobs) - len(todo), report)

        counts = {"ran": 0, "skipped": len(sweep.jobs) - len(todo), "failed": 0}

        def finish(job: Job, record: dict | None, error: str = "") -> None:
            counts["failed" if record is None else "ran" if record["ran"] else "skipped"] += 1
            attempts = _attempts(work).get(job.job_id, 0)
            status = "failed" if record is None else "done"
            rows[job.job_id] = {**_row(job, status, record, error), "attempts": attempts}
            write_manifest(work, list(rows.values()), params)
            progress.finished(job, record, error)

        clock = time.perf_counter()
        warmed: tuple[dict, ...] = ()
        if workers == 0 or not todo:
            cluster_name = "in-process"
            for job in todo:
                progress.running(1)
                try:
                    record = run_job(job, work, variant, profile)
                except Exception as error:
                    finish(job, None, _one_line(error))
                else:
                    finish(job, record)
            if todo and active_variant() is not None:
                warmed = ({"variant": active_variant(), "device": device_name(active_variant())},)
        else:
            client, cluster, cluster_name = _client(scheduler, workers, threads, gpu, todo[0],
                                                    variant, warm)
            warmed = _warm_records(client)
            link = client.dashboard_link if cluster is None or _has_bokeh() else None
            progress.say(f"generate: {len(todo)} jobs on {cluster_name}; dashboard: "
                         f"{link or 'none (install bokeh for it)'}")
            try:
                _run_on(client, todo, work, variant, retries, gpu, finish, progress, profile)
            finally:
                client.close()
                if cluster is not None:
                    cluster.close()
        wall = time.perf_counter() - clock
        progress.close()
    except BaseException:
        release_claim(work)
        raise
    _finish(work, out)
    return GenerateResult(out, list(rows.values()), counts["ran"], counts["skipped"],
                          counts["failed"], wall, cluster_name, warmed)


def _run_on(client, todo: list[Job], out: Path, variant: str | None, retries: int,
            gpu: float | None, finish, progress: _Progress, profile: bool = False) -> None:
    """Submit the jobs to a Dask client and record each as it finishes."""
    from distributed import as_completed

    resources = {"GPU": gpu} if gpu else None
    futures = {}
    for job in todo:
        future = client.submit(run_job, job, str(out), variant, profile,
                               key=f"evfuse-{job.job_id}", retries=retries, pure=False,
                               resources=resources)
        futures[future] = job
    for future in as_completed(futures):
        job = futures[future]
        threads = client.nthreads()
        progress.running(sum(min(len(tasks), threads.get(worker, 1))
                             for worker, tasks in client.processing().items()))
        if future.status == "finished":
            finish(job, future.result())
        else:
            try:
                error = future.exception()
            except Exception as cause:           # a cancelled future
                error = cause
            finish(job, None, _one_line(error))
        future.release()


class _Progress:
    """Jobs done / running / failed, events and simulated seconds per wall second: a tqdm bar
    on a terminal, else one line per finished job."""

    def __init__(self, total: int, skipped: int, report: Callable[[str], None] | None) -> None:
        self.total, self.done, self.failed, self.now = total, skipped, 0, 0
        self.events, self.simulated, self.clock = 0, 0.0, time.perf_counter()
        self.report = report
        self.bar = None
        if report is None and sys.stderr.isatty():
            from tqdm import tqdm

            self.bar = tqdm(total=total, initial=skipped, unit="job", file=sys.stderr)
        if skipped:
            self.say(f"generate: {skipped} of {total} jobs already complete")

    def say(self, line: str) -> None:
        if self.bar is not None:
            self.bar.write(line)
        elif self.report is not None:
            self.report(line)
        else:
            print(line, file=sys.stderr, flush=True)

    def running(self, count: int) -> None:
        self.now = count

    def finished(self, job: Job, record: dict | None, error: str) -> None:
        wall = max(time.perf_counter() - self.clock, 1e-9)
        if record is None:
            self.failed += 1
            what = f"failed: {error}"
        else:
            self.done += 1
            self.events += record.get("events") or 0
            self.simulated += record["duration_s"]
            what = (f"done: {record.get('events') or 0} events, {record['duration_s']:g} s "
                    f"simulated")
        rates = (f"{self.events / wall:,.0f} events/s, {self.simulated / wall:.3g} simulated "
                 "s per wall s")
        if self.bar is not None:
            self.bar.update(1)
            self.bar.set_postfix_str(f"running {self.now}, failed {self.failed}, {rates}")
            if record is None:
                self.bar.write(f"{job.job_id} {what}")
            return
        self.say(f"[{self.done + self.failed}/{self.total}: {self.done} done, {self.now} running, "
                 f"{self.failed} failed; {rates}] {job.job_id} {what}")

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()
