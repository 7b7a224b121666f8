# The README's commands: `make demo` (main job) and `make test` (whole suite; `make test-quick`
# the tests not marked slow), on Debian bookworm's DOLFINx 0.5.2; `make lint` (ruff) and `make bench` (docs/performance.md). All set
# everything up first; a second set-up run costs seconds.
# The `-current` targets do the same on the current DOLFINx (0.11, PyPI wheel, Python >= 3.12).
PY := .venv/bin/python
NP ?= 2
export OMPI_ALLOW_RUN_AS_ROOT := 1
export OMPI_ALLOW_RUN_AS_ROOT_CONFIRM := 1
export OMPI_MCA_rmaps_base_oversubscribe := 1
# Each stack's own MPI launcher, whatever PATH says (an activated .venv-current puts MPICH's first)
MPIRUN = $(shell $(PY) -c 'from dolfinx_granular.fem.compat import mpi_command; print(" ".join(mpi_command($(NP))))')
CURRENT := .venv-current
PYC := $(CURRENT)/bin/python
MPIEXEC_C := $(CURRENT)/bin/mpiexec -n $(NP)
# Set up .venv-current, then run $(1) there. Without a Python >= 3.12 (setup-current.sh exits 3)
# the 0.11 leg says that it did not run and succeeds, so that the 0.5.2 leg still counts.
define current
	@rc=0; bash scripts/setup-current.sh || rc=$$?; \
	if [ $$rc -eq 3 ]; then echo "$@: the DOLFINx 0.11 leg did NOT run (no Python >= 3.12 here)"; exit 0; fi; \
	[ $$rc -eq 0 ] || exit $$rc; set -ex; $(1)
endef

.PHONY: setup warm demo test test-quick test-serial test-mpi lint bench setup-current demo-current test-current test-quick-current bench-current clean

setup: .venv/.setup-done

.venv/.setup-done: scripts/setup.sh pyproject.toml
	bash scripts/setup.sh
	touch $@

# The JIT caches (Numba kernels, FFCx forms) for the sources as they are now, so that a run does
# not start by compiling: setup.sh fills them, this refills them after a source changed (about a
# minute; a second or two when current). Not fatal: without it the run compiles instead.
warm: setup
	@$(PY) -m dolfinx_granular.warmup || echo "warm: the warm-up failed (above); the run will compile instead"

# make demo replaces the previous make demo's results (results/slope) with --force
demo: warm
	$(MPIRUN) $(PY) demos/slope.py --force

test: setup test-serial test-mpi

test-serial: warm
	$(PY) -m pytest -q --color=no tests

test-mpi: warm
	$(MPIRUN) $(PY) -m pytest -q --color=no -m mpi -p no:cacheprovider tests

# The tests not marked slow (docs, command lines, snippets, kernels, small DOLFINx solves),
# serially and on 2 ranks: a few minutes, where `make test` takes about half an hour
test-quick: warm
	$(PY) -m pytest -q --color=no -m "not slow" tests
	$(MPIRUN) $(PY) -m pytest -q --color=no -m "mpi and not slow" -p no:cacheprovider tests

# ruff pinned: another version may format differently (configuration in pyproject.toml)
RUFF_VERSION := 0.17.6
lint: setup
	$(PY) -m pip install -q --disable-pip-version-check "ruff==$(RUFF_VERSION)"
	.venv/bin/ruff check .
	.venv/bin/ruff format --check .

bench: warm
	$(PY) benchmarks/report.py

setup-current:
	bash scripts/setup-current.sh

demo-current:
	$(call current,$(MPIEXEC_C) $(PYC) demos/slope.py --out results/slope-current --force)

test-current:
	$(call current,$(PYC) -m pytest -q --color=no tests; \
	  $(MPIEXEC_C) $(PYC) -m pytest -q --color=no -m mpi -p no:cacheprovider tests)

test-quick-current:
	$(call current,$(PYC) -m pytest -q --color=no -m "not slow" tests; \
	  $(MPIEXEC_C) $(PYC) -m pytest -q --color=no -m "mpi and not slow" -p no:cacheprovider tests)

bench-current:
	$(call current,$(PYC) benchmarks/report.py --out results/report-current)

clean:
	rm -rf .venv $(CURRENT) results .pytest_cache
