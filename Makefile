# hd — two commands for a fresh machine:
#   make demo   build, label, train and evaluate on the built-in procedural Mars terrain
#   make test   run the test suite
# Both create the virtual environment (.venv) on first use.

PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.hd-installed
DEMO_OUT ?= demo-out

.PHONY: demo test test-all lint bench venv clean

venv: $(STAMP)

$(STAMP): pyproject.toml requirements/cpu-constraints.txt scripts/ensure-system-libs.sh
	bash scripts/ensure-system-libs.sh
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install -q --upgrade pip
	$(BIN)/python -m pip install -q -c requirements/cpu-constraints.txt -e '.[test]'
	touch $(STAMP)

demo: $(STAMP)
	$(BIN)/hd demo --out $(DEMO_OUT)

# Lint and types (rules and their reasons: docs/development.md). mypy checks the packages, the CLI,
# benchmarks and scripts in one run, then each test folder on its own: they are flat folders of
# modules (two conftest.py), imported by pytest from their own directory.
lint: $(STAMP)
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .
	$(BIN)/mypy
	for d in tests/*/; do $(BIN)/mypy --allow-incomplete-defs "$$d" || exit 1; done
	@! grep -rnE --include='*.py' --exclude-dir=.venv 'type: ignore\[[^]]*\] *$$' . \
		|| { echo "error: the type: ignore above lacks its reason comment"; exit 1; }

test: lint
	bash scripts/ensure-test-browser.sh
	$(BIN)/python -m pytest -q

test-all: $(STAMP)
	$(BIN)/python -m pytest -q -m ''

bench: $(STAMP)
	for b in benchmarks/bench_*.py; do $(BIN)/python $$b || exit 1; done

clean:
	rm -rf $(VENV) $(DEMO_OUT) .pytest_cache .mypy_cache .ruff_cache
