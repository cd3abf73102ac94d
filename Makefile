# Two commands on a fresh machine (Python >= 3.11):
#   make run    builds the virtual environment and runs the demo (daemon + embedded Zenoh router)
#   make test   builds the virtual environment and runs the test suite (every tier)
# and, while working:
#   make test-fast   the fast tier: no Zenoh session, nothing slow (about 1 min 45 s on 2 cores)
#   make lint        ruff check, ruff format --check and mypy (what .ci/run runs before the tests)
PYTHON ?= python3
VENV   ?= .venv
BIN     = $(VENV)/bin
TYPECHECK_TREE = build/typecheck

.PHONY: install run test test-fast lint bench report clean

$(VENV)/.installed: pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e ".[test]"
	touch $@

install: $(VENV)/.installed

run: $(VENV)/.installed
	$(BIN)/radar-fusion demo

test: $(VENV)/.installed
	$(BIN)/python -m pytest -q

test-fast: $(VENV)/.installed
	$(BIN)/python -m pytest -q -m "not bus and not slow"

# All three run, so one pass shows every finding; the target fails if any of them failed.
# mypy checks radar_fusion as it is installed (tools/ as radar_fusion.tools): a tree of
# symlinks, laid anew each time, with its paths printed back as the files they point to.
lint: $(VENV)/.installed
	@status=0; \
	$(BIN)/ruff check . || status=1; \
	$(BIN)/ruff format --check . || status=1; \
	rm -rf $(TYPECHECK_TREE) && mkdir -p $(TYPECHECK_TREE) && \
	cp -rs "$(CURDIR)/service/radar_fusion" $(TYPECHECK_TREE)/ && \
	cp -rs "$(CURDIR)/tools" $(TYPECHECK_TREE)/radar_fusion/tools || status=1; \
	$(BIN)/mypy > $(TYPECHECK_TREE).mypy.txt 2>&1 || status=1; \
	sed -e 's#^$(TYPECHECK_TREE)/radar_fusion/tools/#tools/#' \
	    -e 's#^$(TYPECHECK_TREE)/radar_fusion/#service/radar_fusion/#' $(TYPECHECK_TREE).mypy.txt; \
	exit $$status

bench: $(VENV)/.installed
	$(BIN)/radar-fusion bench

report: $(VENV)/.installed
	$(BIN)/radar-fusion bench --report reports/bench

clean:
	rm -rf $(VENV) out reports build .pytest_cache .mypy_cache .ruff_cache
