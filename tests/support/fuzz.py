"""The fuzz harness (``fuzz/harness.py``, which is not a package) loaded for the tests,
and the seeded mutation they feed its checks in place of atheris's coverage-guided
one."""

from __future__ import annotations

import importlib.util
import random
import sys
from pathlib import Path
from types import ModuleType

__all__ = ["HARNESS", "harness", "mutate"]

HARNESS = Path(__file__).resolve().parents[2] / "fuzz" / "harness.py"


def _load() -> ModuleType:
    spec = importlib.util.spec_from_file_location("fuzz_harness", HARNESS)
    assert spec is not None
    assert spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return module


#: ``fuzz/harness.py``: ``targets()``, ``seeds(target)`` and ``check(target, data)``.
harness = _load()


def mutate(rng: random.Random, data: bytes) -> bytes:
    """``data`` with one to six random edits: a bit flipped, a byte deleted or inserted,
    a rotation, random bytes appended."""
    buf = bytearray(data)
    for _ in range(rng.randint(1, 6)):
        op = rng.random()
        if op < 0.3 and buf:
            buf[rng.randrange(len(buf))] ^= 1 << rng.randrange(8)
        elif op < 0.5 and buf:
            del buf[rng.randrange(len(buf))]
        elif op < 0.7:
            buf.insert(rng.randrange(len(buf) + 1), rng.randrange(256))
        elif op < 0.85 and len(buf) > 2:
            cut = rng.randrange(1, len(buf))
            buf = buf[cut:] + buf[:cut]
        else:
            buf += rng.randbytes(rng.randint(1, 20))
    return bytes(buf)
