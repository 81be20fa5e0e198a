PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
TEST_STAMP := $(VENV)/.installed-test

.PHONY: run test test-all first-try bench validation lint clean

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/pip install --quiet --upgrade pip
	$(BIN)/pip install --quiet -e .
	touch $@

$(TEST_STAMP): $(STAMP)
	$(BIN)/pip install --quiet -e '.[test]'
	touch $@

run: $(STAMP)
	$(BIN)/python -m spotnav.app.kernels
	$(BIN)/spotnav reproduce --quick --out results/quick

# The suite in two processes (pytest-xdist), one per core of a 2-core machine; no test asserts how long anything took.
PYTEST := $(BIN)/python -m pytest -q -n 2 --dist worksteal

test: $(TEST_STAMP)
	$(BIN)/ruff check src tests benchmarks
	$(BIN)/mypy
	$(BIN)/python -m spotnav.app.kernels
	$(PYTEST) -m "not slow"
	SPOTNAV_BENCH_SIZES=512 $(BIN)/python -m pytest -q benchmarks --benchmark-disable

# Everything make test runs, and the slow tests: full-size studies and the compile from an empty cache.
test-all: $(TEST_STAMP)
	$(BIN)/ruff check src tests benchmarks
	$(BIN)/mypy
	$(BIN)/python -m spotnav.app.kernels
	$(PYTEST)
	SPOTNAV_BENCH_SIZES=512 $(BIN)/python -m pytest -q benchmarks --benchmark-disable

# A fresh install: the README's first try with an empty kernel cache (also in make test), and warm_kernels alone
# compiles every kernel (slow: only here).
first-try: $(TEST_STAMP)
	$(BIN)/python -m pytest -q tests/test_cli.py::test_the_readme_first_try_compiles_once_and_says_so \
	  tests/app/test_kernels.py::test_warming_compiles_every_kernel

bench: $(TEST_STAMP)
	$(BIN)/python -m pytest benchmarks --benchmark-columns=median,iqr,rounds --benchmark-sort=name
	$(BIN)/spotnav bench

CYCLES_DEV ?= ../shared/cycles-dev
CYCLES_GEOMETRY ?= ../shared/cycles-geometry
CYCLES_PHOTOMETRY ?= ../shared/cycles-photometry
VALIDATION := results/validation

# A plain calibrate on each Cycles set's cal_* frames (cycles-photometry: spots the camera clips), then its test_* frames localized by the precise method
# (calibrated, and with the nominal setup: refused, not wrong) and the thesis's, and its seq_* helix tracked.
validation: $(STAMP)
	@for folder in $(CYCLES_DEV) $(CYCLES_GEOMETRY) $(CYCLES_PHOTOMETRY); do \
	  test -d $$folder || { echo "no Cycles frames at $$folder (make validation CYCLES_DEV=... CYCLES_GEOMETRY=... CYCLES_PHOTOMETRY=...)"; exit 2; }; \
	done
	@for folder in $(CYCLES_DEV) $(CYCLES_GEOMETRY) $(CYCLES_PHOTOMETRY); do for set in b1 b3; do \
	  d=$$folder/$$set; o=$(VALIDATION)/$$(basename $$folder)/$$set; mkdir -p $$o; \
	  $(BIN)/spotnav calibrate --scene $$d/setup.toml --poses $$d/known.csv --height-correction \
	    --out $$o/calibrated.toml > $$o/calibrate.txt || exit 1; \
	  for run in "precise calibrated" "precise setup" "thesis calibrated"; do \
	    set -- $$run; scene=$$o/calibrated.toml; [ $$2 = setup ] && scene=$$d/setup.toml; \
	    $(BIN)/spotnav localize --scene $$scene --method $$1 $$d/test_*.png --out $$o/poses_$$1_$$2.csv 2>/dev/null || exit 1; \
	    echo "== $$(basename $$folder) $$set, $$1, $$2:"; \
	    $(BIN)/spotnav evaluate $$o/poses_$$1_$$2.csv $$d/truth.csv --out $$o/$$1_$$2 2>/dev/null || exit 1; \
	  done; \
	  if [ -f $$d/seq_truth.csv ]; then \
	    $(BIN)/spotnav track --scene $$o/calibrated.toml "$$d/seq_*.png" --out $$o/track.csv 2>/dev/null || exit 1; \
	    echo "== $$(basename $$folder) $$set, tracked, calibrated:"; \
	    $(BIN)/spotnav evaluate $$o/track.csv $$d/seq_truth.csv --out $$o/track 2>/dev/null || exit 1; \
	  fi; \
	done; done

lint: $(TEST_STAMP)
	$(BIN)/ruff check src tests benchmarks
	$(BIN)/ruff format --check src tests benchmarks
	$(BIN)/mypy

clean:
	rm -rf $(VENV) results .pytest_cache .hypothesis .mypy_cache
