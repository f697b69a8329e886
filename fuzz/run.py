"""Coverage-guided fuzzing of every device's decoders with atheris.

Usage (after ``pip install -e . --group fuzz``; ``nox -s nightly`` runs every target long)::

    python fuzz/run.py chassis -atheris_runs=200000
    python fuzz/run.py board -max_total_time=60 my-corpus/

Targets: every registered device and its commands (chassis, chassis-commands, board,
board-commands, and any installed device's). Flags after the target go
to libFuzzer. Without a corpus directory, one is made in a temporary directory from
valid frames of every kind (``harness.seeds``). A failing input is written to
``crash-*`` and the run exits non-zero; replay it with ``python fuzz/run.py TARGET
crash-...``. The checks themselves are in ``fuzz/harness.py``.
"""

from __future__ import annotations

import os
import sys
import tempfile

import atheris
import harness

# Instrument every loaded function (the SDK's modules are imported by the harness;
# instrument_imports() misses modules that a package's __init__ pulls in first).
atheris.instrument_all()


def main() -> None:
    targets = harness.targets()
    if len(sys.argv) < 2 or sys.argv[1] not in targets:
        sys.exit(f"usage: {sys.argv[0]} {{{','.join(targets)}}} [libFuzzer flags] [corpus]")
    target = sys.argv.pop(1)
    args = sys.argv
    if not any(not a.startswith("-") for a in args[1:]):
        corpus = tempfile.mkdtemp(prefix=f"fuzz-{target}-")
        for i, seed in enumerate(harness.seeds(target)):
            with open(os.path.join(corpus, f"seed-{i}"), "wb") as f:
                f.write(seed)
        args = [*args, corpus]
    atheris.Setup(args, lambda data: harness.check(target, data))
    atheris.Fuzz()


if __name__ == "__main__":
    main()
