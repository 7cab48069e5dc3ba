"""``--profile`` (:mod:`sim.profile`): each stage's Dr.Jit kernels are charged to the stage that
ran them, the profile's wall times are ``timings_s``'s, host + device is the wall on llvm, and the
scalar variant, an out-of-memory and a run without a simulation each say what they are."""

from __future__ import annotations

import json
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from sim.profile import (
    EVENT_CAMERA_STAGES,
    PROFILE_JSON,
    STAGES,
    profile_record,
    profile_table,
    profiles_summary,
    recording,
    stage,
)
from sim.sampling import SamplingParams
from sim.scene import parse_scene
from sim.simulate import simulate
from sim.simulate.memory import device_memory, is_out_of_memory
from sim.validation import ParameterError
from tests.conftest import scene_text
from tests.test_event_driver import CAMERA, FRAMES  # 48x36, one-sample frames
from tests.test_simulate import OBJECTS  # the textured poster

ROOT = Path(__file__).resolve().parent.parent
TURNING = ('[trajectory]\ntype = "linear"\nposition = [0.0, 0.0, 0.0]\n'
           "velocity = [0.6, 0.0, 0.2]\nlook_at = [0.3, 1.0, 0.1]\n")
OOM = "jit_malloc(): out of memory! Could not allocate 2147483648 bytes of device memory."


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    path = tmp_path_factory.mktemp("scene") / "small.toml"
    path.write_text(scene_text(OBJECTS, camera=CAMERA, trajectory=TURNING, duration=0.3,
                               extra=FRAMES))
    return parse_scene(path.read_text(), path)


def _heavy(n: int):
    """A Dr.Jit kernel of ``n`` lanes, evaluated (queued: Dr.Jit runs it asynchronously)."""
    import drjit as dr
    from drjit.llvm import Float

    x = dr.arange(Float, n) * 1e-6
    y = dr.sin(x) * dr.cos(x) + dr.sqrt(x + 1.0)
    dr.eval(y)
    return y


def test_kernels_are_charged_to_the_stage_that_ran_them():
    pytest.importorskip("drjit")
    with recording() as ledger:
        with stage("host"):
            time.sleep(0.02)                            # Python only: no kernel
        with stage("outer"):
            _heavy(200_000)                             # the outer stage's own kernel
            with stage("inner"):
                _heavy(300_000)                         # queued here, finished by the mark
                _heavy(400_000)
            _heavy(500_000)                             # the outer stage's again
    stages = ledger.stages
    assert "host" not in stages
    assert stages["inner"].kernels == 2 and stages["outer"].kernels == 2
    assert stages["inner"].device_s > 0 and stages["outer"].device_s > 0
    total = ledger.total()
    assert total.kernels == 4
    assert total.device_s == pytest.approx(stages["inner"].device_s + stages["outer"].device_s)


def test_without_a_ledger_stages_cost_nothing_and_record_nothing():
    with stage("anything"):
        pass                                           # no ledger active: a no-op
    with recording(False) as ledger:
        assert ledger is None


def _profiled(scene, folder: Path, **options):
    result = simulate(scene, folder, start=0.05, duration=0.1, progress=False, profile=True,
                      **options)
    written = json.loads((folder / PROFILE_JSON).read_text())
    timings = json.loads((folder / "sequence.json").read_text())["timings_s"]
    return result, written, timings


def test_host_plus_device_is_the_wall_of_each_stage_on_llvm(scene, tmp_path):
    """On llvm every stage's kernels ran inside it: device <= wall, host = wall - device within
    5 % of the wall; the walls are timings_s's; the event camera sums its three stages."""
    result, written, timings = _profiled(scene, tmp_path / "run", sampler="pixel")
    if result.variant == "scalar_rgb":
        pytest.skip("needs a JIT variant")
    assert written == json.loads(json.dumps(result.profile))        # what the call returned
    assert written["device_time_measured"] and written["variant"] == result.variant
    assert written["simulated_s"] == pytest.approx(0.1)
    stages = written["stages"]
    for name, record in stages.items():
        wall, device, host = record["wall_s"], record["device_s"], record["host_s"]
        if name in timings:
            assert wall == pytest.approx(timings[name], abs=1e-3), name
        assert 0.0 <= device <= wall * 1.05 + 2e-3, name    # its kernels ran within it
        assert host + device == pytest.approx(wall, rel=0.05, abs=1e-3), name
    assert stages["event_render"]["launches"] > 0 and stages["event_render"]["device_s"] > 0
    camera = written["event_camera"]
    assert camera["wall_s"] == pytest.approx(
        sum(stages[name]["wall_s"] for name in EVENT_CAMERA_STAGES), abs=2e-3)
    assert camera["device_s"] == pytest.approx(
        sum(stages[name]["device_s"] for name in EVENT_CAMERA_STAGES), abs=1e-3)
    assert camera["host_s"] + camera["device_s"] == pytest.approx(camera["wall_s"], rel=0.05)
    assert camera["per_simulated_s"]["wall_s"] == pytest.approx(camera["wall_s"] / 0.1,
                                                                rel=1e-2)
    device_total = sum(r["device_s"] for r in stages.values())
    assert written["total"]["device_s"] == pytest.approx(device_total, abs=2e-3)
    assert written["total"]["device_s"] <= written["total"]["wall_s"]
    table = profile_table(written)
    assert "event camera" in table and "per simulated second" in table
    rows = [line.split()[0] for line in table.splitlines()[3:] if line[:1].isalpha()]
    listed = [name for name in rows if name in STAGES]
    assert listed == sorted(listed, key=STAGES.index)               # in the order they run


def test_a_profiled_run_writes_the_same_sequence(scene, tmp_path):
    """The profile only observes: the events and sequence.json (timings aside) are those of an
    unprofiled run, and nothing but profile.json is added."""
    _profiled(scene, tmp_path / "profiled", sampler="pixel")
    simulate(scene, tmp_path / "plain", start=0.05, duration=0.1, progress=False,
             sampler="pixel")
    names = {p.relative_to(tmp_path / "profiled").as_posix()
             for p in (tmp_path / "profiled").rglob("*") if p.is_file()}
    plain = {p.relative_to(tmp_path / "plain").as_posix()
             for p in (tmp_path / "plain").rglob("*") if p.is_file()}
    assert names - plain == {PROFILE_JSON} and plain <= names
    for name in ("events.txt", "groundtruth.txt", "calib.txt"):
        assert (tmp_path / "profiled" / name).read_bytes() == (tmp_path / "plain" / name
                                                               ).read_bytes()


def test_on_scalar_rgb_the_profile_has_wall_times_only():
    record = profile_record({"setup": 0.5, "render": 1.25, "event_render": 2.0, "total": 4.0},
                            None, "scalar_rgb", 0.5)
    assert record["device_time_measured"] is False
    assert "not measured on scalar_rgb" in record["note"]
    assert record["stages"]["render"] == {
        "wall_s": 1.25, "device_s": None, "host_s": None, "launches": None, "kernels": None,
        "compile_s": None, "copies": None, "copy_bytes": None}
    assert record["event_camera"]["wall_s"] == 2.0
    assert record["event_camera"]["per_simulated_s"] == {"wall_s": 4.0, "device_s": None,
                                                          "host_s": None}
    table = profile_table(record)
    assert "not measured on scalar_rgb" in table and " - " in table


def test_a_scalar_run_writes_its_wall_times(scene, tmp_path):
    """scalar_rgb runs no Dr.Jit kernels: the command says so and writes the wall times (in a
    process of its own: a process keeps its first variant)."""
    out = tmp_path / "scalar"
    done = _cli("simulate", str(scene.source), "--out", str(out), "--start", "0.05",
                "--duration", "0.1", "--no-events", "--no-motion-truth", "--quiet",
                "--variant", "scalar_rgb", "--profile")
    assert done.returncode == 0, done.stderr
    assert "device time is not measured on scalar_rgb" in done.stdout
    written = json.loads((out / PROFILE_JSON).read_text())
    assert written["variant"] == "scalar_rgb" and written["device_time_measured"] is False
    assert written["stages"]["render"]["wall_s"] > 0
    assert written["stages"]["render"]["device_s"] is None


def test_many_jobs_profiles_are_summed(tmp_path):
    records = []
    for i, (wall, device) in enumerate(((1.0, 0.25), (3.0, 1.75))):
        record = profile_record({"event_render": wall, "total": wall + 1}, None, "llvm_ad_rgb",
                                0.5)
        record["device_time_measured"] = True
        record["event_camera"].update(device_s=device, launches=10)
        path = tmp_path / f"{i}.json"
        path.write_text(json.dumps(record))
        records.append(path)
    line = profiles_summary(records)
    assert "2 jobs" in line and "1 s simulated in 4.00 s" in line
    assert "device 2.000 s, host 2.000 s per simulated second" in line and "20 launches" in line


def test_out_of_memory_is_recognised_through_its_chain():
    try:
        try:
            raise RuntimeError(OOM)
        except RuntimeError as cause:
            raise RuntimeError("dr.while_loop(): encountered an exception") from cause
    except RuntimeError as error:
        assert is_out_of_memory(error)
    assert is_out_of_memory(MemoryError())
    assert not is_out_of_memory(RuntimeError("jit_var_new(): invalid index"))


def test_other_errors_pass_through_device_memory(scene):
    with pytest.raises(KeyError, match="x"):
        with device_memory(scene, None, "pixel"):
            raise KeyError("x")


def test_an_out_of_memory_names_the_resolution_and_block_and_what_to_lower(scene, tmp_path,
                                                                          monkeypatch):
    from sim.shader import EventShader

    def no_memory(self, *args, **kwargs):
        raise RuntimeError(OOM)

    monkeypatch.setattr(EventShader, "luminance", no_memory)
    with pytest.raises(ParameterError) as caught:
        simulate(scene, tmp_path / "oom", start=0.05, duration=0.1, progress=False,
                 sampler="pixel")
    message = caught.value.rephrase({"spp": "--spp", "min_rate": "--min-rate"})
    assert "\n" not in message
    assert "ran out of memory" in message and "48x36 sensor" in message
    assert "blocks of 10 ms" in message and "--min-rate" in message and "--spp" in message
    assert "jit_malloc(): out of memory!" in message
    assert not (tmp_path / "oom").exists()                 # nothing that looks complete
    # Passes of several blocks: the pass is named, and fewer blocks a pass suggested.
    with pytest.raises(ParameterError) as caught:
        simulate(scene, tmp_path / "oom4", start=0.05, duration=0.1, progress=False,
                 sampler="pixel", sampling=SamplingParams(wavefront=4))
    message = caught.value.rephrase({"wavefront": "--wavefront", "min_rate": "--min-rate"})
    assert "a pass of 4 blocks" in message and "lower --wavefront" in message
    assert "\n" not in message and not (tmp_path / "oom4").exists()


def _cli(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "fusion.cli", *args], capture_output=True,
                          text=True, cwd=ROOT, timeout=300)


def test_the_command_line_prints_the_table_and_where_it_wrote_it(scene, tmp_path):
    out = tmp_path / "cli"
    done = _cli("simulate", str(scene.source), "--out", str(out), "--start", "0.05",
                "--duration", "0.1", "--sampler", "pixel", "--no-motion-truth", "--quiet",
                "--profile")
    assert done.returncode == 0, done.stderr
    assert "event camera" in done.stdout
    assert f"profile written to {out / PROFILE_JSON}" in done.stdout
    assert json.loads((out / PROFILE_JSON).read_text())["simulated_s"] == pytest.approx(0.1)


def test_run_refuses_to_profile_a_sequence_folder(tmp_path):
    folder = tmp_path / "seq"
    folder.mkdir()
    (folder / "calib.txt").write_text("40 40 24 18 0 0 0 0 0\n")
    (folder / "images.txt").write_text("")
    (folder / "groundtruth.txt").write_text("")
    (folder / "events.txt").write_text("")
    done = _cli("run", str(folder), "--out", str(tmp_path / "out"), "--profile")
    assert done.returncode != 0
    line = done.stderr.strip().splitlines()[-1]
    assert "--profile" in line and "sequence folder, nothing is simulated" in line
    assert not (tmp_path / "out").exists()


def test_profile_figures_are_finite(scene, tmp_path):
    _, written, _ = _profiled(scene, tmp_path / "frame", sampler="frame")
    values = [v for r in written["stages"].values() for k, v in r.items()
              if k.endswith("_s") and v is not None]
    assert values and np.all(np.isfinite(values))


def test_generate_profiles_every_job_without_changing_its_hash(tmp_path):
    """``generate --profile``: each job gets profile.json; the manifest's output_hash (which
    leaves profile.json out, as it does sequence.json's timings) is the unprofiled job's."""
    from sim.dataset import generate, read_manifest

    tiny = ROOT / "sweeps" / "tiny.toml"
    generate(tiny, tmp_path / "plain", workers=0, report=lambda line: None)
    generate(tiny, tmp_path / "profiled", workers=0, profile=True, report=lambda line: None)
    plain = {row["job_id"]: row["output_hash"] for row in read_manifest(tmp_path / "plain")}
    rows = read_manifest(tmp_path / "profiled")
    assert rows and {row["job_id"]: row["output_hash"] for row in rows} == plain
    profiles = sorted((tmp_path / "profiled" / "jobs").glob(f"*/{PROFILE_JSON}"))
    assert len(profiles) == len(rows)
    assert not list((tmp_path / "plain" / "jobs").glob(f"*/{PROFILE_JSON}"))
    assert f"{len(rows)} jobs' profile.json" in profiles_summary(profiles)
