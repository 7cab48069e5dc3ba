# evfuse: `make demo` sets up and runs the whole pipeline (simulate, map, fill, score) on the
# default scene; `make test` sets up and runs the tests; `make docs` builds the documentation
# site into site/ (strict: a warning is an error).
SHELL := /bin/bash
PYTHON ?= $(shell command -v python3.11 || command -v python3)
VENV := .venv
BIN := $(VENV)/bin
# pytest-xdist workers of `make test`: the development machine's 2 cores (each worker loads
# Mitsuba and Dr.Jit, about 1 GB; `make test TEST_WORKERS=0` runs in one process).
TEST_WORKERS ?= 2
DEMO_SCENE ?= complex_sphere
DEMO_OUT ?= runs/demo
DEMO_T0 ?= 1.0
DEMO_T1 ?= 3.0

.PHONY: setup llvm demo test docs bench lint clean

setup: $(VENV)/.installed llvm

$(VENV)/.installed: pyproject.toml
	@$(PYTHON) -c 'import sys; assert sys.version_info >= (3, 11), "evfuse needs Python >= 3.11"'
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[test]'
	@touch $@

# The documentation's tools (MkDocs-Material, mkdocstrings, matplotlib for the benchmark plots).
$(VENV)/.installed-docs: $(VENV)/.installed pyproject.toml
	$(BIN)/python -m pip install --quiet -e '.[test,docs]'
	@touch $@

# Mitsuba's llvm_ad_rgb variant needs LLVM >= 16 (Dr.Jit 1.5). Debian/Ubuntu ship libllvm19.
# The probe is evfuse's own (sim/variant.py: find_llvm_libraries, the standard library only), so
# that make and evfuse agree on what is installed.
LLVM_PROBE := $(PYTHON) -c 'import runpy, sys; sys.argv[1:] = ["--find-llvm"]; runpy.run_path("sim/variant.py", run_name="__main__")'
llvm:
	@if found="$$($(LLVM_PROBE) 2>/dev/null)"; then \
	  echo "LLVM >= 16 present ($$found): Mitsuba's llvm_ad_rgb variant can be used"; \
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
	$(BIN)/python -m pytest -q -n $(TEST_WORKERS)

# The benchmark page and the changelog page are generated into docs/generated/ (ignored) from
# benchmarks/results/*.json and CHANGELOG.md, then MkDocs builds the site strictly.
DOCS_OUT ?= site
docs: $(VENV)/.installed-docs
	$(BIN)/python -m benchmarks.report --out docs/generated
	cp CHANGELOG.md docs/generated/changelog.md
	NO_MKDOCS_2_WARNING=1 $(BIN)/mkdocs build --strict --site-dir $(DOCS_OUT)
	@echo "documentation written to $(DOCS_OUT)/index.html"

bench: setup
	$(BIN)/python -m benchmarks.bench_render
	$(BIN)/python -m benchmarks.bench_shader
	$(BIN)/python -m benchmarks.bench_sampling --quick
	$(BIN)/python -m benchmarks.bench_sampling --agreement
	$(BIN)/python -m benchmarks.bench_events
	$(BIN)/python -m benchmarks.bench_emvs
	$(BIN)/python -m benchmarks.bench_fill
	$(BIN)/python -m benchmarks.bench_generate --quick

lint: setup
	$(BIN)/ruff check .

clean:
	rm -rf $(VENV) runs site docs/generated .pytest_cache .ruff_cache *.egg-info
