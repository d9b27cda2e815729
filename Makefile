# objslam — `make help` lists the targets. A fresh machine needs only `make run` and `make test`.
SHELL := /bin/bash
.DEFAULT_GOAL := help
PY := .venv/bin/python
CARGO_FEATURES := --features rerun
RUN_ARGS ?=
BENCHMARK_ARGS ?=
ABLATION_ARGS ?=
MATCH_SIM_ARGS ?=
GRASP_ARGS ?=
PLACE_ARGS ?=
ROBUSTNESS_ARGS ?=

.PHONY: help setup run test test-rust test-py bench benchmark associate parameterize slam grasp grasp-robustness place match match-sim sensor report view lint fmt clean

help: ## List the targets
	@grep -E '^[a-zA-Z_-]+:.*## ' $(MAKEFILE_LIST) | awk 'BEGIN {FS = ":.*## "}; {printf "  \033[1m%-12s\033[0m %s\n", $$1, $$2}'

setup: ## Install everything from a bare Debian 12 machine (idempotent; seconds when done)
	@./scripts/setup.sh

run: setup ## Run the main job: one episode on scene 1 (RUN_ARGS="--scene ... --seed ..." to change)
	@$(PY) experiments/run.py $(RUN_ARGS)

test: setup test-rust test-py ## Run all tests (cargo tests in the release profile + pytest)

# Without the rerun feature, so the heavy rerun tree is not rebuilt with the test profile's feature
# set (the recorder is tested from Python, through the bindings built by `make setup`).
test-rust: ## Rust tests only (release profile, shared with maturin's build)
	cargo test --release -p objslam-core

test-py: ## Python tests only (needs `make setup`)
	$(PY) -m pytest -q tests

bench: setup ## Benchmarks (criterion + Python references in one run) → reports/bench.{md,json}
	$(PY) experiments/bench.py

benchmark: setup ## Exploration benchmark: 7 scenes × 5 strategies × seeds → reports/exploration.{md,json,png}
	$(PY) experiments/benchmark.py $(BENCHMARK_ARGS)

associate: setup ## Association ablation (scenes × modes) → reports/association.{md,json}
	$(PY) experiments/ablations.py associate $(ABLATION_ARGS)

parameterize: setup ## Parameterization stages (raw → iForest → lines → refined) → reports/parameterization.{md,json}
	$(PY) experiments/ablations.py parameterize $(ABLATION_ARGS)

slam: setup ## Pose accuracy: scenes × pose sources (slam, kinematics) → reports/slam.{md,json}
	$(PY) experiments/ablations.py slam $(ABLATION_ARGS)

grasp: setup ## Grasp success: 7 scenes × seeds × map sources (estimated, ground_truth, init_only) → reports/grasping.{md,json}
	$(PY) experiments/grasp.py $(GRASP_ARGS)

grasp-robustness: setup ## Grasp success vs an injected map centre error (0-9 mm), blind approach vs contact retries → reports/grasping_robustness/
	$(PY) experiments/grasp_robustness.py --run $(ROBUSTNESS_ARGS)

place: setup ## Placement tasks on the maps of the last grasp sweep (runs/grasp_sweep.json) → reports/placement.{md,json}
	$(PY) experiments/place.py $(PLACE_ARGS)

match: ## Scene matching vs shared-object ratio (500 trials per row) → reports/scene_matching.{md,json}
	cargo run --release -p objslam-core --example match_experiment -- --scenes scenes --out reports --other-seeds 1,2,3

match-sim: setup ## Scene matching, part (b): maps of two simulator runs per scene (7 scenes × 2 Init episodes) → sim_pairs in reports/scene_matching.{md,json}
	$(PY) experiments/match_sim.py $(MATCH_SIM_ARGS)

sensor: setup ## Depth sensor error vs distance per preset (realistic, ideal) from SAPIEN renders → reports/sensor.{md,json}
	$(PY) experiments/sensor.py $(SENSOR_ARGS)

report: ## Report of the latest run folder → reports/foundation_run.{md,json}
	$(PY) experiments/report_run.py

view: ## Open the latest run's recording in the Rerun viewer
	@test -e runs/latest/run.rrd || { echo "no runs/latest/run.rrd: run 'make run' first"; exit 1; }
	.venv/bin/rerun runs/latest/run.rrd

lint: ## rustfmt + clippy -D warnings + ruff
	cargo fmt --all --check
	cargo clippy --release --workspace --all-targets $(CARGO_FEATURES) -- -D warnings
	.venv/bin/ruff check sim experiments tests

fmt: ## Format Rust and Python sources
	cargo fmt --all
	.venv/bin/ruff format sim experiments tests

clean: ## Remove build outputs (keeps .venv and runs/)
	cargo clean
	rm -f sim/objslam/_native*.so
