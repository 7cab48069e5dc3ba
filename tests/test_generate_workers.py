"""``evfuse generate`` on a GPU machine's terms (issue 36): the Dr.Jit kernel cache every worker
shares, and the cost table with its device row, read from the jobs' ``profile.json`` where
they have one, else from ``timings_s``. (The warm workers themselves run in
``tests/test_generate.py``, on a real local cluster.)"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from sim.dataset import cost_table, job_costs, kernel_cache_dir
from sim.variant import use_variant

TIMINGS = {"setup": 1.0, "imu": 0.5, "frame_setup": 0.25, "render": 2.0, "write": 0.75,
           "event_render": 3.0, "event_sample": 2.0, "emulate": 1.0, "emulate_compile": 0.5,
           "event_write": 0.25, "event_depth": 0.25, "checkpoint": 0.5}


def _job(folder: Path, variant: str, profile: dict | None = None, duration: float = 0.25
         ) -> Path:
    folder.mkdir(parents=True)
    (folder / "sequence.json").write_text(json.dumps(
        {"duration": duration, "render": {"variant": variant}, "timings_s": TIMINGS}))
    if profile is not None:
        (folder / "profile.json").write_text(json.dumps(profile))
    return folder


def _profile(device_s: float, variant: str = "cuda_ad_rgb", device: str = "NVIDIA H200"):
    stages = {name: {"wall_s": wall, "device_s": None, "launches": 0}
              for name, wall in TIMINGS.items()}
    stages["event_render"]["wall_s"] = 4.0                   # the profile's own wall figure
    return {"variant": variant, "device": device, "simulated_s": 0.25,
            "stages": stages,
            "event_camera": {"wall_s": 7.0, "device_s": device_s, "host_s": 7.0 - device_s,
                             "launches": 120}}


def test_a_jobs_costs_come_from_its_profile_else_from_its_timings(tmp_path):
    plain = job_costs(_job(tmp_path / "a", "llvm_ad_rgb"))
    assert plain["source"] == "timings_s" and plain["device_s"] is None
    assert plain["wall_s"]["event camera"] == 6.0                       # 3 + 2 + 1
    assert plain["wall_s"]["events, rest"] == 1.0 and plain["wall_s"]["checkpoints"] == 0.5
    assert plain["wall_s"]["frames"] == 3.0 and plain["wall_s"]["other"] == 1.5
    assert plain["wall_s"]["total"] == sum(TIMINGS.values())
    profiled = job_costs(_job(tmp_path / "b", "cuda_ad_rgb", _profile(2.5)))
    assert profiled["source"] == "profile.json"
    assert profiled["wall_s"]["event camera"] == 7.0                    # 4 + 2 + 1
    assert (profiled["device_s"], profiled["launches"]) == (2.5, 120)
    assert (profiled["variant"], profiled["device"]) == ("cuda_ad_rgb", "NVIDIA H200")


def test_the_cost_tables_device_row_names_the_gpu_and_its_seconds(tmp_path):
    jobs = [_job(tmp_path / f"j{k}", "cuda_ad_rgb", _profile(1.75)) for k in range(2)]
    table = cost_table(jobs)
    assert table.splitlines()[0].startswith("cost of 2 jobs (0.5 s simulated)")
    assert "from 2 profile.json and 0 timings_s" in table
    camera = next(line for line in table.splitlines() if "event camera" in line).split()
    assert camera[2:6] == ["14.00", "3.50", "10.50", "28.000"]      # wall, device, host, per s
    assert ("device: cuda_ad_rgb on NVIDIA H200: the GPU ran 3.50 s of the event camera's "
            "14.00 s (25%), 240 launches") in table


def test_without_profiles_the_device_row_says_what_rendered_and_that_it_is_unmeasured(
        tmp_path):
    jobs = [_job(tmp_path / "p", "llvm_ad_rgb", _profile(1.0, "llvm_ad_rgb", "")),
            _job(tmp_path / "t", "llvm_ad_rgb")]
    table = cost_table(jobs, {"Some CPU (2 cores)"})
    assert ("device: llvm_ad_rgb on Some CPU (2 cores): device seconds not measured "
            "(profile.json in 1 of 2 jobs; generate --profile writes them)") in table
    camera = next(line for line in table.splitlines() if "event camera" in line).split()
    assert camera[2] == "13.00" and len(camera) == 4                 # no device, no host
    assert cost_table([]) == "cost: no complete job"
    (tmp_path / "bad").mkdir()
    (tmp_path / "bad" / "sequence.json").write_text("{not json")
    assert cost_table([tmp_path / "bad"]) == ("cost: no complete job; left out, unreadable: "
                                              "bad (JSONDecodeError)")
    assert "left out, unreadable: bad" in cost_table([tmp_path / "t", tmp_path / "bad"])


def test_the_kernel_cache_is_drjits_own_folder(monkeypatch, tmp_path):
    monkeypatch.setenv("DRJIT_CACHE_DIR", str(tmp_path / "shared"))
    assert kernel_cache_dir() == tmp_path / "shared"
    monkeypatch.delenv("DRJIT_CACHE_DIR")
    monkeypatch.setenv("HOME", str(tmp_path))
    assert kernel_cache_dir() == tmp_path / ".drjit"


def test_drjit_puts_its_kernels_in_that_folder(tmp_path):
    """What :func:`kernel_cache_dir` says is where Dr.Jit (1.5) puts the kernels it compiles:
    a fresh process with ``DRJIT_CACHE_DIR`` set fills that folder, on this machine's backend,
    and a second one finds the kernel there (the folder does not grow)."""
    variant = use_variant()
    if variant == "scalar_rgb":
        pytest.skip("scalar_rgb compiles no kernels")
    backend = "cuda" if variant.startswith("cuda") else "llvm"
    folder = tmp_path / "cache"
    code = (f"import drjit as dr\nfrom drjit.{backend} import Float\n"
            "x = dr.arange(Float, 10) * 1.25 + 0.5\ndr.eval(x)\nprint(x[2])")
    kernels = []
    for _ in range(2):                  # a second process finds the first one's kernel
        done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                              env={**os.environ, "DRJIT_CACHE_DIR": str(folder)}, timeout=300)
        assert done.returncode == 0, done.stderr[-1000:]
        assert done.stdout.split()[-1] == "3.0"
        kernels.append(sorted(name for name in os.listdir(folder) if name.endswith(".bin")))
    assert kernels[0] and kernels[1] == kernels[0]
