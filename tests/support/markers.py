"""The markers that say what a test needs, and the checks that keep every test honest
about them (a pytest plugin; ``tests/conftest.py`` loads it, ``--strict-markers`` is on).

CI and ``noxfile.py`` select tests by these markers, never by lists of files, so a test
that opens a port without ``integration`` would silently drop out of the runs on the
other transports and loops. The plugin therefore watches what each test does while its
function-scoped fixtures and body run, and fails the test (at teardown, naming what it
did and the marker to add) when it:

- opens a pseudo-terminal (``os.openpty``), binds or connects a socket, or starts a
  process (``subprocess.Popen``, which asyncio's subprocesses use too) without
  ``integration``;
- starts mosquitto without ``mqtt``, Chromium without ``browser``, or speaks DDS (a
  Cyclone DDS participant, the Fast DDS peer) without ``ros2``; the support modules that
  do these call :func:`needs` (``tests/support/watch.py``, free of pytest, since the
  benchmarks use those modules too).

The check is armed before the test's fixtures are set up, so a module- or
session-scoped fixture counts for the first test that needs it. The test machinery's own
processes are :func:`exempt`: the netns plugin's child pytest (what a ``netns`` test
does is checked in the child that runs it) and its namespace's setup, and the docs'
build (``mkdocs``, not a port).

``timing`` cannot be detected: a test that asserts on wall-clock time carries it by
hand. Under pytest-xdist such tests are deselected (parallel load would make them lie);
``pytest -m timing`` runs them serially, as README and CI do after the parallel run.
A test over :data:`SLOW_SECONDS` without ``slow`` is listed at the end of a run.
"""

from __future__ import annotations

import os
import socket
import subprocess
from collections.abc import Callable, Iterator
from typing import Any

import pytest

from . import watch
from .watch import exempt, needs

__all__ = ["MARKERS", "SLOW_SECONDS", "exempt", "needs"]

#: Every marker a test may carry (``--strict-markers`` refuses any other), and what it says.
MARKERS = {
    "integration": "opens a real pty, socket or process (a transport, a simulator, the CLI)",
    "browser": "drives Debian's Chromium headless through Playwright",
    "mqtt": "runs a real mosquitto broker on loopback",
    "ros2": "speaks DDS: Cyclone DDS participants or the Fast DDS peer",
    "timing": "asserts on wall-clock time, or floods the machine from other processes: run "
    "serially (pytest -m timing), never under xdist",
    "slow": "takes more than about 5 s on its own",
    "codec": "sans-IO codecs: vectors, round trips, the contract, compiled vs pure",
    "uvloop": "about uvloop itself: CI's uvloop stage runs it (skips where uvloop is absent)",
    "surface": "a remote surface over the device (dashboard, Foxglove, teleop, the surface "
    "contract): its timing tests run on the default transport only",
}

#: A test that takes longer than this on its own should carry ``slow``.
SLOW_SECONDS = 5.0


def _watch(owner: Any, name: str, marker: str, what: Callable[..., str]) -> None:
    original = getattr(owner, name)

    def watched(*args: Any, **kwargs: Any) -> Any:
        needs(marker, what(*args, **kwargs))
        return original(*args, **kwargs)

    watched.__wrapped__ = original  # type: ignore[attr-defined]
    setattr(owner, name, watched)


def _argv(args: Any) -> str:
    if isinstance(args, str | bytes | os.PathLike):
        return os.fsdecode(args)
    return " ".join(os.fsdecode(a) for a in list(args)[:3])


def _install() -> None:
    _watch(os, "openpty", "integration", lambda: "opens a pty (os.openpty)")
    for name in ("bind", "connect", "connect_ex"):
        _watch(
            socket.socket,
            name,
            "integration",
            lambda sock, address, _n=name: f"calls socket.{_n}({address!r})",
        )
    _watch(
        subprocess.Popen,
        "__init__",
        "integration",
        lambda _self, *a, **k: f"starts a process ({_argv(a[0] if a else k.get('args', ''))})",
    )
    try:
        from cyclonedds.domain import DomainParticipant
    except ImportError:  # the ros2 extra is not installed: nothing can speak DDS
        return
    _watch(DomainParticipant, "__init__", "ros2", lambda *_a, **_k: "makes a DDS participant")


def pytest_configure(config: pytest.Config) -> None:
    for name, text in MARKERS.items():
        config.addinivalue_line("markers", f"{name}: {text}")
    _install()


def _under_xdist(config: pytest.Config) -> bool:
    return hasattr(config, "workerinput") or bool(getattr(config.option, "numprocesses", 0))


def pytest_report_header(config: pytest.Config) -> str | None:
    if _under_xdist(config):
        return "timing tests are deselected under xdist: run them serially with -m timing"
    return None


def pytest_xdist_auto_num_workers(config: pytest.Config) -> int:
    """``-n auto``: three workers a core, at most 8. Most tests spend their time waiting
    on ptys, sockets, processes and timers, not on the CPU (on 2 cores, all but the
    timing tests: 135 s with 6 workers, 176 s with 4, 296 s with 2).
    ``PYTEST_XDIST_AUTO_NUM_WORKERS`` still sets the number."""
    forced = os.environ.get("PYTEST_XDIST_AUTO_NUM_WORKERS", "")
    if forced.isdigit():
        return int(forced)
    return min(3 * len(os.sched_getaffinity(0)), 8)  # the cores this process may use


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    if not hasattr(config, "workerinput"):
        return
    # The slow tests first (a stable sort, the same on every worker), so that the
    # longest ones do not start last and leave the other workers idle at the end.
    items.sort(key=lambda item: item.get_closest_marker("slow") is None)
    timing = [item for item in items if item.get_closest_marker("timing") is not None]
    if timing:
        config.hook.pytest_deselected(items=timing)
        items[:] = [item for item in items if item.get_closest_marker("timing") is None]


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_setup(item: pytest.Item) -> Iterator[None]:
    """Arms the check before any fixture of the test is set up: a module- or
    session-scoped one that it is the first to need is its doing too."""
    watch.arm(item.get_closest_marker)
    yield


@pytest.fixture(autouse=True)
def _markers_kept() -> Iterator[None]:
    """Disarms the check after the test's function-scoped fixtures are torn down (it is
    set up first, so it is torn down last), and fails the test if it did something
    that its markers do not say."""
    try:
        yield
    finally:
        seen = watch.disarm()
    if seen:
        missing = ", ".join(f"{what}: mark it {marker}" for marker, what in seen.items())
        pytest.fail(f"markers: this test {missing} (tests/support/markers.py)", pytrace=False)


_durations: dict[str, float] = {}


def pytest_runtest_logreport(report: pytest.TestReport) -> None:
    if report.when == "call" and "slow" not in report.keywords:
        _durations[report.nodeid] = report.duration


def pytest_terminal_summary(terminalreporter: Any) -> None:
    over = sorted(((d, n) for n, d in _durations.items() if d > SLOW_SECONDS), reverse=True)
    if not over:
        return
    terminalreporter.section("tests over 5 s without the slow marker")
    for duration, nodeid in over:
        terminalreporter.write_line(f"{duration:6.1f} s  {nodeid}")
