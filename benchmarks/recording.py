"""What recording costs: the recorder's CPU at 50 Hz, the size of an hour, and reading
an hour back (about 1.5 minutes; --quick: about 30 s, a tenth of an hour).

    pip install -e ".[all,fast]" --group bench
    python benchmarks/recording.py [--quick]

1. **CPU at 50 Hz**, one chassis streaming into an ``async for`` (the simulator in
   another process, as in load.py), each in a fresh process: the raw ``os.read``
   floor, ``Chassis``, ``Chassis(record="run.jsonl")``, ``Chassis(record="run.mcap")``.
2. **An hour**: 180,000 telemetry frames from the chassis firmware model while the host
   drives a slow circle (its velocity every 50 ms: 72,000 frames the other way), through
   a ``Chassis`` that is never connected, recording to MCAP and to JSON lines at
   simulated times, as fast as it goes: the file per hour, and the recorder's CPU per
   frame.
3. **Reading that hour back**: ``decode_capture`` (every telemetry frame), ``chassis-sdk
   replay`` into /dev/null (the fastest of three runs), ``chassis-sdk export --csv``;
   beside them the floor, the ``mcap`` reader alone over the file (no decoding) and
   reading the JSON lines.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import json
import math
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from load import measure_floor, rss_bytes, start_simulators

WINDOW = 10.0
HOUR = 3600.0


async def measure_cpu(record: str | None) -> dict[str, object]:
    """One chassis at 50 Hz, recorded to ``record`` (a suffix) or not."""
    from chassis_sdk import Chassis

    proc, ports = await start_simulators(1)
    assert proc.stdin is not None
    frames = 0
    lags: list[float] = []
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / f"run{record}" if record else None
        base = rss_bytes()

        async def consume(robot: Chassis) -> None:
            nonlocal frames
            async for t in robot.telemetry():
                frames += 1
                lags.append(time.monotonic() - t.timestamp)  # read -> the application

        try:
            async with Chassis(ports[0], record=path) as robot:
                task = asyncio.ensure_future(consume(robot))
                await asyncio.sleep(1.0)
                f0, c0, t0 = frames, time.process_time(), time.monotonic()
                lags.clear()
                size0 = path.stat().st_size if path else 0
                await asyncio.sleep(WINDOW)
                f1, c1, t1 = frames, time.process_time(), time.monotonic()
                size1 = path.stat().st_size if path else 0
                rss = rss_bytes()
                task.cancel()
        finally:
            proc.stdin.close()
            await proc.wait()
    return {
        "record": record or "-",
        "cpu_percent": (c1 - c0) / (t1 - t0) * 100,
        "frames_per_s": (f1 - f0) / (t1 - t0),
        "file_bytes_per_s": (size1 - size0) / (t1 - t0),
        "rss_growth_mb": (rss - base) / 1e6,
        "lag_p50_us": statistics.median(lags) * 1e6,
        "lag_p99_us": statistics.quantiles(lags, n=100)[98] * 1e6,
    }


def simulate(seconds: float) -> list[tuple[float, bool, bytes]]:
    """``seconds`` of a chassis driving a slow circle: ``(time, sent by the host,
    bytes)``, telemetry from the firmware model at 50 Hz and the host's velocity
    every 50 ms, at simulated times from now on."""
    from chassis_sdk.devices.chassis.firmware import ChassisFirmware
    from chassis_sdk.devices.chassis.protocol import ChassisEncoder

    firmware = ChassisFirmware()
    encoder = ChassisEncoder()
    t0 = time.monotonic() + 10.0  # after the recorder starts, as in a live session
    firmware.on_connect(t0)
    session = []
    step = 0.01
    for i in range(int(seconds / step) + 1):
        now = t0 + i * step
        if i % 5 == 0:
            frame = encoder.drive_velocity(0.3, 0.2)
            firmware.receive(frame, now)
            session.append((now, True, frame))
        data = firmware.poll(now)
        if data:
            session.append((now, False, data))
    return session


def write_hour(path: Path | None, session: list[tuple[float, bool, bytes]]) -> dict[str, float]:
    """The session through a ``Chassis`` that is never connected, as fast as it goes,
    recorded to ``path`` (or not: the cost of decoding and handling alone)."""
    from chassis_sdk import Chassis
    from chassis_sdk.recording import open_recording

    device = Chassis("/dev/bench")
    recording = open_recording(path, device) if path is not None else None
    c0 = time.process_time()
    try:
        for now, sent, data in session:
            if not sent:
                device.feed(data, now)  # decoded, handled and tapped as if received
            elif recording is not None:
                recording.tx(data, now)  # as the device's tap sees a frame written
    finally:
        if recording is not None:
            recording.close()
    return {
        "cpu_s": time.process_time() - c0,
        "bytes": path.stat().st_size if path is not None else 0,
        "frames": len(session),
        "rx_chunks": sum(not sent for _, sent, _ in session),
    }


def timed(command: list[str]) -> float:
    start = time.monotonic()
    subprocess.run(command, check=True, stdout=subprocess.DEVNULL)
    return time.monotonic() - start


#: Runs the CLI and prints its peak memory (VmHWM, kB) to stderr as it exits. A child's
#: ``ru_maxrss`` would not do: it starts from the forking parent's size.
_PEAK = (
    "import atexit, runpy, sys\n"
    "def peak():\n"
    "    for line in open('/proc/self/status'):\n"
    "        if line.startswith('VmHWM:'):\n"
    "            print('peak-kb', line.split()[1], file=sys.stderr)\n"
    "atexit.register(peak)\n"
    "sys.argv = ['chassis-sdk', *sys.argv[1:]]\n"
    "runpy.run_module('chassis_sdk.cli', run_name='__main__')\n"
)


#: Entries of the session (telemetry and host frames) in about its first two seconds: the capture
#: whose replay measures the command's start-up when a shorter session is scaled.
STARTUP_ENTRIES = 150
#: Runs of each ``replay`` timed: the fastest is reported (a shared machine only ever adds
#: time: the others measure its neighbours).
REPLAY_RUNS = 3


def best_rss(args: list[str]) -> tuple[float, float]:
    """The fastest of :data:`REPLAY_RUNS` runs of ``chassis-sdk ARGS``, and the largest
    peak memory among them (MB)."""
    runs = [timed_rss(args) for _ in range(REPLAY_RUNS)]
    return min(s for s, _ in runs), max(mb for _, mb in runs)


def timed_rss(args: list[str]) -> tuple[float, float]:
    """Seconds ``chassis-sdk ARGS`` takes, and its own peak memory (MB)."""
    start = time.monotonic()
    done = subprocess.run(
        [sys.executable, "-c", _PEAK, *args],
        check=True, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    elapsed = time.monotonic() - start
    peak = [line.split()[1] for line in done.stderr.splitlines() if line.startswith("peak-kb")]
    return elapsed, int(peak[-1]) / 1024 if peak else math.nan


def read_floor(path: Path) -> float:
    """Reading the file with no decoding: the mcap reader's records, or the lines."""
    start = time.monotonic()
    if path.suffix == ".mcap":
        from mcap.stream_reader import StreamReader

        with path.open("rb") as f:
            for _ in StreamReader(f).records:
                pass
    else:
        with path.open() as f:
            for line in f:
                json.loads(line)
    return time.monotonic() - start


def decode_all(path: Path) -> tuple[float, int]:
    from chassis_sdk import Telemetry
    from chassis_sdk.recording import capture

    start = time.monotonic()
    n = sum(isinstance(m, Telemetry) for _, m in capture.decode_capture(path, "chassis"))
    return time.monotonic() - start, n


def columns_all(path: Path) -> tuple[float, int]:
    """``capture_columns``: the same frames into arrays (numpy), or (nan, 0) without it."""
    from chassis_sdk.recording import capture

    try:
        import numpy  # noqa: F401
    except ImportError:
        return math.nan, 0
    start = time.monotonic()
    n = len(capture.capture_columns(path, "chassis")["Telemetry"]["t"])
    return time.monotonic() - start, n


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="3 s windows, a tenth of an hour")
    parser.add_argument("--cpu", metavar="SUFFIX", help="(internal) one CPU measurement")
    parser.add_argument("--json", metavar="FILE", help="also write the figures to FILE")
    args = parser.parse_args()
    global WINDOW
    if args.quick:
        WINDOW = 3.0
    if args.cpu is not None:
        job = measure_floor(1) if args.cpu == "floor" else measure_cpu(args.cpu or None)
        print(json.dumps(asyncio.run(job)))
        return
    quick = ["--quick"] if args.quick else []
    print("recording one chassis at 50 Hz into an async for (a fresh process each)")
    print(f"{'recording':<24}{'CPU %':>7}{'x floor':>9}{'frames/s':>10}{'file KB/s':>11}"
          f"{'lag p50 us':>12}{'p99 us':>8}")  # fmt: skip
    floor = None
    report: dict[str, Any] = {"cpu": [], "hour": {}}
    for suffix in ("floor", "", ".jsonl", ".mcap"):
        out = subprocess.run(
            [sys.executable, __file__, "--cpu", suffix, *quick],
            check=True, capture_output=True, text=True,
        )  # fmt: skip
        r = json.loads(out.stdout)
        report["cpu"].append({"recording": suffix, **r})
        cpu = float(r["cpu_percent"])
        floor = cpu if suffix == "floor" else floor
        name = {"floor": "floor: raw os.read", "": "Chassis, no recording"}.get(
            suffix, f"Chassis(record=*{suffix})"
        )
        rest = ""
        if "frames_per_s" in r:
            rest = (f"{r['frames_per_s']:>10.1f}{r['file_bytes_per_s'] / 1e3:>11.2f}"
                    f"{r['lag_p50_us']:>12.0f}{r['lag_p99_us']:>8.0f}")  # fmt: skip
        print(f"{name:<24}{cpu:>7.2f}{cpu / floor if floor else 1.0:>8.2f}x{rest}")
    print(f"({WINDOW:.0f} s window; 100 % = one core; lag: frame read -> the application's "
          "async for)")  # fmt: skip

    seconds = HOUR / 10 if args.quick else HOUR
    scale = HOUR / seconds
    print()
    what = "an hour" if scale == 1 else f"{seconds / 60:.0f} minutes, scaled to an hour"
    print(f"{what} of a chassis driving (50 Hz telemetry, velocity every 50 ms)")
    print(f"{'file':<8}{'MB/hour':>9}{'write s':>9}{'us/frame':>10}{'decode s':>10}"
          f"{'columns s':>11}{'replay s':>10}{'export s':>10}{'floor s':>9}")  # fmt: skip
    session = simulate(seconds)
    bare = write_hour(None, session)
    with tempfile.TemporaryDirectory() as tmp:
        for suffix in (".mcap", ".jsonl"):
            path = Path(tmp) / f"hour{suffix}"
            w = write_hour(path, session)
            decode, n = decode_all(path)
            columns, n_columns = columns_all(path)
            cli = [sys.executable, "-m", "chassis_sdk.cli"]
            replay, replay_mb = best_rss(["replay", str(path), "--protocol", "chassis"])
            as_json, json_mb = best_rss(["replay", str(path), "--json"])
            # An hour's replay starts Python once: scaled, only the part after the
            # start-up (the session's first two seconds replayed) is multiplied.
            startup_s = start_json_s = 0.0
            if scale != 1:
                start = Path(tmp) / f"start{suffix}"
                write_hour(start, session[:STARTUP_ENTRIES])
                startup_s = best_rss(["replay", str(start), "--protocol", "chassis"])[0]
                start_json_s = best_rss(["replay", str(start), "--json"])[0]
                os.remove(start)
            replay_hour = startup_s + (replay - startup_s) * scale
            json_hour = start_json_s + (as_json - start_json_s) * scale
            export = timed([*cli, "export", str(path), "--csv", str(Path(tmp) / "csv")])
            floor_s = read_floor(path)
            per_frame = (w["cpu_s"] - bare["cpu_s"]) / w["frames"] * 1e6
            print(f"{suffix[1:]:<8}{w['bytes'] * scale / 1e6:>9.1f}{w['cpu_s'] * scale:>9.1f}"
                  f"{per_frame:>10.1f}{decode * scale:>10.1f}{columns * scale:>11.1f}"
                  f"{replay_hour:>10.1f}"
                  f"{export * scale:>10.1f}{floor_s * scale:>9.1f}")  # fmt: skip
            assert n == w["rx_chunks"], (n, w)
            report["hour"][suffix[1:]] = {
                "mb_per_hour": w["bytes"] * scale / 1e6, "write_s": w["cpu_s"] * scale,
                "recorder_us_per_frame": per_frame, "decode_s": decode * scale,
                "columns_s": columns * scale, "replay_s": replay_hour, "replay_mb": replay_mb,
                "replay_json_s": json_hour, "replay_json_mb": json_mb,
                "replay_startup_s": startup_s,
                "export_s": export * scale, "floor_s": floor_s * scale, "scale": scale,
            }  # fmt: skip
            assert n_columns in (0, n), (n_columns, n)
            with contextlib.suppress(FileNotFoundError):
                os.remove(path)
    print(f"{'none':<8}{'':>9}{bare['cpu_s'] * scale:>9.1f}   (decoding, odometry, events alone)")
    print(
        "(write: CPU to decode and record the hour as fast as it goes; us/frame: the "
        "recorder's own, per frame either way; "
        "decode: decode_capture of every frame; columns: capture_columns (numpy arrays) of "
        "the same frames; replay: `chassis-sdk replay` into /dev/null, the fastest of "
        f"{REPLAY_RUNS} runs (scaled: one start-up, measured replaying two seconds, plus the "
        "rest times the scale); "
        "export: `export --csv`; floor: the file read with no decoding)"
    )
    for name, h in report["hour"].items():
        plain = f"replay {h['replay_s']:.1f} s, {h['replay_mb']:.0f} MB peak"
        json_text = f"replay --json {h['replay_json_s']:.1f} s, {h['replay_json_mb']:.0f} MB peak"
        print(f"{name}: {plain}; {json_text}")
    if args.json:
        Path(args.json).write_text(json.dumps(report, indent=1))


if __name__ == "__main__":
    main()
