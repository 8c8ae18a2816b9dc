# softhand: the two commands of the README.
#   make demo   replay a sample tracker bag through all three nodes; writes runs/<stamp>/
#   make test   the whole test suite (unit, physics on two workers; then real ROS 2 processes)
# Each creates .venv from requirements.lock on first use (python3 + python3-venv needed).
# ROS processes started by the demo, tests and benchmarks set ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST
# and a ROS_DOMAIN_ID of their own in code (softhand_sim/ros_env.py); the exports below make
# anything else started from make (e.g. `make shell`) loopback-only as well.

PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.softhand-installed
# tf2_msgs (for /tf) built from ros_ws/vendor into the venv; the stamp says "built" or why not
TF2_STAMP := $(VENV)/.tf2_msgs-built
TF2_SOURCES := $(shell find ros_ws/vendor/tf2_msgs -type f 2>/dev/null)
PIP_VERSION := 26.3
export ROS_AUTOMATIC_DISCOVERY_RANGE := LOCALHOST
export ROS_DOMAIN_ID ?= 61
unexport ROS_LOCALHOST_ONLY

.PHONY: venv tf2_msgs demo test bench bags hand colcon clean help

help:
	@echo "make demo    replay the grasp bag through tracking, sim, world and record nodes -> runs/<stamp>/"
	@echo "make test    run the test suite"
	@echo "make bench   solver benchmark (softhand bench)"
	@echo "make bags    regenerate the sample tracker bags in bags/"
	@echo "make hand    build the hand model and render docs/img/hand.png"
	@echo "make colcon  build ros_ws with colcon into ros_ws/install"
	@echo "make tf2_msgs  (re)build tf2_msgs into .venv (after installing a C/C++ compiler)"

venv: $(STAMP) $(TF2_STAMP)

$(STAMP): requirements.lock softhand_sim/setup.py softhand_tracking/setup.py softhand_world/setup.py
	@$(PYTHON) -c 'import sys; sys.exit(0 if sys.version_info[:2] == (3, 11) else 1)' || \
	  echo "warning: softhand is tested on Python 3.11; on 3.12 pybullet has no wheel and builds from source (needs a C++ compiler and python3-dev)"
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	# a current pip: older ones (Debian's 23.x) do legacy `setup.py develop` editable installs,
	# which put the console scripts under lib/<pkg> (the ament layout) instead of .venv/bin
	$(BIN)/python -m pip install --quiet --disable-pip-version-check pip==$(PIP_VERSION)
	$(BIN)/python -m pip install --quiet --disable-pip-version-check -r requirements.lock
	$(BIN)/python -m pip install --quiet --disable-pip-version-check --no-deps --no-build-isolation \
	  --config-settings editable_mode=compat -e ./softhand_sim -e ./softhand_tracking -e ./softhand_world
	touch $@

# Cached: runs again only when the venv or the vendored sources change. Without a C/C++ compiler
# or the Python headers it prints one warning and make goes on (the nodes then run without TF).
$(TF2_STAMP): $(STAMP) tools/build_tf2_msgs.py $(TF2_SOURCES)
	@echo "building tf2_msgs into $(VENV) (once: about 60 s of CPU time)"
	@$(BIN)/python tools/build_tf2_msgs.py --venv $(VENV) --stamp $@ || true

tf2_msgs: $(STAMP)
	rm -f $(TF2_STAMP)
	$(MAKE) --no-print-directory $(TF2_STAMP)

demo: venv
	$(BIN)/softhand demo $(ARGS)

# Two passes: the tests that start no ROS process (physics, hand model, config, ...) on both cores
# with pytest-xdist (worksteal: an idle worker takes tests queued on the busy one, so a long test
# near the end does not leave a core idle), then the node-level tests one at a time (their rates and timing assume the
# machine is theirs). Both passes run; make fails if either does. With ARGS: one plain pytest run of those.
test: venv
ifeq ($(strip $(ARGS)),)
	@$(BIN)/python -m pytest -m "not ros" -n 2 --dist worksteal; a=$$?; \
	  $(BIN)/python -m pytest -m ros; b=$$?; \
	  echo "make test: tests without ROS processes exit $$a, node-level tests exit $$b"; \
	  [ $$a -eq 0 ] && [ $$b -eq 0 ]
else
	$(BIN)/python -m pytest $(ARGS)
endif

bench: venv
	$(BIN)/softhand bench $(ARGS)

bags: venv
	$(BIN)/python tools/make_bags.py

hand: venv
	$(BIN)/softhand hand --out docs/img/hand.png

colcon: venv
	cd ros_ws && ../$(BIN)/colcon build --base-paths src --build-base build --install-base install

clean:
	rm -rf $(VENV) ros_ws/build ros_ws/install ros_ws/log
