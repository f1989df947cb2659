# chaintwin: the README's two commands, `make demo` and `make test`, each
# create the virtual environment they need on a fresh machine.

PYTHON ?= python3
VENV   ?= .venv
BIN    := $(VENV)/bin
SOURCES := chaintwin tests benchmarks scripts

.PHONY: demo test test-fast check format bench docs clean

$(BIN)/python:
	@$(PYTHON) -c 'import sys; assert sys.version_info >= (3, 11), "chaintwin needs Python >= 3.11"'
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install -q --upgrade pip

# the batch job and the dashboard the demo points to (`chaintwin serve`): the web extra
$(VENV)/.installed-run: pyproject.toml | $(BIN)/python
	$(BIN)/python -m pip install -q -e '.[web]'
	@touch $@

# dev: every extra (the tests cover them all) and the tools
$(VENV)/.installed-dev: pyproject.toml | $(BIN)/python
	$(BIN)/python -m pip install -q -e '.[dev]'
	@touch $@ $(VENV)/.installed-run

## demo: the main job on the bundled virtual conveyor
demo: $(VENV)/.installed-run
	$(BIN)/chaintwin demo

## test: formatter check, linter, type checker, the layers contract (docs/design.md),
## tests and doctests (warnings as errors, one worker per core, a test file per worker)
## with a coverage floor; installs PostgreSQL and
## Chromium if missing (the store's and the dashboard's tests use them)
test: $(VENV)/.installed-dev
	bash scripts/ensure_test_tools.sh
	$(BIN)/ruff format --check $(SOURCES)
	$(BIN)/ruff check $(SOURCES)
	$(BIN)/mypy chaintwin
	$(BIN)/lint-imports --no-cache
	NO_MKDOCS_2_WARNING=1 $(BIN)/mkdocs build --strict --quiet
	$(BIN)/pytest -q -n auto --dist loadfile --cov --cov-report=term:skip-covered

## docs: the documentation site in site/ (mkdocs.yml; `$(BIN)/mkdocs serve` to read it live)
docs: $(VENV)/.installed-dev
	NO_MKDOCS_2_WARNING=1 $(BIN)/mkdocs build --strict

## test-fast: what `make test` checks but the slow, browser and PostgreSQL tests (markers
## in pyproject.toml) and the coverage floor: formatter check, linter, type checker (its
## cache makes it quick after the first run), the quick tests and the doctests
test-fast: $(VENV)/.installed-dev
	$(BIN)/ruff format --check $(SOURCES)
	$(BIN)/ruff check $(SOURCES)
	$(BIN)/mypy chaintwin
	$(BIN)/lint-imports --no-cache
	$(BIN)/pytest -q -m "not slow and not browser and not postgres"

format: $(VENV)/.installed-dev
	$(BIN)/ruff format $(SOURCES)
	$(BIN)/ruff check --fix $(SOURCES)

## bench: the benchmark scripts (not part of the tests)
bench: $(VENV)/.installed-dev
	$(BIN)/python benchmarks/bench_read.py
	$(BIN)/python benchmarks/bench_simulate.py
	$(BIN)/python benchmarks/bench_weigh.py
	$(BIN)/python benchmarks/bench_monitor.py
	$(BIN)/python benchmarks/bench_ingest.py
	$(BIN)/python benchmarks/bench_throughput.py
	$(BIN)/python benchmarks/bench_serve.py
	$(BIN)/python benchmarks/bench_live.py
	$(BIN)/python benchmarks/bench_opcua.py

clean:
	rm -rf $(VENV) .mypy_cache .ruff_cache .pytest_cache .hypothesis site
