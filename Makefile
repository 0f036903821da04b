# Two commands do everything on a fresh Debian 12 machine:  `make demo`  and  `make test`.
SHELL := /bin/bash
ROOT := $(shell pwd)
ENV := source $(ROOT)/tools/env.sh
OUT ?= $(ROOT)/demo_output
GUI ?= 0

.PHONY: setup demo demo-station test lint format pytest rostest bench clean

setup:
	@bash tools/setup.sh

demo: setup
	@$(ENV) && python3 scripts/demo_measurement.py --output-dir "$(OUT)" --gui $(GUI)

# the station alone: home -> up -> home through the controller, bag and snapshot
demo-station: setup
	@$(ENV) && python3 scripts/demo_station.py --output-dir "$(OUT)" --gui $(GUI)

lint: setup
	@$(ENV) && ruff check . && ruff format --check .

format: setup
	@$(ENV) && ruff format . && ruff check --fix .

# Everything: lint, pytest on the ROS-free core, every rostest; one summary line `N passed, M failed`.
test: setup
	@$(ENV) && bash tools/run_tests.sh

pytest: setup
	@$(ENV) && python3 -m pytest -q test/core

rostest: setup
	@$(ENV) && bash tools/run_tests.sh --rostest-only

# The speed figures the issues name (minutes, not part of `make test`): planning pipeline on the cube, motion layer.
bench: setup
	@$(ENV) && python3 scripts/bench_planning.py && python3 scripts/bench_motion.py

clean:
	rm -rf "$$(bash tools/workspace_path.sh)" .test_results .ros_home demo_output
