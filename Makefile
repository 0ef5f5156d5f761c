# Two-command start: `make run` and `make test` on a fresh machine.
# Python 3.12+ (scripts/find_python.sh): JAX >= 0.12 installs there.
# Installs come from the lock files in requirements/ (the same versions on every machine): `make run` installs only
# what the study needs (run.lock), `make test` adds the test tools and the peer libraries (dev.lock, a superset at
# the same versions). `make upgrade` re-resolves both from pyproject.toml and re-runs what the README says must hold.
PY ?= $(shell sh scripts/find_python.sh)
VENV := .venv
BIN := $(VENV)/bin
RUN_STAMP := $(VENV)/.installed-run
DEV_STAMP := $(VENV)/.installed-dev
PIP := $(BIN)/python -m pip install --quiet
# uv installs the locked set into the venv, in parallel (a fresh `make run` install: 122 s with pip, see README)
UV := $(BIN)/python -m uv pip install --quiet --python $(BIN)/python
# the versions the locks were resolved for; uv writes environment markers for every platform (--universal)
DEV_EXTRAS := --extra dev --extra bench
LOCK := $(BIN)/python -m uv pip compile pyproject.toml --universal --python-version 3.12 --no-header --quiet

.PHONY: run test test-all test-slurm figures bench optimizers misma gyro discrepancy generalisation calibration calibration-unseen dataset-figures docs venv upgrade clean

$(BIN)/python:
	$(PY) -m venv $(VENV)
	$(PIP) --upgrade pip uv

$(RUN_STAMP): $(BIN)/python requirements/run.lock pyproject.toml
	$(UV) -r requirements/run.lock
	$(UV) --no-deps -e .
	touch $(RUN_STAMP)

$(DEV_STAMP): $(RUN_STAMP) requirements/dev.lock
	$(UV) -r requirements/dev.lock
	touch $(DEV_STAMP)

STAMP := $(DEV_STAMP)

venv: $(DEV_STAMP)

upgrade: $(BIN)/python
	$(LOCK) --upgrade $(DEV_EXTRAS) -o requirements/dev.lock
	$(LOCK) --upgrade -c requirements/dev.lock -o requirements/run.lock
	rm -f $(RUN_STAMP) $(DEV_STAMP)
	$(MAKE) test docs
	$(BIN)/python -m experiments.docs --check

run: $(RUN_STAMP)
	$(BIN)/python -m experiments.run strategy=three_stage

test: $(STAMP)
	$(BIN)/python -m pytest -q -n 2

test-all: $(STAMP)
	$(BIN)/python -m pytest -q -n 2 -m ''

test-slurm: $(STAMP)
	$(BIN)/python -m pytest -q -m slurm tests/test_slurm.py

figures: $(STAMP)
	$(BIN)/python -m experiments.figures
	$(BIN)/python -m experiments.fig9_seeds

bench: $(STAMP)
	$(BIN)/python -m experiments.bench

optimizers: $(STAMP)
	$(BIN)/python -m experiments.optimizers --jobs 2

misma: $(STAMP)
	$(BIN)/python -m experiments.misma

gyro: $(STAMP)
	$(BIN)/python -m experiments.gyro

discrepancy: $(STAMP)
	$(BIN)/python -m experiments.discrepancy study=hidden
	$(BIN)/python -m experiments.discrepancy study=devices max_effects=4
	$(BIN)/python -m experiments.discrepancy study=lab_casing

docs: $(STAMP)
	$(BIN)/python -m experiments.docs

dataset-figures: $(STAMP)
	$(BIN)/python -m experiments.dataset_figures

clean:
	rm -rf $(VENV) outputs multirun

generalisation: $(STAMP)
	$(BIN)/python -m experiments.generalisation

calibration: $(STAMP)
	$(BIN)/python -m experiments.calibrate data=bundled

calibration-unseen: $(STAMP)
	$(BIN)/python -m experiments.calibration_unseen
