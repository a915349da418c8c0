# relight - developer entry points. `make demo` and `make test` install on first use.
SHELL := /bin/bash
PYTHON ?= $(shell command -v python3.11 || command -v python3)
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: install install-system demo serve test test-slow test-all test-cpus lint clean
PORT ?= 8000
DEMO_BUNDLE := out/demo/face.bundle

install: $(STAMP)

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --upgrade pip
	$(BIN)/python -m pip install -e '.[test]'
	touch $(STAMP)

# System packages the tests drive (not on PyPI): Chromium for the browser page's test, QEMU's
# user-mode emulator for `make test-cpus`. Installs with Debian's apt when run as root; otherwise
# says what to install (those tests then skip).
install-system:
	@for pair in chromium:chromium qemu-x86_64:qemu-user; do \
	  cmd=$${pair%%:*}; pkg=$${pair##*:}; \
	  if command -v $$cmd >/dev/null 2>&1 || { [ $$cmd = chromium ] && command -v chromium-browser >/dev/null 2>&1; }; then \
	    echo "install-system: $$cmd present"; \
	  elif [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1; then \
	    export DEBIAN_FRONTEND=noninteractive; \
	    apt-get install -y -q $$pkg >/dev/null || { apt-get update -q >/dev/null && apt-get install -y -q $$pkg >/dev/null; }; \
	  else \
	    echo "install-system: $$cmd is missing; install the '$$pkg' package (its tests skip without it)" >&2; \
	  fi; \
	done

demo: $(STAMP)
	$(BIN)/relight demo

# The frame service on the bundle `make demo` built; it prints the browser page's URL once ready.
serve: $(STAMP)
	@test -f $(DEMO_BUNDLE) || { echo "make serve: $(DEMO_BUNDLE) is missing - run 'make demo' first" >&2; exit 1; }
	$(BIN)/relight-serve $(DEMO_BUNDLE) --port $(PORT)

# The suite on two worker processes (pytest-xdist). `make test` leaves out the tests marked
# slow (whole captures of phone-format videos and of the real face and RTI sets, the demo, the
# container's install, the longer browser and command runs: ~10 minutes more); `make test-slow`
# runs only those, `make test-all` everything. CI runs both.
PYTEST := $(BIN)/python -m pytest -n 2
test: $(STAMP)
	$(PYTEST) -m "not slow"

test-slow: $(STAMP)
	$(PYTEST) -m slow

test-all: $(STAMP)
	$(PYTEST)

# The kernels' tests on other CPUs than this one: PoCL compiles for the CPU it runs on and links
# the kernel library its features select (avx512, avx2, sse41, ...), so a result that depends on
# the vector width shows only on another machine type. QEMU's user-mode emulator plays the CPUs:
# Haswell (AVX2 + FMA: PoCL's avx2 library) and Nehalem (SSE4.2, no AVX or FMA: its sse41 library,
# the oldest NumPy's wheels run on). The shared test data are made natively first; under the
# emulator NumPy keeps to its baseline code (QEMU 7.2 mis-runs its AVX2 sort: a segfault, not a
# PoCL matter). ~4 min per CPU on 2 cores. Skips, saying so, without qemu-x86_64.
CPU_MODELS ?= Haswell-v4 Nehalem
CPU_TESTS := tests/test_kernels.py tests/test_recipe.py tests/test_reflectance.py tests/test_relight.py tests/test_spline.py \
	tests/test_bundle.py
CPU_SHARED := build/test-cpus/shared
test-cpus: $(STAMP)
	@if ! command -v qemu-x86_64 >/dev/null 2>&1; then \
	  echo "test-cpus: SKIPPED - qemu-x86_64 is missing: make install-system (Debian's qemu-user) as root" >&2; \
	  exit 0; \
	fi; \
	set -e; rm -rf build/test-cpus && mkdir -p $(CPU_SHARED); \
	echo "== the kernels' tests natively (the shared test data made here)"; \
	RELIGHT_TEST_SHARED=$(CURDIR)/$(CPU_SHARED) $(PYTEST) -q $(CPU_TESTS); \
	for cpu in $(CPU_MODELS); do \
	  echo "== the kernels' tests on an emulated $$cpu"; \
	  RELIGHT_TEST_SHARED=$(CURDIR)/$(CPU_SHARED) POCL_CACHE_DIR=$(CURDIR)/build/test-cpus/pocl-$$cpu \
	  NPY_DISABLE_CPU_FEATURES="X86_V3 X86_V4 AVX512_ICL AVX512_SPR" \
	  qemu-x86_64 -cpu $$cpu $(BIN)/python -W ignore::ImportWarning -m pytest -q -p no:cacheprovider -p no:xdist \
	    $(CPU_TESTS) 2> >(grep -v "^qemu-x86_64: warning: TCG doesn't support" >&2); \
	done

# ruff, then the architecture's import contracts ([tool.importlinter] in pyproject.toml). The
# package's folders are mapped onto `relight.*` (pyproject's package-dir), which import-linter
# cannot follow: it reads a tree of links laid out as the installed package.
LINT_TREE := build/lint-tree
lint: $(STAMP)
	$(BIN)/ruff check .
	@rm -rf $(LINT_TREE) && mkdir -p $(LINT_TREE)/relight
	@for f in relight/*.py; do ln -s ../../../$$f $(LINT_TREE)/relight/; done
	@for d in cli pipeline kernels engine service apps bench; do ln -s ../../../$$d $(LINT_TREE)/relight/$$d; done
	cd $(LINT_TREE) && PYTHONPATH=. ../../$(BIN)/lint-imports ../../pyproject.toml

clean:
	rm -rf $(VENV) out build *.egg-info
