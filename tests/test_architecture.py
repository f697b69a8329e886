"""The plan of the package, held: every import points down a layer, no import cycle,
and the sans-IO codecs load without the runtime.

The imports are read from the source (an AST walk over every module, imports inside
functions and ``importlib.import_module("...")`` with a literal name included), so a
lazy import cannot hide an upward one.
"""

from __future__ import annotations

import ast
import os
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest

import chassis_sdk

ROOT = Path(chassis_sdk.__file__).parent

#: The pure parts of the core: no asyncio, no clock of their own, no runtime.
PURE_CORE = {
    "chassis_sdk.core.backoff",
    "chassis_sdk.core.battery",
    "chassis_sdk.core.construct",
    "chassis_sdk.core.enums",
    "chassis_sdk.core.firmware",
    "chassis_sdk.core.framing",
    "chassis_sdk.core.motion.arbiter",
    "chassis_sdk.core.pack",
    "chassis_sdk.core.refusals",
    "chassis_sdk.core.calibration",
    "chassis_sdk.core.charge",
    "chassis_sdk.core.plain",
    "chassis_sdk.core.validation",
    "chassis_sdk.core.writequeue",
}
#: Layers, bottom up: a module may import its own layer and those below, never above.
LAYERS = [
    ("base", ("chassis_sdk.errors", "chassis_sdk._version", "chassis_sdk._lazy")),
    ("pure core", tuple(PURE_CORE)),
    ("core", ("chassis_sdk.core",)),
    ("devices", ("chassis_sdk.devices", "chassis_sdk.protocol")),
    ("sim", ("chassis_sdk.sim",)),
    ("recording", ("chassis_sdk.recording",)),
    ("integrations", ("chassis_sdk.integrations", "chassis_sdk.teleop")),
    ("cli", ("chassis_sdk.cli",)),
    ("facade", ("chassis_sdk",)),
]
#: Standard and third-party modules the pure parts and the codecs must never load.
RUNTIME = ("asyncio", "anyio", "serial", "serial_asyncio", "serial_asyncio_fast", "serialx")


def layer(module: str) -> int:
    """The index in LAYERS of ``module`` (the longest matching prefix wins)."""
    best, best_len = -1, -1
    for rank, (_, prefixes) in enumerate(LAYERS):
        for prefix in prefixes:
            if (module == prefix or module.startswith(prefix + ".")) and len(prefix) > best_len:
                best, best_len = rank, len(prefix)
    assert best >= 0, module
    return best


def modules() -> dict[str, Path]:
    found = {}
    for path in ROOT.rglob("*.py"):
        parts = list(path.relative_to(ROOT.parent).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts.pop()
        found[".".join(parts)] = path
    return found


MODULES = modules()


def _is_type_checking(node: ast.If) -> bool:
    test = node.test
    return (isinstance(test, ast.Name) and test.id == "TYPE_CHECKING") or (
        isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING"
    )


def _resolve(module: str, level: int, name: str | None, is_package: bool) -> str:
    if level == 0:
        return name or ""
    base = module.split(".")
    if not is_package:
        base = base[:-1]
    if level > 1:
        base = base[: len(base) - (level - 1)]
    return ".".join([*base, name] if name else base)


def imports(module: str) -> Iterator[tuple[str, int, bool]]:
    """``(imported module, line, only for type checking)`` of every import in
    ``module``; ``from X import name`` counts as importing ``X.name`` when that is a
    module."""
    path = MODULES[module]
    is_package = path.name == "__init__.py"
    tree = ast.parse(path.read_text(encoding="utf-8"))
    typing_only: set[int] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.If) and _is_type_checking(node):
            for inner in node.body:
                typing_only.update(id(n) for n in ast.walk(inner))
    for node in ast.walk(tree):
        only = id(node) in typing_only
        if isinstance(node, ast.Import):
            for alias in node.names:
                yield alias.name, node.lineno, only
        elif isinstance(node, ast.ImportFrom):
            target = _resolve(module, node.level, node.module, is_package)
            for alias in node.names:
                sub = f"{target}.{alias.name}"
                yield (sub if sub in MODULES else target), node.lineno, only
        elif (
            isinstance(node, ast.Call)
            and isinstance(node.func, ast.Attribute | ast.Name)
            and (node.func.attr if isinstance(node.func, ast.Attribute) else node.func.id)
            == "import_module"
            and node.args
            and isinstance(node.args[0], ast.Constant)
            and isinstance(node.args[0].value, str)
        ):
            name = node.args[0].value
            level = len(name) - len(name.lstrip("."))
            yield _resolve(module, level, name.lstrip(".") or None, is_package), node.lineno, only


def internal(target: str) -> str | None:
    """The package module ``target`` names (itself or the module it is in), if any."""
    while target and target not in MODULES:
        target = target.rpartition(".")[0]
    return target or None


def test_every_import_points_down_a_layer() -> None:
    upward = []
    for module in MODULES:
        for target, line, _ in imports(module):
            found = internal(target) if target.startswith("chassis_sdk") else None
            if found is None or found == module:
                continue
            # A package's own __init__ is imported by its modules implicitly: the
            # package façades (core, devices, the top) must therefore stay lazy.
            if layer(found) > layer(module):
                upward.append(
                    f"{module}:{line} imports {found} "
                    f"({LAYERS[layer(module)][0]} -> {LAYERS[layer(found)][0]})"
                )
    assert upward == [], "\n".join(upward)


def test_the_import_graph_has_no_cycle() -> None:
    graph: dict[str, set[str]] = {m: set() for m in MODULES}
    for module in MODULES:
        for target, _, only in imports(module):
            found = internal(target) if target.startswith("chassis_sdk") else None
            if found is None or found == module:
                continue
            # An import under TYPE_CHECKING counts: a module that needs another's type
            # while that one imports it is a friend reaching into its state. Only a
            # lazy package façade naming its own modules for type checkers is exempt.
            if only and MODULES[module].name == "__init__.py" and found.startswith(module + "."):
                continue
            graph[module].add(found)
        # Importing a module runs its package's __init__ first.
        parent = module.rpartition(".")[0]
        if parent in MODULES and parent != module:
            graph[module].add(parent)
    # Tarjan's strongly connected components.
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    cycles: list[list[str]] = []
    counter = [0]

    def visit(v: str) -> None:
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on_stack.add(v)
        for w in graph[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                cycles.append(sorted(component))

    for v in graph:
        if v not in index:
            visit(v)
    # A package __init__ that lazily re-exports its modules is the one allowed
    # back-edge: its modules import it (Python does), it imports them only on access.
    real = [c for c in cycles if not _only_through_lazy_init(c, graph)]
    assert real == [], "\n".join(" <-> ".join(c) for c in real)


def _only_through_lazy_init(component: list[str], graph: dict[str, set[str]]) -> bool:
    """True if the cycle closes only through a package's implicit ``__init__`` edge."""
    inits = {m for m in component if MODULES[m].name == "__init__.py"}
    pruned = {
        m: {w for w in graph[m] if w in component and not (w in inits and m.startswith(w + "."))}
        for m in component
    }
    # Without the implicit child -> package edges, is the component still cyclic?
    seen: set[str] = set()
    done: set[str] = set()

    def cyclic(v: str) -> bool:
        seen.add(v)
        for w in pruned[v]:
            if w not in done and (w in seen or cyclic(w)):
                return True
        done.add(v)
        return False

    return not any(cyclic(v) for v in component if v not in done)


def test_pure_parts_import_nothing_async() -> None:
    bad = []
    for module in sorted(PURE_CORE):
        for target, line, _ in imports(module):
            top = target.split(".")[0]
            if top in RUNTIME or (target.startswith("chassis_sdk.") and target not in PURE_CORE):
                if target.startswith("chassis_sdk.errors"):
                    continue
                bad.append(f"{module}:{line} imports {target}")
    assert bad == [], "\n".join(bad)


def _run(code: str, **env: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-c", code],
        capture_output=True,
        text=True,
        timeout=60,
        env={**os.environ, **env},
        check=False,
    )


@pytest.mark.integration
def test_the_codecs_load_without_the_runtime() -> None:
    code = (
        "import sys, chassis_sdk.protocol\n"
        "from chassis_sdk.protocol import ChassisDecoder, BoardDecoder\n"
        f"bad = [m for m in sys.modules if m.split('.')[0] in {RUNTIME!r}"
        " or m == 'chassis_sdk.core.transport']\n"
        "print(sorted(bad))"
    )
    result = _run(code)
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip() == "[]"


@pytest.mark.integration
def test_import_chassis_sdk_loads_no_runtime() -> None:
    result = _run(
        "import sys, chassis_sdk; print(sorted(m for m in sys.modules"
        f" if m.split('.')[0] in {RUNTIME!r}))"
    )
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip() == "[]"


@pytest.mark.integration
def test_record_works_whichever_way_the_device_class_was_imported(tmp_path: Path) -> None:
    # The core names no recorder: it finds the one chassis_sdk.recording declares.
    code = (
        "import sys\n"
        "from chassis_sdk.devices.chassis.device import Chassis\n"
        f"robot = Chassis('/dev/never-opened', record={str(tmp_path / 'x.jsonl')!r})\n"
        "print(robot.recording is not None, 'chassis_sdk.recording' in sys.modules)"
    )
    result = _run(code)
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip() == "True True"


@pytest.mark.integration
def test_a_bogus_backend_fails_only_the_open_in_one_line() -> None:
    cli = [sys.executable, "-m", "chassis_sdk.cli"]
    env = {**os.environ, "CHASSIS_SDK_BACKEND": "bogus"}
    helped = subprocess.run(
        [*cli, "--help"], capture_output=True, text=True, env=env, timeout=60, check=False
    )
    assert helped.returncode == 0, helped.stderr
    assert "usage: chassis-sdk" in helped.stdout
    opened = subprocess.run(
        [*cli, "info", "/dev/ttyNONE0"],
        capture_output=True,
        text=True,
        env=env,
        timeout=60,
        check=False,
    )
    assert opened.returncode != 0
    lines = opened.stderr.strip().splitlines()
    assert len(lines) == 1, opened.stderr
    assert "CHASSIS_SDK_BACKEND='bogus'" in lines[0]
    assert "pyserial-asyncio" in lines[0]


@pytest.mark.parametrize("module", sorted(MODULES))
def test_no_module_outside_core_touches_a_device_private_attribute(module: str) -> None:
    if module.startswith(("chassis_sdk.core", "chassis_sdk.devices")):
        return  # the core is the device; a device package is its subclass
    tree = ast.parse(MODULES[module].read_text(encoding="utf-8"))
    private = {"_link", "_streams", "_requests", "_watchdog", "_decoder", "_ingest"}
    found = [
        f"{module}:{node.lineno} .{node.attr}"
        for node in ast.walk(tree)
        if isinstance(node, ast.Attribute)
        and node.attr in private
        and not (isinstance(node.value, ast.Name) and node.value.id in ("self", "cls"))
    ]
    assert found == []


#: The most lines of code one class may have (a class past it does several things: a
#: surface's access, its protocol and its state were one 573-line class).
MAX_CLASS_LINES = 300


def _code_lines(module: str) -> list[tuple[str, int]]:
    """``(class, lines of code)`` of each class in ``module``: lines that are not
    blank, not comments and not docstrings."""
    source = MODULES[module].read_text(encoding="utf-8")
    tree = ast.parse(source)
    docs: set[int] = set()
    for node in ast.walk(tree):
        body = getattr(node, "body", None)
        if (
            isinstance(node, ast.Module | ast.ClassDef | ast.FunctionDef | ast.AsyncFunctionDef)
            and body
            and isinstance(body[0], ast.Expr)
            and isinstance(body[0].value, ast.Constant)
            and isinstance(body[0].value.value, str)
        ):
            docs.update(range(body[0].lineno, (body[0].end_lineno or body[0].lineno) + 1))
    lines = source.splitlines()
    sizes = []
    for node in ast.walk(tree):
        if isinstance(node, ast.ClassDef):
            span = range(node.lineno, (node.end_lineno or node.lineno) + 1)
            code = [
                n
                for n in span
                if n not in docs
                and lines[n - 1].strip()
                and not lines[n - 1].strip().startswith("#")
            ]
            sizes.append((node.name, len(code)))
    return sizes


def test_no_class_is_over_300_lines_of_code() -> None:
    big = [
        f"{module}.{name}: {n} lines of code"
        for module in sorted(MODULES)
        for name, n in _code_lines(module)
        if n > MAX_CLASS_LINES
    ]
    assert big == [], "\n".join(big)
