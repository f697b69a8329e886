"""The speed goals table, made from one ``all.py --json`` run: every figure beside its
goal, each SDK figure as its ratio to the floor measured in the same run.

    python benchmarks/all.py --json results.json
    python benchmarks/goals.py results.json                          # print it
    python benchmarks/goals.py results.json --write docs/figures.md  # put it in the docs
    python benchmarks/goals.py results.json --write docs/figures.md --plot docs/img/scaling.svg

``--write`` replaces what lies between ``<!-- goals:begin -->`` and ``<!-- goals:end -->``
in the file, and the scaling table between ``<!-- scaling:begin -->`` and
``<!-- scaling:end -->`` (CPU, delivery, lag and errors of every configuration at N = 1,
32, 128 and 512, each beside its floor), so the docs' tables are never typed by hand.
``--plot`` draws CPU and lag against N from the same run (and writes its rows beside it
as ``.json``).
"""

from __future__ import annotations

import argparse
import contextlib
import functools
import json
import re
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any

#: The chassis counts the scaling table shows (the figure and its .json have them all).
SCALING_ROWS = (1, 32, 128, 512)


def _span(values: Iterable[float], unit: str = "×") -> str:
    """``2.1-2.9×`` (or one value) of the values, or a dash if there are none."""
    v = sorted(values)
    if not v:
        return "not measured"
    lo, hi = v[0], v[-1]
    return f"{lo:.2f}{unit}" if f"{lo:.2f}" == f"{hi:.2f}" else f"{lo:.2f}-{hi:.2f}{unit}"


def _met(ok: bool | None) -> str:
    return "—" if ok is None else ("**met**" if ok else "not met")


def _is_floor(row: dict[str, Any], kind: str = "floor") -> bool:
    """A floor row of ``scaling.py``: the raw reader (``floor``), or the raw reader
    waking a task per frame (``wake``)."""
    return "backend" not in row and row.get("kind", "floor") == kind


def _cpu_ratios(rows: list[dict[str, Any]], n: int, floor: str = "floor") -> dict[str, list[float]]:
    """CPU / floor (same loop, same N) of every transport, by loop."""
    out: dict[str, list[float]] = {}
    floors = {_loop(r): r["cpu_percent"] for r in rows if r["chassis"] == n and _is_floor(r, floor)}
    for r in rows:
        if r["chassis"] == n and "backend" in r:
            loop = _loop(r)
            if floors.get(loop):
                out.setdefault(loop, []).append(r["cpu_percent"] / floors[loop])
    return out


def _p99(key: str, result: dict[str, Any]) -> float:
    return float(result[key]["p99"])


def _by_loop(ratios: dict[str, list[float]]) -> str:
    return "; ".join(f"{_span(v)} {loop}" for loop, v in sorted(ratios.items())) or "—"


def table(report: dict[str, Any]) -> list[str]:
    """The goals table's lines (markdown)."""
    scripts = report["scripts"]

    def figures(script: str) -> Any:
        return scripts.get(script, {}).get("figures")

    lines = ["| figure | goal | measured | |", "|---|---|---|---|"]
    scaling = figures("scaling.py") or []
    for n in (1, 32, 128):
        ratios = _cpu_ratios(scaling, n)
        worst = max((max(v) for v in ratios.values()), default=None)
        lines.append(
            f"| CPU per chassis at 50 Hz vs the raw reader, N = {n} | ≤ 1.5× | "
            f"{_by_loop(ratios)} | {_met(None if worst is None else worst <= 1.5)} |"
        )
        if woken := _cpu_ratios(scaling, n, "wake"):
            lines.append(
                f"| same, against the raw reader waking a task per frame, N = {n} | (context) | "
                f"{_by_loop(woken)} | |"
            )
    lines.append(_capacity_row(scaling))
    decoder = figures("decoder_throughput.py") or {}
    versus = decoder.get("vs_pymavlink", {})
    for label in ("per frame", "4 KiB"):
        r = versus.get(label)
        lines.append(
            f"| protocol A decoder vs pymavlink, {label} | ≥ 5× | "
            f"{'not measured' if r is None else f'{r:.2f}×'} | "
            f"{_met(None if r is None else r >= 5)} |"
        )
    hour = (figures("recording.py") or {}).get("hour", {}).get("jsonl")
    if hour is not None:
        ok = hour["replay_s"] <= 2 and hour["replay_mb"] <= 50
        lines.append(
            f"| `replay` of a 1 h capture (180,000 frames) | ≤ 2 s, ≤ 50 MB | "
            f"{hour['replay_s']:.1f} s, {hour['replay_mb']:.0f} MB | {_met(ok)} |"
        )
        lines.append(
            f"| `replay --json` of the same | ≤ 4 s | {hour['replay_json_s']:.1f} s | "
            f"{_met(hour['replay_json_s'] <= 4)} |"
        )
    latency = figures("latency.py") or {}

    def versus_floor(figure: Callable[[dict[str, Any]], float]) -> dict[str, list[float]]:
        """``figure`` of every transport over the floor's, by loop (where measured)."""
        out: dict[str, list[float]] = {}
        for loop, result in latency.items():
            with contextlib.suppress(KeyError):
                base = figure(result["floor"])
                out[loop] = [figure(r) / base for r in result["sdk"]]
        return out

    # Each goal, then a figure that is context, not a goal: the part of the latency the
    # process adds after its read callback; the CPU a request costs.
    for key, label, context, context_label in (
        (
            "latency",
            "write → `async for` p99",
            lambda r: r["inside"]["p50"],
            "of it, read callback → `async for` p50",
        ),
        (
            "round_trip",
            "request round trip p99",
            lambda r: r["round_trip_cpu_us"],
            "request round trip, CPU per call",
        ),
    ):
        goal = versus_floor(functools.partial(_p99, key))
        worst = max((max(v) for v in goal.values() if v), default=None)
        lines.append(
            f"| {label} vs the floor, every transport | ≤ 1.2× | {_by_loop(goal)} | "
            f"{_met(None if worst is None else worst <= 1.2)} |"
        )
        if ratios := versus_floor(context):
            lines.append(f"| {context_label} vs the floor's | (context) | {_by_loop(ratios)} | |")
    machine = report["machine"]
    quick = " (quick mode: shorter windows, fewer samples)" if report.get("quick") else ""
    lines += [
        "",
        f"Measured {machine['date']}, commit {machine['commit']}, {machine['cpu']}, "
        f"{machine['python']}{quick}; load before/after each script: "
        + ", ".join(
            f"{name} {s['load_before'].split()[0]}/{s['load_after'].split()[0]}"
            for name, s in scripts.items()
        )
        + ".",
    ]
    return lines


def _capacity_row(rows: list[dict[str, Any]]) -> str:
    """The most chassis every transport ran cleanly (no error, >= 99 % of the frames
    delivered within the window), by loop, and what fell short just above it."""
    parts, tops = [], []
    for loop in sorted({_loop(r) for r in rows if "backend" in r}):
        mine = [r for r in rows if "backend" in r and _loop(r) == loop]
        bad = [r for r in mine if r["errors"] or r["got"] < 0.99]
        worst_n = min((r["chassis"] for r in bad), default=None)
        top = max((r["chassis"] for r in mine if worst_n is None or r["chassis"] < worst_n),
                  default=0)  # fmt: skip
        tops.append(top)
        text = f"{top} {loop}"
        if worst_n is not None:
            short = ", ".join(
                f"{r['backend']} {r['got'] * 100:.1f} % delivered, {r['errors']} errors, "
                f"CPU {r['cpu_percent']:.0f} %"
                for r in bad
                if r["chassis"] == worst_n
            )
            text += f" (at {worst_n}: {short})"
        parts.append(text)
    top_all = min(tops) if tops else None
    return (
        "| chassis at 50 Hz in one process, nothing lost, no error (every transport) "
        f"| ≥ 512 | {'; '.join(parts) or 'not measured'} | "
        f"{_met(None if top_all is None else top_all >= 512)} |"
    )


def scaling_table(report: dict[str, Any]) -> list[str]:
    """The scaling table's lines (markdown): every configuration at each of
    :data:`SCALING_ROWS` chassis, its CPU as a ratio to the floor on the same loop."""
    rows = report["scripts"].get("scaling.py", {}).get("figures") or []
    floors = {(r["chassis"], _loop(r)): r for r in rows if _is_floor(r)}
    woken = {(r["chassis"], _loop(r)): r for r in rows if _is_floor(r, "wake")}
    lines = [
        "| N | configuration | CPU (one core = 100 %) | × floor | frames delivered "
        "| lag p50 / p99 | errors |",
        "|---|---|---|---|---|---|---|",
    ]
    for n in SCALING_ROWS:
        if (n, "asyncio") not in floors or (n, "uvloop") not in floors:
            continue
        a, u = floors[(n, "asyncio")]["cpu_percent"], floors[(n, "uvloop")]["cpu_percent"]
        lines.append(f"| {n} | floor, asyncio / uvloop | {a:.1f} % / {u:.1f} % | | 100 % | | 0 |")
        for loop in ("asyncio", "uvloop"):
            if w := woken.get((n, loop)):
                base = floors[(n, loop)]["cpu_percent"]
                lines.append(
                    f"| {n} | floor + task wake, {loop} | {w['cpu_percent']:.1f} % | "
                    f"{w['cpu_percent'] / base:.2f}× | {w['got'] * 100:.1f} % | | {w['errors']} |"
                )
        for r in rows:
            if r["chassis"] == n and "backend" in r:
                floor = floors[(n, _loop(r))]["cpu_percent"]
                lines.append(
                    f"| {n} | {r['backend']}, {_loop(r)} | {r['cpu_percent']:.1f} % | "
                    f"{r['cpu_percent'] / floor:.2f}× | {r['got'] * 100:.1f} % | "
                    f"{r['lag_p50_ms']:.2f} / {r['lag_p99_ms']:.2f} ms | {r['errors']} |"
                )
    return lines


def _loop(row: dict[str, Any]) -> str:
    return str(row["config"]).rsplit(" / ", 1)[1]


def _replace(doc: str, name: str, text: str) -> str:
    begin, end = f"<!-- {name}:begin -->", f"<!-- {name}:end -->"
    pattern = re.compile(re.escape(begin) + ".*?" + re.escape(end), re.S)
    if not pattern.search(doc):
        raise SystemExit(f"the document has no {begin} ... {end} block to replace")
    return pattern.sub(lambda _: f"{begin}\n{text}\n{end}", doc)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("results", help="the file all.py --json wrote")
    parser.add_argument("--write", metavar="DOC", help="replace the tables in DOC")
    parser.add_argument("--plot", metavar="FILE", help="draw the scaling figure (.svg/.png)")
    args = parser.parse_args()
    report = json.loads(Path(args.results).read_text())
    text = "\n".join(table(report))
    if not args.write:
        print(text)
        print()
        print("\n".join(scaling_table(report)))
    else:
        doc = Path(args.write)
        updated = _replace(doc.read_text(), "goals", text)
        updated = _replace(updated, "scaling", "\n".join(scaling_table(report)))
        doc.write_text(updated)
        print(f"wrote the goals and scaling tables into {doc}")
    if args.plot:
        from scaling import plot

        rows = report["scripts"]["scaling.py"]["figures"]
        plot(rows, args.plot)
        Path(args.plot).with_suffix(".json").write_text(json.dumps(rows, indent=1))
        print(f"drew {args.plot}")


if __name__ == "__main__":
    main()
