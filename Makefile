# pbdyn — two commands set everything up: `make demo` and `make test`.
PYTHON ?= python3
VENV   := .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed

.PHONY: demo test bench sysdeps native clean

$(STAMP): setup.cfg pyproject.toml
	@bash tools/install_sysdeps.sh
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e '.[test]'
	-$(PY) -m pbdyn.planning.native.build
	touch $(STAMP)

## Optional system libraries (libusb-1.0 for open3d's mesh backend), installed only when missing.
sysdeps:
	@bash tools/install_sysdeps.sh

## The native ruckig batch (pbdyn/planning/native): ruckig's calculator built from the installed version's sources
## with a C++ compiler; optional (without it the planners use the ruckig Python package: same results, slower).
native: $(STAMP)
	$(PY) -m pbdyn.planning.native.build

## The first study: a resumable batch on the quickstart scenario, its maps' metrics, the evaluation table and figures.
demo: $(STAMP)
	$(VENV)/bin/pbdyn batch scenarios/quickstart.toml --out results/quickstart.sqlite
	$(VENV)/bin/pbdyn evaluate results/quickstart.sqlite --plots results/quickstart-figures

test: $(STAMP)
	@bash tools/install_sysdeps.sh
	$(PY) -m pytest -q -p no:cacheprovider

bench: $(STAMP)
	$(PY) tools/bench/bench_trial.py


clean:
	rm -rf $(VENV) build *.egg-info .pytest_cache pbdyn/planning/native/_ruckig_batch.so
