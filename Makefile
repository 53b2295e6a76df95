# Two commands for a fresh machine:
#   make demo   set everything up and run the demo on the simulated thesis robot
#   make test   set everything up and run all tests (what CI runs)
#   make test-repeat N=5 K=EXPR   rerun the tests pytest -k EXPR selects N times (flake hunting;
#                                 ARGS="-n 4 --dist loadgroup" repeats them in parallel workers)
PYTHON ?= python3
VENV   ?= .venv
BIN    := $(VENV)/bin
DEMO_ARGS ?=
N ?= 5
K ?=
ARGS ?=

.PHONY: setup system-deps demo test test-repeat lint clean

$(BIN)/blackbox: pyproject.toml
	scripts/setup.sh $(PYTHON) $(VENV)

setup: $(BIN)/blackbox

system-deps:
	scripts/install-system-deps.sh

demo: setup
	$(BIN)/blackbox demo $(DEMO_ARGS)

test: setup system-deps
	VENV=$(VENV) scripts/test.sh

# Stops at the first failing run and names it; pytest's exit code 5 (nothing selected) is an
# error too, so a mistyped K cannot pass N times by running nothing.
test-repeat: setup
	@test -n "$(K)" || { echo "usage: make test-repeat N=5 K='pytest -k expression'" >&2; exit 2; }
	@for i in $$(seq 1 $(N)); do \
		echo "test-repeat: run $$i of $(N), -k '$(K)'"; \
		$(BIN)/python -m pytest -q -x -k "$(K)" $(ARGS); rc=$$?; \
		if [ $$rc -eq 5 ]; then echo "test-repeat: no test matches -k '$(K)'" >&2; exit 2; fi; \
		if [ $$rc -ne 0 ]; then echo "test-repeat: run $$i of $(N) failed (-k '$(K)')" >&2; exit 1; fi; \
	done; \
	echo "test-repeat: all $(N) runs passed (-k '$(K)')"

lint: setup
	$(BIN)/ruff check src tests benchmarks
	$(BIN)/mypy

clean:
	rm -rf $(VENV) build src/*.egg-info .pytest_cache
