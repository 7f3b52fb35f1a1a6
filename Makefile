# dotsim: every target installs what it needs when it is missing.
PYTHON ?= python3
VENV ?= .venv
BIN := $(VENV)/bin
# Where a local CPU build of torch 2.13.0 is on disk (as on the dev machines), take it: an
# unpinned torch would pull several GB of CUDA packages. Elsewhere torch resolves as usual;
# override with `make setup TORCH=torch==2.x.y`.
TORCH ?= $(if $(wildcard /opt/wheels/torch-2.13.0*),torch==2.13.0,torch)
CONFIG ?= configs/default.toml
OUT ?= out
SCENES ?= 4
WORKERS ?= 1
DATA ?= $(OUT)/dataset

.PHONY: setup test lint bench dataset assets train clean

$(BIN)/dotsim: pyproject.toml
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/pip install -q "$(TORCH)"
	$(BIN)/pip install -q -e ".[dev]"
	touch $@

setup: $(BIN)/dotsim

test: setup
	$(BIN)/python -m pytest -q tests

lint: setup
	$(BIN)/ruff check .

bench: setup
	$(BIN)/python -m bench.run_all

assets: setup
	$(BIN)/dotsim assets build --split train
	$(BIN)/dotsim assets build --split test

dataset: setup
	$(BIN)/dotsim generate --config $(CONFIG) --out $(DATA) --split train --scenes $(SCENES) --workers $(WORKERS)
	$(BIN)/dotsim show $(DATA) -o $(OUT)/contact_sheet.png

train: setup
	$(BIN)/dotsim train --config configs/train_tiny.toml --data $(DATA) --out $(OUT)/train

clean:
	rm -rf $(OUT) $(VENV) *.egg-info
