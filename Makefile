# The commands of the README. Each creates (or reuses) .venv/ with the pinned
# ROS 2 Kilted wheels, the package (editable) and its test tools, then runs.
PYTHON ?= python3.11
VENV   := .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed

# DDS stays on this machine; tests pick their own domain ids on top of this.
export ROS_AUTOMATIC_DISCOVERY_RANGE ?= LOCALHOST

.PHONY: demo test bench venv clean system-deps

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

# Measures and prints; never fails on a slow machine (the goals are read off bench/results.md).
bench: $(STAMP)
	$(VENV)/bin/fabric-guidance bench --out bench/results.json

# The distribution's packages some tests use (root; CI runs this before `make test`). Without
# them the PLC program's, mbpoll's and the loopback tests skip with their reason.
SYSTEM_DEPS := g++ make gcc-avr avr-libc arduino-core-avr mbpoll iproute2
system-deps:
	@if [ "$$(id -u)" != 0 ]; then echo "system-deps: run as root (apt-get install $(SYSTEM_DEPS))"; exit 1; fi
	apt-get update -qq || (sleep 10 && apt-get update -qq)
	DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends $(SYSTEM_DEPS) >/dev/null

clean:
	rm -rf $(VENV) .pytest_cache .hypothesis *.egg-info
