# The commands of the README. Each creates (or reuses) .venv/ with the pinned
# ROS 2 Kilted wheels, the package (editable) and its test tools, then runs.
PYTHON ?= python3.11
VENV   := .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed

# DDS stays on this machine; tests pick their own domain ids on top of this.
export ROS_AUTOMATIC_DISCOVERY_RANGE ?= LOCALHOST

.PHONY: demo test test-deep bench venv clean system-deps test-pymodbus

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

# The Modbus tests under the other pymodbus releases the package supports (package.xml):
# Ubuntu 24.04's python3-pymodbus 3.6.9 and the newest release below package.xml's bound (the pin
# 3.9.2 is .venv's): a bound, so that a new pymodbus release cannot fail CI overnight.
# Each extra venv holds pymodbus alone; a .pth file appends .venv's site-packages behind it,
# so ROS wheels, pytest and the package come from .venv and are not installed again.
# The tests: the client and mock, plc_output against one and two mock PLCs (its link states),
# and the contract suite's mock half (the PLC program's half uses no pymodbus). Under 2 minutes.
PYMODBUS_VERSIONS ?= 3.6.9 latest
MODBUS_TESTS ?= test/test_plc_modbus.py test/test_plc_endpoints.py test/test_node_plc.py::TestCommands \
                $(wildcard test/test_plc_contract.py)
MODBUS_SELECT ?= not program
SITE_PACKAGES = $(shell $(PY) -c 'import sysconfig; print(sysconfig.get_paths()["purelib"])')
# The ROS wheels find their shared libraries through sys.prefix (ros_wheels_bootstrapper), which
# is the extra venv's there: hand them .venv's library path, bootstrap already done.
ROS_LIBRARY_PATH = $(shell $(PY) -c 'import ros_wheels_bootstrapper as b; print(b.get_ros_paths())')

test-pymodbus: $(STAMP) $(PYMODBUS_VERSIONS:%=.venv-pymodbus-%/.installed)
	@for v in $(PYMODBUS_VERSIONS); do \
	  .venv-pymodbus-$$v/bin/python -c 'import pymodbus; print("pymodbus", pymodbus.__version__)' && \
	  LD_LIBRARY_PATH='$(ROS_LIBRARY_PATH)' _ROS_WHEELS_BOOTSTRAP_COMPLETE=1 \
	    .venv-pymodbus-$$v/bin/python -m pytest -q -p no:cacheprovider -k '$(MODBUS_SELECT)' \
	    $(MODBUS_TESTS) || exit 1; \
	done

.venv-pymodbus-%/.installed: $(STAMP)
	@test -x $(@D)/bin/python || $(PYTHON) -m venv --without-pip $(@D)
	$(PY) -m pip install --quiet --disable-pip-version-check --upgrade \
	  --target $$($(@D)/bin/python -c 'import sysconfig; print(sysconfig.get_paths()["purelib"])') \
	  $(if $(filter latest,$*),'pymodbus<3.17',pymodbus==$*)
	echo "import site; site.addsitedir('$(SITE_PACKAGES)')" > \
	  $$($(@D)/bin/python -c 'import sysconfig; print(sysconfig.get_paths()["purelib"])')/zz_fabric_guidance_venv.pth
	@touch $@

# The property tests only, with many random examples (test/conftest.py, profile "deep"):
# for people to run now and then; CI runs the fixed, derandomized examples.
test-deep: $(STAMP)
	HYPOTHESIS_PROFILE=deep $(PY) -m pytest -m property -p no:cacheprovider

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
	rm -rf $(VENV) .venv-pymodbus-* .pytest_cache .hypothesis *.egg-info
