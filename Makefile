# The commands of the README. Each creates (or reuses) .venv/ with the pinned
# ROS 2 Kilted wheels, the package (editable) and its test tools, then runs.
PYTHON ?= python3.11
VENV   := .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed

# DDS stays on this machine; tests pick their own domain ids on top of this.
export ROS_AUTOMATIC_DISCOVERY_RANGE ?= LOCALHOST

.PHONY: demo test test-deep bench venv clean

venv: $(STAMP)

$(STAMP): requirements/standalone.txt requirements/test.txt setup.py
	@test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --disable-pip-version-check -r requirements/standalone.txt -r requirements/test.txt
	$(PY) -m pip install --quiet --disable-pip-version-check --no-deps -e .
	@touch $(STAMP)

demo: $(STAMP)
	$(VENV)/bin/fabric-guidance demo

test: $(STAMP)
	$(PY) -m pytest

# The property tests only, with many random examples (test/conftest.py, profile "deep"):
# for people to run now and then; CI runs the fixed, derandomized examples.
test-deep: $(STAMP)
	HYPOTHESIS_PROFILE=deep $(PY) -m pytest -m property -p no:cacheprovider

# Measures and prints; never fails on a slow machine (the goals are read off bench/results.md).
bench: $(STAMP)
	$(VENV)/bin/fabric-guidance bench --out bench/results.json

clean:
	rm -rf $(VENV) .pytest_cache .hypothesis *.egg-info
