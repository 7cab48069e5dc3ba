"""How closely two event streams of the same scene agree: counts overall and per block, and the
timestamps of matched events.

Used to check one sampler against a reference (``tests/test_sampler_agreement.py``,
``benchmarks/bench_sampling.py``): the per-pixel sampler and the frame sampler at ``lam / 4``
must fire the same events, at the same times within the sampling bound.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

__all__ = ["EventAgreement", "event_agreement"]


@dataclass(frozen=True)
class EventAgreement:
    """The agreement of a stream with a reference (see :func:`event_agreement`).

    Attributes
    ----------
    reference_count, count : int
        Events in the reference and in the stream.
    count_error : float
        ``count / reference_count - 1`` (0 when both are empty).
    blocks : int
        Blocks holding at least ``min_events`` reference events.
    worst_block_error : float
        Largest ``|count / reference count - 1|`` over those blocks (0 when there are none).
    worst_block : tuple of int
        (row, column) of that block, in blocks.
    worst_block_events : int
        Reference events in that block (0 when there are none).
    matched : float
        Share of the reference's events matched (the i-th event of a pixel and polarity in one
        stream to the i-th in the other).
    dt_median_us, dt_p95_us, dt_max_us : float, microseconds
        Median, 95th percentile and largest |t - t_reference| over the matched events.
    """

    reference_count: int
    count: int
    count_error: float
    blocks: int
    worst_block_error: float
    worst_block: tuple[int, int]
    worst_block_events: int
    matched: float
    dt_median_us: float
    dt_p95_us: float
    dt_max_us: float

    def as_dict(self) -> dict:
        return asdict(self)


def _counts(events: np.ndarray, shape: tuple[int, int], block: int) -> np.ndarray:
    rows, cols = -(-shape[0] // block), -(-shape[1] // block)
    index = (events["y"].astype(np.int64) // block) * cols + events["x"].astype(np.int64) // block
    return np.bincount(index, minlength=rows * cols).reshape(rows, cols)


def _ranked(events: np.ndarray, width: int) -> tuple[np.ndarray, np.ndarray]:
    """A key (pixel, polarity, rank within them) per event, sorted, and the events' times."""
    group = (events["y"].astype(np.int64) * width + events["x"]) * 2 + (events["p"] > 0)
    order = np.lexsort((events["t"], group))
    group, times = group[order], events["t"][order].astype(np.int64)
    starts = np.flatnonzero(np.r_[True, group[1:] != group[:-1]])
    rank = np.arange(len(group)) - np.repeat(starts, np.diff(np.r_[starts, len(group)]))
    return group * (1 << 24) + rank, times


def event_agreement(reference: np.ndarray, events: np.ndarray, shape: tuple[int, int],
                    block: int = 16, min_events: int = 100) -> EventAgreement:
    """Compare an event stream with a reference stream of the same sensor and time span.

    Parameters
    ----------
    reference, events : (N,) structured ndarrays
        Fields ``t`` (ns), ``x``, ``y``, ``p``.
    shape : (int, int)
        Sensor height and width.
    block : int
        Side of the square blocks counts are compared in (pixels).
    min_events : int
        Blocks with fewer reference events are not compared.

    Returns
    -------
    EventAgreement
    """
    n_ref, n = len(reference), len(events)
    count_error = 0.0 if n_ref == n == 0 else (n / n_ref - 1.0 if n_ref else float("inf"))
    want, got = _counts(reference, shape, block), _counts(events, shape, block)
    dense = want >= min_events
    worst, where = 0.0, (0, 0)
    if dense.any():
        errors = np.where(dense, np.abs(got / np.maximum(want, 1) - 1.0), -1.0)
        flat = int(np.argmax(errors))
        worst, where = float(errors.flat[flat]), tuple(int(i) for i in np.unravel_index(
            flat, errors.shape))
    key_ref, t_ref = _ranked(reference, shape[1])
    key, t = _ranked(events, shape[1])
    common, at_ref, at = np.intersect1d(key_ref, key, assume_unique=True, return_indices=True)
    dt = np.abs(t[at] - t_ref[at_ref]) * 1e-3
    stats = (np.percentile(dt, [50, 95]).tolist() + [float(dt.max())]) if len(dt) else [0.0] * 3
    return EventAgreement(n_ref, n, float(count_error), int(dense.sum()), worst, where,
                          int(want[where]) if dense.any() else 0,
                          len(common) / n_ref if n_ref else 1.0, *map(float, stats))
