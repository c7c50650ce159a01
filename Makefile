# pbdyn — two commands set everything up: `make demo` and `make test`.
PYTHON ?= python3
VENV   := .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed
TESTS  := $(VENV)/.installed-test
NATIVE := $(VENV)/.native
## setuptools announces an editable install of a package_dir mapping (urdf/, scenarios/ -> data packages) with a
## warning for developers about same-named folders; the install is correct and the notice is noise to a user.
EDITABLE := PYTHONWARNINGS="ignore:Editable installation"

.PHONY: demo test bench sysdeps native clean

## pbdyn and what it runs with: its system libraries (tools/install_sysdeps.sh), the venv, the package (editable).
## Nothing only the tests use (`make demo` needs this and the native build alone).
$(STAMP): setup.cfg setup.py pyproject.toml
	@bash tools/install_sysdeps.sh
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(EDITABLE) $(PY) -m pip install --quiet -e .
	touch $(STAMP)

## The test extras (pytest, selenium, ...), once per install of the package.
$(TESTS): $(STAMP)
	$(EDITABLE) $(PY) -m pip install --quiet -e '.[test]'
	touch $(TESTS)

## Built (or tried: a failed build leaves the Python package in use) after the install and whenever its source changes.
$(NATIVE): $(STAMP) pbdyn/planning/primitives/native/ruckig_batch.cpp pbdyn/planning/primitives/native/build.py
	-$(PY) -m pbdyn.planning.primitives.native.build
	touch $(NATIVE)

## Optional system libraries (libusb-1.0 for open3d's mesh backend, g++ for the native build), installed only when
## missing; `bash tools/install_sysdeps.sh --test` adds the tests' browser (chromium) and virtual display (xvfb).
sysdeps:
	@bash tools/install_sysdeps.sh

## The native ruckig batch (pbdyn/planning/primitives/native): ruckig's calculator built from the installed
## version's sources with a C++ compiler; optional (without it the planners use the ruckig Python package: same
## results, slower).
native: $(STAMP)
	$(PY) -m pbdyn.planning.primitives.native.build

## The first study: a resumable batch on the quickstart scenario, its maps' metrics, the evaluation table and figures.
demo: $(NATIVE)
	$(VENV)/bin/pbdyn batch scenarios/quickstart.toml --out results/quickstart.sqlite
	$(VENV)/bin/pbdyn evaluate results/quickstart.sqlite --plots results/quickstart-figures

## The tests' system packages (the browser, xvfb) are checked on every run and installed when missing.
test: $(NATIVE) $(TESTS)
	@bash tools/install_sysdeps.sh --test
	$(PY) -m pytest -q -p no:cacheprovider -n auto --durations=30

bench: $(NATIVE)
	$(PY) tools/bench/bench_trial.py


clean:
	rm -rf $(VENV) build *.egg-info .pytest_cache pbdyn/planning/primitives/native/_ruckig_batch.so*
