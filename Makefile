# Two-command quick start: `make demo` and `make test`. Both create .venv when missing.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
KERNELS := $(VENV)/.kernels
OUT ?= out/demo
# The tested versions (pip -c); `make install CONSTRAINTS=` takes the newest in pyproject's ranges instead
CONSTRAINTS ?= constraints.txt
PIP_CONSTRAINTS := $(if $(CONSTRAINTS),-c $(CONSTRAINTS))

.PHONY: demo test bench install clean constraints

$(BIN)/python:
	$(PYTHON) -m venv $(VENV)
	$(BIN)/pip install --quiet --upgrade pip

# Re-install whenever pyproject.toml or the constraints change. The bytecode of the installed packages is compiled
# afterwards on every core (pip compiles its 5949 modules one after another on one core: 13-17 of its 27 CPU-s;
# docs/testing.md). As with pip, a module that does not compile is left to the interpreter.
$(STAMP): pyproject.toml $(CONSTRAINTS) | $(BIN)/python
	$(BIN)/pip install --quiet --no-compile $(PIP_CONSTRAINTS) -e ".[test]"
	$(BIN)/python -m compileall -qq -j 0 $(VENV)/lib || true
	touch $(STAMP)

# The numba kernels a demo run calls, compiled into their cache (__pycache__ beside each module) before the first
# run, on every core: else the first run compiles them one after another on one core (aerotri/core/precompile.py,
# docs/testing.md). A kernel changed later compiles on its next call, as without this step.
$(KERNELS): $(STAMP) aerotri/core/numba_signatures.txt
	$(BIN)/python -m aerotri.core.precompile
	touch $(KERNELS)

install: $(KERNELS)

demo: $(KERNELS)
	$(BIN)/aerotri demo $(OUT)

# One pytest-xdist worker per core (at most 4), see docs/testing.md; `make test PYTEST_ARGS=tests/ortho` runs a subset.
# The 15 slowest tests are listed at the end: the suite's 10-minute budget is watched from there.
test: $(KERNELS)
	$(BIN)/python -m pytest -q -n auto --maxprocesses 4 --dist worksteal --durations=15 $(PYTEST_ARGS)

bench: $(KERNELS)
	# headless Chromium and pdftoppm for bench/render_reports.py (what a reviewer sees), gdal_contour for
	# bench/eval_contours.py; bench only
	if ! command -v chromium >/dev/null || ! command -v pdftoppm >/dev/null || ! command -v gdal_contour >/dev/null; then \
		$$( [ "$$(id -u)" = 0 ] || echo sudo ) apt-get install -y chromium poppler-utils gdal-bin; fi
	$(BIN)/pip install --quiet $(PIP_CONSTRAINTS) -e ".[test,bench]"
	$(BIN)/pip install --quiet --no-deps "orthority>=0.4"
	@for b in bench/*.py; do echo "== $$b"; $(BIN)/python $$b || exit 1; done

# After the suite has passed on .venv: its versions become the tested set (the header lines are kept)
constraints: $(STAMP)
	{ grep '^#' constraints.txt; $(BIN)/pip freeze --exclude-editable; } > constraints.txt.tmp && mv constraints.txt.tmp constraints.txt

clean:
	rm -rf out .pytest_cache
