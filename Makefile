# The two commands of the README: `make demo` and `make test`. Each creates the
# virtual environment and installs what it needs on a fresh machine.
PYTHON ?= python3
VENV ?= .venv
BIN := $(VENV)/bin

.PHONY: demo test lint clean

$(BIN)/cmrt: pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[test]'
	touch $(BIN)/cmrt

demo: $(BIN)/cmrt
	$(BIN)/cmrt demo

test: $(BIN)/cmrt
	$(BIN)/ruff check cmrt tests tools
	$(BIN)/python -m pytest -q

clean:
	rm -rf $(VENV)
