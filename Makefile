# Two commands on a fresh machine (Python >= 3.10):
#   make demo   - create .venv if missing, install what the demo needs, generate PointMaze U-maze
#                 expert data, run a two-task HiSPO stream that grows one subspace and prunes the
#                 other, print R, PER, MEM, decisions
#   make test   - create .venv if missing, add the tests' extras (.[dev]), run the test suite
# torch is pinned to the build the suite is checked with; pyproject keeps the range open for
# users. Override with `make TORCH_PIN=torch==X.Y.Z`. The physics and data stack is pinned too
# (SIM_PINS): another MuJoCo or NumPy collects other expert episodes and rolls out other
# successes, so a run made here can be repeated on a fresh machine only at the same versions
# (docs/data.md, "Reproducing a dataset"). On a CPU-only machine pip resolves the pin
# to a CUDA build (several GB): `make demo TORCH_INDEX=https://download.pytorch.org/whl/cpu`
# takes the CPU wheel.
PYTHON ?= python3
VENV ?= .venv
TORCH_PIN ?= torch==2.13.0
TORCH_INDEX ?=
SIM_PINS ?= mujoco==4.0.1 numpy==2.4.6 gymnasium==1.4.0 gymnasium-robotics==1.4.2 minari==0.5.4
# test processes side by side, one torch thread each (0: one process)
TEST_WORKERS ?= 2
BIN := $(VENV)/bin
# what is installed: the package (the demo's needs), then the tests' extras
INSTALLED := $(VENV)/.hispo-pl-installed
DEV_INSTALLED := $(VENV)/.hispo-pl-dev-installed

.PHONY: demo test test-all lint bench clean

$(INSTALLED): pyproject.toml
	@echo "[make] $(VENV): creating it if missing, then installing into it (quietly; the first time takes minutes)"
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	@echo "[make] upgrading pip"
	$(BIN)/python -m pip install -q --upgrade pip
	@echo "[make] installing $(TORCH_PIN)$(if $(TORCH_INDEX), from $(TORCH_INDEX))"
	$(BIN)/python -m pip install -q "$(TORCH_PIN)" $(if $(TORCH_INDEX),--index-url $(TORCH_INDEX))
	@echo "[make] installing $(SIM_PINS)"
	$(BIN)/python -m pip install -q $(SIM_PINS)
	@echo "[make] installing hispo-pl (editable) with what the demo needs"
	$(BIN)/python -m pip install -q -e .
	touch $(INSTALLED)
	@echo "[make] $(VENV) is ready: . $(VENV)/bin/activate puts hispo-pl on the path"

$(DEV_INSTALLED): $(INSTALLED)
	@echo "[make] adding the tests' extras (pytest, ruff, the notebook runner, minari[create], rliable)"
	$(BIN)/python -m pip install -q -e ".[dev]"
	touch $(DEV_INSTALLED)

demo: $(INSTALLED)
	@echo "[make] the demo: HiSPO on a two-task PointMaze stream (expert data are made on first use)"
	$(BIN)/hispo-pl fit --config configs/demo.yaml --config configs/methods/hispo.yaml

test: $(DEV_INSTALLED)
	$(BIN)/python -m pytest -q -n $(TEST_WORKERS) --dist loadfile

test-all: $(DEV_INSTALLED)
	$(BIN)/python -m pytest -q -n $(TEST_WORKERS) --dist loadfile -m "slow or not slow"

lint: $(DEV_INSTALLED)
	$(BIN)/ruff check .

bench: $(INSTALLED)
	$(BIN)/python benchmarks/throughput.py

clean:
	rm -rf $(VENV) runs .pytest_cache
