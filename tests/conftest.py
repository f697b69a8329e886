"""The event loop the tests run on: asyncio's own, or uvloop with
``CHASSIS_SDK_TEST_LOOP=uvloop`` (CI runs the integration tests on it once); the
markers' plugin (what each marker means, and the check that every test carries the
ones it needs) and the ``netns`` marker's plugin."""

from __future__ import annotations

import os
from collections.abc import Callable, Mapping

import pytest
from hypothesis import settings

# Hypothesis's deadline (200 ms an example by default) is a wall-clock assertion: under
# pytest-xdist's load it fails for the machine, not the code (how fast the code is, the
# benchmarks measure). Off for every property test.
settings.register_profile("chassis_sdk", deadline=None)
settings.load_profile("chassis_sdk")

# The markers (tests/support/markers.py), and `netns`: a test in a network namespace of
# its own, loopback only (tests/support/netns.py).
pytest_plugins = ("tests.support.markers", "tests.support.netns")

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
