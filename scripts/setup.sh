#!/usr/bin/env bash
# Install what dolfinx_granular needs on Debian bookworm, skipping what is already there.
# Debian packages (sudo only when not root), a venv .venv on Debian's /usr/bin/python3 with the
# system site packages (DOLFINx lives there), the package editable and pyvista, with pip
# constrained so that numpy & co. stay Debian's versions (a numpy 2 breaks DOLFINx 0.5).
# The BLAS and LAPACK of numpy, SciPy, PETSc and MUMPS: Debian's serial OpenBLAS (one thread, so
# one per MPI rank), selected in Debian's alternatives (docs/performance.md, section 11).
set -euo pipefail
cd "$(dirname "$0")/.."

DEB_PACKAGES="python3-dolfinx python3-gmsh python3-numba python3-scipy python3-pytest \
python3-matplotlib python3-venv python3-pip python3-setuptools python3-wheel mpi-default-bin \
libgl1 libxrender1 libegl1 libopenblas0-serial"

missing=""
for p in $DEB_PACKAGES; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing="$missing $p"
done
if [ -n "$missing" ]; then
  echo "setup: installing Debian packages:$missing"
  SUDO=""; [ "$(id -u)" -eq 0 ] || SUDO="sudo"
  $SUDO apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq $missing >/dev/null
fi

# libblas.so.3 and liblapack.so.3 -> the serial OpenBLAS, also where another BLAS ranks higher in
# the alternatives (the multithreaded libopenblas0-pthread would oversubscribe the cores under MPI)
for lib in blas lapack; do
  target=$(dpkg -L libopenblas0-serial | grep -E "/openblas-serial/lib$lib\.so\.3$" | head -n 1)
  name="lib$lib.so.3-$(basename "$(dirname "$(dirname "$target")")")"  # e.g. ...-x86_64-linux-gnu
  if [ "$(update-alternatives --query "$name" | sed -n 's/^Value: //p')" != "$target" ]; then
    echo "setup: $name -> $target (update-alternatives)"
    SUDO=""; [ "$(id -u)" -eq 0 ] || SUDO="sudo"
    $SUDO update-alternatives --set "$name" "$target"
  fi
done

if [ ! -x .venv/bin/python ]; then
  echo "setup: creating .venv from /usr/bin/python3 with system site packages"
  /usr/bin/python3 -m venv --system-site-packages .venv
fi

constraints=.venv/constraints.txt
/usr/bin/python3 - > "$constraints" <<'PY'
import importlib.metadata as md
for dist in ("numpy", "scipy", "matplotlib", "numba", "llvmlite", "Pillow", "packaging"):
    try:
        print(f"{dist}=={md.version(dist)}")
    except md.PackageNotFoundError:
        pass
PY
export PIP_DISABLE_PIP_VERSION_CHECK=1
.venv/bin/python -m pip install -q -c "$constraints" --no-build-isolation -e .
.venv/bin/python -m pip install -q -c "$constraints" "pyvista>=0.43" 
.venv/bin/python -c "import numpy, dolfinx, pyvista, dolfinx_granular; print('setup: ok, numpy', numpy.__version__, 'dolfinx', dolfinx.__version__, 'pyvista', pyvista.__version__)"
# Fill Numba's and FFCx's caches now (a tiny run of the demo's and the API's code paths), so that
# the first `make demo` does not spend its set-up compiling; skipped in seconds while the sources
# are unchanged. Numba's cache is keyed to each source's mtime: an edited source recompiles on its
# first use (correct, just slower) until the next set-up warms it again. Not fatal: without it
# the first run compiles instead.
.venv/bin/python -m dolfinx_granular.warmup || echo "setup: the warm-up failed (above); the first run will compile instead"
