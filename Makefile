# Every target bootstraps its own virtual environment in .venv.
PYTHON ?= python3
VENV   := .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed

BENCH_STAMP := $(VENV)/.bench-installed
ASV    := $(VENV)/bin/asv
BASE   ?= HEAD~1

.PHONY: demo test bench bench-speed bench-ab bench-render bench-ccx bench-trade bench-large-deformation clean

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e '.[dev]'
	touch $(STAMP)

demo: $(STAMP)
	$(VENV)/bin/vertebra demo --out demo-output

test: $(STAMP)
	MPLBACKEND=Agg $(PY) -m pytest -q

$(BENCH_STAMP): pyproject.toml $(STAMP)
	$(PY) -m pip install --quiet -e '.[dev,bench]'
	$(ASV) machine --yes >/dev/null
	touch $(BENCH_STAMP)

# the studies (accuracy, validation, the docs' tables): docs/benchmarks.md
bench: $(STAMP)
	MPLBACKEND=Agg $(PY) -m benchmarks.run_all

# every speed benchmark once, on the installed working tree (asv, docs/benchmarks.md)
bench-speed: $(BENCH_STAMP)
	$(ASV) run --quick --show-stderr --environment existing:$(PY)

# A/B of two commits, each built into its own virtualenv: make bench-ab BASE=<commit>
bench-ab: $(BENCH_STAMP)
	$(ASV) continuous --factor 1.1 --show-stderr $(BASE) HEAD

# the docs' tables and pictures again from the studies' JSON
bench-render: $(STAMP)
	MPLBACKEND=Agg $(PY) -m benchmarks.render

bench-ccx: $(STAMP)
	MPLBACKEND=Agg $(PY) -m benchmarks.bench_ccx_crosscheck

bench-trade: $(STAMP)
	OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 MPLBACKEND=Agg $(PY) -m benchmarks.bench_trade

bench-large-deformation: $(STAMP)
	OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 MPLBACKEND=Agg $(PY) -m benchmarks.bench_nonlinear_acceptance

clean:
	rm -rf $(VENV) demo-output .pytest_cache .asv
