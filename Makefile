# lumigraph: `make demo` (set-up + the main job on the default scene), `make test` (set-up + all tests).
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed-stamp
SCENE  ?= turntable
export PYOPENGL_PLATFORM := egl

.PHONY: setup demo test bench repro clean

setup: $(STAMP)

$(STAMP): pyproject.toml scripts/install-system-deps.sh
	./scripts/install-system-deps.sh
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install -q --upgrade pip
	# torch is pinned to the CPU wheel (torch==2.13.0) in pyproject.toml
	$(BIN)/python -m pip install -q -e '.[dev]'
	touch $(STAMP)

demo: setup
	$(BIN)/lumigraph run $(SCENE)

test: setup
	$(BIN)/python -m pytest -q tests

bench: setup
	$(BIN)/python -m bench.run_all

# the DVC pipeline, with the venv's lumigraph on PATH (local cache only)
repro: setup
	PATH="$(CURDIR)/$(BIN):$$PATH" $(BIN)/dvc repro

clean:
	rm -rf artifacts bench/results
