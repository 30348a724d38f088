# Two commands do all the set-up: `make run` and `make test` create .venv when it is missing.
PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed-$(shell cat requirements.txt setup.py | md5sum | cut -c1-12)

.PHONY: venv run test lint bench clean

venv: $(STAMP)

$(STAMP): requirements.txt setup.py
	@test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --disable-pip-version-check -r requirements.txt
	$(PY) -m pip install --quiet --disable-pip-version-check --no-deps --no-build-isolation -e .
	@rm -f $(VENV)/.installed-* && touch $@

run: venv
	$(VENV)/bin/twinslam demo

test: venv
	$(PY) -m ruff check .
	$(PY) -m pytest

lint: venv
	$(PY) -m ruff check .

bench: venv
	$(PY) -m bench.dds
	$(PY) -m bench.sim
	$(PY) -m bench.sim --covis room
	$(PY) -m bench.frontend
	$(PY) -m bench.udt
	$(PY) -m bench.pipeline
	$(PY) -m bench.mbrl

clean:
	rm -rf $(VENV) build *.egg-info .pytest_cache .ruff_cache
