# The two entry points of the README: `make demo` and `make test`.
VENV ?= .venv
BIN := $(VENV)/bin

.PHONY: setup demo test bench profile clean

setup:
	@scripts/setup.sh

demo: setup
	$(BIN)/ssga demo

test: setup
	@scripts/test-deps.sh
	$(BIN)/ruff check --quiet --select F,E9 ssga_core ssga_bench plugins examples tests benchmarks
	SSGA_STRICT_PLUGINS=1 $(BIN)/python -m pytest -q

# Speed benchmarks (pytest-benchmark); figures are for comparing runs on one machine.
bench: setup
	$(BIN)/python -m pytest benchmarks -q -o python_files='bench_*.py' --benchmark-enable --benchmark-columns=median,iqr,ops --benchmark-sort=name

# End-to-end throughput of the presets with 1 and 2 workers, each stage's rate (docs/scaling.md).
profile: setup
	$(BIN)/python scripts/profile_presets.py --presets demo,bench,paper --workers 1,2 --test-per-class 6 --out runs/profile

clean:
	rm -rf $(VENV) .pytest_cache
