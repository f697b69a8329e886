"""Run every benchmark and print its table (about 12 minutes; --quick: about 2.5 minutes).

    pip install ".[bench,fast]"
    python benchmarks/all.py [--quick]

The figures in docs/figures.md come from this command on the 2-core development
machine. It first prints what a figure depends on: the date, the commit, the CPU,
Python and the versions of the packages on the path.
"""

from __future__ import annotations

import datetime
import os
import platform
import subprocess
import sys
from importlib import metadata
from pathlib import Path

HERE = Path(__file__).parent
SCRIPTS = [
    "decoder_throughput.py",
    "latency.py",
    "load.py",
    "phantoms.py",
    "mqtt_fleet.py",
    "recording.py",
    "scaling.py",
]


PACKAGES = [
    "chassis-sdk",
    "pyserial",
    "pyserial-asyncio",
    "pyserial-asyncio-fast",
    "pymavlink",
    "aiomqtt",
    "foxglove-sdk",
    "mcap",
    "serialx",
    "uvloop",
]


def _cpu() -> str:
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def _load() -> str:
    """The machine's load averages (1, 5, 15 minutes): a busy machine moves figures."""
    one, five, fifteen = os.getloadavg()
    return f"{one:.2f} {five:.2f} {fifteen:.2f}"


def machine() -> list[str]:
    """What the figures depend on, one ``key: value`` line each."""
    try:
        commit = subprocess.run(
            ["git", "describe", "--always", "--dirty"],
            cwd=HERE,
            capture_output=True,
            text=True,
            check=True,
        ).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        commit = "unknown (not a git checkout)"
    versions = []
    for name in PACKAGES:
        try:
            versions.append(f"{name} {metadata.version(name)}")
        except metadata.PackageNotFoundError:
            versions.append(f"{name} -")
    return [
        f"date: {datetime.datetime.now(datetime.UTC):%Y-%m-%d %H:%M} UTC",
        f"commit: {commit}",
        f"cpu: {_cpu()} ({platform.machine()}), {len(os.sched_getaffinity(0))} cores usable",
        f"python: {platform.python_implementation()} {platform.python_version()}",
        f"packages: {', '.join(versions)}",
    ]


def main() -> int:
    extra = sys.argv[1:]
    print("== machine")
    for line in machine():
        print(line)
    print(flush=True)
    for script in SCRIPTS:
        print(f"== {script} {' '.join(extra)}".rstrip(), flush=True)
        print(f"load before: {_load()}", flush=True)
        done = subprocess.run([sys.executable, str(HERE / script), *extra], check=False)
        print(f"load after: {_load()}", flush=True)
        if done.returncode:
            print(f"{script} failed with exit code {done.returncode}", file=sys.stderr)
            return done.returncode
        print(flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
