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
# `make run` installs what running needs (the daemon extra: the numerical stack; `pip install .` alone is the
# client, docs/clients.md), nothing for the tests (no pytest, no playwright).
RUN_EXTRAS := [daemon$(ARAVIS_EXTRA)]
RUN_STAMP  := $(VENV)/.run-installed$(subst $(comma),-,$(ARAVIS_EXTRA))
# `make service-venv`: a non-editable install for the systemd unit (deploy/graytrack.service).
PREFIX ?= /opt/graytrack
PYTEST_WORKERS ?= 2

.PHONY: run test unit lint bench clean install service-venv docs-images

$(BIN)/python:
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip

$(STAMP): pyproject.toml setup.py | $(BIN)/python
	$(BIN)/python -m pip install --quiet -e ".[daemon,test,cluster$(ARAVIS_EXTRA)]"
	touch $(STAMP)

install: $(STAMP)

$(RUN_STAMP): pyproject.toml setup.py | $(BIN)/python
	$(BIN)/python -m pip install --quiet -e ".$(RUN_EXTRAS)"
	touch $(RUN_STAMP)

# The daemon on the embedded default, the virtual rig, at http://$(HOST):$(PORT).
run: $(RUN_STAMP)
	$(BIN)/python -m graytrack serve --host $(HOST) --port $(PORT)

# A venv of its own for the service, with graytrack installed from this checkout as a package
# (not editable: the service keeps running whatever happens to the checkout). README, "Install as a service".
service-venv:
	$(PYTHON) -m venv $(PREFIX)/.venv
	$(PREFIX)/.venv/bin/python -m pip install --quiet --upgrade pip
	$(PREFIX)/.venv/bin/python -m pip install --quiet "$(CURDIR)$(RUN_EXTRAS)"
	install -m 0644 README.md $(PREFIX)/README.md

# docs/page.png (the status page) and docs/report.png (a calibration's error plot), made from a live daemon.
docs-images: $(STAMP)
	$(BIN)/python docs/make_images.py

# ruff over the tree, mypy over core/ ([tool.ruff], [tool.mypy] in pyproject.toml); ~1 s once mypy's cache is warm.
# mypy reads core/ as graytrack.core through a link under build/typing: setuptools' editable finder maps the
# package onto the folder at import time, which a type checker cannot follow. Its paths are shown as core/….
TYPING := build/typing/graytrack
lint: $(STAMP)
	$(BIN)/ruff check --quiet .
	@mkdir -p $(TYPING) && ln -sfn ../../../core $(TYPING)/core && ln -sf ../../../graytrack/__init__.py $(TYPING)/
	@$(BIN)/mypy > build/mypy.out; status=$$?; sed 's|^$(TYPING)/||' build/mypy.out; exit $$status

# Both parts always run (a failure in the first still shows the second's), and either failing fails the target.
# worksteal: each worker starts on one half of the suite in order (a module's shared daemon or recording is made
# on one worker, not on both as tests are dealt out one by one), and takes from the other's when its half is done.
# Bytecode caches on for the tests, whatever the environment says (an empty PYTHONDONTWRITEBYTECODE is unset):
# without them every process compiles what it imports from the checkout, and pytest rewrites the asserts of all
# ~270 test modules again in each worker and in the `alone` run (collecting the suite: 9.7 s, 4.0 s from the
# caches), and each daemon and command a test starts compiles graytrack again (~0.3 s of CPU each).
test unit: export PYTHONDONTWRITEBYTECODE =
# The alone run reads only the files that name the mark (collecting the whole suite again to find its few tests took
# ~10 s; tests/test_alone_files.py checks that every test marked alone is in one of them); given PYTEST_ARGS, which
# may select tests of their own, it collects as before.
ALONE_FILES := $(shell grep -rlE --include='*.py' 'mark\.alone' tests)
# The suite's compiled kernels are compiled (on a fresh clone, ~100 s of CPU; loaded from numba's cache in a second
# after) while lint runs, on the other core, rather than by the test session before its workers start or by each
# worker and daemon on first use (tests/conftest.py warm_kernels).
test: $(STAMP)
	@$(BIN)/python -c 'from tests.conftest import warm_kernels; warm_kernels()' & \
	warm=$$!; $(MAKE) --no-print-directory lint; linted=$$?; wait $$warm; [ $$linted -eq 0 ] || exit $$linted; \
	$(BIN)/python -m pytest -n $(PYTEST_WORKERS) --dist worksteal -m "not alone" $(PYTEST_ARGS); first=$$?; \
	$(BIN)/python -m pytest -n 0 -m alone $(if $(PYTEST_ARGS),,$(ALONE_FILES)) $(PYTEST_ARGS); alone=$$?; \
	[ $$alone -eq 5 ] && alone=0; \
	[ $$first -eq 0 ] && [ $$alone -eq 0 ]  # 5: no alone test selected

# The unit tests alone (numerics and files, no daemon, browser or device): the quick check while editing.
unit: $(STAMP)
	$(BIN)/python -m pytest -n $(PYTEST_WORKERS) -m unit $(PYTEST_ARGS)

bench: $(STAMP)
	for script in bench/*.py; do echo "== $$script"; $(BIN)/python $$script || exit 1; done

clean:
	rm -rf $(VENV) build *.egg-info .pytest_cache
