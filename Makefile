# Two-command quick start: `make demo` and `make test`. Both create .venv when missing.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
OUT ?= out/demo

.PHONY: demo test bench install clean

$(BIN)/python:
	$(PYTHON) -m venv $(VENV)
	$(BIN)/pip install --quiet --upgrade pip

# Re-install whenever pyproject.toml changes. The bytecode of the installed packages is compiled afterwards on every
# core (pip compiles its 5949 modules one after another on one core: 13-17 of its 27 CPU-s; docs/testing.md). As with
# pip, a module that does not compile is left to the interpreter.
$(STAMP): pyproject.toml | $(BIN)/python
	$(BIN)/pip install --quiet --no-compile -e ".[test]"
	$(BIN)/python -m compileall -qq -j 0 $(VENV)/lib || true
	touch $(STAMP)

install: $(STAMP)

demo: $(STAMP)
	$(BIN)/aerotri demo $(OUT)

# One pytest-xdist worker per core (at most 4), see docs/testing.md; `make test PYTEST_ARGS=tests/ortho` runs a subset.
# The 15 slowest tests are listed at the end: the suite's 10-minute budget is watched from there.
test: $(STAMP)
	$(BIN)/python -m pytest -q -n auto --maxprocesses 4 --dist worksteal --durations=15 $(PYTEST_ARGS)

bench: $(STAMP)
	# headless Chromium and pdftoppm for bench/render_reports.py (what a reviewer sees), gdal_contour for
	# bench/eval_contours.py; bench only
	if ! command -v chromium >/dev/null || ! command -v pdftoppm >/dev/null || ! command -v gdal_contour >/dev/null; then \
		$$( [ "$$(id -u)" = 0 ] || echo sudo ) apt-get install -y chromium poppler-utils gdal-bin; fi
	$(BIN)/pip install --quiet -e ".[test,bench]"
	$(BIN)/pip install --quiet --no-deps "orthority>=0.4"
	@for b in bench/*.py; do echo "== $$b"; $(BIN)/python $$b || exit 1; done

clean:
	rm -rf out .pytest_cache
