"""Run every benchmark and print its table (about 2.5 minutes; --quick: about 40 s).

    pip install ".[bench,fast]"
    python benchmarks/all.py [--quick]

The figures in README.md come from this command on the 2-core development machine.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

HERE = Path(__file__).parent
SCRIPTS = ["decoder_throughput.py", "latency.py", "load.py", "phantoms.py"]


def main() -> int:
    extra = sys.argv[1:]
    for script in SCRIPTS:
        print(f"== {script} {' '.join(extra)}".rstrip(), flush=True)
        done = subprocess.run([sys.executable, str(HERE / script), *extra], check=False)
        if done.returncode:
            print(f"{script} failed with exit code {done.returncode}", file=sys.stderr)
            return done.returncode
        print(flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
