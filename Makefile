# Two commands do all the set-up: `make run` and `make test` create .venv when it is missing,
# install the pinned requirements and build the twinslam_msgs interface package into it.
PYTHON ?= python3
VENV := $(abspath .venv)
PY := $(VENV)/bin/python
# the editable install maps each top-level package: a package added or renamed reinstalls it
STAMP := $(VENV)/.installed-$(shell (cat requirements.txt setup.py; ls -d */__init__.py) \
	| md5sum | cut -c1-12)
# the interface package is rebuilt whenever a .msg file or its CMake/package files change
MSG_SOURCES := $(sort $(wildcard msg_schemas/msg/*.msg)) msg_schemas/CMakeLists.txt \
	msg_schemas/package.xml
MSGS_STAMP := $(VENV)/.twinslam_msgs-$(shell cat $(MSG_SOURCES) | md5sum | cut -c1-12)
MSGS_BUILD := build/twinslam_msgs
# the modules with numba kernels (compiled once at set-up, recompiled when one changes)
KERNEL_SOURCES := $(sort $(shell grep -l -r --include=*.py "@njit" device_tracker edge_mapper \
	udt_node twinslam))
KERNELS_STAMP := $(VENV)/.kernels-$(shell cat $(KERNEL_SOURCES) | md5sum | cut -c1-12)

.PHONY: venv msgs kernels run test lint bench clean

venv: $(STAMP) $(MSGS_STAMP) $(KERNELS_STAMP)

$(STAMP): requirements.txt setup.py
	@test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --disable-pip-version-check -r requirements.txt
	$(PY) -m pip install --quiet --disable-pip-version-check --no-deps --no-build-isolation -e .
	@rm -f $(VENV)/.installed-* && touch $@

# rosidl through CMake into the venv prefix, which the ROS wheels made an ament prefix: the
# generated Python package lands in site-packages, its libraries in .venv/lib (on the loader
# path the wheels' bootstrapper sets). Fresh build directory each time: a removed .msg must not
# leave its generated code behind.
msgs: $(MSGS_STAMP)

$(MSGS_STAMP): $(STAMP) $(MSG_SOURCES)
	@echo "building the twinslam_msgs interface package (rosidl, ~40 s)"
	@rm -rf $(MSGS_BUILD) && mkdir -p $(MSGS_BUILD)
	cd $(MSGS_BUILD) && PATH=$(VENV)/bin:$$PATH AMENT_PREFIX_PATH=$(VENV) \
	  CMAKE_PREFIX_PATH=$(VENV) cmake $(CURDIR)/msg_schemas -DCMAKE_INSTALL_PREFIX=$(VENV) \
	  -DPython3_EXECUTABLE=$(PY) -DBUILD_TESTING=OFF > configure.log 2>&1 \
	  || { tail -40 configure.log; exit 1; }
	cd $(MSGS_BUILD) && PATH=$(VENV)/bin:$$PATH $(MAKE) --no-print-directory -j2 install \
	  > build.log 2>&1 || { grep -iE -B2 -A8 "error" build.log | tail -60; exit 1; }
	$(PY) -c "from twinslam_msgs.msg import MapStats, Keyframe"
	@rm -f $(VENV)/.twinslam_msgs-* && touch $@

# numba compiles on first use: done here, not in the first node start (twinslam/cli/precompile.py)
kernels: $(KERNELS_STAMP)

$(KERNELS_STAMP): $(STAMP) $(MSGS_STAMP) $(KERNEL_SOURCES)
	$(PY) -m twinslam.cli.precompile
	@rm -f $(VENV)/.kernels-* && touch $@

run: venv
	$(VENV)/bin/twinslam demo

test: venv
	$(PY) -m ruff check .
	$(VENV)/bin/lint-imports
	$(PY) -m mypy
	$(PY) -m pytest

lint: venv
	$(PY) -m ruff check .
	$(VENV)/bin/lint-imports
	$(PY) -m mypy

bench: venv
	$(PY) -m bench.dds
	$(PY) -m bench.sim
	$(PY) -m bench.sim --covis room
	$(PY) -m bench.frontend
	$(PY) -m bench.udt
	$(PY) -m bench.pipeline
	$(PY) -m bench.mbrl
	$(PY) -m bench.live --rounds 4 --frames 1000

clean:
	rm -rf $(VENV) build *.egg-info .pytest_cache .ruff_cache .mypy_cache
