"""Datasets: many sequences from one sweep file, generated on Dask (``evfuse generate``).

Modules (private; everything public is re-exported here):

- ``_sweep``: sweep files (:func:`load_sweep`, :func:`parse_sweep` -> :class:`Sweep`,
  :class:`SweepError`): scenes, seeds, a grid and drawn parameters, expanded into jobs.
- ``_jobs``: one job (:class:`Job`, its stable ``job_id``), the parameters a sweep may set
  (:data:`PARAMETERS`) and one job simulated in this process (:func:`run_job`).
- ``_run``: :func:`generate` (the jobs on a Dask ``LocalCluster``, an existing scheduler or in
  process; resumable) and :func:`estimate_jobs` (``--dry-run``'s cost from a probe).
- ``_manifest``: ``manifest.csv`` / ``.parquet`` (:func:`write_manifest`,
  :func:`read_manifest`) and a job folder's :func:`output_hash`.
"""

from __future__ import annotations

# --- generate (sweeps, jobs, Dask, manifest) ---
from sim.dataset._jobs import PARAMETERS, Job, job_inputs, run_job
from sim.dataset._manifest import output_hash, read_manifest, write_manifest
from sim.dataset._run import GenerateResult, default_cluster_size, estimate_jobs, generate
from sim.dataset._sweep import Sweep, SweepError, load_sweep, parse_sweep

__all__ = [
    # generate
    "PARAMETERS", "GenerateResult", "Job", "Sweep", "SweepError", "default_cluster_size",
    "estimate_jobs", "generate", "job_inputs", "load_sweep", "output_hash", "parse_sweep",
    "read_manifest", "run_job", "write_manifest",
]
