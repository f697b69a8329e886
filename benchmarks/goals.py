"""The speed goals table (issue 29's targets), made from one ``all.py --json`` run:
every figure beside its goal, each as min / median / max over the runs, each SDK figure
as its ratio to the floor measured in the same run.

    python benchmarks/all.py --json results.json [--runs 3]
    python benchmarks/goals.py results.json                          # print it
    python benchmarks/goals.py results.json --write docs/figures.md  # put it in the docs
    python benchmarks/goals.py results.json --write docs/figures.md --plot docs/img/scaling.svg

A goal is met or not on the median of the runs (the machine drifts by a third from one
minute to the next); "nothing lost" is judged on every run, since one loss is a loss.
A figure with several configurations (transports, event loops) is met only if each
configuration's median is. ``--write`` replaces what lies between ``<!-- goals:begin
-->`` and ``<!-- goals:end -->`` in the file, and the scaling table between ``<!--
scaling:begin -->`` and ``<!-- scaling:end -->`` (CPU, delivery, lag and errors of
every configuration at N = 1, 32, 128 and 512, each beside its floor, medians of the
runs), so the docs' tables are never typed by hand. ``--plot`` draws CPU and lag
against N from the same medians (and writes its rows beside it as ``.json``).
"""

from __future__ import annotations

import argparse
import functools
import json
import re
import statistics
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any

#: The chassis counts the scaling table shows (the figure and its .json have them all).
SCALING_ROWS = (1, 32, 128, 512)
#: The chassis counts of the CPU goals.
CPU_ROWS = (1, 32, 128)
PROTOCOLS = (("chassis", "protocol A"), ("board", "protocol B"))
NOT_MEASURED = "not measured"

Row = tuple[str, str, str, bool | None]


# -- reading the report -------------------------------------------------------------


def runs(report: dict[str, Any], script: str) -> list[Any]:
    """The figures of every run of ``script`` (a file from before ``--runs``: its one)."""
    entry = report["scripts"].get(script, {})
    if "runs" in entry:
        return [r["figures"] for r in entry["runs"] if "figures" in r]
    return [entry["figures"]] if "figures" in entry else []


def _loop(row: dict[str, Any]) -> str:
    return str(row["config"]).rsplit(" / ", 1)[1]


def _delivery(row: dict[str, Any]) -> str:
    return str(row.get("delivery", "async for"))


def _is_floor(row: dict[str, Any], kind: str = "floor") -> bool:
    """A floor row of ``scaling.py``: the raw reader (``floor``), or the raw reader
    waking a task per frame (``wake``)."""
    return "backend" not in row and row.get("kind", "floor") == kind


# -- formatting ---------------------------------------------------------------------


def mmm(values: Iterable[float], unit: str = "×", digits: int = 2) -> str:
    """``min / **median** / max`` of the values with ``unit`` (one value: itself)."""
    v = sorted(values)
    if not v:
        return NOT_MEASURED
    if len(v) == 1:
        return f"{v[0]:.{digits}f}{unit}"
    lo, med, hi = v[0], statistics.median(v), v[-1]
    return f"{lo:.{digits}f} / **{med:.{digits}f}** / {hi:.{digits}f}{unit}"


def _med(values: Iterable[float]) -> float | None:
    v = list(values)
    return statistics.median(v) if v else None


def _all_met(medians: Iterable[float | None], ok: Callable[[float], bool]) -> bool | None:
    """Met if every median meets ``ok``; None (not judged) if there are none."""
    m = [x for x in medians if x is not None]
    return None if not m else all(ok(x) for x in m)


def _met(ok: bool | None) -> str:
    return "—" if ok is None else ("**met**" if ok else "not met")


def _by_config(values: dict[tuple[str, str], list[float]], unit: str = "×", digits: int = 2) -> str:
    """``asyncio: serialx 1.1 / 1.2 / 1.3×, ...; uvloop: ...`` (configuration: backend, loop)."""
    parts = []
    for loop in sorted({loop for _, loop in values}):
        cells = [
            f"{backend} {mmm(v, unit, digits)}"
            for (backend, lp), v in sorted(values.items())
            if lp == loop
        ]
        parts.append(f"{loop}: {', '.join(cells)}")
    return "; ".join(parts) or NOT_MEASURED


# -- the rows -----------------------------------------------------------------------


def decoder_rows(report: dict[str, Any]) -> list[Row]:
    results = runs(report, "decoder_throughput.py")
    rows: list[Row] = []
    for p, name in PROTOCOLS:
        keys = (f"{p} / per call", f"{p} / 4 KiB")
        # The compiled figures: only from runs where this protocol took the compiled path.
        compiled: list[dict[str, Any]] = []
        paths = set()
        for r in results:
            c = r.get("compiled")
            path = c["path"] if c else r.get("pure", {}).get("path", "?")
            paths.add(path)
            if c and (path == "compiled" or f"{p}: compiled" in path):
                compiled.append(c["vs_pymavlink"])
        per_call = [c[keys[0]] for c in compiled if keys[0] in c]
        kib = [c[keys[1]] for c in compiled if keys[1] in c]
        if per_call or kib:
            measured = f"per call {mmm(per_call)}; 4 KiB {mmm(kib)}"
        else:
            why = ", ".join(sorted(paths)) or "no decoder_throughput.py run"
            measured = f"{NOT_MEASURED} (path: {why})"
        med_call, med_kib = _med(per_call), _med(kib)
        ok = None if med_call is None or med_kib is None else med_call >= 10 and med_kib >= 15
        rows.append(
            (
                f"{name} decoder vs pymavlink, compiled, per call / 4 KiB",
                "≥ 10× / ≥ 15×",
                measured,
                ok,
            )
        )
        pure = [r["pure"]["vs_pymavlink"] for r in results if "pure" in r]
        ref = results[0].get("reference", {}) if results else {}
        today = ref.get("vs_pymavlink_min", {})
        per_call = [c[keys[0]] for c in pure if keys[0] in c]
        kib = [c[keys[1]] for c in pure if keys[1] in c]
        med_call, med_kib = _med(per_call), _med(kib)
        if keys[0] in today and keys[1] in today:
            goal = (
                f"no slower than today: ≥ {today[keys[0]]:.2f}× / ≥ {today[keys[1]]:.2f}× "
                f"(today's slowest of 3 runs; median {ref['vs_pymavlink'][keys[0]]:.2f}× / "
                f"{ref['vs_pymavlink'][keys[1]]:.2f}×, {ref['date']}, {ref['commit']})"
            )
            ok = (
                None
                if med_call is None or med_kib is None
                else med_call >= today[keys[0]] and med_kib >= today[keys[1]]
            )
        else:
            goal, ok = "no slower than today (no reference in this run)", None
        measured = (
            f"per call {mmm(per_call)}; 4 KiB {mmm(kib)}" if per_call or kib else NOT_MEASURED
        )
        rows.append((f"{name} decoder vs pymavlink, pure, per call / 4 KiB", goal, measured, ok))
    return rows


def _scaling_ratios(
    all_runs: list[list[dict[str, Any]]], n: int, delivery: str, floor: str = "floor"
) -> dict[tuple[str, str], list[float]]:
    """CPU / floor (same run, same loop, same N) of each SDK configuration with
    ``delivery``, by (backend, loop), one value per run."""
    out: dict[tuple[str, str], list[float]] = {}
    for rows in all_runs:
        floors = {
            _loop(r): r["cpu_percent"] for r in rows if r["chassis"] == n and _is_floor(r, floor)
        }
        for r in rows:
            mine = r["chassis"] == n and "backend" in r and _delivery(r) == delivery
            if mine and (base := floors.get(_loop(r))):
                out.setdefault((r["backend"], _loop(r)), []).append(r["cpu_percent"] / base)
    return out


def cpu_rows(report: dict[str, Any]) -> list[Row]:
    all_runs = runs(report, "scaling.py")
    rows: list[Row] = []
    for n in CPU_ROWS:
        ratios = _scaling_ratios(all_runs, n, "callback")
        ok = _all_met((_med(v) for v in ratios.values()), lambda x: x <= 1.5)
        rows.append(
            (
                f"CPU per chassis at 50 Hz vs the raw reader, callback delivery, N = {n}",
                "≤ 1.5× (median of the runs)",
                _by_config(ratios),
                ok,
            )
        )
    for n in CPU_ROWS:
        ratios = _scaling_ratios(all_runs, n, "async for")
        ok = _all_met((_med(v) for v in ratios.values()), lambda x: x <= 1.8)
        rows.append(
            (
                f"the same with `async for`, N = {n}",
                "≤ 1.8× (median of the runs)",
                _by_config(ratios),
                ok,
            )
        )
        woken = _scaling_ratios(all_runs, n, "async for", "wake")
        ok = _all_met((_med(v) for v in woken.values()), lambda x: x <= 1.35)
        rows.append(
            (
                f"the same with `async for` vs the reader-plus-task-wake floor, N = {n}",
                "≤ 1.35× (median of the runs)",
                _by_config(woken),
                ok,
            )
        )
    return rows


def capacity_rows(report: dict[str, Any], n: int = 512) -> list[Row]:
    """CPU % at ``n`` chassis, nothing lost (no sequence gap, drop or logged error, and
    at least 99 % of the window's frames delivered: the window's edges cut a frame or
    two), on every transport, for each delivery."""
    all_runs = runs(report, "scaling.py")
    rows: list[Row] = []
    for delivery in ("callback", "async for"):
        cpu: dict[tuple[str, str], list[float]] = {}
        lost: list[str] = []
        for rows_of_run in all_runs:
            for r in rows_of_run:
                if r["chassis"] == n and "backend" in r and _delivery(r) == delivery:
                    cpu.setdefault((r["backend"], _loop(r)), []).append(r["cpu_percent"])
                    if r["errors"] or r["got"] < 0.99:
                        lost.append(
                            f"{r['backend']} {_loop(r)}: {r['got'] * 100:.1f} % delivered, "
                            f"{r['errors']} errors"
                        )
        floors = [
            r["cpu_percent"]
            for rows_of_run in all_runs
            for r in rows_of_run
            if r["chassis"] == n and _is_floor(r) and _loop(r) == "asyncio"
        ]
        measured = _by_config(cpu, " %", 0)
        if cpu:
            measured += f" (floor, asyncio: {mmm(floors, ' %', 0)})"
            measured += f"; lost: {', '.join(lost)}" if lost else "; nothing lost in any run"
        ok = _all_met((_med(v) for v in cpu.values()), lambda x: x <= 70)
        if ok is not None and lost:
            ok = False
        rows.append(
            (
                f"{n} chassis at 50 Hz in one process, nothing lost, every transport, "
                f"{delivery} delivery",
                "one core at most 70 % busy",
                measured,
                ok,
            )
        )
    return rows


def mqtt_rows(report: dict[str, Any], n: int = 50) -> list[Row]:
    results = runs(report, "mqtt_fleet.py")
    fleets = [f for r in results for f in r.get("fleets", []) if f["n"] == n]
    floors = [r["floor"]["p99"] for r in results if "floor" in r]
    rate = {f"{f['rate']:g}" for f in fleets}
    cpu = [f["cpu"] for f in fleets]
    p99 = [f["p99"] for f in fleets]
    delivered = [f["delivered"] / f["expected"] * 100 for f in fleets]
    if fleets:
        measured = (
            f"bridge CPU {mmm(cpu, ' %', 0)}; command → wire p99 {mmm(p99, ' ms', 1)} "
            f"(floor, mosquitto alone: {mmm(floors, ' ms', 1)}); telemetry delivered "
            f"{mmm(delivered, ' %', 0)} of {n} × {'/'.join(sorted(rate))} a second"
        )
    else:
        measured = NOT_MEASURED + (" (quick mode has no 50)" if report.get("quick") else "")
    mc, mp = _med(cpu), _med(p99)
    ok = None if mc is None or mp is None else mc <= 25 and mp <= 5
    return [
        (
            f"one MQTT bridge process, {n} robots at 50 Hz (simulators in another process)",
            "bridge CPU ≤ 25 % of a core; command → wire p99 ≤ 5 ms",
            measured,
            ok,
        )
    ]


def replay_rows(report: dict[str, Any]) -> list[Row]:
    results = runs(report, "recording.py")
    hours = [r.get("hour", {}) for r in results]
    formats = sorted({f for h in hours for f in h})
    plain, as_json = [], []
    meds_plain, meds_json = [], []
    for f in formats:
        mine = [h[f] for h in hours if f in h]
        s = [x["replay_s"] for x in mine]
        j = [x["replay_json_s"] for x in mine]
        mb = [x["replay_mb"] for x in mine]
        floor = [x["floor_s"] for x in mine]
        plain.append(
            f"{f} {mmm(s, ' s', 1)} (peak {mmm(mb, ' MB', 0)}; floor {mmm(floor, ' s', 2)})"
        )
        as_json.append(f"{f} {mmm(j, ' s', 1)}")
        meds_plain.append(_med(s))
        meds_json.append(_med(j))
    scaled = (
        " (a tenth of an hour: one start-up plus ten times the rest)"
        if report.get("quick") and formats
        else ""
    )
    measured = (
        f"`replay`: {'; '.join(plain) or NOT_MEASURED}. "
        f"`--json`: {'; '.join(as_json) or NOT_MEASURED}"
    )
    ok_plain = _all_met(meds_plain, lambda x: x <= 2)
    ok_json = _all_met(meds_json, lambda x: x <= 4)
    ok = None if ok_plain is None or ok_json is None else ok_plain and ok_json
    return [
        (
            "`replay` / `replay --json` of a 1 h capture (180,000 frames)" + scaled,
            "≤ 2 s / ≤ 4 s",
            measured,
            ok,
        )
    ]


def _p99(key: str, result: dict[str, Any]) -> float:
    return float(result[key]["p99"])


def latency_rows(report: dict[str, Any]) -> list[Row]:
    results = runs(report, "latency.py")

    def versus_floor(
        figure: Callable[[dict[str, Any]], float],
    ) -> dict[tuple[str, str], list[float]]:
        out: dict[tuple[str, str], list[float]] = {}
        for result in results:
            for loop, r in result.items():
                try:
                    base = figure(r["floor"])
                except KeyError:
                    continue
                for sdk in r["sdk"]:
                    out.setdefault((sdk["backend"], loop), []).append(figure(sdk) / base)
        return out

    rows: list[Row] = []
    for key, label, context, context_label in (
        (
            "latency",
            "write → `async for` p99 vs its floor, every transport",
            lambda r: float(r["inside"]["p50"]),
            "of it, read callback → `async for` p50 vs the floor's",
        ),
        (
            "round_trip",
            "request round trip p99 vs its floor, every transport",
            lambda r: float(r["round_trip_cpu_us"]),
            "request round trip, CPU per call vs the floor's",
        ),
    ):
        goal = versus_floor(functools.partial(_p99, key))
        ok = _all_met((_med(v) for v in goal.values()), lambda x: x <= 1.2)
        rows.append((label, "≤ 1.2×", _by_config(goal), ok))
        if ratios := versus_floor(context):
            rows.append((context_label, "(context)", _by_config(ratios), None))
    return rows


def table(report: dict[str, Any]) -> list[str]:
    """The goals table's lines (markdown)."""
    rows = [
        *decoder_rows(report),
        *cpu_rows(report),
        *capacity_rows(report),
        *mqtt_rows(report),
        *replay_rows(report),
        *latency_rows(report),
    ]
    k = report.get("runs", 1)
    lines = ["| figure | target | measured: min / **median** / max over the runs | |"]
    lines.append("|---|---|---|---|")
    lines += [
        f"| {f} | {t} | {m} | {'' if t == '(context)' else _met(ok)} |" for f, t, m, ok in rows
    ]
    machine = report["machine"]
    quick = " Quick mode: shorter windows, fewer samples." if report.get("quick") else ""
    load = []
    for name, entry in report["scripts"].items():
        one = [float(r["load_before"].split()[0]) for r in entry.get("runs", [entry])]
        one += [float(r["load_after"].split()[0]) for r in entry.get("runs", [entry])]
        load.append(f"{name} {min(one):.2f}-{max(one):.2f}")
    lines += [
        "",
        f"{k} run{'s' if k != 1 else ''} of each script behind a goal, interleaved; met or "
        "not on the median of the runs (a figure of several transports and loops: on "
        "each one's median; nothing lost: in every run)." + quick,
        f"Decoding path: {machine.get('decoding path', 'not recorded')}. Measured "
        f"{machine['date']}, commit {machine['commit']}, {machine['cpu']}, {machine['python']}; "
        f"packages: {machine.get('packages', 'not recorded')}; load average (1 min) over "
        f"each script's runs: {', '.join(load)}.",
    ]
    return lines


# -- the scaling table and figure -----------------------------------------------------


def median_rows(all_runs: list[list[dict[str, Any]]]) -> list[dict[str, Any]]:
    """One row per (N, configuration): the median over the runs of each figure (the
    most errors of any run)."""
    groups: dict[tuple[int, str], list[dict[str, Any]]] = {}
    for rows in all_runs:
        for r in rows:
            groups.setdefault((r["chassis"], r["config"]), []).append(r)
    out = []
    for group in groups.values():
        row = dict(group[0])
        for key, value in group[0].items():
            if key == "errors":
                row[key] = max(r[key] for r in group)
            elif isinstance(value, float) and all(key in r for r in group):
                row[key] = statistics.median(r[key] for r in group)
        row["runs"] = len(group)
        out.append(row)
    return out


def scaling_table(report: dict[str, Any]) -> list[str]:
    """The scaling table's lines (markdown): every configuration at each of
    :data:`SCALING_ROWS` chassis, its CPU as a ratio to the floor on the same loop
    (medians of the runs)."""
    rows = median_rows(runs(report, "scaling.py"))
    floors = {(r["chassis"], _loop(r)): r for r in rows if _is_floor(r)}
    woken = {(r["chassis"], _loop(r)): r for r in rows if _is_floor(r, "wake")}
    lines = [
        "| N | configuration | CPU (one core = 100 %) | × floor | frames delivered "
        "| lag p50 / p99 | errors |",
        "|---|---|---|---|---|---|---|",
    ]
    for n in SCALING_ROWS:
        loops = sorted({loop for (m, loop) in floors if m == n})
        if not loops:
            continue
        cells = " / ".join(f"{floors[(n, loop)]['cpu_percent']:.1f} %" for loop in loops)
        lines.append(f"| {n} | floor, {' / '.join(loops)} | {cells} | | 100 % | | 0 |")
        for loop in loops:
            if w := woken.get((n, loop)):
                base = floors[(n, loop)]["cpu_percent"]
                lines.append(
                    f"| {n} | floor + task wake, {loop} | {w['cpu_percent']:.1f} % | "
                    f"{w['cpu_percent'] / base:.2f}× | {w['got'] * 100:.1f} % | | {w['errors']} |"
                )
        for r in rows:
            if r["chassis"] == n and "backend" in r and (n, _loop(r)) in floors:
                floor = floors[(n, _loop(r))]["cpu_percent"]
                lag = (
                    f"{r['lag_p50_ms']:.2f} / {r['lag_p99_ms']:.2f} ms" if "lag_p50_ms" in r else ""
                )
                lines.append(
                    f"| {n} | {r['backend']}, {_delivery(r)}, {_loop(r)} | "
                    f"{r['cpu_percent']:.1f} % | {r['cpu_percent'] / floor:.2f}× | "
                    f"{r['got'] * 100:.1f} % | {lag} | {r['errors']} |"
                )
    k = len(runs(report, "scaling.py"))
    if k > 1:
        lines += ["", f"Medians of {k} runs (errors: the most of any run)."]
    return lines


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

        rows = median_rows(runs(report, "scaling.py"))
        plot(rows, args.plot)
        Path(args.plot).with_suffix(".json").write_text(json.dumps(rows, indent=1))
        print(f"drew {args.plot}")


if __name__ == "__main__":
    main()
