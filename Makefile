# zenoh-nc: `make demo` runs the NC server plus a PLC program; `make test` runs every test.
PYTHON ?= python3
VENV   ?= .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed

.PHONY: venv demo test test-core bench clean

venv: $(STAMP)

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip install -q -e '.[dev]'
	touch $(STAMP)

demo: $(STAMP)
	$(VENV)/bin/zenoh-nc-demo $(DEMO_ARGS)

test: $(STAMP)
	$(PY) -m pytest $(PYTEST_ARGS)

test-core: $(STAMP)
	$(PY) -m pytest tests/core tests/schema tests/plc $(PYTEST_ARGS)

bench: $(STAMP)
	$(PY) bench/nc_cycle.py
	$(PY) bench/command_rtt.py
	$(PY) bench/fb_latency.py

clean:
	rm -rf $(VENV) build *.egg-info .pytest_cache
