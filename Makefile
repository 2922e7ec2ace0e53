# Two commands do all the set-up: `make run` and `make test` (each creates .venv when missing).
PYTHON ?= python3.11
VENV   := .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed
WARM   := $(VENV)/.warm
TEST_WORKERS ?= $(shell echo $$(( $$(nproc 2>/dev/null || echo 1) + 1 )))

.PHONY: run test venv bench clean

$(STAMP): constraints.txt setup.py package.xml
	@test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade "pip==25.3" "setuptools==80.9.0" "wheel==0.45.1"
	$(PY) -m pip install --quiet -c constraints.txt "ros-jazzy-rclpy[fastrtps]" ros-jazzy-common-interfaces
	$(PY) -m pip install --quiet -c constraints.txt -e ".[test]"
	@touch $(STAMP)

venv: $(STAMP)

# compile once the kernels every bundled scene and URDF robot uses (cached on disk), in one worker
# process per processor, so that first runs start without compiling; again when a kernel changes.
# `make test` runs it first: the suite's processes then load the kernels instead of each compiling them
$(WARM): $(STAMP) $(wildcard robodyn_ros/kernels/*.py)
	@$(PY) -m compileall -q -j 0 robodyn_ros > /dev/null
	$(VENV)/bin/robodyn warm --quiet
	@touch $(WARM)

# the sim node on stanford_arm with its scripted commands, 10 s of simulation as fast as possible,
# recorded (replacing the recording of the previous `make run`); it prints the run summary on exit
# (same format as `robodyn run`). On an empty kernel cache the node compiles only what this run uses
# (`robodyn warm`, which `make test` runs, compiles the other scenes' kernels)
run: $(STAMP)
	@$(PY) -m compileall -q -j 0 robodyn_ros > /dev/null
	$(VENV)/bin/sim --ros-args -p scene:=stanford_arm -p scripted_commands:=true -p mode:=max \
	  -p duration:=10.0 -p record:=runs/stanford_arm.mcap -p overwrite:=true

# the suite in one worker process per core and one more (pytest-xdist; the extra one runs while others wait
# on their child processes: 2 workers kept 2 cores 91 % busy), each test file whole in one worker (its
# module fixtures once; node tests claim their own ROS_DOMAIN_ID with a lock file, so workers never share one).
# The package's bytecode is written first (compileall; what pip does for an installed package): an editable
# checkout in an environment with PYTHONDONTWRITEBYTECODE set never gets it, and each of the suite's
# hundreds of child processes (nodes, CLI runs, workers) then compiles the package's source again (~0.2 s CPU each)
test: $(WARM)
	@$(PY) -m compileall -q -j 0 robodyn_ros test > /dev/null
	$(PY) -m pytest -q -n $(TEST_WORKERS) --dist loadfile

bench: $(STAMP)
	$(PY) -m robodyn_ros.bench speed --out docs/bench_speed.md
	$(PY) -m robodyn_ros.bench urdf --out docs/urdf_robots.md
	$(PY) -m robodyn_ros.bench stiff --out docs/bench_stiff.md
	$(PY) -m robodyn_ros.bench contact --out docs/bench_contact.md
	$(PY) -m robodyn_ros.bench contact --steps --out docs/bench_contact_steps.md
	$(PY) -m robodyn_ros.bench startup --out docs/bench_startup.md
	$(PY) -m robodyn_ros.bench peers --out docs/bench_peers.md

clean:
	rm -rf $(VENV) build install log
