"""The long fuzz run: every target of ``tests/fuzz_targets.py`` for thousands of cases.

The test suite runs each target for 200 cases (the ``ci`` profile, the same cases every run);
this runs each for ``--examples`` cases from a random (or given) seed, and prints a table of the
targets with the cases tried (every call of the property, shrinking included) and the distinct
failures Hypothesis found (one per exception type and place, each shrunk to a minimal case and
shown below the table). Written to ``benchmarks/results/fuzz.json``. Never fails a build: the
exit status is 1 when a failure was found, else 0.

Run: ``.venv/bin/python benchmarks/fuzz.py [--examples 5000] [--reaching-examples 500]
[--seed 21] [--only h5]``; the targets that run a simulation per accepted case
(``tests.fuzz_targets.REACHING``) take ``--reaching-examples``.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
import traceback
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))                   # tests.fuzz_targets, from a checkout

from hypothesis import HealthCheck, given, seed, settings  # noqa: E402

from tests.fuzz_targets import REACHING, TARGETS  # noqa: E402

RESULTS = ROOT / "benchmarks" / "results"


def run_target(name: str, examples: int, seed_value: int) -> dict:
    """Fuzz one target; its cases tried, distinct failures (shrunk) and seconds."""
    strategy, check = TARGETS[name]
    calls = 0

    def counted(case):
        nonlocal calls
        calls += 1
        check(case)

    test = seed(seed_value)(settings(
        max_examples=examples, deadline=None, database=None, derandomize=False,
        report_multiple_bugs=True, print_blob=True,
        suppress_health_check=list(HealthCheck))(given(strategy)(counted)))
    failures = []
    start = time.perf_counter()
    try:
        test()
    except BaseExceptionGroup as group:                # several distinct bugs
        failures = [_describe(exc) for exc in group.exceptions]
    except Exception as exc:                           # one
        failures = [_describe(exc)]
    return {"target": name, "cases": calls, "failures": failures,
            "seconds": round(time.perf_counter() - start, 1)}


def _describe(exc: BaseException) -> str:
    """An exception as one line: its type, message and the failing case Hypothesis noted."""
    notes = " ".join(" ".join(getattr(exc, "__notes__", [])).split())
    where = traceback.extract_tb(exc.__traceback__)[-1] if exc.__traceback__ else None
    place = f" at {Path(where.filename).name}:{where.lineno}" if where else ""
    message = " ".join(str(exc).split())[:300]
    return f"{type(exc).__name__}{place}: {message} [{notes[:300]}]"


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--examples", type=int, default=5000, help="cases per target")
    parser.add_argument("--reaching-examples", type=int, default=None,
                        help="cases per target that runs a simulation per accepted case "
                             "(tests.fuzz_targets.REACHING; default: --examples)")
    parser.add_argument("--seed", type=int, default=21, help="Hypothesis seed")
    parser.add_argument("--only", default=None, help="only targets whose name contains this")
    parser.add_argument("--out", default=str(RESULTS / "fuzz.json"), help="JSON to write")
    args = parser.parse_args()
    names = [n for n in TARGETS if args.only is None or args.only in n]
    rows = []
    for name in names:
        examples = args.examples
        if name in REACHING and args.reaching_examples is not None:
            examples = args.reaching_examples
        row = run_target(name, examples, args.seed)
        row["examples"] = examples
        rows.append(row)
        print(f"{name:<50} {row['cases']:>8} cases  {len(row['failures']):>2} failures  "
              f"{row['seconds']:>7.1f} s", flush=True)
    print("\n| target | cases tried | failures found | seconds |\n|---|---:|---:|---:|")
    for row in rows:
        print(f"| {row['target']} | {row['cases']:,} | {len(row['failures'])} | "
              f"{row['seconds']:.1f} |")
    for row in rows:
        for failure in row["failures"]:
            print(f"\n{row['target']}: {failure}")
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps({"examples_per_target": args.examples,
                               "examples_per_reaching_target": args.reaching_examples,
                               "seed": args.seed,
                               "targets": rows}, indent=2) + "\n")
    print(f"\nwritten to {out}")
    return 1 if any(row["failures"] for row in rows) else 0


if __name__ == "__main__":
    sys.exit(main())
