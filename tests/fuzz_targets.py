"""Property-based fuzz targets: every parser and entry point a user feeds (issue 21, "Fuzzing").

Each target is a Hypothesis strategy of cases and a property that one case must satisfy. The
property is the same everywhere: the outcome is either success, with every figure finite, or a
refusal (``ValueError`` from a library entry point, exit status 2 from the command line) whose
message is ONE line naming the input (the file, the flag); never another exception type (what a
user sees as a traceback, or ``evfuse CMD: unexpected error``), and never a change to the input
(its files are hashed before and after).

``tests/test_fuzz.py`` runs each target with the ``ci`` settings profile (a few hundred cases,
derandomized); ``benchmarks/fuzz.py`` runs them for many thousands of cases.
"""

from __future__ import annotations

import contextlib
import copy
import dataclasses
import hashlib
import io
import json
import math
import os
import re
import tempfile
import tomllib
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
from hypothesis import strategies as st

from tests.conftest import WALL, scene_text

# --- the property ------------------------------------------------------------------------------


def file_hashes(*paths: Path) -> dict[str, str]:
    """SHA-256 of every file under ``paths`` (files or folders), by path."""
    hashes = {}
    for path in paths:
        files = [path] if path.is_file() else sorted(p for p in path.rglob("*") if p.is_file())
        for file in files:
            hashes[str(file)] = hashlib.sha256(file.read_bytes()).hexdigest()
    return hashes


def check_refusal(message: str, names: tuple[str, ...]) -> None:
    """A refusal's message: one non-empty line that names one of ``names``."""
    assert message.strip(), "an empty error message"
    assert "\n" not in message.strip(), f"a message of several lines: {message!r}"
    assert any(name in message for name in names), \
        f"the message names none of {names}: {message!r}"


def refused_or_result(call: Callable[[], Any], inputs: tuple[Path, ...],
                      names: tuple[str, ...]) -> Any:
    """``call()``'s result, or None when it raised a ValueError whose message is one line naming
    one of ``names``; any other exception propagates (a failure of the property). The files of
    ``inputs`` must be unchanged either way."""
    before = file_hashes(*inputs)
    try:
        result = call()
    except ValueError as exc:
        check_refusal(str(exc), names)
        result = None
    assert file_hashes(*inputs) == before, "the input was modified"
    return result


def non_finite(value: Any, where: str = "", depth: int = 0, seen: set | None = None) -> str | None:
    """Where a non-finite float hides in ``value`` (dataclasses, containers, arrays and plain
    objects' attributes, a few levels deep), or None."""
    seen = set() if seen is None else seen
    if depth > 6 or id(value) in seen:
        return None
    if isinstance(value, float | np.floating):
        return None if math.isfinite(value) else where or "value"
    if isinstance(value, np.ndarray):
        if value.dtype.kind in "fc" and not np.isfinite(value).all():
            return where or "array"
        if value.dtype.names:
            for name in value.dtype.names:
                found = non_finite(value[name], f"{where}.{name}", depth + 1, seen)
                if found:
                    return found
        return None
    if isinstance(value, str | bytes | int | bool | Path | type(None)) or callable(value):
        return None
    seen.add(id(value))
    if isinstance(value, dict):
        items = value.items()
    elif isinstance(value, list | tuple | set | frozenset):
        items = enumerate(value)
    elif dataclasses.is_dataclass(value):
        items = ((f.name, getattr(value, f.name)) for f in dataclasses.fields(value))
    elif hasattr(value, "__dict__"):
        items = vars(value).items()
    else:
        return None
    for key, item in items:
        found = non_finite(item, f"{where}.{key}", depth + 1, seen)
        if found:
            return found
    return None


def assert_finite(value: Any) -> None:
    found = non_finite(value)
    assert found is None, f"success with a non-finite figure at {found}"


@contextlib.contextmanager
def scratch() -> Any:
    """A fresh temporary folder for one case (Hypothesis runs many cases per test)."""
    with tempfile.TemporaryDirectory(prefix="evfuse-fuzz-") as folder:
        yield Path(folder)


# --- strategies shared by the text formats -------------------------------------------------------

SPECIAL_NUMBERS = ("nan", "NaN", "-nan", "inf", "-inf", "Infinity", "1e999", "-1e999", "1e308",
                   "-1e308", "1e-320", "0", "-0", "0.0", "1e-9", "9223372036854775807",
                   "18446744073709551616", "1_000", "0x10", "1e", ".", "-", "+1", "1.5e+3")
WORDS = ("abc", "t", "#", "#x", "x", "None", "true", "'1'", "1,2", "\u00e9", "\x00", "1\x0b2")


def number_text() -> st.SearchStrategy[str]:
    """The text of a number as a user might write it: ordinary, huge, tiny, non-finite."""
    return st.one_of(
        st.floats(allow_nan=True, allow_infinity=True).map(repr),
        st.floats(-1e4, 1e4, allow_nan=False).map(lambda v: f"{v:.9f}"),
        st.integers(-10**20, 10**20).map(str),
        st.sampled_from(SPECIAL_NUMBERS),
    )


def field_text() -> st.SearchStrategy[str]:
    return st.one_of(number_text(), number_text(), st.sampled_from(WORDS),
                     st.text(st.characters(codec="utf-8", exclude_characters="\n\r"),
                             min_size=1, max_size=6).filter(lambda s: s.strip() == s and s))


def line_text(columns: int) -> st.SearchStrategy[str]:
    """A line of about ``columns`` fields (sometimes one more or fewer)."""
    count = st.sampled_from([columns] * 6 + [0, 1, max(columns - 1, 0), columns + 1])
    return count.flatmap(lambda n: st.lists(field_text(), min_size=n, max_size=n)).map(" ".join)


@st.composite
def mutated(draw: Any, base: bytes) -> bytes:
    """``base`` with one to three mutations: truncated, bytes overwritten or inserted, a line
    dropped, duplicated or swapped, a field replaced."""
    data = bytearray(base)
    for _ in range(draw(st.integers(1, 3))):
        kind = draw(st.sampled_from(["truncate", "overwrite", "insert", "drop", "swap", "dup",
                                     "field", "field", "field"]))
        lines = bytes(data).split(b"\n")
        if kind == "truncate":
            data = data[:draw(st.integers(0, len(data)))]
        elif kind == "overwrite" and data:
            at = draw(st.integers(0, len(data) - 1))
            junk = draw(st.binary(min_size=1, max_size=8))
            data[at:at + len(junk)] = junk
        elif kind == "insert":
            at = draw(st.integers(0, len(data)))
            data[at:at] = draw(st.sampled_from([b" ", b"\n", b"\r\n", b"\t", b"#", b"-", b".",
                                                b"\xff", b"nan", b"\x00"]))
        elif kind in ("drop", "swap", "dup") and len(lines) > 1:
            i = draw(st.integers(0, len(lines) - 2))
            j = draw(st.integers(0, len(lines) - 2))
            if kind == "drop":
                del lines[i]
            elif kind == "swap":
                lines[i], lines[j] = lines[j], lines[i]
            else:
                lines.insert(i, lines[j])
            data = bytearray(b"\n".join(lines))
        elif kind == "field" and len(lines) > 1:
            i = draw(st.integers(0, len(lines) - 2))
            fields = lines[i].split(b" ")
            k = draw(st.integers(0, len(fields) - 1))
            fields[k] = draw(field_text()).encode("utf-8")
            lines[i] = b" ".join(fields)
            data = bytearray(b"\n".join(lines))
    return bytes(data)


def text_file(valid: st.SearchStrategy[bytes], columns: int) -> st.SearchStrategy[bytes]:
    """A file's bytes: valid, a mutation of a valid one, random lines, or random bytes."""
    random_lines = st.lists(line_text(columns), max_size=6).map(
        lambda lines: ("\n".join(lines) + "\n").encode("utf-8"))
    return st.one_of(valid, valid.flatmap(mutated), valid.flatmap(mutated), random_lines,
                     st.binary(max_size=64))


def write_case(folder: Path, name: str, data: bytes) -> Path:
    path = folder / name
    path.write_bytes(data)
    return path


# --- calib.txt ---------------------------------------------------------------------------------

def _calib_valid() -> st.SearchStrategy[bytes]:
    positive = st.floats(1.0, 2000.0)
    centre = st.floats(0.0, 640.0)
    small = st.floats(-1.0, 1.0)
    return st.tuples(positive, positive, centre, centre,
                     st.sampled_from([0, 4, 5]).flatmap(
                         lambda n: st.lists(small, min_size=n, max_size=n))).map(
        lambda v: (" ".join(repr(x) for x in (*v[:4], *v[4])) + "\n").encode())


CALIB_CASES = text_file(_calib_valid(), 9)


def check_calib(data: bytes) -> None:
    from sim.camera import read_calib

    with scratch() as folder:
        path = write_case(folder, "calib.txt", data)
        camera = refused_or_result(lambda: read_calib(path, 240, 180), (path,), (str(path),))
        if camera is not None:
            assert_finite(camera)
            assert camera.fx > 0 and camera.fy > 0


# --- groundtruth.txt ---------------------------------------------------------------------------

@st.composite
def _groundtruth_valid(draw: Any) -> bytes:
    n = draw(st.integers(2, 6))
    t0 = draw(st.floats(0.0, 1e9))
    steps = draw(st.lists(st.floats(1e-3, 10.0), min_size=n, max_size=n))
    lines = []
    t = t0
    for step in steps:
        t += step
        pose = draw(st.lists(st.floats(-10.0, 10.0), min_size=7, max_size=7))
        if not any(pose[3:]):
            pose[6] = 1.0
        lines.append(f"{t:.9f} " + " ".join(repr(v) for v in pose))
    header = draw(st.sampled_from(["", "# timestamp tx ty tz qx qy qz qw\n"]))
    return (header + "\n".join(lines) + "\n").encode()


GROUNDTRUTH_CASES = text_file(_groundtruth_valid(), 8)


def check_groundtruth(data: bytes) -> None:
    from sim.trajectory import read_trajectory

    with scratch() as folder:
        path = write_case(folder, "groundtruth.txt", data)
        trajectory = refused_or_result(lambda: read_trajectory(path), (path,), (str(path),))
        if trajectory is not None:
            times = np.linspace(trajectory.t_start, trajectory.t_end, 5)
            poses = trajectory.pose(times)
            assert np.isfinite(poses).all(), "success with non-finite poses"
            rotations = poses[:, :3, :3]
            assert np.allclose(rotations @ rotations.transpose(0, 2, 1), np.eye(3), atol=1e-6), \
                "success with a rotation that is not orthonormal"


# --- images.txt --------------------------------------------------------------------------------

@st.composite
def _images_valid(draw: Any) -> bytes:
    n = draw(st.integers(0, 5))
    t = draw(st.floats(0.0, 1e6))
    lines = []
    for k in range(n):
        t += draw(st.floats(1e-3, 1.0))
        lines.append(f"{t:.9f} images/frame_{k:08d}.png")
    return ("\n".join(lines) + "\n").encode()


IMAGES_CASES = text_file(_images_valid(), 2)


def check_images(data: bytes) -> None:
    from sim.sequence import read_index

    with scratch() as folder:
        (folder / "images").mkdir()
        for k in range(3):
            (folder / "images" / f"frame_{k:08d}.png").write_bytes(b"x")
        path = write_case(folder, "images.txt", data)
        for check_files in (False, True):
            result = refused_or_result(lambda c=check_files: read_index(path, check_files=c),
                                       (folder,), (str(path),))
            if result is not None:
                times, names = result
                assert np.isfinite(times).all() and len(times) == len(names)
                assert (np.diff(times) > 0).all()


# --- events.txt --------------------------------------------------------------------------------

WIDTH, HEIGHT = 64, 48


@st.composite
def _events_txt_valid(draw: Any) -> bytes:
    n = draw(st.integers(0, 12))
    t = draw(st.integers(0, 10**12))
    lines = []
    for _ in range(n):
        t += draw(st.integers(0, 10**7))
        x, y = draw(st.integers(0, WIDTH - 1)), draw(st.integers(0, HEIGHT - 1))
        lines.append(f"{t // 10**9}.{t % 10**9:09d} {x} {y} {draw(st.integers(0, 1))}")
    return ("\n".join(lines) + "\n").encode()


EVENTS_TXT_CASES = text_file(_events_txt_valid(), 4)


def check_event_array(events: np.ndarray) -> None:
    """A successfully read stream obeys CONVENTIONS.md ("Events") inside the fuzz sensor."""
    from sim.eventio import EVENT_DTYPE

    assert events.dtype == EVENT_DTYPE
    assert (np.diff(events["t"]) >= 0).all(), "success with unsorted times"
    assert (events["t"] >= 0).all(), "success with negative times"
    assert (events["x"] < WIDTH).all() and (events["y"] < HEIGHT).all()
    assert np.isin(events["p"], (-1, 1)).all()


def check_events_txt(data: bytes) -> None:
    from sim.eventio import event_time_span, read_events, read_window

    with scratch() as folder:
        path = write_case(folder, "events.txt", data)
        names = (str(path),)
        events = refused_or_result(lambda: read_events(path, WIDTH, HEIGHT), (path,), names)
        if events is not None:
            check_event_array(events)
            window = refused_or_result(lambda: read_window(path, 0, 10**13), (path,), names)
            assert window is not None
            if len(events):
                span = event_time_span(path, WIDTH, HEIGHT)
                assert math.isfinite(span[0]) and math.isfinite(span[1])


# --- events.h5 ---------------------------------------------------------------------------------

_H5_BASE: dict[str, bytes] = {}


def h5_base() -> bytes:
    """A valid small ``events.h5`` (DSEC layout, 3 chunks of 256 events over 90 ms)."""
    if "base" not in _H5_BASE:
        from sim.eventio import H5EventWriter, make_events

        rng = np.random.default_rng(21)
        n = 700
        t = np.sort(10**9 + rng.integers(0, 90 * 10**6, n))
        events = make_events(t, rng.integers(0, WIDTH, n), rng.integers(0, HEIGHT, n),
                             rng.choice([-1, 1], n))
        with scratch() as folder:
            with H5EventWriter(folder / "events.h5", WIDTH, HEIGHT, chunk_size=256) as writer:
                writer.write(events)
            _H5_BASE["base"] = (folder / "events.h5").read_bytes()
    return _H5_BASE["base"]


H5_EDITS = ("drop_dataset", "dtype", "unsorted", "values", "length", "ms_to_idx", "attrs")
_H5_FIELDS = ("events/t", "events/x", "events/y", "events/p", "events/t_ns_rem", "ms_to_idx",
              "t_offset")


@st.composite
def _h5_edit(draw: Any) -> dict:
    """One edit of the HDF5 structure (applied with h5py), drawn as plain data."""
    kind = draw(st.sampled_from(H5_EDITS))
    field = draw(st.sampled_from(_H5_FIELDS))
    return {"kind": kind, "field": field, "index": draw(st.integers(0, 699)),
            "dtype": draw(st.sampled_from(["f8", "f4", "i1", "i8", "u8", "S4", "i2"])),
            "value": draw(st.one_of(st.integers(-2**63, 2**63 - 1),
                                    st.sampled_from([-1, 0, 1, 2, 999, 1000, 65535, 65536]))),
            "float": draw(st.floats(allow_nan=True, allow_infinity=True)),
            "length": draw(st.integers(0, 800)),
            "attr": draw(st.sampled_from(["width", "height", "t_offset"]))}


@st.composite
def _h5_bytes_edit(draw: Any) -> dict:
    kind = draw(st.sampled_from(["truncate", "overwrite", "overwrite"]))
    size = len(h5_base())
    at = draw(st.integers(0, size - 1))
    return {"kind": kind, "at": at, "junk": draw(st.binary(min_size=1, max_size=256))}


H5_CASES = st.lists(st.one_of(_h5_edit(), _h5_edit(), _h5_bytes_edit()), min_size=0, max_size=3)


def _apply_h5_edit(path: Path, edit: dict) -> None:
    import h5py

    if edit["kind"] in ("truncate", "overwrite"):
        data = bytearray(path.read_bytes())
        if edit["kind"] == "truncate":
            data = data[:edit["at"]]
        else:
            data[edit["at"]:edit["at"] + len(edit["junk"])] = edit["junk"]
        path.write_bytes(bytes(data))
        return
    try:
        with h5py.File(path, "r+") as file:
            _edit_h5(file, edit)
    except Exception:        # an earlier edit broke the file so that h5py cannot edit it
        return


def _edit_h5(file: Any, edit: dict) -> None:
    field = edit["field"]
    if edit["kind"] == "attrs":
        file.attrs[edit["attr"]] = edit["value"] if edit["index"] % 2 else edit["float"]
        return
    if field not in file:
        return
    data = file[field][()]
    if edit["kind"] == "drop_dataset":
        del file[field]
        return
    if np.ndim(data) == 0:
        del file[field]
        file.create_dataset(field, data=np.array(edit["value"] % 2**62))
        return
    data = np.array(data)
    i = edit["index"] % max(len(data), 1)
    if edit["kind"] == "dtype":
        try:
            with np.errstate(invalid="ignore", over="ignore"):
                data = data.astype(edit["dtype"])
        except (ValueError, OverflowError):
            data = np.zeros(len(data), edit["dtype"])
        if data.dtype.kind == "f" and len(data):
            with np.errstate(over="ignore"):
                data[i] = edit["float"]
    elif edit["kind"] == "unsorted" and len(data) > 1:
        data[i], data[(i + 1) % len(data)] = data[(i + 1) % len(data)], data[i]
        data[i] = data[i] - abs(edit["value"]) % 10**6 if data.dtype.kind == "i" else data[i]
    elif edit["kind"] == "values" and len(data):
        info = np.iinfo(data.dtype) if data.dtype.kind in "iu" else None
        value = edit["value"]
        if info is not None:
            value = int(np.clip(value, info.min, info.max))
        data[i] = value
    elif edit["kind"] == "length":
        data = np.resize(data, edit["length"]) if len(data) else data
    del file[field]
    file.create_dataset(field, data=data)


def check_events_h5(edits: list[dict]) -> None:
    from sim.eventio import event_time_span, iter_event_chunks, read_events, read_window

    with scratch() as folder:
        path = folder / "events.h5"
        path.write_bytes(h5_base())
        for edit in edits:
            _apply_h5_edit(path, edit)
        names = (str(path),)
        events = refused_or_result(lambda: read_events(path, WIDTH, HEIGHT), (path,), names)
        if events is not None:
            check_event_array(events)
        chunks = refused_or_result(lambda: list(iter_event_chunks(path, 100)), (path,), names)
        if chunks:
            for chunk in chunks:
                assert chunk.dtype.names == ("t", "x", "y", "p")
        window = refused_or_result(lambda: read_window(path, 10**9 + 20 * 10**6,
                                                       10**9 + 60 * 10**6), (path,), names)
        if window is not None and len(window):
            assert (np.diff(window["t"]) >= 0).all()
        span = refused_or_result(lambda: event_time_span(path), (path,), names)
        if span is not None:
            assert math.isfinite(span[0]) and math.isfinite(span[1])


# --- scene TOML --------------------------------------------------------------------------------

BASE_SCENE = scene_text(WALL, extra="[frames]\nrate = 20.0\nexposure = 0.01\n")
SCENE_SOURCE = "fuzz_scene.toml"


def toml_value(value: Any) -> str:
    """``value`` as inline TOML (floats non-finite included, ints as they are)."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        if math.isnan(value):
            return "nan"
        if math.isinf(value):
            return "inf" if value > 0 else "-inf"
        return repr(value)
    if isinstance(value, str):
        return json.dumps(value, ensure_ascii=False)
    if isinstance(value, list):
        return "[" + ", ".join(toml_value(v) for v in value) + "]"
    if isinstance(value, dict):
        return "{" + ", ".join(f"{toml_key(k)} = {toml_value(v)}" for k, v in value.items()) + "}"
    raise TypeError(type(value))


def toml_key(key: str) -> str:
    return key if re.fullmatch(r"[A-Za-z0-9_-]+", key) else json.dumps(key)


def toml_document(table: dict) -> str:
    return "".join(f"{toml_key(k)} = {toml_value(v)}\n" for k, v in table.items())


def toml_values() -> st.SearchStrategy[Any]:
    scalars = st.one_of(
        st.floats(allow_nan=True, allow_infinity=True),
        st.sampled_from([0, -1, 1, 3, 10**18, -10**18, 2**63 - 1, 1e308, -1e308, 1e-320, 0.0,
                         float("nan"), float("inf"), float("-inf"), 500.0, 3000.0]),
        st.integers(-2**63, 2**63 - 1), st.booleans(),
        st.sampled_from(["", "linear", "rectangle", "directional", "shapes", "x", "nan"]),
        st.text(max_size=8),
    )
    return st.recursive(scalars, lambda inner: st.one_of(
        st.lists(inner, max_size=4), st.dictionaries(st.sampled_from(
            ["type", "x", "size", "center", "rate", "unknown_key"]), inner, max_size=3)),
        max_leaves=6)


def _paths(value: Any, prefix: tuple = ()) -> list[tuple]:
    """Every path to a value inside nested dicts and lists."""
    out = [prefix] if prefix else []
    if isinstance(value, dict):
        for key, item in value.items():
            out += _paths(item, (*prefix, key))
    elif isinstance(value, list):
        for i, item in enumerate(value):
            out += _paths(item, (*prefix, i))
    return out


@st.composite
def scene_tables(draw: Any) -> str:
    """A scene document: the valid base with one to three leaves replaced, removed or joined by
    an unknown key; or random TOML."""
    table = tomllib.loads(BASE_SCENE)
    if draw(st.integers(0, 9)) == 0:
        return draw(st.one_of(st.text(max_size=40), st.dictionaries(
            st.sampled_from(["duration", "trajectory", "objects", "lights", "camera", "zzz"]),
            toml_values(), max_size=5).map(toml_document)))
    for _ in range(draw(st.integers(0, 3))):
        paths = _paths(table)
        path = draw(st.sampled_from(paths))
        parent = table
        for step in path[:-1]:
            parent = parent[step]
        kind = draw(st.sampled_from(["replace", "replace", "replace", "delete", "unknown"]))
        if kind == "replace":
            parent[path[-1]] = draw(toml_values())
        elif kind == "delete":
            del parent[path[-1]]
        elif isinstance(parent, dict):
            parent[draw(st.sampled_from(["unknown", "Width", "colour", "fx "]))] = draw(
                toml_values())
    return toml_document(table)


SCENE_CASES = scene_tables()


def check_scene(text: str) -> None:
    from sim.scene import parse_scene

    scene = refused_or_result(lambda: parse_scene(text, SCENE_SOURCE), (), (SCENE_SOURCE,))
    if scene is not None:
        assert_finite(scene)
        poses = scene.trajectory.pose(np.linspace(0.0, scene.duration, 5))
        assert np.isfinite(poses).all(), "success with non-finite camera poses"
        for light in scene.lights:
            if light.direction is not None:
                assert abs(np.linalg.norm(light.direction) - 1) < 1e-9, \
                    f"success with a light direction {light.direction} that is not a unit vector"


# --- method parameters (--param, fusion.methods) ----------------------------------------------

def _method_names() -> list[str]:
    from fusion.methods import available_methods

    return sorted(available_methods())


def _method_keys() -> list[str]:
    from fusion.methods import available_methods, param_defaults

    keys = {"unknown", "sigma", "x"}
    for method in available_methods().values():
        keys.update(param_defaults(method) or {})
    return sorted(keys)


@st.composite
def _param_case(draw: Any) -> tuple[str, list[str]]:
    method = draw(st.sampled_from(_method_names()))
    params = []
    for _ in range(draw(st.integers(1, 3))):
        key = draw(st.sampled_from(_method_keys()))
        value = draw(st.one_of(number_text(), st.sampled_from(
            ["true", "false", "none", "'a'", "[1]", "1e999", "-1e999", "nan", "inf", "(1,)",
             "", "1j", "0.5", "3", "-3"])))
        scope = draw(st.sampled_from(["", f"{method}.", "nosuch.", "."]))
        params.append(f"{scope}{key}={value}")
    return method, params


PARAM_CASES = _param_case()


def check_params(case: tuple[str, list[str]]) -> None:
    """``--method NAME --param KEY=VALUE``: the command line's parsing and checking of the
    settings (fusion.methods.method_variants), without running anything."""
    from fusion.methods import method_variants

    method, params = case
    variants = refused_or_result(lambda: method_variants([method], params, single=True), (),
                                 ("param", "method"))
    if variants is not None:
        for variant in variants:
            assert_finite(variant.params)


# --- sweep parameters (evfuse bench --family and its knobs) ---------------------------------

@st.composite
def _sweep_case(draw: Any) -> tuple[str, dict[str, list[float]]]:
    from sim.scene.families import FAMILIES

    family = draw(st.sampled_from([*sorted(FAMILIES), "nosuch"]))
    names = sorted({*FAMILIES.get(family, {}), "texture", "steps", "radius"})
    knobs = draw(st.dictionaries(st.sampled_from(names), st.lists(st.one_of(
        st.floats(allow_nan=True, allow_infinity=True), st.integers(-5, 20).map(float),
        st.floats(0.0, 80.0)), min_size=1, max_size=2), max_size=2))
    return family, knobs


SWEEP_CASES = _sweep_case()


def check_sweep(case: tuple[str, dict[str, list[float]]]) -> None:
    """``evfuse bench --family F --KNOB V,...``: every member the knobs make is a scene that
    parses (with finite figures), or one line naming the family or the knob (as the library's
    parameters: the command line names them by its flags)."""
    from sim.scene import parse_scene
    from sim.scene.families import family_variants

    family, knobs = case
    names = ("family", *knobs)
    texts = refused_or_result(lambda: family_variants(family, knobs), (), names)
    for text in texts or []:
        assert_finite(parse_scene(text, f"{family}.toml"))


# --- numeric flags of the command line -----------------------------------------------------------

NUMERIC_FLAGS = {
    "map": ("--t0", "--t1", "--min-depth", "--max-depth", "--planes", "--kernel", "--c",
            "--median", "--ref-time"),
    "fill": ("--threshold", "--min-region", "--ring", "--min-ring-ratio", "--max-inside-ratio",
             "--sigma", "--scale"),
}
_NON_FINITE = re.compile(r"^[+-]?(nan|inf|infinity)$", re.IGNORECASE)


@st.composite
def _flag_case(draw: Any) -> tuple[str, str, str]:
    command = draw(st.sampled_from(sorted(NUMERIC_FLAGS)))
    flag = draw(st.sampled_from(NUMERIC_FLAGS[command]))
    return command, flag, draw(number_text())


FLAG_CASES = _flag_case()


def is_non_finite(text: str) -> bool:
    """Does a flag's value read as a NaN or an infinity (what argparse's float() makes of it)?"""
    try:
        return not math.isfinite(float(text))
    except ValueError:
        return False


_TINY: dict[str, Path] = {}


def tiny_inputs() -> dict[str, Path]:
    """A tiny real recording (64x48, 3,000 random events over 1 s, one frame, two poses) and
    the map ``evfuse map`` makes of it: inputs on which map and fill run to the end in a tenth
    of a second. Made once per process, in a temporary folder removed at exit."""
    if not _TINY:
        import atexit
        import shutil

        import cv2

        from sim.eventio import TextEventWriter, make_events

        root = Path(tempfile.mkdtemp(prefix="evfuse-fuzz-inputs-"))
        atexit.register(shutil.rmtree, root, ignore_errors=True)
        rng = np.random.default_rng(21)
        sequence = root / "tiny_sequence"
        (sequence / "images").mkdir(parents=True)
        (sequence / "calib.txt").write_text("60.0 45.0 31.5 23.5\n")
        (sequence / "groundtruth.txt").write_text("0.0 0 0 0 0 0 0 1\n1.0 0.3 0 0 0 0 0 1\n")
        frame = (rng.random((HEIGHT, WIDTH)) * 255).astype(np.uint8)
        cv2.imwrite(str(sequence / "images" / "frame_00000000.png"), frame)
        (sequence / "images.txt").write_text("0.500000000 images/frame_00000000.png\n")
        n = 3000
        events = make_events(np.sort(rng.integers(0, 10**9, n)), rng.integers(0, WIDTH, n),
                             rng.integers(0, HEIGHT, n), rng.choice([-1, 1], n))
        with TextEventWriter(sequence / "events.txt") as writer:
            writer.write(events)
        status, _, err = run_cli(["map", str(sequence), "--out", str(root / "tiny_map"),
                                  "--quiet"])
        assert status == 0, err
        _TINY.update(sequence=sequence, map=root / "tiny_map")
    return _TINY


def run_cli(argv: list[str]) -> tuple[Any, str, str]:
    """``evfuse ARGV`` in this process: exit status, standard output, standard error."""
    from fusion.cli import main

    stderr, stdout = io.StringIO(), io.StringIO()
    with contextlib.redirect_stderr(stderr), contextlib.redirect_stdout(stdout):
        try:
            status = main(argv)
        except SystemExit as exc:                # argparse: a value it cannot convert
            status = exc.code
    return status, stdout.getvalue(), stderr.getvalue()


def _strict_json(path: Path) -> Any:
    def refuse(token: str) -> None:
        raise AssertionError(f"exit 0 with {token} in {path.name}")

    return json.loads(path.read_text(), parse_constant=refuse)


# Values for which map runs long by design (a DSI of that many planes, an adaptive threshold
# over that large a block): the fuzz stops them at a missing input instead.
_EXPENSIVE = {"--planes": 1000, "--kernel": 1001}


def check_flag(case: tuple[str, str, str]) -> None:
    """``evfuse CMD INPUT --out OUT FLAG VALUE`` for map and fill, which run on a tiny real
    recording and its map (:func:`tiny_inputs`) to the end (simulate's flags:
    :func:`check_simulate_flags`). Exit 0 with finite figures (stdout and the JSON written), or
    exit 2 with one ``evfuse CMD: error:`` line (after argparse's usage lines, for a value it
    cannot convert) and nothing left behind; a non-finite value must be refused by its flag's
    name. The inputs never change."""
    command, flag, value = case
    tiny = tiny_inputs()
    with scratch() as folder:
        out = folder / "out"
        source = tiny["sequence"] if command == "map" else tiny["map"]
        try:
            if flag in _EXPENSIVE and abs(float(value)) > _EXPENSIVE[flag]:
                source = folder / "nosuch"
        except ValueError:
            pass
        argv = [command, str(source), "--out", str(out), flag, value]
        argv += ["--quiet"] if command == "map" else []
        check_cli(argv, folder, out, (tiny["sequence"], tiny["map"]), ((flag, value),),
                  complete=_json_finite)


# --- the command line's contract, for any command ----------------------------------------------

def _cli_error_lines(stderr: str) -> list[str]:
    """The lines of standard error that are not argparse's usage lines nor a progress bar."""
    lines = [line for line in stderr.splitlines() if line.strip()]
    return [line for line in lines if not line.startswith(("usage:", " "))
            and not line.startswith("evfuse: rendering with")]


def _partials(folder: Path) -> list[str]:
    return sorted(str(p.relative_to(folder)) for p in folder.rglob("*") if ".partial" in p.name)


def _json_finite(out: Path) -> None:
    for path in (out.glob("*.json") if out.is_dir() else ()):
        _strict_json(path)


def check_cli(argv: list[str], folder: Path, out: Path, inputs: tuple[Path, ...],
              flags: tuple[tuple[str, str], ...] = (),
              complete: Callable[[Path], None] | None = None,
              allowed: tuple[str, ...] = ()) -> tuple[Any, str, str]:
    """Run ``evfuse ARGV`` in this process and check the command line's contract.

    Exit 0 with a complete output (``complete(out)``, when given) and no non-finite figure on
    standard output; or exit 2 with exactly one ``evfuse CMD: error:`` line on standard error
    (after argparse's usage lines, for a value it cannot convert) that names the flag of a
    non-finite value (one of the case's flags, when it has several), and no ``out`` left
    behind. Never another status (a traceback, or
    ``unexpected error``); never a ``.partial`` left anywhere in ``folder``; never a new entry of
    ``folder`` other than ``out`` and ``allowed``; the files of ``inputs`` never change.

    Returns
    -------
    (status, stdout, stderr)
    """
    command = argv[0]
    before_entries = {p.name for p in folder.iterdir()}
    before = file_hashes(*[p for p in inputs if p.exists()])
    status, stdout, stderr = run_cli(argv)
    assert file_hashes(*[p for p in inputs if p.exists()]) == before, "the input was modified"
    errors = _cli_error_lines(stderr)
    assert status in (0, 2), f"exit {status}: {stderr.strip()[-600:]!r}"
    if status == 2:
        assert len(errors) == 1, f"not one error line: {errors!r}"
        assert errors[0].startswith(f"evfuse {command}: error:"), errors[0]
        non_finite_flags = [flag for flag, value in flags if is_non_finite(value)]
        if len(non_finite_flags) == len(flags) == 1:
            assert flags[0][0] in errors[0], \
                f"{flags[0][0]} {flags[0][1]} refused without naming it: {errors[0]}"
        elif non_finite_flags:                   # some flag of the case is to be named
            assert any(flag in errors[0] for flag, _ in flags), \
                f"{flags} refused without naming any: {errors[0]}"
        assert not out.exists(), f"a refused command left {out.name}"
    else:
        for flag, value in flags:
            assert not is_non_finite(value), f"exit 0 with {flag} {value}"
        assert not re.search(r"\b(nan|inf)\b", stdout, re.IGNORECASE), \
            f"exit 0 with a non-finite figure: {stdout!r}"
        if complete is not None:
            complete(out)
    partials = _partials(folder)
    assert not partials, f"exit {status} left {partials}"
    new = sorted({p.name for p in folder.iterdir()} - before_entries - {out.name, *allowed})
    assert not new, f"exit {status} left behind: {new}"
    return status, stdout, stderr


# --- evfuse simulate: values that reach the simulation ------------------------------------------

TINY_CAMERA = "[camera]\nwidth = 16\nheight = 12\nfx = 15.0\nfy = 11.0\ncx = 7.5\ncy = 5.5\n"
TINY_SCENE = scene_text(WALL, camera=TINY_CAMERA, duration=0.02,
                        extra="[frames]\nrate = 200.0\nexposure = 0.001\n")
"""A 16x12 sensor over 0.02 s with frames at 200 Hz: a simulation of a tenth of a second, so
that a flag's value that passes validation reaches the work (events, frames, depth)."""

SIMULATE_FLAGS = ("--duration", "--start", "--seed", "--spp", "--contrast", "--lambda",
                  "--min-rate", "--max-rate")
SIMULATE_WORDS = {"--sampler": ("pixel", "frame", "x", ""),
                  "--noise": ("ideal", "realistic", "x"),
                  "--frame-sensor": ("ideal", "davis240c_aps", "machine_vision", "nosuch"),
                  "--event-format": ("txt", "h5", "txt,h5", "x", ""),
                  "--rig": ("perfect", "mocap", "lab", "x")}
_SIMULATE_VALUES = ("4294967295", "4294967296", "18446744073709551616", "2147483648", "-1",
                    "100000000", "1000000", "65536", "1e-12", "0.001", "0.01", "0.015")


@st.composite
def _simulate_case(draw: Any) -> list[tuple[str, str]]:
    """One to three of simulate's flags, each with a value: numbers (ordinary, huge, tiny,
    non-finite, the seed's and spp's edges) or a choice's words."""
    pairs = []
    for _ in range(draw(st.integers(1, 3))):
        flag = draw(st.sampled_from([*SIMULATE_FLAGS, *SIMULATE_FLAGS, *SIMULATE_WORDS]))
        if flag in SIMULATE_WORDS:
            value = draw(st.sampled_from(SIMULATE_WORDS[flag]))
        else:
            value = draw(st.one_of(number_text(), st.sampled_from(_SIMULATE_VALUES)))
        pairs.append((flag, value))
    return pairs


SIMULATE_CASES = _simulate_case()


def _complete_sequence(out: Path) -> None:
    """A finished sequence folder: its marker, ``sequence.json`` (strict JSON, finite) and
    every file its indexes list."""
    from sim.output import MARKER
    from sim.sequence import load_sequence

    assert out.is_dir(), "exit 0 without the --out folder"
    assert (out / MARKER).is_file(), "exit 0 without the folder's marker"
    _strict_json(out / "sequence.json")
    load_sequence(out)


def _runs_long(flag: str, value: str) -> bool:
    """Values for which the tiny simulation runs long by design (render rates past 100 kHz, a
    few thousand renders of 65,536 samples per pixel): such a case stops at a missing scene
    instead. A value that cannot fit this machine's memory (spp 10^8 and more) still reaches
    the simulation: it must be refused before any work (issue 39, item 7)."""
    try:
        number = float(value)
    except ValueError:
        return False
    if flag in ("--min-rate", "--max-rate"):
        return number > 1e5
    return flag == "--spp" and 256 < number < 1e8


def check_simulate_flags(pairs: list[tuple[str, str]]) -> None:
    """``evfuse simulate TINY --out FRESH FLAG VALUE ...`` with a fresh ``--out`` for every case
    and a tiny scene (:data:`TINY_SCENE`, ``--spp 1`` unless the case sets it), so that values
    that pass validation reach the simulation: :func:`check_cli`'s contract, and a complete
    sequence folder on success."""
    with scratch() as folder:
        scene = folder / "tiny.toml"
        scene.write_text(TINY_SCENE)
        out = folder / "out"
        argv = ["simulate", str(scene), "--out", str(out), "--quiet"]
        if not any(flag == "--spp" for flag, _ in pairs):
            argv += ["--spp", "1"]
        for flag, value in pairs:
            argv += [flag, value]
        if any(_runs_long(flag, value) for flag, value in pairs):
            argv[1] = str(folder / "nosuch.toml")
        check_cli(argv, folder, out, (scene,), tuple(pairs), complete=_complete_sequence)


# --- sweep files (sim.dataset.parse_sweep) ------------------------------------------------------

BASE_SWEEP = """name = "fuzz"
description = "the fuzz's sweep"
seeds = [1, 2]

[[scenes]]
file = "tiny.toml"

[[scenes]]
family = "sphere"
radius = 0.3

[grid]
sensor = "16x12"
t0 = 0.0
t1 = 0.01
spp = 1

[draw]
contrast = { uniform = [0.15, 0.3] }
"""
"""A valid sweep of 4 jobs (a scene file beside it, and a bench family's member)."""

_SWEEP_VALUES = (4294967295, 4294967296, 2**63 - 1, -1, 0, "100000x100000", "16x12", "0x12",
                 "65536x65536", "1x1", "48x36 ", 100000000, 4, 9, 1e308, float("nan"),
                 {"first": 4294967295, "count": 2}, {"first": 0, "count": 10**9},
                 {"uniform": [0.1, 1e308]}, {"integer": [0, 2**63 - 1]}, {"choice": []},
                 "slider_close", "nosuch", "tabletop")


_GENERATE_EDGES = {"seeds": ([4294967296], [2**63 - 1], {"first": 4294967295, "count": 2}),
                   "sensor": ("100000x100000", "1000000x1000000", "1x1", "8x6"),
                   "spp": (100000000, 4, 2**62), "t1": (1e-9, 0.005, 1e308),
                   "contrast": (1e-300, 1e308, 0.3), "max_rate": (1e308, 1e-9),
                   "lam": (1e-300, 1e308, -1.0)}
"""Edge values of the keys that size a job (item 6: seeds past uint32; item 7: sizes)."""


def _set_edge(draw: Any, table: dict) -> None:
    """Set one key that sizes a sweep's jobs (seeds, or a [grid] value) to an edge value."""
    key = draw(st.sampled_from(sorted(_GENERATE_EDGES)))
    value = copy.deepcopy(draw(st.sampled_from(_GENERATE_EDGES[key])))   # later edits change it
    if key == "seeds":
        table["seeds"] = value
    else:
        table["grid"][key] = value


@st.composite
def sweep_tables(draw: Any) -> str:
    """A sweep document: the valid base with one to three leaves replaced (by TOML values or
    the sweep's edges: huge seeds, sensors, spp), removed or joined by an unknown key; or the
    base's text mutated (truncated, bytes overwritten, lines dropped, ...)."""
    if draw(st.integers(0, 3)) == 0:
        return draw(mutated(BASE_SWEEP.encode())).decode("utf-8", "replace")
    table = tomllib.loads(BASE_SWEEP)
    if draw(st.integers(0, 2)) == 0:                  # the keys that size a job, at their edges
        _set_edge(draw, table)
    for _ in range(draw(st.integers(0, 3))):
        path = draw(st.sampled_from(_paths(table)))
        parent = table
        for step in path[:-1]:
            parent = parent[step]
        kind = draw(st.sampled_from(["replace", "replace", "edge", "edge", "delete",
                                     "unknown"]))
        if kind == "replace":
            parent[path[-1]] = draw(toml_values())
        elif kind == "edge":
            parent[path[-1]] = copy.deepcopy(draw(st.sampled_from(_SWEEP_VALUES)))
        elif kind == "delete":
            del parent[path[-1]]
        elif isinstance(parent, dict):
            parent[draw(st.sampled_from(["unknown", "Seeds", "sensor", "noise", "spp"]))] = \
                copy.deepcopy(draw(st.one_of(toml_values(), st.sampled_from(_SWEEP_VALUES))))
    return toml_document_nested(table)


def toml_document_nested(table: dict) -> str:
    """``table`` as a TOML document: values and inline tables at the top, then its tables and
    arrays of tables (one level deep, as a sweep's)."""
    head = {k: v for k, v in table.items()
            if not isinstance(v, dict) and not (isinstance(v, list) and v
                                                and all(isinstance(i, dict) for i in v))}
    text = toml_document(head)
    for key, value in table.items():
        if key in head:
            continue
        if isinstance(value, dict):
            text += f"\n[{toml_key(key)}]\n" + toml_document(value)
        else:
            for item in value:
                text += f"\n[[{toml_key(key)}]]\n" + toml_document(item)
    return text


SWEEP_FILE_CASES = sweep_tables()

_PHYSICAL_MEMORY = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
_SEED_LIMIT = 2**32
"""Mitsuba's sampler seed is a uint32: a larger seed cannot reach the renders."""


def check_job_sizes(jobs: Any) -> None:
    """Every job of an accepted sweep can run: its seed fits the renders' uint32 seed, and one
    float32 value per pixel (per sample, with spp) fits this machine's memory (a lower bound on
    what a job needs: a refusal is due long before)."""
    for job in jobs:
        assert 0 <= job.seed < _SEED_LIMIT, f"a job with seed {job.seed} accepted"
        sensor = job.params.get("sensor")
        if sensor:
            width, height = (int(v) for v in sensor.split("x"))
            need = width * height * 4 * int(job.params.get("spp", 1))
            assert need <= _PHYSICAL_MEMORY, \
                f"a job of sensor {sensor} (spp {job.params.get('spp', 1)}) accepted: " \
                f"{need / 2**30:.1f} GiB for one value per sample"
        assert_finite(job.params)


def check_sweep_file(text: str) -> None:
    """A sweep file (beside a tiny scene file) through :func:`sim.dataset.load_sweep`: one line
    naming the file, or jobs that can run (:func:`check_job_sizes`)."""
    from sim.dataset import load_sweep

    with scratch() as folder:
        (folder / "tiny.toml").write_text(TINY_SCENE)
        path = folder / "sweep.toml"
        path.write_text(text, encoding="utf-8")
        sweep = refused_or_result(lambda: load_sweep(path), (folder,), (str(path),))
        if sweep is not None:
            assert sweep.jobs, "a sweep of no jobs accepted"
            check_job_sizes(sweep.jobs)


# --- evfuse generate: flags and sweeps that reach the jobs --------------------------------------

GENERATE_SWEEP = """seeds = [1]

[[scenes]]
file = "tiny.toml"

[grid]
sensor = "16x12"
t1 = 0.01
spp = 1
"""
"""One job of the tiny scene: a tenth of a second."""

GENERATE_FLAGS = ("--workers", "--threads", "--retries", "--gpu-per-job")
@st.composite
def _generate_case(draw: Any) -> tuple[str, list[tuple[str, str]]]:
    """A one-job sweep with at most one edge value (a seed, a sensor, spp, ...), and zero to
    two of generate's flags with values."""
    table = tomllib.loads(GENERATE_SWEEP)
    if draw(st.booleans()):
        _set_edge(draw, table)
    pairs = []
    for _ in range(draw(st.integers(0, 2))):
        flag = draw(st.sampled_from(GENERATE_FLAGS))
        pairs.append((flag, draw(st.one_of(number_text(), st.sampled_from(
            ["0", "1", "2", "-1", "0.5", "1e308"])))))
    return toml_document_nested(table), pairs


GENERATE_CASES = _generate_case()


def _complete_dataset(out: Path) -> None:
    from sim.dataset import open_dataset
    from sim.output import MARKER

    assert (out / MARKER).is_file(), "exit 0 without the dataset's marker"
    dataset = open_dataset(out)
    assert len(dataset) >= 1


def check_generate(case: tuple[str, list[tuple[str, str]]]) -> None:
    """``evfuse generate SWEEP --out FRESH --workers 0 FLAG VALUE ...``: the one job runs in this
    process (``--workers 0``, unless the case sets it: a positive number would start a Dask
    cluster, so such a case stops at a missing sweep instead). :func:`check_cli`'s contract,
    and a complete dataset on success."""
    text, pairs = case
    with scratch() as folder:
        (folder / "tiny.toml").write_text(TINY_SCENE)
        sweep = folder / "sweep.toml"
        sweep.write_text(text)
        out = folder / "out"
        workers = dict(pairs).get("--workers")
        try:
            if workers is not None and float(workers) > 0:
                sweep = folder / "nosuch.toml"
        except ValueError:
            pass
        argv = ["generate", str(sweep), "--out", str(out), "--quiet"]
        argv += [] if workers is not None else ["--workers", "0"]
        for flag, value in pairs:
            argv += [flag, value]
        check_cli(argv, folder, out, (folder / "tiny.toml", folder / "sweep.toml"),
                  tuple(pairs), complete=_complete_dataset)


# --- evfuse twin ------------------------------------------------------------------------------

@st.composite
def _twin_case(draw: Any) -> list[tuple[str, str]]:
    pairs = [("--depth", draw(st.one_of(number_text(), st.sampled_from(["2.0", "0.5"]))))]
    for _ in range(draw(st.integers(0, 3))):
        flag = draw(st.sampled_from(["--window", "--illuminance", "--frame-gamma",
                                     "--frame-sensor"]))
        if flag == "--window":
            value = draw(st.one_of(
                st.tuples(number_text(), number_text()).map(",".join),
                st.sampled_from(["0.1,0.9", "0,1", "0.5,0.5", "0.9,0.1", "0.1", "a,b",
                                 "0.1,0.9,1", "-1,2", "0,1e308"])))
        elif flag == "--frame-sensor":
            value = draw(st.sampled_from(["ideal", "davis240c_aps", "machine_vision", "x"]))
        else:
            value = draw(number_text())
        pairs.append((flag, value))
    return pairs


TWIN_CASES = _twin_case()


def _complete_twin(out: Path) -> None:
    """A twin's folder: a scene that ``evfuse simulate`` accepts (it parses, and every figure
    is finite)."""
    from sim.scene import load_scene

    scenes = sorted(out.glob("*.toml"))
    assert scenes, "exit 0 without a scene"
    for scene in scenes:
        try:
            parsed = load_scene(scene)
        except ValueError as exc:
            raise AssertionError(f"exit 0 with a scene that simulate refuses: {exc}") from None
        assert_finite(parsed)


def check_twin(pairs: list[tuple[str, str]]) -> None:
    """``evfuse twin TINY_RECORDING --depth D --out FRESH FLAG VALUE ...``."""
    tiny = tiny_inputs()
    with scratch() as folder:
        out = folder / "out"
        argv = ["twin", str(tiny["sequence"]), "--out", str(out)]
        for flag, value in pairs:
            argv += [flag, value]
        check_cli(argv, folder, out, (tiny["sequence"],), tuple(pairs), complete=_complete_twin)


# --- evfuse convert ----------------------------------------------------------------------------

@st.composite
def _convert_case(draw: Any) -> tuple[str, str, str | None]:
    source = draw(st.sampled_from(["events.txt", "events.h5"]))
    destination = draw(st.sampled_from(["out.h5", "out.txt", "out.png", "out", "out.H5",
                                        "out.txt.h5"]))
    sensor = draw(st.one_of(st.none(), st.sampled_from(
        ["64x48", "16x12", "0x0", "100000x100000", "65535x65535", "65536x1", "-1x5", "x",
         "64X48", " 64x48", "1e3x2", "nan x nan", "4294967296x1"]),
        st.tuples(number_text(), number_text()).map("x".join)))
    return source, destination, sensor


CONVERT_CASES = _convert_case()


def _complete_events(out: Path) -> None:
    from sim.eventio import read_events

    assert out.is_file(), "exit 0 without DST"
    check_event_array(read_events(out, WIDTH, HEIGHT) if out.suffix == ".txt"
                      else read_events(out))


def check_convert(case: tuple[str, str, str | None]) -> None:
    """``evfuse convert SRC DST [--sensor WxH]`` from the tiny recording's events (text, or
    HDF5 made once from them) to a fresh DST."""
    source_name, destination, sensor = case
    tiny = tiny_inputs()
    if "h5" not in tiny:
        status, _, err = run_cli(["convert", str(tiny["sequence"] / "events.txt"),
                                  str(tiny["sequence"].parent / "events.h5"),
                                  "--sensor", f"{WIDTH}x{HEIGHT}"])
        assert status == 0, err
        tiny["h5"] = tiny["sequence"].parent / "events.h5"
    source = tiny["sequence"] / "events.txt" if source_name == "events.txt" else tiny["h5"]
    with scratch() as folder:
        out = folder / destination
        argv = ["convert", str(source), str(out)]
        argv += [] if sensor is None else ["--sensor", sensor]
        check_cli(argv, folder, out, (source,), complete=_complete_events)


# --- evfuse bench: flags up to the run -----------------------------------------------------------

_BENCH_RUNS: list[dict] = []


def _stub_run_bench(methods: Any, scenes: Any, inputs: Any, out: Any, **kwargs: Any) -> list:
    """Stands for ``run_bench`` (a real run of one family member takes 30-60 s here): records
    what reached it, and writes nothing."""
    _BENCH_RUNS.append({"methods": methods, "scenes": scenes, "inputs": inputs, **kwargs})
    return []


@st.composite
def _bench_case(draw: Any) -> list[tuple[str, str]]:
    from sim.scene.families import FAMILIES, KNOBS

    family = draw(st.sampled_from([*sorted(FAMILIES), "nosuch", ""]))
    pairs = [("--family", family)]
    for _ in range(draw(st.integers(0, 3))):
        flag = draw(st.sampled_from([*(f"--{k.replace('_', '-')}" for k in KNOBS), "--noise",
                                     "--outliers", "--input"]))
        if flag == "--input":
            value = draw(st.sampled_from(["oracle", "emvs", "oracle,emvs", "x", "", ","]))
        elif flag in ("--noise", "--outliers"):
            value = draw(number_text())
        else:
            value = draw(st.one_of(number_text(), st.lists(number_text(), min_size=1,
                                                           max_size=3).map(",".join)))
        pairs.append((flag, value))
    return pairs


BENCH_CASES = _bench_case()


def check_bench(pairs: list[tuple[str, str]]) -> None:
    """``evfuse bench --family F --KNOB V,... --out FRESH`` with ``run_bench`` replaced by a
    stub (:func:`_stub_run_bench`): the flags' parsing and checking, the family's scenes
    written into the cache, and the contract up to the run. A case that reaches the run must
    have made scenes that parse with finite figures."""
    from unittest import mock

    from sim.scene import load_scene

    with scratch() as folder:
        out = folder / "out"
        argv = ["bench", "--out", str(out), "--quiet"]
        for flag, value in pairs:
            argv += [flag, value]
        _BENCH_RUNS.clear()
        with mock.patch("fusion.experiments.bench.run_bench", _stub_run_bench):
            status, _, _ = check_cli(argv, folder, out, (), tuple(pairs),
                                     allowed=("out-cache",))
        if status == 2:
            cache = folder / "out-cache"
            assert not cache.exists() or any(cache.rglob("*")), \
                "a refused bench left an empty cache folder"
        for run in _BENCH_RUNS:
            for scene in run["scenes"]:
                if Path(scene).suffix == ".toml":           # a family's member, not a name
                    assert_finite(load_scene(scene))


# --- sequence.json ------------------------------------------------------------------------------

_SIMULATED: dict[str, Path] = {}


def tiny_simulated() -> Path:
    """A sequence folder simulated from :data:`TINY_SCENE` (made once per process)."""
    if "out" not in _SIMULATED:
        import atexit
        import shutil

        root = Path(tempfile.mkdtemp(prefix="evfuse-fuzz-simulated-"))
        atexit.register(shutil.rmtree, root, ignore_errors=True)
        (root / "tiny.toml").write_text(TINY_SCENE)
        status, _, err = run_cli(["simulate", str(root / "tiny.toml"), "--out",
                                  str(root / "seq"), "--quiet", "--spp", "1"])
        assert status == 0, err
        _SIMULATED["out"] = root / "seq"
    return _SIMULATED["out"]


@st.composite
def _sequence_json_case(draw: Any) -> bytes:
    base = (tiny_simulated() / "sequence.json").read_bytes()
    kind = draw(st.integers(0, 3))
    if kind == 0:
        return draw(mutated(base))
    table = json.loads(base)
    for _ in range(draw(st.integers(1, 3))):
        paths = _paths(table)
        if not paths:
            break
        path = draw(st.sampled_from(paths))
        parent = table
        for step in path[:-1]:
            parent = parent[step]
        if draw(st.integers(0, 4)) == 0 and isinstance(parent, dict):
            del parent[path[-1]]
        else:
            parent[path[-1]] = draw(st.one_of(toml_values(), st.sampled_from(
                [None, [], {}, "", 0, -1, 10**30, 1e308, 4294967296, "16x12"])))
    return json.dumps(table, allow_nan=True).encode()


SEQUENCE_JSON_CASES = _sequence_json_case()


def check_sequence_json(data: bytes) -> None:
    """A mutated ``sequence.json`` of a simulated sequence, through
    :func:`sim.sequence.read_sequence_json` and :func:`sim.sequence.load_sequence` (the folder's
    other files intact): one line naming the file or folder, or finite figures."""
    import shutil

    from sim.sequence import load_sequence, read_sequence_json

    with scratch() as folder:
        sequence = folder / "seq"
        shutil.copytree(tiny_simulated(), sequence)
        path = write_case(sequence, "sequence.json", data)
        names = (str(path), str(sequence))
        metadata = refused_or_result(lambda: read_sequence_json(path), (path,), names)
        if metadata is not None:
            assert non_finite(metadata) is None
        loaded = refused_or_result(lambda: load_sequence(sequence), (sequence,), names)
        if loaded is not None:
            assert_finite(loaded)


# --- depth EXR (sim.exr.read_depth) -------------------------------------------------------------

@st.composite
def _exr_case(draw: Any) -> dict:
    """An EXR written with odd channels (names, dtypes, shapes, values), or a valid depth map's
    bytes truncated or overwritten."""
    if draw(st.booleans()):
        return {"bytes": True, "truncate": draw(st.booleans()), "at": draw(st.integers(0, 10**6)),
                "junk": draw(st.binary(min_size=1, max_size=64))}
    names = draw(st.lists(st.sampled_from(["Z", "Z", "R", "G", "depth", "z", "Z.Z"]),
                          min_size=0, max_size=3, unique=True))
    return {"bytes": False, "names": names,
            "dtype": draw(st.sampled_from(["f4", "f4", "f2", "u4"])),
            "shape": draw(st.sampled_from([(12, 16), (1, 1), (1, 300), (300, 1), (12, 16)])),
            "values": draw(st.lists(st.floats(allow_nan=True, allow_infinity=True,
                                              width=32), min_size=1, max_size=4)),
            "uniform": draw(st.sampled_from([0.0, 1.0, 2.5, 65504.0, 1e38]))}


EXR_CASES = _exr_case()


def _write_exr_case(path: Path, case: dict) -> None:
    import OpenEXR

    if case["bytes"]:
        depth = sorted((tiny_simulated() / "depth").glob("*.exr"))[0]
        data = bytearray(depth.read_bytes())
        at = case["at"] % max(len(data), 1)
        if case["truncate"]:
            data = data[:at]
        else:
            data[at:at + len(case["junk"])] = case["junk"]
        path.write_bytes(bytes(data))
        return
    height, width = case["shape"]
    channels = {}
    for name in case["names"]:
        values = np.full((height, width), case["uniform"], np.float64)
        flat = values.reshape(-1)
        count = min(len(case["values"]), flat.size)
        flat[:count] = case["values"][:count]
        with np.errstate(invalid="ignore", over="ignore"):
            if case["dtype"] == "u4":
                array = np.nan_to_num(np.abs(values), posinf=0.0).clip(0, 2**32 - 1)
                array = array.astype(np.uint32)
            else:
                array = values.astype(case["dtype"])
        channels[name] = np.ascontiguousarray(array)
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    if not channels:
        channels = {"R": np.zeros((height, width), np.float32)}
    with OpenEXR.File(header, channels) as exr:
        exr.write(str(path))


def check_depth_exr(case: dict) -> None:
    """A depth EXR with odd channels or damaged bytes through :func:`sim.exr.read_depth`: one
    line naming the file, or an (H, W) float32 map of finite depths >= 0."""
    from sim.exr import read_depth

    with scratch() as folder:
        path = folder / "depth.exr"
        _write_exr_case(path, case)
        depth = refused_or_result(lambda: read_depth(path), (path,), (str(path),))
        if depth is not None:
            assert depth.ndim == 2 and depth.dtype == np.float32
            assert np.isfinite(depth).all() and (depth >= 0).all()


# --- the table of targets ------------------------------------------------------------------------

TARGETS: dict[str, tuple[st.SearchStrategy, Callable[[Any], None]]] = {
    "scene TOML (sim.scene.parse_scene)": (SCENE_CASES, check_scene),
    "calib.txt (sim.camera.read_calib)": (CALIB_CASES, check_calib),
    "groundtruth.txt (sim.trajectory.read_trajectory)": (GROUNDTRUTH_CASES, check_groundtruth),
    "images.txt (sim.sequence.read_index)": (IMAGES_CASES, check_images),
    "events.txt (sim.eventio readers)": (EVENTS_TXT_CASES, check_events_txt),
    "events.h5 (sim.eventio readers)": (H5_CASES, check_events_h5),
    "method parameters (--method/--param)": (PARAM_CASES, check_params),
    "sweep parameters (bench --family knobs)": (SWEEP_CASES, check_sweep),
    "numeric flags (evfuse map/fill)": (FLAG_CASES, check_flag),
    "numeric flags, finite values only": (
        FLAG_CASES.filter(lambda case: not is_non_finite(case[2])), check_flag),
    "sweep files (sim.dataset.load_sweep)": (SWEEP_FILE_CASES, check_sweep_file),
    "sequence.json (read_sequence_json, load_sequence)": (SEQUENCE_JSON_CASES,
                                                          check_sequence_json),
    "depth EXR (sim.exr.read_depth)": (EXR_CASES, check_depth_exr),
    "evfuse convert (SRC DST --sensor)": (CONVERT_CASES, check_convert),
    "evfuse twin flags": (TWIN_CASES, check_twin),
    "evfuse bench flags (up to the run)": (BENCH_CASES, check_bench),
    "evfuse simulate flags (fresh --out, runs)": (SIMULATE_CASES, check_simulate_flags),
    "evfuse generate flags and sweeps (runs)": (GENERATE_CASES, check_generate),
}

REACHING = ("evfuse simulate flags (fresh --out, runs)", "evfuse generate flags and sweeps (runs)")
"""The targets whose accepted cases run a simulation (a tenth of a second to a few seconds
each): the suite runs them for fewer cases, and benchmarks/fuzz.py for ``--reaching-examples``."""
"""Every fuzz target: its name, the strategy of its cases and the property a case must keep. The
last one is for the long run (benchmarks/fuzz.py): Hypothesis stops a target at its first
failure, and this one goes on past the non-finite values to the finite ones."""
