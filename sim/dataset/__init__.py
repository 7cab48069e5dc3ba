"""Datasets, not sequences (issue 24): many simulated sequences in one folder, how they are
generated from a sweep file on Dask (``evfuse generate``), and their loader.

A dataset folder holds ``manifest.csv`` (one row per job) and one sequence folder per job
(``jobs/<job_id>/``, as ``evfuse simulate --out`` writes it).

Modules (private; everything public is re-exported here):

- ``_sweep``: sweep files (:func:`load_sweep`, :func:`parse_sweep` -> :class:`Sweep`,
  :class:`SweepError`): scenes, seeds, a grid and drawn parameters, expanded into jobs.
- ``_jobs``: one job (:class:`Job`, its stable ``job_id``), the parameters a sweep may set
  (:data:`PARAMETERS`) and one job simulated in this process (:func:`run_job`).
- ``_run``: :func:`generate` (the jobs on a Dask ``LocalCluster``, an existing scheduler or in
  process; resumable).
- ``_estimate``: :func:`estimate_jobs` (``--dry-run``'s cost of each job, from warm probes at
  three places of its window, a few seeds of a generated scene).
- ``_manifest``: ``manifest.csv`` / ``.parquet`` (:func:`write_manifest`,
  :func:`read_manifest`) and a job folder's :func:`output_hash`.
- ``_loader``: :func:`open_dataset` (:class:`Dataset`: per standard frame a :class:`Sample`, the
  events since the previous frame with tonic's fields :data:`DATASET_EVENT_DTYPE`, the frame,
  its exact depth, flow, IMU, pose and calibration; :class:`EventWindow` for windows by time).
- ``_workers``: what a Dask worker does once before its first job (:func:`warm_worker`: the
  variant, the imports, a few milliseconds of the first job) and the one Dr.Jit kernel cache a
  local cluster's workers share (:func:`kernel_cache_dir`).
- ``_cost``: :func:`cost_table` (``generate``'s table of its jobs' seconds by part, from their
  ``profile.json`` or ``timings_s``, and the device row).
- ``_card``: :func:`dataset_summary` and :func:`write_card` (``evfuse dataset DIR``: the summary
  and ``DIR/card.md`` with its contact sheet).
"""

from sim.dataset._card import CARD, DatasetSummary, dataset_summary, write_card
from sim.dataset._cost import cost_table, job_costs
from sim.dataset._estimate import ESTIMATE_ERROR, estimate_jobs, estimate_report
from sim.dataset._jobs import PARAMETERS, Job, job_inputs, run_job
from sim.dataset._loader import (
    DATASET_EVENT_DTYPE,
    MANIFEST,
    TIME_UNITS,
    Dataset,
    EventWindow,
    Sample,
    open_dataset,
)
from sim.dataset._manifest import (
    COLUMN_TYPES,
    column_types,
    output_hash,
    read_manifest,
    write_manifest,
)
from sim.dataset._run import GenerateResult, default_cluster_size, generate
from sim.dataset._sweep import Sweep, SweepError, load_sweep, parse_sweep
from sim.dataset._workers import device_name, kernel_cache_dir, warm_worker

__all__ = [
    # generate (sweeps, jobs, Dask, manifest)
    "COLUMN_TYPES", "ESTIMATE_ERROR", "PARAMETERS", "GenerateResult", "Job", "Sweep",
    "SweepError", "column_types", "cost_table", "default_cluster_size", "device_name",
    "estimate_jobs", "estimate_report", "generate", "job_costs", "job_inputs",
    "kernel_cache_dir", "load_sweep", "output_hash", "parse_sweep", "read_manifest",
    "run_job", "warm_worker", "write_manifest",
    # loader and card (evfuse dataset)
    "CARD",
    "DATASET_EVENT_DTYPE",
    "MANIFEST",
    "TIME_UNITS",
    "Dataset",
    "DatasetSummary",
    "EventWindow",
    "Sample",
    "dataset_summary",
    "open_dataset",
    "write_card",
]
