# Every target sets up what it needs: a fresh clone needs only python3 (>=3.11) and a C compiler.
PYTHON ?= python3
VENV   := .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed

.PHONY: install test demo codegen bench bridge-demo clean

install: $(STAMP)

$(STAMP): pyproject.toml
	@test -x $(PY) || $(PYTHON) -m venv $(VENV)
	@$(PY) -m pip install -q --disable-pip-version-check --upgrade pip
	@$(PY) -m pip install -q --disable-pip-version-check -e '.[dev]'
	@touch $(STAMP)
	@echo "installed ddpc-codegen into $(VENV)"

test: install
	$(PY) -m pytest -q

# Steering solvers from configs/: collect a PRBS-excited dataset on the simulator when none is there yet.
data/flying.npz: | install
	$(VENV)/bin/ddpc-codegen collect --scenario flying --duration 60 -o $@

codegen: install data/flying.npz
	$(VENV)/bin/ddpc-codegen codegen configs/flying.toml

# Vehicle and bridge as two processes over UDP on 127.0.0.1: collect, codegen, baseline and steered flights.
bridge-demo: install
	$(PY) -m firmware_bridge.demo

bench: install
	@$(PY) -m pip install -q --disable-pip-version-check -e '.[dev,bench]' || echo "(bench extra not installed: the CVXPYgen comparison is skipped)"
	$(PY) -m ddpc_codegen.bench

clean:
	rm -rf build generated/*/ reports/*.json reports/*.png .pytest_cache
