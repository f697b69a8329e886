"""The README's and the docs' claims point at tests; every test they name must exist."""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def test_every_test_named_in_the_readme_and_docs_exists() -> None:
    pages = [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md"))]
    readme = "\n".join(page.read_text() for page in pages)
    named = set(re.findall(r"`?(test_\w+\.py)?::?(test_\w+)", readme))
    assert len(named) > 20, "the docs name (almost) no tests"
    sources = {p.name: p.read_text() for p in (ROOT / "tests").glob("test_*.py")}
    everything = "\n".join(sources.values())
    missing = []
    for module, name in named:
        haystack = sources.get(module, "") if module else everything
        if not re.search(rf"def {name}\b", haystack):
            missing.append(f"{module}::{name}" if module else name)
    assert not missing, f"README names tests that do not exist: {missing}"
