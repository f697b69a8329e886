"""What every device's ``plot`` shares: the layout (time series on the left, the path
on the right), measured against commanded, the odometry path, and saying so when a
panel has nothing to show.

A plot draws from [`Columns`][chassis_sdk.recording.columns.Columns]: the capture decoded into
arrays (``capture_columns``), so an hour's 180,000 frames are drawn without building
an object per frame."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING, Any

from ..core.odometry import OdometryIntegrator

if TYPE_CHECKING:
    import numpy.typing as npt

    from ..recording.columns import Columns

    #: A column, or values listed: what matplotlib draws.
    Values = Sequence[float] | npt.NDArray[Any]

__all__ = ["empty", "layout", "path_panel", "series", "velocity_panels"]


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


def series(data: Columns, kind: str, field: str) -> tuple[Values, Values]:
    """(times, values) of column ``field`` of message type ``kind`` (empty if none)."""
    table = data.tables.get(kind)
    if table is None:
        return [], []
    return table["t"], table[field]


def empty(ax: Any, text: str) -> None:
    """Say why a panel is empty, instead of leaving it blank."""
    ax.text(0.5, 0.5, text, transform=ax.transAxes, ha="center", va="center", color="gray")


Series3 = tuple["Values", "Values", "Values"]


def velocity_panels(
    linear_ax: Any,
    angular_ax: Any,
    data: Columns,
    kind: str,
    commands: Columns,
    command_kind: type,
    command_si: Callable[[Any], tuple[float, float]],
) -> Series3:
    """Measured linear (m/s) and angular (rad/s) velocity (the ``linear`` and
    ``angular`` columns of ``kind``) on their own axes, each with what the host
    commanded (``command_si`` of every ``command_kind`` message: m/s and rad/s) when
    the capture holds it, as a step line: a command holds until the next. Returns the
    measured (times, linear, angular)."""
    t, v = series(data, kind, "linear")
    _, w = series(data, kind, "angular")
    drives = [(ts, command_si(c)) for ts, c in commands.messages if isinstance(c, command_kind)]
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


def path_panel(ax: Any, t: Values, v: Values, w: Values) -> None:
    """The path dead-reckoned from the measured velocities (x forward at the start)."""
    odometry = OdometryIntegrator()
    xs, ys = [0.0], [0.0]
    for ts, linear, angular in zip(list(t), list(v), list(w), strict=True):
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
