"""Run a benchmark command and record how the results it wrote were made.

``python -m benchmarks.record -- python -m benchmarks.bench_render --frames 10`` runs the command
(``python`` is this interpreter), then, for every ``benchmarks/results/*.json`` the run created
or changed, writes an entry into ``benchmarks/results/provenance.json``: the command, the date,
its wall seconds and exit status, the commit and whether the tree had uncommitted changes, the
machine's cores and load average when it started, and the file's SHA-256.
:mod:`benchmarks.report` shows an entry beside its file only while the hash still matches, so a
file written later by another command (``make bench``) is never shown with a stale record.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import platform
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
RESULTS = ROOT / "benchmarks" / "results"
PROVENANCE = "provenance.json"
"""The record's file name in the results folder (read by :mod:`benchmarks.report`)."""

__all__ = ["PROVENANCE", "file_hash", "main"]


def file_hash(path: Path) -> str:
    """SHA-256 of a file's bytes, hex."""
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def _hashes(folder: Path) -> dict[str, str]:
    return {p.name: file_hash(p) for p in sorted(folder.glob("*.json")) if p.name != PROVENANCE}


def _git(*args: str) -> str | None:
    try:
        done = subprocess.run(["git", *args], cwd=ROOT, capture_output=True, text=True,
                              check=True)
    except (OSError, subprocess.CalledProcessError):
        return None
    return done.stdout.strip()


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--results", type=Path, default=RESULTS,
                        help="results folder to watch (default benchmarks/results)")
    parser.add_argument("command", nargs=argparse.REMAINDER,
                        help="the command, after '--' (python: this interpreter)")
    args = parser.parse_args(argv)
    command = args.command[1:] if args.command[:1] == ["--"] else args.command
    if not command:
        parser.error("expected a command after '--', e.g. -- python -m benchmarks.bench_render")
    folder = args.results
    folder.mkdir(parents=True, exist_ok=True)
    before = _hashes(folder)
    load = os.getloadavg()
    date = time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())
    status = _git("status", "--porcelain")
    tick = time.perf_counter()
    run = [sys.executable if command[0] == "python" else command[0], *command[1:]]
    rc = subprocess.run(run, cwd=ROOT).returncode
    wall = time.perf_counter() - tick
    after = _hashes(folder)
    changed = [name for name, digest in after.items() if before.get(name) != digest]
    path = folder / PROVENANCE
    record = json.loads(path.read_text()) if path.is_file() else {}
    for name in changed:
        record[name] = {"command": " ".join(command), "date": date, "wall_s": round(wall, 1),
                        "exit_status": rc, "commit": _git("rev-parse", "--short", "HEAD"),
                        "uncommitted_changes": bool(status) if status is not None else None,
                        "cores": os.cpu_count(), "machine": platform.machine(),
                        "load_average_at_start": [round(v, 2) for v in load],
                        "sha256": after[name]}
    path.write_text(json.dumps(dict(sorted(record.items())), indent=2) + "\n")
    print(f"\n{' '.join(command)}: exit {rc}, {wall:.0f} s; recorded "
          f"{', '.join(changed) or 'no changed results'} in {path}", file=sys.stderr)
    return rc


if __name__ == "__main__":
    sys.exit(main())
