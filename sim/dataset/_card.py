"""The dataset card: ``evfuse dataset DIR`` prints a dataset's summary and writes ``DIR/card.md``.

The summary (:func:`dataset_summary`) is measured on the sequence folders, each figure from the
files themselves: events and frames as counted in ``sequence.json`` and the frame index, the
simulated seconds, the event rate (events per simulated second), the range of the exact depth
over every depth map (pixels that see a surface), and the camera's linear and angular speed from
``velocity.txt`` (the exact twist at the pose rate). Where the manifest says otherwise for a job,
the summary says so (``mismatches``).

The card (:func:`write_card`) is that summary as Markdown, with a contact sheet
(``DIR/card/contact_sheet.png``: per sequence its middle frame, the event frame of the events
since the frame before, and its exact depth) and the distributions over sequences (quantiles and
a histogram, as tables). Written atomically, file by file (the PNG before the card that shows
it); nothing else in ``DIR`` is touched.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from sim._atomic import write_bytes_atomically
from sim._summary import summary_repr
from sim.dataset._loader import Dataset, open_dataset
from sim.eventio import EVENT_DTYPE
from sim.output import MARKER, OutputError, add_written_files

__all__ = ["CARD", "CARD_FOLDER", "CONTACT_SHEET", "CONTACT_SHEET_ROWS", "DatasetSummary",
           "SequenceSummary", "dataset_summary", "write_card"]

CARD = "card.md"
"""The dataset card, in the dataset folder."""
CARD_FOLDER = "card"
"""The card's figures, in the dataset folder."""
CONTACT_SHEET = "contact_sheet.png"
"""The contact sheet, in :data:`CARD_FOLDER`."""
CONTACT_SHEET_ROWS = 48
"""Most sequences drawn on the contact sheet (the first ones with a frame, in manifest order);
the card says when there are more."""
_TILE_HEIGHT = 108
"""Height of a contact-sheet tile, pixels (each image scaled to it, nearest neighbour)."""


@dataclass(frozen=True)
class SequenceSummary:
    """One done sequence of a dataset, measured on its folder.

    Attributes
    ----------
    job_id, scene : str
        From the manifest.
    width, height : int
        The event camera's size, pixels.
    events : int
        Events (``sequence.json``'s ``events.count``).
    frames : int
        Standard frames.
    duration_s : float, seconds
        Simulated seconds (``sequence.json``'s ``duration``).
    event_rate : float, events per second
        ``events / duration_s``.
    depth_min, depth_max : float, metres
        Range of the exact depth over all depth maps (NaN without one that sees a surface).
    speed_mean, speed_max : float, m/s
        The camera's linear speed over ``velocity.txt`` (NaN without it).
    angular_mean, angular_max : float, rad/s
        Its angular speed likewise.
    """

    job_id: str
    scene: str
    width: int
    height: int
    events: int
    frames: int
    duration_s: float
    event_rate: float
    depth_min: float
    depth_max: float
    speed_mean: float
    speed_max: float
    angular_mean: float
    angular_max: float


@dataclass(frozen=True)
class DatasetSummary:
    """A dataset's summary (:func:`dataset_summary`).

    Attributes
    ----------
    folder : Path
    sequences : tuple of SequenceSummary
        The done jobs, in manifest order.
    failed : tuple of (str, str)
        ``(job_id, error)`` of the failed jobs.
    pending : tuple of str
        The jobs not run yet.
    mismatches : tuple of str
        One line per figure where the manifest disagrees with the sequence folder.
    """

    folder: Path
    sequences: tuple[SequenceSummary, ...]
    failed: tuple[tuple[str, str], ...]
    pending: tuple[str, ...]
    mismatches: tuple[str, ...]

    __repr__ = summary_repr
    _summary_counts = ("frames", "events")

    @property
    def events(self) -> int:
        """Events over all done sequences."""
        return sum(s.events for s in self.sequences)

    @property
    def frames(self) -> int:
        """Standard frames (= samples of :func:`sim.open_dataset`) over all done sequences."""
        return sum(s.frames for s in self.sequences)

    @property
    def duration_s(self) -> float:
        """Simulated seconds over all done sequences."""
        return float(sum(s.duration_s for s in self.sequences))

    def text(self) -> str:
        """The summary as ``evfuse dataset`` prints it (lines, ending in a newline)."""
        rates = [s.event_rate for s in self.sequences]
        lines = [f"dataset {self.folder}: {len(self.sequences)} sequences done, "
                 f"{len(self.failed)} failed, {len(self.pending)} pending",
                 f"events {self.events:,}, frames {self.frames:,}, simulated "
                 f"{self.duration_s:.3f} s, event rate {_ratio(self.events, self.duration_s)} "
                 "events/s over all"]
        if self.sequences:
            lines += [f"event rate per sequence (events/s): {_spread(rates, '.4g')}",
                      f"depth range (m): {_number(_nanmin(s.depth_min for s in self.sequences))}"
                      f" to {_number(_nanmax(s.depth_max for s in self.sequences))}",
                      "mean speed per sequence (m/s): "
                      f"{_spread([s.speed_mean for s in self.sequences], '.3g')}",
                      "mean angular speed per sequence (rad/s): "
                      f"{_spread([s.angular_mean for s in self.sequences], '.3g')}"]
        lines += [f"failed: {job_id}: {error}" for job_id, error in self.failed]
        lines += [f"manifest disagrees: {line}" for line in self.mismatches]
        return "\n".join(lines) + "\n"


def _ratio(a: float, b: float) -> str:
    return f"{a / b:,.0f}" if b > 0 else "n/a"


def _number(value: float, spec: str = ".3g") -> str:
    return "n/a" if value is None or not math.isfinite(value) else format(value, spec)


def _finite(values) -> list[float]:
    return [v for v in values if v is not None and math.isfinite(v)]


def _nanmin(values) -> float:
    found = _finite(values)
    return min(found) if found else math.nan


def _nanmax(values) -> float:
    found = _finite(values)
    return max(found) if found else math.nan


def _spread(values: list[float], spec: str) -> str:
    """``min / median / max`` of the finite values (``n/a`` without any)."""
    found = _finite(values)
    if not found:
        return "n/a"
    low, mid, high = np.min(found), np.median(found), np.max(found)
    return f"min {low:{spec}}, median {mid:{spec}}, max {high:{spec}}"


def _depth_range(seq) -> tuple[float, float]:
    from sim.exr import read_depth

    low, high = math.inf, -math.inf
    for path in seq.standard_frames().depth_paths or ():
        depth = read_depth(path)
        seen = depth[depth > 0]
        if seen.size:
            low, high = min(low, float(seen.min())), max(high, float(seen.max()))
    return (low, high) if high >= low else (math.nan, math.nan)


def _speeds(seq) -> tuple[float, float, float, float]:
    velocity = seq.read_velocity()
    if velocity is None or not len(velocity):
        return (math.nan,) * 4
    linear = np.linalg.norm(velocity[:, 1:4], axis=1)
    angular = np.linalg.norm(velocity[:, 4:7], axis=1)
    return (float(linear.mean()), float(linear.max()), float(angular.mean()),
            float(angular.max()))


def _summarise(dataset: Dataset, k: int) -> tuple[SequenceSummary, list[str]]:
    seq, row = dataset.sequences[k], dataset.manifest[k]
    metadata = seq.metadata or {}
    frames = len(seq.standard_frames().image_times)
    events = int((metadata.get("events") or {}).get("count", 0))
    times = seq.standard_frames().image_times
    duration = float(metadata.get("duration", times[-1] - times[0] if len(times) else 0.0))
    summary = SequenceSummary(row["job_id"], row.get("scene") or "", seq.camera.width,
                              seq.camera.height, events, frames, duration,
                              events / duration if duration > 0 else math.nan,
                              *_depth_range(seq), *_speeds(seq))
    mismatches = []
    for column, value in (("events", events), ("frames", frames), ("duration_s", duration)):
        stated = row.get(column)                 # typed by the manifest's schema, or None
        if stated is None:
            continue
        if not math.isclose(stated, value, rel_tol=1e-9, abs_tol=1e-9):
            mismatches.append(f"{row['job_id']}: {column} {stated} in the manifest, {value:g} "
                              "in its folder")
    return summary, mismatches


def dataset_summary(folder: str | Path, dataset: Dataset | None = None) -> DatasetSummary:
    """Measure a dataset folder's sequences (reads every depth map and ``velocity.txt``, no
    event).

    Parameters
    ----------
    folder : str or Path
        A dataset folder (``manifest.csv``).
    dataset : Dataset, optional
        The folder already opened (:func:`sim.open_dataset`).

    Returns
    -------
    DatasetSummary

    Raises
    ------
    sim.validation.ParameterError
        As :func:`sim.open_dataset`.
    """
    dataset = dataset if dataset is not None else open_dataset(folder, report=False)
    rows, mismatches = [], []
    for k in range(len(dataset.sequences)):
        summary, found = _summarise(dataset, k)
        rows.append(summary)
        mismatches += found
    return DatasetSummary(Path(folder), tuple(rows), dataset.failed, dataset.pending,
                          tuple(mismatches))


# --- the contact sheet -------------------------------------------------------------------------

def _depth_colours(depth: np.ndarray) -> np.ndarray:
    """(H, W, 3) uint8 RGB: inverse depth in TURBO over the map's range (near red, far blue);
    black where no surface is seen."""
    seen = depth > 0
    image = np.zeros((*depth.shape, 3), np.uint8)
    if not seen.any():
        return image
    inverse = np.where(seen, 1.0 / np.where(seen, depth, 1.0), 0.0)
    low, high = inverse[seen].min(), inverse[seen].max()
    levels = np.clip((inverse - low) / max(high - low, 1e-12) * 255, 0, 255).astype(np.uint8)
    colours = cv2.cvtColor(cv2.applyColorMap(levels, cv2.COLORMAP_TURBO), cv2.COLOR_BGR2RGB)
    image[seen] = colours[seen]
    return image


def _tile(image: np.ndarray) -> np.ndarray:
    """``image`` (gray or RGB) as RGB scaled to the tile height (nearest neighbour)."""
    if image.ndim == 2:
        image = np.repeat(image[:, :, None], 3, axis=2)
    width = max(1, round(image.shape[1] * _TILE_HEIGHT / image.shape[0]))
    return cv2.resize(image, (width, _TILE_HEIGHT), interpolation=cv2.INTER_NEAREST)


def _label(width: int, text: str, height: int = 18) -> np.ndarray:
    strip = np.full((height, width, 3), 255, np.uint8)
    cv2.putText(strip, text, (4, height - 5), cv2.FONT_HERSHEY_SIMPLEX, 0.4, (0, 0, 0), 1,
                cv2.LINE_AA)
    return strip


def _sheet_row(dataset: Dataset, k: int) -> np.ndarray:
    """Sequence ``k``'s row: its middle frame, the event frame of its sample, its depth."""
    from sim.statistics import event_frame

    samples = dataset.samples_of(k)
    sample = dataset[samples[len(samples) // 2]]
    events = np.empty(sample.events.size, EVENT_DTYPE)
    events["t"] = sample.events["t"]
    events["x"], events["y"] = sample.events["x"], sample.events["y"]
    events["p"] = np.where(sample.events["p"] > 0, 1, -1)
    width, height = sample.event_camera.width, sample.event_camera.height
    depth = (np.zeros(sample.frame.shape, np.float32) if sample.depth is None
             else sample.depth)
    tiles = [_tile(sample.frame), _tile(event_frame(events, width, height)),
             _tile(_depth_colours(depth))]
    gap = np.full((_TILE_HEIGHT, 4, 3), 255, np.uint8)
    body = np.concatenate([tiles[0], gap, tiles[1], gap, tiles[2]], axis=1)
    title = (f"{dataset.job_ids[k]}  t = {sample.t:.3f} s, {sample.events.size} events since "
             "the previous frame")
    return np.concatenate([_label(body.shape[1], title), body], axis=0)


def _contact_sheet(dataset: Dataset) -> np.ndarray:
    drawn = [k for k in range(len(dataset.sequences)) if len(dataset.samples_of(k))]
    rows = [_sheet_row(dataset, k) for k in drawn[:CONTACT_SHEET_ROWS]]
    width = max(row.shape[1] for row in rows)
    padded = [np.pad(row, ((0, 6), (0, width - row.shape[1]), (0, 0)), constant_values=255)
              for row in rows]
    header = _label(width, "frame | events (ON red, OFF blue) | exact depth (near red)")
    return np.concatenate([header, *padded], axis=0)


# --- the card -------------------------------------------------------------------------------------

def _quantile_rows(name: str, values: list[float], spec: str) -> str:
    found = _finite(values)
    if not found:
        return f"| {name} | n/a | n/a | n/a | n/a | n/a |"
    q = np.quantile(found, [0.0, 0.25, 0.5, 0.75, 1.0])
    return f"| {name} | " + " | ".join(format(v, spec) for v in q) + " |"


def _histogram(name: str, values: list[float], spec: str, bins: int = 8) -> list[str]:
    found = _finite(values)
    if not found:
        return [f"{name}: no values"]
    spread = max(found) - min(found) > 1e-9 * max(1.0, *map(abs, found))   # not one value
    counts, edges = np.histogram(found, bins=min(bins, len(set(found))) if spread else 1)
    most = max(int(counts.max()), 1)
    lines = [f"{name}:"]
    for count, low, high in zip(counts, edges[:-1], edges[1:], strict=True):
        bar = "#" * round(20 * int(count) / most)
        lines.append(f"  [{low:{spec}}, {high:{spec}}]  {int(count):4d}  {bar}")
    return lines


CARD_MARK = ("<!-- written by evfuse dataset, which replaces it on each run; keep your own notes "
             "in another file -->")
"""The first line of every card evfuse writes: ``evfuse dataset`` replaces only a card that
starts with it (or with the heading of a card written before the mark existed)."""


def _is_evfuse_card(path: Path, folder: Path) -> bool:
    """True if ``path`` is a card ``evfuse dataset`` wrote (:data:`CARD_MARK`, or the opening
    lines of an unmarked card of evfuse 0.1.0)."""
    try:
        with path.open("r", encoding="utf-8", errors="replace") as handle:
            head = handle.read(4096)
    except OSError:
        return False
    return head.startswith(CARD_MARK) or head.startswith(
        f"# Dataset card: {folder.name}\n\nWritten by `evfuse dataset` ")


def _card_text(summary: DatasetSummary, shown: int) -> str:
    seqs = summary.sequences
    lines = [CARD_MARK, f"# Dataset card: {summary.folder.name}", "",
             "Written by `evfuse dataset` from the sequence folders (every figure measured on "
             "the files) and `manifest.csv`.", "", "## Summary", "", "```",
             summary.text().rstrip("\n"), "```", "", "## Sequences", "",
             "| job | scene | size | events | frames | simulated s | events/s | depth m "
             "| speed m/s mean (max) | angular rad/s mean (max) |",
             "|---|---|---|---:|---:|---:|---:|---|---|---|"]
    for s in seqs:
        lines.append(f"| {s.job_id} | {s.scene} | {s.width}x{s.height} | {s.events} | "
                     f"{s.frames} | {s.duration_s:g} | {_number(s.event_rate, '.4g')} | "
                     f"{_number(s.depth_min)} - {_number(s.depth_max)} | "
                     f"{_number(s.speed_mean)} ({_number(s.speed_max)}) | "
                     f"{_number(s.angular_mean)} ({_number(s.angular_max)}) |")
    if summary.failed:
        lines += ["", "## Failed jobs", "", "| job | error |", "|---|---|"]
        lines += [f"| {job_id} | {error.replace('|', '/')} |" for job_id, error in summary.failed]
    if summary.pending:
        lines += ["", f"Pending jobs: {', '.join(summary.pending)}."]
    lines += ["", "## Contact sheet", ""]
    if shown:
        more = (f" (the first {shown} of {len(seqs)} sequences with frames)"
                if shown < len(seqs) else "")
        lines += [f"Per sequence{more}: its middle frame, the events since the frame before it "
                  "and its exact depth.", "", f"![contact sheet]({CARD_FOLDER}/{CONTACT_SHEET})"]
    else:
        lines.append("No done sequence has a frame.")
    series = [("event rate (events/s)", [s.event_rate for s in seqs], ".4g"),
              ("nearest depth (m)", [s.depth_min for s in seqs], ".3g"),
              ("farthest depth (m)", [s.depth_max for s in seqs], ".3g"),
              ("mean speed (m/s)", [s.speed_mean for s in seqs], ".3g"),
              ("mean angular speed (rad/s)", [s.angular_mean for s in seqs], ".3g")]
    lines += ["", "## Distributions over sequences", "",
              "| figure | min | 25 % | median | 75 % | max |", "|---|---:|---:|---:|---:|---:|"]
    lines += [_quantile_rows(name, values, spec) for name, values, spec in series]
    lines += ["", "```"]
    for name, values, spec in series:
        lines += _histogram(name, values, spec)
    lines += ["```", ""]
    return "\n".join(lines)


def write_card(folder: str | Path) -> DatasetSummary:
    """Write ``folder/card.md`` and ``folder/card/contact_sheet.png``, the dataset's card.

    Parameters
    ----------
    folder : str or Path
        A dataset folder evfuse wrote (``manifest.csv`` and evfuse's ``.evfuse`` marker).

    Returns
    -------
    DatasetSummary
        What the card says (:func:`dataset_summary`).

    Raises
    ------
    sim.validation.ParameterError
        As :func:`sim.open_dataset`, or a folder without evfuse's marker (the card is evfuse's
        output inside a folder evfuse wrote; it writes nowhere else), or a ``card.md`` there
        that evfuse did not write (no :data:`CARD_MARK`): never replaced.
    """
    folder = Path(folder)
    dataset = open_dataset(folder, time_unit="ns", report=False)
    if not (folder / MARKER).is_file():
        raise OutputError(f"{OutputError.literal(folder)} has no {MARKER} marker: evfuse did not "
                          "write it, so the card is not written into it")
    card = folder / CARD
    if (card.exists() or card.is_symlink()) and (card.is_symlink()
                                                 or not _is_evfuse_card(card, folder)):
        raise OutputError(f"{OutputError.literal(card)} was not written by evfuse dataset (its "
                          "first line is not evfuse's mark), so it is not replaced: move it "
                          "aside, or pass --no-card")
    summary = dataset_summary(folder, dataset)
    shown = min(sum(1 for k in range(len(dataset.sequences)) if len(dataset.samples_of(k))),
                CONTACT_SHEET_ROWS)
    if shown:
        (folder / CARD_FOLDER).mkdir(exist_ok=True)
        ok, png = cv2.imencode(".png", cv2.cvtColor(_contact_sheet(dataset), cv2.COLOR_RGB2BGR))
        if not ok:
            raise ValueError(f"{folder / CARD_FOLDER / CONTACT_SHEET}: cannot encode the PNG")
        write_bytes_atomically(folder / CARD_FOLDER / CONTACT_SHEET, png.tobytes())
    write_bytes_atomically(folder / CARD, _card_text(summary, shown).encode("utf-8"))
    add_written_files(folder, [CARD] + [f"{CARD_FOLDER}/{CONTACT_SHEET}"] * bool(shown))
    return summary
