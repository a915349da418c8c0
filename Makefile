# relight - developer entry points. `make demo` and `make test` install on first use.
PYTHON ?= $(shell command -v python3.11 || command -v python3)
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: install demo serve test lint clean
PORT ?= 8000
DEMO_BUNDLE := out/demo/face.bundle

install: $(STAMP)

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --upgrade pip
	$(BIN)/python -m pip install -e '.[test]'
	touch $(STAMP)

demo: $(STAMP)
	$(BIN)/relight demo

# The frame service on the bundle `make demo` built; it prints the browser page's URL once ready.
serve: $(STAMP)
	@test -f $(DEMO_BUNDLE) || { echo "make serve: $(DEMO_BUNDLE) is missing - run 'make demo' first" >&2; exit 1; }
	$(BIN)/relight-serve $(DEMO_BUNDLE) --port $(PORT)

test: $(STAMP)
	$(BIN)/python -m pytest

lint: $(STAMP)
	$(BIN)/ruff check .

clean:
	rm -rf $(VENV) out build *.egg-info
