# pbdyn — two commands set everything up: `make demo` and `make test`.
PYTHON ?= python3
VENV   := .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed

.PHONY: demo test bench sysdeps clean

$(STAMP): setup.cfg pyproject.toml
	@bash tools/install_sysdeps.sh
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e '.[test]'
	touch $(STAMP)

## Optional system libraries (libusb-1.0 for open3d's mesh backend), installed only when missing.
sysdeps:
	@bash tools/install_sysdeps.sh

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
	rm -rf $(VENV) build *.egg-info .pytest_cache
