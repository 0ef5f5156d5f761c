# Two-command start: `make run` and `make test` on a fresh machine.
# Python 3.12+ (scripts/find_python.sh): JAX >= 0.12 installs there.
PY ?= $(shell sh scripts/find_python.sh)
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: run test test-all test-slurm figures bench optimizers misma gyro discrepancy generalisation calibration calibration-unseen dataset-figures docs venv clean

$(STAMP): pyproject.toml
	test -x $(BIN)/python || $(PY) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[dev,bench]'
	touch $(STAMP)

venv: $(STAMP)

run: $(STAMP)
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
