# User-facing targets: `make demo`, `make test` and `make test-fast`. Each refreshes .venv/ through `make venv`.
SHELL := /bin/bash
PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed

# Every dependency, pinned. torch==2.13.0 resolves to the CPU wheel; a looser pin pulls CUDA builds.
# setuptools<80: newer releases silently break `colcon build --symlink-install`.
PINS := \
	torch==2.13.0 \
	numpy==2.4.6 scipy==1.17.1 \
	ros-rclpy==9.1.2 ros-sensor-msgs==5.5.1 ros-rmw-fastrtps-cpp==9.3.3 \
	colcon-core==0.21.3 colcon-ros==0.5.0 colcon-python-setup-py==0.2.9 colcon-bash==0.5.0 \
	"setuptools<80" \
	safetensors==0.8.0 trimesh==5.2.0 manifold3d==3.5.4 rtree==1.4.1 pypcd4==1.5.1 \
	tqdm==4.70.1 matplotlib==3.11.2 \
	pytest==9.2.0 hypothesis==6.170.15 ruff==0.17.6

.PHONY: venv demo test test-fast lint bench eval train clean

venv: $(STAMP)

$(STAMP): Makefile setup.py package.xml
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip install -q $(PINS)
	$(PY) -m pip install -q --no-deps --no-build-isolation -e .
	touch $(STAMP)

# `make demo`: colcon-build into out/ws, run the installed node, replay the shipped Kinect frames, draw out/*.png.
WS := out/ws
demo: venv
	$(VENV)/bin/colcon --log-base $(WS)/log build --base-paths . \
		--build-base $(WS)/build --install-base $(WS)/install
	$(PY) -m triplet_normal_ros.ros.demo --prefix $(WS)/install/triplet_normal_ros --out out

lint: venv
	$(VENV)/bin/ruff check --config .ci/ruff.toml triplet_normal_ros test

# `make test` (CI): lint, then every test, including the `slow` ones (colcon builds, the node as a separate process,
# training runs, accuracy checks of the shipped checkpoint, eval --quick, CLI subprocesses).
test: venv lint
	$(PY) -m pytest test -q --strict-markers

# `make test-fast`: the tests not marked `slow`, for the edit-test loop; `make test` before committing.
test-fast: venv
	$(PY) -m pytest test -q --strict-markers -m "not slow"

# Offline tools on the shipped data and checkpoint (see docs/CLI.md, docs/TRAINING.md).
train: venv
	$(VENV)/bin/triplet-normal train --recipe cpu --run-dir out/train_cpu

eval: venv
	$(VENV)/bin/triplet-normal eval --pcpnet-dir ../shared/data/pcpnet --out docs/RESULTS.md

bench: venv
	$(VENV)/bin/triplet-normal bench --out docs/RESULTS.md

clean:
	rm -rf $(VENV) build install log out .pytest_cache .hypothesis .ruff_cache
