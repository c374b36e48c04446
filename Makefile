# make demo      set up .venv, render SPD balls at 512x512 to balls.png, print the statistics
# make test      set up .venv, run the test suite (slow tests excluded)
# make test-all  the whole suite, slow tests and the site's test included
# make docs      build the documentation site into docs/_build/html (warnings are errors)
# make test-docs build the site and open every page in headless Chromium (needs chromium, chromium-driver)
# The suite's time is mostly numba compiling kernel variants, one core each: TEST_WORKERS
# processes (pytest-xdist, one test file each at a time) compile different variants side by side.
PYTHON ?= python3
TEST_WORKERS ?= 2
VENV := .venv
PY := $(VENV)/bin/python
CORE := $(VENV)/.core
STAMP := $(VENV)/.installed

.PHONY: demo test test-all docs test-docs clean

# the demo needs only the core install; the suite and the site every extra they exercise
$(CORE): pyproject.toml
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e .
	$(PY) -m compileall -q src/raykernel    # bytecode, as pip writes for an installed package (not for -e)
	touch $(CORE)

$(STAMP): $(CORE)
	$(PY) -m pip install --quiet -e '.[test,distributed,cast,video,docs,explore]'
	touch $(STAMP)

demo: $(CORE)
	$(VENV)/bin/raykernel render spd:balls -o balls.png --resolution 512

test: $(STAMP)
	$(PY) -m pytest -q -n $(TEST_WORKERS) --dist loadfile

test-all: $(STAMP)
	$(PY) -m pytest -q -n $(TEST_WORKERS) --dist loadfile -m ''

docs: $(STAMP)
	$(PY) -m sphinx -W --keep-going -q -b html docs docs/_build/html
	@echo "docs/_build/html/index.html"

test-docs: $(STAMP)
	$(PY) -m pytest -q -m docs tests/test_docs_site.py

clean:
	rm -rf $(VENV) build src/*.egg-info docs/_build docs/auto_examples
