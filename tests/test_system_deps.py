"""README's test command starts with ``sh tools/system-deps.sh``: it must work as root
on a machine without sudo (issue 28 row 10: ``sudo: command not found``, exit 127), use
sudo as a user, and say what to run, in one line, as a user without sudo.

The script runs for real against stand-ins for ``id``, ``dpkg-query``, ``apt-get`` and
``sudo`` on a PATH that holds nothing else but the few tools it needs, so nothing is
installed and the machine's own sudo (or its absence) does not matter.
"""

from __future__ import annotations

import os
import shutil
import subprocess
from pathlib import Path

import pytest

pytestmark = pytest.mark.integration

SCRIPT = Path(__file__).resolve().parents[1] / "tools" / "system-deps.sh"
TOOLS = (
    "sh", "grep", "env", "cat", "sed", "head", "mkdir", "rm", "mv", "touch", "date", "du",
    "cut", "dirname", "tail", "mktemp",
)  # fmt: skip


def stand_in(bin_dir: Path, name: str, body: str) -> None:
    path = bin_dir / name
    path.write_text(f"#!/bin/sh\n{body}\n")
    path.chmod(0o755)


def bare_path(tmp_path: Path) -> Path:
    """A directory holding only the tools the script needs, to be the whole PATH."""
    bin_dir = tmp_path / "bin"
    bin_dir.mkdir()
    for tool in TOOLS:
        found = shutil.which(tool)
        if found is None:
            pytest.skip(f"{tool} is not on PATH")
        (bin_dir / tool).symlink_to(found)
    return bin_dir


def debian13(tmp_path: Path, *, made: bool) -> Path:
    """A stand-in for the Debian 13 root: complete (its mark written) or not there."""
    root = tmp_path / "debian13"
    if made:
        root.mkdir()
        (root / ".chassis-sdk-complete").touch()
    return root


def run(
    tmp_path: Path, *, uid: int, sudo: bool, root_made: bool = True
) -> tuple[subprocess.CompletedProcess[str], str]:
    bin_dir = bare_path(tmp_path)
    calls = tmp_path / "calls"
    stand_in(bin_dir, "id", f"echo {uid}")
    stand_in(bin_dir, "dpkg-query", "exit 1")  # nothing installed
    stand_in(bin_dir, "apt-get", f'echo "apt-get $*" >> {calls}')
    # debootstrap makes the root's directory, as the real one does.
    stand_in(bin_dir, "debootstrap", f'echo "debootstrap $*" >> {calls}; mkdir -p "$4"')
    if sudo:
        stand_in(bin_dir, "sudo", f'echo "sudo $1" >> {calls}; exec "$@"')
    root = debian13(tmp_path, made=root_made)
    done = subprocess.run(
        [str(bin_dir / "sh"), str(SCRIPT)],
        capture_output=True,
        text=True,
        env={
            "PATH": str(bin_dir),
            "HOME": str(tmp_path),
            "TMPDIR": str(tmp_path),  # the debootstrap log: never a file another user owns
            "CHASSIS_SDK_DEBIAN13": str(root),
        },
        timeout=30,
        check=False,
    )
    return done, calls.read_text() if calls.exists() else ""


def test_as_root_without_sudo_it_installs_with_apt_get(tmp_path: Path) -> None:
    done, calls = run(tmp_path, uid=0, sudo=False)
    assert done.returncode == 0, done.stderr
    assert "sudo" not in calls
    lines = calls.splitlines()
    assert lines[0] == "apt-get update -qq"
    assert lines[1].startswith("apt-get install -y -qq --no-install-recommends")
    assert "mosquitto" in lines[1]
    assert "chromium" in lines[1]
    assert "system-deps: installed" in done.stdout


def test_as_a_user_it_uses_sudo(tmp_path: Path) -> None:
    done, calls = run(tmp_path, uid=1000, sudo=True)
    assert done.returncode == 0, done.stderr
    assert calls.splitlines()[:2] == ["sudo env", "apt-get update -qq"]


def test_as_a_user_without_sudo_it_says_what_to_run(tmp_path: Path) -> None:
    done, calls = run(tmp_path, uid=1000, sudo=False)
    assert done.returncode == 1
    assert calls == ""
    assert len(done.stderr.splitlines()) == 1
    assert done.stderr.startswith(
        "system-deps: not root and no sudo: as root, run: sh tools/system-deps.sh (it installs: "
    )
    assert "mosquitto" in done.stderr


@pytest.mark.skipif(
    not list(Path("/etc/apt").glob("sources.list*")), reason="no apt sources to take a mirror from"
)
def test_a_missing_debian13_root_is_made_with_debootstrap_from_apts_mirror(tmp_path: Path) -> None:
    done, calls = run(tmp_path, uid=0, sudo=False, root_made=False)
    assert done.returncode == 0, done.stderr
    (debootstrap,) = [line for line in calls.splitlines() if line.startswith("debootstrap")]
    words = debootstrap.split()
    assert words[1:3] == ["--variant=minbase", "--include=g++,libfastdds-dev,fastddsgen"]
    assert words[3:5] == ["trixie", f"{tmp_path / 'debian13'}.partial"]
    assert words[5].startswith(("http://", "https://", "file:/")), words[5]
    root = tmp_path / "debian13"
    assert (root / ".chassis-sdk-complete").exists()  # written last, after the move
    assert (root / "build").is_dir()  # the peer's build binds onto it
    assert not (tmp_path / "debian13.partial").exists()
    assert "Debian 13 root made in" in done.stdout


@pytest.mark.skipif(os.name != "posix", reason="a POSIX shell script")
def test_nothing_missing_touches_nothing(tmp_path: Path) -> None:
    bin_dir = bare_path(tmp_path)
    # Every package reported installed and every command present: no apt-get at all.
    stand_in(bin_dir, "id", "echo 1000")
    stand_in(bin_dir, "dpkg-query", "echo 'install ok installed'")
    stand_in(bin_dir, "apt-get", "echo apt-get >&2; exit 99")
    for command in (
        "fastddsgen",
        "g++",
        "ip",
        "unshare",
        "mosquitto",
        "chromium",
        "tmux",
        "check_urdf",
    ):
        stand_in(bin_dir, command, "exit 0")
    include = Path("/usr/include/fastdds/dds/domain/DomainParticipantFactory.hpp")
    if not include.exists():
        pytest.skip("Fast DDS's headers are not installed here")
    root = debian13(tmp_path, made=True)
    done = subprocess.run(
        [str(bin_dir / "sh"), str(SCRIPT)],
        capture_output=True,
        text=True,
        env={"PATH": str(bin_dir), "CHASSIS_SDK_DEBIAN13": str(root)},
        timeout=30,
        check=False,
    )
    assert done.returncode == 0, done.stderr
    assert done.stdout.startswith("system-deps: all present")
