"""What every device's ``plot`` shares: the layout (time series on the left, the path
on the right), measured against commanded, the odometry path, and saying so when a
panel has nothing to show."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

from ..core.odometry import OdometryIntegrator

__all__ = ["empty", "layout", "path_panel", "series", "velocity_panels"]

Rows = Sequence[tuple[float, object]]


def layout(fig: Any, panels: int) -> tuple[list[Any], Any]:
    """``panels`` time-series axes down the left (sharing time), one path axis right."""
    grid = fig.add_gridspec(panels, 2, width_ratios=(2.2, 1))
    left: list[Any] = []
    for i in range(panels):
        left.append(fig.add_subplot(grid[i, 0], sharex=left[0] if left else None))
    for ax in left:
        ax.grid(True, alpha=0.3)
    left[-1].set_xlabel("time since start of capture (s)")
    return left, fig.add_subplot(grid[:, 1])


def series(
    rows: Rows, kind: type, field: str, scale: float = 1.0
) -> tuple[list[float], list[float]]:
    """(times, values) of ``field`` of every message of type ``kind``."""
    picked = [(t, m) for t, m in rows if isinstance(m, kind)]
    return [t for t, _ in picked], [getattr(m, field) * scale for _, m in picked]


def empty(ax: Any, text: str) -> None:
    """Say why a panel is empty, instead of leaving it blank."""
    ax.text(0.5, 0.5, text, transform=ax.transAxes, ha="center", va="center", color="gray")


Series3 = tuple[list[float], list[float], list[float]]


def velocity_panels(
    linear_ax: Any,
    angular_ax: Any,
    rows: Rows,
    kind: type,
    commands: Rows,
    command_kind: type,
    command_si: Callable[[Any], tuple[float, float]],
) -> Series3:
    """Measured linear (m/s) and angular (rad/s) velocity (the ``linear`` and
    ``angular`` of every ``kind`` message) on their own axes, each with what the host
    commanded (``command_si`` of every ``command_kind``: m/s and rad/s) when the capture
    holds it, as a step line: a command holds until the next. Returns the measured
    (times, linear, angular)."""
    t, v = series(rows, kind, "linear")
    _, w = series(rows, kind, "angular")
    drives = [(ts, command_si(c)) for ts, c in commands if isinstance(c, command_kind)]
    ct = [ts for ts, _ in drives]
    cv = [vw[0] for _, vw in drives]
    cw = [vw[1] for _, vw in drives]
    for ax, values, wanted, unit in ((linear_ax, v, cv, "m/s"), (angular_ax, w, cw, "rad/s")):
        ax.plot(t, values, label="measured")
        if ct:
            ax.step(ct, wanted, where="post", linestyle="--", label="commanded")
        ax.set_ylabel(f"{'linear' if unit == 'm/s' else 'angular'} ({unit})")
        ax.legend(loc="upper right", fontsize=8)
    return t, v, w


def path_panel(ax: Any, t: list[float], v: list[float], w: list[float]) -> None:
    """The path dead-reckoned from the measured velocities (x forward at the start)."""
    odometry = OdometryIntegrator()
    xs, ys = [0.0], [0.0]
    for ts, linear, angular in zip(t, v, w, strict=True):
        pose = odometry.update(linear, angular, ts)
        xs.append(pose.x)
        ys.append(pose.y)
    ax.set_title("path from odometry", fontsize=10)
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_aspect("equal", adjustable="datalim")
    ax.grid(True, alpha=0.3)
    if len(xs) < 3:
        empty(ax, "no velocity samples")
        return
    ax.plot(xs, ys)
    ax.plot(xs[:1], ys[:1], "o", color="green", label="start")
    ax.plot(xs[-1:], ys[-1:], "s", color="red", label="end")
    ax.legend(loc="best", fontsize=8)
