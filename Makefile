# Two commands for a fresh machine:
#   make demo   set everything up and run the demo on the simulated thesis robot
#   make test   set everything up and run all tests (what CI runs)
PYTHON ?= python3
VENV   ?= .venv
BIN    := $(VENV)/bin
DEMO_ARGS ?=

.PHONY: setup system-deps demo test lint clean

$(BIN)/blackbox: pyproject.toml
	scripts/setup.sh $(PYTHON) $(VENV)

setup: $(BIN)/blackbox

system-deps:
	scripts/install-system-deps.sh

demo: setup
	$(BIN)/blackbox demo $(DEMO_ARGS)

test: setup system-deps
	VENV=$(VENV) scripts/test.sh

lint: setup
	$(BIN)/ruff check src tests benchmarks
	$(BIN)/mypy

clean:
	rm -rf $(VENV) build src/*.egg-info .pytest_cache
