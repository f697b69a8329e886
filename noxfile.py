"""The developer's commands (``pip install nox``; ``nox -l`` lists them).

    nox -s fast        lint, types, and every test that needs no port, broker or browser
    nox -s full        README's test command: the whole suite in parallel, then `timing`
    nox -s transports  the integration tests on the fast fork, serialx and uvloop
    nox -s docs        mkdocs build --strict (``nox -s docs -- serve`` to serve it)
    nox -s nightly     fuzz every decoder and run every benchmark (over an hour)

Each session installs the project from this checkout (``-e``: the tests import this
tree, with its compiled fast path) with the extras and dependency groups it needs
(pyproject.toml). ``nox -R`` reuses the environments and skips the installs.
``full`` and ``transports`` need the system parts first: ``sh tools/system-deps.sh``.
CONTRIBUTING.md says how long each takes.
"""

from __future__ import annotations

import nox

nox.options.default_venv_backend = "venv"
nox.options.sessions = ["fast"]

#: The tests that need nothing but Python: no pty, socket, process, broker or browser.
UNIT = "not (integration or browser or mqtt or ros2 or netns or slow or timing)"


def _install(session: nox.Session, extras: str, *groups: str) -> None:
    args = ["-e", f".[{extras}]"] if extras else ["-e", "."]
    for group in groups:
        args += ["--group", group]
    session.install("--upgrade", "pip>=25.1")  # --group
    session.install(*args)


def _pytest(session: nox.Session, *args: str, env: dict[str, str] | None = None) -> None:
    """The suite in parallel (timing deselected there), then its timing tests alone."""
    marks = list(args)
    session.run("python", "-m", "pytest", "-n", "auto", *marks, *session.posargs, env=env)
    expr = "timing"
    if "-m" in marks:
        expr = f"({marks[marks.index('-m') + 1]}) and timing"
    session.run(
        "python", "-m", "pytest", "-m", expr, *session.posargs, env=env, success_codes=[0, 5]
    )


def _lint(session: nox.Session) -> None:
    session.run("ruff", "check", ".")
    session.run("ruff", "format", "--check", ".")
    session.run("mypy", "--strict", "chassis_sdk")
    session.run("mypy", "--strict", "tests", "examples", "benchmarks", "fuzz")


@nox.session
def fast(session: nox.Session) -> None:
    """Lint, types, and the tests that need no port, broker or browser (the unit, codec,
    contract and stateful tests): the loop to run before every commit."""
    _install(session, "all", "test", "lint")
    _lint(session)
    session.run("python", "-m", "pytest", "-n", "auto", "-m", UNIT, *session.posargs)


@nox.session
def full(session: nox.Session) -> None:
    """README's test command: every test, in parallel, then the timing tests serially."""
    _install(session, "all", "test")
    _pytest(session)


@nox.session
@nox.parametrize("backend", ["pyserial-asyncio-fast", "serialx", "uvloop"])
def transports(session: nox.Session, backend: str) -> None:
    """The integration tests on another transport, or on uvloop (with uvloop's own tests).
    (CI runs the fast fork with uvloop on the pure decoders, and serialx on asyncio's loop.)"""
    extra = {"pyserial-asyncio-fast": "fast", "serialx": "serialx", "uvloop": "uvloop"}[backend]
    _install(session, f"all,{extra}", "test")
    if backend == "uvloop":
        _pytest(session, "-m", "integration or uvloop", env={"CHASSIS_SDK_TEST_LOOP": "uvloop"})
    else:
        _pytest(session, "-m", "integration")


@nox.session
def docs(session: nox.Session) -> None:
    """The site, --strict (``-- serve`` serves it instead, with reload)."""
    _install(session, "all", "docs")
    if session.posargs[:1] == ["serve"]:
        session.run("mkdocs", "serve", *session.posargs[1:])
    else:
        session.run("mkdocs", "build", "--strict", env={"NO_MKDOCS_2_WARNING": "1"})


@nox.session
def nightly(session: nox.Session) -> None:
    """What CI leaves out for time: a long coverage-guided fuzz of every decoder, then
    every benchmark (``benchmarks/all.py``, about 75 minutes on 2 cores). Arguments go to
    ``all.py`` (``nox -s nightly -- --json results.json``)."""
    _install(session, "all,fast,serialx,uvloop", "fuzz", "bench")
    crashes = session.create_tmp()  # a failing input is written here, named in the log
    for target in ("chassis", "chassis-commands", "board", "board-commands"):
        session.run(
            "python", "fuzz/run.py", target, "-atheris_runs=200000", f"-artifact_prefix={crashes}/"
        )
    session.run("python", "benchmarks/all.py", *session.posargs)
