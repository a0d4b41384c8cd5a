# Two commands do all the set-up:  `make demo` (install + main job) and `make test` (install + tests).
PYTHON ?= python3.11
VENV   ?= .venv
PY     := $(VENV)/bin/python
PIP    := $(PY) -m pip
SCENE  ?= data/synth/studio
STAMP  := $(VENV)/.installed

.PHONY: install demo train-quick test weights bench clean reports
.PHONY: server test-cluster gpu-check gpu-kit

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

# The main job: secret 5 (run-to-run variation, colour correction, initialisation and hardware
# shares of the spread) on the synthetic studio scene, 5 variants x 5 seeds (2 at a time) in portable
# determinism mode (the 2 dispatch variants excepted), tracked in ./mlflow.db; its report goes to
# outputs/reports/secret5 (the committed reports/ is never touched), then `study check` compares
# every run with the committed reports/secret5/runs.csv, bit for bit. Re-running resumes.
demo: install weights
	$(VENV)/bin/study run secret5 --profile quick
	$(VENV)/bin/study report secret5
	$(VENV)/bin/study check secret5
	@echo "report: outputs/reports/secret5/index.md (the committed answers: reports/index.md)"
	@echo "browse the runs: $(VENV)/bin/mlflow ui --backend-store-uri sqlite:///mlflow.db, then open the link study run printed"

# One training run of the quick profile (the issue-2 demo).
train-quick: install
	test -d $(SCENE) || $(VENV)/bin/ftgspp synth --out $(SCENE) --preset studio --seed 0
	$(VENV)/bin/ftgspp train profile=quick data.path=$(SCENE) hydra.run.dir=outputs/train-quick

# Every study's quick profile, then every report and reports/index.md (the page to open first).
# Resumable: finished runs are skipped, so a second call with nothing missing only rewrites the
# reports. Prints the plan and expected time first: the quick runs an hour measured for this
# CPU's vector ISA (harness/spec/throughput.py, the README's table). Runs go JOBS at a time
# (default: each quick profile's `jobs`, 2; BENCHMARKS.md has the --jobs 1 vs 2 measurement).
STUDIES ?= $(sort $(filter-out _%,$(basename $(notdir $(wildcard studies/*.yaml)))))
JOBS ?=

reports: install weights
	$(PY) -m harness.cli.reports_plan --jobs $(or $(JOBS),2) --todo .reports-todo
	@set -e; for s in $$(cat .reports-todo); do case " $(STUDIES) " in *" $$s "*) \
	  $(VENV)/bin/study run $$s --profile quick --rerun-stale $(if $(JOBS),--jobs $(JOBS));; esac; done
	@# render speed and size of the speed-accuracy grid's models, one at a time, nothing else running
	case " $(STUDIES) " in *" speed_accuracy "*) $(VENV)/bin/study measure speed_accuracy --profile quick;; esac
	$(VENV)/bin/study report --all --profile quick --if-changed --out reports
	$(VENV)/bin/study index --profile quick --out reports
	@echo "open reports/index.md"

# Two pytest workers (pytest-xdist), one test file each at a time so a file's fixtures are built
# once: 1.6x faster than one worker on 2 cores (BENCHMARKS.md). TEST_JOBS=1 runs them serially.
test: install weights
	$(VENV)/bin/python -m pytest -q -n $(or $(TEST_JOBS),2) --dist loadfile

# The multi-user tracking server (docs/cluster.md): PostgreSQL + mlflow server with proxied
# artifacts on 127.0.0.1:5000, data in ./tracking-server. Ctrl-C stops both.
server: install
	$(VENV)/bin/ftgspp-server --root tracking-server

# Real PostgreSQL, real one-node SLURM, headless Chromium (installs them from Debian as
# root first; about 10 minutes on 2 cores). Not part of `make test`.
test-cluster: install
	bash tests/cluster/install.sh
	$(VENV)/bin/python -m pytest -q -s -p no:cacheprovider tests/cluster/cluster_*.py

# For users with a CUDA GPU: gsplat 1.5.3 (the cuda extra), then parity on its real kernels,
# a quick run on gsplat vs the cpu backend, and the benches (docs/gpu.md). Prints a verdict.
gpu-check: install weights
	$(PIP) install -q -e '.[cuda,test]'
	$(VENV)/bin/ftgspp check-gpu

# The offline kit for a GPU machine without network (the device tool's; docs/gpu.md): wheels for
# CPython 3.12 manylinux x86-64 of what `scripts/gpu_check.sh` needs beyond that machine's own
# packages (gsplat 1.5.3, Hydra, OmegaConf, antlr4, diptest) and the LPIPS-Alex weights, in $(KIT)/
# (git-ignored), checked offline: pip resolves it for 3.12, nothing replaces the machine's torch.
# Prints its size (limit 48 MiB) and what would travel with this checkout.
KIT ?= .whl
gpu-kit: install weights
	$(PY) -m harness.cli.gpu_kit build --dest $(KIT)

bench: install
	$(VENV)/bin/ftgspp bench render

clean:
	rm -rf outputs multirun mlruns mlflow.db data/synth .pytest_cache
