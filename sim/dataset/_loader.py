"""The loader of a dataset folder (``evfuse generate``'s output): :func:`open_dataset`.

A dataset folder ``DIR`` holds ``manifest.csv`` (one row per job: ``job_id``, ``path`` relative
to ``DIR``, ``status`` done / failed / pending, ``error``, ...) and one sequence folder per done
job (``DIR/jobs/<job_id>/``, read with :func:`sim.sequence.load_sequence`).

A *sample* is one standard frame of one done sequence, with the events since the previous frame:
sample ``k`` of a sequence with frame times ``t_0 < t_1 < ...`` holds the events with
``t_{k-1} <= t < t_k`` (``t_{-1}``: the sequence's start, so that sample 0 holds every event
before the first frame). Every event before the last frame of a sequence is in exactly one
sample; those after it are reachable with :meth:`Dataset.window`. Frame times are converted to
integer nanoseconds (``round(t * 1e9)``; index files hold whole nanoseconds, so exactly).

Lazy: opening reads the manifest and each sequence's index files, never an event; a sample reads
its own events only. From ``events.h5`` the window is found with ``ms_to_idx`` (only the
milliseconds around it are read); from an ``events.txt`` alone, the byte offsets of the frame
boundaries (and each boundary's event index) are found once per sequence, in one streaming pass
on its first sample (:func:`sim.eventio.text_offsets`), and each sample then parses its own
lines. The per-event depth and labels (``cause``, ``object_id``) come from ``events.h5`` window
by window; beside an ``events.txt``, from ``events_depth.txt`` and ``events_labels.txt``, which
hold one line per event in the events' order: the same first pass finds, in one streaming pass
over each, the byte offsets of the lines of each boundary's event (:func:`sim.eventio.line_offsets`)
and checks that it holds one line per event; each sample then parses its own lines of each
(:func:`sim.event_depth.read_event_depth_span`, :func:`sim.event_labels.read_event_label_span`).
A window by time (:meth:`Dataset.window`) reads them through the sequence's accessors
(:meth:`sim.Sequence.event_depth`, :meth:`sim.Sequence.event_labels`), which stream the text
files and keep the window's rows only. A sequence without them has None.
"""

from __future__ import annotations

import sys
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from sim._summary import summary_repr
from sim.camera import Camera
from sim.dataset._manifest import MANIFEST_CSV, read_manifest
from sim.eventio import EVENT_DTYPE, line_offsets, read_text_span, read_window, text_offsets
from sim.sequence import Sequence, load_sequence
from sim.validation import ParameterError

__all__ = ["DATASET_EVENT_DTYPE", "MANIFEST", "TIME_UNITS", "Dataset", "EventWindow", "Sample",
           "open_dataset"]

MANIFEST = MANIFEST_CSV                   # one name, the writer's (sim.dataset._manifest)
"""The manifest of a dataset folder: one row per job (``job_id``, ``path``, ``status``, ...)."""

DATASET_EVENT_DTYPE = np.dtype([("x", "<u2"), ("y", "<u2"), ("t", "<i8"), ("p", "i1")])
"""A sample's events, with tonic's fields in tonic's order: ``x``, ``y`` (pixel column and row),
``t`` (int64, in the dataset's :data:`TIME_UNITS`: microseconds by default, as tonic's datasets
and the ``time_window`` of its transforms), ``p`` (0 OFF, 1 ON: an index into tonic's polarity
channel). tonic's ``ToFrame``, ``ToVoxelGrid`` and ``ToTimesurface`` take it as it is (some of
them write into ``p``: each sample's array is its own)."""

TIME_UNITS = {"us": 1000, "ns": 1}
"""The units of a sample's event times, by name: nanoseconds per unit. ``us`` (tonic's) floors
each nanosecond time to its microsecond (the DSEC layout's ``events/t``); ``ns`` is exact."""

_REPORTED = ("failed", "pending")


@dataclass(frozen=True, eq=False)
class EventWindow:
    """The events of a time window of one sequence, with their per-event truth.

    Attributes
    ----------
    t_start_ns : int or None
        Start of the window (nanoseconds, inclusive); None from the sequence's first event.
    t_end_ns : int or None
        End of the window (nanoseconds, exclusive); None to its last event.
    events : (N,) DATASET_EVENT_DTYPE ndarray
        Sorted by ``t``, in ``time_unit``; empty for a sequence simulated without events.
    time_unit : {"us", "ns"}
    depth : (N,) float32 ndarray, metres, or None
        Each event's exact z-depth (0 = no surface; :mod:`sim.event_depth`); None when the
        sequence has none.
    depth_flag : (N,) uint8 ndarray or None
        0, ``FLAG_EDGE`` or ``FLAG_NO_SURFACE`` (:mod:`sim.event_depth`).
    cause : (N,) uint8 ndarray or None
        What made each event: 0 signal, 1 shot / background, 2 leak, 3 hot pixel; None when
        the sequence has no label file.
    object_id : (N,) int32 ndarray or None
        The scene object each event's pixel sees at its time (its index in the scene file,
        -1 none); None when the sequence has no label file.
    """

    t_start_ns: int | None
    t_end_ns: int | None
    events: np.ndarray
    time_unit: str
    depth: np.ndarray | None = None
    depth_flag: np.ndarray | None = None
    cause: np.ndarray | None = None
    object_id: np.ndarray | None = None

    __repr__ = summary_repr


@dataclass(frozen=True, eq=False)
class Sample:
    """One standard frame of a dataset, with the events since the previous frame.

    Attributes
    ----------
    job_id : str
        The sequence's job (its folder ``DIR/jobs/<job_id>``).
    sequence : int
        Index of the sequence in :attr:`Dataset.sequences`.
    frame_index : int
        Index of the frame in the sequence's standard frames.
    t : float, seconds
        The frame's time (mid-exposure).
    window : EventWindow
        The events of ``[previous frame's time, t)`` and their truth.
    frame : (H, W) uint8 ndarray
        The standard frame (8-bit gray).
    depth : (H, W) float32 ndarray, metres, or None
        Exact z-depth at the frame's time (0 = no surface); None without one.
    forward_flow, backward_flow : (H, W, 2) float32 ndarray, pixels, or None
        Exact optical flow to the next / previous frame (:func:`sim.flow.read_flow`); None at
        the last / first frame or without motion truth.
    forward_flow_flags, backward_flow_flags : (H, W) uint8 ndarray or None
        Their validity bits (0 = valid).
    motion_field : (H, W, 2) float32 ndarray, pixels per second, or None
    object_mask : (H, W) uint16 ndarray or None
        0 where nothing is seen, ``i`` where the sequence's ``object_names[i - 1]`` is.
    imu : (M, 7) float64 ndarray or None
        IMU readings ``t ax ay az gx gy gz`` (s, m/s^2, rad/s) with times in the window.
    pose : (4, 4) float64 ndarray or None
        ``T_world_camera`` of the frame's camera at ``t``, from the sequence's
        ``groundtruth.txt`` (the event camera's pose times ``T_event_frame``; exact unless the
        job asked for capture errors).
    camera : sim.Camera
        The frame's calibration (a rig's frame camera, else the event camera).
    event_camera : sim.Camera
        The event camera's calibration.
    T_event_frame : (4, 4) float64 ndarray
        The frame camera in the event camera's frame (the identity for one camera).
    """

    job_id: str
    sequence: int
    frame_index: int
    t: float
    window: EventWindow
    frame: np.ndarray
    depth: np.ndarray | None
    forward_flow: np.ndarray | None
    forward_flow_flags: np.ndarray | None
    backward_flow: np.ndarray | None
    backward_flow_flags: np.ndarray | None
    motion_field: np.ndarray | None
    object_mask: np.ndarray | None
    imu: np.ndarray | None
    pose: np.ndarray | None
    camera: Camera
    event_camera: Camera
    T_event_frame: np.ndarray

    __repr__ = summary_repr

    @property
    def events(self) -> np.ndarray:
        """(N,) DATASET_EVENT_DTYPE ndarray: the window's events (tonic's fields)."""
        return self.window.events

    @property
    def sensor_size(self) -> tuple[int, int, int]:
        """``(width, height, 2)`` of the event camera: tonic's ``sensor_size``."""
        return (self.event_camera.width, self.event_camera.height, 2)


class Dataset:
    """A dataset folder, opened by :func:`open_dataset`: its done sequences and their samples.

    ``len(ds)`` samples, one per standard frame of every done sequence (in manifest order, then
    frame order); ``ds[i]`` is :class:`Sample` ``i`` (negative ``i`` from the end). Nothing is
    cached but, per sequence, the byte offsets of a text-only event file's frame boundaries (and
    of the same events' lines in its per-event depth and label files) and the last sequence's
    poses and IMU table.

    Attributes
    ----------
    folder : Path
    time_unit : {"us", "ns"}
        The unit of the samples' event times (:data:`TIME_UNITS`).
    job_ids : tuple of str
        The done jobs, in manifest order.
    sequences : tuple of sim.Sequence
        Their sequence folders (:func:`sim.load_sequence`), in the same order.
    manifest : tuple of dict
        Their manifest rows, every column typed as :func:`sim.dataset.read_manifest` gives it
        (int, float or str; None where empty).
    failed : tuple of (str, str)
        ``(job_id, error)`` of each failed job (skipped).
    pending : tuple of str
        The jobs not run yet (skipped).
    """

    def __init__(self, folder: Path, time_unit: str, rows: list[dict]) -> None:
        self.folder = folder
        self.time_unit = time_unit
        done = [row for row in rows if row["status"] == "done"]
        self.failed = tuple((row["job_id"], row.get("error") or "") for row in rows
                            if row["status"] == "failed")
        self.pending = tuple(row["job_id"] for row in rows if row["status"] == "pending")
        self.manifest = tuple(done)
        self.job_ids = tuple(row["job_id"] for row in done)
        sequences = []
        for row in done:
            path = folder / row["path"]
            if not path.is_dir():
                raise ParameterError(f"{ParameterError.literal(folder / MANIFEST)}: job "
                                     f"{row['job_id']} is done but its folder "
                                     f"{ParameterError.literal(path)} does not exist")
            sequences.append(load_sequence(path))
        self.sequences = tuple(sequences)
        self._boundaries = tuple(np.round(seq.standard_frames().image_times * 1e9)
                                 .astype(np.int64) for seq in self.sequences)
        self._starts = np.concatenate(([0], np.cumsum([b.size for b in self._boundaries])))
        self._text_index: dict[int, dict[str, tuple[np.ndarray, ...]]] = {}
        self._tables: dict[tuple[int, str], object] = {}

    def __repr__(self) -> str:
        return (f"Dataset({str(self.folder)!r}: {len(self.sequences)} sequences, {len(self)} "
                f"samples, {len(self.failed)} failed, {len(self.pending)} pending)")

    def __len__(self) -> int:
        return int(self._starts[-1])

    def __iter__(self) -> Iterator[Sample]:
        for index in range(len(self)):
            yield self[index]

    def locate(self, index: int) -> tuple[int, int]:
        """``(sequence, frame_index)`` of sample ``index`` (negative from the end).

        Raises
        ------
        IndexError
            ``index`` outside ``[-len(ds), len(ds))``.
        """
        if isinstance(index, bool) or not isinstance(index, int | np.integer):
            raise TypeError(f"a sample index is an integer, got {index!r}")
        count = len(self)
        if not -count <= index < count:
            raise IndexError(f"sample {index} out of range: the dataset has {count} samples")
        index = int(index) % count
        sequence = int(np.searchsorted(self._starts, index, side="right")) - 1
        return sequence, index - int(self._starts[sequence])

    def samples_of(self, sequence: int | str | Sequence) -> range:
        """The sample indexes of one sequence (its index, job id or the sequence itself), in
        frame order."""
        k = self._sequence_index(sequence)
        return range(int(self._starts[k]), int(self._starts[k + 1]))

    def _sequence_index(self, sequence: int | str | Sequence) -> int:
        if isinstance(sequence, str):
            if sequence not in self.job_ids:
                raise ValueError(f"no done job {sequence!r} in {self.folder}")
            return self.job_ids.index(sequence)
        if isinstance(sequence, Sequence):
            for k, seq in enumerate(self.sequences):
                if seq is sequence:
                    return k
            raise ValueError(f"sequence {sequence.folder} is not one of this dataset's")
        if isinstance(sequence, bool) or not isinstance(sequence, int | np.integer) \
                or not 0 <= sequence < len(self.sequences):
            raise ValueError(f"sequence must be an index in [0, {len(self.sequences)}), a job "
                             f"id or one of ds.sequences, got {sequence!r}")
        return int(sequence)

    def sensor_size(self, sequence: int | str | Sequence) -> tuple[int, int, int]:
        """``(width, height, 2)`` of a sequence's event camera: tonic's ``sensor_size``."""
        camera = self.sequences[self._sequence_index(sequence)].camera
        return (camera.width, camera.height, 2)

    def window(self, sequence: int | str | Sequence, t0: float | None,
               t1: float | None) -> EventWindow:
        """The events of one sequence with ``t0 <= t < t1`` and their per-event truth.

        Parameters
        ----------
        sequence : int, str or sim.Sequence
            Its index in :attr:`sequences`, its job id, or the sequence itself.
        t0, t1 : float or None, seconds
            The window (``None``: from the first event / to the last); read lazily, as a
            sample's.

        Returns
        -------
        EventWindow

        Raises
        ------
        ValueError
            An unknown sequence, a window that ends before it starts, or an unreadable file.
        """
        k = self._sequence_index(sequence)
        t0_ns = None if t0 is None else int(round(float(t0) * 1e9))
        t1_ns = None if t1 is None else int(round(float(t1) * 1e9))
        if t0_ns is not None and t1_ns is not None and t1_ns < t0_ns:
            raise ValueError(f"window [{t0}, {t1}) s ends before it starts")
        return self._window(k, t0_ns, t1_ns, None)

    def _window(self, k: int, t0_ns: int | None, t1_ns: int | None,
                frame_index: int | None) -> EventWindow:
        seq = self.sequences[k]
        if frame_index is not None and seq.events_h5 is None and seq.events_txt is not None:
            raw, found_depth, found_labels = self._text_sample(k, frame_index)
        else:
            raw = self._raw_events(k, t0_ns, t1_ns)
            found_depth = seq.event_depth(t0_ns, t1_ns)
            found_labels = seq.event_labels(t0_ns, t1_ns)
        events = np.empty(raw.size, DATASET_EVENT_DTYPE)
        events["x"], events["y"] = raw["x"], raw["y"]
        events["t"] = raw["t"] // TIME_UNITS[self.time_unit]
        events["p"] = raw["p"] > 0
        depth = flag = cause = object_id = None
        if found_depth is not None:
            _check_aligned(seq, raw, found_depth, "per-event depth")
            depth, flag = found_depth["depth"], found_depth["flag"]
        if found_labels is not None:
            if len(found_labels) != raw.size:
                raise ValueError(f"{seq.folder}: {len(found_labels)} event labels but {raw.size} "
                                 f"events in [{t0_ns}, {t1_ns}) ns; expected one label per event")
            cause, object_id = found_labels["cause"], found_labels["object_id"]
        return EventWindow(t0_ns, t1_ns, events, self.time_unit, depth, flag, cause, object_id)

    def _raw_events(self, k: int, t0_ns: int | None, t1_ns: int | None) -> np.ndarray:
        """Events of ``[t0_ns, t1_ns)`` of sequence ``k`` as EVENT_DTYPE (ns, p +-1)."""
        seq = self.sequences[k]
        width, height = seq.camera.width, seq.camera.height
        if seq.events_h5 is not None:
            return read_window(seq.events_h5, 0 if t0_ns is None else t0_ns,
                               np.iinfo(np.int64).max if t1_ns is None else t1_ns)
        if seq.events_txt is None:                # simulated without events: none to read
            return np.empty(0, EVENT_DTYPE)
        bounds = np.array([0 if t0_ns is None else t0_ns,
                           np.iinfo(np.int64).max if t1_ns is None else t1_ns], np.int64)
        offsets, lines, _ = text_offsets(seq.events_txt, bounds, width=width, height=height)
        return read_text_span(seq.events_txt, int(offsets[0]), int(offsets[1]), int(lines[0]),
                              width=width, height=height)

    def _text_index_of(self, k: int) -> dict[str, tuple[np.ndarray, ...]]:
        """Sequence ``k``'s text index, made on its first sample: for ``events.txt`` (key
        ``"events"``) the byte offset, line number and event index at which each sample begins
        (entry ``j``; entry ``j + 1`` ends it), and for each per-event text file beside it
        (``"depth"``, ``"labels"``) the byte offset and line number of those events' lines.

        Raises
        ------
        ValueError
            A per-event file that does not hold one line per event.
        """
        if k not in self._text_index:
            seq = self.sequences[k]
            bounds = self._boundaries[k]            # event times are >= 0: 0 is before all
            first = min(0, int(bounds[0])) if bounds.size else 0
            times = np.concatenate(([first], bounds, [np.iinfo(np.int64).max]))
            offsets, lines, counts = text_offsets(seq.events_txt, times, width=seq.camera.width,
                                                  height=seq.camera.height)
            index = {"events": (offsets, lines, counts)}
            for name, path in (("depth", seq.events_depth_txt), ("labels", seq.events_labels_txt)):
                if path is None:
                    continue
                at, numbers, found = line_offsets(path, counts)
                if found != counts[-1]:
                    raise ValueError(f"{path}: {found} lines for the {int(counts[-1])} events of "
                                     f"{seq.events_txt}; expected one line per event")
                index[name] = (at, numbers)
            self._text_index[k] = index
        return self._text_index[k]

    def _text_sample(self, k: int, j: int
                     ) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None]:
        """The events of sample ``j`` of text-only sequence ``k`` (EVENT_DTYPE), their depth
        rows and labels (None without the file): each read from its own lines only."""
        from sim.event_depth import read_event_depth_span
        from sim.event_labels import read_event_label_span

        seq = self.sequences[k]
        index = self._text_index_of(k)
        offsets, lines, counts = index["events"]
        raw = read_text_span(seq.events_txt, int(offsets[j]), int(offsets[j + 1]),
                             int(lines[j]), width=seq.camera.width, height=seq.camera.height)
        depth = labels = None
        if "depth" in index:
            at, numbers = index["depth"]
            depth = read_event_depth_span(seq.events_depth_txt, int(at[j]), int(at[j + 1]),
                                          int(numbers[j]))
        if "labels" in index:
            at, numbers = index["labels"]
            labels = read_event_label_span(seq.events_labels_txt, int(at[j]), int(at[j + 1]),
                                           int(numbers[j]), int(counts[j]))
        return raw, depth, labels

    def _table(self, k: int, name: str):
        """The poses (``"poses"``) or IMU table (``"imu"``) of sequence ``k``: only the last
        sequence's are kept."""
        key = (k, name)
        if key not in self._tables:
            from sim.trajectory import read_trajectory

            seq = self.sequences[k]
            if name == "poses":
                value = (None if seq.groundtruth_path is None
                         else read_trajectory(seq.groundtruth_path))
            else:
                value = seq.read_imu()
            self._tables = {kept: v for kept, v in self._tables.items() if kept[0] == k}
            self._tables[key] = value
        return self._tables[key]

    def __getitem__(self, index: int) -> Sample:
        from sim.exr import read_depth
        from sim.flow import read_flow, read_motion_field, read_object_mask
        from sim.statistics import read_gray

        k, j = self.locate(index)
        seq = self.sequences[k]
        frames = seq.standard_frames()
        t = float(frames.image_times[j])
        boundaries = self._boundaries[k]
        t0_ns = None if j == 0 else int(boundaries[j - 1])
        window = self._window(k, t0_ns, int(boundaries[j]), j)
        at_depth = frames.nearest_depth(t)
        flows = {}
        for name in ("forward_flow", "backward_flow"):
            index_file = getattr(frames, name)
            path = None if index_file is None else index_file.at(t)
            flows[name], flows[f"{name}_flags"] = (None, None) if path is None else read_flow(path)
        motion = None if frames.motion_field is None else frames.motion_field.at(t)
        mask = None if frames.object_masks is None else frames.object_masks.at(t)
        imu = self._table(k, "imu")
        if imu is not None:
            t_start = -np.inf if t0_ns is None else frames.image_times[j - 1]
            imu = imu[(imu[:, 0] >= t_start) & (imu[:, 0] < t)].copy()
        poses = self._table(k, "poses")
        pose = None if poses is None else poses.pose(t) @ frames.T_event_frame
        return Sample(job_id=self.job_ids[k], sequence=k, frame_index=j, t=t, window=window,
                      frame=read_gray(frames.image_paths[j]),
                      depth=None if at_depth is None else read_depth(frames.depth_paths[at_depth]),
                      **flows, motion_field=None if motion is None else read_motion_field(motion),
                      object_mask=None if mask is None else read_object_mask(mask), imu=imu,
                      pose=pose, camera=frames.camera, event_camera=seq.camera,
                      T_event_frame=frames.T_event_frame)


def _check_aligned(seq: Sequence, events: np.ndarray, truth: np.ndarray, what: str) -> None:
    """Refuse per-event truth that is not one-to-one with the events it annotates."""
    if truth.size != events.size or not all(np.array_equal(truth[name], events[name])
                                            for name in ("t", "x", "y", "p")):
        raise ValueError(f"{seq.folder}: the {what} ({truth.size} events) is not aligned with "
                         f"the events ({events.size}); expected one entry per event, in order")


def open_dataset(folder: str | Path, time_unit: str = "us", *, report: bool = True) -> Dataset:
    """Open a dataset folder written by ``evfuse generate``: its done sequences, lazily.

    Parameters
    ----------
    folder : str or Path
        The dataset folder (with ``manifest.csv``).
    time_unit : {"us", "ns"}
        The unit of the samples' event times (:data:`TIME_UNITS`): microseconds as tonic's
        (default), or exact nanoseconds.
    report : bool
        Say on standard error, in one line each, which jobs failed or are pending (they are
        skipped; :attr:`Dataset.failed` and :attr:`Dataset.pending` list them either way).

    Returns
    -------
    Dataset

    Raises
    ------
    sim.validation.ParameterError
        No such folder, no ``manifest.csv`` (not a dataset folder), a manifest without the
        ``job_id``, ``path`` and ``status`` columns or with another status, or a done job whose
        folder is missing; ``time_unit`` not ``us`` or ``ns``.
    ValueError
        A sequence folder that :func:`sim.load_sequence` cannot read.

    Examples
    --------
    >>> ds = sim.open_dataset("datasets/tabletop")              # doctest: +SKIP
    >>> sample = ds[0]                                          # doctest: +SKIP
    >>> sample.events["t"], sample.frame.shape, sample.depth    # doctest: +SKIP
    """
    if time_unit not in TIME_UNITS:
        raise ParameterError(f"{{time_unit}} must be one of {', '.join(TIME_UNITS)}, got "
                             f"{ParameterError.literal(repr(time_unit))}", time_unit="time_unit")
    folder = Path(folder)
    dataset = Dataset(folder, time_unit, read_manifest(folder))
    if report:
        for job_id, error in dataset.failed:
            print(f"evfuse: dataset {folder}: job {job_id} failed (skipped): {error}",
                  file=sys.stderr)
        if dataset.pending:
            print(f"evfuse: dataset {folder}: {len(dataset.pending)} jobs pending (skipped): "
                  f"{', '.join(dataset.pending[:5])}{' ...' if len(dataset.pending) > 5 else ''}",
                  file=sys.stderr)
    return dataset
