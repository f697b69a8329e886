"""What the web dashboard costs and how fast it drives and stops (about a minute;
--quick: 25 s).

    pip install -e ".[web]" --group bench && sh tools/system-deps.sh # aiohttp, Playwright, Chromium
    python benchmarks/web.py [--quick] [--json FILE]

1. **Cost at 50 Hz**: a simulated chassis (telemetry at 50 Hz) and its ``Chassis`` in a
   child process, alone (the floor) and with a ``WebDashboard`` serving 0, 1 and 4
   pages (each page a WebSocket client in this process, reading every state): CPU (% of
   one core) and resident memory over the window, and the states each page received a
   second (the dashboard sends 20).
2. **Latency from a real page** (Debian's Chromium, headless, through Playwright,
   against the simulator): a held key → the simulated wheels moving; the key let go →
   stopped; the tab frozen → stopped (by the deadman); the page closed → stopped. The
   floor beside each: ``robot.set_velocity`` / ``robot.stop`` called directly, measured
   the same way (this process polls the simulator's wheel targets every millisecond),
   and the wire time of one 18-byte frame at 115200 baud.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import json
import os
import resource
import statistics
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent))
from all import machine  # this directory's all.py
from load import rss_bytes

from chassis_sdk import Chassis
from chassis_sdk.errors import install_hint
from chassis_sdk.sim import ChassisSimulator

SELF = os.path.abspath(__file__)
ROOT = Path(__file__).resolve().parent.parent
#: One drive frame (18 bytes, 10 bits a byte) at 115200 baud, seconds.
WIRE = 18 * 10 / 115200


# --- 1: cost, in a fresh process each ---------------------------------------------------------


async def measure_cost(dashboard: bool, window: float) -> dict[str, Any]:
    """(in a child) The simulator and a Chassis, with or without a dashboard: prints
    ``ready PORT``, then after ``go`` on stdin one second of warm-up and the window."""
    async with contextlib.AsyncExitStack() as stack:
        sim = await stack.enter_async_context(ChassisSimulator())
        robot = await stack.enter_async_context(Chassis(sim.port))
        port = 0
        if dashboard:
            from chassis_sdk.integrations.web import WebDashboard

            web = await stack.enter_async_context(WebDashboard(robot, port=0))
            port = web.port
        print(f"ready {port}", flush=True)
        await asyncio.to_thread(sys.stdin.readline)
        await asyncio.sleep(1.0)
        rss0, c0, t0 = rss_bytes(), time.process_time(), time.monotonic()
        await asyncio.sleep(window)
        c1, t1, rss1 = time.process_time(), time.monotonic(), rss_bytes()
        telemetry = robot.stats.frames
    return {
        "cpu_percent": (c1 - c0) / (t1 - t0) * 100,
        "rss_mb": rss0 / 1e6,
        "rss_growth_mb": (rss1 - rss0) / 1e6,
        "max_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1e3,
        "frames": telemetry,
        "elapsed_s": t1 - t0,
    }


async def cost_child(pages: int | None, window: float) -> dict[str, Any]:
    """``pages=None``: the floor (no dashboard)."""
    import websockets

    mode = "floor" if pages is None else "dashboard"
    cmd = [sys.executable, SELF, "--cost", mode, "--window", str(window)]
    proc = await asyncio.create_subprocess_exec(
        *cmd, stdin=asyncio.subprocess.PIPE, stdout=asyncio.subprocess.PIPE
    )
    assert proc.stdin is not None
    assert proc.stdout is not None
    states = [0] * (pages or 0)
    async with contextlib.AsyncExitStack() as stack:
        ready = (await asyncio.wait_for(proc.stdout.readline(), 30.0)).split()
        if not ready or ready[0] != b"ready":
            raise RuntimeError(f"cost child: {ready!r}")
        port = int(ready[1])
        readers = []
        for k in range(pages or 0):
            ws = await stack.enter_async_context(websockets.connect(f"ws://127.0.0.1:{port}/ws"))

            async def read(ws: Any = ws, k: int = k) -> None:
                async for _ in ws:
                    states[k] += 1

            readers.append(asyncio.create_task(read()))
        proc.stdin.write(b"go\n")
        await proc.stdin.drain()
        await asyncio.sleep(1.0)
        counted = list(states)
        t0 = time.monotonic()
        line = await asyncio.wait_for(proc.stdout.readline(), window + 30.0)
        elapsed = time.monotonic() - t0
        result: dict[str, Any] = json.loads(line)
        result["pages"] = pages or 0
        result["states_per_page_hz"] = (
            statistics.mean((s - c) / elapsed for s, c in zip(states, counted, strict=True))
            if pages
            else 0.0
        )
        for task in readers:
            task.cancel()
    proc.stdin.close()
    await proc.wait()
    return result


# --- 2: latency from a real page --------------------------------------------------------------


async def _until(condition: Callable[[], bool], timeout: float = 5.0) -> float:
    start = time.monotonic()
    async with asyncio.timeout(timeout):
        while not condition():  # noqa: ASYNC110  (the simulator's state has no event)
            await asyncio.sleep(0.001)
    return time.monotonic() - start


async def measure_latency(repeats: int) -> dict[str, list[float]]:
    sys.path.insert(0, str(ROOT))
    from chassis_sdk.integrations.web import WebDashboard
    from tests.support.browser import chromium

    out: dict[str, list[float]] = {
        "floor_command": [],
        "floor_stop": [],
        "key_command": [],
        "key_release": [],
        "frozen": [],
        "closed": [],
    }
    deadman = 0.4
    async with (
        ChassisSimulator() as sim,
        Chassis(sim.port, command_timeout=deadman) as robot,
        WebDashboard(robot, port=0) as web,
        chromium() as browser,
    ):

        def moving() -> bool:
            return any(sim.firmware.target)

        for _ in range(repeats):  # the floor: the API called directly
            t0 = time.monotonic()
            await robot.set_velocity(0.2, 0.0)
            await _until(moving)
            out["floor_command"].append(time.monotonic() - t0)
            t0 = time.monotonic()
            await robot.stop()
            await _until(lambda: not moving())
            out["floor_stop"].append(time.monotonic() - t0)
            await asyncio.sleep(0.05)
        from playwright.async_api import expect

        for _ in range(repeats):
            context = await browser.new_context()
            page = await context.new_page()
            await page.goto(web.url)
            await expect(page.locator("#link")).to_have_text("link connected")
            t0 = time.monotonic()
            await page.keyboard.down("KeyW")
            await _until(moving)
            out["key_command"].append(time.monotonic() - t0)
            await asyncio.sleep(0.2)
            t0 = time.monotonic()
            await page.keyboard.up("KeyW")
            await _until(lambda: not moving())
            out["key_release"].append(time.monotonic() - t0)
            await page.keyboard.down("KeyW")
            await _until(moving)
            freeze = asyncio.create_task(
                page.evaluate(
                    "() => { const end = performance.now() + 1000;"
                    " while (performance.now() < end) {} }"
                )
            )
            await asyncio.sleep(0.02)  # the freeze has begun (the last message went before)
            t0 = time.monotonic()
            await _until(lambda: not moving())
            out["frozen"].append(time.monotonic() - t0 + 0.02)
            await freeze
            await _until(moving)  # it drives again once the tab thaws (the key is held)
            t0 = time.monotonic()
            await page.close()
            await _until(lambda: not moving())
            out["closed"].append(time.monotonic() - t0)
            await context.close()
    out["deadman"] = [deadman]
    return out


def ms(values: list[float]) -> str:
    return f"median {statistics.median(values) * 1000:6.1f} ms, max {max(values) * 1000:6.1f} ms"


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="fewer repeats, shorter windows")
    parser.add_argument("--json", metavar="FILE", help="also write the figures to FILE")
    parser.add_argument("--cost", choices=["floor", "dashboard"], help=argparse.SUPPRESS)
    parser.add_argument("--window", type=float, default=10.0, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.cost:
        print(json.dumps(asyncio.run(measure_cost(args.cost == "dashboard", args.window))))
        return 0
    try:
        import aiohttp  # noqa: F401
        import playwright  # noqa: F401
        import websockets  # noqa: F401
    except ImportError as exc:
        print(
            "web.py needs aiohttp, playwright and websockets: "
            f"{install_hint('web')} --group bench ({exc})"
        )
        return 1
    window = 3.0 if args.quick else 10.0
    repeats = 3 if args.quick else 10
    for line in machine():
        print(line)
    print(f"window {window:g} s, {repeats} repeats")
    print("\n1. CPU and memory at 50 Hz telemetry (one process: simulator + Chassis [+ dashboard])")
    costs = {}
    for label, pages in (("floor", None), ("0 pages", 0), ("1 page", 1), ("4 pages", 4)):
        costs[label] = asyncio.run(cost_child(pages, window))
    floor = costs["floor"]["cpu_percent"]
    for label, r in costs.items():
        ratio = r["cpu_percent"] / floor if floor else float("nan")
        print(f"  {label:8} cpu {r['cpu_percent']:5.1f} % ({ratio:4.2f}x floor)  "
              f"rss {r['rss_mb']:5.1f} MB (+{r['rss_growth_mb']:4.1f} MB in the window)  "
              f"states/page {r['states_per_page_hz']:4.1f}/s")  # fmt: skip
    print("\n2. From a real page (Chromium) to the simulated wheels")
    lat = asyncio.run(measure_latency(repeats))
    wire = f"(wire {WIRE * 1000:.2f} ms)"
    print(f"  floor: set_velocity -> moving   {ms(lat['floor_command'])}   {wire}")
    print(f"  held key -> moving              {ms(lat['key_command'])}")
    print(f"  floor: stop() -> stopped        {ms(lat['floor_stop'])}")
    print(f"  key let go -> stopped           {ms(lat['key_release'])}")
    deadman = f"(deadman {lat['deadman'][0] * 1000:.0f} ms)"
    print(f"  tab frozen -> stopped           {ms(lat['frozen'])}   {deadman}")
    print(f"  page closed -> stopped          {ms(lat['closed'])}")
    if args.json:
        Path(args.json).write_text(json.dumps({"cost": costs, "latency": lat}, indent=1) + "\n")
        print(f"wrote {args.json}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
