# robocloud: `make run` starts the system, `make test` sets up and runs the tests.
# Every target builds its own virtual environment from nothing but Python 3.11+.
# `make check` is the quick loop: lint and the tests that need no server.
PYTHON ?= $(shell command -v python3.11 || command -v python3)
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

# Left out of `make check` (markers mostly given in tests/conftest.py): tests of
# several seconds, real processes, a browser, the PostgreSQL server.
QUICK := not slow and not system and not browser and not postgres

.PHONY: run test fuzz check lint bench reset clean venv

venv: $(STAMP)

$(STAMP): pyproject.toml requirements.lock
	$(PYTHON) -c 'import sys; assert sys.version_info >= (3, 11), "robocloud needs Python 3.11 or newer"'
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --disable-pip-version-check -r requirements.lock
	$(BIN)/python -m pip install --quiet --disable-pip-version-check --no-deps -e .
	touch $(STAMP)

# `make run DEMO_ARGS=--nxt` adds the thesis's NXT robots (stand-in bricks) to cloud-a.
run: $(STAMP)
	$(BIN)/python -m robocloud.cli.demo $(DEMO_ARGS)

# The tests use the PostgreSQL and MQTT servers already running, else start their own
# (tests/session_servers.py); chromium is installed when missing, where that can be done.
# Three workers on two cores: the system tests mostly wait on their processes
# (two workers kept the cores 56 % busy; three took 289 s against 371 s). A
# file stays on one worker (its servers start once); the slowest files start
# first (tests/conftest.py orders them), so --no-loadscope-reorder keeps that order.
test: $(STAMP)
	sh tests/wildfire/ensure_chromium.sh
	$(BIN)/python -m pytest -q -n 3 --dist loadfile --no-loadscope-reorder

# schemathesis for 40 s instead of make test's 8 (tests/system/test_api_fuzz.py).
fuzz: $(STAMP)
	ROBOCLOUD_FUZZ_SECONDS=40 $(BIN)/python -m pytest -q -s tests/system/test_api_fuzz.py

check: lint
	$(BIN)/python -m pytest -q -n 2 -m "$(QUICK)"

lint: $(STAMP)
	$(BIN)/ruff check src tests benchmarks examples
	$(BIN)/mypy

bench: $(STAMP)
	$(BIN)/python -m benchmarks.run

# `make run` keeps its stores and logs in var/ between runs; this starts it afresh.
reset:
	rm -rf var

clean: reset
	rm -rf $(VENV) build dist src/*.egg-info .pytest_cache .mypy_cache .ruff_cache
