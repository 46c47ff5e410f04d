# Two commands: `make demo` and `make test`. Both create .venv on first use; `make demo`
# installs only the runtime dependencies, `make test` adds the test extras.
PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed-runtime
TEST_STAMP := $(VENV)/.installed-test
DOCS_STAMP := $(VENV)/.installed-docs

.PHONY: demo test test-slow lint bench docs docs-generated clean venv

define pip_install
	@test -x $(PY) || $(PYTHON) -m venv $(VENV)
	@if command -v uv >/dev/null 2>&1; then \
		uv pip install --python $(PY) -e '$(1)'; \
	else \
		$(PY) -m pip install --quiet --upgrade pip && \
		$(PY) -m pip install --quiet -e '$(1)'; \
	fi
endef

$(STAMP): pyproject.toml
	$(call pip_install,.)
	@touch $(STAMP)

$(TEST_STAMP): $(STAMP)
	$(call pip_install,.[test])
	@touch $(TEST_STAMP)

$(DOCS_STAMP): $(STAMP)
	$(call pip_install,.[docs])
	@touch $(DOCS_STAMP)

venv: $(STAMP)

demo: $(STAMP)
	$(VENV)/bin/testbed run helicopter --filter kalman --controller lqr --duration 20 --seed 0 \
		--rrd runs/demo.rrd --json runs/demo.json --plot runs/demo.png

test: $(TEST_STAMP)
	$(VENV)/bin/ruff check .
	$(PY) -m pytest -q -m "not slow"

# the long cases (full reproductions, coverage over many units, level and power at the
# standard size, the README's numbers under both OpenBLAS kernels); CI runs them too
test-slow: $(TEST_STAMP)
	$(PY) -m pytest -q -m slow

lint: $(TEST_STAMP)
	$(VENV)/bin/ruff check .

bench: $(TEST_STAMP)
	$(PY) scripts/benchmark.py --json runs/benchmark.json

# The site: docs/*.md (MyST), the tutorial notebook (executed while building) and the API
# reference from the docstrings, into build/docs/html; any warning fails the build.
docs: $(DOCS_STAMP) docs-generated
	rm -rf docs/api
	$(VENV)/bin/sphinx-build -W --keep-going -q -b html docs build/docs/html
	@echo "open build/docs/html/index.html"

# What is generated from the code: the CLI reference from the parser (run it after adding or
# changing a command or an option; tests/test_cli_reference.py fails until then).
docs-generated: $(STAMP)
	$(PY) scripts/cli_reference.py

clean:
	rm -rf $(VENV) runs build dist *.egg-info docs/api
