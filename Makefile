# Two commands do all the set-up: `make run` and `make test` (each creates .venv when missing).
PYTHON ?= python3.11
VENV   := .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed

.PHONY: run test venv bench clean

$(STAMP): constraints.txt setup.py package.xml
	@test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade "pip==25.3" "setuptools==80.9.0" "wheel==0.45.1"
	$(PY) -m pip install --quiet -c constraints.txt "ros-jazzy-rclpy[fastrtps]" ros-jazzy-common-interfaces
	$(PY) -m pip install --quiet -c constraints.txt -e ".[test]"
	@touch $(STAMP)

venv: $(STAMP)

run: $(STAMP)
	$(VENV)/bin/robodyn run stanford_arm --duration 10 --record runs/stanford_arm.mcap

test: $(STAMP)
	$(PY) -m pytest -q

bench: $(STAMP)
	$(PY) -m robodyn_ros.bench

clean:
	rm -rf $(VENV) build install log
