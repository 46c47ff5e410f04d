# Two commands: `make demo` and `make test`. Both create .venv on first use; `make demo`
# installs only the runtime dependencies, `make test` adds the test extras.
PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed-runtime
TEST_STAMP := $(VENV)/.installed-test

.PHONY: demo test lint bench clean venv

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

venv: $(STAMP)

demo: $(STAMP)
	$(VENV)/bin/testbed run helicopter --filter kalman --controller lqr --duration 20 --seed 0 \
		--rrd runs/demo.rrd --json runs/demo.json --plot runs/demo.png

test: $(TEST_STAMP)
	$(VENV)/bin/ruff check .
	$(PY) -m pytest -q

lint: $(TEST_STAMP)
	$(VENV)/bin/ruff check .

bench: $(TEST_STAMP)
	$(PY) scripts/benchmark.py --json runs/benchmark.json

clean:
	rm -rf $(VENV) runs build dist *.egg-info
