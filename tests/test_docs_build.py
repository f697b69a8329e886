"""The docs as a user reads them (issue 28 row 5): ``mkdocs build --strict`` from the
repository, and the API reference checked in the built HTML.

The class a user imports carries every public method on its own page (``Chassis``'s
``set_velocity``, ``stop``, ... live on its base classes), cross-references are links
(no Sphinx role printed literally: mkdocstrings does not read ``:meth:``), and the
examples are code blocks, not a flattened ``>>>`` paragraph.

Needs mkdocs-material and mkdocstrings, which the ``test`` group installs (through
``docs``; README's test command). This is CI's docs build: it is not built again. Without mkdocs the test fails and says so; it does not skip.
"""

from __future__ import annotations

import html
import importlib.util
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

from .support.watch import exempt

# One worker builds the site for every test here (--dist loadgroup), once; the build
# takes over 5 s.
pytestmark = [pytest.mark.xdist_group("docs"), pytest.mark.slow]

ROOT = Path(__file__).resolve().parent.parent

#: What the issue found missing on Chassis's entry, and a few more of each base.
CHASSIS_METHODS = (
    "set_velocity",
    "stop",
    "emergency_stop",
    "events",
    "odometry",
    "wait_for",
    "verify",
    "connect",
    "close",
    "connection_states",
    "telemetry",
    "clear_faults",
)
BOARD_METHODS = ("set_velocity", "stop", "events", "verify", "connect", "imu", "set_led")


@pytest.fixture(scope="module")
def site(tmp_path_factory: pytest.TempPathFactory) -> Path:
    assert importlib.util.find_spec("mkdocs") is not None, (
        "the docs build needs the docs group: pip install --group docs"
    )
    out = tmp_path_factory.mktemp("site")
    with exempt():  # a build, not a port: these tests are not `integration`
        built = subprocess.run(
            [sys.executable, "-m", "mkdocs", "build", "--strict", "--site-dir", str(out)],
            cwd=ROOT,
            capture_output=True,
            text=True,
            timeout=300,
            env={**os.environ, "NO_MKDOCS_2_WARNING": "1"},
        )
    assert built.returncode == 0, built.stderr[-4000:]
    return out


def section(page: str, anchor: str) -> str:
    """The HTML of the documented object whose heading has ``id=anchor``, up to the
    next object at the same level."""
    start = page.index(f'id="{anchor}"')
    level = page.rfind("<h", 0, start)
    tag = page[level : level + 3]  # <h2
    end = page.find(f"{tag} id=", start + 1)
    return page[start : end if end != -1 else len(page)]


def reference_pages(site: Path) -> dict[str, str]:
    return {
        str(path.relative_to(site)): path.read_text(encoding="utf-8")
        for path in sorted((site / "reference").rglob("*.html"))
    }


@pytest.mark.parametrize(
    ("name", "methods"), [("Chassis", CHASSIS_METHODS), ("Board", BOARD_METHODS)]
)
def test_the_class_a_user_imports_lists_every_public_method(
    site: Path, name: str, methods: tuple[str, ...]
) -> None:
    page = (site / "reference" / "api" / "index.html").read_text(encoding="utf-8")
    entry = section(page, f"chassis_sdk.{name}")
    documented = set(re.findall(rf'id="chassis_sdk\.{name}\.(\w+)"', entry))
    missing = [m for m in methods if m not in documented]
    assert not missing, f"{name}'s page has no entry for {missing}"
    assert not [m for m in documented if m.startswith("_")], documented  # public only


def test_no_sphinx_role_is_printed_literally(site: Path) -> None:
    for name, text in reference_pages(site).items():
        visible = html.unescape(re.sub(r"<[^>]+>", "", text))
        found = re.findall(r":(?:meth|class|func|attr|data|mod|exc|obj):", visible)
        assert not found, f"{name} prints {len(found)} Sphinx roles literally, e.g. {found[:3]}"


def test_cross_references_are_links(site: Path) -> None:
    page = (site / "reference" / "api" / "index.html").read_text(encoding="utf-8")
    entry = section(page, "chassis_sdk.Chassis")
    links = re.findall(r'<a class="autorefs autorefs-internal"[^>]*href="([^"]+)"', entry)
    assert len(links) >= 5, "Chassis's entry links to (almost) nothing"
    # The class's own docstring names connect(): a link to it.
    intro = entry[: entry.index('id="chassis_sdk.Chassis.')]
    assert re.search(r'href="[^"]*#chassis_sdk\.[\w.]*connect"', intro), intro[:3000]


def test_examples_are_code_blocks(site: Path) -> None:
    pages = reference_pages(site)
    everything = "\n".join(pages.values())
    # A ">>>" example read as Markdown is nested quotes around one flattened line.
    assert "<blockquote>\n<blockquote>" not in everything
    assert "doctest" not in everything
    page = pages[os.path.join("reference", "api", "index.html")]
    intro = section(page, "chassis_sdk.Chassis")
    intro = intro[: intro.index('id="chassis_sdk.Chassis.')]
    blocks = re.findall(r'<div class="[^"]*highlight"><pre>(.*?)</pre>', intro, re.S)
    code = [html.unescape(re.sub(r"<[^>]+>", "", block)) for block in blocks]
    assert any('async with Chassis("/dev/ttyUSB0") as robot:' in c for c in code), code
    # Lines kept as lines, indentation kept.
    example = next(c for c in code if "async with Chassis" in c)
    assert "\n        async for t in robot.telemetry():" in example, example
