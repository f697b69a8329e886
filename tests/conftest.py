"""The event loop the tests run on: asyncio's own, or uvloop with
``CHASSIS_SDK_TEST_LOOP=uvloop`` (CI runs the integration tests on it once); the
markers' plugin (what each marker means, and the check that every test carries the
ones it needs) and the ``netns`` marker's plugin."""

from __future__ import annotations

import os
from collections.abc import Callable, Iterator, Mapping

import pytest
from hypothesis import settings

from .support.netns import IN_NETNS

# Hypothesis's deadline (200 ms an example by default) is a wall-clock assertion: under
# pytest-xdist's load it fails for the machine, not the code (how fast the code is, the
# benchmarks measure). Off for every property test.
settings.register_profile("chassis_sdk", deadline=None)
settings.load_profile("chassis_sdk")

# The markers (tests/support/markers.py), and `netns`: a test in a network namespace of
# its own, loopback only (tests/support/netns.py).
pytest_plugins = ("tests.support.markers", "tests.support.netns")


def pytest_collection_finish(session: pytest.Session) -> None:
    """Build the DDS peers (each Fast DDS's, `tests.support.dds_peer`) before the first
    test that talks to one, when any is selected: a cold build takes up to a minute,
    which inside a test would be taken from its time (a bridge started for 8 s would be
    gone before its peer). Cached builds cost nothing; one that cannot be made is left
    to the tests, which fail saying why. (A test re-run in a network namespace finds
    them built by the run that started it.)"""
    if os.environ.get(IN_NETNS) == "1" or session.config.option.collectonly:
        return
    if not any(item.get_closest_marker("ros2") is not None for item in session.items):
        return
    from .support.dds_peer import FAST_DDS, build_peer

    for major in FAST_DDS:
        try:
            build_peer(major)
        except RuntimeError as exc:
            print(f"\n{exc}")


@pytest.fixture
def fast_dds(request: pytest.FixtureRequest) -> Iterator[int]:
    """The Fast DDS major version this test's peers run: each of `FAST_DDS` where a
    test is parametrized with it (``indirect=True``, ids `FAST_DDS_IDS`), else 2. The
    default is put back after it, so no other test of this process inherits it."""
    from .support.dds_peer import use_fast_dds

    major: int = getattr(request, "param", 2)
    use_fast_dds(major)
    yield major
    use_fast_dds(2)


if os.environ.get("CHASSIS_SDK_TEST_LOOP") == "uvloop":
    import asyncio
    import importlib

    uvloop = importlib.import_module("uvloop")  # installed for this run only

    @pytest.hookimpl(tryfirst=True)
    def pytest_configure(config: pytest.Config) -> None:
        # pytest-timeout's default method (SIGALRM) never fires while uvloop's loop waits
        # in C with nothing to do: the Python handler runs only when bytecode does, so a
        # hung test hung CI. A thread times it out instead (ending the process: xdist
        # reports the test and starts another worker).
        if config.getvalue("timeout_method") is None:
            config.option.timeout_method = "thread"

    def pytest_asyncio_loop_factories(
        config: pytest.Config, item: pytest.Item
    ) -> Mapping[str, Callable[[], asyncio.AbstractEventLoop]]:
        factory: Callable[[], asyncio.AbstractEventLoop] = uvloop.new_event_loop
        return {"uvloop": factory}
