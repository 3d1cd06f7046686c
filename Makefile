# neuralcol — developer entry points. `make help` lists them.
PY      ?= python3
VENV    ?= .venv
BIN     := $(VENV)/bin
PYTHON  := $(BIN)/python
# CPU build of torch: on the project machines this version lies on disk, so it installs offline and
# cheaply. Elsewhere, point pip at a CPU wheel index (PIP_INDEX_URL / PIP_EXTRA_INDEX_URL) or override
# TORCH, e.g. `make install TORCH="torch==2.5.1"`.
TORCH   ?= torch==2.13.0
STAMP   := $(VENV)/.installed
ARGS    ?=

.PHONY: help install lint test test-full run sweep bench bench-quick gpu-check clean

help:  ## list the targets
	@grep -E '^[a-z-]+:.*## ' $(MAKEFILE_LIST) | awk -F':.*## ' '{printf "  %-12s %s\n", $$1, $$2}'

$(STAMP): pyproject.toml
	test -x $(PYTHON) || $(PY) -m venv $(VENV)
	$(PYTHON) -m pip install --quiet --upgrade pip
	$(PYTHON) -c "import torch" 2>/dev/null || $(PYTHON) -m pip install "$(TORCH)"
	$(PYTHON) -m pip install --quiet -e ".[dev,export,body]"
	touch $(STAMP)

install: $(STAMP)  ## create .venv with a CPU torch and install neuralcol (editable, dev and export extras)

lint: $(STAMP)  ## ruff
	$(BIN)/ruff check neuralcol experiments tests bench research

# test files run on this many pytest workers (pytest-xdist; one file per worker, one thread per worker:
# tests/conftest.py). TEST_WORKERS=0 runs them in this process.
TEST_WORKERS ?= 2
XDIST   := $(if $(filter 0,$(TEST_WORKERS)),,-n $(TEST_WORKERS) --dist loadfile)

test: $(STAMP)  ## fast test suite (excludes `slow`)
	$(PYTHON) -m pytest -m "not slow" -q $(XDIST) $(ARGS)

test-full: $(STAMP)  ## every test, slow ones included
	$(PYTHON) -m pytest -q $(XDIST) $(ARGS)

run: $(STAMP)  ## main job on the embedded procedural data set (proc_hand)
	$(PYTHON) -m experiments.run $(ARGS)

bench: $(STAMP)  ## benchmarks -> bench/results.json, bench/results.md
	$(PYTHON) -m bench.run $(ARGS)

bench-quick: $(STAMP)  ## fewer repetitions, for development
	$(PYTHON) -m bench.run --quick $(ARGS)

gpu-check: $(STAMP)  ## GPU kit, <= 9 min on CUDA -> bench/gpu/ (no CUDA: CPU dry run); docs/gpu.md
	$(PYTHON) -m bench.gpu_check $(ARGS)

clean:  ## remove caches and outputs (keeps .venv and data/)
	rm -rf outputs multirun .pytest_cache .ruff_cache bench/tmp
	find . -name __pycache__ -type d -prune -not -path './$(VENV)/*' -exec rm -rf {} +
