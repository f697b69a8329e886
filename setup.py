"""The optional compiled fast path (see chassis_sdk/core/compiled.py).

Everything else about the package is in pyproject.toml. The extensions are built from
the generated C files in the tree (and the sdist), so installing needs a C compiler but
not Cython; ``tools/cythonize.sh`` regenerates them from the ``.pyx`` sources. Without a
compiler, or if compiling fails, the install goes on with a warning and the pure Python
code runs (``chassis-sdk --version`` says which path is active). ``CHASSIS_SDK_PURE=1``
at install time skips building them.
"""

from __future__ import annotations

import os
import sys

from setuptools import Extension, setup
from setuptools.command.build_ext import build_ext

#: The compiled modules: one per protocol, each beside the pure code it mirrors.
FAST = [
    Extension("chassis_sdk.devices.chassis._compiled", ["chassis_sdk/devices/chassis/_compiled.c"]),
    Extension("chassis_sdk.devices.board._compiled", ["chassis_sdk/devices/board/_compiled.c"]),
]


class OptionalBuildExt(build_ext):
    """Build each extension if it can be; warn, never fail, when it cannot."""

    def run(self) -> None:
        try:
            super().run()
        except Exception as exc:  # no compiler at all (distutils' CCompilerError and kin)
            self._warn(f"the compiled fast path was not built ({exc})")

    def build_extension(self, ext: Extension) -> None:
        try:
            super().build_extension(ext)
        except Exception as exc:
            self._warn(f"{ext.name} was not built ({exc})")

    @staticmethod
    def _warn(what: str) -> None:
        print(
            f"WARNING: chassis-sdk: {what}; the pure Python decoders will be used "
            "(same results, slower). Install a C compiler and reinstall for the fast path.",
            file=sys.stderr,
        )


pure = os.environ.get("CHASSIS_SDK_PURE", "") not in ("", "0")
present = [ext for ext in FAST if all(os.path.exists(s) for s in ext.sources)]
setup(ext_modules=[] if pure else present, cmdclass={"build_ext": OptionalBuildExt})
