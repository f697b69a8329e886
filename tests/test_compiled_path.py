"""Which decoding path runs, and how a user finds out: `chassis-sdk --version` and
`info` say it; ``CHASSIS_SDK_PURE=1`` forces the pure path. The differential tests of
the two paths are in tests/test_compiled_chassis.py and tests/test_compiled_board.py."""

from __future__ import annotations

import importlib.util
import os
import re
import subprocess
import sys

import pytest

from chassis_sdk.sim import BoardSimulator, ChassisSimulator

MODULES = ["chassis_sdk.devices.chassis._compiled", "chassis_sdk.devices.board._compiled"]


def built() -> bool:
    """Whether both protocols' extensions are importable here."""
    return all(importlib.util.find_spec(name) is not None for name in MODULES)


def cli(*args: str, pure: bool = False, timeout: float = 30) -> subprocess.CompletedProcess[str]:
    env = {k: v for k, v in os.environ.items() if k != "CHASSIS_SDK_PURE"}
    if pure:
        env["CHASSIS_SDK_PURE"] = "1"
    return subprocess.run(
        [sys.executable, "-m", "chassis_sdk.cli", *args],
        capture_output=True,
        text=True,
        env=env,
        timeout=timeout,
        check=False,
    )


def expected_path() -> str:
    return "compiled" if built() else "pure (not built)"


@pytest.mark.integration
def test_version_says_which_decoders_run() -> None:
    done = cli("--version")
    assert done.returncode == 0, done.stderr
    line = done.stdout.strip()
    assert re.fullmatch(r"chassis-sdk \S+ \(Python 3\.\d+\.\d+, decoders: .+\)", line), line
    assert line.endswith(f"decoders: {expected_path()})"), line


@pytest.mark.integration
def test_chassis_sdk_pure_forces_the_pure_path() -> None:
    done = cli("--version", pure=True)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip().endswith("decoders: pure (CHASSIS_SDK_PURE=1))")
    probe = (
        "from chassis_sdk.core import compiled; from chassis_sdk.core.framing import FrameDecoder;"
        "from chassis_sdk.protocol import BoardDecoder, ChassisDecoder;"
        "print(compiled.status(), ChassisDecoder.feed is FrameDecoder.feed,"
        " BoardDecoder.feed is FrameDecoder.feed)"
    )
    env = {**os.environ, "CHASSIS_SDK_PURE": "1"}
    out = subprocess.run(
        [sys.executable, "-c", probe], capture_output=True, text=True, env=env, check=True
    ).stdout
    assert out.split() == ["pure", "(CHASSIS_SDK_PURE=1)", "True", "True"]


@pytest.mark.skipif(not built(), reason="the compiled fast path is not built here")
def test_when_built_the_module_decoders_use_it() -> None:
    from chassis_sdk.core import compiled
    from chassis_sdk.core.framing import FrameDecoder
    from chassis_sdk.protocol import (
        BoardCommandDecoder,
        BoardDecoder,
        ChassisCommandDecoder,
        ChassisDecoder,
    )

    if compiled.forced_pure():
        pytest.skip("CHASSIS_SDK_PURE is set")
    assert compiled.status() == "compiled"
    for cls in (ChassisDecoder, ChassisCommandDecoder, BoardDecoder, BoardCommandDecoder):
        assert cls.feed is not FrameDecoder.feed, cls


@pytest.mark.integration
@pytest.mark.parametrize("simulator", [ChassisSimulator, BoardSimulator])
@pytest.mark.parametrize("pure", [False, True])
async def test_info_names_the_decoders(
    simulator: type[ChassisSimulator] | type[BoardSimulator], pure: bool
) -> None:
    import anyio

    device = "board" if simulator is BoardSimulator else "chassis"
    async with simulator() as sim:
        done = await anyio.to_thread.run_sync(
            lambda: cli("info", sim.port, "--device", device, pure=pure)
        )
    assert done.returncode == 0, done.stderr
    lines = done.stdout.splitlines()
    assert lines[0].startswith("port ")
    shown = "pure (CHASSIS_SDK_PURE=1)" if pure else expected_path()
    assert lines[1] == f"decoders     {shown}"
