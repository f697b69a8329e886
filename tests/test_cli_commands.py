"""The command line's parser: every command is its own ``func``, none falls through to
another, ``--device`` has one meaning whichever of its names is typed, and a bad
argument is refused while parsing (exit 2, nothing printed first, no port opened)."""

from __future__ import annotations

import argparse

import pytest

import chassis_sdk.cli
from chassis_sdk.cli import build_parser, drive_command, main

from .support.cli import cli


def _subcommands(parser: argparse.ArgumentParser) -> dict[str, argparse.ArgumentParser]:
    actions = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
    assert len(actions) == 1
    choices: dict[str, argparse.ArgumentParser] = actions[0].choices
    return choices


def test_every_command_has_its_own_func() -> None:
    commands = _subcommands(build_parser())
    assert {"demo", "ports", "detect", "sim", "info", "monitor", "drive", "record"} <= set(commands)
    assert {"replay", "plot", "export", "serve", "bridge"} <= set(commands)
    funcs = {}
    for name, sub in commands.items():
        func = sub.get_default("func")
        assert callable(func), f"{name} sets no func"
        funcs[name] = func
    # No two commands share one: none is another's fallback.
    assert len(set(funcs.values())) == len(funcs)


@pytest.mark.parametrize("argv", [["drvie", "/dev/ttyX"], ["frobnicate"], ["Drive", "/dev/ttyX"]])
def test_an_unknown_command_is_a_usage_error_and_never_drives(
    argv: list[str],
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    driven: list[object] = []
    monkeypatch.setattr(drive_command, "drive", lambda *a: driven.append(a))
    with pytest.raises(SystemExit) as exit_info:
        main(argv)
    assert exit_info.value.code == 2
    err = capsys.readouterr().err
    assert "usage: chassis-sdk" in err
    assert "invalid choice" in err
    assert driven == []


def test_no_command_is_a_usage_error(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exit_info:
        main([])
    assert exit_info.value.code == 2
    assert "usage: chassis-sdk" in capsys.readouterr().err


@pytest.mark.parametrize(
    "command",
    [
        ["info", "/dev/ttyX"],
        ["monitor", "/dev/ttyX"],
        ["drive", "/dev/ttyX"],
        ["record", "/dev/ttyX", "out.jsonl"],
        ["replay", "cap.jsonl"],
        ["plot", "cap.jsonl"],
        ["export", "cap.jsonl", "--csv", "out"],
        ["serve", "/dev/ttyX"],
        ["bridge", "/dev/ttyX", "--robot-id", "r1"],
        ["demo"],
    ],
    ids=lambda c: c[0],
)
def test_protocol_is_the_old_name_of_device(command: list[str]) -> None:
    parser = build_parser()
    old = parser.parse_args([*command, "--protocol", "board"])
    new = parser.parse_args([*command, "--device", "board"])
    assert old.device == new.device == "board"
    assert not hasattr(old, "protocol")


def test_protocol_is_taken_but_not_shown(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exit_info:
        main(["info", "--help"])
    assert exit_info.value.code == 0
    page = capsys.readouterr().out
    assert "--device" in page
    assert "--protocol" not in page


def test_an_unknown_device_is_refused_under_either_name(
    capsys: pytest.CaptureFixture[str],
) -> None:
    for flag in ("--device", "--protocol"):
        with pytest.raises(SystemExit) as exit_info:
            main(["info", "/dev/ttyX", flag, "tractor"])
        assert exit_info.value.code == 2
        assert "invalid choice: 'tractor'" in capsys.readouterr().err


def test_the_package_exports_the_parser() -> None:
    assert "build_parser" in chassis_sdk.cli.__all__


def test_the_device_comes_from_chassis_sdk_device_before_its_old_name(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    monkeypatch.setenv("CHASSIS_SDK_PROTOCOL", "chassis")
    monkeypatch.setenv("CHASSIS_SDK_DEVICE", "board")
    assert build_parser().parse_args(["info", "/dev/ttyX"]).device == "board"
    monkeypatch.setenv("CHASSIS_SDK_DEVICE", "tractor")
    with pytest.raises(SystemExit) as exited:
        main(["info", "/dev/ttyX"])
    assert exited.value.code == 2
    assert "CHASSIS_SDK_DEVICE='tractor' is not a known device" in capsys.readouterr().err


# --- refused while parsing -----------------------------------------------------------------


def test_row18_argument_types_refuse_a_type_error_too(
    capsys: pytest.CaptureFixture[str],
) -> None:
    import argparse

    from chassis_sdk.cli.arguments import arg_type

    def must_be_int(value: object) -> object:
        if not isinstance(value, int):
            raise TypeError(f"n must be an integer, got {value!r}")
        return value

    parser = argparse.ArgumentParser(prog="x")
    parser.add_argument("--n", type=arg_type(float, must_be_int))
    with pytest.raises(SystemExit) as exited:
        parser.parse_args(["--n", "1.5"])
    assert exited.value.code == 2
    assert "argument --n: n must be an integer, got 1.5" in capsys.readouterr().err


@pytest.mark.integration
@pytest.mark.parametrize(
    ("args", "says"),
    [
        pytest.param(("serve", "/dev/ttyX", "--foxglove-port", "70000"), "argument --foxglove-port: port=70000 is out of range", id="serve-port"),
        pytest.param(("bridge", "/dev/ttyX", "--robot-id", "r1", "--broker", "http://x"), "argument --broker: must be mqtt://HOST:PORT or mqtts://HOST:PORT, got 'http://x'", id="broker-http"),
        pytest.param(("bridge", "/dev/ttyX", "--robot-id", "r1", "--broker", "mqtt://h:99999"), "argument --broker: has a bad port", id="broker-port"),
        pytest.param(("bridge", "/dev/ttyX", "--robot-id", "a/b#"), "argument --robot-id: robot_id must be letters, digits, '-' or '_', got 'a/b#'", id="robot-id"),
        pytest.param(("bridge", "/dev/ttyX", "--robot-id", "r1", "--prefix", "+"), "argument --prefix: prefix must be letters", id="prefix"),
        pytest.param(("bridge", "/dev/ttyX", "--robot-id", "r1", "--rate", "1000"), "argument --rate: rate must be a finite number 0 to 100", id="bridge-rate"),
        pytest.param(("sim", "chassis", "--noise", "2"), "argument --noise: noise must be a finite number 0 to 1, got 2.0", id="sim-noise"),
        pytest.param(("sim", "chassis", "--drop", "-0.1"), "argument --drop: drop must be a finite number 0 to 1", id="sim-drop"),
    ],
)  # fmt: skip
async def test_row11_bad_arguments_are_refused_while_parsing(
    args: tuple[str, ...], says: str
) -> None:
    code, out, err = await cli(*args)
    assert code == 2, err
    assert says in err
    assert "Traceback" not in err
    assert out == ""  # nothing printed first ("bridging ... as robots/a/b#")


@pytest.mark.integration
async def test_row11_a_bad_broker_from_the_environment_is_refused_while_parsing() -> None:
    code, out, err = await cli(
        "bridge", "/dev/ttyX", "--robot-id", "r1", env={"CHASSIS_SDK_BROKER": "http://y"}
    )
    assert code == 2, err
    assert "argument --broker: must be mqtt://HOST:PORT or mqtts://HOST:PORT, got 'http://y'" in err
    assert out == ""


# --- issue 44, item 9: usage errors in the user's words, with the command's usage --------


#: (what is typed, the command whose usage is shown ("" for chassis-sdk's own), how the
#: error line after "error: " starts): each refused by the parser (exit 2), nothing run.
USAGE_ERRORS = [
    pytest.param(("dock", "/dev/ttyX", "park"), "dock", "argument start|stop: invalid choice: 'park' (choose from 'start', 'stop')", id="dock-choice-named"),
    pytest.param(("calibrate", "/dev/ttyX", "both"), "calibrate", "argument linear|angular: invalid choice: 'both' (choose from 'linear', 'angular')", id="calibrate-choice-named"),
    pytest.param(("info",), "info", "no port given (give PORT, or set CHASSIS_SDK_PORT)", id="missing-port-info"),
    pytest.param(("dock", "start"), "dock", "no port given (give PORT, or set CHASSIS_SDK_PORT)", id="missing-port-dock"),
    pytest.param(("estop",), "estop", "no port given (give PORT, or set CHASSIS_SDK_PORT)", id="missing-port-estop"),
    pytest.param(("drive", "/dev/ttyX"), "drive", "give a velocity: --linear V and/or --angular W", id="missing-velocity"),
    pytest.param(("mointor", "/dev/ttyX"), "", "argument COMMAND: invalid choice: 'mointor', did you mean 'monitor'? (choose from 'demo', ", id="did-you-mean-command"),
    pytest.param(("clear_faults", "/dev/ttyX"), "", "argument COMMAND: invalid choice: 'clear_faults', did you mean 'clear-faults'?", id="did-you-mean-dash"),
    pytest.param(("frobnicate",), "", "argument COMMAND: invalid choice: 'frobnicate' (choose from 'demo', ", id="nothing-close"),
    pytest.param(("dock", "/dev/ttyX", "strat"), "dock", "argument start|stop: invalid choice: 'strat', did you mean 'start'?", id="did-you-mean-choice"),
    pytest.param(("info", "/dev/ttyX", "--device", "bord"), "info", "argument --device: invalid choice: 'bord', did you mean 'board'?", id="did-you-mean-device"),
    pytest.param(("sim", "chassis", "--reply-delay", "-1"), "sim", "argument --reply-delay: reply_delay must be a finite number >= 0 s, got -1.0", id="reply-delay-negative"),
    pytest.param(("sim", "chassis", "--drop", "abc"), "sim", "argument --drop: 'abc' is not a number", id="drop-not-a-number"),
    pytest.param(("sim", "chassis", "--tcp", "5e3"), "sim", "argument --tcp: '5e3' is not a whole number", id="tcp-not-a-whole-number"),
]  # fmt: skip


@pytest.mark.integration
@pytest.mark.parametrize(("args", "command", "error"), USAGE_ERRORS)
async def test_usage_errors_say_what_was_typed_under_the_commands_usage(
    args: tuple[str, ...], command: str, error: str
) -> None:
    code, out, err = await cli(*args, env={"CHASSIS_SDK_PORT": ""})
    prog = f"chassis-sdk {command}".strip()
    assert (code, out) == (2, ""), err
    assert "Traceback" not in err
    assert err.startswith(f"usage: {prog} "), err  # the command's usage, not the top level's
    assert err.strip().splitlines()[-1].startswith(f"{prog}: error: {error}"), err
