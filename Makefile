# Every target bootstraps its own virtual environment in .venv.
PYTHON ?= python3
VENV   := .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed

.PHONY: demo test bench bench-ccx bench-trade bench-large-deformation clean

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e '.[dev]'
	touch $(STAMP)

demo: $(STAMP)
	$(VENV)/bin/vertebra demo --out demo-output

test: $(STAMP)
	MPLBACKEND=Agg $(PY) -m pytest -q

bench: $(STAMP)
	MPLBACKEND=Agg $(PY) benchmarks/run_all.py

bench-ccx: $(STAMP)
	MPLBACKEND=Agg $(PY) benchmarks/bench_ccx_crosscheck.py

bench-trade: $(STAMP)
	OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 MPLBACKEND=Agg $(PY) benchmarks/bench_trade.py

bench-large-deformation: $(STAMP)
	OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 MPLBACKEND=Agg $(PY) benchmarks/bench_nonlinear_acceptance.py

clean:
	rm -rf $(VENV) demo-output .pytest_cache
