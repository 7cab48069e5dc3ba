"""The Makefile's LLVM probe agrees with evfuse's own (sim/variant.py) and never re-installs."""

from __future__ import annotations

import os
import shutil
import subprocess
from pathlib import Path

import pytest

from sim import variant

ROOT = Path(__file__).resolve().parents[1]

pytestmark = pytest.mark.skipif(shutil.which("make") is None, reason="no make on this machine")


def _make_llvm(tmp_path: Path, *args: str) -> tuple[str, list[str]]:
    """``make llvm`` with ``apt-get`` and ``sudo`` replaced by stubs that log their call and
    fail (nothing is installed); returns its output and the stubs' calls."""
    stubs = tmp_path / "bin"
    stubs.mkdir(exist_ok=True)
    log = tmp_path / "calls.log"
    for name in ("apt-get", "sudo"):
        stub = stubs / name
        stub.write_text(f'#!/bin/sh\necho "{name} $*" >> "{log}"\nexit 1\n')
        stub.chmod(0o755)
    env = {k: v for k, v in os.environ.items() if k not in ("DRJIT_LIBLLVM_PATH", "MAKEFLAGS")}
    env["PATH"] = f"{stubs}{os.pathsep}{env.get('PATH', '')}"
    done = subprocess.run(["make", "--no-print-directory", "-s", "llvm", *args], cwd=ROOT,
                          env=env, capture_output=True, text=True, timeout=60, check=False)
    assert done.returncode == 0, done.stderr
    calls = log.read_text().splitlines() if log.exists() else []
    return done.stdout + done.stderr, calls


def test_make_llvm_finds_the_llvm_that_evfuse_finds(tmp_path, monkeypatch):
    monkeypatch.delenv("DRJIT_LIBLLVM_PATH", raising=False)
    libraries = variant.find_llvm_libraries()
    if not libraries:
        pytest.skip("no LLVM >= 16 on this machine: see the next test")
    output, calls = _make_llvm(tmp_path)
    assert "LLVM >= 16 present" in output and libraries[0].path in output, output
    assert calls == []                     # found: apt-get is not run again
    assert "scalar_rgb" not in output


def test_make_llvm_without_llvm_installs_or_says_how(tmp_path):
    fake = tmp_path / "python"             # a probe that finds nothing
    fake.write_text("#!/bin/sh\nexit 1\n")
    fake.chmod(0o755)
    output, calls = _make_llvm(tmp_path, f"PYTHON={fake}")
    assert "present" not in output
    if os.geteuid() == 0:
        assert calls and calls[0].startswith("apt-get install") and "libllvm19" in calls[0]
        assert "could not install libllvm19" in output       # the stub failed
    else:
        assert "libllvm19" in output and "scalar_rgb" in output


def test_the_probe_script_exits_1_when_no_llvm_is_found(monkeypatch, capsys):
    monkeypatch.setattr(variant, "find_llvm_libraries", lambda: [])
    assert variant._main(["--find-llvm"]) == 1
    monkeypatch.setattr(variant, "find_llvm_libraries",
                        lambda: [variant.LlvmLibrary("/usr/lib/llvm-19/lib/libLLVM.so", 19)])
    assert variant._main(["--find-llvm"]) == 0
    assert capsys.readouterr().out.strip() == "LLVM 19 at /usr/lib/llvm-19/lib/libLLVM.so"
    assert variant._main([]) == 2
