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
import dataclasses
import hashlib
import io
import json
import math
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
    "simulate": ("--duration", "--start", "--seed", "--spp", "--contrast", "--lambda",
                 "--min-rate", "--max-rate"),
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
    """``evfuse CMD INPUT --out OUT FLAG VALUE``. map and fill run on a tiny real recording and
    its map (:func:`tiny_inputs`) to the end; simulate parses its scene and stops at an existing
    non-empty ``--out``. Exit 0 with finite figures (stdout and the JSON written), or exit 2
    with one ``evfuse CMD: error:`` line (after argparse's usage lines, for a value it cannot
    convert) and nothing left behind; a non-finite value must be refused by its flag's name.
    The inputs never change."""
    command, flag, value = case
    tiny = tiny_inputs()
    with scratch() as folder:
        out = folder / "out"
        if command == "simulate":
            scene = folder / "tiny.toml"
            scene.write_text(scene_text(WALL, duration=0.1))
            out.mkdir()
            (out / "keep.txt").write_text("mine")
            argv = ["simulate", str(scene), "--out", str(out), flag, value, "--quiet"]
            inputs: tuple[Path, ...] = (scene, out)
        else:
            source = tiny["sequence"] if command == "map" else tiny["map"]
            try:
                if flag in _EXPENSIVE and abs(float(value)) > _EXPENSIVE[flag]:
                    source = folder / "nosuch"
            except ValueError:
                pass
            argv = [command, str(source), "--out", str(out), flag, value]
            argv += ["--quiet"] if command == "map" else []
            inputs = (tiny["sequence"], tiny["map"])
        before = file_hashes(*inputs)
        status, stdout, stderr = run_cli(argv)
        assert file_hashes(*inputs) == before, "the input was modified"
        lines = [line for line in stderr.splitlines() if line.strip()]
        errors = [line for line in lines if not line.startswith(("usage:", " "))]
        assert status in (0, 2), f"exit {status}: {stderr!r}"
        if status == 2:
            assert len(errors) == 1, f"not one error line: {lines!r}"
            assert errors[0].startswith(f"evfuse {command}: error:"), errors[0]
            if is_non_finite(value):
                assert flag in errors[0], f"{flag} {value} refused without naming it: {errors[0]}"
            if command != "simulate":
                assert not out.exists(), "a refused command left its --out folder"
        else:
            assert not is_non_finite(value), f"exit 0 with {flag} {value}"
            assert not re.search(r"\b(nan|inf)\b", stdout, re.IGNORECASE), \
                f"exit 0 with a non-finite figure: {stdout!r}"
            for path in out.glob("*.json"):
                _strict_json(path)
        leftovers = sorted(p.name for p in folder.iterdir() if p.name not in ("tiny.toml", "out"))
        assert not leftovers, f"left behind: {leftovers}"


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
    "numeric flags (evfuse map/fill/simulate)": (FLAG_CASES, check_flag),
    "numeric flags, finite values only": (
        FLAG_CASES.filter(lambda case: not is_non_finite(case[2])), check_flag),
}
"""Every fuzz target: its name, the strategy of its cases and the property a case must keep. The
last one is for the long run (benchmarks/fuzz.py): Hypothesis stops a target at its first
failure, and this one goes on past the non-finite values to the finite ones."""
