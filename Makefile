# relight - developer entry points. `make demo` and `make test` install on first use.
PYTHON ?= $(shell command -v python3.11 || command -v python3)
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: install install-system demo serve test test-slow test-all lint clean
PORT ?= 8000
DEMO_BUNDLE := out/demo/face.bundle

install: $(STAMP)

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --upgrade pip
	$(BIN)/python -m pip install -e '.[test]'
	touch $(STAMP)

# System packages the tests drive (not on PyPI): Chromium for the browser page's test. Installs
# with Debian's apt when run as root; otherwise says what to install (the test then skips).
install-system:
	@if command -v chromium >/dev/null 2>&1 || command -v chromium-browser >/dev/null 2>&1; then \
	  echo "install-system: chromium present"; \
	elif [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1; then \
	  export DEBIAN_FRONTEND=noninteractive; \
	  apt-get install -y -q chromium >/dev/null || { apt-get update -q >/dev/null && apt-get install -y -q chromium >/dev/null; }; \
	else \
	  echo "install-system: Chromium is missing; install the 'chromium' package (the browser test skips without it)" >&2; \
	fi

demo: $(STAMP)
	$(BIN)/relight demo

# The frame service on the bundle `make demo` built; it prints the browser page's URL once ready.
serve: $(STAMP)
	@test -f $(DEMO_BUNDLE) || { echo "make serve: $(DEMO_BUNDLE) is missing - run 'make demo' first" >&2; exit 1; }
	$(BIN)/relight-serve $(DEMO_BUNDLE) --port $(PORT)

# The suite on two worker processes (pytest-xdist). `make test` leaves out the tests marked
# slow (whole captures of phone-format videos, the demo, the container's install, the real RTI
# set: ~4 minutes more); `make test-slow` runs only those, `make test-all` everything. CI runs both.
PYTEST := $(BIN)/python -m pytest -n 2
test: $(STAMP)
	$(PYTEST) -m "not slow"

test-slow: $(STAMP)
	$(PYTEST) -m slow

test-all: $(STAMP)
	$(PYTEST)

# ruff, then the architecture's import contracts ([tool.importlinter] in pyproject.toml). The
# package's folders are mapped onto `relight.*` (pyproject's package-dir), which import-linter
# cannot follow: it reads a tree of links laid out as the installed package.
LINT_TREE := build/lint-tree
lint: $(STAMP)
	$(BIN)/ruff check .
	@rm -rf $(LINT_TREE) && mkdir -p $(LINT_TREE)/relight
	@for f in relight/*.py; do ln -s ../../../$$f $(LINT_TREE)/relight/; done
	@for d in pipeline kernels service bench; do ln -s ../../../$$d $(LINT_TREE)/relight/$$d; done
	cd $(LINT_TREE) && PYTHONPATH=. ../../$(BIN)/lint-imports ../../pyproject.toml

clean:
	rm -rf $(VENV) out build *.egg-info
