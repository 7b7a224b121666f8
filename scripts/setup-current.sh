#!/usr/bin/env bash
# The second install path: the current DOLFINx (0.11) from PyPI, on any Linux with Python >= 3.12.
# Creates .venv-current from the first Python >= 3.12 it finds ($PYTHON, python3.13, python3.12,
# python3, then pyenv's versions) and installs this package editable with the extras `dolfinx`
# (the binary wheel dolfinx-solver-real: DOLFINx, PETSc with MUMPS, MPICH and its mpiexec; gmsh),
# `viz` (pyvista) and `test` (pytest). Nothing is compiled; a second run takes seconds.
# Exit status 3 (and one line saying so) when no Python >= 3.12 is found.
set -euo pipefail
cd "$(dirname "$0")/.."
VENV=${CURRENT_VENV:-.venv-current}

is_new_enough() {  # a working interpreter of version >= 3.12 (pyenv shims of other versions fail)
  "$1" -c 'import sys; sys.exit(sys.version_info < (3, 12))' >/dev/null 2>&1
}

find_python() {
  local c
  for c in ${PYTHON:-} python3.13 python3.12 python3; do
    if command -v "$c" >/dev/null 2>&1 && is_new_enough "$c"; then command -v "$c"; return; fi
  done
  for c in "${PYENV_ROOT:-$HOME/.pyenv}"/versions/3.1[2-9]*/bin/python3; do
    if [ -x "$c" ] && is_new_enough "$c"; then echo "$c"; return; fi
  done
}

if [ ! -x "$VENV/bin/python" ]; then
  py=$(find_python)
  if [ -z "$py" ]; then
    echo "setup-current: no Python >= 3.12 found (tried \$PYTHON, python3.13, python3.12, python3," \
         "pyenv's versions): the DOLFINx 0.11 install path is NOT set up"
    exit 3
  fi
  echo "setup-current: creating $VENV from $py ($("$py" --version))"
  "$py" -m venv "$VENV"
fi
export PIP_DISABLE_PIP_VERSION_CHECK=1
"$VENV/bin/python" -m pip install -q -e ".[dolfinx,viz,test]"
"$VENV/bin/python" -c "import dolfinx_granular, dolfinx, numba, numpy; from petsc4py import PETSc; \
print('setup-current: ok, dolfinx', dolfinx.__version__, 'PETSc', '.'.join(map(str, PETSc.Sys.getVersion())), \
'numba', numba.__version__, 'numpy', numpy.__version__)"
# Fill Numba's and FFCx's caches (see scripts/setup.sh); skipped in seconds while the sources are
# unchanged, so that every `make *-current` can run this script.
"$VENV/bin/python" -m dolfinx_granular.warmup || echo "setup-current: the warm-up failed (above); the first run will compile instead"
