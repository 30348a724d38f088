# Two commands do all the set-up: `make run` and `make test` create .venv when it is missing,
# install the pinned requirements and build the twinslam_msgs interface package into it.
PYTHON ?= python3
VENV := $(abspath .venv)
PY := $(VENV)/bin/python
# the editable install maps each top-level package: a package added or renamed reinstalls it
STAMP := $(VENV)/.installed-$(shell (cat requirements.txt setup.py; ls -d */__init__.py) \
	| md5sum | cut -c1-12)
# uv installs the requirements, from the sources pip is configured with (pip where uv cannot be
# installed; `make INSTALLER=pip` asks for pip): pip's resolution alone took 74 s on one core
# (tools/install_requirements.py says why)
INSTALLER ?= uv
BYTECODE_STAMP := $(subst .installed-,.bytecode-,$(STAMP))
# an interface package is rebuilt whenever one of its .msg files or its CMake/package files
# change: twinslam_msgs (the protocol) and tf2_msgs (msg_schemas/standard: no wheel carries it)
MSG_SOURCES := $(sort $(wildcard msg_schemas/msg/*.msg)) msg_schemas/CMakeLists.txt \
	msg_schemas/package.xml $(sort $(wildcard msg_schemas/cmake/*.cmake))
MSGS_STAMP := $(VENV)/.twinslam_msgs-$(shell cat $(MSG_SOURCES) | md5sum | cut -c1-12)
TF2_DIR := msg_schemas/standard/tf2_msgs
TF2_SOURCES := $(sort $(wildcard $(TF2_DIR)/msg/*.msg)) $(TF2_DIR)/CMakeLists.txt \
	$(TF2_DIR)/package.xml $(sort $(wildcard msg_schemas/cmake/*.cmake))
TF2_STAMP := $(VENV)/.tf2_msgs-$(shell cat $(TF2_SOURCES) | md5sum | cut -c1-12)
# composition_interfaces (msg_schemas/standard: launch_ros imports it, no wheel carries it)
COMPOSITION_DIR := msg_schemas/standard/composition_interfaces
COMPOSITION_SOURCES := $(sort $(wildcard $(COMPOSITION_DIR)/srv/*.srv)) \
	$(COMPOSITION_DIR)/CMakeLists.txt $(COMPOSITION_DIR)/package.xml \
	$(sort $(wildcard msg_schemas/cmake/*.cmake))
COMPOSITION_STAMP := $(VENV)/.composition_interfaces-$(shell cat $(COMPOSITION_SOURCES) \
	| md5sum | cut -c1-12)
# the twinslam package in the venv's ament index (ros2 launch / ros2 run find it there): the
# editable install leaves setup.py's data_files out, so its share folder links to the checkout
AMENT_STAMP := $(VENV)/.ament-twinslam-$(shell (cat setup.py Makefile; ls launch config) \
	| md5sum | cut -c1-12)
# the modules with numba kernels (compiled once at set-up, recompiled when one changes)
KERNEL_SOURCES := $(sort $(shell grep -l -r --include=*.py "@njit" device_tracker edge_mapper \
	udt_node twinslam))
KERNELS_STAMP := $(VENV)/.kernels-$(shell cat $(KERNEL_SOURCES) | md5sum | cut -c1-12)

.PHONY: venv venv-parts msgs kernels run test lint lint-ruff lint-imports lint-types bench clean

# After pip, the set-up steps run side by side in a sub-make with two jobs (whatever -j make was
# given): the three interface packages, the bytecode of what the project imports (pip would
# compile all it installs on one core, 44 of its 91 s measured; neither uv nor pip compiles),
# and the kernels (they need twinslam_msgs, not tf2_msgs).
venv:
	@$(MAKE) --no-print-directory -j2 --output-sync=target venv-parts

venv-parts: $(STAMP) $(MSGS_STAMP) $(TF2_STAMP) $(COMPOSITION_STAMP) $(AMENT_STAMP) \
	$(BYTECODE_STAMP) $(KERNELS_STAMP)

$(STAMP): requirements.txt setup.py tools/install_requirements.py
	@test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) tools/install_requirements.py $(PY) requirements.txt --installer $(INSTALLER)
	@# colcon marks an install base's layout on first use by truncating, then writing a file:
	@# two of the interface builds starting at once into a fresh venv, one read it empty and
	@# refused ("created with the layout ''"). Marked here, before they run side by side.
	@echo merged > $(VENV)/.colcon_install_layout
	$(PY) -m pip install --quiet --disable-pip-version-check --no-deps --no-build-isolation -e .
	@rm -f $(VENV)/.installed-* $(VENV)/.bytecode-* && touch $@

# the bytecode of what the project's processes import, written once by the suite's collection
# (it imports every test module, so every module of the project and what they import; a process
# writes the bytecode of what it imports where PYTHONDONTWRITEBYTECODE is unset), before the
# suite's parallel workers would each compile the same modules side by side. 1 840 files in 9 s
# on one core, where compiling all of site-packages took 33 s of CPU (most of it never
# imported: sympy, pandas, most of ray and torch); a module imported only later is compiled by
# its first process. It needs the interface packages: test modules import them. The benches
# are imported too: collection finds them without importing (tests/test_bench_commands.py),
# and what they import (torch among it) would otherwise be compiled in the suite, by whichever
# processes import it first.
BENCH_IMPORTS := import importlib, pkgutil, bench; [importlib.import_module(f"bench.{m.name}") for m in pkgutil.iter_modules(bench.__path__)]
$(BYTECODE_STAMP): $(STAMP) $(MSGS_STAMP) $(TF2_STAMP) $(COMPOSITION_STAMP)
	@env -u PYTHONDONTWRITEBYTECODE $(PY) -m pytest --collect-only -q -n0 -p no:cacheprovider \
	  > /dev/null 2>&1 || true
	@env -u PYTHONDONTWRITEBYTECODE $(PY) -c '$(BENCH_IMPORTS)' > /dev/null 2>&1 || true
	@touch $@

# colcon, as a ROS 2 host builds (tests/test_colcon_build.py builds the twinslam package over
# what this installs), merge-installs each interface package into the venv prefix, which the ROS
# wheels made an ament prefix: the generated Python package lands in site-packages, its
# libraries in .venv/lib (on the loader path the wheels' bootstrapper sets). Fresh build
# directory each time: a removed .msg must not leave its generated code behind. C and Python
# only (msg_schemas/cmake/python_only_generators.cmake): every node in the venv is rclpy.
# $(call rosidl_build,PACKAGE,SOURCE_DIR,A MESSAGE TO IMPORT[,MODULE: msg or srv])
define rosidl_build
	@echo "building the $(1) interface package with colcon (rosidl, ~10-20 s)"
	@rm -rf build/colcon/$(1) && mkdir -p build/colcon
	PATH=$(VENV)/bin:$$PATH AMENT_PREFIX_PATH=$(VENV) CMAKE_PREFIX_PATH=$(VENV) \
	  $(VENV)/bin/colcon --log-base build/colcon/log-$(1) build --paths $(2) \
	  --build-base build/colcon --install-base $(VENV) --merge-install \
	  --cmake-args -DPython3_EXECUTABLE=$(PY) -DBUILD_TESTING=OFF -DTWINSLAM_PYTHON_ONLY=ON \
	  > build/colcon/$(1).log 2>&1 \
	  || { grep -iE -B2 -A8 "error" build/colcon/log-$(1)/latest_build/$(1)/stdout_stderr.log \
	       | tail -60; tail -20 build/colcon/$(1).log; exit 1; }
	$(PY) -c "from $(1).$(or $(4),msg) import $(3)"
	@rm -f $(VENV)/.$(1)-* && touch $@
endef

msgs: $(MSGS_STAMP) $(TF2_STAMP) $(COMPOSITION_STAMP)

$(MSGS_STAMP): $(STAMP) $(MSG_SOURCES)
	$(call rosidl_build,twinslam_msgs,msg_schemas,MapStats)

$(TF2_STAMP): $(STAMP) $(TF2_SOURCES)
	$(call rosidl_build,tf2_msgs,$(TF2_DIR),TFMessage)

$(COMPOSITION_STAMP): $(STAMP) $(COMPOSITION_SOURCES)
	$(call rosidl_build,composition_interfaces,$(COMPOSITION_DIR),LoadNode,srv)

# share/twinslam (package.xml and each file of launch/ and config/ linked to the checkout: ros2
# launch searches the share folder without following a linked folder), the package's marker in
# the ament index, and lib/twinslam/NODE for ros2 run (links to the venv's console scripts)
$(AMENT_STAMP): $(STAMP) setup.py
	@rm -rf $(VENV)/share/twinslam $(VENV)/lib/twinslam
	@mkdir -p $(VENV)/share/ament_index/resource_index/packages $(VENV)/share/twinslam/launch \
	  $(VENV)/share/twinslam/config $(VENV)/lib/twinslam
	@touch $(VENV)/share/ament_index/resource_index/packages/twinslam
	@ln -sfn $(CURDIR)/package.xml $(VENV)/share/twinslam/package.xml
	@for f in launch/*_launch.py config/*.yaml config/*.xml config/*.json; do \
	  ln -sfn $(CURDIR)/$$f $(VENV)/share/twinslam/$$f; done
	@for node in sequence_player device_tracker edge_mapper udt_node; do \
	  ln -sfn ../../bin/$$node $(VENV)/lib/twinslam/$$node; done
	@rm -f $(VENV)/.ament-twinslam-* && touch $@

# numba compiles on first use: done here, not in the first node start (twinslam/cli/precompile.py)
kernels: $(KERNELS_STAMP)

$(KERNELS_STAMP): $(STAMP) $(MSGS_STAMP) $(KERNEL_SOURCES)
	$(VENV)/bin/twinslam precompile
	@rm -f $(VENV)/.kernels-* && touch $@

run: venv
	$(VENV)/bin/twinslam demo

# The lint stage — ruff, the import contracts, mypy — then the suite on parallel workers
# (pytest-xdist: README, "Tests", has the worker counts measured). A two-job sub-make runs the
# lint stage beside the set-up steps it does not need (mypy waits for the interface packages,
# the kernels compile beside it); the suite starts only when both passed. Bytecode is cached
# even where the environment says not to, or every node process a test starts compiles the
# project's modules again.
TEST_WORKERS ?= 4
LINT_STEPS := lint-ruff lint-imports lint-types

test:
	@$(MAKE) --no-print-directory -j2 --output-sync=target venv-parts $(LINT_STEPS)
	env -u PYTHONDONTWRITEBYTECODE $(PY) -m pytest -n $(TEST_WORKERS)

lint:
	@$(MAKE) --no-print-directory -j2 --output-sync=target $(LINT_STEPS)

lint-ruff: $(STAMP)
	$(PY) -m ruff check .

lint-imports: $(STAMP)
	$(VENV)/bin/lint-imports

lint-types: $(STAMP) $(MSGS_STAMP) $(TF2_STAMP)
	$(PY) -m mypy

bench: venv
	$(PY) -m bench.dds
	$(PY) -m bench.sim
	$(PY) -m bench.sim --covis room
	$(PY) -m bench.frontend
	$(PY) -m bench.descriptor_matching
	$(PY) -m bench.udt
	$(PY) -m bench.pipeline
	$(PY) -m bench.mbrl
	$(PY) -m bench.fleet
	$(PY) -m bench.edge_scaling
	$(PY) -m bench.edge_work
	$(PY) -m bench.visual
	$(PY) -m bench.live --rounds 4 --frames 1000
	$(PY) -m bench.update_loop

clean:
	rm -rf $(VENV) build *.egg-info .pytest_cache .ruff_cache .mypy_cache .cache
