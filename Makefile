# The two commands of the quick start: `make demo` and `make test`. Both create .venv when it is missing.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
BENCH_STAMP := $(VENV)/.installed-bench

.PHONY: demo bench figures test lint typecheck unit clean

$(BIN)/python:
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip

# Reinstall whenever the project's declared dependencies change.
$(STAMP): pyproject.toml | $(BIN)/python
	$(BIN)/python -m pip install --quiet -e '.[test,fast,plot]'
	touch $(STAMP)

# Master and slave on localhost, 1000 samples/s of 100 bytes each way, live statistics for 5 s.
demo: $(STAMP)
	$(BIN)/tdtp demo --duration 5

$(BENCH_STAMP): pyproject.toml | $(BIN)/python
	$(BIN)/python -m pip install --quiet -e '.[test,fast,bench,plot]'
	touch $(BENCH_STAMP)

# The benchmark suite (~2.5 min on 2 cores): prints the table, writes benchmarks/results/latest.*
bench: $(BENCH_STAMP)
	$(BIN)/python benchmarks/run_all.py

# The paper's figures 7 and 8 and the other scenarios, in virtual time (docs/REPRODUCTION.md).
figures: $(STAMP)
	$(BIN)/tdtp simulate all --out docs/figures --jobs 2

lint: $(STAMP)
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .

typecheck: $(STAMP)
	$(BIN)/mypy --strict tdtp

unit: $(STAMP)
	$(BIN)/python -m pytest -q -n 2

test: lint typecheck unit

clean:
	rm -rf $(VENV) .mypy_cache .pytest_cache .ruff_cache .hypothesis
