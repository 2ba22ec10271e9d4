"""Longer fuzz run of the diffsurf readers, with the strategies of tests/test_fuzz_readers.py.

    PYTHONPATH=tests python benchmarks/fuzz_readers.py       # 3000 examples per target
    PYTHONPATH=tests python benchmarks/fuzz_readers.py --examples 20000 --target msh \
        --target ply-binary --save-dir /tmp/fuzz

(tests/ on the path: the strategies and the oracle are the tests' own.)

Every input must give a valid result or an io.ReadError with a one-line message naming the
file. Unlike the test, the run does not stop at the first bug: it collects every distinct bug
(by exception type and the reader's code location), keeps the shortest input of each, and
prints a summary: outcome counts per target, the most common ReadError messages, and the bugs.
Exit status 1 when a bug was found.
"""
from __future__ import annotations

import argparse
import collections
import logging
import re
import sys
import tempfile
import time
import traceback
from pathlib import Path

from hypothesis import HealthCheck, given, settings

import test_fuzz_readers as fz

#: csv: any outcome allowed but a crash; csv-rules: also the same points and text as the
#: documented rules in plain Python (str.strip, str.split, float()), bit for bit; the others
#: (the seeds of the mesh formats, tests/test_fuzz_readers.py TARGET_SEEDS): any outcome but
#: a crash or a read that does not end within fz.READ_SECONDS.
TARGETS = ["csv", "csv-rules", *fz.TARGET_SEEDS]


def _signature(exc: BaseException) -> str:
    """Exception type plus the innermost frame, so one bug is counted once."""
    cause = exc.__cause__ or exc
    frames = traceback.extract_tb(cause.__traceback__)
    where = f"{Path(frames[-1].filename).name}:{frames[-1].lineno}" if frames else "?"
    return f"{type(exc).__name__}: {str(exc).splitlines()[0][:120] if str(exc) else ''} @ {where}"


def _message_class(text: str) -> str:
    """A ReadError message with the file name, numbers and quoted text folded, for counting."""
    text = text.split(": ", 1)[-1]
    text = re.sub(r"'[^']*'", "'…'", text)
    return re.sub(r"\d+", "N", text)[:110]


def run(target: str, examples: int, workdir: str):
    outcomes = collections.Counter()
    messages = collections.Counter()
    bugs: dict[str, bytes] = {}
    strategy = {"csv": fz.CSV_INPUTS,
                "csv-rules": fz.st.one_of(fz.csv_of_numbers(), fz.CSV_INPUTS)}.get(target)
    strategy = strategy if strategy is not None else fz.target_inputs(target)

    def one(data: bytes) -> None:
        try:
            if target == "csv":
                outcome = fz.read_contactors_bytes(data, workdir)
            elif target == "csv-rules":
                outcome = fz.compare_with_reference(data, workdir)
            else:
                outcome = fz.read_target_bytes(target, data, workdir)
        except fz.Bug as exc:
            key = _signature(exc)
            if key not in bugs or len(data) < len(bugs[key]):
                bugs[key] = data
            outcomes["BUG"] += 1
            return
        outcomes[outcome] += 1
        if outcome == "error":
            messages[_message_class(_last_error[0])] += 1

    _last_error = [""]
    real_check = fz.check_read_error

    def spy(exc, path):
        _last_error[0] = str(exc)
        real_check(exc, path)

    fz.check_read_error = spy
    try:
        given(data=strategy)(settings(
            max_examples=examples, deadline=None, database=None,
            suppress_health_check=list(HealthCheck))(one))()
    finally:
        fz.check_read_error = real_check
    return outcomes, messages, bugs


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--examples", type=int, default=3000, help="examples per target")
    parser.add_argument("--target", choices=TARGETS, action="append",
                        help="fuzz only this reader input (repeatable; default all)")
    parser.add_argument("--save-dir", type=Path, default=None,
                        help="write the shortest input of each bug here")
    args = parser.parse_args(argv)
    # meshio's warnings about meshes it did read are logged by io; not wanted here
    logging.getLogger("diffsurf").setLevel(logging.ERROR)
    found = 0
    with tempfile.TemporaryDirectory() as workdir:
        for target in args.target or TARGETS:
            t0 = time.perf_counter()
            outcomes, messages, bugs = run(target, args.examples, workdir)
            dt = time.perf_counter() - t0
            reader = "read_contactors" if target.startswith("csv") else "read_target"
            print(f"\n== {reader} on {target}: {sum(outcomes.values())} inputs in {dt:.1f} s: "
                  + ", ".join(f"{n} {k}" for k, n in sorted(outcomes.items())))
            for text, n in messages.most_common(8):
                print(f"   {n:6d}  ReadError: {text}")
            for i, (key, data) in enumerate(sorted(bugs.items())):
                found += 1
                print(f"   BUG {key}\n       shortest input ({len(data)} bytes): {data[:160]!r}")
                if args.save_dir:
                    args.save_dir.mkdir(parents=True, exist_ok=True)
                    ext = ".csv" if target.startswith("csv") else fz.TARGET_SEEDS[target][0]
                    (args.save_dir / f"{target}-bug{i}{ext}").write_bytes(data)
    print(f"\n{found} distinct bug(s) found")
    return 1 if found else 0


if __name__ == "__main__":
    sys.exit(main())
