"""The robot profile: where it is found, what it refuses (one line naming the file, the
key and what is allowed), how it is written back, and that every command and the API
use it: a flag beats the environment, the environment beats the file, the file beats
the default."""

from __future__ import annotations

import asyncio
import json
import os
import re
import sys
from pathlib import Path
from typing import Any

import pytest

from chassis_sdk import Geofence, Reflex, open_robot
from chassis_sdk.cli import build_parser, main, parse
from chassis_sdk.cli.profile import subparsers
from chassis_sdk.core.battery import BatteryModel
from chassis_sdk.core.calibration import Calibration
from chassis_sdk.core.motion import MotionLimits
from chassis_sdk.devices.config import (
    COMMAND_TABLES,
    DEVICE_TABLES,
    ENV_CONFIG,
    Profile,
    ProfileError,
    find_profile,
    load_profile,
    locate_profile,
    update_profile,
)
from chassis_sdk.protocol import DriveVelocity
from chassis_sdk.sim import ChassisSimulator

from .support.helpers import until, wait_until

ROOT = Path(__file__).resolve().parent.parent
EXAMPLE = ROOT / "chassis_sdk" / "devices" / "chassis-sdk.example.toml"
DOCS = ROOT / "docs" / "configuration.md"


@pytest.fixture
def home(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """A working directory and a user config dir of the test's own, no profile in
    the environment."""
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("XDG_CONFIG_HOME", str(tmp_path / "xdg"))
    monkeypatch.setenv("HOME", str(tmp_path))
    for variable in (ENV_CONFIG, "CHASSIS_SDK_PORT", "CHASSIS_SDK_DEVICE", "CHASSIS_SDK_PROTOCOL"):
        monkeypatch.delenv(variable, raising=False)
    return tmp_path


def write(path: Path, text: str) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text, encoding="utf-8")
    return path


# --- finding it -----------------------------------------------------------------------


def test_found_in_order_config_flag_environment_working_directory_user_dir(
    home: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    assert locate_profile() is None
    assert load_profile() == Profile()
    user = write(home / "xdg" / "chassis-sdk" / "chassis-sdk.toml", "[robot]\nbaudrate = 1\n")
    assert locate_profile() == (user, "user config dir")
    here = write(home / "chassis-sdk.toml", "[robot]\nbaudrate = 2\n")
    assert locate_profile() == (Path("chassis-sdk.toml"), "./chassis-sdk.toml")
    assert here.samefile(find_profile() or "")
    named = write(home / "env.toml", "[robot]\nbaudrate = 3\n")
    monkeypatch.setenv(ENV_CONFIG, str(named))
    assert locate_profile() == (named, f"${ENV_CONFIG}")
    flag = write(home / "flag.toml", "[robot]\nbaudrate = 4\n")
    assert load_profile(flag).get("robot", "baudrate") == 4
    assert load_profile().get("robot", "baudrate") == 3


def test_a_named_file_that_is_missing_is_an_error_not_no_profile(
    home: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    with pytest.raises(ProfileError, match=r"^--config nope.toml: no such file$"):
        load_profile("nope.toml")
    monkeypatch.setenv(ENV_CONFIG, "gone.toml")
    with pytest.raises(ProfileError, match=r"^\$CHASSIS_SDK_CONFIG=gone.toml: no such file$"):
        load_profile()


# --- what it refuses ------------------------------------------------------------------

#: (file text, what the one-line error must say): every line names the file and key.
MALFORMED = [
    ("[safety]\nstall = 'ignore'\n", r"\[safety\] ignoring the stall needs allow_unsafe"),
    ("[safety]\nstall = 'back_off'\n", r"\[safety\] stall cannot back_off"),
    (
        "[safety]\ngeofence_rectangle = [1, 2]\ngeofence_circle = [0, 0, 1]\n",
        r"\[safety\] one geofence, not geofence_rectangle and geofence_circle",
    ),
    ("[limts]\nmax_linear = 1\n", r"unknown table \[limts\]; did you mean 'limits'\?"),
    ("port = 'x'\n", r"port = 'x' is outside any table"),
    ("[robot]\nprot = 'x'\n", r"\[robot\] prot: unknown key; did you mean 'port'\?"),
    ("[robot]\ndevice = 'mower'\n", r"\[robot\] device: 'mower' is not a known device"),
    ("[robot]\nbaudrate = 'fast'\n", r"\[robot\] baudrate: must be a whole number"),
    ("[robot]\nbaudrate = 0\n", r"\[robot\] baudrate: must be > 0"),
    ("[robot]\nreconnect = 1\n", r"\[robot\] reconnect: must be true or false"),
    ("[limits]\nmax_linear = -1\n", r"\[limits\] max_linear must be a finite number > 0"),
    ("[limits]\nmax_linear = nan\n", r"\[limits\] max_linear: must be a finite number"),
    ("[limits]\nmax_linear = true\n", r"\[limits\] max_linear: must be a number"),
    ("[deadman]\ncommand_timeout = 0\n", r"\[deadman\] command_timeout: must be > 0"),
    ("[calibration]\nlinear_scale = 5\n", r"\[calibration\] linear_scale must be"),
    ("[battery]\nchemistry = 'nicd'\n", r"\[battery\] chemistry: must be one of 'lifepo4'"),
    ("[battery]\ncells = 7.5\n", r"\[battery\] cells: must be a whole number"),
    ("[battery]\ncurve = [[3.0, 0, 1]]\n", r"\[battery\] curve: each item must be a list of 2"),
    ("[battery]\nlow = 5\ncritical = 10\n", r"\[battery\] "),
    ("[robot\n", r"not TOML"),
    ("[web]\nprot = 80\n", r"\[web\] prot: `chassis-sdk web` has no such option; did you mean"),
    ("[web]\nhttp_port = 'eighty'\n", r"\[web\] http_port: "),
    ("[web]\nport = 8080\n", r"\[web\] port = 8080: renamed http_port \(port is the serial port"),
    ("[ros2]\nmax_linear = -2\n", r"\[ros2\] max_linear: max_linear must be a finite number"),
    ("[ros2]\nstamped = 'yes'\n", r"\[ros2\] stamped: must be true or false"),
    ("[drive]\ndevice = 'mower'\n", r"\[drive\] device: must be one of 'chassis', 'board'"),
]


@pytest.mark.parametrize(("text", "says"), MALFORMED, ids=[m[1][:40] for m in MALFORMED])
def test_a_wrong_table_key_type_or_value_is_one_line_naming_file_and_key(
    home: Path, text: str, says: str, capsys: pytest.CaptureFixture[str]
) -> None:
    bad = write(home / "bad.toml", text)
    code = main(["--config", str(bad), "drive", "/dev/null"])
    err = capsys.readouterr().err
    assert code == 2
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert lines[0].startswith(f"chassis-sdk: {bad}: "), err
    assert re.search(says, lines[0]), lines[0]


def test_every_command_table_is_a_command_and_every_command_has_its_table() -> None:
    commands = set(subparsers(build_parser())) - {"config"}
    assert commands == set(COMMAND_TABLES)


# --- writing it back ------------------------------------------------------------------


def test_update_profile_keeps_comments_and_other_keys_and_refuses_a_bad_value(
    home: Path,
) -> None:
    path = write(home / "robot.toml", "# my robot\n[robot]\nport = 'a'  # the cable\n")
    update_profile(path, "calibration", {"linear_scale": 1.04})
    update_profile(path, "calibration", {"angular_scale": 0.83})
    text = path.read_text()
    assert "# my robot" in text
    assert "# the cable" in text
    assert load_profile(path).calibration == Calibration(1.04, 0.83)
    with pytest.raises(ProfileError, match=r"\[calibration\] linear_scale"):
        update_profile(path, "calibration", {"linear_scale": 9.0})
    assert path.read_text() == text  # nothing written
    link = home / "link.toml"
    link.symlink_to(path)
    path.chmod(0o600)
    update_profile(link, "calibration", {"linear_scale": 1.02})
    assert link.is_symlink()
    assert load_profile(path).calibration == Calibration(1.02, 0.83)
    assert path.stat().st_mode & 0o777 == 0o600
    fresh = home / "new.toml"
    update_profile(fresh, "calibration", {"linear_scale": 0.97})
    assert load_profile(fresh).calibration == Calibration(0.97, 1.0)


# --- precedence on the command line ---------------------------------------------------


def test_flag_beats_environment_beats_file_beats_default(
    home: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    def parsed(*argv: str) -> object:
        return parse(build_parser(), list(argv))

    args = parsed("web")
    assert (args.port, args.max_linear, args.http_port) == (None, 0.5, 8080)  # type: ignore[attr-defined]
    write(
        home / "chassis-sdk.toml",
        "[robot]\nport = '/dev/file'\n[limits]\nmax_linear = 0.3\n[web]\nhttp_port = 9000\n"
        "max_angular = 0.7\n[ros2]\nstamped = true\nno_tf = true\n",
    )
    args = parsed("web")
    assert (args.port, args.max_linear, args.http_port, args.max_angular) == (  # type: ignore[attr-defined]
        "/dev/file",
        0.3,
        9000,
        0.7,
    )
    ros2 = parsed("ros2")
    assert (ros2.stamped, ros2.no_tf, ros2.max_linear) == (True, True, 0.3)  # type: ignore[attr-defined]
    assert parsed("ros2", "--config", str(home / "chassis-sdk.toml")).no_tf is True  # type: ignore[attr-defined]
    monkeypatch.setenv("CHASSIS_SDK_PORT", "/dev/env")
    assert parsed("web").port == "/dev/env"  # type: ignore[attr-defined]
    args = parsed("web", "/dev/flag", "--max-linear", "0.2", "--http-port", "9001")
    assert (args.port, args.max_linear, args.http_port) == ("/dev/flag", 0.2, 9001)  # type: ignore[attr-defined]
    # --config may come before or after the command's name
    other = write(home / "other.toml", "[limits]\nmax_linear = 0.1\n")
    assert parsed("--config", str(other), "web").max_linear == 0.1  # type: ignore[attr-defined]
    assert parsed("web", "--config", str(other)).max_linear == 0.1  # type: ignore[attr-defined]


def test_ports_lists_every_port_whatever_the_profile_names(home: Path) -> None:
    write(home / "chassis-sdk.toml", "[robot]\nport = '/dev/file'\n")
    assert getattr(parse(build_parser(), ["ports"]), "port", None) is None


def test_config_prints_each_setting_with_its_source(
    home: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    write(home / "chassis-sdk.toml", "[limits]\nmax_linear = 0.3\n[web]\nhttp_port = 9000\n")
    monkeypatch.setenv("CHASSIS_SDK_PORT", "/dev/env")
    assert main(["config", "web", "--json"]) == 0
    shown = json.loads(capsys.readouterr().out)
    assert shown["profile"] == "chassis-sdk.toml"
    assert shown["found_by"] == "./chassis-sdk.toml"
    tables = shown["tables"]
    assert tables["limits"]["max_linear"] == {"value": 0.3, "source": "file"}
    assert tables["limits"]["max_angular"] == {"value": None, "source": "default"}
    assert tables["robot"]["port"] == {"value": "/dev/env", "source": "$CHASSIS_SDK_PORT"}
    web = shown["command"]["settings"]
    assert web["http_port"] == {"value": 9000, "source": "[web] http_port"}
    assert web["max_linear"] == {"value": 0.3, "source": "[limits] max_linear"}
    assert web["host"] == {"value": "127.0.0.1", "source": "default"}
    assert main(["config"]) == 0
    text = capsys.readouterr().out
    assert "profile: chassis-sdk.toml (found by ./chassis-sdk.toml)" in text
    assert re.search(r"max_linear\s+0\.3\s+chassis-sdk\.toml", text)


def test_the_example_profile_is_valid_and_names_every_device_key(
    home: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    profile = load_profile(EXAMPLE)
    assert isinstance(profile.battery(), BatteryModel)
    text = EXAMPLE.read_text()
    for table, keys in DEVICE_TABLES.items():
        assert f"[{table}]" in text
        for key in keys:
            assert re.search(rf"^#? ?{key} = ", text, re.M), (table, key)
    assert main(["config", "--example"]) == 0
    assert capsys.readouterr().out.strip() == text.strip()


def test_the_docs_document_every_key_and_every_command_table() -> None:
    docs = DOCS.read_text()
    for table, keys in DEVICE_TABLES.items():
        assert f"[{table}]" in docs
        for key in keys:
            assert f"| `{key}` |" in docs, (table, key)
    for command in COMMAND_TABLES:
        assert f"[{command}]" in docs, command


def test_the_safety_table_is_the_devices_policy(home: Path) -> None:
    path = write(
        home / "robot.toml",
        "[safety]\nbumper = 'back_off'\nback_off_distance = 0.2\nbattery = 'slow'\n"
        "slow_speed = 0.15\nbattery_critical = 22.0\ngeofence_circle = [1.0, 0.0, 3.0]\n",
    )
    policy = load_profile(path).safety
    assert policy is not None
    assert policy.bumper == Reflex("back_off", distance=0.2, speed=0.15)
    assert policy.battery.action == "slow"
    assert policy.battery_critical == 22.0
    assert policy.fence == Geofence(centre=(1.0, 0.0), radius=3.0)
    assert policy.stall == Reflex()
    assert load_profile(path).device_options()["safety"] == policy


# --- the API and the commands use it -------------------------------------------------


@pytest.mark.integration
async def test_open_robot_builds_the_device_the_profile_describes(home: Path) -> None:
    async with ChassisSimulator() as sim:
        write(
            home / "chassis-sdk.toml",
            f"[robot]\nport = '{sim.port}'\n[limits]\nmax_linear = 0.2\n"
            "[calibration]\nlinear_scale = 1.05\n[battery]\nchemistry = 'li-ion'\ncells = 7\n"
            "[deadman]\ncommand_timeout = 0.3\n",
        )
        async with open_robot() as robot:
            assert robot.limits == MotionLimits(max_linear=0.2)
            assert robot.calibration == Calibration(linear_scale=1.05)
            assert isinstance(robot.battery_model, BatteryModel)
            await robot.set_velocity(0.5, 0.0)
            await asyncio.sleep(0)  # the write is queued at once

        def linear() -> list[int]:
            return [c.linear_mm for _, c in sim.firmware.received if isinstance(c, DriveVelocity)]

        await until(lambda: 0 in linear()[1:])  # the simulator has read the zero of close()
        assert max(linear()) == 200


def test_open_robot_without_a_port_says_so(home: Path) -> None:
    write(home / "chassis-sdk.toml", "[limits]\nmax_linear = 0.2\n")
    with pytest.raises(ProfileError, match=r"chassis-sdk.toml: no \[robot\] port, and no port"):
        open_robot()
    assert open_robot(port="/dev/ttyUSB9").port == "/dev/ttyUSB9"


@pytest.mark.integration
async def test_drive_takes_port_and_limits_from_the_profile(home: Path) -> None:
    async with ChassisSimulator() as sim:
        write(
            home / "chassis-sdk.toml",
            f"[robot]\nport = '{sim.port}'\n[limits]\nmax_linear = 0.25\n",
        )
        proc = await asyncio.create_subprocess_exec(
            sys.executable, "-m", "chassis_sdk.cli", "drive", "--linear", "0.4",
            "--duration", "0.3", stdout=asyncio.subprocess.PIPE,
            stderr=asyncio.subprocess.PIPE, env={**os.environ, "PYTHONPATH": str(ROOT)},
        )  # fmt: skip
        async with asyncio.timeout(30):
            out, err = await proc.communicate()
        assert proc.returncode == 0, err.decode()
        assert "clamped to 0.25 m/s" in out.decode()
        drives = [c for _, c in sim.firmware.received if isinstance(c, DriveVelocity)]
        assert max(d.linear_mm for d in drives) == 250
        assert drives[-1] == DriveVelocity(0, 0.0)


def test_the_docs_name_exactly_the_keys_each_command_table_takes() -> None:
    from chassis_sdk.cli.profile import TABLE_KEYS, table_options

    commands = subparsers(build_parser())
    rows = re.findall(r"^\| `\[([a-z0-9-]+)\]` \| [^|]+ \| ([^|]+) \|$", DOCS.read_text(), re.M)
    assert {name for name, _ in rows} == set(COMMAND_TABLES) == set(TABLE_KEYS)
    for name, keys in rows:
        device_keys = {"port", "baudrate", "device"}
        documented = set(re.findall(r"`([a-z_0-9]+)`", keys)) - device_keys
        assert documented == set(TABLE_KEYS[name]), name
        assert documented <= set(table_options(name, commands[name])), name


#: An action or a one-shot input, or a flag that loosens safety: refused in a table.
NOT_SETTINGS = [
    ("estop", "release = true"),
    ("calibrate", "measured = 2.0"),
    ("calibrate", "dry_run = true"),
    ("calibrate", "imu = false"),
    ("drive", "linear = 0.3"),
    ("drive", "duration = 60"),
    ("clear-faults", "front_bumper = true"),
    ("serve", "no_token = true"),
    ("serve", "token = 'abcdefghijklmnopqrstuvwxyz'"),
    ("bridge", "take_over = true"),
]


@pytest.mark.parametrize(("table", "line"), NOT_SETTINGS)
def test_a_table_refuses_actions_one_shot_inputs_and_loosening_flags(
    home: Path, table: str, line: str, capsys: pytest.CaptureFixture[str]
) -> None:
    key = line.split()[0]
    bad = write(home / "bad.toml", f"[{table}]\n{line}\n")
    assert main(["--config", str(bad), "config"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith(
        f"chassis-sdk: {bad}: [{table}] {key}: --{key.replace('_', '-')} is given"
    )
    assert len(err.splitlines()) == 1


@pytest.mark.integration
async def test_estop_with_a_release_in_the_file_is_refused_and_nothing_is_released(
    home: Path,
) -> None:
    async with ChassisSimulator() as sim:
        write(home / "chassis-sdk.toml", f"[robot]\nport = '{sim.port}'\n[estop]\nrelease = true\n")
        proc = await asyncio.create_subprocess_exec(
            sys.executable, "-m", "chassis_sdk.cli", "estop", stdout=asyncio.subprocess.PIPE,
            stderr=asyncio.subprocess.PIPE, env={**os.environ, "PYTHONPATH": str(ROOT)},
        )  # fmt: skip
        async with asyncio.timeout(30):
            _, err = await proc.communicate()
        assert proc.returncode == 2, err.decode()
        assert sim.firmware.received == type(sim.firmware.received)()


def test_the_environment_beats_a_command_table_too(
    home: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    write(
        home / "chassis-sdk.toml",
        "[monitor]\nport = '/dev/from-file'\n[bridge]\nbroker = 'mqtt://127.0.0.1:1883'\n",
    )
    monkeypatch.setenv("CHASSIS_SDK_PORT", "/dev/from-env")
    monkeypatch.setenv("CHASSIS_SDK_BROKER", "mqtt://fleet.example:1883")
    assert parse(build_parser(), ["monitor"]).port == "/dev/from-env"
    assert (
        parse(build_parser(), ["bridge", "--robot-id", "r1"]).broker == "mqtt://fleet.example:1883"
    )
    assert main(["config", "monitor", "--json"]) == 0
    shown = json.loads(capsys.readouterr().out)
    assert shown["command"]["settings"]["port"] == {
        "value": "/dev/from-env",
        "source": "$CHASSIS_SDK_PORT",
    }


def test_an_abbreviated_config_is_not_taken_for_config(home: Path) -> None:
    slow = write(home / "slow.toml", "[limits]\nmax_linear = 0.1\n")
    for argv in (["--conf", str(slow), "drive", "/dev/x", "--linear", "0.3"],
                 ["drive", "/dev/x", "--linear", "0.3", "--conf", str(slow)]):  # fmt: skip
        with pytest.raises(SystemExit) as refused:
            parse(build_parser(), argv)
        assert refused.value.code == 2
    args = parse(build_parser(), ["drive", "/dev/x", "--linear", "0.3", "--config", str(slow)])
    assert args.max_linear == 0.1


def test_from_config_builds_one_class_and_refuses_a_profile_of_another_device(home: Path) -> None:
    from chassis_sdk import Board, Chassis

    write(home / "chassis-sdk.toml", "[robot]\ndevice = 'board'\nport = '/dev/b'\n")
    board = Board.from_config()
    assert (type(board), board.port) == (Board, "/dev/b")
    assert Board.from_config(port="/dev/c").port == "/dev/c"
    with pytest.raises(ProfileError, match=r"\[robot\] device is 'board', not 'chassis'"):
        Chassis.from_config()


@pytest.mark.integration
def test_the_blocking_api_builds_from_the_profile_too(home: Path) -> None:
    from chassis_sdk import sync

    with sync.Simulator("chassis") as sim:
        write(
            home / "chassis-sdk.toml",
            f"[robot]\nport = '{sim.port}'\n[limits]\nmax_linear = 0.2\n",
        )
        with sync.Chassis.from_config() as robot:
            assert robot.limits == MotionLimits(max_linear=0.2)
            robot.set_velocity(0.5, 0.0)
        firmware: Any = sim.server.firmware

        def drives() -> list[DriveVelocity]:
            return [c for _, c in list(firmware.received) if isinstance(c, DriveVelocity)]

        # The simulator reads in its own thread: wait for the zero that close() wrote
        # after the command (CI once looked before the simulator had read either).
        wait_until(lambda: any(d.linear_mm == 0 for d in drives()[1:]))
        assert max(d.linear_mm for d in drives()) == 200
    other = write(home / "b.toml", "[robot]\ndevice = 'chassis'\nport = 'p'\n")
    with pytest.raises(ProfileError, match=r"\[robot\] device is 'chassis', not 'board'"):
        sync.Board.from_config(other)


# --- one meaning per name, defaults in effect, a charge that reads true (issue 44, item 10)


def test_a_key_names_one_thing_in_every_table() -> None:
    """``port``, ``baudrate`` and ``device`` are the device's in ``[robot]`` and in every
    command's table: no command's option of that name means something else (``[web]
    port`` was the page's TCP port, and a sed that set both ports broke the file)."""
    from chassis_sdk.cli.profile import options_of

    for name, parser in subparsers(build_parser()).items():
        for key, action in options_of(parser).items():
            if key in {"port", "baudrate", "device"}:
                assert action.dest == key, f"[{name}] {key} is --{action.dest}, not the device's"


def test_the_old_name_of_a_renamed_option_is_refused_naming_the_new(
    home: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    with pytest.raises(SystemExit) as exited:
        main(["web", "/dev/null", "--port", "9000"])
    assert exited.value.code == 2
    assert "--port: renamed: use --http-port" in capsys.readouterr().err
    write(home / "chassis-sdk.toml", "[web]\nport = 9000\n")
    assert main(["web", "/dev/null"]) == 2
    err = capsys.readouterr().err
    assert "[web] port = 9000: renamed http_port" in err, err
    # A device path is the serial port, as in [robot] port.
    write(home / "chassis-sdk.toml", "[web]\nport = '/dev/ttyUSB7'\nhttp_port = 9000\n")
    args = parse(build_parser(), ["web"])
    assert (args.port, args.http_port) == ("/dev/ttyUSB7", 9000)


def test_config_does_not_list_battery_defaults_that_are_not_in_effect(
    home: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["config", "--json"]) == 0
    battery = json.loads(capsys.readouterr().out)["tables"]["battery"]
    assert battery["low"]["value"] is None
    assert all(row["source"].startswith("unused: no [battery] table") for row in battery.values())
    assert main(["config"]) == 0
    text = capsys.readouterr().out
    assert "[battery]\n  not in effect (no [battery] table: no percentage is computed)" in text
    assert main(["--config", str(EXAMPLE), "config", "--json"]) == 0
    battery = json.loads(capsys.readouterr().out)["tables"]["battery"]
    assert battery["low"] == {"value": 20, "source": "file"}
    assert battery["hysteresis"] == {"value": 5.0, "source": "default"}


def test_the_example_profile_reads_the_fresh_simulator_as_charged() -> None:
    from chassis_sdk.devices.chassis.firmware import ChassisFirmware

    model = load_profile(EXAMPLE).battery()
    assert model is not None
    voltage = ChassisFirmware().battery_voltage  # idle, as the simulator starts
    percentage = None
    for i in range(100):
        percentage = model.update(voltage, 1.2, now=i * 0.1)
    assert percentage is not None
    assert percentage >= 90, f"a fresh simulator reads {percentage:.0f} % (low is {model.low})"


@pytest.mark.integration
async def test_info_says_the_charge_is_not_yet_known_or_why_there_is_none(home: Path) -> None:
    from .support.cli import cli

    profile = write(home / "battery.toml", "[battery]\nchemistry = 'lifepo4'\ncells = 8\n")
    async with ChassisSimulator() as sim:
        code, out, err = await cli("--config", str(profile), "info", sim.port, cwd=home)
        assert code == 0, err
        assert re.search(r"^battery      27\.\d V, state of charge not yet known", out, re.M), out
        code, out, err = await cli("info", sim.port, cwd=home)
        assert code == 0, err
        assert "state of charge unknown (no [battery] in the profile)" in out, out


def test_open_robot_of_a_named_device_refuses_a_profile_of_another(home: Path) -> None:
    from chassis_sdk import Board, Chassis

    write(home / "chassis-sdk.toml", "[robot]\ndevice = 'chassis'\nport = '/dev/ttyUSB3'\n")
    assert type(open_robot(device="chassis")) is Chassis
    with pytest.raises(ProfileError, match=r"\[robot\] device is 'chassis', not 'board'"):
        open_robot(device="board")
    write(home / "chassis-sdk.toml", "[robot]\nport = '/dev/ttyUSB3'\n")  # no device named
    assert type(open_robot(device="board")) is Board
