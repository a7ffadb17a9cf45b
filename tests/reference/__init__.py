"""Independent references the tests (and benchmarks) compare the runtime with."""
