# The commands of the README. Each creates (or reuses) .venv/ with the pinned
# ROS 2 Kilted wheels, the package (editable) and its test tools, then runs.
PYTHON ?= python3.11
VENV   := .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed

# DDS stays on this machine; tests pick their own domain ids on top of this.
export ROS_AUTOMATIC_DISCOVERY_RANGE ?= LOCALHOST

# The upstream launch wheels (launch, launch_ros, launch_pytest...; not on the package index),
# beside the clone in CI and on developers' machines.
ROS_TOOLING ?= ../shared/ros-tooling
LVENV   := .venv-launch
LPY     := $(LVENV)/bin/python
LSTAMP  := $(LVENV)/.installed
LBUILD  := build-launch
# Python 3.12 as on Ubuntu 24.04 (with pyenv: PYTHON312=$$(pyenv prefix 3.12.1)/bin/python3.12).
PYTHON312 ?= python3.12
VENV312 := .venv-py312
# The core and node tests (no graph of several processes): what 3.12 could break.
PY312_TESTS ?= test/test_package.py test/test_power_law.py test/test_geometry.py \
  test/test_feedback.py test/test_channels.py test/test_calibration.py test/test_gaze_wire.py \
  test/test_core_properties.py test/test_speech_task_conditions.py test/test_plc_register_map.py \
  test/test_plc_sequence.py test/test_plc_modbus.py test/test_node_pressure_controller.py \
  test/test_node_target_selector.py test/test_node_gaze_bridge.py test/test_node_plc.py \
  test/test_shutdown.py
SITE    := import sysconfig; print(sysconfig.get_path('purelib'))

.PHONY: demo test test-launch test-py312 bench venv clean

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
	@if [ -d "$(ROS_TOOLING)" ]; then $(MAKE) --no-print-directory test-launch; else \
	  echo "SKIPPED launch_pytest tests and colcon build check:" \
	    "$(ROS_TOOLING) is absent (docs/launch.md)"; fi

# .venv-launch: its own pytest 7.4.4, colcon and the launch wheels; everything else (rclpy, the
# pinned wheels, the package) from .venv through a .pth file, which site processes after the
# venv's own site-packages: the venv's pytest wins.
$(LSTAMP): $(STAMP) requirements/launch.txt
	@test -x $(LPY) || $(PYTHON) -m venv $(LVENV)
	$(PY) test/launch_venv_pth.py > "$$($(LPY) -c "$(SITE)")/zz_fabric_guidance_venv.pth"
	$(LPY) -m pip install --quiet --disable-pip-version-check -r requirements/launch.txt
	$(LPY) -m pip install --quiet --disable-pip-version-check --no-deps $(ROS_TOOLING)/*.whl
	@touch $(LSTAMP)

# colcon build of the package into $(LBUILD)/ as a lab builds it, then the launch_pytest tests
# against that install tree (share/, the ament index and lib/fabric_guidance/ from there).
test-launch: $(LSTAMP)
	rm -rf $(LBUILD)
	$(LVENV)/bin/colcon --log-base $(LBUILD)/log build --paths $(CURDIR) \
	  --build-base $(LBUILD)/build --install-base $(LBUILD)/install
	AMENT_PREFIX_PATH=$(abspath $(LBUILD))/install/fabric_guidance \
	  PYTHONPATH=$$(ls -d $(abspath $(LBUILD))/install/fabric_guidance/lib/python3*/site-packages) \
	  FABRIC_GUIDANCE_INSTALL=$(abspath $(LBUILD))/install \
	  $(LVENV)/bin/pytest test/test_launch.py -p no:cacheprovider $(PYTEST_ARGS)

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

# Measures and prints; never fails on a slow machine (the goals are read off bench/results.md).
bench: $(STAMP)
	$(VENV)/bin/fabric-guidance bench --out bench/results.json

clean:
	rm -rf $(VENV) $(LVENV) $(VENV312) $(LBUILD) .pytest_cache .hypothesis *.egg-info
