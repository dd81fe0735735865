# The two entry points of the README: `make demo` and `make test`.
VENV ?= .venv
BIN := $(VENV)/bin

.PHONY: setup demo test bench clean

setup:
	@scripts/setup.sh

demo: setup
	$(BIN)/ssga demo

test: setup
	$(BIN)/ruff check --quiet --select F,E9 ssga_core ssga_bench plugins examples tests benchmarks
	SSGA_STRICT_PLUGINS=1 $(BIN)/python -m pytest -q

# Speed benchmarks (pytest-benchmark); figures are for comparing runs on one machine.
bench: setup
	$(BIN)/python -m pytest benchmarks -q -o python_files='bench_*.py' --benchmark-enable --benchmark-columns=median,iqr,ops --benchmark-sort=name

clean:
	rm -rf $(VENV) .pytest_cache
