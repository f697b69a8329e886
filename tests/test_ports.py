"""Ports that survive renumbering: the ``usb:VID:PID[:SERIAL]`` form, its lookup in
``serial.tools.list_ports.comports()`` (monkeypatched with pyserial's own
``ListPortInfo`` entries whose nodes are the simulators' real ptys), what ``ports``
prints, and a device with ``reconnect=True`` that finds its robot again under another
node, through the real transport, once by a moved symlink (as udev moves
``/dev/serial/by-id``) and once by a ``usb:`` identity whose entry moves.

Run under each transport: ``CHASSIS_SDK_BACKEND=pyserial-asyncio``,
``=pyserial-asyncio-fast``, ``=serialx``.
"""

from __future__ import annotations

import asyncio
import fcntl
import json
import logging
import os
import subprocess
import threading
from collections.abc import AsyncIterator, Callable, Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest
from serial.tools.list_ports_common import ListPortInfo

from chassis_sdk import Chassis, ConnectionState, PortOpenError
from chassis_sdk.cli import main as cli_main
from chassis_sdk.core import ports as ports_module
from chassis_sdk.core.ports import (
    PortNotFoundError,
    UsbIdentity,
    list_serial_ports,
    parse_usb_identity,
    resolve_port,
)
from chassis_sdk.sim import ChassisSimulator

from .support.cli import CLI, ROOT, silent_pty
from .support.helpers import next_state, open_fds_on, until

S = ConnectionState

#: The two robots are told apart by their battery (volts).
VOLTS_A, VOLTS_B = 25.5, 21.0


def usb_entry(device: str, vid: int, pid: int, serial: str | None) -> ListPortInfo:
    """A comports() entry for a USB adapter at ``device``."""
    entry = ListPortInfo(device, skip_link_detection=True)
    entry.vid, entry.pid, entry.serial_number = vid, pid, serial
    entry.description, entry.manufacturer = "CP2102 USB to UART Bridge", "Silicon Labs"
    return entry


# --- the form ------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("text", "canonical"),
    [
        pytest.param("usb:10C4:EA60", "usb:10C4:EA60", id="no-serial"),
        pytest.param("usb:10c4:ea60", "usb:10C4:EA60", id="lower-hex"),
        pytest.param("USB:10C4:EA60:0001", "usb:10C4:EA60:0001", id="upper-prefix"),
        pytest.param("usb:1a86:7523:A50285BI", "usb:1A86:7523:A50285BI", id="serial-kept"),
        pytest.param("usb:0403:6001:ab:cd", "usb:0403:6001:ab:cd", id="serial-with-colon"),
        pytest.param("usb:0000:FFFF:x", "usb:0000:FFFF:x", id="extremes"),
    ],
)
def test_identity_forms(text: str, canonical: str) -> None:
    identity = parse_usb_identity(text)
    assert identity is not None
    assert str(identity) == canonical
    assert parse_usb_identity(canonical) == identity


@pytest.mark.parametrize(
    "text",
    [
        pytest.param("usb:", id="empty"),
        pytest.param("usb:10C4", id="no-pid"),
        pytest.param("usb:10C4:", id="empty-pid"),
        pytest.param("usb:10C4:EA6", id="short-pid"),
        pytest.param("usb:10C4:EA600", id="long-pid"),
        pytest.param("usb:10C:EA60", id="short-vid"),
        pytest.param("usb:G0C4:EA60", id="not-hex"),
        pytest.param("usb:0x10C4:EA60", id="0x"),
        pytest.param("usb:+1C4:EA60", id="sign"),
        pytest.param("usb: 10C4:EA60", id="space-before-vid"),
        pytest.param("usb:10C4 :EA60", id="space-after-vid"),
        pytest.param("usb:１０C4:EA60", id="unicode-digits"),
        pytest.param("usb:10C4:EA60:", id="empty-serial"),
        pytest.param("usb:10C4:EA60: 0001", id="space-in-serial"),
        pytest.param("usb:10C4:EA60:00\t01", id="tab-in-serial"),
        pytest.param("usb:10C4:EA60:00\x0001", id="nul-in-serial"),
        pytest.param("usb:10C4-EA60", id="dash"),
    ],
)
def test_malformed_identities_are_value_errors_naming_the_form(text: str) -> None:
    with pytest.raises(ValueError, match=r"usb:VID:PID\[:SERIAL\]"):
        parse_usb_identity(text)
    with pytest.raises(ValueError, match=r"usb:VID:PID\[:SERIAL\]"):
        resolve_port(text)
    with pytest.raises(ValueError, match=r"usb:VID:PID\[:SERIAL\]"):
        Chassis(text)  # at construction, before anything is opened


@pytest.mark.parametrize(
    "port",
    ["/dev/ttyUSB0", "/dev/serial/by-id/usb-Silicon_Labs_CP2102-if00-port0", "socket://h:1"],
)
def test_paths_and_urls_are_not_identities(port: str) -> None:
    assert parse_usb_identity(port) is None


def test_a_port_that_is_not_text_is_a_type_error() -> None:
    with pytest.raises(TypeError, match="port must be a string"):
        parse_usb_identity(5)  # type: ignore[arg-type]


def test_identity_matching() -> None:
    any_serial = UsbIdentity(0x10C4, 0xEA60)
    assert any_serial.matches(0x10C4, 0xEA60, None)
    assert any_serial.matches(0x10C4, 0xEA60, "0001")
    assert not any_serial.matches(0x10C4, 0xEA61, "0001")
    one = UsbIdentity(0x10C4, 0xEA60, "0001")
    assert one.matches(0x10C4, 0xEA60, "0001")
    assert not one.matches(0x10C4, 0xEA60, "0002")
    assert not one.matches(0x10C4, 0xEA60, None)
    assert not one.matches(None, None, "0001")


# --- resolving -----------------------------------------------------------------------------


@pytest.fixture
async def two_sims() -> AsyncIterator[tuple[ChassisSimulator, ChassisSimulator]]:
    async with ChassisSimulator() as a, ChassisSimulator() as b:
        a.firmware.set_battery(VOLTS_A)
        b.firmware.set_battery(VOLTS_B)
        yield a, b


def node(sim: ChassisSimulator) -> str:
    """The simulator's real pty node (``sim.port`` is a symlink to it)."""
    return os.path.realpath(sim.port)


@pytest.mark.integration
async def test_resolution_against_the_attached_devices(
    two_sims: tuple[ChassisSimulator, ChassisSimulator], monkeypatch: pytest.MonkeyPatch
) -> None:
    a, b = (node(s) for s in two_sims)
    attached = [
        ListPortInfo("/dev/ttyS0", skip_link_detection=True),  # not USB: never matched
        usb_entry(a, 0x10C4, 0xEA60, "0001"),
        usb_entry(b, 0x10C4, 0xEA60, "0002"),
        usb_entry("/dev/ttyACM0", 0x2341, 0x0043, None),
    ]
    monkeypatch.setattr("serial.tools.list_ports.comports", lambda: attached)
    assert resolve_port("usb:10C4:EA60:0001") == a
    assert resolve_port("usb:10c4:ea60:0002") == b
    assert resolve_port("usb:2341:0043") == "/dev/ttyACM0"
    with pytest.raises(PortNotFoundError) as none:
        resolve_port("usb:10C4:EA60:0003")
    text = str(none.value)
    assert "\n" not in text
    assert "no USB serial device is usb:10C4:EA60:0003" in text
    assert f"usb:10C4:EA60 serial 0001 at {a}" in text  # names what is attached
    assert "usb:2341:0043 (no serial number) at /dev/ttyACM0" in text
    assert "/dev/ttyS0" not in text
    with pytest.raises(PortNotFoundError) as several:
        resolve_port("usb:10C4:EA60")
    text = str(several.value)
    assert "\n" not in text
    assert text.startswith("2 USB serial devices are usb:10C4:EA60 (")
    assert a in text
    assert b in text
    assert "add the serial number, e.g. usb:10C4:EA60:0001" in text
    # Paths, symlinks and URLs are returned as given (the OS follows a link at open).
    for port in (a, "/dev/serial/by-id/usb-x-if00-port0", "socket://127.0.0.1:9", "/nope"):
        assert resolve_port(port) == port
    # Nothing attached at all.
    monkeypatch.setattr("serial.tools.list_ports.comports", list)
    with pytest.raises(PortNotFoundError, match=r"attached: no USB serial device;"):
        resolve_port("usb:10C4:EA60:0001")


def test_twins_sharing_a_serial_are_told_to_use_another_name(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    twins = [usb_entry(f"/dev/ttyUSB{i}", 0x1A86, 0x7523, "0001") for i in range(2)]
    monkeypatch.setattr("serial.tools.list_ports.comports", lambda: twins)
    with pytest.raises(PortNotFoundError, match="share a serial number: .*by-path"):
        resolve_port("usb:1A86:7523:0001")
    assert [p.identity for p in list_serial_ports()] == ["usb:1A86:7523", "usb:1A86:7523"]


@pytest.mark.integration
async def test_the_listing_gives_each_device_its_identity_and_by_id_link(
    two_sims: tuple[ChassisSimulator, ChassisSimulator],
    monkeypatch: pytest.MonkeyPatch,
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
) -> None:
    a, b = (node(s) for s in two_sims)
    by_id = tmp_path / "by-id"
    by_id.mkdir()
    link_a = by_id / "usb-Silicon_Labs_CP2102_0001-if00-port0"
    link_a.symlink_to(a)
    (by_id / "usb-unrelated-if00-port0").symlink_to("/dev/nonexistent")
    attached = [
        usb_entry(a, 0x10C4, 0xEA60, "0001"),
        usb_entry(b, 0x10C4, 0xEA60, None),
        ListPortInfo("/dev/ttyS0", skip_link_detection=True),
    ]
    monkeypatch.setattr("serial.tools.list_ports.comports", lambda: attached)
    monkeypatch.setattr(ports_module, "BY_ID_DIR", str(by_id))
    found = {p.device: p for p in list_serial_ports()}
    assert found[a].identity == "usb:10C4:EA60:0001"
    assert found[a].by_id == str(link_a)
    assert found[b].identity == "usb:10C4:EA60"  # no serial number
    assert found[b].by_id == ""
    assert found["/dev/ttyS0"].identity == found["/dev/ttyS0"].by_id == ""
    # The identity printed is one that resolves to the device it is printed for.
    assert resolve_port(found[a].identity) == a

    assert cli_main(["ports", "--json"]) == 0
    rows = {row["device"]: row for row in json.loads(capsys.readouterr().out)}
    assert rows[a]["identity"] == "usb:10C4:EA60:0001"
    assert rows[a]["by_id"] == str(link_a)
    assert rows[b]["identity"] == "usb:10C4:EA60"
    assert rows["/dev/ttyS0"]["identity"] == ""
    assert cli_main(["ports"]) == 0
    text = capsys.readouterr().out
    assert f"id usb:10C4:EA60:0001  by-id {link_a}" in text
    assert "id usb:10C4:EA60\n" in text
    assert "use PORT=usb:10C4:EA60:0001 (a device's id above) to survive renumbering" in text


def test_ports_without_usb_devices_gives_no_hint(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    serial_only = [ListPortInfo("/dev/ttyS0", skip_link_detection=True)]
    monkeypatch.setattr("serial.tools.list_ports.comports", lambda: serial_only)
    assert cli_main(["ports"]) == 0
    text = capsys.readouterr().out
    assert "/dev/ttyS0" in text
    assert "renumbering" not in text
    assert " id " not in text


# --- opening by identity -------------------------------------------------------------------


def test_constructing_looks_nothing_up(monkeypatch: pytest.MonkeyPatch) -> None:
    def no_lookup() -> list[ListPortInfo]:
        raise AssertionError("constructing looked the port up")

    monkeypatch.setattr("serial.tools.list_ports.comports", no_lookup)
    robot = Chassis("usb:10C4:EA60:0001", reconnect=True)
    assert robot.port == "usb:10C4:EA60:0001"
    assert robot.port_node is None


@pytest.mark.integration
async def test_port_node_of_a_path_and_of_a_socket() -> None:
    async with ChassisSimulator() as pty, ChassisSimulator(tcp_port=0) as tcp:
        async with Chassis(pty.port) as robot:
            assert robot.port == pty.port  # the simulator's own symlink, as given
            assert robot.port_node == node(pty)
        assert robot.port_node is None
        async with Chassis(tcp.port) as robot:
            assert robot.port_node == tcp.port
            assert await robot.get_firmware_version() == 103


@pytest.mark.integration
async def test_an_identity_not_attached_is_a_one_line_port_error(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    with silent_pty() as other:
        attached = [usb_entry(other, 0x1A86, 0x7523, "X")]
        monkeypatch.setattr("serial.tools.list_ports.comports", lambda: attached)
        robot = Chassis("usb:10C4:EA60:0001", connect_timeout=1.0)
        with pytest.raises(PortNotFoundError) as caught:
            await robot.connect()
    assert isinstance(caught.value, PortOpenError)
    assert "\n" not in str(caught.value)
    assert f"usb:1A86:7523 serial X at {other}" in str(caught.value)
    assert robot.connection_state is S.DISCONNECTED
    assert robot.port_node is None


@pytest.mark.integration
async def test_an_identity_that_moves_while_its_node_opens_is_not_kept(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    # The adapter leaves and another takes its node between the lookup and the open:
    # the node open then is not this robot's, so it is closed and the open fails (a
    # reconnecting device tries again).
    with silent_pty() as first, silent_pty() as second:
        answers = iter([[usb_entry(first, 0x10C4, 0xEA60, "0001")]] * 1)
        later = [usb_entry(second, 0x10C4, 0xEA60, "0001")]
        monkeypatch.setattr("serial.tools.list_ports.comports", lambda: next(answers, later))
        robot = Chassis("usb:10C4:EA60:0001", connect_timeout=2.0)
        held = open_fds_on(first)  # the test's own end of the pty
        with pytest.raises(
            PortOpenError, match=f"moved while opening \\({first}, now at {second}\\)"
        ):
            await robot.connect()
        assert robot.port_node is None
        await until(lambda: open_fds_on(first) == held)  # closed, not kept


@pytest.mark.integration
async def test_busy_hint_names_the_holder_of_the_node_an_identity_reached(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    with silent_pty() as held:
        attached = [usb_entry(held, 0x10C4, 0xEA60, "0001")]
        monkeypatch.setattr("serial.tools.list_ports.comports", lambda: attached)
        link = tmp_path / "by-id-link"
        link.symlink_to(held)
        holder = os.open(held, os.O_RDWR | os.O_NOCTTY)
        try:
            fcntl.flock(holder, fcntl.LOCK_EX | fcntl.LOCK_NB)  # as an exclusive opener
            for port, shown in (
                ("usb:10C4:EA60:0001", f"usb:10C4:EA60:0001 ({held})"),
                (str(link), str(link)),
            ):
                with pytest.raises(PortOpenError) as caught:
                    await Chassis(port, connect_timeout=2.0).connect()
                assert str(caught.value).startswith(f"could not open {shown}: port busy")
                assert "held by this process" in str(caught.value)
        finally:
            os.close(holder)


# --- renumbering through the real transport --------------------------------------------------


class Seen(logging.Handler):
    """Sets an asyncio event when the SDK logs a line containing ``text`` (the reconnect
    loop's own report of a failed attempt): a wait on the SDK, not a sleep."""

    def __init__(self, text: str) -> None:
        super().__init__(logging.DEBUG)
        self.text = text
        self.lines: list[str] = []
        self._loop = asyncio.get_running_loop()
        self._event = asyncio.Event()

    def emit(self, record: logging.LogRecord) -> None:
        line = record.getMessage()
        if line.startswith(("rx ", "tx ")):  # the hex dumps
            return
        self.lines.append(line)
        if self.text in line:
            self._loop.call_soon_threadsafe(self._event.set)

    async def wait(self, timeout: float = 5.0) -> None:
        self._event.clear()
        async with asyncio.timeout(timeout):
            await self._event.wait()


@contextmanager
def sdk_log(text: str) -> Iterator[Seen]:
    log = logging.getLogger("chassis_sdk")
    seen = Seen(text)
    old = log.level
    log.setLevel(logging.DEBUG)
    log.addHandler(seen)
    try:
        yield seen
    finally:
        log.removeHandler(seen)
        log.setLevel(old)


def move_link(link: Path, target: str) -> None:
    """Point ``link`` at ``target`` atomically (as udev does on a replug)."""
    tmp = link.with_name(link.name + ".new")
    tmp.symlink_to(target)
    os.replace(tmp, link)


async def renumbered(
    robot: Chassis,
    a: ChassisSimulator,
    b: ChassisSimulator,
    seen: Seen,
    unplug: Callable[[], None],
    replug: Callable[[], None],
) -> None:
    """A is unplugged, a reopen finds nothing there, the name moves to B: the device
    reconnects by the same name and telemetry resumes from B."""
    node_a, node_b = node(a), node(b)
    states = robot.connection_states()
    first = await robot.wait_for(lambda t: abs(t.voltage - VOLTS_A) < 0.5, 3.0)
    assert first.voltage == pytest.approx(VOLTS_A, abs=0.5)
    assert robot.port_node == node_a
    unplug()
    await a.stop()
    assert await next_state(states) is S.RECONNECTING
    assert robot.port_node is None
    await seen.wait()  # an attempt found nothing there yet; it will be retried
    replug()
    assert await next_state(states) is S.CONNECTED
    t = await robot.wait_for(lambda t: abs(t.voltage - VOLTS_B) < 0.5, 3.0)
    assert t.voltage == pytest.approx(VOLTS_B, abs=0.5)
    assert robot.port_node == node_b
    assert robot.stats.reconnects == 1
    assert await robot.get_firmware_version() == 103  # requests reach B too
    assert b.firmware.received  # B heard the host


@pytest.mark.integration
async def test_a_moved_symlink_is_followed_on_reconnect(
    two_sims: tuple[ChassisSimulator, ChassisSimulator], tmp_path: Path
) -> None:
    a, b = two_sims
    node_a, node_b = node(a), node(b)
    link = tmp_path / "usb-Silicon_Labs_CP2102_0001-if00-port0"
    link.symlink_to(node_a)
    with sdk_log("reopen failed") as seen:
        async with Chassis(str(link), reconnect=True, connect_timeout=1.0) as robot:
            # Unplugged, udev removes the link with the node. (A link left pointing at
            # A's freed node could find a pty of that number that another process made
            # meanwhile: devpts hands out the lowest free one.)
            await renumbered(robot, a, b, seen, link.unlink, lambda: move_link(link, node_b))
            assert robot.port == str(link)  # what the user gave
    assert f"{link} is now {node_a}" in seen.lines
    assert f"{link} is now {node_b}" in seen.lines
    failures = [line for line in seen.lines if "reopen failed" in line]
    assert "no such device" in failures[0]


@pytest.mark.integration
async def test_a_usb_identity_is_looked_up_again_on_reconnect(
    two_sims: tuple[ChassisSimulator, ChassisSimulator], monkeypatch: pytest.MonkeyPatch
) -> None:
    a, b = two_sims
    node_a, node_b = node(a), node(b)
    identity = "usb:10C4:EA60:SIM0001"
    other = usb_entry("/dev/ttyUSB7", 0x1A86, 0x7523, "ZZ")  # attached all along
    attached = [other, usb_entry(node_a, 0x10C4, 0xEA60, "SIM0001")]
    lock = threading.Lock()  # comports() is called from a worker thread

    def comports() -> list[ListPortInfo]:
        with lock:
            return list(attached)

    def unplug() -> None:
        # The adapter leaves the listing; a near miss (another serial number) comes.
        with lock:
            attached[:] = [other, usb_entry("/dev/ttyUSB9", 0x10C4, 0xEA60, "SIM0002")]

    def replug_as_b() -> None:
        with lock:
            attached[:] = [usb_entry(node_b, 0x10C4, 0xEA60, "SIM0001"), other]

    monkeypatch.setattr("serial.tools.list_ports.comports", comports)
    with sdk_log("reopen failed") as seen:
        async with Chassis(identity, reconnect=True, connect_timeout=1.0) as robot:
            await renumbered(robot, a, b, seen, unplug, replug_as_b)
            assert robot.port == identity
    assert f"{identity} is now {node_a}" in seen.lines
    assert f"{identity} is now {node_b}" in seen.lines
    failures = [line for line in seen.lines if "reopen failed" in line]
    assert failures
    for line in failures:
        assert f"no USB serial device is {identity}" in line
        assert "usb:1A86:7523 serial ZZ at /dev/ttyUSB7" in line
        assert "usb:10C4:EA60 serial SIM0002 at /dev/ttyUSB9" in line


# --- the CLI -------------------------------------------------------------------------------


@pytest.mark.integration
def test_cli_info_by_identity_reaches_the_device(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    async def serve_one() -> int:
        async with ChassisSimulator() as sim:
            attached = [usb_entry(node(sim), 0x10C4, 0xEA60, "0001")]
            monkeypatch.setattr("serial.tools.list_ports.comports", lambda: attached)
            # main() runs its own loop: in a thread, while this one serves the robot.
            return await asyncio.to_thread(cli_main, ["info", "usb:10c4:ea60:0001"])

    assert asyncio.run(serve_one()) == 0
    text = capsys.readouterr().out
    assert "port         usb:10c4:ea60:0001\n" in text  # the name given, as given
    assert "103" in text  # the simulator's firmware version: it answered


@pytest.mark.integration
@pytest.mark.parametrize(
    ("port", "expected"),
    [
        pytest.param(
            "usb:FFFF:FFFE:NOSUCH", "no USB serial device is usb:FFFF:FFFE:NOSUCH", id="absent"
        ),
        pytest.param("usb:FFFF", "is not of the form usb:VID:PID[:SERIAL]", id="malformed"),
    ],
)
def test_cli_info_on_an_identity_not_attached_is_one_line(port: str, expected: str) -> None:
    done = subprocess.run(
        [*CLI, "info", port], capture_output=True, text=True, cwd=ROOT, timeout=30
    )
    assert done.returncode != 0
    assert done.stdout == ""
    lines = done.stderr.splitlines()
    assert len(lines) == 1, done.stderr
    assert lines[0].startswith("chassis-sdk: ")
    assert expected in lines[0]
