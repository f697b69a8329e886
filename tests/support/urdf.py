"""ROS's own URDF parser (urdfdom's ``check_urdf``, Debian's liburdfdom-tools, installed
by ``tools/system-deps.sh``) on a description the SDK made: what robot_state_publisher
would read."""

from __future__ import annotations

import shutil
import subprocess
import tempfile
from pathlib import Path

__all__ = ["check_urdf"]


def check_urdf(text: str) -> str:
    """``check_urdf``'s report on ``text`` (the tree of links it parsed).

    Raises:
        RuntimeError: ``check_urdf`` is not installed.
        AssertionError: It refused the description (its output in the message).
    """
    tool = shutil.which("check_urdf")
    if tool is None:
        raise RuntimeError("check_urdf is not installed; install it with: sh tools/system-deps.sh")
    with tempfile.TemporaryDirectory() as work:
        path = Path(work, "robot.urdf")
        path.write_text(text)
        done = subprocess.run([tool, str(path)], capture_output=True, text=True, timeout=30)
    assert done.returncode == 0, f"check_urdf refused it:\n{done.stdout}{done.stderr}"
    return done.stdout
