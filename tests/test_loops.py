"""``chassis_sdk.run`` and the event loop it runs on: uvloop when installed; a device
object works in whichever event loop it is connected in; a user's script under it ends
in one line on a timeout, and quietly with the robot stopped on Ctrl-C."""

from __future__ import annotations

import asyncio
import importlib.util
import re
import signal
import socket
import struct
import sys
import textwrap
import time
from pathlib import Path

import pytest

import chassis_sdk
from chassis_sdk import Chassis, ConnectionState
from chassis_sdk.protocol import DriveVelocity
from chassis_sdk.sim import ChassisSimulator

from .support.cli import ROOT
from .support.helpers import ThreadedPeer, drives, until
from .support.standin import is_zero_drive


async def _loop_module() -> str:
    return type(asyncio.get_running_loop()).__module__


@pytest.mark.uvloop
def test_run_uses_uvloop_when_it_is_installed(monkeypatch: pytest.MonkeyPatch) -> None:
    pytest.importorskip("uvloop")
    monkeypatch.delenv("CHASSIS_SDK_LOOP", raising=False)
    assert chassis_sdk.run(_loop_module()).startswith("uvloop")
    assert chassis_sdk.run(_loop_module(), uvloop=True).startswith("uvloop")
    assert chassis_sdk.run(_loop_module(), uvloop=False).startswith("asyncio")
    monkeypatch.setenv("CHASSIS_SDK_LOOP", "asyncio")
    assert chassis_sdk.run(_loop_module()).startswith("asyncio")


def test_run_without_uvloop(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(sys.modules, "uvloop", None)  # as if not installed
    assert chassis_sdk.run(_loop_module()).startswith("asyncio")
    with pytest.raises(ImportError, match=re.escape('pip install -e ".[uvloop]"')):
        chassis_sdk.run(_loop_module(), uvloop=True)


@pytest.mark.uvloop
@pytest.mark.integration
def test_a_chassis_drives_and_stops_on_uvloop() -> None:
    pytest.importorskip("uvloop")

    async def drive() -> tuple[str, list[object]]:
        async with ChassisSimulator() as sim:
            async with Chassis(sim.port) as robot:
                await robot.set_velocity(0.2, 0.0)
                n = 0
                async for _ in robot.telemetry():
                    n += 1
                    if n == 10:
                        break
                assert await robot.get_firmware_version() > 0
            return await _loop_module(), [c for _, c in sim.firmware.received]

    module, received = chassis_sdk.run(drive(), uvloop=True)
    assert module.startswith("uvloop")
    from chassis_sdk.protocol import DriveVelocity

    drives = [c for c in received if isinstance(c, DriveVelocity)]
    assert drives[0].linear_mm == 200
    assert drives[-1] == DriveVelocity(0, 0.0)


@pytest.mark.uvloop
async def test_the_tests_run_on_the_loop_asked_for() -> None:
    import os

    wanted = os.environ.get("CHASSIS_SDK_TEST_LOOP", "asyncio")
    assert (await _loop_module()).startswith(wanted)


def _loops() -> list[object]:
    return [
        pytest.param(False, id="asyncio"),
        pytest.param(
            True,
            id="uvloop",
            marks=pytest.mark.skipif(
                importlib.util.find_spec("uvloop") is None, reason="uvloop is not installed"
            ),
        ),
    ]


@pytest.mark.integration
@pytest.mark.parametrize("how", ["unplug", "peer reset"])
@pytest.mark.parametrize("use_uvloop", _loops())
def test_the_simulator_survives_writing_to_a_client_whose_transport_closed(
    use_uvloop: bool, how: str
) -> None:
    """uvloop raises RuntimeError on a write to a closed transport where asyncio ignores
    it. The simulator's clock writes to every TCP client; a client closed by ``unplug``
    or reset by its peer stays in the set until its reader task runs, so a write in
    between used to kill the clock and re-raise from ``stop``."""

    async def scenario() -> int:
        async with ChassisSimulator(tcp_port=0) as sim:
            host, port = sim.port.removeprefix("socket://").rsplit(":", 1)
            reader, writer = await asyncio.open_connection(host, int(port))
            assert await reader.read(1)  # connected and served: telemetry flows
            if how == "unplug":
                sim.unplug()  # closes the client's transport; its reader task has not run
            else:  # the host dies with bytes unread: the kernel sends a reset
                sock = writer.get_extra_info("socket")
                sock.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))
                writer.transport.abort()
            for _ in range(20):  # a write on every loop turn while the close completes
                sim.send(b"\x00" * 8)
                await asyncio.sleep(0)
            discarded = sim.bytes_discarded
            while sim.bytes_discarded == discarded:  # the clock still runs
                await asyncio.sleep(0.01)
            writer.close()
            return sim.bytes_discarded

    assert chassis_sdk.run(scenario(), uvloop=use_uvloop) > 0


@pytest.mark.integration
@pytest.mark.parametrize("use_uvloop", _loops())
def test_the_simulator_holds_replies_back_at_least_the_delay_asked(use_uvloop: bool) -> None:
    """uvloop's timers fire up to a millisecond early (libuv's clock is whole
    milliseconds, read at the start of a loop turn: MagicStack/uvloop#739); a fault
    that promises "held back 10 ms" must not answer in 9.4."""
    delay = 0.01

    async def scenario() -> list[float]:
        async with ChassisSimulator() as sim:
            sim.faults.reply_delay = delay
            async with Chassis(sim.port, request_timeout=1.0) as robot:
                times = []
                for _ in range(80):
                    t0 = time.monotonic()
                    await robot.get_firmware_version()
                    times.append(time.monotonic() - t0)
                return times

    times = chassis_sdk.run(scenario(), uvloop=use_uvloop)
    assert min(times) >= delay, sorted(times)[:5]


# --- a device object works in any event loop it is connected in ----------------------------------


@pytest.mark.integration
def test_a_device_works_in_a_second_event_loop() -> None:
    peer = ThreadedPeer()
    robot = Chassis(peer.port, command_timeout=0.2)
    try:

        async def session() -> None:
            async with robot:
                await robot.set_velocity(0.2, 0.0)
                resends = robot.stats.resends
                expiries = robot.stats.command_expiries
                await until(lambda: robot.stats.resends >= resends + 3)
                await until(lambda: robot.stats.command_expiries > expiries)
                assert robot.connection_state is ConnectionState.CONNECTED
                assert await robot.wait_for(lambda t: True, 1.0)

        asyncio.run(session())
        first = len(peer.drive_frames())
        asyncio.run(session())  # a new loop: the same object must work in it
        # The close's zero is the last frame (it may still be on its way).
        peer.wait_for(lambda frames: len(frames) > first + 3 and is_zero_drive(frames[-1]))
        frames = peer.drive_frames()
        assert sum(not is_zero_drive(f) for f in frames[first:]) >= 3  # resends in loop 2
    finally:
        peer.close()


# --- user scripts under chassis_sdk.run ----------------------------------------------------


async def _script(tmp_path: Path, body: str, *args: str) -> tuple[asyncio.subprocess.Process, Path]:
    path = tmp_path / "operator_script.py"
    path.write_text(textwrap.dedent(body))
    proc = await asyncio.create_subprocess_exec(
        sys.executable, str(path), *args, cwd=ROOT,
        stdout=asyncio.subprocess.PIPE, stderr=asyncio.subprocess.PIPE,
    )  # fmt: skip
    return proc, path


def _script_line(err: str) -> str:
    """The whole of stderr is one line named after the script, with no traceback."""
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert lines[0].startswith("operator_script.py: "), err
    return lines[0]


@pytest.mark.integration
async def test_row2_wait_for_times_out_with_an_sdk_error_on_one_line(tmp_path: Path) -> None:
    async with ChassisSimulator() as sim:
        proc, _ = await _script(
            tmp_path,
            """
            import sys
            import chassis_sdk

            async def main() -> None:
                async with chassis_sdk.Chassis(sys.argv[1]) as robot:
                    await robot.wait_for(lambda t: False, timeout=0.3)

            chassis_sdk.run(main(), one_line_errors=True)
            """,
            sim.port,
        )
        async with asyncio.timeout(20):
            _, err = await proc.communicate()
    assert proc.returncode == 2, err  # the timeout's status, as for a request's
    assert "no telemetry satisfied the condition in 0.3 s" in _script_line(err.decode())


@pytest.mark.integration
async def test_row22_ctrl_c_in_a_script_is_quiet_exit_130_and_the_robot_stopped(
    tmp_path: Path,
) -> None:
    async with ChassisSimulator() as sim:
        proc, _ = await _script(
            tmp_path,
            """
            import asyncio
            import sys
            import chassis_sdk

            async def main() -> None:
                async with chassis_sdk.Chassis(sys.argv[1]) as robot:
                    await robot.set_velocity(0.3, 0.0)
                    print("driving", flush=True)
                    while True:
                        await robot.set_velocity(0.3, 0.0)
                        await asyncio.sleep(0.05)

            chassis_sdk.run(main(), one_line_errors=True)
            """,
            sim.port,
        )
        assert proc.stdout is not None
        async with asyncio.timeout(20):
            assert await proc.stdout.readline() == b"driving\n"
            proc.send_signal(signal.SIGINT)
            _, err = await proc.communicate()
            while not drives(sim) or drives(sim)[-1] != DriveVelocity(0, 0.0):
                await asyncio.sleep(0.01)
    assert proc.returncode == 130
    assert err.decode() == ""  # quiet: no KeyboardInterrupt traceback
    assert any(d.linear_mm == 300 for d in drives(sim))
