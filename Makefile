# dlo-service: `make run` starts the detection service (HTTP + zenoh), `make demo` runs the
# demo on a generated scene, `make test` the test suite.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
INSTALLED := $(VENV)/.installed
# The kernels compiled ahead of time (python -m service.build_kernels): their manifest,
# rebuilt when a kernel file, the build's code or the install changes (the build itself
# checks the manifest's key). A failed build (no C compiler) warns and leaves numba's JIT in use.
KERNEL_SOURCES := $(wildcard service/perception/_*_kernels.py) service/perception/_aot.py \
	service/build_kernels.py
AOT_MANIFEST := service/perception/__pycache__/dlo-kernels-aot.json

.PHONY: run demo test lint venv kernels clean distclean

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

venv: $(INSTALLED) kernels

kernels: $(AOT_MANIFEST)

$(AOT_MANIFEST): $(KERNEL_SOURCES) $(INSTALLED)
	$(BIN)/python -m service.build_kernels || \
	  echo "make: kernels not compiled ahead of time; numba's JIT stays in use" >&2

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
