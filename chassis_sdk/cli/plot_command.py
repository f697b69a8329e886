"""``chassis-sdk plot``: draw a capture into a PNG (the device's own ``plot`` if its
commands have one, else every numeric field of every message, by type)."""

from __future__ import annotations

import argparse
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from ..devices import profile
from ..recording import capture
from .arguments import device_arg
from .captures import detect_file, no_messages, require_reader, writable
from .common import jsonable, out, show_warnings
from .devices import commands
from .extras import install_hint, require

if TYPE_CHECKING:
    from .arguments import Job, Subparsers

__all__ = ["add_parser", "plot"]


def add_parser(sub: Subparsers, names: Sequence[str]) -> None:
    """Register ``plot``."""
    p = sub.add_parser(
        "plot",
        help=f"plot a capture: velocities, wheel speeds, voltage, ... ({install_hint('plot')})",
    )
    p.add_argument("file")
    p.add_argument(
        "-o", "--output", help="the PNG to write (default: beside FILE, as FILE's name .png)"
    )
    device_arg(p, names, detected=True)
    p.set_defaults(func=_start)


def _start(args: argparse.Namespace) -> Job:
    require("plot", "plot")
    require_reader("plot", args.file)
    output = args.output or beside(args.file)
    writable(output, "-o" if args.output else "")  # before the capture is read
    show_warnings("chassis_sdk.recording.capture", "plot")  # a capture cut short
    plot(args.file, output, args.device)
    return None


def beside(path: str) -> str:
    """Where a plot of the capture ``path`` goes by default: next to it, named like
    it (``rec/run.jsonl`` -> ``rec/run.png``), not in the current directory."""
    return str(Path(path).with_suffix(".png"))


def plot(path: str, output: str, device: str | None) -> None:
    """Draw the capture ``path`` (of ``device``, else detected) into ``output``.

    Raises:
        ChassisError: The capture holds no frames of the device.
        ImportError: The plot extra is missing (``chassis-sdk plot`` checks it first:
            `chassis_sdk.cli.extras.require`).
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    proto = device or detect_file(path)
    profile(proto)  # an unknown name fails here, naming the known ones
    fig = plt.figure(figsize=(13, 9))
    draw = commands(proto).plot
    if draw is not None:  # from arrays: an hour's frames, no object apiece
        data = capture.capture_columns(path, proto)
        sent_columns = capture.capture_columns(path, proto, commands=True)
        messages, sent = data.frames, sent_columns.frames
        if not messages:
            no_messages(path, proto)
        draw(data, sent_columns, fig)
    else:  # a generic device: every numeric field of every message, by type
        rows = list(capture.decode_capture(path, proto))
        if not rows:
            no_messages(path, proto)
        messages = len(rows)
        sent = sum(1 for _ in capture.decode_capture(path, proto, commands=True))
        _plot_fields(rows, fig)
    fig.suptitle(f"{proto} capture {path}")
    fig.tight_layout()
    fig.savefig(output, dpi=100)
    plt.close(fig)
    extra = f" and {sent} commands" if sent else ""
    out(f"wrote {output} ({messages} messages{extra})")


def _plot_fields(rows: list[tuple[float, object]], fig: Any) -> None:
    series: dict[str, tuple[list[float], list[float]]] = {}
    for t, msg in rows:
        for key, value in jsonable(msg).items():
            numeric = isinstance(value, int | float) and not isinstance(value, bool)
            if numeric and key != "timestamp":
                ts, ys = series.setdefault(f"{type(msg).__name__}.{key}", ([], []))
                ts.append(t)
                ys.append(float(value))
    names = sorted(series)[:6]
    axes = fig.subplots(max(len(names), 1), 1, sharex=True, squeeze=False)[:, 0]
    for ax, name in zip(axes, names, strict=False):
        ax.plot(*series[name])
        ax.set_ylabel(name, fontsize=8)
        ax.grid(True, alpha=0.3)
    axes[-1].set_xlabel("time since start of capture (s)")
