# Two commands do everything on a fresh Debian 12 machine:  `make demo`  and  `make test`.
SHELL := /bin/bash
ROOT := $(shell pwd)
ENV := source $(ROOT)/tools/env.sh
OUT ?= $(ROOT)/demo_output
GUI ?= 0

BENCH_OUT ?= $(ROOT)/bench_results
BENCH_ARGS ?=
BENCHES := planning parts part-family scan-lines scale set-cover metrology motion kinematics collision nbv3d nbv-heldout nbv-map nbv2d nbv2d-heldout mild calibration phoxi scanner real-cell acceptance inspection

.PHONY: setup demo demo-station test lint format pytest rostest bench $(addprefix bench-,$(BENCHES)) fuzz clean

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

# Benchmarks (minutes to hours, not part of `make test`; benchmarks/README.md): `make bench-<domain>` runs one with
# its default conditions, extra options in BENCH_ARGS; the printed figures go to bench_results/<domain>.txt and, where
# the benchmark writes JSON, to bench_results/<domain>.json. `make bench`: the planning pipeline and the motion core.
# run_bench NAME MODULE ARGS
define run_bench
@$(ENV) && mkdir -p "$(BENCH_OUT)" && set -o pipefail && python3 -m $(2) $(3) $(BENCH_ARGS) | tee "$(BENCH_OUT)/$(1).txt"
endef

bench: bench-planning bench-motion

bench-planning: setup
	$(call run_bench,planning,benchmarks.planning.pipeline,--json "$(BENCH_OUT)/planning.json")

bench-parts: setup
	$(call run_bench,parts,benchmarks.planning.parts,--json "$(BENCH_OUT)/parts.json")

bench-scan-lines: setup
	$(call run_bench,scan-lines,benchmarks.planning.scan_lines,--json "$(BENCH_OUT)/scan-lines.json")

bench-part-family: setup
	$(call run_bench,part-family,benchmarks.planning.part_family,--json "$(BENCH_OUT)/part-family.json")

bench-scale: setup
	$(call run_bench,scale,benchmarks.planning.scale,--json "$(BENCH_OUT)/scale.json")

bench-set-cover: setup
	$(call run_bench,set-cover,benchmarks.planning.set_cover,)

bench-metrology: setup
	$(call run_bench,metrology,benchmarks.planning.metrology,)

bench-motion: setup
	$(call run_bench,motion,benchmarks.motion.core,)

bench-collision: setup
	$(call run_bench,collision,benchmarks.motion.collision,)

bench-nbv3d: setup
	$(call run_bench,nbv3d,benchmarks.nbv3d.loop,--json "$(BENCH_OUT)/nbv3d.json")

bench-nbv-heldout: setup
	$(call run_bench,nbv-heldout,benchmarks.nbv3d.loop,--set evaluation --methods ours ours_tour rear_side_voxel proximity_count random oracle --seeds 3 --random-seeds 3 --max-views 20 --pixel-step 4 --json "$(BENCH_OUT)/nbv-heldout.json")

bench-nbv-map: setup
	$(call run_bench,nbv-map,benchmarks.nbv3d.map,--json "$(BENCH_OUT)/nbv-map.json")

bench-nbv2d: setup
	$(call run_bench,nbv2d,benchmarks.nbv2d,--json "$(BENCH_OUT)/nbv2d.json")

bench-nbv2d-heldout: setup
	$(call run_bench,nbv2d-heldout,benchmarks.nbv2d,--set all --scripts fullpix stratpix --json "$(BENCH_OUT)/nbv2d-heldout.json")

bench-mild: setup
	$(call run_bench,mild,benchmarks.mild,)

bench-calibration: setup
	$(call run_bench,calibration,benchmarks.calibration,)

bench-phoxi: setup
	$(call run_bench,phoxi,benchmarks.phoxi,)

bench-kinematics: setup
	$(call run_bench,kinematics,benchmarks.motion.kinematics,)

bench-scanner: setup
	$(call run_bench,scanner,benchmarks.scanner,)

bench-real-cell: setup
	$(call run_bench,real-cell,benchmarks.reliability.real_cell,)

bench-acceptance: setup
	$(call run_bench,acceptance,benchmarks.acceptance,--json "$(BENCH_OUT)/acceptance.json")

bench-inspection: setup
	$(call run_bench,inspection,benchmarks.inspection,--speed --json "$(BENCH_OUT)/inspection.json")

# The reliability probe replayed (minutes; not part of `make test`): hostile inputs to every command-line tool and
# node, one row each, holds / DEFECT; the table goes to bench_results/fuzz.txt, the rows to fuzz.json.
fuzz: setup
	$(call run_bench,fuzz,benchmarks.reliability,--json "$(BENCH_OUT)/fuzz.json")

clean:
	rm -rf "$$(bash tools/workspace_path.sh)" .test_results .ros_home demo_output
