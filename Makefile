# User-facing targets: `make demo`, `make test` and `make test-fast`. Each refreshes .venv/ through `make venv`;
# `make test` also tests on ROS 2 Jazzy in .venv-jazzy/ (`make test-jazzy`) and a subset on Python 3.10 and 3.12 in
# .venv-py3.10/ and .venv-py3.12/ (`make test-pythons`).
SHELL := /bin/bash
PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed

# Every dependency, pinned. torch==2.13.0 is whatever build pip finds first: here the local CPU wheel (/opt/wheels),
# elsewhere PyPI's CUDA build (several GB). docs/CHOOSING.md, "Installing and testing", says how to choose the CPU or CUDA build.
# setuptools<80: newer releases silently break `colcon build --symlink-install`.
# ROS 2 comes from PyPI wheels: Kilted in .venv/, Jazzy (the LTS; Fast DDS 2) in .venv-jazzy/.
KILTED := ros-rclpy==9.1.2 ros-sensor-msgs==5.5.1 ros-rmw-fastrtps-cpp==9.3.3 ros-diagnostic-msgs==5.5.1 \
	ros-visualization-msgs==5.5.1 ros-lifecycle-msgs==2.3.0
JAZZY := ros-rclpy==7.1.6 ros-sensor-msgs==5.3.6 ros-rmw-fastrtps-cpp==8.4.3 ros-diagnostic-msgs==5.3.6 \
	ros-visualization-msgs==5.3.6 ros-lifecycle-msgs==2.0.3
COMMON := \
	torch==2.13.0 \
	numpy==2.4.6 scipy==1.17.1 numba==0.68.1 llvmlite==0.50.0 \
	colcon-core==0.21.3 colcon-ros==0.5.0 colcon-python-setup-py==0.2.9 colcon-bash==0.5.0 \
	"setuptools<80" \
	rosbags==0.11.9 safetensors==0.8.0 trimesh==5.2.0 manifold3d==3.5.4 rtree==1.4.1 pypcd4==1.5.1 \
	tqdm==4.70.1 matplotlib==3.11.2 \
	ray==2.60.0 \
	pytest==9.2.0 hypothesis==6.170.15 ruff==0.17.6 vermin==1.9.2
PINS := $(COMMON) $(KILTED)

.PHONY: venv venv-jazzy demo test test-jazzy test-pythons test-fast lint bench eval train clean

venv: $(STAMP)

# One line per step; pip's own output only when a step fails (the editable install's is kept in $(VENV)/install.log).
# editable_mode=compat: a plain .pth path entry, which PYTHONPATH (a colcon install's setup.bash, the tests, the demo)
# precedes; setuptools' default finder would hand any module the colcon install lacks to the source tree instead.
$(STAMP): Makefile setup.py package.xml
	@echo "make venv: [1/3] virtual environment in $(VENV)/"
	@test -x $(PY) || $(PYTHON) -m venv $(VENV)
	@echo "make venv: [2/3] installing pinned dependencies (first run takes a few minutes)"
	@$(PY) -m pip install -q --upgrade pip
	@$(PY) -m pip install -q $(PINS)
	@echo "make venv: [3/3] installing triplet_normal_ros itself (editable)"
	@$(PY) -m pip install -q --no-deps --no-build-isolation -e . --config-settings editable_mode=compat \
		>$(VENV)/install.log 2>&1 \
		|| { cat $(VENV)/install.log; exit 1; }
	@touch $(STAMP)

# The same, with Jazzy's wheels: what a Jazzy robot runs (rclpy 7, Fast DDS 2, messages 5.3).
JAZZY_VENV := .venv-jazzy
JAZZY_PY := $(JAZZY_VENV)/bin/python
JAZZY_STAMP := $(JAZZY_VENV)/.installed
venv-jazzy: $(JAZZY_STAMP)
$(JAZZY_STAMP): Makefile setup.py package.xml
	@echo "make venv-jazzy: virtual environment with ROS 2 Jazzy's wheels in $(JAZZY_VENV)/"
	@test -x $(JAZZY_PY) || $(PYTHON) -m venv $(JAZZY_VENV)
	@$(JAZZY_PY) -m pip install -q --upgrade pip
	@$(JAZZY_PY) -m pip install -q $(COMMON) $(JAZZY)
	@$(JAZZY_PY) -m pip install -q --no-deps --no-build-isolation -e . --config-settings editable_mode=compat \
		>$(JAZZY_VENV)/install.log 2>&1 \
		|| { cat $(JAZZY_VENV)/install.log; exit 1; }
	@touch $(JAZZY_STAMP)

# `make demo`: colcon-build into out/ws, run the installed node, replay the shipped Kinect frames, draw out/*.png.
WS := out/ws
demo: venv
	@echo "make demo: colcon build into $(WS)/, the CPU kernels compiled into it (its log: $(WS)/log/latest_build)"
	@$(VENV)/bin/colcon --log-base $(WS)/log build --base-paths . \
		--build-base $(WS)/build --install-base $(WS)/install --event-handlers console_direct- console_start_end- \
		|| { echo "make demo: colcon build failed; see $(WS)/log/latest_build" >&2; exit 1; }
	@echo "make demo: running the installed node on the shipped frames"
	@$(PY) -m triplet_normal_ros.ros.tools.demo --prefix $(WS)/install/triplet_normal_ros --out out

# vermin: the lowest Python the code needs must stay setup.py's python_requires (3.10, Humble's Ubuntu 22.04).
MIN_PYTHON := 3.10
lint: venv
	$(VENV)/bin/ruff check --config .ci/ruff.toml triplet_normal_ros test docs/tools
	$(VENV)/bin/vermin --no-tips --violations --eval-annotations -t=$(MIN_PYTHON)- triplet_normal_ros launch test docs/tools setup.py
	$(VENV)/bin/ruff format --check --config .ci/ruff.toml triplet_normal_ros test docs/tools launch setup.py

# `make test` (CI): lint, then every test, including the `slow` ones (colcon builds, the node as a separate process,
# training runs, accuracy checks of the shipped checkpoint, eval --quick, CLI subprocesses).
test: venv lint
	$(PY) -m pytest test -q --strict-markers
	@$(MAKE) --no-print-directory test-jazzy
	@$(MAKE) --no-print-directory test-pythons

# `make test-jazzy`: on Jazzy, what differs between distributions: the colcon-built node as a process, its transport
# (full 640x480 frames from another process), parameters, the launch file, the per-message step and `bag`.
JAZZY_TESTS := test/ros/test_transport.py test/ros/test_large_clouds.py test/ros/test_node_process.py \
	test/ros/test_params.py test/ros/test_one_rule.py test/test_launch.py test/ros/test_launch_process.py \
	test/ros/test_managed_node.py test/ros/test_watchdog_exit.py test/ros/test_stop_while_starting.py \
	test/ros/test_visuals_process.py test/ros/test_first_start.py test/pipeline test/cli/test_bag.py
test-jazzy: venv-jazzy
	$(JAZZY_PY) -m pytest $(JAZZY_TESTS) -q --strict-markers

# `make test-pythons`: the core, its compiled kernels from an empty cache, a fresh colcon build's node on a real frame
# and `bag`, on Python 3.10 (Humble's Ubuntu 22.04) and 3.12 (native Jazzy and Kilted on Ubuntu 24.04), with Kilted's
# wheels (they exist for cp310-cp312). The interpreter: python3.X on PATH, else pyenv's newest 3.X. There torch==2.13.0
# is PyPI's CUDA build (about 2.6 GB of downloads, 5 GB installed per venv), which runs on the CPU. numpy, scipy and
# hypothesis: .venv's pins on 3.12, and on 3.10 the newest releases that still support it.
OTHER_PYTHONS := 3.10 3.12
PY_TESTS := test/test_python_version.py test/core/test_estimator.py test/core/test_kernels.py \
	test/ros/test_first_start.py test/cli/test_bag.py
OTHER_PINS := torch==2.13.0 numba==0.68.1 llvmlite==0.50.0 \
	colcon-core==0.21.3 colcon-ros==0.5.0 colcon-python-setup-py==0.2.9 colcon-bash==0.5.0 "setuptools<80" \
	rosbags==0.11.9 safetensors==0.8.0 trimesh==5.2.0 manifold3d==3.5.4 rtree==1.4.1 pypcd4==1.5.1 tqdm==4.70.1 \
	pytest==9.2.0 $(KILTED)
PINS_3.10 := numpy==2.2.6 scipy==1.15.3 hypothesis==6.168.5
PINS_3.12 := numpy==2.4.6 scipy==1.17.1 hypothesis==6.170.15
# python3.X that runs (a pyenv shim of an unselected version does not), else pyenv's newest 3.X; empty if neither.
find_python = $(shell for p in python$(1) $$(ls -d $$HOME/.pyenv/versions/$(1).*/bin/python$(1) 2>/dev/null | sort -V \
	| tail -1); do "$$p" -c pass 2>/dev/null && { command -v "$$p"; break; }; done)
test-pythons: $(addprefix test-py,$(OTHER_PYTHONS))
test-py%:
	@if [ -z "$(call find_python,$*)" ]; then \
		echo "make test-py$*: no Python $* here (neither python$* nor pyenv's $*.x): its subset did not run"; \
	else $(MAKE) --no-print-directory .venv-py$*/.installed && .venv-py$*/bin/python -m pytest $(PY_TESTS) -q \
		--strict-markers -p no:cacheprovider; fi
.venv-py%/.installed: Makefile setup.py package.xml
	@echo "make test-py$*: virtual environment with $(call find_python,$*) in .venv-py$*/ (first run: a few minutes)"
	@test -x .venv-py$*/bin/python || $(call find_python,$*) -m venv .venv-py$*
	@.venv-py$*/bin/python -m pip install -q --upgrade pip
	@.venv-py$*/bin/python -m pip install -q $(OTHER_PINS) $(PINS_$*)
	@.venv-py$*/bin/python -m pip install -q --no-deps --no-build-isolation -e . --config-settings editable_mode=compat \
		>.venv-py$*/install.log 2>&1 || { cat .venv-py$*/install.log; exit 1; }
	@touch $@

# `make test-fast`: the tests not marked `slow`, for the edit-test loop; `make test` before committing.
test-fast: venv
	$(PY) -m pytest test -q --strict-markers -m "not slow"

# Offline tools on the shipped data and checkpoint (see docs/CLI.md, docs/TRAINING.md).
train: venv
	$(VENV)/bin/triplet-normal train --recipe scales --run-dir out/train_scales

eval: venv
	$(VENV)/bin/triplet-normal eval --pcpnet-dir ../shared/data/pcpnet --out docs/RESULTS.md --update-tracked

bench: venv
	$(VENV)/bin/triplet-normal bench --out docs/RESULTS.md --update-tracked

clean:
	rm -rf $(VENV) $(JAZZY_VENV) .venv-py* build install log out .pytest_cache .hypothesis .ruff_cache
