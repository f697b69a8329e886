#!/bin/sh
# Regenerate the compiled fast path's C from its Cython sources (commit both: the
# install builds the C, with no Cython needed). Needs the Cython pinned below.
set -eu
cd "$(dirname "$0")/.."
python -m cython --version 2>&1 | grep -q "3.3.1" || {
    echo "tools/cythonize.sh: needs Cython 3.3.1 (pip install cython==3.3.1)" >&2
    exit 1
}
for pyx in chassis_sdk/devices/chassis/_compiled.pyx chassis_sdk/devices/board/_compiled.pyx; do
    python -m cython -3 --fast-fail "$pyx"
done
