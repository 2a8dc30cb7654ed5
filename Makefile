# make setup: .venv with the package (editable) and everything it needs; idempotent.
# make demo:  the main job (see README).   make test: the whole test suite.   make unit: its in-process tier.
# make check: ruff, mypy on both packages, import-linter and the unit tier (under a minute).   make docs: the site.
PYTHON ?= python3
VENV := .venv
STAMP := $(VENV)/.installed
export AMENT_PREFIX_PATH := $(CURDIR)/$(VENV)
DEMO_OUT ?= out/demo
TEST_WORKERS ?= 2  # pytest-xdist workers (make test, unit, check): one a core of 2-core machines

.PHONY: setup bytecode demo test unit check docs bench clean

setup: $(STAMP)

$(STAMP): setup.py setup.cfg package.xml Makefile tools/build_interfaces.sh $(wildcard interfaces/*/*)
	test -x $(VENV)/bin/python || $(PYTHON) -m venv $(VENV)
	$(VENV)/bin/python -m pip install --quiet --upgrade "pip>=24"
	$(VENV)/bin/python -m pip install --quiet --editable ".[ros,test,docs,cluster,tune,viz]"
	tools/build_interfaces.sh $(VENV)  # tf2_msgs and nav2_msgs where the wheels have none
	touch $(STAMP)

# The package's bytecode, written here (only what changed): a process reads it even under
# PYTHONDONTWRITEBYTECODE=1, which otherwise has every node and CLI start compile the package (0.2 s each).
bytecode: setup
	$(VENV)/bin/python -m compileall -q robotino_geom_mpc robotino_sim_node test

demo: bytecode
	$(VENV)/bin/robotino-geom-mpc run --scenario paper-circle --out $(DEMO_OUT)

test: bytecode
	$(VENV)/bin/python -m pytest -q -rs --durations=10 -n $(TEST_WORKERS) --dist worksteal test

unit: bytecode
	$(VENV)/bin/python -m pytest -q -n $(TEST_WORKERS) -m "unit and not slow" test

check: bytecode
	$(VENV)/bin/ruff check .
	$(VENV)/bin/mypy
	$(VENV)/bin/lint-imports
	$(VENV)/bin/python -m pytest -q -n $(TEST_WORKERS) -m "unit and not slow" test

docs: setup
	$(VENV)/bin/sphinx-build -W --keep-going -q -b html docs docs/_build/html

bench: setup
	$(VENV)/bin/robotino-geom-mpc bench

clean:
	rm -rf $(VENV) build install log out *.egg-info docs/_build
