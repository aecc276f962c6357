# Every target sets up what it needs: a fresh clone needs only python3 (>=3.11) and a C compiler.
PYTHON ?= python3
VENV   := .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed

.PHONY: install test demo codegen bench clean

install: $(STAMP)

$(STAMP): pyproject.toml
	@test -x $(PY) || $(PYTHON) -m venv $(VENV)
	@$(PY) -m pip install -q --disable-pip-version-check --upgrade pip
	@$(PY) -m pip install -q --disable-pip-version-check -e '.[dev]'
	@touch $(STAMP)
	@echo "installed ddpc-codegen into $(VENV)"

test: install
	$(PY) -m pytest -q

clean:
	rm -rf build generated/*/ reports/*.json reports/*.png .pytest_cache
