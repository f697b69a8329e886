"""A command whose extra is missing says so in one line, naming the extra and the pip
command that installs it from the checkout, before any port opens (issue 44, item 5).

The real ``chassis-sdk`` runs with the extra's package made missing
(`tests.support.cli.cli`'s ``without``: its import fails as if it were not installed);
the port, ``/dev/ttyNOPE``, does not exist, so a command that opened it before the
check would say "could not open" instead.
"""

from __future__ import annotations

import tomllib
from pathlib import Path

import pytest

from chassis_sdk.cli import extras
from chassis_sdk.cli.extras import EXTRAS, install_hint, require
from chassis_sdk.errors import ChassisError
from chassis_sdk.recording.capture import MCAP_MAGIC

from .support.cli import ROOT, cli, one_line

NOPE = "/dev/ttyNOPE"

#: (the command, the package made missing, the command named in the line, the extra).
MISSING = [
    pytest.param(["web", NOPE], "aiohttp", "web", "web", id="web"),
    pytest.param(["serve", NOPE], "foxglove", "serve", "foxglove", id="serve"),
    pytest.param(["serve", NOPE], "websockets", "serve", "foxglove", id="serve-websockets"),
    pytest.param(["record", NOPE, "{tmp}/x.mcap"], "foxglove", "record", "foxglove", id="record-mcap"),
    pytest.param(
        ["record", NOPE, "{tmp}/x.mcap", "--ros2"], "cyclonedds", "record --ros2", "ros2",
        id="record-ros2",
    ),
    pytest.param(["replay", "{mcap}"], "mcap", "replay", "foxglove", id="replay-mcap"),
    pytest.param(
        ["replay", "{mcap}", "--as-device"], "mcap", "replay", "foxglove", id="replay-as-device",
    ),
    pytest.param(
        ["export", "{mcap}", "--csv", "{tmp}/csv"], "mcap", "export", "foxglove", id="export-mcap",
    ),
    pytest.param(["plot", "{mcap}"], "matplotlib", "plot", "plot", id="plot"),
    pytest.param(["plot", "{mcap}"], "numpy", "plot", "plot", id="plot-numpy"),
    pytest.param(["plot", "{mcap}"], "mcap", "plot", "foxglove", id="plot-mcap"),
    pytest.param(["bridge", NOPE, "--robot-id", "r1"], "aiomqtt", "bridge", "mqtt", id="bridge"),
    pytest.param(
        ["drive", NOPE, "--linear", "0.1", "--record", "{tmp}/x.mcap"], "foxglove",
        "drive --record", "foxglove", id="drive-record-mcap",
    ),
    pytest.param(
        ["teleop", NOPE, "--record", "{tmp}/x.mcap"], "foxglove", "teleop --record", "foxglove",
        id="teleop-record-mcap",
    ),
    pytest.param(["ros2", NOPE], "cyclonedds", "ros2", "ros2", id="ros2"),
    pytest.param(
        ["teleop", NOPE, "--joystick", "/dev/input/event0"], "evdev", "teleop --joystick",
        "joystick", id="teleop-joystick",
    ),
]  # fmt: skip


@pytest.mark.integration
@pytest.mark.parametrize(("argv", "module", "command", "extra"), MISSING)
async def test_a_missing_extra_is_one_line_naming_it_before_any_port_opens(
    argv: list[str], module: str, command: str, extra: str, tmp_path: Path
) -> None:
    mcap = tmp_path / "run.mcap"
    mcap.write_bytes(MCAP_MAGIC + b"\0" * 64)  # an MCAP file by its first bytes
    words = [w.format(tmp=tmp_path, mcap=mcap) for w in argv]
    code, out, err = await cli(*words, without=(module,))
    assert (code, out) == (1, ""), err
    assert one_line(err) == (
        f'chassis-sdk: {command} needs {module}, from the {extra} extra: pip install -e ".[{extra}]"'
    )
    assert not (tmp_path / "x.mcap").exists()


def test_an_extra_installed_but_broken_says_why(monkeypatch: pytest.MonkeyPatch) -> None:
    def broken(name: str) -> None:  # cyclonedds installed without its C library
        raise ImportError("libddsc.so.0: cannot open shared object file\nmore")

    monkeypatch.setattr(extras, "import_module", broken)
    with pytest.raises(ChassisError) as info:
        require("ros2", "ros2")
    assert str(info.value) == (
        "ros2 needs cyclonedds (installed, but: libddsc.so.0: cannot open shared object "
        'file), from the ros2 extra: pip install -e ".[ros2]"'
    )


def test_every_extra_checked_is_one_of_pyproject_and_holds_what_it_names() -> None:
    declared = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"][
        "optional-dependencies"
    ]
    for extra, modules in EXTRAS.items():
        assert extra in declared, f"{extra} is not an extra of pyproject.toml"
        require("test", extra)  # `.[all]` is installed here: each module imports
        assert modules
    assert install_hint("web") == 'pip install -e ".[web]"'
    readme = (ROOT / "README.md").read_text()
    assert 'pip install -e ".[all]"' in readme  # the form the hint follows
