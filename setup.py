"""The optional compiled fast path (see chassis_sdk/core/compiled.py).

Everything else about the package is in pyproject.toml. The extensions are built from the
C that Cython generates from the ``.pyx`` sources, which is not committed: in a checkout
this file generates it (Cython is a build requirement in pyproject.toml, so pip fetches
it), and the sdist ships it, so installing from the sdist needs a C compiler but not
Cython. Without a compiler, without Cython in a checkout (``--no-build-isolation``), or if
compiling fails, the install goes on with a warning and the pure Python code runs
(``chassis-sdk --version`` says which path is active). ``CHASSIS_SDK_PURE=1`` at install
time skips building them. Building an sdist whose C cannot be generated fails.
"""

from __future__ import annotations

import os
import sys

from setuptools import Extension, setup
from setuptools.command.build_ext import build_ext

#: The compiled modules, one per protocol, each beside the pure code it mirrors: the
#: module and its Cython source (the C is generated beside it).
FAST = {
    "chassis_sdk.devices.chassis._compiled": "chassis_sdk/devices/chassis/_compiled.pyx",
    "chassis_sdk.devices.board._compiled": "chassis_sdk/devices/board/_compiled.pyx",
}
#: What `cython -3` set; the other directives are in each .pyx's first lines.
DIRECTIVES = {"language_level": "3"}
NO_COMPILER = "Install a C compiler and reinstall for the fast path."
NO_CYTHON = "Install Cython (pip fetches it unless --no-build-isolation) and reinstall."


def warn(what: str, remedy: str = NO_COMPILER) -> None:
    print(
        f"WARNING: chassis-sdk: {what}; the pure Python decoders will be used "
        f"(same results, slower). {remedy}".rstrip(),
        file=sys.stderr,
    )


class OptionalBuildExt(build_ext):
    """Build each extension if it can be; warn, never fail, when it cannot."""

    def run(self) -> None:
        try:
            super().run()
        except Exception as exc:  # no compiler at all (distutils' CCompilerError and kin)
            warn(f"the compiled fast path was not built ({exc})")

    def build_extension(self, ext: Extension) -> None:
        try:
            super().build_extension(ext)
        except Exception as exc:
            warn(f"{ext.name} was not built ({exc})")


def c_of(pyx: str) -> str:
    return pyx.removesuffix(".pyx") + ".c"


def generate(pure: bool) -> list[str]:
    """The modules whose C is ready, warning about the others unless ``pure``. An sdist
    (PKG-INFO at its root, which a checkout has not) ships its C; in a checkout, Cython
    generates each C from its .pyx (and skips a C newer than its sources)."""
    if os.path.exists("PKG-INFO"):
        shipped = [name for name, pyx in FAST.items() if os.path.exists(c_of(pyx))]
        for name in FAST.keys() - shipped:
            if not pure:
                warn(f"{name} was not built (its C is missing from the sdist)")
        return shipped
    try:
        from Cython.Build import cythonize
        from Cython.Compiler import Options
    except ImportError:
        current = []
        for name, pyx in FAST.items():
            c = c_of(pyx)
            # A C left by an earlier build is used only if its .pyx has not changed since.
            if os.path.exists(c) and os.path.getmtime(c) >= os.path.getmtime(pyx):
                current.append(name)
            elif not pure:
                warn(f"{name} was not built (Cython is not installed to generate it)", NO_CYTHON)
        return current
    Options.fast_fail = True  # as `cython --fast-fail`: stop at a module's first error
    generated = []
    for name, pyx in FAST.items():
        try:
            cythonize([Extension(name, [pyx])], compiler_directives=DIRECTIVES)
        except Exception as exc:  # Cython's CompileError: its messages are printed above
            if not pure:
                warn(f"{name} was not built (Cython could not compile {pyx}: {exc})", "")
        else:
            generated.append(name)
    return generated


pure = os.environ.get("CHASSIS_SDK_PURE", "") not in ("", "0")
ready = generate(pure)
if "sdist" in sys.argv[1:] and len(ready) < len(FAST):
    # An sdist without its C would install the pure path everywhere: fail here instead.
    sys.exit("chassis-sdk: the sdist needs the C that Cython generates from each .pyx")
present = [Extension(name, [c_of(FAST[name])]) for name in ready]
setup(ext_modules=[] if pure else present, cmdclass={"build_ext": OptionalBuildExt})
