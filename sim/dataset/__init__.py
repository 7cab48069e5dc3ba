"""Datasets, not sequences (issue 24): many simulated sequences in one folder, and their loader.

A dataset folder holds ``manifest.csv`` (one row per job) and one sequence folder per job
(``jobs/<job_id>/``, as ``evfuse simulate --out`` writes it).

Modules (private; everything public is re-exported here):

- ``_loader``: :func:`open_dataset` (:class:`Dataset`: per standard frame a :class:`Sample`, the
  events since the previous frame with tonic's fields :data:`DATASET_EVENT_DTYPE`, the frame,
  its exact depth, flow, IMU, pose and calibration; :class:`EventWindow` for windows by time).
- ``_card``: :func:`dataset_summary` and :func:`write_card` (``evfuse dataset DIR``: the summary
  and ``DIR/card.md`` with its contact sheet).
"""

from sim.dataset._card import CARD, DatasetSummary, dataset_summary, write_card
from sim.dataset._loader import (
    DATASET_EVENT_DTYPE,
    MANIFEST,
    TIME_UNITS,
    Dataset,
    EventWindow,
    Sample,
    open_dataset,
)

__all__ = [
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
