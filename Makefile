# The environment lives in .venv/ and is (re)built when pyproject.toml changes.
PYTHON ?= python3.11
VENV := .venv
STAMP := $(VENV)/.installed

.PHONY: demo test lint docs bench clean

$(STAMP): pyproject.toml
	@test -x $(VENV)/bin/python || $(PYTHON) -m venv $(VENV) || python3 -m venv $(VENV)
	$(VENV)/bin/python -m pip install -q --upgrade pip
	$(VENV)/bin/python -m pip install -q -e '.[dev]'
	$(VENV)/bin/python -m pip install -q --no-deps 'bpy==4.5.*' zstandard
	@touch $(STAMP)

demo: $(STAMP)
	$(VENV)/bin/kdfaces demo --out kd-out/demo

lint: $(STAMP)
	$(VENV)/bin/ruff check .

# The API reference (Sphinx); warnings are errors.
docs: $(STAMP)
	$(VENV)/bin/sphinx-build -W --keep-going -b html docs docs/_build/html

# The docs build is part of the tests: from scratch (-E), so a warning in an unchanged page still fails it.
test: $(STAMP)
	$(VENV)/bin/ruff check .
	$(VENV)/bin/sphinx-build -W --keep-going -E -q -b html docs docs/_build/test-html
	$(VENV)/bin/python -m pytest

bench: $(STAMP)
	$(VENV)/bin/python scripts/bench.py

clean:
	rm -rf kd-out .pytest_cache docs/_build
