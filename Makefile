# Mollusca Fleet. `make demo` runs a broker, the server and three simulated robots; `make test` runs
# every test (installing what is missing first). See README.md.

PYTHON ?= $(shell command -v python3.11 2>/dev/null || command -v python3 2>/dev/null)
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
STAMP_DEMO := $(VENV)/.installed-demo
FIREFOX_TESTS := tests/frontend/firefox
STAMP_NPM := $(FIREFOX_TESTS)/node_modules/.installed
DEPCRUISE := tools/depcruise
STAMP_DEPCRUISE := $(DEPCRUISE)/node_modules/.installed
PYTEST_ARGS ?=
DEMO_ARGS ?=
POSTGRES_TESTS ?= tests/backend tests/fleet_client tests/system/test_fleet_e2e.py tests/system/test_faults_nothing_lost.py \
	tests/system/test_server_with_agent.py

.PHONY: help venv system-deps test test-report test-postgres lint lint-checks demo screenshots bench bench-quick clean distclean \
	plotly-bundle

help:
	@echo "make demo          broker + server on http://localhost:8000 + 3 simulated robots (Ctrl-C stops all)"
	@echo "                   DEMO_ARGS='--robots 5 --camera' passes options to scripts/demo.py"
	@echo "make screenshots   fleet/robot/history/users pages at phone, tablet, 1280x720 -> docs/screenshots/"
	@echo "make test          Debian packages + venv if missing, then make lint's checks and the whole test suite"
	@echo "                   PYTEST_ARGS='-k demo -x' passes options to pytest (both lanes: docs/testing.md)"
	@echo "make test-report   the 30 slowest tests and the time per folder of the last make test"
	@echo "make test-postgres the server tests against PostgreSQL on 127.0.0.1:5432"
	@echo "make lint          ruff (check, format), mypy, import-linter (the rooms' import rules)"
	@echo "make bench         every benchmark, printed as a table (bench/run_all.py)"
	@echo "make venv          .venv with everything (server, vision, demo, dev tools)"
	@echo "make plotly-bundle rebuild frontend/vendor/plotly.min.js (only the console's trace types; needs npm)"
	@echo "make clean         caches and demo state; make distclean also removes .venv"

# Python >= 3.11 and a venv; re-created only when missing.
$(BIN)/python:
	@test -n "$(PYTHON)" || { echo "Python 3.11 not found (python3.11 or python3)"; exit 1; }
	@$(PYTHON) -c 'import sys; sys.exit(sys.version_info < (3, 11))' || \
		{ echo "$(PYTHON) is older than 3.11; install python3.11 or set PYTHON=/path/to/python3.11"; exit 1; }
	$(PYTHON) -m venv $(VENV)

# Everything (tests, vision, dev tools); re-installed only when pyproject.toml is newer than the stamp.
$(STAMP): pyproject.toml | $(BIN)/python
	$(BIN)/python -m pip install -q --upgrade pip
	$(BIN)/python -m pip install -q -e '.[server,vision,demo,dev,foxglove]'
	touch $(STAMP) $(STAMP_DEMO)

# Just what the demo needs: a fresh clone serves the dashboard within a minute.
$(STAMP_DEMO): pyproject.toml | $(BIN)/python
	$(BIN)/python -m pip install -q -e '.[server,demo]'
	touch $(STAMP_DEMO)

venv: $(STAMP)

# puppeteer-core for the Firefox test (exact versions from package-lock.json; no browser download)
$(STAMP_NPM): $(FIREFOX_TESTS)/package-lock.json
	npm ci --prefix $(FIREFOX_TESTS) --no-audit --no-fund --loglevel=error
	touch $(STAMP_NPM)

# dependency-cruiser: the dashboard's import rules (tools/depcruise/dependency-cruiser.cjs), for make lint
$(STAMP_DEPCRUISE): $(DEPCRUISE)/package-lock.json
	npm ci --prefix $(DEPCRUISE) --no-audit --no-fund --loglevel=error
	touch $(STAMP_DEPCRUISE)

system-deps:
	./scripts/ensure-system-deps.sh

lint: venv $(STAMP_DEPCRUISE)
	@$(MAKE) --no-print-directory lint-checks

# The checks themselves, on an installed venv (make test runs them beside its first lane, niced).
lint-checks:
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .
	$(BIN)/mypy
	$(BIN)/lint-imports
	$(BIN)/python scripts/check_house.py
	@for f in $$(find frontend/js -name '*.js'); do node --input-type=module --check < $$f || { echo "syntax error in $$f"; exit 1; }; done
	$(DEPCRUISE)/node_modules/.bin/depcruise --config $(DEPCRUISE)/dependency-cruiser.cjs --output-type err frontend/js

# The test command (.ci/run runs it): every test, in lanes, with lint and type checks beside the first lane
# (scripts/test_lanes.py --lint; docs/testing.md). A failing check fails make test like a failing test.
test: system-deps venv $(STAMP_NPM) $(STAMP_DEPCRUISE)
	$(BIN)/python scripts/test_lanes.py --lint $(PYTEST_ARGS)

# The 30 slowest tests and the time per folder, from the JUnit reports of the last `make test` (test-results/).
test-report:
	@$(BIN)/python scripts/test_report.py

test-postgres: system-deps venv
	$(BIN)/pytest -q --database postgres $(POSTGRES_TESTS) $(PYTEST_ARGS)

demo: $(STAMP_DEMO)
	$(BIN)/python scripts/demo.py $(DEMO_ARGS)

# Not part of `make test`: pictures for the docs, from a demo with authentication on (scripts/screenshots.py).
screenshots: $(STAMP)
	$(BIN)/python scripts/screenshots.py

bench: system-deps venv
	$(BIN)/python bench/run_all.py

bench-quick: system-deps venv
	$(BIN)/python bench/run_all.py --quick

# The vendored Plotly holds only the trace types in scripts/plotly-bundle/traces.json; the output is
# committed, so nothing else (make test, the demo, compose) needs npm or the network for it.
plotly-bundle:
	cd scripts/plotly-bundle && npm ci --no-audit --no-fund && node build.js

clean:
	rm -rf .demo .pytest_cache .mypy_cache .ruff_cache .hypothesis test-results build dist
	find . -name __pycache__ -type d -not -path './$(VENV)/*' -prune -exec rm -rf {} +

distclean: clean
	rm -rf $(VENV) *.egg-info scripts/plotly-bundle/node_modules
