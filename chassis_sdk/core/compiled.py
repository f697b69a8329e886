"""Which decoding path runs: the optional compiled fast path, or the pure Python code.

A protocol may ship a compiled twin of its hot path (the high-rate frames and the
framing loop), built from Cython at install time when a C compiler is there. The pure
Python code is the reference and the fallback: the compiled one returns the same
messages, keeps the same statistics, buffer and sequence state, and raises the same
errors, and the whole codec suite runs on both. The pure path runs when:

* ``CHASSIS_SDK_PURE=1`` is set (read once, when a protocol module is imported);
* the extension was not built (no compiler at install), or does not load;
* the decoder is a subclass: its overrides are honoured by the pure loop only.

`status` says which path is active (``chassis-sdk --version`` and ``info`` print it).
"""

from __future__ import annotations

import importlib
import os
from types import ModuleType

__all__ = ["ENV", "forced_pure", "load", "status"]

#: The environment variable that forces the pure Python path.
ENV = "CHASSIS_SDK_PURE"

# What each protocol module reported when it asked for its compiled twin:
# module name -> "compiled", or why not.
_loaded: dict[str, str] = {}


def forced_pure() -> bool:
    """Whether ``CHASSIS_SDK_PURE`` asks for the pure path (any value but empty or 0)."""
    return os.environ.get(ENV, "") not in ("", "0")


def load(name: str) -> ModuleType | None:
    """The compiled module ``name``, or ``None`` if the pure path is to run (forced, or
    the module is missing or does not load); the outcome is recorded for `status`."""
    if forced_pure():
        _loaded[name] = f"pure ({ENV}=1)"
        return None
    try:
        module = importlib.import_module(name)
    except ImportError:
        _loaded[name] = "pure (not built)"
        return None
    _loaded[name] = "compiled"
    return module


def status() -> str:
    """One line: ``"compiled"``, ``"pure (CHASSIS_SDK_PURE=1)"``, ``"pure (not built)"``,
    or, if the protocols differ, each protocol's path (``"chassis: compiled, board:
    pure (not built)"``), for the protocol modules imported so far."""
    paths = set(_loaded.values())
    if not paths:
        return "no protocol imported"
    if len(paths) == 1:
        return paths.pop()
    return ", ".join(f"{n.split('.')[-2]}: {p}" for n, p in sorted(_loaded.items()))
