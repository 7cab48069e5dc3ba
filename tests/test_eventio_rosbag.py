"""ROS 1 and ROS 2 bags of dvs_msgs/EventArray (sim.eventio._rosbag): the NumPy serialization
against rosbags' own, bags evfuse writes read by rosbags event for event and the reverse, round
trips through every other format, exact times at the ends of ROS time, and bad input."""

from __future__ import annotations

import builtins

import numpy as np
import pytest

from sim.eventio import (
    H5EventWriter,
    TextEventWriter,
    convert_events,
    iter_event_chunks,
    make_events,
    read_events,
)
from sim.eventio._rosbag import (
    EVENT_ARRAY,
    RosEventWriter,
    bag_info,
    decode_event_array,
    encode_event_array,
    iter_bag_chunks,
    typestore,
)

pytest.importorskip("rosbags")

from rosbags.highlevel import AnyReader  # noqa: E402
from rosbags.rosbag1 import Writer as Writer1  # noqa: E402
from rosbags.rosbag2 import StoragePlugin  # noqa: E402
from rosbags.rosbag2 import Writer as Writer2  # noqa: E402

W, H = 346, 260
NS = 1_000_000_000


def _events(n, seed=0, t0=0, span=3 * NS):
    rng = np.random.default_rng(seed)
    return make_events(np.sort(rng.integers(t0, t0 + span, n)), rng.integers(0, W, n),
                       rng.integers(0, H, n), rng.choice([-1, 1], n))


def _library_message(store, events, ros):
    """An EventArray built from rosbags' own message classes, one Python object an event."""
    types = store.types
    Time = types["builtin_interfaces/msg/Time"]
    Event = types["dvs_msgs/msg/Event"]
    header = types["std_msgs/msg/Header"](stamp=Time(sec=int(events["t"][-1]) // NS,
                                                     nanosec=int(events["t"][-1]) % NS),
                                          frame_id="cam", **({"seq": 4} if ros == 1 else {}))
    return types[EVENT_ARRAY](header=header, height=H, width=W, events=[
        Event(x=int(e["x"]), y=int(e["y"]), ts=Time(sec=int(e["t"]) // NS,
                                                   nanosec=int(e["t"]) % NS),
              polarity=bool(e["p"] > 0)) for e in events])


@pytest.mark.parametrize("ros", [1, 2])
@pytest.mark.parametrize("n", [1, 2, 3, 17])
def test_the_numpy_serialization_is_rosbags_byte_for_byte(ros, n):
    store = typestore(ros)
    events = _events(n, seed=n)
    message = _library_message(store, events, ros)
    library = bytes(store.serialize_ros1(message, EVENT_ARRAY) if ros == 1
                    else store.serialize_cdr(message, EVENT_ARRAY))
    assert encode_event_array(events, W, H, ros, "cam", 4) == library
    decoded, width, height = decode_event_array(library, ros)
    assert (width, height) == (W, H)
    np.testing.assert_array_equal(decoded, events)


@pytest.mark.parametrize("ros", [1, 2])
def test_an_empty_event_array_round_trips(ros):
    store = typestore(ros)
    data = encode_event_array(np.empty(0, _events(1).dtype), W, H, ros)
    message = (store.deserialize_ros1 if ros == 1 else store.deserialize_cdr)(data, EVENT_ARRAY)
    assert len(message.events) == 0 and message.width == W
    assert decode_event_array(data, ros)[0].size == 0


BAGS = [("events.bag", {}), ("events.mcap", {}), ("bag2", {"ros": 2}),
        ("bag3", {"ros": 2, "storage": "sqlite3"})]


@pytest.mark.parametrize(("name", "options"), BAGS)
def test_what_evfuse_writes_rosbags_reads_event_for_event(tmp_path, name, options):
    events = _events(30_000)
    with RosEventWriter(tmp_path / name, W, H, **options) as writer:
        for begin in range(0, events.size, 7_001):
            writer.write(events[begin:begin + 7_001])
    assert sorted(p.name for p in tmp_path.iterdir()) == [name]     # no .partial left
    got = []
    with AnyReader([tmp_path / name]) as reader:
        assert [c.topic for c in reader.connections] == ["/dvs/events"]
        stamps = []
        for connection, stamp, data in reader.messages():
            message = reader.deserialize(data, connection.msgtype)
            assert (message.width, message.height) == (W, H)
            last = message.events[-1].ts
            assert stamp == last.sec * NS + last.nanosec == (message.header.stamp.sec * NS
                                                             + message.header.stamp.nanosec)
            stamps.append(stamp)
            got += [(e.ts.sec * NS + e.ts.nanosec, e.x, e.y, 1 if e.polarity else -1)
                    for e in message.events]
    np.testing.assert_array_equal(np.array(got), np.stack(
        [events["t"], events["x"], events["y"], events["p"]], axis=1))
    # one message per 10 ms slice of the event clock: 3 s -> 300 messages
    assert len(stamps) == len(np.unique(events["t"] // 10_000_000))


@pytest.mark.parametrize("ros", [1, 2])
def test_what_rosbags_writes_evfuse_reads_exactly(tmp_path, ros):
    events = _events(5_000, seed=3)
    store = typestore(ros)
    path = tmp_path / ("lib.bag" if ros == 1 else "lib")
    parts = np.array_split(events, 7)
    if ros == 1:
        writer = Writer1(path)
    else:
        writer = Writer2(path, version=9, storage_plugin=StoragePlugin.MCAP)
    with writer:
        connection = writer.add_connection("/cam/events", EVENT_ARRAY, typestore=store)
        for part in parts:
            message = _library_message(store, part, ros)
            data = (store.serialize_ros1(message, EVENT_ARRAY) if ros == 1
                    else store.serialize_cdr(message, EVENT_ARRAY))
            writer.write(connection, int(part["t"][-1]), data)
    np.testing.assert_array_equal(read_events(path), events)
    chunks = list(iter_event_chunks(path, 999))
    assert [c.size for c in chunks[:-1]] == [999] * (len(chunks) - 1)
    np.testing.assert_array_equal(np.concatenate(chunks), events)
    info = bag_info(path)
    assert (info["width"], info["height"], info["topic"], info["messages"]) == (W, H,
                                                                                "/cam/events", 7)
    assert (info["t_first_ns"], info["t_last_ns"]) == (events["t"][0], events["t"][-1])


def test_round_trips_through_every_other_format(tmp_path):
    events = _events(20_000, seed=5, t0=1_234_567_891)
    with TextEventWriter(tmp_path / "a.txt") as writer:
        writer.write(events)
    chain = ["a.txt", "b.bag", "c.h5", "d.mcap", "e.txt", "f.bag", "g.bag", "h.txt"]
    for src, dst in zip(chain, chain[1:], strict=False):
        convert_events(tmp_path / src, tmp_path / dst, W, H)
    for name in chain:
        np.testing.assert_array_equal(read_events(tmp_path / name), events, err_msg=name)
    assert (tmp_path / "a.txt").read_bytes() == (tmp_path / "h.txt").read_bytes()


def test_h5_to_bag_takes_the_sensor_size_and_bag_to_h5_the_bags(tmp_path):
    events = _events(1_000, seed=6)
    with H5EventWriter(tmp_path / "a.h5", W, H) as writer:
        writer.write(events)
    convert_events(tmp_path / "a.h5", tmp_path / "b", dst_selectors={"ros": 2})
    assert bag_info(tmp_path / "b")["width"] == W
    convert_events(tmp_path / "b", tmp_path / "c.h5")
    np.testing.assert_array_equal(read_events(tmp_path / "c.h5"), events)


@pytest.mark.parametrize(("ros", "last_s"), [(1, 2**32 - 1), (2, 2**31 - 1)])
def test_times_are_exact_to_the_nanosecond_at_the_end_of_ros_time(tmp_path, ros, last_s):
    t = np.array([0, 1, NS - 1, NS, 16_777_215_999, 2**31 * NS - 1, last_s * NS + NS - 1])
    t = np.sort(t[t <= last_s * NS + NS - 1])
    events = make_events(t, np.arange(t.size), np.zeros(t.size, int), np.ones(t.size, int))
    path = tmp_path / ("t.bag" if ros == 1 else "t.mcap")
    with RosEventWriter(path, W, H) as writer:
        writer.write(events)
    np.testing.assert_array_equal(read_events(path), events)
    too_late = make_events([(last_s + 1) * NS], [0], [0], [1])
    with pytest.raises(ValueError, match=rf"outside a ROS {ros} time \(0 to {last_s} s\)"), \
            RosEventWriter(tmp_path / ("u.bag" if ros == 1 else "u.mcap"), W, H) as writer:
        writer.write(too_late)
    assert not list(tmp_path.glob("u*"))


def test_messages_split_at_slices_and_at_the_event_cap_whatever_the_chunks(tmp_path):
    t = np.r_[np.arange(0, 25) * 1_000_000, 30_000_000 + np.arange(10)]  # 25 ms + 10 at 30 ms
    events = make_events(t, np.zeros(t.size, int), np.zeros(t.size, int), np.ones(t.size, int))
    sizes = []
    for step in (1, 4, t.size):
        path = tmp_path / f"s{step}.bag"
        with RosEventWriter(path, W, H, max_events=4) as writer:
            for begin in range(0, t.size, step):
                writer.write(events[begin:begin + step])
        with AnyReader([path]) as reader:
            sizes.append([len(reader.deserialize(d, c.msgtype).events)
                          for c, _, d in reader.messages()])
    # slices 0-10 ms, 10-20 ms, 20-25 ms (10, 10, 5 events), 30 ms (10), at most 4 a message
    assert sizes[0] == sizes[1] == sizes[2] == [4, 4, 2, 4, 4, 2, 4, 1, 4, 4, 2]


def test_a_time_window_reads_only_its_events(tmp_path):
    events = _events(10_000, seed=8)
    with RosEventWriter(tmp_path / "w.bag", W, H) as writer:
        writer.write(events)
    t0, t1 = NS, 2 * NS + 5
    inside = events[(events["t"] >= t0) & (events["t"] < t1)]
    np.testing.assert_array_equal(np.concatenate(list(iter_event_chunks(tmp_path / "w.bag",
                                                                        500, t0, t1))), inside)


# --- bad input: one line naming the file, nothing written ------------------------------------

def _message_bag(path, parts, ros=1, topic="/dvs/events"):
    store = typestore(ros)
    writer = Writer1(path) if ros == 1 else Writer2(path, version=9)
    with writer:
        connection = writer.add_connection(topic, EVENT_ARRAY, typestore=store)
        for k, part in enumerate(parts):
            writer.write(connection, k + 1, encode_event_array(part, W, H, ros))


def test_a_time_before_the_previous_events_is_reported_by_index_not_sorted(tmp_path):
    events = _events(100, seed=9)
    later, earlier = events[50:], events[:50]
    _message_bag(tmp_path / "n.bag", [later, earlier])
    with pytest.raises(ValueError, match=r"n\.bag: event 50: t = \d+ ns is before the previous"):
        read_events(tmp_path / "n.bag")
    t = np.arange(20) * 1000
    t[[10, 11]] = t[[11, 10]]
    swapped = make_events(t, np.zeros(20, int), np.zeros(20, int), np.ones(20, int))
    _message_bag(tmp_path / "m.bag", [swapped])
    with pytest.raises(ValueError, match=r"m\.bag: event 11: "):
        read_events(tmp_path / "m.bag")


def test_a_bag_without_events_and_a_topic_not_there_are_named(tmp_path):
    store = typestore(1)
    with Writer1(tmp_path / "none.bag") as writer:
        connection = writer.add_connection("/chatter", "std_msgs/msg/String", typestore=store)
        writer.write(connection, 1, store.serialize_ros1(
            store.types["std_msgs/msg/String"](data="hi"), "std_msgs/msg/String"))
    with pytest.raises(ValueError, match=r"none\.bag: no dvs_msgs/msg/EventArray topic; "
                                         r"expected a bag with events \(its topics: "
                                         r"\['/chatter'\]\)"):
        read_events(tmp_path / "none.bag")
    _message_bag(tmp_path / "e.bag", [_events(10)])
    with pytest.raises(ValueError, match=r"e\.bag: no topic '/other'; expected one of "
                                         r"\['/dvs/events'\]"):
        list(iter_event_chunks(tmp_path / "e.bag", options={"topic": "/other"}))
    (tmp_path / "x.txt").write_text("0.1 1 1 1\n")
    with pytest.raises(ValueError, match=r"x\.txt: topic do\(es\) not apply to a txt file"):
        list(iter_event_chunks(tmp_path / "x.txt", options={"topic": "/dvs/events"}))


def test_two_event_topics_need_one_named(tmp_path):
    store = typestore(1)
    with Writer1(tmp_path / "two.bag") as writer:
        for topic in ("/a/events", "/b/events"):
            connection = writer.add_connection(topic, EVENT_ARRAY, typestore=store)
            writer.write(connection, 1, encode_event_array(_events(3), W, H, 1))
    with pytest.raises(ValueError, match=r"2 dvs_msgs/msg/EventArray topics \['/a/events', "
                                         r"'/b/events'\]; expected the event topic named"):
        read_events(tmp_path / "two.bag")
    assert iter_bag_chunks(tmp_path / "two.bag", topic="/b/events").__next__().size == 3


@pytest.mark.parametrize("name", ["t.bag", "t.mcap"])
def test_a_truncated_bag_is_one_line_naming_it(tmp_path, name):
    with RosEventWriter(tmp_path / name, W, H) as writer:
        writer.write(_events(20_000))
    data = (tmp_path / name).read_bytes()
    (tmp_path / name).write_bytes(data[: len(data) // 2])
    with pytest.raises(ValueError, match=rf"{name}: not a readable ROS [12] bag .*; expected "
                                         "a complete"):
        read_events(tmp_path / name)


def test_a_corrupt_message_is_named_by_its_index(tmp_path):
    store = typestore(1)
    with Writer1(tmp_path / "c.bag") as writer:
        connection = writer.add_connection("/dvs/events", EVENT_ARRAY, typestore=store)
        writer.write(connection, 1, encode_event_array(_events(3), W, H, 1))
        writer.write(connection, 2, encode_event_array(_events(3), W, H, 1)[:-2])
    with pytest.raises(ValueError, match=r"c\.bag: event message 1: 3 events need 39 bytes "
                                         r"after the header, the message has 37"):
        read_events(tmp_path / "c.bag")


def test_the_ros_version_comes_from_the_name_or_is_asked_for(tmp_path):
    with pytest.raises(ValueError, match=r"cannot tell the ROS version from the name"):
        RosEventWriter(tmp_path / "plain", W, H)
    with pytest.raises(ValueError, match=r"a \.bag is a ROS 1 bag, not ROS 2"):
        RosEventWriter(tmp_path / "x.bag", W, H, ros=2)
    with pytest.raises(ValueError, match="unknown event file type '.foo'"):
        read_events(tmp_path / "x.foo")
    assert not list(tmp_path.iterdir())


def test_an_interrupted_writer_leaves_nothing(tmp_path):
    for name, options in BAGS:
        with pytest.raises(RuntimeError), RosEventWriter(tmp_path / name, W, H,
                                                         **options) as writer:
            writer.write(_events(1000))
            raise RuntimeError("interrupted")
    assert not list(tmp_path.iterdir())
    with pytest.raises(ValueError, match="cannot be checkpointed"), \
            RosEventWriter(tmp_path / "k.bag", W, H) as writer:
        writer.checkpoint()
    assert not list(tmp_path.iterdir())


def test_a_failed_conversion_to_a_bag_leaves_nothing(tmp_path):
    (tmp_path / "bad.txt").write_text("0.1 1 1 1\n0.05 2 2 0\n")
    for dst in ("out.bag", "out.mcap", "out2"):
        with pytest.raises(ValueError, match=r"bad\.txt:2: .*before"):
            convert_events(tmp_path / "bad.txt", tmp_path / dst, W, H,
                           dst_selectors={"ros": 2 if dst == "out2" else None})
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bad.txt"]


def test_without_rosbags_one_line_names_the_extra(tmp_path, monkeypatch):
    real_import = builtins.__import__

    def no_rosbags(name, *args, **kwargs):
        if name.startswith("rosbags"):
            raise ImportError(name)
        return real_import(name, *args, **kwargs)

    monkeypatch.setattr(builtins, "__import__", no_rosbags)
    with pytest.raises(ValueError, match=r"^ROS bags need rosbags, which is not installed; "
                                         r"expected it from pip install 'evfuse\[formats\]'$"):
        RosEventWriter(tmp_path / "x.bag", W, H)


def test_convert_bad_bag_input_is_one_line_and_writes_nothing(tmp_path, capsys):
    from tests.conftest import run_cli

    _message_bag(tmp_path / "e.bag", [_events(10)])
    (tmp_path / "cut.bag").write_bytes((tmp_path / "e.bag").read_bytes()[:100])
    cases = [(["e.bag", "o.txt", "--topic", "/nope"], "e.bag: no topic '/nope'"),
             (["cut.bag", "o.txt"], "cut.bag: not a readable ROS 1 bag"),
             (["e.bag", "o.h5x"], "unknown event file type '.h5x'"),
             (["e.bag", "o.bag", "--ros", "2"], "o.bag: ros=2 is not a .bag format"),
             (["e.bag", "plain"], "e.bag: no sensor_msgs/CameraInfo topic; expected the "
                                   "camera's intrinsics"),
             (["e.bag", "plain.x"], "unknown event file type '.x'; expected")]
    for argv, expected in cases:
        code = run_cli(["convert", *(str(tmp_path / a) if not a.startswith("-") and a not in
                                     ("/nope", "2") else a for a in argv)])
        err = capsys.readouterr().err.strip().splitlines()
        assert code == 2 and len(err) == 1 and expected in err[0], (argv, err)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["cut.bag", "e.bag"]
    assert run_cli(["convert", str(tmp_path / "e.bag"), str(tmp_path / "o.mcap")]) == 0
    np.testing.assert_array_equal(read_events(tmp_path / "o.mcap"), read_events(tmp_path /
                                                                                "e.bag"))


def test_a_window_does_not_trust_the_bag_time_of_a_message(tmp_path):
    """A recorder stamps a message when it arrives; here every bag time is 1 ns, before all
    of its events: a window still finds its events by their own times."""
    events = _events(3000, seed=11)
    _message_bag(tmp_path / "r.bag", np.array_split(events, 30))     # bag times 1..30 ns
    t0, t1 = int(events["t"][1000]), int(events["t"][2000])
    np.testing.assert_array_equal(np.concatenate(list(iter_event_chunks(tmp_path / "r.bag",
                                                                        256, t0, t1))),
                                  events[1000:2000])


def test_a_recording_bag_with_two_event_topics_is_read_by_the_topic_given(tmp_path, capsys,
                                                                         monkeypatch):
    """The commands that read a recording take --topic: a bag with two event topics is read
    from the one named (and refused without it, or with a topic it does not hold)."""
    from sim.recording import recording_folder
    from tests.conftest import run_cli

    monkeypatch.setenv("EVFUSE_CACHE", str(tmp_path / "cache"))
    store = typestore(1)
    bag = tmp_path / "two.bag"
    with Writer1(bag) as writer:
        for topic, count in (("/a/events", 3), ("/b/events", 5)):
            connection = writer.add_connection(topic, EVENT_ARRAY, typestore=store)
            writer.write(connection, 1, encode_event_array(_events(count), W, H, 1))
    calib = tmp_path / "calib.txt"
    calib.write_text("200 200 173 130 0 0 0 0 0\n")
    for topic, count in (("/a/events", 3), ("/b/events", 5)):
        folder = recording_folder(bag, calib=calib, topic=topic, cache=tmp_path / "cache")
        assert len(read_events(folder / "events.h5")) == count
    assert run_cli(["events", str(bag), "--stats", "--calib", str(calib)]) == 2
    assert "expected the one to read named (--topic)" in capsys.readouterr().err
    assert run_cli(["events", str(bag), "--stats", "--calib", str(calib), "--topic",
                    "/c/events"]) == 2
    assert "/c/events" in capsys.readouterr().err
    assert run_cli(["events", str(bag), "--stats", "--calib", str(calib), "--topic",
                    "/b/events"]) == 0
    assert [line.split() for line in capsys.readouterr().out.splitlines()
            if line.split()[:1] == ["count"]] == [["count", "5"]]
    raw = tmp_path / "x.raw"
    convert_events(bag, raw, src_options={"topic": "/a/events"})
    with pytest.raises(ValueError, match="has no topics; expected topic only with a ROS bag"):
        recording_folder(raw, calib=calib, topic="/a/events", cache=tmp_path / "cache")
