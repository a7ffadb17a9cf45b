"""vertebra's benchmarks: the speed benchmarks run by asv (``speed/``) and the accuracy and
validation studies (``bench_*.py``, run from the repository root as ``python -m
benchmarks.bench_NAME``), which write JSON into ``results/``; ``render.py`` turns those into the
Markdown tables and pictures the docs show. docs/benchmarks.md says which makes what."""
