"""Run every benchmark and print its table (about 75 minutes; --quick: about 5).

    pip install -e ".[all,fast,serialx,uvloop]" --group bench
    python benchmarks/all.py [--quick] [--runs K] [--json results.json]
    python benchmarks/goals.py results.json --write docs/figures.md

The figures in docs/figures.md come from this command on the 2-core development
machine. It first prints what a figure depends on: the date, the commit, the CPU,
Python, the versions of the packages on the path and the decoding path (compiled or
pure), and the load before and after each script. The scripts behind a goal
(`REPEATED`) run ``--runs`` times (default 3; 1 with ``--quick``), interleaved (all of
them once, then again), since the machine drifts by a third from one minute to the
next: ``goals.py`` shows each figure as min / median / max over the runs. The other
scripts run once. ``--json FILE`` also writes all of that and every run's figures to
one file, from which ``goals.py`` makes the goals table in the docs.
"""

from __future__ import annotations

import argparse
import concurrent.futures
import datetime
import json
import os
import platform
import subprocess
import sys
import tempfile
import time
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
    "reflexes.py",
    "goal_accuracy.py",
]
#: How each script that can writes its figures to a file.
JSON_FLAG = {
    "decoder_throughput.py": "--json",
    "latency.py": "--json-file",
    "mqtt_fleet.py": "--json",
    "recording.py": "--json",
    "scaling.py": "--json",
    "ros2.py": "--json",
    "web.py": "--json",
    "reflexes.py": "--json-file",
}
#: The scripts whose figures the goals table shows: run ``--runs`` times.
REPEATED = ("decoder_throughput.py", "latency.py", "mqtt_fleet.py", "recording.py", "scaling.py")


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
    "cython",
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


def decoding_path() -> str:
    """Which decoding path the protocols take here (``chassis_sdk.core.compiled``), asked
    of a fresh interpreter with this environment (``CHASSIS_SDK_PURE`` included)."""
    code = (
        "import chassis_sdk.protocol\n"
        "from chassis_sdk.core import compiled\n"
        "s = compiled.status()\n"
        "print('pure (no compiled path in this version)' if s == 'no protocol imported' else s)"
    )
    try:
        done = subprocess.run(
            [sys.executable, "-c", code], capture_output=True, text=True, check=True
        )
    except (OSError, subprocess.CalledProcessError) as exc:
        return f"unknown ({exc})"
    return done.stdout.strip()


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
        f"decoding path: {decoding_path()}",
    ]


def _run_script(
    script: str, k: int, runs: int, extra: list[str], as_json: str | None, tmp: Path, live: bool
) -> tuple[str, str, dict[str, object], int]:
    """Run one script (its ``k``-th run): its name, its output with the header and the
    load lines (printed as it goes instead when ``live``), its run record, and its exit
    code."""
    again = f" (run {k + 1} of {runs})" if script in REPEATED and runs > 1 else ""
    lines = [f"== {script} {' '.join(extra)}".rstrip() + again]
    before = _load()
    lines.append(f"load before: {before}")
    out = tmp / f"{script}.{k}.json"
    flags = [JSON_FLAG[script], str(out)] if as_json and script in JSON_FLAG else []
    command = [sys.executable, str(HERE / script), *extra, *flags]
    if live:
        print("\n".join(lines), flush=True)
    began = time.monotonic()
    done = subprocess.run(command, check=False, capture_output=not live, text=True)
    took = time.monotonic() - began
    after = _load()
    text = "" if live else "\n".join(lines) + "\n" + done.stdout + done.stderr
    text += f"load after: {after}; took {took:.0f} s\n"
    run: dict[str, object] = {"load_before": before, "load_after": after, "seconds": round(took, 1)}
    if out.exists():
        run["figures"] = json.loads(out.read_text())
    return script, text, run, done.returncode


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="every script's quick mode")
    parser.add_argument("--json", metavar="FILE", help="write the machine and every figure")
    parser.add_argument(
        "--jobs",
        type=int,
        default=1,
        metavar="J",
        help="scripts run at once (default 1; CI's quick mode runs 3: it only checks that "
        "they run and print, and their figures compete for the cores)",
    )
    parser.add_argument(
        "--runs",
        type=int,
        metavar="K",
        help="runs of each script behind a goal (default 3; with --quick, 1)",
    )
    args = parser.parse_args()
    runs = args.runs if args.runs is not None else (1 if args.quick else 3)
    if runs < 1:
        parser.error("--runs must be at least 1")
    extra = ["--quick"] if args.quick else []
    lines = machine()
    report: dict[str, object] = {"machine": dict(line.split(": ", 1) for line in lines)}
    scripts: dict[str, dict[str, object]] = {}
    report["scripts"] = scripts
    report["quick"] = args.quick
    report["runs"] = runs
    print("== machine")
    for line in lines:
        print(line)
    print(flush=True)
    with tempfile.TemporaryDirectory() as tmp:
        order = [(k, script) for k in range(runs) for script in (SCRIPTS if k == 0 else REPEATED)]
        with concurrent.futures.ThreadPoolExecutor(max(1, args.jobs)) as pool:
            jobs = [
                pool.submit(
                    _run_script, script, k, runs, extra, args.json, Path(tmp), args.jobs == 1
                )
                for k, script in order
            ]
            for job in jobs:  # in order, each script's output whole
                script, output, run, code = job.result()
                print(output, end="", flush=True)
                if code:
                    print(f"{script} failed with exit code {code}", file=sys.stderr)
                    for other in jobs:
                        other.cancel()
                    return code
                # The first run's keys stay at the top (as before --runs); every run,
                # the first included, is in "runs".
                entry = scripts.setdefault(script, {**run, "runs": []})
                runs_list = entry["runs"]
                assert isinstance(runs_list, list)
                runs_list.append(run)
                print(flush=True)
    if args.json:
        Path(args.json).write_text(json.dumps(report, indent=1) + "\n")
        print(f"wrote {args.json}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
