# make demo      set up .venv, render SPD balls at 512x512 to balls.png, print the statistics
# make test      set up .venv, run the test suite (slow tests excluded)
# make test-all  the whole suite, slow tests included
# The suite's time is mostly numba compiling kernel variants, one core each: TEST_WORKERS
# processes (pytest-xdist, one test file each at a time) compile different variants side by side.
PYTHON ?= python3
TEST_WORKERS ?= 2
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed

.PHONY: demo test test-all bench clean

$(STAMP): pyproject.toml
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e '.[test,distributed,video]'
	$(PY) -m compileall -q src/raykernel    # bytecode, as pip writes for an installed package (not for -e)
	touch $(STAMP)

demo: $(STAMP)
	$(VENV)/bin/raykernel render spd:balls -o balls.png --resolution 512

test: $(STAMP)
	$(PY) -m pytest -q -n $(TEST_WORKERS) --dist loadfile

test-all: $(STAMP)
	$(PY) -m pytest -q -n $(TEST_WORKERS) --dist loadfile -m ''

clean:
	rm -rf $(VENV) build src/*.egg-info
