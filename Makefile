# forcdecode: two commands for a fresh machine
#   make run    install into .venv, then run the main job (Snakemake, config/config.yaml)
#   make test   install into .venv (with the test extras), then run the tests (not the slow ones)
#   make test-all   the tests marked slow too;  make lint   snakemake --lint and snakefmt --check
#   make report     results/report.zip: the run's figures and tables with captions (after make run)
PYTHON ?= python3
VENV   ?= .venv
BIN    := $(VENV)/bin
CORES  ?= 2
# test processes (pytest-xdist): numba runs one thread in the tests (tests/conftest.py), the training tests
# one torch thread, so one process per core;
# a test module stays in one process (--dist loadfile: its module-scoped fixtures are built once), and modules
# start in collection order (--no-loadscope-reorder; tests/conftest.py puts the longest first)
TEST_WORKERS ?= 2
PYTEST := $(BIN)/python -m pytest -n $(TEST_WORKERS) --dist loadfile --no-loadscope-reorder

.PHONY: install install-test run test test-all lint report bench clean clean-cache

$(BIN)/python:
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip

$(VENV)/.installed: pyproject.toml | $(BIN)/python
	$(BIN)/python -m pip install --quiet -e .
	touch $@

$(VENV)/.installed-test: pyproject.toml | $(BIN)/python
	$(BIN)/python -m pip install --quiet -e ".[test,reference]"
	touch $(VENV)/.installed $@

install: $(VENV)/.installed
install-test: $(VENV)/.installed-test

run: install
	$(BIN)/snakemake --cores $(CORES) --configfile config/config.yaml

test: install-test
	$(PYTEST)

test-all: install-test
	$(PYTEST) -m ""

lint: install-test
	$(BIN)/snakemake --lint --configfile config/config.yaml
	$(BIN)/snakefmt --check .

report: install
	$(BIN)/snakemake --configfile config/config.yaml --report results/report.zip

bench: install-test
	$(BIN)/forcdecode bench engine --json

clean:
	rm -rf results/* .snakemake

# numba caches compiled kernels beside the sources and recompiles a function when ITS file changes,
# not when a kernel it calls (in another file) does: after editing src/forcdecode/micromag, run this
clean-cache:
	find src -name '*.nbi' -delete -o -name '*.nbc' -delete
