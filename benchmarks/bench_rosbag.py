"""ROS bag rows of the formats benchmark: events/s written and read, peak memory, beside rosbags.

Each case runs in its own process (so its peak resident memory, ``ru_maxrss``, is its own):

1. evfuse writes N synthetic events (a random stream, 640x480, 1 Mev/s of event clock,
   generated chunk by chunk in the process, never held whole) to ``.bag`` (ROS 1) and ``.mcap``
   (ROS 2) with :class:`sim.eventio._rosbag.RosEventWriter`, and reads them back with
   :func:`sim.eventio.iter_event_chunks` (1 M-event chunks);
2. the same conversion as ``evfuse convert`` does, ``events.h5`` -> bag and bag -> ``events.h5``;
3. the library, rosbags, on the same kind of stream: its own serializer (``serialize_ros1`` /
   ``serialize_cdr`` of ``dvs_msgs/EventArray`` messages built from its message classes, one
   object an event) writing, and ``AnyReader`` + ``deserialize`` reading. It is the only
   pip-installable reader and writer of these bags, so it is the baseline; it runs on
   ``--library-events`` (default 1 M) events, as a per-event Python loop over 10 M takes
   minutes; rates (events/s) are what is compared.

The ratio evfuse / rosbags is of rates measured in the same run. Run:
``.venv/bin/python benchmarks/bench_rosbag.py [--events 10000000]``; the table is printed and
written to ``benchmarks/results/formats_ros.json`` (rows for ``bench_formats.py``'s table).
"""

from __future__ import annotations

import argparse
import json
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

RESULTS = Path(__file__).resolve().parent / "results"
WIDTH, HEIGHT = 640, 480
CHUNK = 1 << 20


def _stream(n: int, seed: int = 0):
    """N events in CHUNK-sized chunks, 1 Mev/s of event clock, random pixels."""
    from sim.eventio import EVENT_DTYPE

    rng = np.random.default_rng(seed)
    t0 = 0
    for begin in range(0, n, CHUNK):
        size = min(CHUNK, n - begin)
        chunk = np.empty(size, EVENT_DTYPE)
        chunk["t"] = t0 + np.sort(rng.integers(0, size * 1000, size))
        chunk["x"] = rng.integers(0, WIDTH, size)
        chunk["y"] = rng.integers(0, HEIGHT, size)
        chunk["p"] = rng.choice(np.array([-1, 1], np.int8), size)
        t0 += size * 1000
        yield chunk


def _case(kind: str, path: str, n: int) -> dict:
    """One case in this process: seconds and events."""
    from sim.eventio import H5EventWriter, convert_events, iter_event_chunks
    from sim.eventio._rosbag import RosEventWriter

    start = time.perf_counter()
    count = n
    if kind == "none":
        import rosbags.highlevel  # noqa: F401  (what every case imports)
    elif kind == "write":
        with RosEventWriter(path, WIDTH, HEIGHT) as writer:
            for chunk in _stream(n):
                writer.write(chunk)
    elif kind == "read":
        count = sum(chunk.size for chunk in iter_event_chunks(path, CHUNK))
    elif kind == "h5":                                    # the source of the conversions
        with H5EventWriter(path, WIDTH, HEIGHT) as writer:
            for chunk in _stream(n):
                writer.write(chunk)
    elif kind.startswith("convert:"):
        convert_events(kind.split(":", 1)[1], path)
    elif kind == "library-write":
        _library_write(path, n)
    elif kind == "library-read":
        count = _library_read(path)
    return {"seconds": time.perf_counter() - start, "events": count}


def _library_messages(store, n: int, ros: int):
    types = store.types
    Time, Event = types["builtin_interfaces/msg/Time"], types["dvs_msgs/msg/Event"]
    Header, Array = types["std_msgs/msg/Header"], types["dvs_msgs/msg/EventArray"]
    for chunk in _stream(n):
        slot = chunk["t"] // 10_000_000
        for part in np.split(chunk, np.flatnonzero(np.diff(slot)) + 1):
            t = part["t"].tolist()
            events = [Event(x=x, y=y, ts=Time(sec=ti // 10**9, nanosec=ti % 10**9),
                            polarity=p > 0)
                      for x, y, ti, p in zip(part["x"].tolist(), part["y"].tolist(), t,
                                             part["p"].tolist(), strict=True)]
            header = Header(stamp=Time(sec=t[-1] // 10**9, nanosec=t[-1] % 10**9),
                            frame_id="", **({"seq": 0} if ros == 1 else {}))
            yield t[-1], Array(header=header, height=HEIGHT, width=WIDTH, events=events)


def _library_write(path: str, n: int) -> None:
    from rosbags.rosbag1 import Writer as Writer1
    from rosbags.rosbag2 import StoragePlugin
    from rosbags.rosbag2 import Writer as Writer2

    from sim.eventio._rosbag import EVENT_ARRAY, typestore

    ros = 1 if path.endswith(".bag") else 2
    store = typestore(ros)
    writer = (Writer1(Path(path)) if ros == 1
              else Writer2(Path(path), version=9, storage_plugin=StoragePlugin.MCAP))
    serialize = store.serialize_ros1 if ros == 1 else store.serialize_cdr
    with writer:
        connection = writer.add_connection("/dvs/events", EVENT_ARRAY, typestore=store)
        for stamp, message in _library_messages(store, n, ros):
            writer.write(connection, stamp, serialize(message, EVENT_ARRAY))


def _library_read(path: str) -> int:
    from rosbags.highlevel import AnyReader

    count = 0
    with AnyReader([Path(path)]) as reader:
        for connection, _, data in reader.messages():
            message = reader.deserialize(data, connection.msgtype)
            count += len(message.events)
    return count


def _run(kind: str, path: Path, n: int) -> dict:
    """``_case`` in a child process; its result with the child's peak RSS (MiB)."""
    code = (f"import json, resource, sys; sys.path.insert(0, {str(Path.cwd())!r}); "
            f"from benchmarks.bench_rosbag import _case; "
            f"r = _case({kind!r}, {str(path)!r}, {n}); "
            f"r['peak_rss_mib'] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024; "
            f"print(json.dumps(r))")
    out = subprocess.run([sys.executable, "-c", code], check=True, capture_output=True,
                         text=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--events", type=int, default=10_000_000)
    parser.add_argument("--library-events", type=int, default=1_000_000)
    args = parser.parse_args(argv)
    rows = []
    with tempfile.TemporaryDirectory() as folder:
        folder = Path(folder)
        baseline = _run("none", Path("/dev/null"), 0)["peak_rss_mib"]     # imports only
        h5 = folder / "src.h5"
        _run("h5", h5, args.events)
        for fmt, name in (("ROS 1 .bag", "e.bag"), ("ROS 2 .mcap", "e.mcap")):
            path = folder / name
            for what, kind, target, n in (
                    ("evfuse write", "write", path, args.events),
                    ("evfuse read", "read", path, args.events),
                    ("evfuse convert h5 -> bag", f"convert:{h5}", folder / f"c{name}", 0),
                    ("evfuse convert bag -> h5", f"convert:{path}", folder / f"{name}.h5", 0),
                    ("rosbags write", "library-write", folder / f"lib{name}", args.library_events),
                    ("rosbags read", "library-read", folder / f"lib{name}", 0)):
                result = _run(kind, target, n)
                events = result["events"] or args.events
                rows.append({"format": fmt, "case": what, "events": events,
                             "seconds": round(result["seconds"], 3),
                             "mev_per_s": round(events / result["seconds"] / 1e6, 3),
                             "peak_rss_mib": round(result["peak_rss_mib"], 1)})
                if what.startswith("evfuse convert"):
                    rows[-1]["events"] = args.events
                    rows[-1]["mev_per_s"] = round(args.events / result["seconds"] / 1e6, 3)
    for fmt in ("ROS 1 .bag", "ROS 2 .mcap"):
        mine = {r["case"]: r["mev_per_s"] for r in rows if r["format"] == fmt}
        for r in rows:
            if r["format"] == fmt and r["case"] in ("evfuse write", "evfuse read"):
                library = mine["rosbags " + r["case"].split()[1]]
                r["ratio_to_rosbags"] = round(r["mev_per_s"] / library, 1)
    print(f"{'format':12} {'case':26} {'events':>10} {'s':>8} {'Mev/s':>7} {'peak MiB':>9} "
          f"{'x rosbags':>9}")
    for r in rows:
        print(f"{r['format']:12} {r['case']:26} {r['events']:>10} {r['seconds']:>8.2f} "
              f"{r['mev_per_s']:>7.2f} {r['peak_rss_mib']:>9.1f} "
              f"{r.get('ratio_to_rosbags', ''):>9}")
    RESULTS.mkdir(exist_ok=True)
    record = {"events": args.events, "library_events": args.library_events,
              "interpreter_peak_rss_mib": round(baseline, 1), "rows": rows,
              "machine": f"{platform.machine()}, {platform.python_version()}, shared 2-core "
                         "development machine (timings only indicative)",
              "note": "each case in its own process; peak RSS is that process's ru_maxrss"}
    (RESULTS / "formats_ros.json").write_text(json.dumps(record, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
