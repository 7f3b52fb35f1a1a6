# dotsim: every target installs what it needs when it is missing.
PYTHON ?= python3
VENV ?= .venv
BIN := $(VENV)/bin
# Where a local CPU build of torch 2.13.0 is on disk (as on the dev machines), take it: an
# unpinned torch would pull several GB of CUDA packages. Elsewhere torch resolves as usual;
# override with `make setup TORCH=torch==2.x.y`.
TORCH ?= $(if $(wildcard /opt/wheels/torch-2.13.0*),torch==2.13.0,torch)
CONFIG ?= default
OUT ?= out
SCENES ?= 4
WORKERS ?= 1
DATA ?= $(OUT)/dataset
TEST_DATA ?= $(OUT)/testset

.PHONY: setup ray test lint bench bench-quick dataset testset assets assets-train train eval addon clean

# pyrealsense2 (a test dependency) loads libusb-1.0, and the OpenNI2 tests the native OpenNI2
# library: Debian packages, installed here when missing and apt-get is there.
SYSTEM_LIBS := libusb-1.0-0 libopenni2-dev

$(BIN)/dotsim: pyproject.toml
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	@dpkg -s $(SYSTEM_LIBS) >/dev/null 2>&1 || ! command -v apt-get >/dev/null || \
		(apt-get update -qq && apt-get install -y -qq $(SYSTEM_LIBS) >/dev/null) || \
		echo "warning: could not install $(SYSTEM_LIBS); the RealSense and OpenNI2 tests will be skipped"
	$(BIN)/pip install -q "$(TORCH)"
	$(BIN)/pip install -q -e ".[dev]"
	touch $@

setup: $(BIN)/dotsim

# Only what `dotsim generate --ray` needs (setup already installs it with the dev extra).
ray: setup
	$(BIN)/pip install -q -e ".[ray]"

test: setup
	$(BIN)/python -m pytest -q tests

lint: setup
	$(BIN)/ruff check .

# Every benchmark at full settings (over an hour on two cores); bench-quick is a smoke run.
bench: setup
	$(BIN)/python -m bench.run_all

bench-quick: setup
	$(BIN)/python -m bench.run_all --quick

# Incremental: a rebuild with nothing changed takes well under a second.
assets: assets-train
	$(BIN)/dotsim assets build --split test

assets-train: setup
	$(BIN)/dotsim assets build --split train

dataset: assets-train
	$(BIN)/dotsim generate --config $(CONFIG) --out $(DATA) --split train --scenes $(SCENES) --workers $(WORKERS)
	$(BIN)/dotsim show $(DATA) -o $(OUT)/contact_sheet.png
	$(BIN)/dotsim show $(DATA) --overview -o $(OUT)/overview.png

# The test split: disjoint assets (test cache), its own clutter density, another seed.
testset: assets
	$(BIN)/dotsim generate --config $(CONFIG) --out $(TEST_DATA) --split test --scenes $(SCENES) --workers $(WORKERS) --seed 1

# The network sized for make dataset's 608 x 448 frames, trained for MINUTES on this machine's CPU
# (a rerun continues the run for MINUTES more). What to expect: docs/TRAINER.md "make train / make eval".
TRAIN_CONFIG ?= train_cpu
MINUTES ?= 20
RUN ?= $(OUT)/runs/cpu

train: setup
	@echo "make train: $(MINUTES) min of $(TRAIN_CONFIG) on $(DATA) (4 scenes by default) is a SMOKE RUN: it shows the"
	@echo "  pipeline works, not a useful network (measured with the earlier backbone: it did not beat SGBM). At 608 x 448, 119 scenes"
	@echo "  (14 min to render) and 64 min of training on one thread (bench.trainer_accuracy) beat SGBM with LCN (o(0.5)"
	@echo "  0.319 vs 0.394); a network as good as GigaDepth's needs longer runs or a GPU (docs/TRAINER.md \"Benchmarks\")."
	$(BIN)/dotsim train --config $(TRAIN_CONFIG) --data $(DATA) --out $(RUN) --minutes $(MINUTES) --resume

# The test split of its own (make testset); SGBM's preprocessing (plain or LCN) is chosen on the
# training frames, never on the test frames.
eval: testset
	$(BIN)/dotsim eval --checkpoint $(RUN)/checkpoint.pt --data $(TEST_DATA) --val-data $(DATA) --out $(RUN)/eval

# The Blender extension: dist/dotsim-<version>-<platform>.zip per platform PyPI has wheels for
# (downloaded once into build/addon_wheels/); `make addon PLATFORMS="--platform linux-x64"` for one.
PLATFORMS ?=
addon: setup
	$(BIN)/python -m blender_addon.build_extension $(PLATFORMS)

clean:
	rm -rf $(OUT) $(VENV) *.egg-info build dist
