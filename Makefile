# Set-up is part of every target: a fresh machine needs only python3 and make.
PY ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: demo test test-fast typecheck lint bench

$(STAMP): pyproject.toml setup.py
	test -x $(BIN)/python || $(PY) -m venv $(VENV)
	$(BIN)/python -m pip install -q --upgrade pip
	$(BIN)/python -m pip install -q -e '.[test]'
	touch $(STAMP)

demo: $(STAMP)
	$(BIN)/auvgw demo

test: $(STAMP)
	$(BIN)/ruff check .
	$(MAKE) --no-print-directory typecheck
	$(BIN)/python -m pytest -q --durations=20 -n 2 --dist loadscope

test-fast: $(STAMP)
	$(BIN)/ruff check .
	$(BIN)/python -m pytest -q -m "not e2e" -n 2 --dist loadscope

# mypy sees the installed package (a plain, non-editable copy: the editable install maps folders
# through an import hook no type checker follows); strict on ground/, drivers/, slam/ and control/ (pyproject.toml)
TYPED := $(VENV)/typecheck
typecheck: $(STAMP)
	rm -rf $(TYPED) build && $(BIN)/python -m pip install -q --no-deps --target $(TYPED) . >/dev/null
	cd $(TYPED) && $(CURDIR)/$(BIN)/mypy --config-file $(CURDIR)/pyproject.toml -p auvgw

lint: $(STAMP)
	$(BIN)/ruff check .

bench: $(STAMP)
	for b in benchmarks/bench_*.py; do $(BIN)/python $$b || exit 1; done
