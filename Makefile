PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin

.PHONY: demo test lint clean

$(BIN)/hamgrav: pyproject.toml
	@$(PYTHON) -c 'import sys; sys.exit(sys.version_info < (3, 11))' 2>/dev/null || { echo "error: hamgrav needs Python >= 3.11 and '$(PYTHON)' is missing or older; run 'make PYTHON=/path/to/python3.11 ...'"; exit 1; }
	test -d $(VENV) || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e ".[test]"
	touch $(BIN)/hamgrav

demo: $(BIN)/hamgrav
	$(BIN)/hamgrav demo

test: $(BIN)/hamgrav
	$(BIN)/python -m pytest -q

lint: $(BIN)/hamgrav
	$(BIN)/ruff check src tests bench
	$(BIN)/ruff format --check src tests bench

clean:
	rm -rf $(VENV) demo-output .pytest_cache
