"""Sweep files: a TOML description of a dataset's jobs (:func:`load_sweep` -> :class:`Sweep`).

A sweep names scenes, seeds, a grid of simulate's parameters (their Cartesian product) and
parameters drawn per job from its seed; every job is one :class:`~sim.dataset.Job`. It is
validated completely before any job runs: an unknown key, a wrong type or a bad value raises
:class:`SweepError` naming the file and the key. ``sweeps/README.md`` documents the format;
``sweeps/*.toml`` are examples.

::

    name = "tiny"                      # optional, with description
    seeds = [1, 2]                     # or { first = 0, count = 100 }

    [[scenes]]                         # one of:
    name = "slider_close"              #   a built-in scene (evfuse scenes)
    # file = "my_scene.toml"           #   a scene file, relative to the sweep file
    # family = "sphere"                #   a bench family; its knobs as numbers or lists
    # radius = [0.2, 0.3]              #   (each list: one scene per value, a product)
    # procedural = "tabletop"          #   a procedural family, drawn from each job's seed;
    #                                  #   its other keys go to tabletop_scene(seed, **keys)

    [grid]                             # a value or a list of values per parameter
    sensor = "48x36"
    contrast = [0.2, 0.3]

    [draw]                             # per job, from its seed
    lam = { uniform = [0.3, 0.6] }     # uniform, log_uniform, integer (inclusive), choice
"""

from __future__ import annotations

import itertools
import math
import tomllib
import zlib
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from sim._summary import summary_repr
from sim.dataset._jobs import PARAMETERS, Job, check_parameter
from sim.textfile import bom_hint
from sim.validation import MAX_SEED

__all__ = ["DRAWS", "Sweep", "SweepError", "draw_parameters",
           "load_sweep", "parse_sweep"]

DRAWS = ("uniform", "log_uniform", "integer", "choice")
"""How a ``[draw]`` parameter is drawn from the job's seed."""
_TOP = ("name", "description", "seeds", "scenes", "grid", "draw")
_MAX_JOBS = 1_000_000
_SCENE_KINDS = ("name", "file", "family", "procedural")


class SweepError(ValueError):
    """A sweep file that cannot be used: the message names the file and the key."""


@dataclass(frozen=True)
class Sweep:
    """A validated sweep file.

    Attributes
    ----------
    source : str
        Where it came from (a path, or ``<sweep>``).
    text : str
        The file's text as read (``DIR/sweep.toml`` is a byte copy of it).
    name, description : str
    jobs : tuple of Job
        Every job, in the order scenes x grid x seeds; job ids are unique.
    parameters : tuple of str
        The grid's and draw's parameter names (the manifest's parameter columns).
    """

    source: str
    text: str
    name: str
    description: str
    jobs: tuple[Job, ...]
    parameters: tuple[str, ...]

    __repr__ = summary_repr


def load_sweep(path: str | Path) -> Sweep:
    """Read and validate a sweep file (:func:`parse_sweep`).

    Raises
    ------
    SweepError
        A missing or unreadable file, or anything :func:`parse_sweep` refuses.
    """
    path = Path(path)
    try:
        text = path.read_bytes().decode("utf-8")
    except (OSError, UnicodeDecodeError) as error:
        raise SweepError(f"{path}: cannot read the sweep file ({error})") from None
    return parse_sweep(text, path)


def parse_sweep(text: str, source: str | Path = "<sweep>") -> Sweep:
    """Parse and validate the TOML text of a sweep.

    Parameters
    ----------
    text : str
    source : str or Path
        Where it came from: messages name it, and scene files are relative to its folder.

    Returns
    -------
    Sweep

    Raises
    ------
    SweepError
        Not TOML, an unknown key, a missing or wrong value (the message names the file and the
        key, e.g. ``sweeps/x.toml: grid.contrast[1]: contrast must be ...``), two jobs alike.
    """
    source = str(source)
    base = Path(source).parent if not source.startswith("<") else Path.cwd()

    def fail(key: str, message: str) -> SweepError:
        return SweepError(f"{source}: {key}: {message}")

    try:
        raw = tomllib.loads(text)
    except tomllib.TOMLDecodeError as error:
        raise SweepError(f"{source}: not valid TOML: {error}{bom_hint(text)}") from None
    for key in raw:
        if key not in _TOP:
            raise fail(key, f"unknown key; expected {', '.join(_TOP)}")
    name = raw.get("name", Path(source).stem if not source.startswith("<") else "sweep")
    description = raw.get("description", "")
    for key, value in (("name", name), ("description", description)):
        if not isinstance(value, str):
            raise fail(key, f"expected a string, got {value!r}")
    seeds = _seeds(raw.get("seeds"), fail)
    scenes = _scenes(raw.get("scenes"), base, fail)
    grid = _grid(raw.get("grid", {}), fail)
    draws = _draws(raw.get("draw", {}), fail)
    for key in sorted(set(grid) & set(draws)):
        raise fail(f"draw.{key}", "also in [grid]: a parameter is either a grid's or drawn")
    size = len(scenes) * math.prod(len(v) for v in grid.values()) * len(seeds)
    if size > _MAX_JOBS:
        raise fail("grid", f"{size} jobs; expected at most {_MAX_JOBS}")
    jobs = []
    for scene in scenes:
        for combo in itertools.product(*grid.values()):
            for seed in seeds:
                params = {**dict(zip(grid, combo, strict=True)),
                          **draw_parameters(draws, seed)}
                jobs.append(Job(scene, seed, dict(sorted(params.items()))))
    _check_sampling(jobs, fail)
    _check_jobs(jobs, fail)
    seen: dict[str, Job] = {}
    for job in jobs:
        if job.job_id in seen:
            raise fail("scenes", f"two jobs alike ({job.job_id}): a scene, seed or grid value "
                                 "is listed twice")
        seen[job.job_id] = job
    return Sweep(source, text, name, description, tuple(jobs),
                 tuple(sorted({*grid, *draws})))


def _check_sampling(jobs: list[Job], fail) -> None:
    """Every job's lam, min_rate and max_rate together, as simulate takes them
    (:class:`~sim.sampling.SamplingParams`: min_rate <= max_rate), and no wavefront with the
    frame sampler, before any job runs."""
    from sim.sampling import SamplingParams, check_sampler

    for job in jobs:
        try:
            check_sampler(job.params.get("wavefront"), job.params.get("sampler"))
        except ValueError as error:
            raise fail("grid", f"a job with {error}") from None
    keys = ("lam", "min_rate", "max_rate")
    for combo in {tuple(job.params.get(k) for k in keys) for job in jobs}:
        given = {k: v for k, v in zip(keys, combo, strict=True) if v is not None}
        if not given:
            continue
        try:
            SamplingParams(**given)
        except ValueError as error:
            where = ", ".join(f"{k} = {v!r}" for k, v in given.items())
            raise fail("grid", f"a job with {where}: {error}") from None


GENERATED_SENSOR = (240, 180)
"""Sensor of a family or procedural scene (their camera is the DAVIS240C preset), px."""

_WINDOW_KEYS = ("t0", "t1", "frame_rate", "speed", "sensor", "spp")
"""The parameters that decide a job's window, frames, sensor and samples per pixel."""


def _check_jobs(jobs: list[Job], fail) -> None:
    """What every job of a kind would fail on, before any job runs, each distinct scene and
    window loaded once (:func:`~sim.dataset._jobs.job_inputs`; a procedural scene is drawn,
    with renders, only when its job runs, so it is not loaded here):

    - its ``spp`` against this machine's memory
      (:func:`sim.simulate.memory.check_simulation_memory`) with its sensor: its scene's camera
      at the job's ``sensor``, else the ``sensor`` value or a generated scene's DAVIS240C
      (jobs without an ``spp`` value are checked by their ``sensor`` alone, when the sweep
      file is read);
    - its window holds at least one frame, and no more than can be counted.
    """
    from sim.dataset._jobs import job_inputs
    from sim.frames import frame_times
    from sim.simulate.memory import check_simulation_memory

    seen = set()
    for job in jobs:
        key = (repr(job.identity["scene"]), tuple(job.params.get(k) for k in _WINDOW_KEYS))
        if key in seen:
            continue
        seen.add(key)
        scene = kwargs = None
        if "procedural" not in job.scene:
            try:
                scene, kwargs = job_inputs(job)
            except (ValueError, OSError):
                pass                              # refused by the job's own check, named there
        if "spp" in job.params:
            if scene is not None:
                width, height = scene.camera.width, scene.camera.height
            elif "sensor" in job.params:
                width, height = (int(v) for v in str(job.params["sensor"]).split("x"))
            elif job.generated:
                width, height = GENERATED_SENSOR
            else:
                width = height = None             # a scene that cannot load: its job says why
            if width is not None:
                try:
                    check_simulation_memory(width, height, int(job.params["spp"]),
                                            at_least=True)
                except ValueError as error:
                    raise fail("grid", f"a job of {job.label} at {width}x{height} with spp = "
                                       f"{job.params['spp']}: {error}") from None
        if scene is None:
            continue
        try:
            frames = len(frame_times(kwargs["duration"], scene.frames))
        except (OverflowError, ValueError, MemoryError):
            raise fail("grid", f"a job of {job.label} simulates {kwargs['duration']:g} s: "
                               "more frames than this machine can hold") from None
        if frames == 0:
            raise fail("grid", f"a job of {job.label} simulates {kwargs['duration']:g} s, too "
                               f"short for one frame at {scene.frames.rate:g} Hz with a "
                               f"{scene.frames.longest_exposure:g} s exposure")


def _seeds(value: object, fail) -> list[int]:
    if isinstance(value, dict):
        unknown = set(value) - {"first", "count"}
        if unknown or "count" not in value:
            raise fail("seeds", f"expected {{ first = N, count = M }}, got {value!r}")
        first, count = value.get("first", 0), value["count"]
        if not all(isinstance(v, int) and not isinstance(v, bool) and v >= 0
                   for v in (first, count)) or count < 1:
            raise fail("seeds", f"expected integers first >= 0 and count >= 1, got {value!r}")
        if first + count - 1 > MAX_SEED:
            raise fail("seeds", f"expected seeds in 0..{MAX_SEED} (2**32 - 1), got first = "
                                f"{first}, count = {count} (last seed {first + count - 1})")
        return list(range(first, first + count))
    if not isinstance(value, list) or not value:
        raise fail("seeds", f"expected a list of seeds or {{ first = N, count = M }}, got "
                            f"{value!r}")
    for i, seed in enumerate(value):
        if not isinstance(seed, int) or isinstance(seed, bool) or not 0 <= seed <= MAX_SEED:
            raise fail(f"seeds[{i}]", f"expected an integer in 0..{MAX_SEED} (2**32 - 1), got "
                                      f"{seed!r}")
    if len(set(value)) != len(value):
        raise fail("seeds", "a seed is listed twice")
    return list(value)


def _scenes(value: object, base: Path, fail) -> list[dict]:
    from scenes import builtin_scenes
    from sim.scene.families import FAMILIES, family_scene

    if not isinstance(value, list) or not value:
        raise fail("scenes", "expected one or more [[scenes]] tables")
    out = []
    for i, entry in enumerate(value):
        key = f"scenes[{i}]"
        if not isinstance(entry, dict):
            raise fail(key, f"expected a table, got {entry!r}")
        kinds = [k for k in _SCENE_KINDS if k in entry]
        if len(kinds) != 1:
            raise fail(key, f"expected exactly one of {', '.join(_SCENE_KINDS)}, got "
                            f"{', '.join(kinds) or 'none'}")
        kind = kinds[0]
        name = entry[kind]
        if not isinstance(name, str):
            raise fail(f"{key}.{kind}", f"expected a string, got {name!r}")
        rest = {k: v for k, v in entry.items() if k != kind}
        if kind in ("name", "file") and rest:
            raise fail(f"{key}.{next(iter(rest))}", f"unknown key for a {kind} scene")
        if kind == "name":
            if name not in builtin_scenes():
                raise fail(f"{key}.name", f"{name!r} is not a built-in scene; expected one of "
                                          f"{', '.join(builtin_scenes())}")
            out.append({"name": name})
        elif kind == "file":
            path = (base / name).resolve()
            if not path.is_file():
                raise fail(f"{key}.file", f"no scene file {path}")
            out.append({"file": name, "path": str(path)})
        elif kind == "family":
            if name not in FAMILIES:
                raise fail(f"{key}.family", f"{name!r}: expected one of {', '.join(FAMILIES)}")
            lists = {k: v if isinstance(v, list) else [v] for k, v in rest.items()}
            for k, values in lists.items():
                if not values:
                    raise fail(f"{key}.{k}", "an empty list (no scene); expected a number or a "
                                             "list of one or more")
            for combo in itertools.product(*lists.values()):
                knobs = dict(zip(lists, combo, strict=True))
                for k, v in knobs.items():
                    if isinstance(v, bool) or not isinstance(v, int | float):
                        raise fail(f"{key}.{k}", f"expected a number, got {v!r}")
                try:
                    family_scene(name, **knobs)
                except ValueError as error:
                    raise fail(key, str(error)) from None
                out.append({"family": name, **knobs})
        else:
            out.append({"procedural": name, **_procedural_ranges(name, rest, key, fail)})
    return out


def _procedural_ranges(name: str, ranges: dict, key: str, fail) -> dict:
    """A procedural scene's ranges, checked by its family's ranges class
    (:mod:`sim.scene.procedural`: ``TabletopRanges``, ``RoomRanges``)."""
    from dataclasses import fields

    from sim.scene.procedural import PROCEDURAL_FAMILIES, RoomRanges, TabletopRanges

    classes = {"tabletop": TabletopRanges, "room": RoomRanges}
    if name not in PROCEDURAL_FAMILIES or name not in classes:
        raise fail(f"{key}.procedural", f"{name!r}: expected one of "
                                        f"{', '.join(PROCEDURAL_FAMILIES)}")
    known = {item.name for item in fields(classes[name])}
    for range_name in ranges:
        if range_name not in known:
            raise fail(f"{key}.{range_name}", f"not a range of the {name} family; expected "
                                              f"one of {', '.join(sorted(known))}")
    try:
        classes[name](**ranges)
    except (ValueError, TypeError) as error:
        raise fail(key, str(error)) from None
    return ranges


def _grid(value: object, fail) -> dict[str, list]:
    if not isinstance(value, dict):
        raise fail("grid", f"expected a table, got {value!r}")
    grid = {}
    for name, values in value.items():
        values = values if isinstance(values, list) else [values]
        if not values:
            raise fail(f"grid.{name}", "expected one or more values")
        checked = []
        for i, item in enumerate(values):
            try:
                checked.append(check_parameter(name, item))
            except ValueError as error:
                where = f"grid.{name}" + (f"[{i}]" if len(values) > 1 else "")
                raise fail(where, str(error)) from None
        if len(set(map(repr, checked))) != len(checked):
            raise fail(f"grid.{name}", "a value is listed twice")
        grid[name] = checked
    return grid


def _draws(value: object, fail) -> dict[str, tuple[str, list]]:
    if not isinstance(value, dict):
        raise fail("draw", f"expected a table, got {value!r}")
    draws = {}
    for name, spec in value.items():
        key = f"draw.{name}"
        if name not in PARAMETERS:
            raise fail(key, f"unknown parameter; expected one of {', '.join(PARAMETERS)}")
        if not isinstance(spec, dict) or len(spec) != 1 or next(iter(spec)) not in DRAWS:
            raise fail(key, f"expected {{ KIND = [...] }} with KIND one of {', '.join(DRAWS)}, "
                            f"got {spec!r}")
        kind, args = next(iter(spec.items()))
        if not isinstance(args, list) or not args:
            raise fail(f"{key}.{kind}", f"expected a list, got {args!r}")
        try:
            args = [check_parameter(name, a) for a in args]
        except ValueError as error:
            raise fail(f"{key}.{kind}", str(error)) from None
        if kind != "choice":
            ok = len(args) == 2 and all(isinstance(a, int | float) for a in args)
            ok = ok and args[0] < args[1] and (kind != "log_uniform" or args[0] > 0)
            ok = ok and (kind != "integer" or all(isinstance(a, int) for a in args))
            if not ok:
                raise fail(f"{key}.{kind}", f"expected [low, high] with low < high"
                           f"{' (integers)' if kind == 'integer' else ''}"
                           f"{', low > 0' if kind == 'log_uniform' else ''}, got {args!r}")
        draws[name] = (kind, args)
    return draws


def draw_parameters(draws: dict[str, tuple[str, list]], seed: int) -> dict:
    """The drawn parameters of the job with ``seed``: each from its own stream,
    ``numpy.random.default_rng([seed, crc32(name)])``, so that adding a parameter does not
    change the others' draws.

    Parameters
    ----------
    draws : dict
        name -> (kind of :data:`DRAWS`, its list: ``[low, high]`` or the choices).
    seed : int

    Returns
    -------
    dict
        name -> value (floats rounded to 6 significant digits, so that they print as written).
    """
    out = {}
    for name, (kind, args) in sorted(draws.items()):
        rng = np.random.default_rng([seed, zlib.crc32(name.encode())])
        if kind == "choice":
            out[name] = args[int(rng.integers(len(args)))]
            continue
        low, high = args
        if kind == "integer":
            out[name] = int(rng.integers(low, high + 1))
            continue
        if kind == "uniform":
            value = rng.uniform(low, high)
        else:
            value = math.exp(rng.uniform(math.log(low), math.log(high)))
        out[name] = float(f"{value:.6g}")
    return out
