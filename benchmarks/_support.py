"""The tests' shared helpers (``tests/support``) of this checkout, for the benchmarks
that drive the same stand-ins, scenarios and broker, whatever ``PYTHONPATH`` says: an
older checkout there has its own ``tests``. They load as the package ``_tests``, so
that their relative imports work."""

from __future__ import annotations

import importlib
import importlib.util
import sys
from pathlib import Path
from types import ModuleType

SUPPORT = Path(__file__).resolve().parent.parent / "tests" / "support"


def support(name: str) -> ModuleType:
    """``tests/support/NAME.py`` of this checkout, as ``_tests.NAME``."""
    if "_tests" not in sys.modules:
        spec = importlib.util.spec_from_file_location(
            "_tests", SUPPORT / "__init__.py", submodule_search_locations=[str(SUPPORT)]
        )
        assert spec is not None
        assert spec.loader is not None
        package = importlib.util.module_from_spec(spec)
        sys.modules["_tests"] = package
        spec.loader.exec_module(package)
    return importlib.import_module(f"_tests.{name}")
