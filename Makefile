# Two commands on a fresh machine (Python >= 3.11):
#   make run    builds the virtual environment and runs the demo (daemon + embedded Zenoh router)
#   make test   builds the virtual environment and runs the test suite
PYTHON ?= python3
VENV   ?= .venv
BIN     = $(VENV)/bin

.PHONY: run test bench report clean

$(VENV)/.installed: pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e ".[test]"
	touch $@

run: $(VENV)/.installed
	$(BIN)/radar-fusion demo

test: $(VENV)/.installed
	$(BIN)/python -m pytest -q

bench: $(VENV)/.installed
	$(BIN)/radar-fusion bench

report: $(VENV)/.installed
	$(BIN)/radar-fusion bench --report reports/bench

clean:
	rm -rf $(VENV) out reports .pytest_cache
