# Two commands do all the set-up:  `make demo` (install + main job) and `make test` (install + tests).
PYTHON ?= python3.11
VENV   ?= .venv
PY     := $(VENV)/bin/python
PIP    := $(PY) -m pip
SCENE  ?= data/synth/studio
STAMP  := $(VENV)/.installed

.PHONY: install demo test weights bench clean

# torch 2.13.0 (CPU) goes in first, alone, so nothing later pulls a multi-GB CUDA build.
$(STAMP): pyproject.toml
	@command -v $(PYTHON) >/dev/null || { echo "error: $(PYTHON) not found (set PYTHON=...)"; exit 2; }
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PIP) install -q --upgrade pip
	$(PIP) install -q torch==2.13.0
	$(PIP) install -q -e '.[test]'
	touch $(STAMP)

install: $(STAMP)

weights: install
	$(VENV)/bin/ftgspp weights fetch

demo: install
	$(VENV)/bin/ftgspp synth --out $(SCENE) --preset studio --seed 0
	$(VENV)/bin/ftgspp train profile=quick data.path=$(SCENE) hydra.run.dir=outputs/demo
	@echo "results: outputs/demo (metrics.json, renders/)"

test: install weights
	$(VENV)/bin/python -m pytest -q

bench: install
	$(VENV)/bin/ftgspp bench render

clean:
	rm -rf outputs multirun mlruns mlflow.db data/synth .pytest_cache
