"""Where a simulation's time goes: each stage's wall seconds beside the Dr.Jit kernels it ran.

``evfuse simulate --profile`` (:func:`sim.simulate.simulate` with ``profile=True``) writes
``profile.json`` into the output folder and prints it as a table. For each stage of
``sequence.json``'s ``timings_s`` it gives

- ``wall_s``: the stage's wall seconds (exactly ``timings_s``'s figure);
- ``device_s``: the execution time of the Dr.Jit kernels the stage ran, from Dr.Jit's kernel
  history (``dr.JitFlag.KernelHistory``): on ``cuda_ad_rgb`` the GPU's time, on ``llvm_ad_rgb``
  the time the CPU cores spent inside compiled kernels;
- ``host_s`` = ``wall_s - device_s``: Python, NumPy, Numba, tracing, compilation and copies;
- ``launches``: Dr.Jit operations the stage ran (compiled kernels, reductions, prefix sums,
  compressions, aggregates: every kernel-history entry but memory copies and fills), and
  ``kernels`` the compiled kernels among them;
- ``compile_s``: code generation and compilation of the stage's kernels that were not in
  Dr.Jit's kernel cache (part of ``host_s``);
- ``copies`` and ``copy_bytes``: the memory copies Dr.Jit made (host <-> device on a GPU).

and an ``event_camera`` entry over ``event_render`` + ``event_sample`` + ``emulate`` (the event
camera's renders, its sampler's bookkeeping and the emulator), with ``simulated_s`` and
``variant``.

How kernels are charged to stages
---------------------------------
A :class:`KernelLedger` is active while a profiled simulation runs. The code that times a stage
for ``timings_s`` also runs the same stretch inside ``with stage(name):`` (:func:`stage`); the
stretches nest (the event camera's renders and its emulator inside its sampler's step, per-event
depth inside writing). On entering a stretch the ledger charges what ran so far to the enclosing
stage, on leaving it what ran inside to this one. At each of these marks it waits for the kernels
queued so far (``dr.sync_thread``) and reads Dr.Jit's kernel history (which Dr.Jit empties on
each read). So the kernels that ran during a stage are charged to it, whatever runs
asynchronously, and what runs outside every stage is charged to ``other``. Waiting at each mark
is the profile's only cost to the run (the kernels would otherwise overlap the next stage's host
work): a profiled run's wall time is a few percent above an unprofiled one's.

``scalar_rgb`` runs no Dr.Jit kernels: the profile there has the wall times alone and
``device_s``, ``host_s`` null, with a note.
"""

from __future__ import annotations

import contextvars
from collections.abc import Iterator, Mapping
from contextlib import contextmanager
from dataclasses import asdict, dataclass

__all__ = ["EVENT_CAMERA_STAGES", "PROFILE_JSON", "STAGES", "KernelLedger", "StageKernels",
           "profile_record", "profile_table", "profiles_summary", "recording", "stage"]

STAGES = ("setup", "imu", "frame_setup", "depth", "exposure_control", "frame_motion",
          "frame_edges", "render", "frame_sensor", "write", "flow", "emulate_compile",
          "event_render", "event_sample", "emulate", "event_write", "event_depth", "checkpoint")
"""The stages of ``sequence.json``'s ``timings_s``, in the order a simulation runs them (frames,
then events): :func:`sim.simulate.simulate` starts its timings from them, the profile's table
lists them in this order."""

PROFILE_JSON = "profile.json"
"""The profile's file name in a sequence folder."""

EVENT_CAMERA_STAGES = ("event_render", "event_sample", "emulate")
"""The stages of ``timings_s`` that make up the event camera (its renders, its sampler's
bookkeeping, the emulator)."""

NOT_MEASURED_NOTE = ("device time is not measured on scalar_rgb (it runs no Dr.Jit kernels): "
                     "wall times only")
"""``profile.json``'s ``note`` on ``scalar_rgb``."""


@dataclass
class StageKernels:
    """The Dr.Jit work charged to one stage.

    Attributes
    ----------
    device_s : float, seconds
        Summed execution time of its kernel-history entries.
    launches : int
        Entries that are not memory copies or fills (kernels, reductions, prefix sums, ...).
    kernels : int
        Compiled kernels among them (``KernelType.JIT``).
    compile_s : float, seconds
        Code generation + backend compilation of those kernels (0 for a cache hit).
    copies : int
        Memory copies (``KernelType.Memcpy``).
    copy_bytes : int
        Their bytes.
    """

    device_s: float = 0.0
    launches: int = 0
    kernels: int = 0
    compile_s: float = 0.0
    copies: int = 0
    copy_bytes: int = 0

    def add(self, entry: Mapping) -> None:
        """Charge one kernel-history entry (a dict of :func:`drjit.kernel_history`)."""
        import drjit as dr

        kind = entry.get("type")
        self.device_s += float(entry.get("execution_time", 0.0)) * 1e-3      # ms -> s
        if kind == dr.KernelType.Memcpy:
            self.copies += 1
            self.copy_bytes += int(entry.get("size", 0))
            return
        if kind == dr.KernelType.Memset:
            return
        self.launches += 1
        if kind == dr.KernelType.JIT:
            self.kernels += 1
            self.compile_s += (float(entry.get("codegen_time", 0.0))
                               + float(entry.get("backend_time", 0.0))) * 1e-3


class KernelLedger:
    """Dr.Jit's kernel history, charged stage by stage (see the module's notes).

    Use it through :func:`recording` and :func:`stage`.
    """

    def __init__(self) -> None:
        self.stages: dict[str, StageKernels] = {}
        self.open: list[str] = ["other"]          # the enclosing stages, innermost last

    def lap(self, stage: str) -> None:
        """Wait for the queued kernels and charge every entry of the history to ``stage``."""
        import drjit as dr

        dr.sync_thread()
        entries = dr.kernel_history()
        if entries:
            cost = self.stages.setdefault(stage, StageKernels())
            for entry in entries:
                cost.add(entry)

    def total(self, names=None) -> StageKernels:
        """Everything charged to the stages ``names`` (default all), summed."""
        out = StageKernels()
        for name in self.stages if names is None else names:
            for key, value in asdict(self.stages.get(name, StageKernels())).items():
                setattr(out, key, getattr(out, key) + value)
        return out


_ACTIVE: contextvars.ContextVar[KernelLedger | None] = contextvars.ContextVar(
    "evfuse_kernel_ledger", default=None)


@contextmanager
def stage(name: str) -> Iterator[None]:
    """Mark a stretch nested in another stage as ``name``'s (see the module's notes): with a
    ledger active, what ran before is charged to the enclosing stage, what runs inside to
    ``name``; else nothing."""
    ledger = _ACTIVE.get()
    if ledger is None:
        yield
        return
    ledger.lap(ledger.open[-1])
    ledger.open.append(name)
    try:
        yield
    finally:
        ledger.lap(name)
        ledger.open.pop()


@contextmanager
def recording(enabled: bool = True) -> Iterator[KernelLedger | None]:
    """Record Dr.Jit's kernel history into a :class:`KernelLedger` (None when not ``enabled``).

    Turns ``dr.JitFlag.KernelHistory`` on (and back to what it was), drops the history left
    from before, and charges what is left at the end to ``"other"``.
    """
    if not enabled:
        yield None
        return
    import drjit as dr

    before = dr.flag(dr.JitFlag.KernelHistory)
    dr.sync_thread()
    dr.kernel_history()                               # what ran before is not ours
    dr.set_flag(dr.JitFlag.KernelHistory, True)
    ledger = KernelLedger()
    token = _ACTIVE.set(ledger)
    try:
        yield ledger
        ledger.lap("other")
    finally:
        _ACTIVE.reset(token)
        dr.set_flag(dr.JitFlag.KernelHistory, before)


def _stage_record(wall: float, cost: StageKernels | None, measured: bool) -> dict:
    cost = cost or StageKernels()
    record = {"wall_s": round(wall, 4)}
    if measured:
        record.update(device_s=round(cost.device_s, 4), host_s=round(wall - cost.device_s, 4),
                      launches=cost.launches, kernels=cost.kernels,
                      compile_s=round(cost.compile_s, 4), copies=cost.copies,
                      copy_bytes=cost.copy_bytes)
    else:
        record.update(device_s=None, host_s=None, launches=None, kernels=None,
                      compile_s=None, copies=None, copy_bytes=None)
    return record


def profile_record(timings: Mapping[str, float], ledger: KernelLedger | None, variant: str,
                   simulated_s: float | None, device: str | None = None) -> dict:
    """``profile.json``: each stage's wall and Dr.Jit costs, and the event camera's.

    Parameters
    ----------
    timings : mapping of str to float, seconds
        ``sequence.json``'s ``timings_s`` (unrounded), with ``total``.
    ledger : KernelLedger or None
        The run's kernels (None on ``scalar_rgb``: wall times only).
    variant : str
        The Mitsuba variant.
    simulated_s : float or None, seconds
        The event stream's span (None: no events simulated).
    device : str, optional
        The device's name where known.

    Returns
    -------
    dict
        ``variant``, ``device``, ``simulated_s``, ``device_time_measured``, ``note``,
        ``stages`` (each stage of ``timings`` but ``total``, plus ``other``: kernels outside
        every stage), ``event_camera`` (its stages summed, with ``per_simulated_s``: its wall,
        device and host seconds per simulated second) and ``total`` (the whole run).
    """
    measured = ledger is not None
    costs = ledger.stages if ledger is not None else {}
    stages = {name: _stage_record(float(wall), costs.get(name), measured)
              for name, wall in timings.items() if name != "total"}
    for name in costs:            # kernels charged to a stage without wall time of its own
        if name not in stages:
            stages[name] = _stage_record(0.0, costs[name], measured)
    camera_wall = sum(float(timings.get(name, 0.0)) for name in EVENT_CAMERA_STAGES)
    camera_cost = ledger.total(EVENT_CAMERA_STAGES) if ledger is not None else None
    event_camera = _stage_record(camera_wall, camera_cost, measured)
    if simulated_s:
        event_camera["per_simulated_s"] = {
            key: (None if event_camera[key] is None
                  else round(event_camera[key] / simulated_s, 4))
            for key in ("wall_s", "device_s", "host_s")}
    total_wall = float(timings.get("total", sum(float(v) for v in timings.values())))
    return {
        "variant": variant,
        "device": device,
        "simulated_s": simulated_s,
        "device_time_measured": measured,
        "note": None if measured else NOT_MEASURED_NOTE,
        "stages": stages,
        "event_camera": event_camera,
        "total": _stage_record(total_wall, ledger.total() if ledger else None, measured),
    }


def profile_table(record: Mapping) -> str:
    """``profile.json`` as a text table: a row per stage that took time, the event camera and
    the total."""
    def cell(value, digits: int = 3) -> str:
        if value is None:
            return "-"
        return f"{value:,}" if isinstance(value, int) else f"{value:.{digits}f}"

    head = (f"{'stage':<16} {'wall s':>8} {'device s':>9} {'host s':>8} {'launches':>9} "
            f"{'compile s':>9} {'copied MB':>9}")
    rows = [head, "-" * len(head)]

    def row(name: str, r: Mapping) -> str:
        mb = None if r["copy_bytes"] is None else r["copy_bytes"] / 1e6
        return (f"{name:<16} {cell(r['wall_s']):>8} {cell(r['device_s']):>9} "
                f"{cell(r['host_s']):>8} {cell(r['launches']):>9} {cell(r['compile_s']):>9} "
                f"{cell(mb, 1):>9}")

    stages = record["stages"]
    for name in sorted(stages, key=lambda n: STAGES.index(n) if n in STAGES else len(STAGES)):
        r = stages[name]
        if r["wall_s"] >= 0.0005 or (r["device_s"] or 0.0) >= 0.0005:
            rows.append(row(name, r))
    rows.append("-" * len(head))
    rows.append(row("event camera", record["event_camera"]))
    rows.append(row("total", record["total"]))
    per = record["event_camera"].get("per_simulated_s")
    lines = [f"profile ({record['variant']}"
             + (f", {record['device']}" if record.get("device") else "") + "):", *rows]
    if per:
        lines.append(f"event camera per simulated second: wall {cell(per['wall_s'])} s, "
                     f"device {cell(per['device_s'])} s, host {cell(per['host_s'])} s "
                     f"({record['simulated_s']:g} s simulated)")
    if record.get("note"):
        lines.append(record["note"])
    return "\n".join(lines)


def profiles_summary(paths: list) -> str:
    """One line on many runs' ``profile.json`` (a dataset's jobs): their event camera's wall,
    device and host seconds, summed and per simulated second.

    Parameters
    ----------
    paths : list of str or Path
        ``profile.json`` files.

    Returns
    -------
    str
    """
    import json
    from pathlib import Path

    records = [json.loads(Path(p).read_text(encoding="utf-8")) for p in paths]
    simulated = sum(r["simulated_s"] or 0.0 for r in records)
    if not records or not simulated:
        return f"profiles: {len(records)} profile.json, no events simulated"
    camera = [r["event_camera"] for r in records]
    wall = sum(c["wall_s"] for c in camera)
    measured = all(r["device_time_measured"] for r in records)
    line = (f"profiles: {len(records)} jobs' profile.json; their event camera: "
            f"{simulated:g} s simulated in {wall:.2f} s of wall time "
            f"({wall / simulated:.3f} s per simulated second")
    if measured:
        device = sum(c["device_s"] for c in camera)
        line += (f"; device {device / simulated:.3f} s, host {(wall - device) / simulated:.3f}"
                 f" s per simulated second, {sum(c['launches'] for c in camera):,} launches")
    else:
        line += f"; {NOT_MEASURED_NOTE}"
    return line + f"; variants {', '.join(sorted({r['variant'] for r in records}))})"
