"""Shared fixtures: small scenes written as TOML text, so tests exercise the real parser."""

from __future__ import annotations

import hashlib
import importlib
import os
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path

import pytest

SHARED_DATA = Path(__file__).resolve().parents[2] / "shared" / "data"
ECD_SLIDER = SHARED_DATA / "ecd_slider_depth_first50k"


def scene_text(objects: str, *, camera: str | None = None, trajectory: str | None = None,
               lights: str | None = None, duration: float = 1.0, extra: str = "") -> str:
    """TOML of a small test scene: 64x48 camera with fx != fy, static at the origin looking +y."""
    camera = camera or (
        "[camera]\nwidth = 64\nheight = 48\nfx = 60.0\nfy = 45.0\ncx = 30.3\ncy = 22.7\n"
    )
    trajectory = trajectory or (
        '[trajectory]\ntype = "linear"\nposition = [0.0, 0.0, 0.0]\n'
        "velocity = [0.0, 0.0, 0.0]\nlook_at = [0.0, 1.0, 0.0]\n"
    )
    lights = lights or (
        '[[lights]]\ntype = "directional"\ndirection = [0.0, 1.0, 0.0]\n'
        'illuminance_lux = 400.0\n'
    )
    return (f'name = "test"\ndescription = "test scene"\nduration = {duration}\nseed = 3\n'
            f"{extra}\n{camera}\n{trajectory}\n{lights}\n{objects}\n")


def undistort_points(src, camera_matrix, distortion, R=None, P=None, criteria=None):
    """OpenCV's ``undistortPoints`` with its iteration's termination criteria, on OpenCV 4
    (``undistortPointsIter``) and OpenCV 5 (``undistortPoints(..., criteria)``, the other
    gone): the tests' analytic reference for a distorting lens."""
    import cv2
    import numpy as np

    distortion = np.asarray(distortion, dtype=np.float64)
    if criteria is None:
        return cv2.undistortPoints(src, camera_matrix, distortion, None, R, P)
    if hasattr(cv2, "undistortPointsIter"):                             # OpenCV 4
        return cv2.undistortPointsIter(src, camera_matrix, distortion, R, P, criteria)
    return cv2.undistortPoints(src, camera_matrix, distortion, None, R, P, criteria)


def tree_hashes(*paths: str | Path) -> dict[str, str]:
    """SHA-256 of every file under each of ``paths`` (a file or a folder), by path; a folder as
    ``<dir>``, a link as ``-> target``, a missing path as ``<missing>``: two calls compare equal
    only if no file was written, added, removed or replaced."""
    hashes: dict[str, str] = {}

    def add(path: Path) -> None:
        if path.is_symlink():
            hashes[str(path)] = f"-> {os.readlink(path)}"
        elif path.is_dir():
            hashes[str(path)] = "<dir>"
            for child in sorted(path.iterdir()):
                add(child)
        elif path.is_file():
            hashes[str(path)] = hashlib.sha256(path.read_bytes()).hexdigest()
        else:
            hashes[str(path)] = "<missing>"

    for path in paths:
        add(Path(path))
    return hashes


_WRITTEN = {"--out", "--cache"}
"""Flags whose value a command writes (its output), never hashed as an input."""


def cli_inputs(argv: Sequence[str]) -> list[Path]:
    """The existing paths among ``argv`` that the command only reads: every argument naming an
    existing file or folder except the value of ``--out`` / ``--cache`` (and ``convert``'s DST)."""
    argv = list(argv)
    written = {k + 1 for k, arg in enumerate(argv[:-1]) if arg in _WRITTEN}
    if argv and argv[0] == "convert":
        positional = [k for k, arg in enumerate(argv) if k and not arg.startswith("-")]
        written |= set(positional[1:2])
    return [Path(arg) for k, arg in enumerate(argv)
            if k not in written and k and not arg.startswith("-") and Path(arg).exists()]


def run_cli(argv: Sequence[str], inputs: Sequence[str | Path] | None = None) -> int:
    """``fusion.cli.main(argv)``, asserting that no file of its inputs changed (CONVENTIONS:
    inputs are sacred): every file under ``inputs`` (default :func:`cli_inputs`) is hashed
    before and after, whatever the exit status.

    Returns
    -------
    int
        The exit status of ``main``.
    """
    from fusion.cli import main

    inputs = cli_inputs(argv) if inputs is None else list(inputs)
    before = tree_hashes(*inputs)
    code = main(list(argv))
    after = tree_hashes(*inputs)
    changed = sorted(k for k in set(before) | set(after) if before.get(k) != after.get(k))
    assert not changed, f"evfuse {' '.join(map(str, argv))} changed its inputs: {changed[:5]}"
    return code


@pytest.fixture(scope="session")
def ecd_slider() -> Path:
    """The real ECD slider_depth prefix, or skip when ../shared/data is absent."""
    if not ECD_SLIDER.is_dir():
        pytest.skip(f"{ECD_SLIDER} is absent")
    return ECD_SLIDER


WALL = """
[[objects]]
name = "wall"
type = "rectangle"
center = [0.0, 1.0, 0.0]
size = [6.0, 6.0]
[objects.material]
texture_scale = [6.0, 6.0]
texture = { type = "shapes", resolution = 256, count = 30, min_size = 10, max_size = 40 }
"""
# A dark box before a bright wall, lit from the side (its shadow on the wall), seen through a
# strongly distorting lens with fx != fy: geometric edges (tests of edge_spp).
BOX_BEFORE_WALL = """
[[objects]]
name = "wall"
type = "rectangle"
center = [0.0, 2.0, 0.0]
size = [4.0, 4.0]
normal = [0.0, -1.0, 0.0]
up = [0.0, 0.0, 1.0]
material = { color = 0.8 }
[[objects]]
name = "box"
type = "box"
center = [0.05, 1.0, 0.02]
size = [0.3, 0.2, 0.3]
material = { color = 0.08 }
"""
LENS = (-0.3, 0.08, 0.001, -0.002, 0.0)          # strong barrel distortion, as a DAVIS240C's
SIDE_LIGHT_TOML = ('[[lights]]\ntype = "directional"\ndirection = [0.3, 1.0, -0.2]\n'
                   "illuminance_lux = 400.0\n")
LENS_CAMERA = ("[camera]\nwidth = 64\nheight = 48\nfx = 60.0\nfy = 45.0\ncx = 30.3\ncy = 22.7\n"
               f"distortion = {list(LENS)}\n")

FAST = ('[trajectory]\ntype = "linear"\nposition = [-0.15, 0.0, 0.0]\n'
        "velocity = [1.0, 0.0, 0.0]\nlook_at = [-0.15, 1.0, 0.0]\n")


@pytest.fixture(scope="session")
def plane_sequence(tmp_path_factory):
    """A 64x48 camera sliding 0.3 m past a fronto-parallel textured wall 1 m away."""
    from sim.scene import parse_scene
    from sim.simulate import simulate

    extra = "[frames]\nrate = 20.0\nexposure = 0.01\nexposure_samples = 1\n[render]\nspp = 4\n"
    scene = parse_scene(scene_text(WALL, trajectory=FAST, duration=0.3, extra=extra))
    out = tmp_path_factory.mktemp("seq") / "plane"
    return simulate(scene, out, progress=False).out


def filtered_reference_events(u, omega, t_end: float, contrast: float, y0: float,
                              step: float = 1e-7) -> list[tuple[float, int]]:
    """Events of one pixel whose filtered level obeys ``dy/dt = omega(t) (u(t) - y)``,
    integrated by SciPy (rtol 1e-12) independently of :mod:`sim.noise`, and walked on a grid
    of ``step`` seconds (crossings interpolated inside a grid step, whose curvature error is
    far below a nanosecond at 0.1 us): ``(t seconds, polarity)`` with the emulator's rule
    (reference starts at ``y0`` and moves by ``contrast`` at each crossing)."""
    import numpy as np
    from scipy.integrate import solve_ivp

    solution = solve_ivp(lambda t, y: [omega(t) * (u(t) - y[0])], (0.0, t_end), [y0],
                         rtol=1e-12, atol=1e-14, dense_output=True, max_step=1e-5)
    grid = np.arange(0.0, t_end, step)
    y = solution.sol(grid)[0]
    ref, out = y0, []
    for k in range(1, len(grid)):
        for sign in (1, -1):
            while sign * (y[k] - ref) >= contrast:
                level = ref + sign * contrast
                frac = (level - y[k - 1]) / (y[k] - y[k - 1])
                out.append((grid[k - 1] + frac * step, sign))
                ref = level
    return out


# Hypothesis profiles for the fuzz targets (tests/test_fuzz.py, benchmarks/fuzz.py): "ci" (the
# default) tries a few hundred cases per target, derandomized so that every run tries the same
# ones; HYPOTHESIS_PROFILE=long tries many more with a random seed.
try:
    from hypothesis import HealthCheck, settings
except ImportError:  # pragma: no cover - the test extra installs it
    pass
else:
    _QUIET = [HealthCheck.too_slow, HealthCheck.data_too_large, HealthCheck.filter_too_much]
    settings.register_profile("ci", max_examples=200, deadline=None, derandomize=True,
                              suppress_health_check=_QUIET, print_blob=True)
    settings.register_profile("long", max_examples=5000, deadline=None,
                              suppress_health_check=_QUIET, print_blob=True)
    import os as _os

    settings.load_profile(_os.environ.get("HYPOTHESIS_PROFILE", "ci"))


DATASET_JOBS = (("complex_sphere-0", "complex_sphere", ("h5", "txt")),
                ("boxes_6dof-0", "boxes_6dof", ("txt", "depth-txt")))
"""The done jobs of :func:`small_dataset`: one sequence read from ``events.h5``, one from
``events.txt`` alone, its per-event depth in ``events_depth.txt`` (the loader's two paths)."""


def write_dataset_manifest(folder: Path, rows: list[dict]) -> None:
    """``folder/manifest.csv`` with the shared contract's columns (issue 24), one row a job."""
    import csv

    columns = ["job_id", "path", "status", "error", "scene", "seed", "attempts", "events",
               "frames", "renders", "pixel_samples", "duration_s", "wall_s", "output_hash",
               "evfuse_version", "mitsuba_version", "drjit_version", "numpy_version"]
    with (folder / "manifest.csv").open("w", newline="", encoding="utf-8") as handle:
        writer = csv.DictWriter(handle, columns, restval="")
        writer.writeheader()
        writer.writerows(rows)


@pytest.fixture(scope="session")
def small_dataset(tmp_path_factory) -> Path:
    """A dataset folder as ``evfuse generate`` writes it (the shared contract of issue 24): two
    done jobs simulated by the library (48x36, 0.1 s, frames at 60 Hz: 6 frames each), a failed
    one and a pending one, and ``manifest.csv``. Read-only for the tests (copy it to change it)."""
    import dataclasses
    import time

    import drjit
    import mitsuba
    import numpy as np

    from scenes import resolve_scene
    from sim.output import evfuse_version, write_marker
    from sim.scene import load_scene
    from sim.simulate import simulate

    folder = tmp_path_factory.mktemp("dataset") / "tiny"
    (folder / "jobs").mkdir(parents=True)
    write_marker(folder, "generate")
    versions = {"evfuse_version": evfuse_version(), "mitsuba_version": mitsuba.__version__,
                "drjit_version": drjit.__version__, "numpy_version": np.__version__}
    rows = []
    for job_id, name, formats in DATASET_JOBS:
        scene = load_scene(resolve_scene(name))
        scene = dataclasses.replace(scene, camera=scene.camera.with_resolution(48, 36),
                                    frames=dataclasses.replace(scene.frames, rate=60.0,
                                                                max_exposure=0.01))
        began = time.perf_counter()
        result = simulate(scene, folder / "jobs" / job_id, duration=0.1, start=0.5, spp=1,
                          progress=False, event_formats=formats)
        digest = hashlib.sha256()
        for path in sorted(p for p in result.out.rglob("*") if p.is_file()):
            digest.update(str(path.relative_to(result.out)).encode() + path.read_bytes())
        rows.append({"job_id": job_id, "path": f"jobs/{job_id}", "status": "done",
                     "scene": name, "seed": scene.seed, "attempts": 1,
                     "events": result.n_events, "frames": result.n_frames,
                     "renders": result.n_renders, "pixel_samples": result.event_pixel_samples,
                     "duration_s": 0.1, "wall_s": round(time.perf_counter() - began, 3),
                     "output_hash": digest.hexdigest(), **versions})
    rows.append({"job_id": "broken-0", "path": "jobs/broken-0", "status": "failed",
                 "error": "ValueError: the scene cannot render", "scene": "broken", "seed": 0,
                 "attempts": 3, **versions})
    rows.append({"job_id": "later-0", "path": "jobs/later-0", "status": "pending",
                 "scene": "boxes_6dof", "seed": 1, "attempts": 0, **versions})
    write_dataset_manifest(folder, rows)
    return folder


@contextmanager
def interrupted_pixel_blocks(monkeypatch: pytest.MonkeyPatch, blocks: int,
                             every: int = 3) -> Iterator[list[float]]:
    """Inside the block, ``simulate``'s per-pixel sampler raises KeyboardInterrupt after
    ``blocks`` blocks (their end times, s, go into the list yielded), with a checkpoint every
    ``every`` blocks (that stays set after the block, for the resumed run)."""
    driver = importlib.import_module("sim.simulate._events")
    checkpoints = importlib.import_module("sim.simulate._checkpoint")
    real, seen = driver.pixel_blocks, []

    def interrupting(*args, **kwargs):
        for block in real(*args, **kwargs):
            if len(seen) == blocks:
                raise KeyboardInterrupt
            seen.append(block.t)
            yield block

    monkeypatch.setattr(checkpoints, "CHECKPOINT_SAMPLES", every)
    monkeypatch.setattr(checkpoints, "CHECKPOINT_SECONDS", 1e9)
    monkeypatch.setattr(driver, "pixel_blocks", interrupting)
    try:
        yield seen
    finally:
        monkeypatch.setattr(driver, "pixel_blocks", real)


# --- figures whose bound depends on the Mitsuba variant ------------------------------------------

VARIANT_FIGURES_ENV = "EVFUSE_VARIANT_FIGURES"
"""A JSON-lines file that :func:`variant_bound` appends each figure to where the active variant
has no bound of its own yet (``benchmarks/gpu_check.sh`` sets it, to bring them back)."""
MEASURED_VARIANT = "llvm_ad_rgb"
"""The variant every bound was first measured on."""


@pytest.fixture(scope="session")
def variant() -> str:
    """The Mitsuba variant the suite renders with (:func:`sim.variant.use_variant`)."""
    from sim.variant import use_variant

    return use_variant()


def bound_for(variant: str, what: str, value: float, bounds: dict[str, float],
              test: str = "") -> float:
    """The bound of a figure that depends on the variant (renders, float32 atomics, kernel
    order): ``bounds[variant]``. Where the variant has none yet, the bound measured on
    :data:`MEASURED_VARIANT`, and the figure is recorded to say what the variant gives: a
    warning in the test report and a line in :data:`VARIANT_FIGURES_ENV`'s file when set
    (never a silent skip).

    Parameters
    ----------
    variant : str
    what : str
        The figure's name, as the record shows it.
    value : float
        The figure measured by the test.
    bounds : dict of str to float
        Each variant's bound, :data:`MEASURED_VARIANT`'s at least.
    test : str
        The test's node id, for the record.
    """
    import json
    import warnings

    if variant in bounds:
        return bounds[variant]
    record = {"test": test, "figure": what, "variant": variant, "value": float(value),
              "bound_from": MEASURED_VARIANT, "bound": bounds[MEASURED_VARIANT]}
    target = os.environ.get(VARIANT_FIGURES_ENV)
    if target:
        fd = os.open(target, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o644)
        try:
            os.write(fd, (json.dumps(record) + "\n").encode())
        finally:
            os.close(fd)
    warnings.warn(f"{what} = {value:g} on {variant}, which has no bound of its own yet: "
                  f"checked against {MEASURED_VARIANT}'s {bounds[MEASURED_VARIANT]:g}, recorded",
                  stacklevel=2)
    return bounds[MEASURED_VARIANT]


@pytest.fixture
def variant_bound(request, variant):
    """:func:`bound_for` for this test and the active variant:
    ``variant_bound(what, value, {"llvm_ad_rgb": bound, ...})``."""
    def bound(what: str, value: float, bounds: dict[str, float]) -> float:
        return bound_for(variant, what, value, bounds, request.node.nodeid)
    return bound
