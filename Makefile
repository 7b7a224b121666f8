# The two commands of the README: `make demo` (main job) and `make test` (whole suite).
# Both set everything up first; a second set-up run costs seconds.
PY := .venv/bin/python
NP ?= 2
export OMPI_ALLOW_RUN_AS_ROOT := 1
export OMPI_ALLOW_RUN_AS_ROOT_CONFIRM := 1
export OMPI_MCA_rmaps_base_oversubscribe := 1
MPIRUN := mpirun -n $(NP)

.PHONY: setup demo test test-serial test-mpi bench clean

setup: .venv/.setup-done

.venv/.setup-done: scripts/setup.sh pyproject.toml
	bash scripts/setup.sh
	touch $@

demo: setup
	$(MPIRUN) $(PY) demos/slope.py

test: setup test-serial test-mpi

test-serial: setup
	$(PY) -m pytest -q --color=no tests

test-mpi: setup
	$(MPIRUN) $(PY) -m pytest -q --color=no -m mpi -p no:cacheprovider tests

bench: setup
	$(PY) benchmarks/report.py

clean:
	rm -rf .venv results .pytest_cache
