"""Run every benchmark and print its table (about 25 minutes; --quick: about 4).

    pip install ".[bench,fast,serialx,uvloop,columns]"
    python benchmarks/all.py [--quick] [--json results.json]
    python benchmarks/goals.py results.json --write docs/figures.md

The figures in docs/figures.md come from this command on the 2-core development
machine. It first prints what a figure depends on: the date, the commit, the CPU,
Python and the versions of the packages on the path, and the load before and after
each script. ``--json FILE`` also writes all of that and every script's figures to one
file, from which ``goals.py`` makes the goals table in the docs.
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import platform
import subprocess
import sys
import tempfile
from importlib import metadata
from pathlib import Path

HERE = Path(__file__).parent
SCRIPTS = [
    "decoder_throughput.py",
    "latency.py",
    "load.py",
    "phantoms.py",
    "mqtt_fleet.py",
    "mqtt_hostile.py",
    "stalled_port.py",
    "recording.py",
    "scaling.py",
    "ros2.py",
    "web.py",
]
#: How each script that can writes its figures to a file.
JSON_FLAG = {
    "decoder_throughput.py": "--json",
    "latency.py": "--json-file",
    "recording.py": "--json",
    "scaling.py": "--json",
    "ros2.py": "--json",
    "web.py": "--json",
}


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
    "aiohttp",
    "playwright",
    "cyclonedds",
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
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="every script's quick mode")
    parser.add_argument("--json", metavar="FILE", help="write the machine and every figure")
    args = parser.parse_args()
    extra = ["--quick"] if args.quick else []
    report: dict[str, object] = {"machine": dict(line.split(": ", 1) for line in machine())}
    scripts: dict[str, object] = {}
    report["scripts"] = scripts
    report["quick"] = args.quick
    print("== machine")
    for line in machine():
        print(line)
    print(flush=True)
    with tempfile.TemporaryDirectory() as tmp:
        for script in SCRIPTS:
            print(f"== {script} {' '.join(extra)}".rstrip(), flush=True)
            before = _load()
            print(f"load before: {before}", flush=True)
            out = Path(tmp) / f"{script}.json"
            flags = [JSON_FLAG[script], str(out)] if args.json and script in JSON_FLAG else []
            command = [sys.executable, str(HERE / script), *extra, *flags]
            done = subprocess.run(command, check=False)
            after = _load()
            print(f"load after: {after}", flush=True)
            if done.returncode:
                print(f"{script} failed with exit code {done.returncode}", file=sys.stderr)
                return done.returncode
            entry: dict[str, object] = {"load_before": before, "load_after": after}
            if out.exists():
                entry["figures"] = json.loads(out.read_text())
            scripts[script] = entry
            print(flush=True)
    if args.json:
        Path(args.json).write_text(json.dumps(report, indent=1) + "\n")
        print(f"wrote {args.json}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
