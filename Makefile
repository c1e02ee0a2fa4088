# Two commands on a fresh machine (Python >= 3.10):
#   make demo   - create .venv if missing, generate PointMaze U-maze expert data, run a two-task HiSPO
#                 stream that grows one subspace and prunes the other, print R, PER, MEM, decisions
#   make test   - create .venv if missing, run the test suite
# On a CPU-only machine torch is pinned to the local CPU build (a looser pin pulls CUDA wheels);
# pyproject keeps the range open for users. Override with `make TORCH_PIN=torch==X.Y.Z`.
PYTHON ?= python3
VENV ?= .venv
TORCH_PIN ?= torch==2.13.0
# test processes side by side, one torch thread each (0: one process)
TEST_WORKERS ?= 2
BIN := $(VENV)/bin

.PHONY: demo test test-all lint bench clean

$(BIN)/hispo-pl: pyproject.toml
	@echo "[make] $(VENV): creating it if missing, then installing into it (quietly; the first time takes minutes)"
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	@echo "[make] upgrading pip"
	$(BIN)/python -m pip install -q --upgrade pip
	@echo "[make] installing $(TORCH_PIN)"
	$(BIN)/python -m pip install -q "$(TORCH_PIN)"
	@echo "[make] installing hispo-pl (editable) with its dev tools"
	$(BIN)/python -m pip install -q -e ".[dev]"
	touch $(BIN)/hispo-pl
	@echo "[make] $(VENV) is ready: . $(VENV)/bin/activate puts hispo-pl on the path"

demo: $(BIN)/hispo-pl
	@echo "[make] the demo: HiSPO on a two-task PointMaze stream (expert data are made on first use)"
	$(BIN)/hispo-pl fit --config configs/demo.yaml --config configs/methods/hispo.yaml

test: $(BIN)/hispo-pl
	$(BIN)/python -m pytest -q -n $(TEST_WORKERS) --dist loadfile

test-all: $(BIN)/hispo-pl
	$(BIN)/python -m pytest -q -n $(TEST_WORKERS) --dist loadfile -m "slow or not slow"

lint: $(BIN)/hispo-pl
	$(BIN)/ruff check .

bench: $(BIN)/hispo-pl
	$(BIN)/python benchmarks/throughput.py

clean:
	rm -rf $(VENV) runs .pytest_cache
