"""CPU and lag against the number of chassis in one process, on every transport and
both event loops and both deliveries, beside the raw-reader floor (about 15 minutes;
--quick: 32 chassis, about 1).

    pip install -e ".[all,fast,serialx,uvloop]" --group bench
    python benchmarks/scaling.py [--quick] [--plot docs/img/scaling.svg]

N chassis stream 50 Hz telemetry from another process (``_writer.py``: precomputed
frames on N pseudo-terminals, staggered); this process reads them with N ``Chassis``,
in a fresh process per configuration, with each of two deliveries (``delivery`` in the
JSON rows): ``async for`` (each chassis's telemetry into a task of its own) and
``callback`` (each chassis's telemetry taken by ``Notifier(robot).listen("telemetry",
callback)``, called inside the read path: no task woken). CPU is
``time.process_time()`` over a window after a second of warm-up (half a second with
--quick; 100 % = one core); lag
is from a frame's due time at the writer to the application's ``async for`` body or
callback, p50 and
p99 (the writer's own lateness is printed beside it); "got" is the share of the frames
written in the window that reached the application; "errors" counts sequence gaps,
dropped messages and every exception the event loop had to log. The floor reads the
same ptys with ``loop.add_reader`` and ``os.read`` and nothing else. A second floor,
"floor + task wake", adds what any ``async for`` consumer needs at the least: the read
callback cuts the frames by their size and wakes a task per chassis through a future,
which takes them one by one (no decoding): the gap between the two floors is what
waking the application costs on its own.
"""

from __future__ import annotations

import argparse
import asyncio
import importlib.util
import json
import os
import statistics
import subprocess
import sys
import time
from collections import deque
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from chassis_sdk.protocol import Telemetry

HERE = Path(__file__).parent
COUNTS = [1, 8, 32, 64, 128, 256, 512]
BACKENDS = ["pyserial-asyncio", "pyserial-asyncio-fast", "serialx"]
MODULES = {"pyserial-asyncio-fast": "serial_asyncio_fast", "serialx": "serialx"}
WARMUP = 1.0


def installed(backend: str) -> bool:
    module = MODULES.get(backend)
    return module is None or importlib.util.find_spec(module) is not None


FRAME = 28  # the 0x81 telemetry frame the writer sends


class _Frames:
    """A chassis's frames waiting for its task in the "floor + task wake"."""

    __slots__ = ("items", "waiter")

    def __init__(self) -> None:
        self.items: deque[bytes] = deque()
        self.waiter: asyncio.Future[None] | None = None


#: How the application takes each chassis's telemetry in the SDK configurations.
DELIVERIES = ("async for", "callback")


async def measure(n: int, window: float, kind: str, delivery: str = "async for") -> dict[str, Any]:
    """One configuration: ``kind`` is ``floor``, ``wake`` (the floor plus a task woken
    per frame) or ``sdk``, whose ``delivery`` is one of `DELIVERIES`."""
    writer = await asyncio.create_subprocess_exec(
        sys.executable, str(HERE / "_writer.py"), str(n), str(WARMUP + window + 0.3),
        stdin=subprocess.PIPE, stdout=subprocess.PIPE,
    )  # fmt: skip
    assert writer.stdout is not None
    assert writer.stdin is not None
    info = json.loads(await writer.stdout.readline())
    ports, t0, period = info["ports"], info["t0"], info["period"]
    loop = asyncio.get_running_loop()
    errors = 0

    def count_error(loop: asyncio.AbstractEventLoop, context: dict[str, Any]) -> None:
        nonlocal errors
        errors += 1

    loop.set_exception_handler(count_error)
    got = 0
    lags: list[float] = []
    start = t0 + WARMUP
    stop = start + window
    result: dict[str, Any] = {"chassis": n}
    if kind in ("floor", "wake"):
        fds = [os.open(p, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK) for p in ports]

        def read(fd: int) -> None:
            nonlocal got
            if start <= time.monotonic() < stop:
                got += len(os.read(fd, 4096)) // FRAME
            else:
                os.read(fd, 4096)

        def read_and_wake(fd: int, box: _Frames) -> None:
            data = os.read(fd, 4096)
            box.items.extend(data[i : i + FRAME] for i in range(0, len(data), FRAME))
            waiter = box.waiter
            if waiter is not None and not waiter.done():
                waiter.set_result(None)

        async def take(box: _Frames) -> None:
            nonlocal got
            while True:
                if not box.items:
                    box.waiter = loop.create_future()
                    await box.waiter
                box.items.popleft()
                if start <= time.monotonic() < stop:
                    got += 1

        tasks = []
        for fd in fds:
            if kind == "floor":
                loop.add_reader(fd, read, fd)
            else:
                box = _Frames()
                tasks.append(asyncio.ensure_future(take(box)))
                loop.add_reader(fd, read_and_wake, fd, box)
        await asyncio.sleep(start - time.monotonic())
        c0 = time.process_time()
        await asyncio.sleep(stop - time.monotonic())
        cpu = time.process_time() - c0
        for task in tasks:
            task.cancel()
        for fd in fds:
            loop.remove_reader(fd)
            os.close(fd)
        if kind == "wake":
            result["kind"] = "wake"
    else:
        from chassis_sdk import Chassis
        from chassis_sdk.core.notifier import Notifier

        robots = [Chassis(p, link_timeout=None, connect_timeout=30) for p in ports]
        await asyncio.gather(*(r.connect() for r in robots))

        async def consume(i: int, robot: Chassis) -> None:
            nonlocal got
            offset = t0 + i * period / n
            async for t in robot.telemetry():
                now = time.monotonic()
                if start <= now < stop:
                    got += 1
                    lags.append(now - (offset + t.seq * period))

        def taker(i: int) -> Callable[[Telemetry], None]:
            offset = t0 + i * period / n

            def take(t: Telemetry) -> None:
                nonlocal got
                now = time.monotonic()
                if start <= now < stop:
                    got += 1
                    lags.append(now - (offset + t.seq * period))

            return take

        tasks, notifiers = [], []
        for i, robot in enumerate(robots):
            if delivery == "callback":
                notifier = Notifier(robot)
                notifier.listen("telemetry", taker(i))
                notifiers.append(notifier)
            else:
                tasks.append(asyncio.ensure_future(consume(i, robot)))
        await asyncio.sleep(start - time.monotonic())
        c0 = time.process_time()
        await asyncio.sleep(stop - time.monotonic())
        cpu = time.process_time() - c0
        for task in tasks:
            task.cancel()
        for notifier in notifiers:
            notifier.close()
        errors += sum(r.stats.sequence_gaps + r.stats.queue_drops for r in robots)
        result["backend"] = robots[0].transport_backend
        result["delivery"] = delivery
        await asyncio.gather(*(r.close() for r in robots))
    writer.stdin.close()
    late = json.loads(await writer.stdout.readline())
    await writer.wait()
    result.update(
        cpu_percent=cpu / window * 100,
        got=got / (n * window / period),
        errors=errors,
        writer_late_p99_ms=late["late_p99_ms"],
    )
    if lags:
        lags.sort()
        result["lag_p50_ms"] = statistics.median(lags) * 1e3
        result["lag_p99_ms"] = lags[int(len(lags) * 0.99)] * 1e3
    return result


def run_one(
    n: int, window: float, backend: str | None, uvloop: bool, delivery: str = "async for"
) -> dict[str, Any]:
    """One configuration in a fresh process: ``backend`` is a transport, or ``None``
    for the floor, or ``"wake"`` for the floor plus a task woken per frame."""
    args = [sys.executable, __file__, "--one", str(n), "--window", str(window)]
    args += ["--uvloop"] if uvloop else []
    args += ["--delivery", delivery, "--warmup", str(WARMUP)]
    args += ["--kind", {None: "floor", "wake": "wake"}.get(backend, "sdk")]
    env = dict(os.environ)
    if backend not in (None, "wake"):
        env["CHASSIS_SDK_BACKEND"] = backend
    out = subprocess.run(args, env=env, check=True, capture_output=True, text=True)
    result: dict[str, Any] = json.loads(out.stdout)
    return result


def plot(rows: list[dict[str, Any]], path: str) -> None:
    import matplotlib
    import matplotlib.ticker

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (cpu_ax, lag_ax) = plt.subplots(1, 2, figsize=(12, 4.5))
    configs = sorted({r["config"] for r in rows})
    for config in configs:
        mine = [r for r in rows if r["config"] == config]
        ns = [r["chassis"] for r in mine]
        cpu = [r["cpu_percent"] for r in mine]
        if config.startswith("floor"):  # black on asyncio's loop, grey on uvloop
            style = ":" if config.startswith("floor +") else "--"
            colour = "0.55" if config.endswith("uvloop") else "black"
            cpu_ax.plot(ns, cpu, style, color=colour, label=config)
        else:
            style = "-s" if "callback" in config else "-o"  # squares: callback delivery
            cpu_ax.plot(ns, cpu, style, label=config, markersize=3)
            lag_ax.plot(ns, [r.get("lag_p99_ms", float("nan")) for r in mine], style,
                        label=config, markersize=3)  # fmt: skip
    for ax, label in ((cpu_ax, "CPU, % of one core"), (lag_ax, "lag p99, ms (write -> app)")):
        ax.set_xscale("log", base=2)
        ax.set_xticks(sorted({r["chassis"] for r in rows}))
        ax.get_xaxis().set_major_formatter(matplotlib.ticker.ScalarFormatter())
        ax.set_xlabel("chassis at 50 Hz in one process")
        ax.set_ylabel(label)
        ax.grid(True, alpha=0.3)
    lag_ax.set_yscale("log")
    cpu_ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path)


def main() -> None:
    global WARMUP
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="32 chassis, 1.5 s windows")
    parser.add_argument("--counts", help="comma-separated N (default 1,8,...,512)")
    parser.add_argument("--plot", metavar="FILE", help="draw CPU and lag against N (.svg/.png)")
    parser.add_argument("--json", metavar="FILE", help="write every row to FILE")
    parser.add_argument("--one", type=int, help=argparse.SUPPRESS)
    parser.add_argument("--window", type=float, default=5.0, help=argparse.SUPPRESS)
    parser.add_argument("--kind", default="sdk", help=argparse.SUPPRESS)
    parser.add_argument("--uvloop", action="store_true", help=argparse.SUPPRESS)
    parser.add_argument("--delivery", default="async for", help=argparse.SUPPRESS)
    parser.add_argument("--warmup", type=float, default=WARMUP, help=argparse.SUPPRESS)
    args = parser.parse_args()
    WARMUP = 0.5 if args.quick else args.warmup
    if args.one is not None:
        factory = None
        if args.uvloop:
            factory = importlib.import_module("uvloop").new_event_loop
        with asyncio.Runner(loop_factory=factory) as runner:
            print(json.dumps(runner.run(measure(args.one, args.window, args.kind, args.delivery))))
        return
    counts = [32] if args.quick else COUNTS
    if args.counts:
        counts = [int(c) for c in args.counts.split(",")]
    window = 1.5 if args.quick else args.window
    loops = [False] + ([True] if importlib.util.find_spec("uvloop") else [])
    configs: list[tuple[str | None, bool, str]] = [(None, u, "") for u in loops]
    configs += [("wake", u, "") for u in loops]
    configs += [(b, u, d) for d in DELIVERIES for b in BACKENDS if installed(b) for u in loops]
    print(f"{'N':>4}  {'configuration':<44}{'CPU %':>7}{'x floor':>9}{'got':>8}"
          f"{'lag p50':>9}{'p99 ms':>8}{'errors':>7}{'writer late p99':>16}")  # fmt: skip
    rows = []
    for n in counts:
        floors: dict[bool, float] = {}
        for backend, on_uvloop, delivery in configs:
            what = {None: "floor: raw os.read", "wake": "floor + task wake"}.get(
                backend, f"{backend}, {delivery}"
            )
            name = f"{what} / {'uvloop' if on_uvloop else 'asyncio'}"
            try:
                r = run_one(n, window, backend, on_uvloop, delivery or "async for")
            except subprocess.CalledProcessError as exc:
                tail = (exc.stderr or "").strip().splitlines()[-1:] or ["?"]
                print(f"{n:>4}  {name:<44} not measured: {tail[0]}", flush=True)
                continue
            r["config"] = name
            rows.append(r)
            if backend is None:
                floors[on_uvloop] = r["cpu_percent"]
            base = floors.get(on_uvloop)
            ratio = float(r["cpu_percent"]) / base if base else float("nan")
            lag = f"{'':>17}"
            if "lag_p50_ms" in r:
                lag = f"{r['lag_p50_ms']:>9.2f}{r['lag_p99_ms']:>8.2f}"
            late = f"{r['writer_late_p99_ms']:>14.2f}ms"
            print(f"{n:>4}  {name:<44}{r['cpu_percent']:>7.1f}{ratio:>8.2f}x{r['got']:>8.1%}"
                  f"{lag}{r['errors']:>7}{late}", flush=True)  # fmt: skip
    print(f"({window:g} s windows; 100 % = one core; got: frames that reached the application)")
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=1))
    if args.plot:
        plot(rows, args.plot)
        print(f"wrote {args.plot}")


if __name__ == "__main__":
    main()
