"""Decoder throughput for both protocols, on both decoding paths, against pymavlink in
the same process (about 1 minute; --quick: about 10 s).

    pip install . --group bench     # pymavlink, for the comparison
    python benchmarks/decoder_throughput.py [--quick] [--json FILE]

ChassisDecoder on 0x81 telemetry (28 bytes, protocol A) and BoardDecoder on 0x11 IMU
frames (23 bytes, protocol B), fed one frame per call (a quiet port) and in 4 KiB
chunks (what a busy port delivers), against pymavlink's MAVLink 2 parser on its
40-byte ATTITUDE message fed the same way. Each path runs in a process of its own: the
compiled fast path (when it is built) and the pure Python code (``CHASSIS_SDK_PURE=1``),
one after the other. In each, every round measures the three decoders back to back in
a rotating order, and a ratio to pymavlink is taken within a round, so a machine that
drifts slows both sides of a ratio alike; a figure is the median over the rounds.

The pure path's goal is "no slower than today": `REFERENCE` holds its figures
measured before the compiled path landed (date and commit in it). Its frames/s move
with the machine's load; the ratios to pymavlink measured in the same rounds are the
steadier comparison, and the one ``goals.py`` uses.

Also measured, on the active path: the decoders of a whole capture into numpy columns
(what ``plot`` uses), against the decoder object per frame.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from chassis_sdk.errors import install_hint
from chassis_sdk.protocol import (
    BoardDecoder,
    BoardEncoder,
    ChassisDecoder,
    ChassisEncoder,
    ChassisStatus,
    DockingState,
    ImuSample,
    Telemetry,
    Vector3,
    WheelSpeeds,
)

WIRE_BYTES_PER_S = 115200 / 10
RUNS = 7
N = 50_000
CHUNKINGS = ("per call", "4 KiB")
PROTOCOLS = {"chassis": "protocol A (chassis 0x81)", "board": "protocol B (board 0x11)"}

#: The pure path before the compiled path landed, "today" in the goal: three runs of
#: this script (each the median of 7 rounds of 50,000 frames per decoder) on the 2-core
#: development machine (AMD EPYC, CPython 3.11.7, pymavlink 2.4.50; load average 1.5-5
#: from other work: pymavlink itself went from 31,000 to 104,000 frames/s between runs).
#: Two runs at commit ab500e9, the third at 3d954c5 with CHASSIS_SDK_PURE=1 (the same
#: pure code: that commit added the compiled twin beside it); both were on a branch
#: squashed into 43d36c2, whose parent 80e8c90 holds the pure code they measured.
#: ``vs_pymavlink`` is the median of the three runs, ``vs_pymavlink_min`` the slowest,
#: ``vs_pymavlink_max`` the fastest; ``frames_per_s`` the medians (they move with the
#: load).
REFERENCE: dict[str, Any] = {
    "date": "2026-12-02",
    "commit": "ab500e9",
    "vs_pymavlink": {
        "chassis / per call": 2.62,
        "chassis / 4 KiB": 2.97,
        "board / per call": 2.47,
        "board / 4 KiB": 2.54,
    },
    "vs_pymavlink_min": {
        "chassis / per call": 2.13,
        "chassis / 4 KiB": 2.74,
        "board / per call": 2.25,
        "board / 4 KiB": 2.00,
    },
    "vs_pymavlink_max": {
        "chassis / per call": 3.71,
        "chassis / 4 KiB": 3.74,
        "board / per call": 4.16,
        "board / 4 KiB": 2.55,
    },
    "frames_per_s": {
        "chassis / per call": 120_571,
        "chassis / 4 KiB": 230_043,
        "board / per call": 130_749,
        "board / 4 KiB": 141_430,
        "pymavlink / per call": 51_640,
        "pymavlink / 4 KiB": 53_761,
    },
}


def chassis_stream(n: int) -> tuple[bytes, int]:
    enc = ChassisEncoder()
    t = Telemetry(24.6, ChassisStatus.REMOTE_OFFLINE, DockingState.SEARCHING, 0.3, -0.2,
                  WheelSpeeds(0.2, 0.4, 0.2, 0.4))  # fmt: skip
    frames = [enc.encode(t) for _ in range(n)]  # each with its own sequence number
    return b"".join(frames), len(frames[0])


def board_stream(n: int) -> tuple[bytes, int]:
    s = ImuSample(Vector3(0.01, -0.02, 1.0), Vector3(0.5, -0.5, 10.0), Vector3(300, -300, -420))
    frame = BoardEncoder().encode(s)
    return frame * n, len(frame)


def mavlink_stream(n: int) -> tuple[bytes, int] | None:
    try:
        from pymavlink.dialects.v20 import common as mavlink
    except ImportError:
        return None
    sender = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
    frame = mavlink.MAVLink_attitude_message(1000, 0.1, -0.2, 0.3, 0.01, 0.02, 0.03).pack(sender)
    return frame * n, len(frame)


class MavlinkDecoder:
    """pymavlink's parser behind the same ``feed`` call."""

    def __init__(self) -> None:
        from pymavlink.dialects.v20 import common as mavlink

        self._parser = mavlink.MAVLink(None)

    def feed(self, data: bytes) -> list[object]:
        return self._parser.parse_buffer(data) or []


def measure(make_decoder: Callable[[], Any], chunks: list[bytes], frames: int) -> float:
    """Frames per second decoding ``chunks`` with a fresh decoder."""
    dec = make_decoder()
    feed = dec.feed
    n = 0
    t0 = time.perf_counter()
    for c in chunks:
        n += len(feed(c))
    elapsed = time.perf_counter() - t0
    assert n == frames, (n, frames)
    return frames / elapsed


def columns(cases: dict[str, tuple[Callable[[], Any], bytes, int]]) -> dict[str, float]:
    """A whole capture into arrays (numpy, ``capture_columns``), frames/s, printed
    beside the decoder one object per frame on the same bytes."""
    try:
        from chassis_sdk.recording.columns import decode_joined
    except ImportError:
        print(f"numpy is not installed ({install_hint('columns')}): no column figures")
        return {}
    rates = {}
    for name, (dec, stream, _) in cases.items():
        chunks = [stream[i : i + 4096] for i in range(0, len(stream), 4096)]
        objects = statistics.median(measure(dec, chunks, N) for _ in range(RUNS))
        times = []
        for _ in range(RUNS):
            t0 = time.perf_counter()
            found = decode_joined(stream, [0.0], [len(stream)], dec())
            times.append(time.perf_counter() - t0)
            assert found.frames == N, found.frames
        rate = rates[name] = N / statistics.median(times)
        print(f"{name} into columns, whole capture: {rate:,.0f} frames/s, "
              f"{rate / objects:.0f}x the decoder's objects in 4 KiB chunks")  # fmt: skip
    return rates


def one_path() -> dict[str, Any]:
    """Every figure of the path this process runs (``CHASSIS_SDK_PURE`` decides)."""
    from chassis_sdk.core import compiled

    streams = {"chassis": chassis_stream(N), "board": board_stream(N)}
    makers: dict[str, Callable[[], Any]] = {"chassis": ChassisDecoder, "board": BoardDecoder}
    mav = mavlink_stream(N)
    if mav is not None:
        streams["pymavlink"] = mav
        makers["pymavlink"] = MavlinkDecoder
    chunked = {
        (name, label): [
            stream[i : i + (size if label == "per call" else 4096)]
            for i in range(0, len(stream), size if label == "per call" else 4096)
        ]
        for name, (stream, size) in streams.items()
        for label in CHUNKINGS
    }
    names = list(streams)
    rates: dict[str, list[float]] = {f"{name} / {label}": [] for name, label in chunked}
    ratios: dict[str, list[float]] = {
        f"{p} / {label}": [] for p in PROTOCOLS for label in CHUNKINGS if mav is not None
    }
    for k in range(RUNS):
        for label in CHUNKINGS:
            got = {}
            for name in names[k % len(names) :] + names[: k % len(names)]:  # rotate
                got[name] = measure(makers[name], chunked[name, label], N)
                rates[f"{name} / {label}"].append(got[name])
            if mav is not None:
                for p in PROTOCOLS:
                    ratios[f"{p} / {label}"].append(got[p] / got["pymavlink"])
    result: dict[str, Any] = {
        "path": compiled.status(),
        "frames_per_s": {key: statistics.median(v) for key, v in rates.items()},
        "vs_pymavlink": {key: statistics.median(v) for key, v in ratios.items()},
        "vs_pymavlink_rounds": ratios,
        "rounds": RUNS,
        "frames": N,
    }
    return result


def run_path(pure: bool, quick: bool) -> dict[str, Any]:
    """`one_path` in a fresh process, on the pure path or the default one."""
    env = dict(os.environ)
    env.pop("CHASSIS_SDK_PURE", None)
    if pure:
        env["CHASSIS_SDK_PURE"] = "1"
    args = [sys.executable, __file__, "--one", *(["--quick"] if quick else [])]
    out = subprocess.run(args, env=env, check=True, capture_output=True, text=True)
    result: dict[str, Any] = json.loads(out.stdout)
    return result


def print_path(name: str, r: dict[str, Any]) -> None:
    print(f"== {name} path: {r['path']}")
    print(f"{'decoder':<22}{'chunking':<11}{'frames/s':>11}{'x wire':>8}{'x pymavlink':>13}")
    for key, fps in r["frames_per_s"].items():
        who, label = key.split(" / ")
        size = {"chassis": 28, "board": 23, "pymavlink": 40}[who]
        ratio = r["vs_pymavlink"].get(key)
        text = f"{ratio:>12.2f}x" if ratio is not None else ""
        print(f"{who:<22}{label:<11}{fps:>11,.0f}{fps / (WIRE_BYTES_PER_S / size):>8,.0f}{text}")


def main() -> None:
    global RUNS, N
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="fewer, shorter rounds (for CI)")
    parser.add_argument("--json", metavar="FILE", help="also write the figures to FILE")
    parser.add_argument("--one", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.quick:
        RUNS, N = 3, 10_000
    if args.one:
        print(json.dumps(one_path()))
        return
    report: dict[str, Any] = {"reference": REFERENCE}
    default = run_path(False, args.quick)
    if "compiled" in default["path"]:
        report["compiled"] = default
        print_path("compiled", default)
    else:
        print(f"== compiled path: not measured ({default['path']})")
    pure = report["pure"] = run_path(True, args.quick)
    print_path("pure", pure)
    if "pymavlink / 4 KiB" not in pure["frames_per_s"]:
        print("pymavlink is not installed (pip install --group bench): no comparison")
    for key, today in REFERENCE["vs_pymavlink"].items():
        if key in pure["vs_pymavlink"]:
            now = pure["vs_pymavlink"][key]
            print(f"pure {key} vs pymavlink: {now:.2f}x, today's reference {today:.2f}x "
                  f"({REFERENCE['date']}, {REFERENCE['commit']})")  # fmt: skip
    print(
        f"(median of {RUNS} rounds of {N:,} frames per decoder; wire limit at 115200 baud: "
        f"{WIRE_BYTES_PER_S / 28:.0f} frames/s of 0x81, {WIRE_BYTES_PER_S / 23:.0f} of 0x11)"
    )
    # In this process: the default path (compiled when built), like the columns' users.
    report["columns_frames_per_s"] = columns(
        {
            "chassis 0x81": (ChassisDecoder, *chassis_stream(N)),
            "board 0x11": (BoardDecoder, *board_stream(N)),
        }
    )
    if args.json:
        Path(args.json).write_text(json.dumps(report, indent=1))


if __name__ == "__main__":
    main()
