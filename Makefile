# The two commands a new user needs: `make serve` and `make test`.
PY ?= python3
VENV := .venv
BIN := $(VENV)/bin
HOST ?= 127.0.0.1
PORT ?= 8000

.PHONY: serve test test-slow sim-dataset lint typecheck clean

$(BIN)/python:
	$(PY) -m venv $(VENV)
	$(BIN)/pip install -q --upgrade pip

# torch is installed first, alone and exactly pinned, so that no other package pulls a CUDA build.
$(VENV)/.serve-installed: pyproject.toml | $(BIN)/python
	$(BIN)/pip install -q -e ".[serve]"
	touch $@

$(VENV)/.dev-installed: pyproject.toml | $(BIN)/python
	$(BIN)/pip install -q torch==2.13.0
	$(BIN)/pip install -q -e ".[dev]"
	touch $@ $(VENV)/.serve-installed

serve: $(VENV)/.serve-installed
	$(BIN)/drape serve --host $(HOST) --port $(PORT)

test: $(VENV)/.dev-installed
	$(BIN)/ruff check drape tests bench
	$(BIN)/mypy
	$(BIN)/pytest

test-slow: $(VENV)/.dev-installed
	$(BIN)/pytest -m slow

# the small ground-truth dataset of the simulation issue: a knee-length skirt x 8 parameter sets x 3 clips x 90 frames
SIM_DIR ?= data/sim/skirt
sim-dataset: $(VENV)/.dev-installed
	mkdir -p $(SIM_DIR)
	$(BIN)/drape outfits generate --type skirt --vertices 2000 --seed 3 --length 0.6 --out $(SIM_DIR)/skirt.obj
	$(BIN)/drape sim dataset --garment $(SIM_DIR)/skirt.obj --params 8 --motions walk,dance_a,dance_b \
		--frames 90 --out $(SIM_DIR)

clean:
	rm -rf $(VENV) .pytest_cache .ruff_cache .mypy_cache
