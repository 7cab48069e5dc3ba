"""Event file formats: write and read speed of evfuse's codecs beside the libraries of each
ecosystem, and the peak memory of a streamed conversion.

N events (default 10 million: ``--events``) over 60 s on a 640x480 sensor, whole microseconds,
random pixels, are written once to ``events.h5`` (the source). Then, each in its own process (so
that its peak resident memory, ``ru_maxrss``, is its own):

- ``evfuse write FMT``: the format's streaming writer fed chunks of 2^20 events from an array in
  memory (as the libraries are given one);
- ``evfuse read FMT``: every chunk of ``iter_event_chunks(events.FMT)``, streamed;
- ``evfuse convert FMT``: ``convert_events(events.h5, events.FMT)``, streamed both ways (chunks
  of 2^20): its peak RSS is the bounded memory of a conversion, measured again on half the
  events (both many chunks long: the same peak if memory does not grow with the file);
- the libraries on the same events: faery (EVT 3.0, EVT 2.0: write from an in-memory array,
  read to an array), evlib (read EVT 3.0, EVT 2.0, HDF5 of its own layout is not ours: not
  timed), expelliarmus (read EVT 3.0, EVT 2.0), dv-processing (AEDAT4: write through its Python
  ``EventStore.push_back``, the only way in from NumPy, and read with ``getNextEventBatch``,
  each packet converted to a NumPy array as a Python user does).
  A library's process holds the whole array (it takes or gives one), so its RSS is not bounded.

evfuse's process first writes and reads a two-event file of the format, so that the Numba loops
are loaded from their cache (once per process, about 0.1-0.3 s) before the clock starts.

Each figure is events per second (millions) and the process's peak RSS (``VmHWM``, MiB,
including the interpreter and the libraries it imports). The ratio column is evfuse's time over
the fastest library's for the same format and direction (< 2 is the issue's goal). Every
measurement is the best of ``--repeat`` runs; the machine may be shared (say so when quoting).

ROS bags (``ros1`` ``.bag``, ``ros2`` ``.mcap``): evfuse's writer and reader beside rosbags' own
serializer (``serialize_ros1`` / ``serialize_cdr`` of messages built from its classes, one Python
object an event, one message per 10 ms as evfuse writes them) and ``AnyReader.deserialize``;
rosbags is the only pip-installable reader and writer of these bags.

Run: ``.venv/bin/python benchmarks/bench_formats.py [--events N] [--repeat R] [--formats
ros1,ros2]``. Printed and written to ``benchmarks/results/formats.json`` (with ``--formats``,
only those formats' rows are replaced).
"""

from __future__ import annotations

import argparse
import json
import platform
import subprocess
import sys
import tempfile
from pathlib import Path

RESULTS = Path(__file__).resolve().parent / "results"
ROOT = Path(__file__).resolve().parents[1]
W, H = 640, 480
SPAN_US = 60_000_000

# (format, direction, tool, file name)
MEASURES = [
    ("evt3", "write", "evfuse", "e3.raw"), ("evt3", "write", "faery", "f3.raw"),
    ("evt3", "read", "evfuse", "e3.raw"), ("evt3", "read", "faery", "e3.raw"),
    ("evt3", "read", "evlib", "e3.raw"), ("evt3", "read", "expelliarmus", "e3.raw"),
    ("evt2", "write", "evfuse", "e2.raw"), ("evt2", "write", "faery", "f2.raw"),
    ("evt2", "read", "evfuse", "e2.raw"), ("evt2", "read", "faery", "e2.raw"),
    ("evt2", "read", "evlib", "e2.raw"), ("evt2", "read", "expelliarmus", "e2.raw"),
    ("aedat4", "write", "evfuse", "e.aedat4"), ("aedat4", "write", "dv-processing", "d.aedat4"),
    ("aedat4", "read", "evfuse", "e.aedat4"), ("aedat4", "read", "dv-processing", "e.aedat4"),
    ("h5", "read", "evfuse", "events.h5"), ("txt", "write", "evfuse", "e.txt"),
    ("txt", "read", "evfuse", "e.txt"),
    ("evt3", "convert", "evfuse", "c3.raw"), ("evt2", "convert", "evfuse", "c2.raw"),
    ("aedat4", "convert", "evfuse", "c.aedat4"), ("txt", "convert", "evfuse", "c.txt"),
    ("ros1", "write", "evfuse", "e.bag"), ("ros1", "write", "rosbags", "r.bag"),
    ("ros1", "read", "evfuse", "e.bag"), ("ros1", "read", "rosbags", "e.bag"),
    ("ros1", "convert", "evfuse", "c.bag"),
    ("ros2", "write", "evfuse", "e.mcap"), ("ros2", "write", "rosbags", "r.mcap"),
    ("ros2", "read", "evfuse", "e.mcap"), ("ros2", "read", "rosbags", "e.mcap"),
    ("ros2", "convert", "evfuse", "c.mcap"),
]

_WORKER = r"""
import sys, time
import numpy as np
fmt, direction, tool, folder, name = sys.argv[1:6]
folder = __import__("pathlib").Path(folder)
path = folder / name
def source_array():
    from sim.eventio import read_events
    return read_events(folder / "events.h5")
count = 0
if tool == "evfuse":
    from sim.eventio import convert_events, iter_event_chunks, make_events
    from sim.eventio._formats import format_named
    warm = folder / ("warm_" + name)             # load the compiled (cached) loops first
    with format_named(fmt).open_writer(warm, sensor_size=(640, 480)) as writer:
        writer.write(make_events([0, 1000], [0, 1], [0, 1], [1, -1]))
    sum(chunk.size for chunk in iter_event_chunks(warm, 1 << 20))
    if direction == "write":                # from an array in memory, as the libraries
        ev = source_array()
        start = time.perf_counter()
        with format_named(fmt).open_writer(path, sensor_size=(640, 480)) as writer:
            for begin in range(0, ev.size, 1 << 20):
                writer.write(ev[begin:begin + (1 << 20)])
        count = ev.size
    elif direction == "convert":            # streamed from events.h5: bounded memory
        start = time.perf_counter()
        convert_events(folder / "events.h5", path, dst_selectors=format_named(fmt).selector)
        count = -1
    else:
        start = time.perf_counter()
        for chunk in iter_event_chunks(path, 1 << 20):
            count += chunk.size
elif tool == "faery":
    import faery
    if direction == "write":
        ev = source_array()
        arr = np.zeros(ev.size, faery.EVENTS_DTYPE)
        arr["t"], arr["x"], arr["y"], arr["on"] = ev["t"] // 1000, ev["x"], ev["y"], ev["p"] > 0
        del ev
        start = time.perf_counter()
        faery.events_stream_from_array(arr, dimensions=(640, 480)).to_file(path, version=fmt)
        count = arr.size
    else:
        start = time.perf_counter()
        count = faery.events_stream_from_file(path).to_array().size
elif tool == "evlib":
    import evlib
    start = time.perf_counter()
    count = evlib.load_events(str(path)).collect().height
elif tool == "expelliarmus":
    from expelliarmus import Wizard
    start = time.perf_counter()
    wizard = Wizard(encoding=fmt)
    wizard.set_file(str(path))
    count = wizard.read().size
elif tool == "dv-processing":
    import dv_processing as dv
    if direction == "write":
        ev = source_array()
        t, x, y, p = ((ev["t"] // 1000).tolist(), ev["x"].tolist(), ev["y"].tolist(),
                      (ev["p"] > 0).tolist())
        del ev
        start = time.perf_counter()
        config = dv.io.MonoCameraWriter.EventOnlyConfig("bench", (640, 480))
        writer = dv.io.MonoCameraWriter(str(path), config)
        step = 1 << 20
        for begin in range(0, len(t), step):
            store = dv.EventStore()
            push = store.push_back
            for i in range(begin, min(begin + step, len(t))):
                push(t[i], x[i], y[i], p[i])
            writer.writeEvents(store)
        del writer
        count = len(t)
    else:
        start = time.perf_counter()
        recording = dv.io.MonoCameraRecording(str(path))
        while (batch := recording.getNextEventBatch()) is not None:
            count += batch.numpy().size          # to arrays, as evfuse and the others give
elif tool == "rosbags":                     # its own serializer: one object an event
    from rosbags.highlevel import AnyReader
    from sim.eventio._rosbag import EVENT_ARRAY, typestore
    if direction == "write":
        from rosbags.rosbag1 import Writer as Writer1
        from rosbags.rosbag2 import StoragePlugin, Writer as Writer2
        ev = source_array()
        ros = 1 if name.endswith(".bag") else 2
        store = typestore(ros)
        types = store.types
        Time, Event = types["builtin_interfaces/msg/Time"], types["dvs_msgs/msg/Event"]
        Header, Array = types["std_msgs/msg/Header"], types[EVENT_ARRAY]
        serialize = store.serialize_ros1 if ros == 1 else store.serialize_cdr
        if ros == 2:                                    # rosbags writes a ROS 2 bag folder
            path = path.with_suffix("")
        if path.exists():                               # an earlier repeat's: rosbags never
            __import__("shutil").rmtree(path) if path.is_dir() else path.unlink()  # overwrites
        slot = ev["t"] // 10_000_000                   # evfuse's messages: 10 ms slices
        cuts = np.flatnonzero(np.diff(slot)) + 1
        start = time.perf_counter()
        writer = (Writer1(path) if ros == 1
                  else Writer2(path, version=9, storage_plugin=StoragePlugin.MCAP))
        with writer:
            connection = writer.add_connection("/dvs/events", EVENT_ARRAY, typestore=store)
            for part in np.split(ev, cuts):
                t = part["t"].tolist()
                events = [Event(x=x, y=y, ts=Time(sec=ti // 10**9, nanosec=ti % 10**9),
                                polarity=p > 0)
                          for x, y, ti, p in zip(part["x"].tolist(), part["y"].tolist(), t,
                                                 part["p"].tolist())]
                header = Header(stamp=Time(sec=t[-1] // 10**9, nanosec=t[-1] % 10**9),
                                frame_id="", **({"seq": 0} if ros == 1 else {}))
                writer.write(connection, t[-1], serialize(
                    Array(header=header, height=480, width=640, events=events), EVENT_ARRAY))
        count = ev.size
    else:
        start = time.perf_counter()
        with AnyReader([path]) as reader:
            for connection, _, data in reader.messages():
                count += len(reader.deserialize(data, connection.msgtype).events)
seconds = time.perf_counter() - start
# VmHWM: this process's own peak (ru_maxrss would carry the parent's over fork and exec)
hwm = next(line for line in open("/proc/self/status") if line.startswith("VmHWM"))
print(count, seconds, int(hwm.split()[1]))
"""


def _source(folder: Path, n: int) -> None:
    """Write ``n`` events (60 s, whole microseconds, seeded) to ``events.h5``, in chunks."""
    import numpy as np

    from sim.eventio import H5EventWriter, make_events

    rng = np.random.default_rng(0)
    t = np.sort(rng.integers(0, SPAN_US, n)) * 1000
    with H5EventWriter(folder / "events.h5", W, H) as writer:
        for begin in range(0, n, 1 << 20):
            m = min(n, begin + (1 << 20)) - begin
            writer.write(make_events(t[begin:begin + m], rng.integers(0, W, m),
                                     rng.integers(0, H, m), rng.choice([-1, 1], m)))


def _run(fmt: str, direction: str, tool: str, folder: Path, name: str) -> tuple[float, float]:
    done = subprocess.run([sys.executable, "-c", _WORKER, fmt, direction, tool, str(folder),
                           name], capture_output=True, text=True, cwd=ROOT,
                          env={"PYTHONPATH": str(ROOT), "PATH": "/usr/bin:/bin"})
    if done.returncode:
        raise RuntimeError(f"{tool} {direction} {fmt}: {done.stderr.strip().splitlines()[-1]}")
    _, seconds, rss_kib = done.stdout.split()[-3:]
    return float(seconds), int(rss_kib) / 1024


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--events", type=int, default=10_000_000)
    parser.add_argument("--repeat", type=int, default=2)
    parser.add_argument("--formats", default=None,
                        help="comma-separated formats to measure (default all); their rows "
                             "replace those in the recorded formats.json, the others are kept")
    parser.add_argument("--only", choices=("write", "read", "convert"), default=None,
                        help="measure one direction only")
    args = parser.parse_args(argv)
    chosen = None if args.formats is None else set(args.formats.split(","))
    rows = []
    with tempfile.TemporaryDirectory(prefix="bench_formats_") as tmp:
        folder, half = Path(tmp), Path(tmp) / "half"
        _source(folder, args.events)
        half.mkdir()
        _source(half, args.events // 2)
        for fmt, direction, tool, name in MEASURES:
            if chosen is not None and fmt not in chosen:
                continue
            if args.only is not None and direction != args.only:
                continue
            try:
                runs = [_run(fmt, direction, tool, folder, name) for _ in range(args.repeat)]
            except RuntimeError as error:
                print(f"skipped: {error}", file=sys.stderr)
                continue
            seconds = min(r[0] for r in runs)
            rss = max(r[1] for r in runs)
            rows.append({"format": fmt, "direction": direction, "tool": tool,
                         "seconds": seconds, "mev_per_s": args.events / seconds / 1e6,
                         "peak_rss_mib": rss})
            if direction == "convert":          # bounded: the same peak for half the events
                rows[-1]["peak_rss_mib_half"] = _run(fmt, direction, tool, half, name)[1]
            print(f"{fmt:<7} {direction:<5} {tool:<14} {args.events / seconds / 1e6:7.2f} Mev/s"
                  f"  {rss:7.0f} MiB", flush=True)
    if chosen is not None and (RESULTS / "formats.json").is_file():
        kept = json.loads((RESULTS / "formats.json").read_text())
        if kept.get("events") != args.events:
            raise SystemExit(f"formats.json holds {kept.get('events')} events, not "
                             f"{args.events}; measure every format or the same count")
        rows = [r for r in kept["rows"] if r["format"] not in chosen
                or args.only not in (None, r["direction"])] + rows
    for row in rows:
        libraries = [r["seconds"] for r in rows if r["format"] == row["format"]
                     and r["direction"] == row["direction"] and r["tool"] != "evfuse"]
        row["evfuse_over_fastest_library"] = (
            row["seconds"] / min(libraries) if row["tool"] == "evfuse" and libraries else None)
    print(f"\n{args.events:,} events, 640x480, 60 s; best of {args.repeat}; peak RSS of the "
          "process")
    print("| format | direction | tool | Mev/s | peak RSS MiB (half the events) | "
          "evfuse time / fastest library |")
    print("|---|---|---|---|---|---|")
    for row in rows:
        ratio = row["evfuse_over_fastest_library"]
        half_rss = row.get("peak_rss_mib_half")
        print(f"| {row['format']} | {row['direction']} | {row['tool']} | "
              f"{row['mev_per_s']:.2f} | {row['peak_rss_mib']:.0f}"
              f"{'' if half_rss is None else f' ({half_rss:.0f})'} | "
              f"{'' if ratio is None else f'{ratio:.2f}'} |")
    RESULTS.mkdir(exist_ok=True)
    document = {"events": args.events, "sensor": [W, H], "span_s": SPAN_US / 1e6,
                "repeat": args.repeat, "python": platform.python_version(),
                "machine": platform.machine(), "rows": rows}
    (RESULTS / "formats.json").write_text(json.dumps(document, indent=2) + "\n")
    print(f"written to {RESULTS / 'formats.json'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
