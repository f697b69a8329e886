"""The README's claims point at tests; every test it names must exist."""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def test_every_test_named_in_the_readme_exists() -> None:
    readme = (ROOT / "README.md").read_text()
    named = set(re.findall(r"`?(test_\w+\.py)?::?(test_\w+)", readme))
    assert named, "the README names no tests"
    sources = {p.name: p.read_text() for p in (ROOT / "tests").glob("test_*.py")}
    everything = "\n".join(sources.values())
    missing = []
    for module, name in named:
        haystack = sources.get(module, "") if module else everything
        if not re.search(rf"def {name}\b", haystack):
            missing.append(f"{module}::{name}" if module else name)
    assert not missing, f"README names tests that do not exist: {missing}"
