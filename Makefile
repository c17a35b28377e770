# dlo-service: `make run` starts the detection service (HTTP + zenoh), `make demo` runs the
# demo on a generated scene, `make test` the test suite.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
INSTALLED := $(VENV)/.installed

.PHONY: run demo test lint venv clean distclean

# Host, port, workers and zenoh come from the DLO_* environment (see the README), e.g.
# `DLO_PORT=8080 make run`; the defaults listen on 127.0.0.1:8000.
run: venv
	$(BIN)/dlo serve

demo: venv
	$(BIN)/dlo demo --out-dir out/demo

test: venv
	$(BIN)/python -m pytest -q

lint: venv
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .

venv: $(INSTALLED)

$(BIN)/python:
	$(PYTHON) -m venv $(VENV)

# Reinstall only when pyproject.toml changed since the last install.
$(INSTALLED): pyproject.toml | $(BIN)/python
	$(BIN)/python -m pip install -e '.[dev]'
	touch $@

clean:
	rm -rf out .pytest_cache .ruff_cache *.egg-info
	find . -path ./$(VENV) -prune -o -type d -name __pycache__ -exec rm -rf {} +

distclean: clean
	rm -rf $(VENV)
