"""Choosing the Mitsuba variant: LLVM discovery, forcing, and refusal of old LLVMs."""

from __future__ import annotations

import subprocess
import sys

import pytest

from sim import variant as variant_module


@pytest.mark.parametrize("path, version", [
    ("/usr/lib/x86_64-linux-gnu/libLLVM-19.so", 19),
    ("/usr/lib/x86_64-linux-gnu/libLLVM.so.19.1", 19),
    ("/usr/lib/llvm-17/lib/libLLVM.so", 17),
    ("/opt/homebrew/opt/llvm/lib/libLLVM.dylib", None),
])
def test_llvm_version_is_read_from_the_name(path, version):
    assert variant_module._llvm_version(path) == version


def test_old_llvm_is_never_offered(monkeypatch):
    monkeypatch.delenv("DRJIT_LIBLLVM_PATH", raising=False)
    for lib in variant_module.find_llvm_libraries():
        assert lib.version is None or lib.version >= 16


def test_unknown_forced_variant_is_rejected():
    with pytest.raises(ValueError, match="expected one of"):
        variant_module._choose("llvm_ad_rgbx")


def _run(code: str, **env) -> subprocess.CompletedProcess:
    import os

    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          timeout=300, check=False, env={**os.environ, **env})


def test_forced_variant_is_used_and_announced_once():
    done = _run("from sim.variant import use_variant; print(use_variant()); print(use_variant())",
                EVFUSE_VARIANT="scalar_rgb")
    assert done.returncode == 0, done.stderr
    assert done.stdout.split() == ["scalar_rgb", "scalar_rgb"]
    assert done.stderr.count("scalar_rgb") == 1


def test_switching_variant_in_one_process_is_an_error():
    done = _run("from sim.variant import use_variant; use_variant('scalar_rgb');"
                "use_variant('llvm_ad_rgb')")
    assert done.returncode != 0 and "already active" in done.stderr


def test_without_usable_llvm_the_choice_falls_back_to_scalar(tmp_path):
    # An LLVM 15 is refused by its name; a broken library is refused by the probe.
    fake = tmp_path / "libLLVM-18.so"
    fake.write_bytes(b"not a library")
    code = ("import sim.variant as v; v.find_llvm_libraries = lambda: "
            f"[v.LlvmLibrary({str(fake)!r}, 18)]; v._cuda_driver_present = lambda: False;"
            "print(v.use_variant())")
    done = _run(code, XDG_CACHE_HOME=str(tmp_path / "cache"), EVFUSE_VARIANT="")
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == "scalar_rgb"
    assert "no working LLVM" in done.stderr and done.stderr.count("evfuse:") == 1
