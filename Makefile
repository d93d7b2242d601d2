# The two commands of the README: `make demo` and `make test`. Each creates the
# virtual environment and installs what it needs on a fresh machine.
PYTHON ?= python3
VENV ?= .venv
BIN := $(VENV)/bin

.PHONY: demo test test-fast lint clean

$(BIN)/cmrt: pyproject.toml
	@# Offscreen rendering without a GPU needs the OSMesa system library (Debian: libosmesa6).
	@if ! ldconfig -p | grep -q libOSMesa; then \
	  if command -v apt-get >/dev/null && [ "$$(id -u)" = 0 ]; then \
	    apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq libosmesa6 >/dev/null; \
	  else echo "note: libOSMesa not found and cannot be installed here: cmrt render/plot tests need it"; fi; \
	fi
	@# The dashboard's browser test drives Debian's chromium through its chromedriver (selenium, never a download).
	@if ! command -v chromium >/dev/null || ! command -v chromedriver >/dev/null; then \
	  if command -v apt-get >/dev/null && [ "$$(id -u)" = 0 ]; then \
	    apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium chromium-driver >/dev/null; \
	  else echo "note: chromium and chromedriver not found and cannot be installed here: the dashboard's browser test needs them"; fi; \
	fi
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[test]'
	touch $(BIN)/cmrt

demo: $(BIN)/cmrt
	$(BIN)/cmrt demo

# Python may write its bytecode caches whatever the shell says (PYTHONDONTWRITEBYTECODE made every test
# process recompile cmrt and pytest re-rewrite every test module's asserts: ~7 s of CPU per process).
PYTEST := env -u PYTHONDONTWRITEBYTECODE $(BIN)/python -m pytest

test: $(BIN)/cmrt
	$(BIN)/ruff check cmrt tests tools
	$(PYTEST) -q

# The quick loop while editing: everything but the tests marked slow (pyproject.toml), on every core
# (pytest-xdist): about 130 s on 2 cores. CI (`make test`) stays in one process.
test-fast: $(BIN)/cmrt
	$(PYTEST) -q -m "not slow" -n auto

clean:
	rm -rf $(VENV)
