"""evfuse simulate --resume: an interrupted run, continued from its checkpoint, writes the files
an uninterrupted run writes; and the pieces that make it so (sampler, emulator, writers)."""

from __future__ import annotations

import importlib
import json
import os
import signal
from dataclasses import asdict, replace
from pathlib import Path

import numpy as np
import pytest

from fusion.cli import main
from sim.camera import Camera
from sim.eventio import H5EventWriter, TextEventWriter, make_events, read_events
from sim.events import EventEmulator, EventParams
from sim.frame_shader import FrameShader
from sim.render import Renderer
from sim.sampling import SamplingStats, adaptive_samples
from sim.scene import parse_scene
from sim.shader import EventShader
from sim.simulate import SimulationResult, simulate
from tests.conftest import FAST, interrupted_pixel_blocks, scene_text

simulation = importlib.import_module("sim.simulate._run")        # simulate() and its steps
checkpoints = importlib.import_module("sim.simulate._checkpoint")  # when and what it saves
event_driver = importlib.import_module("sim.simulate._events")   # the samplers it drives

# Sharp-edged strips passing at 1 m/s: many events, and many intervals split at sub-pixel
# steps (samples with a pending tail, where no checkpoint may be taken). The edges are
# geometry (dark strips before a bright wall): a texture's edges are filtered over each
# sub-sample's footprint (sim.textures) and give ramps, not steps.
CHECKER = """
[[objects]]
name = "wall"
type = "rectangle"
center = [0.0, 1.5, 0.0]
size = [8.0, 8.0]
material = { color = [0.85, 0.85, 0.85] }
""" + "".join(f"""
[[objects]]
name = "strip{i}"
type = "rectangle"
center = [{-1.25 + 0.25 * i:.2f}, 1.0, 0.0]
size = [0.125, 6.0]
material = {{ color = [0.05, 0.05, 0.05] }}
""" for i in range(11))
# Noisy frames under auto-exposure (a responsivity that keeps it inside its range): every
# frame's exposure and noise must survive a resume.
EXTRA = ("[frames]\nrate = 20.0\nexposure = 0.01\nexposure_samples = 2\n"
         "sensor = { preset = \"machine_vision\", responsivity = 1e8 }\n[render]\nspp = 4\n")
TEXT = scene_text(CHECKER, trajectory=FAST, duration=0.12, extra=EXTRA)
# The realistic sensor draws from its generator at every step and carries low-pass state.
EVENTS = EventParams.preset("realistic", seed=3)


class _Renders:
    """Count the renders of frames (Renderer.luminance; this static scene's frames are rendered
    pixel by pixel: FrameShader.still, auto-exposure's look, one render, and
    FrameShader.exposure, one per exposure time) and of the event camera's whole frames
    (EventShader.frame), and raise KeyboardInterrupt at render number ``stop``."""

    def __init__(self, monkeypatch: pytest.MonkeyPatch, stop: int | None = None) -> None:
        self.frames = self.events = 0
        self.stop = stop

        def check() -> None:
            if self.stop is not None and self.frames + self.events + 1 >= self.stop:
                raise KeyboardInterrupt

        def frame(renderer, t, pose=None, spp=None):
            check()
            self.frames += 1
            return _REAL_LUMINANCE(renderer, t, pose, spp)

        def still(shader, t):
            check()
            self.frames += 1
            return _REAL_STILL(shader, t)

        def exposure(shader, t, exposure, depth, times=None):
            check()
            luminance, cost = _REAL_EXPOSURE(shader, t, exposure, depth, times)
            self.frames += cost.times
            return luminance, cost

        def event_frame(shader, t):
            check()
            self.events += 1
            return _REAL_EVENT_FRAME(shader, t)

        monkeypatch.setattr(Renderer, "luminance", frame)
        monkeypatch.setattr(FrameShader, "still", still)
        monkeypatch.setattr(FrameShader, "exposure", exposure)
        monkeypatch.setattr(EventShader, "frame", event_frame)


_REAL_LUMINANCE = Renderer.luminance
_REAL_STILL = FrameShader.still
_REAL_EXPOSURE = FrameShader.exposure
_REAL_EVENT_FRAME = EventShader.frame
_REAL_SAMPLES = event_driver.adaptive_samples


def _simulate(out: Path, resume: bool = False, scene_seed: int | None = None
              ) -> SimulationResult:
    scene = parse_scene(TEXT, seed=scene_seed)
    events = EventParams.preset("realistic", seed=scene.seed)
    return simulate(scene, out, progress=False, events=events, resume=resume, sampler="frame")


def _files(folder: Path) -> list[str]:
    return sorted(str(p.relative_to(folder)) for p in folder.rglob("*") if p.is_file())


def _assert_same_sequence(expected: Path, got: Path) -> None:
    """Same files, same bytes (events.h5 included), except sequence.json's timings."""
    assert _files(got) == _files(expected)
    for rel in _files(expected):
        if rel == "sequence.json":
            want, have = (json.loads((f / rel).read_text()) for f in (expected, got))
            assert want.pop("timings_s") and have.pop("timings_s")
            assert have == want
        else:
            assert (got / rel).read_bytes() == (expected / rel).read_bytes(), rel


@pytest.fixture(scope="module")
def full(tmp_path_factory) -> tuple[SimulationResult, int]:
    """The uninterrupted run, and how many renders its event camera made."""
    with pytest.MonkeyPatch.context() as patch:
        renders = _Renders(patch)
        result = _simulate(tmp_path_factory.mktemp("full") / "seq")
    return result, renders.events


def test_an_interrupted_run_resumes_to_the_uninterrupted_files(full, tmp_path, monkeypatch):
    reference, full_event_renders = full
    meta = json.loads((reference.out / "sequence.json").read_text())
    assert reference.n_events > 5000 and meta["events"]["step_intervals"] > 20
    assert full_event_renders == reference.event_renders
    out = tmp_path / "seq"
    partial, state = tmp_path / "seq.partial", tmp_path / "seq.partial" / ".checkpoint"
    monkeypatch.setattr(checkpoints, "CHECKPOINT_SAMPLES", 1)   # at every boundary allowed

    # 1. Interrupted in the frames, at frame 1's first exposure render (the 4th render: frame
    # 0's auto-exposure metering render and its two exposure renders come first).
    _Renders(monkeypatch, stop=4)
    with pytest.raises(KeyboardInterrupt):
        _simulate(out)
    assert not out.exists()
    assert _files(partial / "images") == ["frame_00000000.png"]
    exposures = json.loads((state / "checkpoint.json").read_text())["exposures"]
    assert len(exposures) == 2 and all(0 < e < 0.01 for e in exposures)   # inside its range

    # 2. Resumed, and interrupted in the events just before the second half of a split
    # interval, long after the last checkpoint (taken before its first half).
    seen = []

    def interrupting(*args, **kwargs):
        for sample in _REAL_SAMPLES(*args, **kwargs):
            if len(seen) > 150 and seen[-1].tail_pending:
                raise KeyboardInterrupt
            seen.append(sample)
            yield sample

    monkeypatch.setattr(event_driver, "adaptive_samples", interrupting)
    renders = _Renders(monkeypatch)
    with pytest.raises(KeyboardInterrupt):
        _simulate(out, resume=True)
    assert renders.frames == 2 * 2                    # frames 1 and 2 only, 2 renders each
    with np.load(state / "events.npz") as saved:
        saved = json.loads(str(saved["state"]))
    assert saved["sample"]["t"] == seen[-2].t < seen[-1].t   # not at the pending half
    assert (partial / "events.txt.partial").stat().st_size > 0

    # 3. Resumed to the end of the events, interrupted before the checkpoint says they are
    # done (the writers have already renamed their files into place).
    monkeypatch.setattr(event_driver, "adaptive_samples", _REAL_SAMPLES)
    done = checkpoints._Checkpoint.set_events_done

    def interrupted_done(self, info):
        raise KeyboardInterrupt

    monkeypatch.setattr(checkpoints._Checkpoint, "set_events_done", interrupted_done)
    renders = _Renders(monkeypatch)
    with pytest.raises(KeyboardInterrupt):
        _simulate(out, resume=True)
    assert renders.frames == 0
    assert renders.events == full_event_renders - saved["stats"]["renders"] > 0
    assert saved["stats"]["renders"] > 150            # it did not start over
    assert (partial / "events.h5").is_file() and not (partial / "events.h5.partial").exists()

    # 4. Resumed from the last checkpoint, at the end: nothing left to render.
    monkeypatch.setattr(checkpoints._Checkpoint, "set_events_done", done)
    renders = _Renders(monkeypatch)
    result = _simulate(out, resume=True)
    assert renders.frames == renders.events == 0
    assert not partial.exists()
    assert (result.n_events, result.event_renders) == (reference.n_events,
                                                       reference.event_renders)
    _assert_same_sequence(reference.out, out)


@pytest.mark.parametrize("edge_spp", [0, 16])
def test_an_interrupted_per_pixel_run_resumes_to_the_uninterrupted_files(tmp_path, monkeypatch,
                                                                          edge_spp):
    """The per-pixel sampler, realistic sensor: stopped after some blocks, resumed from its
    last checkpoint (a block end), and equal byte for byte to one run and to a second one;
    with the strips' edges at 16 samples per pixel too (``edge_spp``: which pixels a block
    renders fine depends on its boundaries' times only)."""
    scene = parse_scene(TEXT)
    scene = replace(scene, render=replace(scene.render, edge_spp=edge_spp))
    events = EventParams.preset("realistic", seed=scene.seed)

    def run(out, resume=False):
        return simulate(scene, out, progress=False, events=events, resume=resume,
                        sampler="pixel")

    whole = run(tmp_path / "whole")
    run(tmp_path / "again")
    assert whole.sampler == "pixel" and whole.n_events > 5000
    record = json.loads((tmp_path / "whole" / "sequence.json").read_text())["events"]
    assert record["edge_spp"] == edge_spp and (record["edge_samples"] > 0) == (edge_spp > 0)
    _assert_same_sequence(tmp_path / "whole", tmp_path / "again")          # deterministic
    out = tmp_path / "cut"
    with interrupted_pixel_blocks(monkeypatch, 7, every=3) as seen, \
            pytest.raises(KeyboardInterrupt):
        run(out)
    with np.load(tmp_path / "cut.partial" / ".checkpoint" / "events.npz") as saved:
        state = json.loads(str(saved["state"]))
        assert saved["observed_rates"].shape == (48 * 64,)
    assert state["sample"]["t"] == pytest.approx(seen[5])                 # blocks 3 and 6
    result = run(out, resume=True)
    assert result.n_events == whole.n_events
    _assert_same_sequence(tmp_path / "whole", out)


def test_an_interrupted_frame_sampler_run_with_edges_resumes_to_the_same_files(tmp_path,
                                                                              monkeypatch):
    """The frame sampler with the strips' edges at 16 samples per pixel (``edge_spp``: which
    pixels of a frame are rendered fine depends on its time only), stopped in the events after
    50 samples and resumed from its last checkpoint: byte for byte the uninterrupted run,
    its count of edge renders included. (A third of the strips' pixels are edges: the frame
    sampler renders 2.5 times as many frames as without, at 3 times the cost each, so 0.012 s
    of them.)"""
    scene = parse_scene(TEXT)
    scene = replace(scene, render=replace(scene.render, edge_spp=16))
    events = EventParams.preset("realistic", seed=scene.seed)

    def run(out, resume=False):
        return simulate(scene, out, progress=False, events=events, resume=resume,
                        sampler="frame", motion_truth=False, duration=0.012)

    whole = run(tmp_path / "whole")
    record = json.loads((tmp_path / "whole" / "sequence.json").read_text())["events"]
    assert record["edge_spp"] == 16 and record["edge_samples"] > 1000
    monkeypatch.setattr(checkpoints, "CHECKPOINT_SAMPLES", 1)   # at every boundary allowed
    seen = []

    def interrupting(*args, **kwargs):
        for sample in _REAL_SAMPLES(*args, **kwargs):
            if len(seen) > 50 and not seen[-1].tail_pending:
                raise KeyboardInterrupt
            seen.append(sample)
            yield sample

    monkeypatch.setattr(event_driver, "adaptive_samples", interrupting)
    out = tmp_path / "cut"
    with pytest.raises(KeyboardInterrupt):
        run(out)
    with np.load(tmp_path / "cut.partial" / ".checkpoint" / "events.npz") as saved:
        state = json.loads(str(saved["state"]))
    assert 0 < state["stats"]["edge_samples"] < record["edge_samples"]
    monkeypatch.setattr(event_driver, "adaptive_samples", _REAL_SAMPLES)
    result = run(out, resume=True)
    assert result.n_events == whole.n_events
    _assert_same_sequence(tmp_path / "whole", out)


def test_a_resume_after_the_event_stage_only_writes_the_indexes(full, tmp_path, monkeypatch):
    reference, _ = full
    out = tmp_path / "seq"
    monkeypatch.setattr(simulation, "write_sequence_json", _raise_interrupt)
    with pytest.raises(KeyboardInterrupt):
        _simulate(out)
    monkeypatch.undo()
    renders = _Renders(monkeypatch)
    _simulate(out, resume=True)
    assert renders.frames == renders.events == 0
    _assert_same_sequence(reference.out, out)


def _raise_interrupt(*args, **kwargs):
    raise KeyboardInterrupt


def test_resume_refuses_what_it_cannot_continue(full, tmp_path, monkeypatch):
    reference, _ = full
    with pytest.raises(ValueError,
                       match=r"no interrupted run .* run without resume=True to start one$"):
        _simulate(tmp_path / "none", resume=True)
    with pytest.raises(ValueError, match="is already complete; there is nothing to resume"):
        _simulate(reference.out, resume=True)
    out = tmp_path / "seq"
    _Renders(monkeypatch, stop=1)
    with pytest.raises(KeyboardInterrupt):
        _simulate(out)
    monkeypatch.undo()
    with pytest.raises(ValueError, match=r"other inputs: .*seed \(3 in the checkpoint, 9 now\)"
                                         r".*\(or run without resume=True to start again\)$"):
        _simulate(out, resume=True, scene_seed=9)
    (tmp_path / "seq.partial" / ".checkpoint" / "checkpoint.json").unlink()
    with pytest.raises(ValueError,
                       match="holds no checkpoint .* run without resume=True to start again$"):
        _simulate(out, resume=True)
    assert (tmp_path / "seq.partial").is_dir()        # refused: left as it was


def test_cli_resume(tmp_path, capsys, monkeypatch):
    scene_file = tmp_path / "checker.toml"
    scene_file.write_text(TEXT)
    out = tmp_path / "cli"
    args = ["simulate", str(scene_file), "--out", str(out), "--duration", "0.06", "--quiet"]
    assert main([*args, "--resume"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "run without --resume" in err
    _Renders(monkeypatch, stop=3)
    assert main(args) == 130
    err = capsys.readouterr().err
    assert err == "evfuse simulate: interrupted; resume with the same command plus --resume\n"
    monkeypatch.undo()
    assert main([*args, "--seed", "9", "--resume"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "seed (3 in the checkpoint, 9 now)" in err
    assert err.endswith("(or run without --resume to start again)\n")
    assert main([*args, "--resume"]) == 0
    assert f"to {out}" in capsys.readouterr().out
    assert json.loads((out / "sequence.json").read_text())["frames"]["count"] == 2
    assert main([*args, "--resume"]) == 2
    assert "already complete" in capsys.readouterr().err


def test_cli_sigterm_is_an_interruption_that_resumes_to_the_same_files(tmp_path, capsys,
                                                                      monkeypatch):
    scene_file = tmp_path / "checker.toml"
    scene_file.write_text(TEXT)
    args = ["simulate", str(scene_file), "--duration", "0.06", "--quiet", "--out"]
    assert main([*args, str(tmp_path / "whole")]) == 0
    calls = []

    def terminated_at_the_third_render(real):
        def render(shader, t, *args):
            calls.append(t)
            if len(calls) == 3:
                os.kill(os.getpid(), signal.SIGTERM)  # as `kill PID` or a scheduler would
            return real(shader, t, *args)
        return render

    # The frames' renders: auto-exposure's look at frame 0, then frame 0's and 1's exposures.
    monkeypatch.setattr(FrameShader, "still", terminated_at_the_third_render(_REAL_STILL))
    monkeypatch.setattr(FrameShader, "exposure",
                        terminated_at_the_third_render(_REAL_EXPOSURE))
    before = signal.getsignal(signal.SIGTERM)
    out = tmp_path / "cut"
    capsys.readouterr()
    assert main([*args, str(out)]) == 143
    assert capsys.readouterr().err == ("evfuse simulate: terminated; resume with the same "
                                       "command plus --resume\n")
    assert len(calls) == 3 and not out.exists() and (tmp_path / "cut.partial").is_dir()
    assert signal.getsignal(signal.SIGTERM) is before          # the handler was put back
    monkeypatch.undo()
    assert main([*args, str(out), "--resume"]) == 0
    _assert_same_sequence(tmp_path / "whole", out)


@pytest.mark.parametrize("signal_name, status", [("SIGINT", 130), ("SIGTERM", 143)])
def test_an_interruption_inside_the_renderer_is_still_an_interruption(tmp_path, capsys,
                                                                      monkeypatch, signal_name,
                                                                      status):
    """Ctrl-C or SIGTERM inside Mitsuba's render reaches us wrapped in Dr.Jit's RuntimeError."""
    scene_file = tmp_path / "checker.toml"
    scene_file.write_text(TEXT)
    signum = getattr(signal, signal_name)
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)

    def render_op_with_a_signal(shader, t):
        try:
            os.kill(os.getpid(), signum)
            raise AssertionError("the signal handler did not raise")
        except KeyboardInterrupt as exc:
            raise RuntimeError("drjit.custom(<mitsuba.python.util._RenderOp>): error while "
                               "performing a custom differentiable operation.") from exc

    monkeypatch.setattr(FrameShader, "still", render_op_with_a_signal)   # frame 0's first
    try:
        code = main(["simulate", str(scene_file), "--duration", "0.06", "--quiet", "--out",
                     str(tmp_path / "cut")])
    finally:
        signal.signal(signal.SIGINT, previous)
    word = "terminated" if signal_name == "SIGTERM" else "interrupted"
    assert (code, capsys.readouterr().err) == (
        status, f"evfuse simulate: {word}; resume with the same command plus --resume\n")
    assert (tmp_path / "cut.partial" / ".checkpoint").is_dir()


# --- the pieces ------------------------------------------------------------------------------

class _StaticView:
    """A static camera whose pixels step at known times: every split keeps both halves."""

    def __init__(self) -> None:
        self.camera = Camera(8, 6, 10.0, 10.0, 3.5, 2.5)
        self.scene = self
        self.trajectory = self
        self.steps = np.random.default_rng(0).uniform(0.0, 0.1, (6, 8))

    def camera_velocity(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        return np.zeros(3), np.zeros(3)                # predicted flow 0: 100 Hz

    def depth(self, t: float) -> np.ndarray:
        return np.ones((6, 8), np.float32)

    def luminance(self, t: float) -> np.ndarray:
        return np.where(self.steps <= t, 1.0, 0.2).astype(np.float32)


def test_sampling_continues_after_any_sample_without_a_pending_tail():
    view = _StaticView()
    stats = SamplingStats()
    samples, counts = [], []
    for sample in adaptive_samples(view, 0.0, 0.1, 0.2, 1e-3, stats=stats):
        samples.append(sample)
        counts.append(asdict(stats))
    assert sum(s.tail_pending for s in samples) == stats.steps >= 5
    for k, after in enumerate(samples):
        if after.tail_pending:
            with pytest.raises(ValueError, match="pending"):
                next(adaptive_samples(view, 0.0, 0.1, 0.2, 1e-3, after=after))
            continue
        restored = SamplingStats(**counts[k])
        rest = list(adaptive_samples(view, 0.0, 0.1, 0.2, 1e-3, stats=restored, after=after))
        assert [s.t for s in rest] == [s.t for s in samples[k + 1:]]
        assert [s.tail_pending for s in rest] == [s.tail_pending for s in samples[k + 1:]]
        assert restored == stats


def test_emulator_state_continues_the_same_events():
    rng = np.random.default_rng(1)
    frames = np.log(rng.uniform(0.05, 2.0, (12, 20, 30)))
    times = np.linspace(0.0, 0.011, 12)
    emulator = EventEmulator((20, 30), EVENTS)
    emulator.start(frames[0], times[0])
    for k in range(1, 6):
        emulator.advance(frames[k], times[k])
    state = emulator.get_state()
    plain = {k: v for k, v in state.items() if not isinstance(v, np.ndarray)}
    assert json.loads(json.dumps(plain)) == plain     # what is not an array goes to JSON
    rest = [emulator.advance(frames[k], times[k]) for k in range(6, 12)]
    assert sum(len(c) for c in rest) > 100
    again = EventEmulator((20, 30), EVENTS)
    again.set_state(state)
    for k, chunk in zip(range(6, 12), rest, strict=True):
        np.testing.assert_array_equal(again.advance(frames[k], times[k]), chunk)
    with pytest.raises(ValueError, match=r"ref has shape \(2, 2\); expected the sensor's"):
        again.set_state({**state, "ref": np.zeros((2, 2))})
    with pytest.raises(ValueError, match="lacks level"):
        again.set_state({key: v for key, v in state.items() if key != "level"})


def _stream(count: int) -> np.ndarray:
    rng = np.random.default_rng(2)
    t = np.sort(rng.integers(1_000, 40_000_000, count))
    return make_events(t, rng.integers(0, 30, count), rng.integers(0, 20, count),
                       rng.choice([-1, 1], count))


@pytest.mark.parametrize("closed", [False, True], ids=["interrupted", "closed"])
def test_writers_resume_from_a_checkpoint(tmp_path, closed):
    events = _stream(3000)
    parts = (events[:700], events[700:1500], events[1500:])
    whole = {"h5": tmp_path / "whole.h5", "txt": tmp_path / "whole.txt"}
    with H5EventWriter(whole["h5"], 30, 20, chunk_size=64) as h5, \
            TextEventWriter(whole["txt"]) as txt:
        for writer in (h5, txt):
            writer.write(events)
    paths = {"h5": tmp_path / "events.h5", "txt": tmp_path / "events.txt"}

    def open_writers(resume):
        return {"h5": H5EventWriter(paths["h5"], 30, 20, chunk_size=64,
                                    resume=resume and resume["h5"]),
                "txt": TextEventWriter(paths["txt"], resume=resume and resume["txt"])}

    writers = open_writers(None)
    for writer in writers.values():
        writer.write(parts[0])
    saved = {fmt: writer.checkpoint() for fmt, writer in writers.items()}
    assert saved["txt"]["count"] == 700 and saved["h5"]["stored"] == 700
    for writer in writers.values():
        writer.write(parts[1][:300])                  # after the checkpoint: to be cut off
        if closed:
            writer.close()
        else:
            writer.__exit__(KeyboardInterrupt, KeyboardInterrupt(), None)
    assert paths["h5"].is_file() == closed
    writers = open_writers(saved)
    for writer in writers.values():
        writer.write(parts[1])
        writer.write(parts[2])
        writer.close()
    assert paths["txt"].read_bytes() == whole["txt"].read_bytes()
    assert paths["h5"].read_bytes() == whole["h5"].read_bytes()    # packed: layout from data
    np.testing.assert_array_equal(read_events(paths["h5"]), events)
    # Resumed and closed at once: the files hold exactly what the checkpoint counted.
    first = {"h5": tmp_path / "first.h5", "txt": tmp_path / "first.txt"}
    with H5EventWriter(first["h5"], 30, 20, chunk_size=64) as h5, \
            TextEventWriter(first["txt"]) as txt:
        for writer in (h5, txt):
            writer.write(parts[0])
    for writer in open_writers(saved).values():
        writer.close()
    for fmt in ("txt", "h5"):
        assert paths[fmt].read_bytes() == first[fmt].read_bytes(), fmt
    paths["txt"].write_bytes(b"")
    with pytest.raises(ValueError, match=r"holds 0 bytes, fewer than the \d+ the checkpoint"):
        TextEventWriter(paths["txt"], resume=saved["txt"])
    with pytest.raises(ValueError, match="checkpoint\\(\\) of a h5 event writer"):
        H5EventWriter(paths["h5"], 30, 20, resume=saved["txt"])


def test_an_hdf5_chunk_damaged_by_a_kill_is_refused_in_one_line(tmp_path):
    """A kill inside an HDF5 write can leave the chunk a checkpoint ends in half-written (its
    compressed bytes garbled): resuming it is refused at once, naming the file and the dataset,
    instead of failing at the next write with HDF5's "filter returned failure during read"."""
    import h5py

    events = _stream(3000)
    path = tmp_path / "events.h5"
    writer = H5EventWriter(path, 30, 20, chunk_size=64)
    writer.write(events[:700])
    saved = writer.checkpoint()
    writer.write(events[700:1000])
    writer._file.close()                                 # the process is gone
    partial = writer.partial
    with h5py.File(partial, "r") as file:                # the chunk holding event 699
        info = file["events/t"].id.get_chunk_info_by_coord((699 // 64 * 64,))
    with open(partial, "r+b") as raw:
        raw.seek(info.byte_offset)
        raw.write(b"\xff" * info.size)
    with pytest.raises(ValueError) as caught:
        H5EventWriter(path, 30, 20, chunk_size=64, resume=saved)
    message = str(caught.value)
    assert "\n" not in message and str(partial) in message
    assert "/events/t is damaged where the checkpoint ends" in message
    assert "simulate again from the start" in message
