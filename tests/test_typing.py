"""What a user's type checker sees (issue 44, item 11): code written as the docs show
passes ``mypy --strict``, and a call the device does not have is caught.

mypy runs in this process (no subprocess) on a small snippet, against this tree's
package and the project's mypy settings.
"""

from __future__ import annotations

from pathlib import Path

import pytest

mypy_api = pytest.importorskip("mypy.api", reason="mypy comes with the lint group")

ROOT = Path(__file__).resolve().parent.parent

SNIPPET = """\
from chassis_sdk import Board, Chassis, ChassisInfo, open_robot


async def main() -> None:
    async with open_robot(device="chassis") as robot:
        info: ChassisInfo = await robot.get_chassis_info()
        print(info.track_width)
    async with open_robot("robot.toml", device="board", port="/dev/ttyUSB0") as board:
        on: bool = await board.get_led()
        print(on)
    async with Chassis.from_config() as same:
        await same.get_chassis_info()
    async with open_robot() as either:  # the profile's device: the base class
        await either.stop()
    assert isinstance(either, (Chassis, Board))
    async with open_robot(device="board") as wrong:
        await wrong.get_chassis_info()  # WRONG
"""


def test_open_robot_is_typed_by_the_device_it_names(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    snippet = tmp_path / "snippet.py"
    snippet.write_text(SNIPPET, encoding="utf-8")
    monkeypatch.setenv("MYPYPATH", str(ROOT))  # this tree's package, editable or not
    report, errors, _status = mypy_api.run(
        [
            "--strict",
            "--config-file",
            str(ROOT / "pyproject.toml"),
            "--cache-dir",
            str(tmp_path / "cache"),
            "--no-error-summary",
            str(snippet),
        ]
    )
    wrong = SNIPPET.splitlines().index("        await wrong.get_chassis_info()  # WRONG") + 1
    found = [line for line in report.splitlines() if ": error: " in line]
    assert found == [
        f'{snippet}:{wrong}: error: "Board" has no attribute "get_chassis_info"  [attr-defined]'
    ], report + errors
