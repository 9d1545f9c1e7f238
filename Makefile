# Two entry points (see README): `make run` and `make test`. Both create .venv with pinned versions when missing.
# `make test-fast` is the loop to run while working: the suite less its slow tier (tests/README.md).
PY ?= python3
VENV := .venv
BIN := $(VENV)/bin
# pytest-xdist gives each test file to one worker per core, in the order tests/conftest.py sets.
PYTEST := $(BIN)/python -m pytest -q -rs -n auto --dist loadfile --no-loadscope-reorder

$(BIN)/.installed: pyproject.toml constraints.txt
	test -x $(BIN)/python || $(PY) -m venv $(VENV)
	$(BIN)/python -m pip install -q --upgrade pip
	$(BIN)/python -m pip install -q -c constraints.txt -e ".[test]"
	touch $@

# On an NVIDIA GPU machine: the same .venv plus a CUDA 13 build of JAX and MuJoCo Warp (README "On a GPU").
$(BIN)/.installed-cuda: $(BIN)/.installed
	$(BIN)/python -m pip install -q -c constraints.txt -e ".[test,cuda]"
	touch $@

.PHONY: run test test-fast lint gpu
gpu: $(BIN)/.installed-cuda
	$(BIN)/angora-jax doctor
run: $(BIN)/.installed
	$(BIN)/angora-jax train cartpole

test: $(BIN)/.installed
	$(BIN)/ruff check .
	$(PYTEST) --durations=15

test-fast: $(BIN)/.installed
	$(BIN)/ruff check .
	$(PYTEST) -m "not slow" --durations=10

lint: $(BIN)/.installed
	$(BIN)/ruff check .
