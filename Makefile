# evfuse: `make demo` sets up and runs the whole pipeline (simulate, map, fill, score) on the
# default scene; `make test` sets up and runs the tests.
SHELL := /bin/bash
PYTHON ?= $(shell command -v python3.11 || command -v python3)
VENV := .venv
BIN := $(VENV)/bin
DEMO_SCENE ?= complex_sphere
DEMO_OUT ?= runs/demo
DEMO_T0 ?= 1.0
DEMO_T1 ?= 3.0

.PHONY: setup llvm demo test bench lint clean

setup: $(VENV)/.installed llvm

# opencv-contrib-python-headless replaced opencv-python-headless. Both wheels own cv2/, so in a
# venv that still has the old one, it is removed and the contrib wheel's files (the same paths,
# just deleted) are put back, at the version already installed.
$(VENV)/.installed: pyproject.toml
	@$(PYTHON) -c 'import sys; assert sys.version_info >= (3, 11), "evfuse needs Python >= 3.11"'
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[test]'
	@if $(BIN)/python -m pip show opencv-python-headless >/dev/null 2>&1; then \
	  $(BIN)/python -m pip uninstall --quiet --yes opencv-python-headless && \
	  $(BIN)/python -m pip install --quiet --force-reinstall --no-deps \
	    "opencv-contrib-python-headless==$$($(BIN)/python -m pip show opencv-contrib-python-headless | sed -n 's/^Version: //p')"; \
	fi
	@touch $@

# Mitsuba's llvm_ad_rgb variant needs LLVM >= 16 (Dr.Jit 1.5). Debian/Ubuntu ship libllvm19.
llvm:
	@if ls /usr/lib/*/libLLVM-1[6-9]*.so* /usr/lib/*/libLLVM-2[0-9]*.so* /usr/lib/llvm-1[6-9]/lib/libLLVM*.so* >/dev/null 2>&1; then \
	  echo "LLVM >= 16 present: Mitsuba's llvm_ad_rgb variant can be used"; \
	elif ! command -v apt-get >/dev/null 2>&1; then \
	  echo "No LLVM >= 16 found and no apt-get: install LLVM >= 16 and set DRJIT_LIBLLVM_PATH, or evfuse renders on scalar_rgb (much slower)"; \
	elif [ "$$(id -u)" = 0 ]; then \
	  (apt-get install -y -q libllvm19 || (apt-get update -q && apt-get install -y -q libllvm19)) >/dev/null \
	    && echo "installed libllvm19" || echo "could not install libllvm19: evfuse will render on scalar_rgb (much slower)"; \
	elif command -v sudo >/dev/null 2>&1 && sudo -n true 2>/dev/null; then \
	  (sudo apt-get install -y -q libllvm19 || (sudo apt-get update -q && sudo apt-get install -y -q libllvm19)) >/dev/null \
	    && echo "installed libllvm19" || echo "could not install libllvm19: evfuse will render on scalar_rgb (much slower)"; \
	else \
	  echo "No LLVM >= 16 found. Run 'sudo apt-get install libllvm19' for fast rendering; until then evfuse renders on scalar_rgb (much slower)"; \
	fi

# Replaces $(DEMO_OUT) (only once the new run is complete).
demo: setup
	$(BIN)/evfuse run $(DEMO_SCENE) --t0 $(DEMO_T0) --t1 $(DEMO_T1) --out $(DEMO_OUT) --overwrite

test: setup
	$(BIN)/python -m pytest -q

bench: setup
	$(BIN)/python benchmarks/bench_render.py
	$(BIN)/python benchmarks/bench_shader.py
	$(BIN)/python benchmarks/bench_sampling.py
	$(BIN)/python benchmarks/bench_events.py
	$(BIN)/python benchmarks/bench_emvs.py
	$(BIN)/python benchmarks/bench_fill.py

lint: setup
	$(BIN)/ruff check .

clean:
	rm -rf $(VENV) runs .pytest_cache .ruff_cache *.egg-info
