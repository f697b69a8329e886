"""Names a package's façade imports on first use (PEP 562): one implementation for the
top-level façade, ``chassis_sdk.core`` and the device packages, so importing any of them
loads nothing it does not need."""

from __future__ import annotations

from collections.abc import Callable, Mapping
from importlib import import_module
from typing import Any

__all__ = ["lazy"]


def lazy(
    package: str, table: Mapping[str, str], namespace: dict[str, Any]
) -> tuple[Callable[[str], Any], Callable[[], list[str]]]:
    """The ``__getattr__`` and ``__dir__`` of ``package``, whose lazily imported names
    are ``table`` (name -> the module, relative to ``package``, that defines it);
    ``namespace`` is the package's ``globals()``, where each name is kept once imported.

    Example:
        ```python
        __getattr__, __dir__ = lazy(__name__, {"Chassis": ".device"}, globals())
        ```
    """

    def __getattr__(name: str) -> Any:
        module = table.get(name)
        if module is None:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        value = getattr(import_module(module, package), name)
        namespace[name] = value  # the next lookup is a plain attribute
        return value

    def __dir__() -> list[str]:
        return sorted({*namespace, *namespace.get("__all__", ())})

    return __getattr__, __dir__
