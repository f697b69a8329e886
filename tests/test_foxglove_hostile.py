"""The Foxglove server under hostile clients (issue 23, points 8-10): who may connect
(Origin, token, the private port behind the front), and what a Teleop channel does
with what is not quite a Twist. Against the real server, over the chassis simulator
on a pty, with the independent client of tests/support/foxglove_client.py."""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
import os
import signal
import socket
import struct
import sys
import time
from collections.abc import AsyncIterator
from pathlib import Path
from typing import Any
from urllib.parse import urlsplit

import pytest
from websockets.exceptions import InvalidStatus

from chassis_sdk import Chassis
from chassis_sdk.core.motion import WRITE_PERIOD
from chassis_sdk.integrations.foxglove import FoxgloveServer
from chassis_sdk.protocol import DriveVelocity
from chassis_sdk.sim import ChassisSimulator

from .support.cli import cli, running
from .support.foxglove_client import _SERVICE_CALL, FoxgloveClient
from .support.helpers import drives, until

pytestmark = [pytest.mark.surface, pytest.mark.timeout(60)]

TOKEN = "s3cret-token-0123456789"
EVIL = "http://evil.example"
#: What the Foxglove web app and the Electron desktop apps (Foxglove Studio, Lichtblick:
#: pages loaded from file://) send as Origin.
APP_ORIGINS = ("https://app.foxglove.dev", "https://studio.foxglove.dev", "file://")


def twist(linear: float, angular: float = 0.0) -> bytes:
    return json.dumps({"linear": {"x": linear}, "angular": {"z": angular}}).encode()


async def moving(sim: ChassisSimulator, moving: bool, timeout: float) -> float:
    """Seconds until the simulated wheels' targets are (not) zero, checked every 2 ms."""
    return await until(lambda: any(sim.firmware.target) == moving, timeout, poll=0.002)


@contextlib.asynccontextmanager
async def served(
    command_timeout: float = 1.0, **options: Any
) -> AsyncIterator[tuple[ChassisSimulator, Chassis, FoxgloveServer]]:
    async with (
        ChassisSimulator() as sim,
        Chassis(sim.port, command_timeout=command_timeout) as robot,
        FoxgloveServer(robot, port=0, **options) as server,
    ):
        yield sim, robot, server


async def refused(url: str, **client: Any) -> int:
    """The HTTP status a handshake is refused with (AssertionError if it is let in)."""
    try:
        async with FoxgloveClient(url, **client):
            pass
    except InvalidStatus as exc:
        return int(exc.response.status_code)
    raise AssertionError(f"let in: {client}")


async def teleop(client: FoxgloveClient) -> None:
    await client.wait_for(lambda: bool(client.server_info))
    await client.advertise(1, "/cmd_vel", "geometry_msgs/Twist")


# --- 9: who may connect -------------------------------------------------------------------


@pytest.mark.integration
@pytest.mark.timing
async def test_a_page_of_another_origin_is_refused_at_the_handshake_and_never_drives(
    caplog: pytest.LogCaptureFixture,
) -> None:
    caplog.set_level(logging.WARNING, "chassis_sdk.integrations.foxglove")
    async with served() as (sim, robot, server), FoxgloveClient(server.url) as operator:
        await operator.wait_for(lambda: bool(operator.server_info))
        assert await refused(server.url, origin=EVIL) == 403
        # An attacker's page may retry as often as it likes: each is refused and
        # counted; the log and the app hear of it at most once a second, summarised.
        n = 300
        start = time.monotonic()
        statuses = await asyncio.gather(
            *(refused(server.url, origin=f"http://evil{i % 7}.example") for i in range(n))
        )
        took = time.monotonic() - start
        assert set(statuses) == {403}
        assert server.refused_connections == n + 1
        await operator.wait_for(
            lambda: any(f"{n + 1} in all" in s["message"] for s in operator.statuses), 3.0
        )
        lines = [r for r in caplog.records if "refused" in r.getMessage()]
        assert 1 <= len(lines) <= 2 + took / 1.0 + 1, len(lines)
        refusals = [s for s in operator.statuses if "refused" in s["message"]]
        assert all(s["level"] == 1 for s in refusals)  # warnings
        assert "'http://evil.example' is not allowed" in refusals[0]["message"]
        assert len(refusals) == len(lines)
        assert robot.commanded_velocity is None
        assert not drives(sim)
        assert server.rejected == 0
        print(f"\n{n} refused handshakes in {took:.2f} s; {len(lines)} log lines")


@pytest.mark.integration
async def test_origins_let_in_native_clients_the_apps_and_allowed_pages() -> None:
    lichtblick = "http://lichtblick.lan:8080"
    async with served(allow_origins=[lichtblick, "app://desktop/"]) as (sim, _, server):
        for origin in (None, *APP_ORIGINS, lichtblick, "app://desktop", "HTTPS://APP.FOXGLOVE.DEV"):
            async with FoxgloveClient(server.url, origin=origin) as client:
                await client.wait_for(lambda: bool(client.server_info))
        for origin in ("null", "https://app.foxglove.dev.evil.example", "http://lichtblick.lan"):
            assert await refused(server.url, origin=origin) == 403, origin
        # As foxglove-sdk itself: a client offering only the old subprotocol name gets 400.
        assert await refused(server.url, subprotocols=["foxglove.websocket.v1"]) == 400
        async with FoxgloveClient(server.url, origin="https://app.foxglove.dev") as app:
            await teleop(app)
            await app.publish(1, twist(0.2))
            await moving(sim, True, 2.0)
        assert server.refused_connections == 3


def test_bad_access_options_are_refused_before_anything_opens() -> None:
    robot = Chassis("/dev/null")
    for origin in ("null", "*", "http://x.example/path", "x.example", "http://", ""):
        with pytest.raises(ValueError, match="origin"):
            FoxgloveServer(robot, allow_origins=[origin])
    with pytest.raises(ValueError, match="list of origins"):
        FoxgloveServer(robot, allow_origins="http://x.example")
    for token in ("short", "a token with spaces!", "x" * 15):
        with pytest.raises(ValueError, match="token"):
            FoxgloveServer(robot, token=token)
    # Beyond loopback, a token, or an explicit allow_no_token.
    for host in ("0.0.0.0", "192.168.1.20", "::", "robot.lan"):
        with pytest.raises(ValueError, match="needs a token"):
            FoxgloveServer(robot, host=host)
        FoxgloveServer(robot, host=host, token=TOKEN)
        FoxgloveServer(robot, host=host, allow_no_token=True)
    for host in ("127.0.0.1", "localhost", "::1", "127.1.2.3"):
        FoxgloveServer(robot, host=host)


@pytest.mark.integration
async def test_a_token_is_required_when_given_and_never_shown(
    caplog: pytest.LogCaptureFixture,
) -> None:
    caplog.set_level(logging.DEBUG)
    async with served(token=TOKEN) as (sim, _, server):
        assert await refused(server.url) == 401
        assert await refused(server.url, token=TOKEN[:-1] + "X") == 401
        assert await refused(server.url, token=TOKEN + "X") == 401
        assert await refused(server.url, bearer="wrong-token-0123456789") == 401
        assert await refused(f"{server.url}/?token={TOKEN}&token={TOKEN}") == 401
        # The token does not make another origin acceptable.
        assert await refused(server.url, token=TOKEN, origin=EVIL) == 403
        async with FoxgloveClient(server.url, bearer=TOKEN) as native:
            await native.wait_for(lambda: bool(native.server_info))
        async with FoxgloveClient(server.url, token=TOKEN, origin=APP_ORIGINS[0]) as app:
            await teleop(app)
            await app.publish(1, twist(0.2))
            await moving(sim, True, 2.0)
            assert server.refused_connections == 6
            await app.wait_for(lambda: any("6 in all" in s["message"] for s in app.statuses))
            shown = [s["message"] for s in app.statuses]
    assert TOKEN not in server.url
    assert not any(TOKEN in m or TOKEN[:-1] in m for m in shown)
    leaks = [
        (r.name, r.getMessage()[:80])
        for r in caplog.records
        if TOKEN[:-1] in r.getMessage() and r.name != "websockets.client"  # the test's own
    ]
    assert not leaks, leaks


@pytest.mark.integration
async def test_a_client_that_reaches_the_private_port_cannot_drive_or_release() -> None:
    async with served() as (sim, robot, server):
        front = server._front
        assert front is not None
        backend_url = front._backend_url
        # Another address and port than the front's. Not just another port: the two
        # sockets are on different addresses of 127.0.0.0/8, and the kernel may give
        # both the same ephemeral port (CI saw 46209 twice).
        backend = urlsplit(backend_url)
        assert (backend.hostname, backend.port) != (server.host, server.port)
        async with FoxgloveClient(backend_url, origin=EVIL) as sneak:
            await teleop(sneak)
            await sneak.publish(1, twist(0.3))
            await sneak.wait_for(lambda: server.rejected >= 2)
            assert (await sneak.call("release_emergency_stop"))["success"] is False
            assert (await sneak.call("clear_faults"))["success"] is False
            assert (await sneak.call("stop"))["success"] is True  # stopping is always fine
        # It also cannot pose as the front with a channel on the reserved id.
        async with FoxgloveClient(backend_url) as sneak:
            await sneak.wait_for(lambda: bool(sneak.server_info))
            await sneak.send_raw(
                json.dumps(
                    {
                        "op": "advertise",
                        "channels": [
                            {
                                "id": 0xFFFFFFFF,
                                "topic": "/_chassis_sdk/front/guess",
                                "encoding": "json",
                                "schemaName": "x",
                            }
                        ],
                    }
                )
            )
            await teleop(sneak)
            await sneak.publish(1, twist(0.3))
            await sneak.wait_for(lambda: server.rejected >= 7)
        assert robot.commanded_velocity is None
        assert all(d == DriveVelocity(0, 0.0) for d in drives(sim))  # the stop's zero
        assert server.commands == 0


@pytest.mark.integration
async def test_the_private_port_lets_a_local_client_watch_and_stop_and_nothing_more() -> None:
    """What docs/foxglove.md says the private port exposes to a local user who finds it
    (no token, no Origin check there): every stream, ``stop`` and ``emergency_stop``."""
    async with served(token=TOKEN) as (sim, robot, server):
        front = server._front
        assert front is not None
        async with FoxgloveClient(front._backend_url, origin=EVIL) as local:
            await local.wait_for(lambda: "/chassis/telemetry" in local.channels)
            await local.subscribe("/chassis/telemetry")
            await local.wait_for(lambda: len(local.received["/chassis/telemetry"]) >= 3)
            assert set(local.services) == {
                "stop",
                "emergency_stop",
                "release_emergency_stop",
                "clear_faults",
            }
            assert (await local.call("stop"))["success"] is True
            assert (await local.call("emergency_stop"))["success"] is True
            for service in ("release_emergency_stop", "clear_faults"):
                answer = await local.call(service)
                assert answer == {
                    "success": False,
                    "message": "refused: the connection was not checked",
                }, service
            await teleop(local)
            await local.publish(1, twist(0.3))
            await until(lambda: server.rejected >= 4, 2.0)
        assert robot.commanded_velocity is None
        assert server.commands == 0
        assert not any(sim.firmware.target)


@pytest.mark.integration
@pytest.mark.timing
async def test_a_teleop_client_that_vanishes_stops_the_robot_at_once_through_the_front() -> None:
    async with served(command_timeout=2.0) as (sim, _, server):
        client = FoxgloveClient(server.url)
        await client.__aenter__()
        await teleop(client)
        await client.publish(1, twist(0.3))
        await moving(sim, True, 2.0)
        client.abort()  # TCP RST: no closing handshake
        assert await moving(sim, False, 0.5) < 0.5  # far before the 2 s deadman
        with contextlib.suppress(Exception):
            await client.__aexit__(None, None, None)


# --- 8 and 10: what a Teleop channel takes -------------------------------------------------

_DEEP = b'{"linear": ' + b"[" * 1500 + b"]" * 1500 + b"}"
#: Refused either way, for why depending on json: until 3.12 it raises RecursionError at
#: this depth; 3.13's raises it only past about 10,000, which no command within the size
#: bound reaches, so there it parses and is refused for its shape.
_DEEP_WHY = "nested too deeply" if sys.version_info < (3, 13) else "linear is not an object"


@pytest.mark.integration
@pytest.mark.parametrize(
    ("payload", "why"),
    [
        pytest.param(_DEEP, _DEEP_WHY, id="deep-json"),
        pytest.param(b'{"linear": ' + b"[" * 100_000 + b"}", "bytes", id="deeper-than-big"),
        pytest.param(
            b'{"linear": {"x": ' + b"1" * 400 + b'}, "angular": {"z": 0}}',
            "a number of 400 characters",
            id="400-digit-integer",
        ),
        pytest.param(twist(0.3).decode().encode("utf-16"), "not UTF-8", id="utf-16-bom"),
        pytest.param(twist(0.3).decode().encode("utf-16-le"), "not JSON", id="utf-16-le"),
        pytest.param(
            b'{"linear": {"x": 0.3, "x": 0}, "angular": {"z": 0}}', "twice", id="duplicate-key"
        ),
        pytest.param(b'{"linear": {"x": 0.3}, "linear": {"x": 0}}', "twice", id="duplicate-part"),
        pytest.param(b'{"linear": {"x": NaN}}', "NaN", id="nan"),
        pytest.param(b"\xef\xbb\xbf" + twist(0.3), "byte order mark", id="utf-8-bom"),
    ],
)
async def test_teleop_refuses_what_is_not_quite_a_twist_counts_and_reports_it(
    payload: bytes, why: str
) -> None:
    async with served() as (sim, _, server), FoxgloveClient(server.url) as client:
        await teleop(client)
        await client.publish(1, payload)
        await client.wait_for(lambda: bool(client.statuses))
        status = client.statuses[0]
        assert status["level"] == 1, status  # warning
        assert "velocity on /cmd_vel" in status["message"]
        assert why in status["message"], status
        assert server.rejected == 1
        assert server.errors == 0
        # The channel goes on: a good Twist after it drives.
        await client.publish(1, twist(0.2))
        await moving(sim, True, 2.0)
        assert [d.linear_mm for d in drives(sim)] == [200]


@pytest.mark.integration
@pytest.mark.timing
async def test_a_flood_of_junk_is_counted_reported_summarised_and_a_stop_goes_through() -> None:
    n = 3000
    async with (
        served(command_timeout=5.0) as (sim, _, server),
        FoxgloveClient(server.url) as client,
    ):
        await teleop(client)
        await client.publish(1, twist(0.2))
        await moving(sim, True, 2.0)
        start = time.monotonic()
        for i in range(n):
            await client.publish(1, _DEEP if i % 2 else b'{"linear": {"x": 1, "x": 2}}')
        assert (await client.call("stop"))["success"]
        assert await moving(sim, False, 0.5) < 0.5
        await until(lambda: server.rejected == n, 10.0)
        took = time.monotonic() - start
        await client.wait_for(lambda: any(f"{n} in all" in s["message"] for s in client.statuses))
        # The first at once, then one a second at most, each with its count.
        assert len(client.statuses) <= 2 + took / 1.0 + 1, (len(client.statuses), took)
        assert "refused" in client.statuses[-1]["message"]
        assert server.errors == 0
        assert server.commands == 1
        print(f"\n{n} junk Twists in {took:.2f} s: {len(client.statuses)} statuses")


@pytest.mark.integration
@pytest.mark.timing
async def test_a_twist_channel_advertised_again_as_another_schema_stops_at_once() -> None:
    async with (
        served(command_timeout=2.0) as (sim, robot, server),
        FoxgloveClient(server.url) as client,
    ):
        await teleop(client)
        await client.publish(1, twist(0.3))
        await moving(sim, True, 2.0)
        await client.advertise(1, "/cmd_vel", "std_msgs/String")
        assert await moving(sim, False, 0.5) < 0.5  # not the 2 s deadman
        await client.wait_for(
            lambda: any("std_msgs/String" in s["message"] for s in client.statuses)
        )
        # What it publishes now, Twist-shaped or not, never drives.
        for _ in range(5):
            await client.publish(1, twist(0.3))
        await until(lambda: server.rejected >= 6, 2.0)
        assert not any(sim.firmware.target)
        assert robot.commanded_velocity is None
        # Advertised as a Twist again (a new panel), it drives again; the same
        # advertisement once more changes nothing (no stop, no refusal).
        await client.advertise(1, "/cmd_vel", "geometry_msgs/Twist")
        await client.publish(1, twist(0.1))
        await moving(sim, True, 2.0)
        rejected, before = server.rejected, len(drives(sim))
        await client.advertise(1, "/cmd_vel", "geometry_msgs/Twist")
        await client.publish(1, twist(0.15))
        await until(lambda: robot.commanded_velocity == (0.15, 0.0), 2.0)
        await until(lambda: drives(sim)[-1].linear_mm == 150, 2.0)
        assert all(d.linear_mm for d in drives(sim)[before:])  # no zero in between
        assert server.rejected == rejected
        # The same for a Twist channel re-advertised with another encoding.
        await client.advertise(1, "/cmd_vel", "geometry_msgs/Twist", encoding="cbor")
        assert await moving(sim, False, 0.5) < 0.5


@pytest.mark.integration
async def test_what_a_client_names_is_shown_bounded_in_reports() -> None:
    async with served() as (_, _, server), FoxgloveClient(server.url) as client:
        await client.wait_for(lambda: bool(client.server_info))
        await client.advertise(1, "/x" * 20_000 + "\n", "y" * 20_000)
        await client.wait_for(lambda: bool(client.statuses))
        assert len(client.statuses[0]["message"]) < 400
        assert "\n" not in client.statuses[0]["message"]
        assert server.rejected == 1


@pytest.mark.integration
async def test_an_error_in_a_callback_is_caught_counted_and_reported(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    import chassis_sdk.integrations.foxglove.server as live

    def broken(data: bytes) -> tuple[float, float]:
        raise RuntimeError("a bug")

    async with served() as (sim, _, server), FoxgloveClient(server.url) as client:
        await teleop(client)
        with monkeypatch.context() as patch:
            patch.setattr(live, "_twist", broken)
            await client.publish(1, twist(0.3))
            await client.wait_for(lambda: bool(client.statuses))
        assert "internal error: RuntimeError: a bug" in client.statuses[0]["message"]
        assert server.errors == 1
        # The server goes on.
        await client.publish(1, twist(0.2))
        await moving(sim, True, 2.0)


@pytest.mark.integration
@pytest.mark.timing
async def test_a_flood_of_twists_is_state_not_a_queue() -> None:
    n = 5000
    async with (
        served(command_timeout=5.0) as (sim, robot, server),
        FoxgloveClient(server.url) as client,
    ):
        await teleop(client)
        for i in range(n - 1):
            await client.publish(1, twist(0.1 + 0.3 * (i % 2)))
        await client.publish(1, twist(0.25))
        # Velocity is state: the newest of what waits is handed over, not each one.
        await until(lambda: robot.commanded_velocity == (0.25, 0.0), 10.0)
        assert 0 < server.commands <= n
        # A stop right after the flood is not behind it.
        start = time.monotonic()
        assert (await client.call("stop"))["success"]
        await moving(sim, False, 0.5)
        print(
            f"\n{n} Twists: {server.commands} taken, {len(drives(sim))} velocity frames; "
            f"stop in {(time.monotonic() - start) * 1000:.1f} ms"
        )
        assert server.rejected == 0


def _frames(sim: ChassisSimulator, since: float) -> list[tuple[float, DriveVelocity]]:
    """The velocity frames the simulated chassis read from ``since`` (monotonic), timed."""
    return [(t, c) for t, c in sim.firmware.received if isinstance(c, DriveVelocity) and t >= since]


@pytest.mark.integration
@pytest.mark.timing
async def test_a_twist_flood_reaches_the_wire_at_most_once_per_write_period() -> None:
    """2,000 Twists a second for a second: the core writes the newest at most once per
    `WRITE_PERIOD` (about 50 frames a second), not one frame per Twist."""
    rate, seconds = 2000, 1.0
    async with (
        served(command_timeout=5.0) as (sim, robot, server),
        FoxgloveClient(server.url) as client,
    ):
        await teleop(client)
        start = time.monotonic()
        sent = 0
        while (elapsed := time.monotonic() - start) < seconds:
            while sent < elapsed * rate:
                await client.publish(1, twist(0.1 + 0.1 * (sent % 2)))
                sent += 1
            await asyncio.sleep(0.001)  # paces the sender, not a wait for the server
        await client.publish(1, twist(0.25))
        sent += 1
        await until(lambda: robot.commanded_velocity == (0.25, 0.0), 10.0)
        await until(lambda: _frames(sim, start)[-1][1].linear_mm == 250, 1.0)
        end = time.monotonic()
        frames = _frames(sim, start)
        span = frames[-1][0] - frames[0][0]
        per_second = len(frames) / (end - start)
        print(f"\n{sent} Twists in {end - start:.2f} s: {len(frames)} velocity frames "
              f"({per_second:.0f} a second)")  # fmt: skip
        assert sent > 0.9 * rate * seconds
        # A frame may come WRITE_JITTER early, but the rate holds: one per period.
        assert len(frames) <= span / WRITE_PERIOD + 2, (len(frames), span)
        assert per_second <= 51 + 2 / (end - start), per_second
        assert server.rejected == 0
        assert 0 < server.commands <= sent  # the newest of what waited each time


async def call_in_this_step(client: FoxgloveClient, service: str) -> asyncio.Future[bytes]:
    """Send a service call now, without giving the event loop a turn first (as
    `FoxgloveClient.call` does); the future gets the response."""
    spec = client.services[service]
    call = client._next_call
    client._next_call += 1
    future: asyncio.Future[bytes] = asyncio.get_running_loop().create_future()
    client._calls[call] = future
    await client.send_raw(struct.pack("<BIII", _SERVICE_CALL, spec["id"], call, 4) + b"json{}")
    return future


@pytest.mark.integration
@pytest.mark.timing
@pytest.mark.parametrize("service", ["stop", "emergency_stop"])
async def test_a_twist_sent_just_before_a_stop_is_never_written_after_it(service: str) -> None:
    """The stop (or e-stop) service acts at once: a Twist sent just before it, still on
    its way to the device when the call comes, is never written after its zero."""
    stopped = DriveVelocity(0, 0.0)
    async with (
        served(command_timeout=5.0) as (sim, robot, server),
        FoxgloveClient(server.url) as client,
    ):
        await teleop(client)
        await client.wait_for(lambda: service in client.services)
        for _ in range(3):
            await client.publish(1, twist(0.0))  # the neutral owed after an e-stop
            await client.publish(1, twist(0.1))
            await moving(sim, True, 2.0)
            start = time.monotonic()
            # A loaded event loop (an application's slow callbacks) while a Teleop
            # client streams: the server's threads take each Twist meanwhile and hand
            # it over; the loop gets a turn in between.
            await client.publish(1, twist(0.2))
            time.sleep(0.05)
            await asyncio.sleep(0)
            await client.publish(1, twist(0.3))  # the last Twist, then at once the call
            call = await call_in_this_step(client, service)
            time.sleep(0.05)
            resumed = time.monotonic()
            assert json.loads(await asyncio.wait_for(call, 5.0))["success"]
            took = time.monotonic() - resumed
            since = start

            def frames() -> list[DriveVelocity]:
                return [c for _, c in _frames(sim, since)]  # noqa: B023

            await until(lambda: stopped in frames(), 1.0)
            # The stop's zero (by its place: frames read in one chunk share a time).
            zero = frames().index(stopped)

            def moved_after_the_zero() -> bool:
                return any(c.linear_mm for c in frames()[zero + 1 :])  # noqa: B023

            # Whatever was queued before the stop would be written within a period.
            with pytest.raises(TimeoutError):
                await until(moved_after_the_zero, 0.2)
            assert not any(sim.firmware.target)
            assert robot.commanded_velocity is None
            print(f"\n{service} answered {took * 1000:.1f} ms after the loop was free")
            if service == "emergency_stop":
                await robot.release_emergency_stop()


# --- the CLI ---------------------------------------------------------------------------------


def _url(line: str) -> str:
    return line.split(" at ")[1].split()[0]


@pytest.mark.integration
async def test_cli_serve_checks_origin_and_token_and_never_prints_the_token(
    tmp_path: Path,
) -> None:
    token_file = tmp_path / "token"
    token_file.write_text(TOKEN + "\n")
    token_file.chmod(0o600)
    allowed = "http://lichtblick.lan:8080"
    async with (
        ChassisSimulator() as sim,
        running(
            "serve", sim.port, "--foxglove-port", "0",
            "--allow-origin", allowed, "--token-file", str(token_file),
        ) as serve,
    ):  # fmt: skip
        line = await serve.wait_for_line(lambda line: "serving" in line)
        assert "token required" in line
        url = _url(line)
        assert await refused(url, origin=allowed) == 401
        assert await refused(url, origin=EVIL, token=TOKEN) == 403
        async with FoxgloveClient(url, origin=allowed, token=TOKEN) as client:
            await teleop(client)
            await client.publish(1, twist(0.2))
            await moving(sim, True, 5.0)
        serve.proc.send_signal(signal.SIGTERM)
        code, out, err = await serve.finish()
    assert code == 128 + signal.SIGTERM, err
    assert "refused a connection from 127.0.0.1" in err
    assert "'http://evil.example' is not allowed" in err
    assert TOKEN not in out + err
    assert drives(sim)[-1] == DriveVelocity(0, 0.0)


@pytest.mark.integration
async def test_cli_serve_beyond_loopback_makes_a_token_and_checks_a_given_one_first(
    tmp_path: Path,
) -> None:
    loose = tmp_path / "loose"
    loose.write_text(TOKEN + "\n")
    loose.chmod(0o644)
    async with ChassisSimulator() as sim:
        code, _, err = await cli("serve", sim.port, "--token-file", str(loose))
        assert code == 1
        assert "open to group or others" in err, err
        assert "chmod 600" in err, err
        code, _, err = await cli("serve", sim.port, "--token", "short")
        assert code == 1
        assert "at least 16" in err, err
        code, _, err = await cli("serve", sim.port, "--allow-origin", "null")
        assert code == 1
        assert "'null'" in err, err
        assert TOKEN not in err
        assert not sim.firmware.received  # the device never opened
        # Beyond loopback without a token, one is made, as web does (issue 44, item 7):
        # the address (TEST-NET, on no interface here) is then what fails, not the token.
        code, _, err = await cli("serve", sim.port, "--host", "192.0.2.1", "--foxglove-port", "0")
        assert code == 1
        assert "cannot serve on 192.0.2.1" in err, err
        assert "token" not in err, err


@pytest.mark.integration
async def test_cli_serve_takes_the_token_from_the_environment(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.setenv("CHASSIS_SDK_FOXGLOVE_TOKEN", TOKEN)
    async with (
        ChassisSimulator() as sim,
        running("serve", sim.port, "--foxglove-port", "0", "--seconds", "20") as serve,
    ):
        line = await serve.wait_for_line(lambda line: "serving" in line)
        assert "token required" in line
        url = _url(line)
        assert await refused(url) == 401
        async with FoxgloveClient(url, bearer=TOKEN) as client:
            await client.wait_for(lambda: bool(client.server_info))
        serve.proc.send_signal(signal.SIGTERM)
        code, out, err = await serve.finish()
    assert code == 128 + signal.SIGTERM, err
    assert TOKEN not in out + err


async def test_a_token_file_keeps_every_character_but_the_final_newline(tmp_path: Path) -> None:
    from chassis_sdk.cli.common import read_secret_file

    path = tmp_path / "t"
    path.write_text(" " + TOKEN + " \n")
    os.chmod(path, 0o600)
    assert read_secret_file(str(path), "--token-file") == " " + TOKEN + " "


# --- the front's cost -----------------------------------------------------------------------


@pytest.mark.integration
@pytest.mark.timing
async def test_the_front_adds_little_latency_to_what_the_server_sends() -> None:
    """Telemetry through the front and straight from foxglove-sdk's server, received
    side by side: the front's extra delay per message (median) is a fraction of a
    millisecond on an idle machine; asserted loosely (a shared machine)."""
    async with served() as (_, _, server):
        front = server._front
        assert front is not None
        async with (
            FoxgloveClient(server.url) as relayed,
            FoxgloveClient(front._backend_url) as direct,
        ):
            for client in (relayed, direct):
                await client.wait_for(lambda c=client: "/chassis/telemetry" in c.channels)
            await asyncio.gather(
                relayed.subscribe("/chassis/telemetry"), direct.subscribe("/chassis/telemetry")
            )
            for client in (relayed, direct):
                await client.wait_for(
                    lambda c=client: len(c.arrived["/chassis/telemetry"]) >= 150, 10.0
                )
    a = {json.loads(d)["seq"]: t for t, d in relayed.arrived["/chassis/telemetry"]}
    b = {json.loads(d)["seq"]: t for t, d in direct.arrived["/chassis/telemetry"]}
    delays = sorted(a[s] - b[s] for s in a.keys() & b.keys())
    assert len(delays) >= 100
    median, p99 = delays[len(delays) // 2], delays[len(delays) * 99 // 100]
    print(f"\nthe front's extra delay: median {median * 1e3:.3f} ms, p99 {p99 * 1e3:.3f} ms")
    assert median < 0.005


# --- leaving the server, and what one run leaves to the next ----------------------------------


class Heartbeat:
    """The longest the event loop went without running a task that wakes every 5 ms."""

    def __init__(self) -> None:
        self.longest = 0.0
        self._last = 0.0
        self._task: asyncio.Task[None] | None = None

    async def _beat(self) -> None:
        while True:
            await asyncio.sleep(0.005)
            self._beaten()

    def _beaten(self) -> None:
        now = time.monotonic()
        self.longest = max(self.longest, now - self._last)
        self._last = now

    def __enter__(self) -> Heartbeat:
        self._last = time.monotonic()
        self._task = asyncio.create_task(self._beat())
        return self

    def __exit__(self, *exc: object) -> None:
        assert self._task is not None
        self._task.cancel()
        self._beaten()  # a loop blocked until now counts too


@pytest.mark.integration
@pytest.mark.timing
async def test_leaving_the_server_stops_a_teleop_robot_at_once_and_never_blocks_the_loop() -> None:
    """A half-open connection (TCP, never a handshake) and a client that stops reading
    must not hold the server's exit: the robot a Teleop client drives gets its zero at
    once (not at the deadman, nor ~10 s later), and the loop runs throughout."""
    async with (
        ChassisSimulator() as sim,
        Chassis(sim.port, command_timeout=5.0) as robot,
    ):
        server = FoxgloveServer(robot, port=0)
        await server.__aenter__()
        _, half_open = await asyncio.open_connection("127.0.0.1", server.port)
        driver = FoxgloveClient(server.url)
        await driver.__aenter__()
        await teleop(driver)
        await driver.publish(1, twist(0.3))
        await moving(sim, True, 2.0)
        # The driver stops reading, and the server has plenty to send it.
        assert driver._reader is not None
        driver._reader.cancel()
        driver._ws.transport.pause_reading()
        await driver.subscribe(*driver.channels)
        await asyncio.sleep(0.3)
        stopped: list[float] = []

        async def watch() -> None:
            await moving(sim, False, 30.0)
            stopped.append(time.monotonic())

        watcher = asyncio.create_task(watch())
        with Heartbeat() as heartbeat:
            start = time.monotonic()
            await server.__aexit__(None, None, None)
            left = time.monotonic() - start
        await asyncio.wait_for(watcher, 1.0)
        print(
            f"\nleft in {left:.2f} s; zero after {(stopped[0] - start) * 1000:.0f} ms; "
            f"the loop's longest gap {heartbeat.longest * 1000:.1f} ms"
        )
        assert stopped[0] - start < 0.3
        assert heartbeat.longest < 0.1
        assert left < 3.0
        assert drives(sim)[-1] == DriveVelocity(0, 0.0)
        half_open.close()
        driver.abort()
        with contextlib.suppress(Exception):
            await driver.__aexit__(None, None, None)


@pytest.mark.integration
@pytest.mark.timing
async def test_leaving_the_server_interrupted_still_stops_everything() -> None:
    """A second Ctrl-C (a cancel) while the front is closing: the robot has its zero,
    foxglove-sdk's server still stops (in a thread of its own) and the streams are
    detached."""
    async with (
        ChassisSimulator() as sim,
        Chassis(sim.port, command_timeout=5.0) as robot,
    ):
        server = FoxgloveServer(robot, port=0)
        await server.__aenter__()
        assert server._front is not None
        backend = urlsplit(server._front._backend_url)
        _, half_open = await asyncio.open_connection("127.0.0.1", server.port)
        async with FoxgloveClient(server.url) as driver:
            await teleop(driver)
            await driver.publish(1, twist(0.3))
            await moving(sim, True, 2.0)
            leaving = asyncio.create_task(server.aclose())
            await moving(sim, False, 0.3)
            await asyncio.sleep(0.1)  # the front is closing: the half-open holds it
            leaving.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await leaving
        assert server._server is None
        assert server._front is None
        assert server._sink is None
        assert backend.hostname is not None
        assert backend.port is not None
        await until(lambda: not _accepts(str(backend.hostname), int(backend.port)), 3.0)
        half_open.close()


def _accepts(host: str, port: int) -> bool:
    try:
        socket.create_connection((host, port), timeout=0.5).close()
    except OSError:
        return False
    return True


@pytest.mark.integration
@pytest.mark.timing
async def test_the_cli_stops_a_teleop_robot_at_once_on_sigterm_with_a_half_open_client() -> None:
    async with (
        ChassisSimulator() as sim,
        running(
            "serve", sim.port, "--foxglove-port", "0", "--command-timeout", "5"
        ) as serve,
    ):  # fmt: skip
        line = await serve.wait_for_line(lambda line: "serving" in line)
        url = _url(line)
        port = int(url.rsplit(":", 1)[1])
        _, half_open = await asyncio.open_connection("127.0.0.1", port)
        async with FoxgloveClient(url) as client:
            await teleop(client)
            await client.publish(1, twist(0.2))
            await moving(sim, True, 5.0)
            start = time.monotonic()
            serve.proc.send_signal(signal.SIGTERM)
            took = await moving(sim, False, 5.0)
            code, _, err = await serve.finish()
            ended = time.monotonic() - start
        half_open.close()
    print(f"\nzero {took * 1000:.0f} ms after SIGTERM; the CLI ended after {ended:.2f} s")
    assert took < 0.3, took
    assert ended < 4.0, ended
    assert code == 128 + signal.SIGTERM, err


@pytest.mark.integration
async def test_a_service_call_that_timed_out_is_cancelled_not_done_later(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    import chassis_sdk.integrations.foxglove.server as live

    monkeypatch.setattr(live, "_SERVICE_TIMEOUT", 0.2)
    done: list[str] = []
    cancelled: list[str] = []

    async def slow_release() -> None:
        try:
            await asyncio.sleep(0.6)
        except asyncio.CancelledError:
            cancelled.append("release")
            raise
        done.append("release")

    async with served() as (_, robot, server), FoxgloveClient(server.url) as client:
        monkeypatch.setattr(robot, "release_emergency_stop", slow_release)
        await client.wait_for(lambda: "release_emergency_stop" in client.services)
        answer = await client.call("release_emergency_stop")
        assert answer == {"success": False, "message": "no answer within 0.2 s"}
        await asyncio.sleep(0.8)
        assert not done  # the operator was told it did not happen: it never does
        assert cancelled == ["release"]


@pytest.mark.integration
async def test_a_new_run_forgets_the_last_ones_clients_and_secret() -> None:
    """foxglove-sdk's new server numbers its clients from 1 again: a client that reaches
    the new private port directly must not inherit "came through the front" (nor a
    Teleop channel) from the last run's client of the same id."""
    async with (
        ChassisSimulator() as sim,
        Chassis(sim.port, command_timeout=1.0) as robot,
    ):
        server = FoxgloveServer(robot, port=0)
        server.start()
        secret = server._secret
        operator = FoxgloveClient(server.url)
        await operator.__aenter__()
        await teleop(operator)
        await operator.publish(1, twist(0.2))
        await moving(sim, True, 2.0)
        await server.aclose()  # the operator still connected: its state is not unadvertised
        with contextlib.suppress(Exception):
            await operator.__aexit__(None, None, None)
        commands = server.commands
        server.start()
        try:
            assert server._secret != secret
            assert not server._fronted
            assert not server._teleop
            assert not server._sources
            front = server._front
            assert front is not None
            async with FoxgloveClient(front._backend_url) as sneak:
                await sneak.wait_for(lambda: bool(sneak.server_info))
                await teleop(sneak)
                await sneak.publish(1, twist(0.3))
                assert (await sneak.call("clear_faults"))["success"] is False
                await until(lambda: server.rejected >= 3, 2.0)
            assert server.commands == commands
            assert not any(sim.firmware.target)
        finally:
            await server.aclose()


@pytest.mark.integration
@pytest.mark.parametrize(
    ("frame", "why"),
    [
        pytest.param("not json at all", "not JSON", id="not-json"),
        # 20,000 deep: past every CPython's json recursion bound (3.13's is about 10,000).
        pytest.param("[" * 20_000 + "]" * 20_000, "not JSON: nested too deeply", id="deep"),
        pytest.param('["advertise"]', "not a JSON object but list", id="list"),
        pytest.param("42", "not a JSON object but int", id="number"),
    ],
)
async def test_the_front_refuses_text_frames_that_are_not_json_objects(
    frame: str, why: str
) -> None:
    async with served() as (sim, _, server), FoxgloveClient(server.url) as client:
        await client.wait_for(lambda: bool(client.server_info))
        await client.send_raw(frame)
        await client.wait_for(lambda: bool(client.statuses))
        status = client.statuses[0]
        assert "a client's text frame" in status["message"], status
        assert why in status["message"], status
        assert server.rejected == 1
        assert server.errors == 0
        # The connection goes on.
        await teleop(client)
        await client.publish(1, twist(0.2))
        await moving(sim, True, 2.0)


@pytest.mark.integration
async def test_the_front_keeps_a_bounded_record_of_a_connections_channels() -> None:
    import chassis_sdk.integrations.foxglove.server as live

    MAX_CLIENT_CHANNELS = getattr(live, "MAX_CLIENT_CHANNELS", 256)
    n = MAX_CLIENT_CHANNELS + 44
    async with served() as (sim, _, server), FoxgloveClient(server.url) as client:
        await client.wait_for(lambda: bool(client.server_info))
        channels = [
            {
                "id": i,
                "topic": f"/cmd_vel{i}",
                "encoding": "json",
                "schemaName": "geometry_msgs/Twist",
            }
            for i in range(1, n + 1)
        ]
        await client.send_raw(json.dumps({"op": "advertise", "channels": channels}))
        await until(lambda: server.rejected == n - MAX_CLIENT_CHANNELS, 5.0)
        await client.wait_for(
            lambda: any(f"more than {MAX_CLIENT_CHANNELS}" in s["message"] for s in client.statuses)
        )
        await asyncio.sleep(0.2)
        assert len(server._teleop) == MAX_CLIENT_CHANNELS
        # One given back makes room for one more.
        await client.unadvertise(1)
        await client.advertise(n + 1, "/cmd_vel", "geometry_msgs/Twist")
        await client.publish(n + 1, twist(0.2))
        await moving(sim, True, 2.0)
        assert server.rejected == n - MAX_CLIENT_CHANNELS


@pytest.mark.integration
async def test_each_kind_of_warning_status_keeps_one_id_so_a_new_summary_replaces_the_old() -> None:
    async with served() as (_, _, server), FoxgloveClient(server.url) as client:
        await client.wait_for(lambda: bool(client.server_info))
        await client.advertise(2, "/chatter", "std_msgs/String")  # not taken
        await client.wait_for(lambda: len(client.statuses) >= 1)
        await asyncio.sleep(1.1)
        await client.advertise(3, "/chatter", "std_msgs/String")
        await client.wait_for(lambda: len(client.statuses) >= 2)
        assert await refused(server.url, origin=EVIL) == 403
        await client.wait_for(lambda: len(client.statuses) >= 3, 3.0)
        await asyncio.sleep(1.1)
        assert await refused(server.url, origin=EVIL) == 403
        await client.wait_for(lambda: len(client.statuses) >= 4, 3.0)
    ids = [s.get("id") for s in client.statuses]
    assert ids == ["chassis-sdk-refusals"] * 2 + ["chassis-sdk-handshake"] * 2, ids
