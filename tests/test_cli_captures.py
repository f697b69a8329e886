"""The command line's capture and simulator commands (``sim``, ``record``, ``replay``,
``plot``): the real ``chassis-sdk`` in a subprocess against a simulator on a pty or TCP,
a silent pty or a bad path; the cable pulled during ``record``; ``replay --as-device``
feeding an unmodified ``Chassis``; and replay's lines in the monitor's form.

Each failure is one line on stderr with no traceback and an exit code that says so
(2 for an argument refused while parsing); each success says what it did. The rows
named are those of issue 28, which asked for them.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import os
import re
import signal
import socket
from pathlib import Path
from typing import Any

import pytest
from hypothesis import given
from hypothesis import strategies as st

from chassis_sdk.cli.monitor_command import brief
from chassis_sdk.recording import capture
from chassis_sdk.sim import BoardSimulator, ChassisSimulator

from .support.cli import ROOT, cli, one_line, running, silent_pty


def no_traceback(err: str) -> None:
    assert "Traceback" not in err, err
    assert "Exception in callback" not in err, err


def parse_error(code: int, err: str, words: str) -> None:
    """Refused while parsing: exit 2, argparse's usage and one error line naming it."""
    no_traceback(err)
    assert code == 2, err
    last = err.strip().splitlines()[-1]
    assert re.match(r"chassis-sdk( \w+)?: error: ", last), err
    assert words in last, err


async def _record_both(folder: Path) -> dict[str, Path]:
    paths = {}
    async with ChassisSimulator() as sim:
        for suffix in ("mcap", "jsonl"):
            path = folder / f"run.{suffix}"
            cap = await capture.record(sim.port, path, seconds=1.5, device="chassis")
            assert cap.bytes > 1000, cap
            paths[suffix] = path
    return paths


@pytest.fixture(scope="module")
def captures(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """Two real recordings of the chassis simulator, 1.5 s each: run.mcap, run.jsonl."""
    return asyncio.run(_record_both(tmp_path_factory.mktemp("captures")))


# --- row 3: ports checked while parsing; a busy port, a missing directory: one line ------


@pytest.mark.integration
@pytest.mark.parametrize(
    ("args", "words"),
    [
        (("sim", "chassis", "--tcp", "99999"), "port=99999 is out of range"),
        (("sim", "chassis", "--tcp", "-1"), "port=-1 is out of range"),
        (("sim", "chassis", "--tcp", "http"), "--tcp"),
        (("replay", "x.mcap", "--as-device", "--tcp", "99999"), "port=99999 is out of range"),
        (("serve", "/dev/null", "--foxglove-port", "70000"), "port=70000 is out of range"),
        (("web", "/dev/null", "--http-port", "70000"), "port=70000 is out of range"),
    ],
)
async def test_a_tcp_port_out_of_range_is_refused_while_parsing(
    args: tuple[str, ...], words: str
) -> None:
    code, out, err = await cli(*args)
    parse_error(code, err, words)
    assert not out


@pytest.mark.integration
async def test_sim_on_a_tcp_port_in_use_is_one_line() -> None:
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        port = busy.getsockname()[1]
        code, out, err = await cli("sim", "chassis", "--tcp", str(port))
    assert code == 1, err
    line = one_line(err)
    assert f"cannot serve on TCP port {port}: it is in use" in line
    assert not out


@pytest.mark.integration
async def test_replay_as_device_on_a_tcp_port_in_use_is_one_line(
    captures: dict[str, Path],
) -> None:
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        port = busy.getsockname()[1]
        code, _out, err = await cli(
            "replay", str(captures["jsonl"]), "--as-device", "--tcp", str(port)
        )
    assert code == 1, err
    assert f"cannot serve on TCP port {port}: it is in use" in one_line(err)


@pytest.mark.integration
@pytest.mark.parametrize("suffix", ["mcap", "jsonl"])
async def test_record_into_a_missing_directory_is_one_line_before_the_port_opens(
    suffix: str,
) -> None:
    with silent_pty() as port:
        code, out, err = await cli("record", port, f"/nonexistent/dir/x.{suffix}")
    assert code == 1, err
    assert one_line(err) == (
        f"chassis-sdk: cannot write /nonexistent/dir/x.{suffix}: no such directory /nonexistent/dir"
    )
    assert "recording" not in out  # refused before the port opened


@pytest.mark.integration
async def test_record_into_a_directory_is_one_line(tmp_path: Path) -> None:
    folder = tmp_path / "x.jsonl"
    folder.mkdir()
    with silent_pty() as port:
        code, _out, err = await cli("record", port, str(folder))
    assert code == 1, err
    assert "it is a directory" in one_line(err)


# --- row 4: replay --as-device --tcp 0 with a client: a clean end, a true count ---------


def capture_bytes(path: Path) -> int:
    return sum(len(data) for _, data in capture.read_capture(path))


@pytest.mark.integration
async def test_replay_as_device_on_tcp_ends_cleanly_and_counts_the_capture_once(
    captures: dict[str, Path],
) -> None:
    path = captures["mcap"]
    total = capture_bytes(path)
    async with running("replay", str(path), "--as-device", "--tcp", "0") as replay:
        port = (await replay.wait_for_line(lambda line: line.startswith("socket://"))).strip()
        code, _info_out, info_err = await cli("info", port, "--timeout", "0.5")
        no_traceback(info_err)
        code, out, err = await replay.finish()
    assert code == 0, err
    assert err == ""  # no "asyncio ERROR Exception in callback ... CancelledError"
    assert f"replayed {total:,} of the capture's {total:,} bytes" in out, out


@pytest.mark.integration  # the recordings (`captures`) are of a real pty session
def test_a_capture_played_twice_counts_one_playback_and_waits_when_held(
    captures: dict[str, Path],
) -> None:
    device = capture.CaptureFirmware(captures["jsonl"], "chassis")
    total = sum(len(d) for _, d in device.chunks)
    device.hold()  # a TCP server's start: nobody to play to
    assert device.poll(1e9) == b""
    assert device.next_deadline() == float("inf")
    device.on_connect(0.0)  # the first client
    half = device.poll(device.chunks[len(device.chunks) // 2][0])
    assert 0 < len(half) < total
    device.on_connect(10.0)  # a second client: from the start again
    assert len(device.poll(1e9)) == total
    assert device.bytes_played == total  # not the half before it as well


# --- row 6: a recording without a frame of its device warns, then fails ------------------


@pytest.mark.integration
async def test_record_of_the_board_named_chassis_warns_while_recording_and_fails(
    tmp_path: Path,
) -> None:
    path = tmp_path / "x.mcap"
    async with BoardSimulator() as sim:
        code, out, err = await cli(
            "record", sim.port, str(path), "--protocol", "chassis", "--seconds", "4"
        )
    no_traceback(err)
    assert code == 1, err
    warning, error = err.strip().splitlines()
    assert warning.startswith("chassis-sdk record: after 3 s, no chassis frame in "), err
    assert "they look like a board; try --device board" in warning
    assert error.startswith("chassis-sdk: no chassis frame in the "), err
    assert error.endswith("record again with --device board"), err
    assert path.exists()  # kept, for what it is
    assert "recorded " in out


@pytest.mark.integration
async def test_a_recording_says_which_device_it_heard(tmp_path: Path) -> None:
    async with ChassisSimulator() as sim:
        heard = await capture.record(sim.port, tmp_path / "any.jsonl", seconds=0.5)
        named = await capture.record(sim.port, tmp_path / "b.jsonl", seconds=0.5, device="board")
    assert heard.device == "chassis"  # none named: the one heard
    assert named.device is None  # named, and not one frame of it
    assert named.bytes > 0


@pytest.mark.integration
async def test_record_of_a_silent_pty_to_jsonl_fails_in_one_line(tmp_path: Path) -> None:
    with silent_pty() as port:
        code, _out, err = await cli("record", port, str(tmp_path / "x.jsonl"), "--seconds", "1")
    assert code == 1, err
    assert one_line(err) == (
        f"chassis-sdk: no frame of any known device in the 0 bytes recorded from {port} "
        "(is the device on and sending, at this baud rate?)"
    )


@pytest.mark.integration
async def test_record_of_a_silent_pty_warns_after_three_seconds(tmp_path: Path) -> None:
    with silent_pty() as port:
        code, _out, err = await cli("record", port, str(tmp_path / "x.jsonl"), "--seconds", "3.6")
    no_traceback(err)
    assert code == 1, err
    lines = err.strip().splitlines()
    assert lines[0] == (
        f"chassis-sdk record: after 3 s, no frame of any known device from {port}: nothing arrived"
    ), err
    assert len(lines) == 2, err
    assert lines[1].startswith("chassis-sdk: no frame"), err


@pytest.mark.integration
async def test_record_of_the_device_named_says_nothing_on_stderr(tmp_path: Path) -> None:
    async with ChassisSimulator() as sim:
        code, out, err = await cli(
            "record", sim.port, str(tmp_path / "x.jsonl"), "--device", "chassis", "--seconds", "3.6"
        )
    assert (code, err) == (0, ""), err
    assert "recorded " in out


# --- row 12: a missing file, a file of random bytes: plain words -------------------------


@pytest.mark.integration
async def test_replay_of_a_missing_file_says_no_such_file(tmp_path: Path) -> None:
    missing = tmp_path / "nope.mcap"
    code, _out, err = await cli("replay", str(missing))
    assert code == 1, err
    assert one_line(err) == f"chassis-sdk: no such file: {missing}"


@pytest.mark.integration
@pytest.mark.parametrize(
    "command",
    [("replay",), ("plot",), ("export", "--csv", "out")],
)
async def test_a_file_of_random_bytes_is_not_a_capture(
    tmp_path: Path, command: tuple[str, ...]
) -> None:
    noise = tmp_path / "noise.bin"
    noise.write_bytes(bytes(range(256)) * 8 + b"\xc4\xff\xfe" * 100)
    code, _out, err = await cli(command[0], str(noise), *command[1:])
    assert code == 1, err
    assert one_line(err) == (
        f"chassis-sdk: not a chassis-sdk capture (neither JSON lines nor MCAP): {noise}"
    )


# --- row 13: replay prints what monitor does, --json for machines ------------------------


@pytest.mark.integration
@pytest.mark.parametrize("suffix", ["mcap", "jsonl"])
async def test_replay_prints_the_monitor_form_not_python_reprs(
    captures: dict[str, Path], suffix: str
) -> None:
    code, out, err = await cli("replay", str(captures[suffix]))
    assert (code, err) == (0, ""), err
    lines = out.splitlines()
    assert len(lines) > 50
    for line in lines:
        assert "<" not in line, line  # no <ChassisStatus.REMOTE_OFFLINE: 8>
        assert "(" not in line, line  # no Wheels(...)
        assert not re.search(r"\d\.\d{4,}", line), line  # no 16-digit floats
        assert re.match(r"\s*\d+\.\d{3}  \w+: \w+=", line), line
    telemetry = [line for line in lines if "Telemetry: " in line]
    assert telemetry
    assert all("status=REMOTE_OFFLINE" in line for line in telemetry)
    assert all("linear=0.000" in line for line in telemetry)


@pytest.mark.integration
async def test_replay_json_is_one_object_per_line(captures: dict[str, Path]) -> None:
    code, out, err = await cli("replay", str(captures["jsonl"]), "--json")
    assert (code, err) == (0, ""), err
    rows = [json.loads(line) for line in out.splitlines()]
    telemetry = [r for r in rows if r["type"] == "Telemetry"]
    assert telemetry
    assert isinstance(telemetry[0]["linear"], float)
    assert all(isinstance(r["t"], float) for r in rows)


# --- row 15: an MCAP cut by a hard kill: the warning at default verbosity ----------------


@pytest.mark.integration
async def test_replay_of_a_cut_mcap_warns_in_one_line(
    captures: dict[str, Path], tmp_path: Path
) -> None:
    whole = captures["mcap"].read_bytes()
    cut = tmp_path / "cut.mcap"
    for fraction in (0.5, 0.67, 0.8, 0.95):  # torn in a chunk, an index, the summary
        # What kill -9 leaves: no summary section and a torn last record.
        cut.write_bytes(whole[: int(len(whole) * fraction)])
        code, out, err = await cli("replay", str(cut))
        assert code == 0, err
        lines = err.strip().splitlines()
        assert len(lines) == 1, err
        assert lines[0].startswith(f"chassis-sdk replay: {cut} ends early ("), err
        assert "read up to there" in lines[0]
        assert "Telemetry: " in out  # what is there is replayed
    # The whole file says nothing.
    code, _out, err = await cli("replay", str(captures["mcap"]))
    assert (code, err) == (0, "")


# --- row 19: options of --as-device without it ---------------------------------------------


@pytest.mark.integration
@pytest.mark.parametrize(
    ("extra", "flags"),
    [
        (("--tcp", "5001"), "--tcp"),
        (("--speed", "3"), "--speed"),
        (("--start-after", "2"), "--start-after"),
        (("--tcp", "0", "--speed", "2"), "--tcp, --speed"),
    ],
)
async def test_replay_options_of_as_device_without_it_are_refused(
    captures: dict[str, Path], extra: tuple[str, ...], flags: str
) -> None:
    code, out, err = await cli("replay", str(captures["jsonl"]), *extra)
    parse_error(code, err, f"{flags} needs --as-device")
    assert not out  # nothing replayed


# --- issue 44, item 9: an output that cannot be written, refused before reading ------------


@pytest.mark.integration
@pytest.mark.parametrize(
    ("args", "says"),
    [
        pytest.param(("export", "{cap}", "--csv", "/proc/nope"), "cannot make --csv /proc/nope: ", id="export-csv-cannot-be-made"),
        pytest.param(("export", "{cap}", "--csv", "{cap}"), "--csv {cap} is a file, not a directory", id="export-csv-a-file"),
        pytest.param(("plot", "{cap}", "-o", "/nonexistent/x.png"), "cannot write -o /nonexistent/x.png: no such directory /nonexistent", id="plot-no-such-directory"),
        pytest.param(("plot", "{cap}", "-o", "{tmp}"), "cannot write -o {tmp}: it is a directory", id="plot-a-directory"),
    ],
)  # fmt: skip
async def test_an_output_that_cannot_be_written_is_refused_before_the_capture_is_read(
    tmp_path: Path, args: tuple[str, ...], says: str
) -> None:
    cap = tmp_path / "cap.jsonl"
    cap.write_text("hello\n")  # read first, it would be refused as no capture instead
    code, out, err = await cli(*(a.format(cap=cap, tmp=tmp_path) for a in args))
    assert (code, out) == (1, ""), err
    assert one_line(err).startswith(f"chassis-sdk: {says.format(cap=cap, tmp=tmp_path)}"), err


# --- row 20: plot beside the input ---------------------------------------------------------


@pytest.mark.integration
async def test_plot_without_output_writes_beside_the_input(
    captures: dict[str, Path], tmp_path: Path
) -> None:
    folder = tmp_path / "rec"
    folder.mkdir()
    source = folder / "run.jsonl"
    source.write_bytes(captures["jsonl"].read_bytes())
    stray = ROOT / "capture.png"
    before = stray.exists()
    code, out, err = await cli("plot", str(source))
    assert (code, err) == (0, ""), err
    png = folder / "run.png"
    assert png.read_bytes().startswith(b"\x89PNG")
    assert out.startswith(f"wrote {png} ("), out
    assert stray.exists() == before  # nothing in the current directory


# --- the cable pulled during record, the wrong protocol, sim's port, replay as a device ---


@pytest.mark.integration
async def test_record_reports_an_unplug_and_a_replug_and_writes_them_down(tmp_path: Path) -> None:
    path = tmp_path / "cap.jsonl"
    async with (
        ChassisSimulator(tcp_port=0) as sim,
        running("record", sim.port, str(path), "--seconds", "3") as rec,
    ):
        await rec.wait_for_line(lambda line: re.search(r": [1-9][\d,]* bytes", line) is not None)
        sim.unplug()
        await rec.wait_for_line(lambda line: "LINK LOST" in line)
        await sim.replug()
        code, out, err = await rec.finish()
    assert code == 0, err
    assert "\r" not in out  # piped: plain lines, never a carriage return
    assert "the link dropped 1 time(s)" in out
    events = [json.loads(line).get("event") for line in path.read_text().splitlines()]
    assert [e for e in events if e] == ["disconnected", "reconnected"]
    code, out, err = await cli("replay", str(path))
    assert code == 0, err
    assert "Telemetry: " in out


@pytest.mark.integration
async def test_record_fails_when_the_link_is_not_restored(tmp_path: Path) -> None:
    path = tmp_path / "cap.jsonl"
    async with (
        ChassisSimulator(tcp_port=0) as sim,
        running("record", sim.port, str(path), "--seconds", "2") as rec,
    ):
        await rec.wait_for_line(lambda line: re.search(r": [1-9][\d,]* bytes", line) is not None)
        sim.unplug()
        code, _, err = await rec.finish()
    assert code == 1
    assert "was lost and not restored" in one_line(err)


@pytest.mark.integration
async def test_replay_with_the_wrong_protocol_says_so(tmp_path: Path) -> None:
    path = tmp_path / "board.jsonl"
    async with BoardSimulator() as board:
        code, _, err = await cli("record", board.port, str(path), "--seconds", "0.5")
    assert code == 0, err
    code, out, err = await cli("replay", str(path), "--protocol", "chassis")
    assert code == 1
    assert out == ""
    assert "no chassis frames in" in one_line(err)
    assert "it looks like a board capture; try --device board" in err


@pytest.mark.integration
async def test_sim_removes_its_port_link_on_sigterm() -> None:
    async with running("sim", "chassis") as sim:
        port = (await sim.wait_for_line(lambda line: True)).strip()
        assert os.path.islink(port)
        sim.proc.send_signal(signal.SIGTERM)
        code, _, _ = await sim.finish()
    assert code == 128 + signal.SIGTERM
    assert not os.path.lexists(port)


@pytest.mark.integration
@pytest.mark.parametrize("suffix", [".jsonl", ".mcap"])
async def test_replay_as_a_device_feeds_an_unmodified_chassis(tmp_path: Path, suffix: str) -> None:
    from chassis_sdk import Chassis, ConnectionLostError, Telemetry
    from chassis_sdk.recording import capture

    path = tmp_path / f"cap{suffix}"
    async with ChassisSimulator() as sim:
        await capture.record(sim.port, path, seconds=1.0)
    recorded = [
        m.seq for _, m in capture.decode_capture(path, "chassis") if isinstance(m, Telemetry)
    ]
    assert len(recorded) >= 40
    async with running("replay", str(path), "--as-device", "--tcp", "0") as replay:
        port = (await replay.wait_for_line(lambda line: True)).strip()
        seen: list[int] = []
        async with Chassis(port) as robot:
            await robot.set_velocity(0.2, 0.0)  # written, counted, never acted on
            with contextlib.suppress(ConnectionLostError):
                async for t in robot.telemetry():
                    seen.append(t.seq)
        code, out, err = await replay.finish()
    assert code == 0, err
    # What the robot sent, with its own sequence numbers, in order.
    assert len(seen) >= len(recorded) - 5
    assert seen == recorded[len(recorded) - len(seen) :]
    assert "the application wrote" in out
    assert "DriveVelocity" in out


# --- replay's lines: the monitor form, as first written ---------------------------------


def _brief_reference(value: object) -> str:
    """`brief` as first written (a call per field): its loop must print the same."""
    if isinstance(value, dict):
        return " ".join(
            f"{k}={_brief_reference(v)}"
            for k, v in value.items()
            if k not in ("timestamp", "monotonic")
        )
    if isinstance(value, float):
        return f"{value:.3f}"
    return str(value)


_leaves = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True),
    st.integers(),
    st.booleans(),
    st.none(),
    st.text(max_size=8),
    st.lists(st.integers(), max_size=3),
)
_fields = st.recursive(
    _leaves,
    lambda inner: st.dictionaries(
        st.sampled_from(["a", "voltage", "timestamp", "monotonic", "wheels", "seq"]), inner
    ),
    max_leaves=12,
)


@given(st.dictionaries(st.text(max_size=6), _fields, max_size=10))
def test_brief_prints_what_its_first_form_printed(fields: dict[str, Any]) -> None:
    # `replay` and `monitor` print each message through `brief`; its fast loop (no call
    # per float or name) must give the same text for every kind of field.
    assert brief(fields) == _brief_reference(fields)


@pytest.mark.integration  # the recordings (`captures`) are of a real pty session
def test_replay_lines_of_every_message_kind_match_the_first_form(
    captures: dict[str, Path],
) -> None:
    from chassis_sdk.cli.replay_command import replay_line
    from chassis_sdk.core.plain import jsonable

    seen = set()
    for path in captures.values():
        for t, msg in capture.decode_capture(path, "chassis"):
            seen.add(type(msg).__name__)
            expected = f"{t:10.3f}  {type(msg).__name__}: {_brief_reference(jsonable(msg))}"
            assert replay_line(t, msg) == expected
    assert seen, "the captures hold no messages"
