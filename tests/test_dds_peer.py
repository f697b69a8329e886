"""The independent DDS peer (Fast DDS, tests/ros2_peer) and the ``netns`` harness the
ROS 2 bridge's tests stand on: the namespace is loopback only, two peers talk in it
(multicast discovery and unicast only), QoS is enforced, and the peer builds."""

from __future__ import annotations

import asyncio
import os
import signal
import subprocess
from pathlib import Path

import pytest

from .support import netns
from .support.dds_peer import Peer, build_peer, start_peer

TOPIC = "rt/cmd_vel"


@pytest.fixture(scope="session")
def peer_binary() -> Path:
    # Built (or found cached) in the outer pytest, before a netns test's child starts.
    return build_peer()


@pytest.mark.integration
@pytest.mark.timeout(60)
def test_build_peer_gives_a_working_binary() -> None:
    # Not in a namespace: in CI (and wherever Fast DDS is installed) this must build.
    binary = build_peer()
    assert binary.is_file()
    assert os.access(binary, os.X_OK)
    assert build_peer() == binary  # cached
    usage = subprocess.run([binary], capture_output=True, text=True, timeout=10, check=False)
    assert usage.returncode == 2
    assert "usage: peer pub" in usage.stderr


@pytest.mark.integration
@pytest.mark.netns
@pytest.mark.timeout(60)
def test_namespace_is_loopback_only() -> None:
    assert os.environ.get(netns.IN_NETNS) == "1"
    assert sorted(os.listdir("/sys/class/net")) == ["lo"]
    assert netns.interfaces() == {"lo"}
    ip = netns._tool("ip")
    routes = subprocess.run(
        [ip, "route", "show", "224.0.0.0/4"], capture_output=True, text=True, check=True
    ).stdout
    assert "224.0.0.0/4 dev lo" in routes
    link = subprocess.run(
        [ip, "-o", "link", "show", "lo"], capture_output=True, text=True, check=True
    ).stdout
    assert "MULTICAST" in link
    assert ",UP" in link or "<UP" in link


async def _talk(*extra: str) -> tuple[Peer, Peer]:
    async with (
        await start_peer("sub", "twist", TOPIC, "--count", "3", "--duration", "30", *extra) as sub,
        await start_peer(
            "pub", "twist", TOPIC, "--count", "3", "--rate", "20",
            "--linear", "0.3", "--angular", "0.1", *extra,
        ) as pub,
    ):  # fmt: skip
        await sub.wait_for("matched", timeout=20)
        await pub.wait_for("matched", timeout=20)
        done = await sub.wait_for("done", timeout=20)
        assert done["samples"] == 3
        assert await sub.wait() == 0
        assert await pub.wait() == 0
    return sub, pub


def _check_talk(sub: Peer, pub: Peer) -> None:
    assert len(sub.samples) == 3
    for sample in sub.samples:
        assert sample["linear"] == {"x": 0.3, "y": 0, "z": 0}
        assert sample["angular"] == {"x": 0, "y": 0, "z": 0.1}
    assert [e["i"] for e in pub.named("published")] == [0, 1, 2]
    assert pub.named("acked")[0]["ok"] is True
    assert pub.events[-1]["event"] == "writer_deleted"
    # The other side is a ROS 2-like participant: its USER_DATA carries the enclave.
    assert any(e["user_data"] == "enclave=/;" for e in sub.named("participant"))


@pytest.mark.integration
@pytest.mark.ros2
@pytest.mark.netns
@pytest.mark.timeout(60)
async def test_two_peers_talk_with_multicast_discovery(peer_binary: Path) -> None:
    _check_talk(*await _talk())


@pytest.mark.integration
@pytest.mark.ros2
@pytest.mark.netns
@pytest.mark.timeout(60)
async def test_two_peers_talk_unicast_only(peer_binary: Path) -> None:
    _check_talk(*await _talk("--unicast"))


@pytest.mark.integration
@pytest.mark.ros2
@pytest.mark.netns
@pytest.mark.timeout(60)
async def test_best_effort_writer_does_not_match_a_reliable_reader(peer_binary: Path) -> None:
    async with (
        await start_peer("sub", "twist", TOPIC, "--duration", "30") as sub,
        await start_peer("pub", "twist", TOPIC, "--best-effort", "--wait-match", "2") as pub,
    ):
        # They do discover each other (so the no-match below is the QoS's doing) ...
        await sub.wait_for("incompatible_qos", timeout=10)
        # ... and the reader refuses the writer.
        with pytest.raises(TimeoutError):
            await sub.wait_for("matched", timeout=2)
        assert await pub.wait(timeout=10) == 3
        assert pub.named("no_match")
        assert not pub.named("published")
        assert not sub.named("matched")
        assert not sub.samples


@pytest.mark.integration
@pytest.mark.ros2
@pytest.mark.netns
@pytest.mark.timeout(60)
async def test_stop_ends_a_peer_cleanly(peer_binary: Path) -> None:
    async with await start_peer("sub", "twist", TOPIC, "--duration", "30") as sub:
        await sub.wait_for("started", timeout=10)
        assert await sub.stop() == 128 + signal.SIGTERM  # after deleting its entities
    assert sub.events[-1]["event"] == "interrupted"


def test_verdict_needs_exactly_one_passed_test(tmp_path: Path) -> None:
    def verdict(**counts: int) -> str | None:
        attrs = " ".join(f'{k}="{v}"' for k, v in counts.items())
        report = tmp_path / "report.xml"
        report.write_text(f"<testsuites><testsuite {attrs}/></testsuites>")
        return netns._verdict(report)

    assert verdict(tests=1, failures=0, errors=0, skipped=0) is None
    assert verdict(tests=1, skipped=1) == "1 skipped"
    assert verdict(tests=1, failures=1) == "1 failures"
    assert verdict(tests=0) == "the child ran 0 tests, not 1"
    assert verdict(tests=2) == "the child ran 2 tests, not 1"
    assert netns._verdict(tmp_path / "missing.xml") is not None


@pytest.mark.integration
@pytest.mark.ros2
async def test_wait_for_raises_with_the_peer_s_last_lines(peer_binary: Path) -> None:
    # A peer that exits at once (a usage error): wait_for says so without waiting it out.
    async with await start_peer("pub", "nonsense", TOPIC) as bad:
        loop = asyncio.get_running_loop()
        started = loop.time()
        with pytest.raises(TimeoutError, match=r"(?s)exited \(2\).*usage: peer pub"):
            await bad.wait_for("matched", timeout=30)
        assert loop.time() - started < 10
