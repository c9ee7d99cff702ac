# lumigraph: `make demo` (set-up + the main job on the default scene), `make test` (set-up + all tests).
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed-stamp
# nerfstudio's own dataparsers for the conformance tests (tests/pipeline/test_export.py)
CONFORMANCE := $(VENV)/.conformance-stamp
SCENE  ?= turntable
export PYOPENGL_PLATFORM := egl

.PHONY: setup demo test bench repro clean

setup: $(STAMP) $(CONFORMANCE)

$(STAMP): pyproject.toml scripts/install-system-deps.sh
	./scripts/install-system-deps.sh
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install -q --upgrade pip
	# torch is pinned to the CPU wheel (torch==2.13.0) in pyproject.toml
	$(BIN)/python -m pip install -q -e '.[dev]'
	touch $(STAMP)

# nerfstudio without its dependencies (viewer, training loggers, gsplat: hundreds of MB, some not on
# PyPI for this machine): its parsers need only torch, numpy, PIL, imageio, cv2, rich and jaxtyping
$(CONFORMANCE): $(STAMP)
	$(BIN)/python -m pip install -q --no-deps nerfstudio==1.1.5 jaxtyping==0.3.11 wadler_lindig==0.1.8
	touch $(CONFORMANCE)

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
