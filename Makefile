# lumigraph: `make demo` (set-up + the main job on the default scene), `make test` (set-up + all tests).
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed-stamp
# nerfstudio's own dataparsers for the conformance tests (tests/pipeline/test_export.py)
CONFORMANCE := $(VENV)/.conformance-stamp
SCENE  ?= turntable
export PYOPENGL_PLATFORM := egl

.PHONY: install setup demo test bench repro lock clean

install: $(STAMP) $(CONFORMANCE)

# the renderers' numba kernels compiled ahead of first use (once per source tree: a marker in the
# cache folder, keyed by render/'s sources, makes later runs a no-op), then the path tracer's kernels
# as an extension that imports without numba (render/path_aot_build.py; a failed build keeps the JIT);
# then our modules' bytecode, as pip writes it for an installed package (an editable install does
# not, and with PYTHONDONTWRITEBYTECODE set every command would compile them again: ~0.1 s a run)
setup: install
	$(BIN)/python -m pipeline.warm_kernels
	$(BIN)/python -m compileall -q -j 0 pipeline rig recon render bench > /dev/null

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

# the demo runs the stages dvc.yaml wires, with params.yaml's values; for the default scene it then
# records what each stage wrote in dvc.lock (dvc commit), so `dvc status` is up to date afterwards
# (`lumigraph run` compiles the kernels of the reference's integrator in the background while the
# capture renders: on a fresh clone nothing else waits for numba)
demo: install
	$(BIN)/lumigraph run $(SCENE)
	if [ "$(SCENE)" = "$$(sed -n 's/^scene: *//p' params.yaml)" ]; then $(BIN)/dvc commit -f -q; fi

# regenerate dvc.lock from a fresh run of the default scene (commit it with the code it hashes)
lock: setup
	$(BIN)/lumigraph run $$(sed -n 's/^scene: *//p' params.yaml) --overwrite
	$(BIN)/dvc commit -f -q

test: setup
	$(BIN)/python -m pytest -q tests

# the benchmarks against Mitsuba 3 need the bench extra (an independent production renderer)
bench: setup
	$(BIN)/python -m pip install -q -e '.[bench]'
	$(BIN)/python -m bench.run_all

# the DVC pipeline, with the venv's lumigraph on PATH (local cache only)
repro: setup
	PATH="$(CURDIR)/$(BIN):$$PATH" $(BIN)/dvc repro

clean:
	rm -rf artifacts bench/results
