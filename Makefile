# The commands of the README. Each creates (or reuses) .venv/ with the pinned
# ROS 2 Kilted wheels, the package (editable) and its test tools, then runs.
PYTHON ?= python3.11
VENV   := .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed

# DDS stays on this machine; tests pick their own domain ids on top of this.
export ROS_AUTOMATIC_DISCOVERY_RANGE ?= LOCALHOST

# The upstream launch wheels (launch, launch_ros, launch_pytest...; not on the package index),
# beside the clone in CI and on developers' machines: ROS 2 Kilted's in ROS_TOOLING, Jazzy's in
# ROS_TOOLING/jazzy. The launch stage runs once per distribution (LAUNCH_DISTRO), each in a venv
# and a colcon build tree of its own.
ROS_TOOLING ?= ../shared/ros-tooling
LAUNCH_DISTRO ?= kilted
ifeq ($(LAUNCH_DISTRO),jazzy)
LVENV   := .venv-launch-jazzy
# launch_ros imports composition_interfaces when it loads: the placeholder wheel beside Kilted's.
LWHEELS  = $(ROS_TOOLING)/jazzy/*.whl $(ROS_TOOLING)/composition_interfaces-*.whl
LBUILD  := build-launch-jazzy
else ifeq ($(LAUNCH_DISTRO),kilted)
LVENV   := .venv-launch
LWHEELS  = $(ROS_TOOLING)/*.whl
LBUILD  := build-launch
else
$(error LAUNCH_DISTRO=$(LAUNCH_DISTRO): kilted or jazzy)
endif
LPY     := $(LVENV)/bin/python
LSTAMP  := $(LVENV)/.installed
# Python 3.12 as on Ubuntu 24.04 (with pyenv: PYTHON312=$$(pyenv prefix 3.12.1)/bin/python3.12).
PYTHON312 ?= python3.12
VENV312 := .venv-py312
# The core and node tests (no graph of several processes): what 3.12 could break.
PY312_TESTS ?= test/test_package.py test/test_power_law.py test/test_geometry.py \
  test/test_feedback.py test/test_channels.py test/test_calibration.py test/test_gaze_wire.py \
  test/test_gaze_sequence.py test/test_core_properties.py test/test_guidance_properties.py \
  test/test_speech_task_conditions.py \
  test/test_plc_register_map.py test/test_plc_sequence.py test/test_plc_modbus.py test/test_node_pressure_controller.py \
  test/test_node_target_selector.py test/test_node_gaze_bridge.py test/test_node_plc.py \
  test/test_shutdown.py
SITE    := import sysconfig; print(sysconfig.get_path('purelib'))

.PHONY: flakes test-hololens demo test test-deep test-launch test-launch-jazzy test-launch-all test-py312 bench chaos soak \
  venv clean system-deps system-deps-if-root test-pymodbus bids-validator

venv: $(STAMP)

$(STAMP): requirements/standalone.txt requirements/test.txt setup.py
	@test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --disable-pip-version-check -r requirements/standalone.txt -r requirements/test.txt
	$(PY) -m pip install --quiet --disable-pip-version-check --no-deps -e .
	@touch $(STAMP)

demo: $(STAMP)
	$(VENV)/bin/fabric-guidance demo

# The suite, then the Modbus tests under the other supported pymodbus releases, then the
# launch files under the real launch system of Kilted and of Jazzy (where the ros-tooling wheels
# are beside the clone). As root, first the distribution's packages the tests need (system-deps);
# otherwise, at the end, one block naming the groups of tests skipped and the command that runs them.
# pytest runs on PYTEST_WORKERS pytest-xdist workers, each taking whole files (module fixtures
# and module-end reports stay in one process). Graph tests mostly wait on DDS and the clock: on two
# workers the two cores were busy 62 % of the suite's 15 min, three workers take it to about 12
# (each graph test then shares the cores with two others, less than `make flakes` puts beside
# them). Tests marked serial run alone (test/conftest.py). PYTEST_WORKERS=0:
# one process, as before. --durations: the slowest tests named in every run's log (the suite's
# length is watched there).
PYTEST_WORKERS ?= 3
# Each stage's time is printed as it ends and all of them at the end (test/stage.sh).
STAGES := .test-stages
STAGE = test/stage.sh $(STAGES)
test: $(STAMP)
	@rm -f $(STAGES)
	@$(STAGE) system-deps $(MAKE) --no-print-directory system-deps-if-root
	@$(STAGE) bids-validator $(MAKE) --no-print-directory bids-validator
	@$(STAGE) hololens $(MAKE) --no-print-directory test-hololens
	@$(STAGE) pytest $(PY) -m pytest -n $(PYTEST_WORKERS) --dist loadfile --durations=15
	@$(STAGE) pymodbus $(MAKE) --no-print-directory test-pymodbus
	@if [ -d "$(ROS_TOOLING)" ]; then $(STAGE) launch-kilted $(MAKE) --no-print-directory test-launch LAUNCH_DISTRO=kilted && \
	  $(STAGE) launch-jazzy $(MAKE) --no-print-directory test-launch LAUNCH_DISTRO=jazzy; else \
	  echo "SKIPPED launch_pytest tests and colcon build check:" \
	    "$(ROS_TOOLING) is absent (docs/launch.md)"; fi
	@$(PY) test/skipped_groups.py "$(ROS_TOOLING)"
	@echo "make test stages:"; cat $(STAGES)

# Both distributions' launch stages, Kilted's then Jazzy's.
test-launch-all:
	$(MAKE) --no-print-directory test-launch LAUNCH_DISTRO=kilted
	$(MAKE) --no-print-directory test-launch LAUNCH_DISTRO=jazzy

test-launch-jazzy:
	$(MAKE) --no-print-directory test-launch LAUNCH_DISTRO=jazzy

# .venv-launch: its own pytest 7.4.4, colcon and the launch wheels; everything else (rclpy, the
# pinned wheels, the package) from .venv through a .pth file, which site processes after the
# venv's own site-packages: the venv's pytest wins.
$(LSTAMP): $(STAMP) requirements/launch.txt
	@test -x $(LPY) || $(PYTHON) -m venv $(LVENV)
	$(PY) test/launch_venv_pth.py > "$$($(LPY) -c "$(SITE)")/zz_fabric_guidance_venv.pth"
	$(LPY) -m pip install --quiet --disable-pip-version-check -r requirements/launch.txt
	$(LPY) -m pip install --quiet --disable-pip-version-check --no-deps $(LWHEELS)
	@touch $(LSTAMP)

# colcon build of the package into $(LBUILD)/ as a lab builds it, then the launch_pytest tests
# against that install tree (share/, the ament index and lib/fabric_guidance/ from there).
# Bounded: launch_pytest waits forever for a launch description that raised (it logs the error
# to ~/.ros/log/*/launch.log and never becomes ready to test).
LAUNCH_TIMEOUT_S ?= 600
test-launch: $(LSTAMP)
	rm -rf $(LBUILD)
	$(LVENV)/bin/colcon --log-base $(LBUILD)/log build --paths $(CURDIR) \
	  --build-base $(LBUILD)/build --install-base $(LBUILD)/install
	AMENT_PREFIX_PATH=$(abspath $(LBUILD))/install/fabric_guidance \
	  PYTHONPATH=$$(ls -d $(abspath $(LBUILD))/install/fabric_guidance/lib/python3*/site-packages) \
	  FABRIC_GUIDANCE_INSTALL=$(abspath $(LBUILD))/install FABRIC_GUIDANCE_LAUNCH_DISTRO=$(LAUNCH_DISTRO) \
	  timeout -k 10 $(LAUNCH_TIMEOUT_S) $(LVENV)/bin/pytest test/test_launch.py test/test_launch_dry_run.py test/test_workspace.py \
	    -p no:cacheprovider $(PYTEST_ARGS)

# Not part of `make test` (a second full venv takes a few minutes on a cold pip cache).
# --no-build-isolation: the package is installed by the venv's own setuptools 68, as on the lab PC.
$(VENV312)/.installed: requirements/standalone.txt requirements/py312.txt setup.py
	@test -x $(VENV312)/bin/python || $(PYTHON312) -m venv $(VENV312)
	$(VENV312)/bin/python -m pip install --quiet --disable-pip-version-check \
	  -r requirements/standalone.txt -r requirements/py312.txt
	$(VENV312)/bin/python -m pip install --quiet --disable-pip-version-check --no-deps \
	  --no-build-isolation -e .
	@touch $@

test-py312: $(VENV312)/.installed
	$(VENV312)/bin/python -m pytest -p no:cacheprovider $(PY312_TESTS)

# The Modbus tests under the other pymodbus releases the package supports (package.xml):
# Ubuntu 24.04's python3-pymodbus 3.6.9 and the newest release below package.xml's bound (the pin
# 3.9.2 is .venv's): a bound, so that a new pymodbus release cannot fail CI overnight.
# Each extra venv holds pymodbus alone; a .pth file appends .venv's site-packages behind it,
# so ROS wheels, pytest and the package come from .venv and are not installed again.
# The tests: the client and mock, plc_output against one and two mock PLCs (its link states),
# and the contract suite's mock half (the PLC program's half uses no pymodbus). Under 2 minutes.
PYMODBUS_VERSIONS ?= 3.6.9 latest
MODBUS_TESTS ?= test/test_plc_modbus.py test/test_plc_endpoints.py test/test_node_plc.py::TestCommands \
                $(wildcard test/test_plc_contract.py test/test_plc_safety.py)
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

# The headset library's C# core and its tests (hololens/, Debian's mcs and mono); the graph tests
# in pytest run the same build against the nodes. Without mono: one SKIPPED line.
test-hololens:
	@if command -v mcs >/dev/null && command -v mono >/dev/null; then \
	  $(MAKE) --no-print-directory -C hololens all test; else \
	  echo "SKIPPED hololens C# tests: mcs/mono absent (make system-deps installs mono-mcs mono-runtime)"; fi

# Measures and prints; never fails on a slow machine (the goals are read off bench/results.md).
bench: $(STAMP)
	$(VENV)/bin/fabric-guidance bench --out bench/results.json

# The long chaos run (docs/soak_and_chaos.md): FAULTS seeded faults on the lab graph, every
# invariant checked from the mock PLC's register log; table, logs and bags in chaos/seed-SEED/.
# `make test` runs the short form (test/test_chaos.py).
SEED ?= 1
FAULTS ?= 40
chaos: $(STAMP)
	$(VENV)/bin/fabric-guidance chaos --seed $(SEED) --faults $(FAULTS) --out chaos/seed-$(SEED)

# The soak run (docs/soak_and_chaos.md): the simulated graph guiding target after target for
# MINUTES; a row of figures per minute, a plot and a verdict on drift in soak/.
# `make test` runs the short form (test/test_soak.py).
MINUTES ?= 60
soak: $(STAMP)
	$(VENV)/bin/fabric-guidance soak --minutes $(MINUTES) --out soak

# The distribution's packages some tests use (root; `make test` runs this first as root). Without
# them the PLC program's, mbpoll's, the headset's (C#), the loopback and the future-stamp
# (faketime) tests skip with their reason, and `make test` names them at the end
# (test/skipped_groups.py). Only what is missing is installed: nothing is fetched when all are there.
SYSTEM_DEPS := g++ make gcc-avr avr-libc arduino-core-avr mbpoll iproute2 mono-mcs mono-runtime nodejs faketime
# npm: Debian's package where no npm is there (NodeSource's nodejs brings its own and conflicts with it).
system-deps:
	@if [ "$$(id -u)" != 0 ]; then echo "system-deps: run as root (apt-get install $(SYSTEM_DEPS))"; exit 1; fi
	@missing=$$(for p in $(SYSTEM_DEPS); do \
	  dpkg-query -W -f='$${Status}\n' $$p 2>/dev/null | grep -q 'install ok installed' || echo $$p; done; \
	  command -v npm >/dev/null || echo npm); \
	if [ -z "$$missing" ]; then echo "system-deps: $(SYSTEM_DEPS) installed"; else \
	  echo "system-deps: installing" $$missing; \
	  (apt-get update -qq || (sleep 10 && apt-get update -qq)) && \
	  DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends $$missing >/dev/null; fi

# As root on a Debian or Ubuntu machine: system-deps. Otherwise nothing (the summary at the end of
# `make test` says what that skipped).
system-deps-if-root:
	@if [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null && command -v dpkg-query >/dev/null; then \
	  $(MAKE) --no-print-directory system-deps; fi

# The BIDS validator (npm's, 1.x) the study folder is held to (test_study_bids), pinned, installed
# into a folder of the project's own; without npm the test skips with its reason.
BIDS_VALIDATOR_VERSION := 1.15.0
BIDS_VALIDATOR := .npm-bids/node_modules/.bin/bids-validator
bids-validator:
	@if ! command -v npm >/dev/null; then \
	  echo "SKIPPED bids-validator: npm absent (make system-deps installs nodejs npm)"; \
	elif [ "$$($(BIDS_VALIDATOR) --version 2>/dev/null)" != "$(BIDS_VALIDATOR_VERSION)" ]; then \
	  npm install --prefix .npm-bids --no-audit --no-fund --loglevel=error bids-validator@$(BIDS_VALIDATOR_VERSION); fi

clean:
	rm -rf $(VENV) .venv-launch .venv-launch-jazzy $(VENV312) build-launch build-launch-jazzy .venv-pymodbus-* \
	  .pytest_cache .hypothesis .npm-bids \
	  *.egg-info

# The flake finder: the graph and timing-sensitive tests RUNS times under LOAD busy processes
# (default one per core), each test's pass rate, the logs of a failed run kept in flakes/run-N/
# (test/flake_finder.py). Run it before submitting a change to graph or timing code; fix every
# test it shows failing at its cause.
RUNS ?= 3
LOAD ?= $(shell nproc)
flakes: $(STAMP)
	@$(MAKE) --no-print-directory system-deps-if-root
	@$(MAKE) --no-print-directory bids-validator
	@$(MAKE) --no-print-directory -C hololens all >/dev/null 2>&1 || true
	$(PY) test/flake_finder.py --runs $(RUNS) --load $(LOAD) $(if $(FLAKE_ARGS),-- $(FLAKE_ARGS))
