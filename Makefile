# The README's two commands: `make run` and `make test`. Both create .venv from python3 when it is
# missing and (re)install the project when its packaging files change.
PYTHON ?= python3
comma  := ,
VENV   := .venv
BIN    := $(VENV)/bin
HOST   ?= 127.0.0.1
PORT   ?= 8000
# PyGObject (the Aravis extra) builds against system libraries; install it only where they exist.
ARAVIS_EXTRA := $(shell pkg-config --exists gobject-introspection-1.0 cairo 2>/dev/null && echo ",aravis")
# The stamp names the extras, so installing the Aravis system packages later triggers a reinstall.
STAMP  := $(VENV)/.installed$(subst $(comma),-,$(ARAVIS_EXTRA))
PYTEST_WORKERS ?= 2

.PHONY: run test bench clean install

$(BIN)/python:
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip

$(STAMP): pyproject.toml setup.py | $(BIN)/python
	$(BIN)/python -m pip install --quiet -e ".[test,cluster$(ARAVIS_EXTRA)]"
	touch $(STAMP)

install: $(STAMP)

# The daemon on the embedded default, the virtual rig, at http://$(HOST):$(PORT) (DESIGN.md).
run: $(STAMP)
	$(BIN)/python -m graytrack serve --host $(HOST) --port $(PORT)

test: $(STAMP)
	$(BIN)/python -m pytest -n $(PYTEST_WORKERS) $(PYTEST_ARGS)

bench: $(STAMP)
	for script in bench/*.py; do echo "== $$script"; $(BIN)/python $$script || exit 1; done

clean:
	rm -rf $(VENV) build *.egg-info .pytest_cache
