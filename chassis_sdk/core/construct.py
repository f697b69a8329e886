"""Cheap construction and printing of decoded messages, for the frames that arrive at
50-100 Hz.

Profiling showed that decoding a frame's bytes is the small part of its cost and
building the Python objects the large one (a frozen dataclass's ``__init__`` calls
``object.__setattr__`` per field; ``IntFlag(value)`` goes through ``EnumType.__call__``;
a dataclass ``repr`` passes a recursion guard): the figures are in docs/figures.md.

So: `frozen_builder` makes a constructor that fills a frozen, slotted dataclass
through its slot descriptors (the same result as ``__init__``, with the same
immutability afterwards, in half the time), `MemberCache` maps wire integers to
enum members with one dict lookup, and `fast_repr` gives a message class a
``repr`` that prints exactly the same text with one f-string (messages are immutable,
so they cannot contain themselves and need no guard). All plain Python.
"""

from __future__ import annotations

import dataclasses
import enum
from collections.abc import Callable
from typing import Any, Generic, TypeVar

__all__ = ["MemberCache", "fast_repr", "frozen_builder"]

E = TypeVar("E", bound=enum.Enum)
T = TypeVar("T")


def frozen_builder(cls: type[T]) -> Callable[..., T]:
    """Return ``build(*field_values)`` equivalent to ``cls(*field_values)`` for a frozen,
    slotted dataclass, with every field given positionally.

    The function is generated once per class (as ``dataclasses`` generates ``__init__``)
    so that each field costs one descriptor call and no loop.
    """
    if not dataclasses.is_dataclass(cls) or "__slots__" not in cls.__dict__:
        raise TypeError(f"{cls.__name__} is not a slotted dataclass")
    names = [f.name for f in dataclasses.fields(cls)]
    namespace: dict[str, Any] = {"_new": object.__new__, "_cls": cls}
    lines = [f"def build({', '.join(names)}):", "    self = _new(_cls)"]
    for i, name in enumerate(names):
        namespace[f"_set{i}"] = cls.__dict__[name].__set__
        lines.append(f"    _set{i}(self, {name})")
    lines.append("    return self")
    exec("\n".join(lines), namespace)  # the source is built from field names only
    build: Callable[..., T] = namespace["build"]
    build.__qualname__ = f"frozen_builder({cls.__name__})"
    return build


def fast_repr(cls: type[T]) -> type[T]:
    """Class decorator: give a dataclass or ``NamedTuple`` a generated ``__repr__`` that
    returns exactly what its default one does, faster.

    The text is the default's: ``Name(field=repr(value), ...)``, the class's
    ``__qualname__`` for a dataclass (its fields declared ``repr=False`` left out) and
    ``__name__`` for a ``NamedTuple``, read from the instance's class as the defaults
    do. It has no recursion guard: use it only on classes whose instances cannot
    contain themselves (frozen messages of numbers, strings, enums and such messages).
    """
    if dataclasses.is_dataclass(cls):
        names = [f.name for f in dataclasses.fields(cls) if f.repr]
        values = [f"{name}={{self.{name}!r}}" for name in names]
        title = "type(self).__qualname__"
    elif issubclass(cls, tuple) and hasattr(cls, "_fields"):
        named: Any = cls  # a NamedTuple class: its field names are in _fields
        fields: tuple[str, ...] = named._fields
        values = [f"{name}={{self[{i}]!r}}" for i, name in enumerate(fields)]
        title = "type(self).__name__"
    else:
        raise TypeError(f"{cls.__name__} is neither a dataclass nor a NamedTuple")
    source = f'def __repr__(self):\n    return f"{{{title}}}({", ".join(values)})"'
    namespace: dict[str, Any] = {}
    exec(source, namespace)  # the source is built from field names only
    method = namespace["__repr__"]
    method.__qualname__ = f"{cls.__qualname__}.__repr__"
    cls.__repr__ = method  # type: ignore[method-assign]
    return cls


class MemberCache(dict[int, E], Generic[E]):
    """``cache[value]`` is ``enum_cls(value)``, computed once per distinct value.

    Holds at most ``limit`` values (a noisy line cannot grow it without bound: beyond
    the limit, members are built but not kept).
    """

    def __init__(self, enum_cls: type[E], limit: int = 1024) -> None:
        super().__init__()
        self._enum = enum_cls
        self._limit = limit

    def __missing__(self, value: int) -> E:
        member = self._enum(value)
        if len(self) < self._limit:
            self[value] = member
        return member
