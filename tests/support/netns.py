"""The ``netns`` marker: a test that runs in its own network namespace, whose only
interface is loopback (with multicast on, and a route for 224.0.0.0/4), so that DDS
discovery traffic (multicast included) never leaves this test and never meets another's.

A pytest plugin (``tests/conftest.py`` loads it). For an item marked ``netns`` the outer
pytest does not call the test function: it runs that one test again in a child pytest
under ``unshare --net --mount`` (``--map-root-user`` too when not root), with
``CHASSIS_SDK_IN_NETNS=1``, and the outer test passes only if the child passed that
exactly one test (a child that failed, skipped, or ran nothing fails it, with the
child's output). If the namespace cannot be made the test fails, and says why: it
never runs on the host's network instead.

In the child, a session-scoped autouse fixture sets the namespace up (``lo`` up, with
multicast, and the multicast route), mounts a fresh sysfs (in the child's own mount
namespace) so that ``/sys/class/net`` shows this namespace, and checks that ``lo`` is
the only interface.

The outer process still sets up the item's fixtures (function-scoped ones included)
before it starts the child: keep a netns test's fixtures light (building the DDS peer
there is fine: the child then finds it cached).
"""

from __future__ import annotations

import contextlib
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import xml.etree.ElementTree as ET
from collections.abc import Iterator
from pathlib import Path

import pytest

from .markers import exempt

__all__ = ["IN_NETNS", "interfaces", "netns_setup"]

IN_NETNS = "CHASSIS_SDK_IN_NETNS"
# The namespaces' inodes of the outer pytest, so that the child can tell it is elsewhere.
PARENT_NET = "CHASSIS_SDK_NETNS_PARENT_NET"
PARENT_MNT = "CHASSIS_SDK_NETNS_PARENT_MNT"
CHILD_TIMEOUT = "CHASSIS_SDK_NETNS_TIMEOUT"
MARKER = "netns: runs inside its own network namespace whose only interface is loopback"
SBIN_PATH = os.pathsep.join(["/usr/sbin", "/sbin", "/usr/bin", "/bin"])


def _ns_inode(kind: str) -> int:
    return os.stat(f"/proc/self/ns/{kind}").st_ino


def _tool(name: str) -> str:
    """A system tool's path (``ip`` is in /usr/sbin, often not on a user's PATH)."""
    found = shutil.which(name) or shutil.which(name, path=SBIN_PATH)
    if found is None:
        raise RuntimeError(f"{name} is not installed; install it with: sh tools/system-deps.sh")
    return found


def pytest_configure(config: pytest.Config) -> None:
    config.addinivalue_line("markers", MARKER)


def _budget(item: pytest.Item) -> float:
    """The test's pytest-timeout (its marker, else --timeout, else the ini), or 0."""
    marker = item.get_closest_marker("timeout")
    value: object = None
    if marker is not None:
        value = marker.args[0] if marker.args else marker.kwargs.get("timeout")
    if value is None:
        value = item.config.getoption("timeout", None)
    if value is None:
        try:
            value = item.config.getini("timeout")
        except ValueError:  # pytest-timeout is not installed
            value = None
    try:
        return max(float(str(value)), 0.0)
    except ValueError:
        return 0.0


def _timeouts(item: pytest.Item) -> tuple[float, float]:
    """The outer's wait for the child, and the child test's own pytest-timeout: shorter
    each, so that the child's pytest-timeout reports (with the stacks) before the outer
    kills the child, and the outer reports before its own pytest-timeout fires."""
    budget = _budget(item)
    outer = max(budget - 3.0, 10.0) if budget > 0 else 600.0
    return outer, max(outer - 5.0, 5.0)


@pytest.hookimpl(trylast=True)
def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    # In the child: the netns test's timeout is the one the outer gave it.
    child = os.environ.get(CHILD_TIMEOUT)
    if os.environ.get(IN_NETNS) != "1" or child is None:
        return
    for item in items:
        if item.get_closest_marker("netns") is not None:
            item.add_marker(pytest.mark.timeout(float(child)), append=False)


def _verdict(report: Path) -> str | None:
    """Why the child's run is not exactly one passed test, or ``None``."""
    try:
        root = ET.parse(report).getroot()
    except (OSError, ET.ParseError) as e:
        return f"no readable report ({e})"
    suite = root if root.tag == "testsuite" else root.find("testsuite")
    if suite is None:
        return "no testsuite in the report"
    counts = {k: int(suite.get(k, "0")) for k in ("tests", "failures", "errors", "skipped")}
    if counts["tests"] != 1:
        return f"the child ran {counts['tests']} tests, not 1"
    bad = [f"{v} {k}" for k, v in counts.items() if k != "tests" and v]
    return ", ".join(bad) if bad else None


def _last_line(text: str) -> str:
    lines = [line for line in text.strip().splitlines() if line.strip()]
    return lines[-1] if lines else "(no output)"


@pytest.hookimpl(tryfirst=True)
def pytest_pyfunc_call(pyfuncitem: pytest.Function) -> bool | None:
    if pyfuncitem.get_closest_marker("netns") is None or os.environ.get(IN_NETNS) == "1":
        return None
    _run_in_namespace(pyfuncitem)
    return True


def _run_in_namespace(item: pytest.Function) -> None:
    try:
        unshare = _tool("unshare")
    except RuntimeError as e:
        pytest.fail(f"netns: {e}", pytrace=False)
    flags = ["--net", "--mount"] + ([] if os.geteuid() == 0 else ["--map-root-user"])
    rootdir = Path(item.config.rootpath)
    with tempfile.TemporaryDirectory(prefix="netns-") as tmp:
        report = Path(tmp) / "report.xml"
        cmd = [
            unshare, *flags, "--", sys.executable, "-m", "pytest", item.nodeid,
            "-p", "no:cacheprovider", "-q", "-rs", f"--junitxml={report}",
        ]  # fmt: skip
        env = dict(os.environ)
        env[IN_NETNS] = "1"
        env[PARENT_NET] = str(_ns_inode("net"))
        env[PARENT_MNT] = str(_ns_inode("mnt"))
        timeout, child_timeout = _timeouts(item)
        env[CHILD_TIMEOUT] = str(child_timeout)
        # A session of its own, so that a timeout stops the child's own children too. The
        # child checks the test's markers itself.
        with exempt():
            proc = subprocess.Popen(
                cmd,
                cwd=rootdir,
                env=env,
                stdin=subprocess.DEVNULL,
                stdout=subprocess.PIPE,
                stderr=subprocess.STDOUT,
                text=True,
                start_new_session=True,
            )
        timed_out = False
        try:
            output, _ = proc.communicate(timeout=timeout)
        except subprocess.TimeoutExpired:
            timed_out = True
            _kill_group(proc)
            output, _ = proc.communicate()
        except BaseException:  # the outer's own timeout, Ctrl-C
            _kill_group(proc)
            proc.communicate()
            raise
        if timed_out:
            pytest.fail(
                f"netns: the child pytest ran over {timeout:.0f} s:\n{output}", pytrace=False
            )
        if not report.exists() and output.lstrip().startswith("unshare:"):
            pytest.fail(
                f"netns: could not make a network namespace ({_last_line(output)}); "
                "this test does not run on the host's network",
                pytrace=False,
            )
        why = _verdict(report)
        if proc.returncode != 0 or why is not None:
            pytest.fail(
                f"netns: the test in its namespace did not pass (exit {proc.returncode}"
                f"{'; ' + why if why else ''}):\n{output}",
                pytrace=False,
            )


def _kill_group(proc: subprocess.Popen[str]) -> None:
    with contextlib.suppress(ProcessLookupError):
        os.killpg(proc.pid, signal.SIGKILL)


def interfaces() -> set[str]:
    """The network interfaces this process sees (netlink, so this namespace's)."""
    with exempt():
        out = subprocess.run(
            [_tool("ip"), "-o", "link", "show"], capture_output=True, text=True, check=True
        ).stdout
    return {line.split(":")[1].strip().split("@")[0] for line in out.splitlines() if ":" in line}


def _sh(*cmd: str) -> None:
    with exempt():
        done = subprocess.run(cmd, capture_output=True, text=True, check=False)
    if done.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd)}: {(done.stderr or done.stdout).strip()}")


@pytest.fixture(scope="session", autouse=True)
def netns_setup() -> Iterator[None]:
    """In a netns child only: loopback up, with multicast, and nothing else."""
    if os.environ.get(IN_NETNS) != "1":
        yield
        return
    parent_net = os.environ.get(PARENT_NET)
    parent_mnt = os.environ.get(PARENT_MNT)
    if parent_net is None or parent_mnt is None:
        pytest.fail(f"netns: {IN_NETNS}=1 is for the netns plugin's child only", pytrace=False)
    # Never touch the host's network or mounts: check we are in namespaces of our own.
    if str(_ns_inode("net")) == parent_net or str(_ns_inode("mnt")) == parent_mnt:
        pytest.fail("netns: the child is not in a namespace of its own", pytrace=False)
    ip = _tool("ip")
    try:
        _sh(ip, "link", "set", "lo", "up")
        _sh(ip, "link", "set", "lo", "multicast", "on")
        _sh(ip, "route", "add", "224.0.0.0/4", "dev", "lo")
        # sysfs shows the network namespace of whoever mounted it: mount our own (in our
        # private mount namespace) so that /sys/class/net is this namespace's.
        _sh(_tool("mount"), "-t", "sysfs", "sysfs", "/sys")
    except RuntimeError as e:
        pytest.fail(f"netns: setting up the namespace failed: {e}", pytrace=False)
    seen = {"netlink": interfaces(), "/sys/class/net": set(os.listdir("/sys/class/net"))}
    for where, names in seen.items():
        if names != {"lo"}:
            pytest.fail(
                f"netns: interfaces other than lo ({where}): {sorted(names)}", pytrace=False
            )
    yield
