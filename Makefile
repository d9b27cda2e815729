# objslam — `make help` lists the targets. A fresh machine needs only `make run` and `make test`.
SHELL := /bin/bash
.DEFAULT_GOAL := help
PY := .venv/bin/python
CARGO_FEATURES := --features rerun
RUN_ARGS ?=
WEB ?=
BENCHMARK_ARGS ?=
ABLATION_ARGS ?=
MATCH_SIM_ARGS ?=
GRASP_ARGS ?=
PLACE_ARGS ?=
ROBUSTNESS_ARGS ?=
RUNS_ARGS ?=
AR_ARGS ?=
RELOC_ARGS ?=
FEATURES_ARGS ?=
# .cargo/config.toml builds for x86-64-v3 (AVX2); a CPU without it gets a baseline x86-64 build.
ifeq ($(shell [ "$$(uname -m)" = x86_64 ] && ! grep -qw avx2 /proc/cpuinfo && echo 1),1)
export RUSTFLAGS += -C target-cpu=x86-64
endif

.PHONY: help setup run runs test test-fast test-rust test-rust-unit test-py fuzz bench benchmark associate parameterize slam grasp grasp-robustness place match match-sim features reloc ar report sensor reports-index view lint fmt clean

help: ## List the targets
	@grep -E '^[a-zA-Z_-]+:.*## ' $(MAKEFILE_LIST) | awk 'BEGIN {FS = ":.*## "}; {printf "  \033[1m%-12s\033[0m %s\n", $$1, $$2}'

setup: ## Install everything from a bare Debian 12 machine (idempotent; seconds when done)
	@./scripts/setup.sh

run: setup ## Run the main job: one episode on scene 1 (RUN_ARGS="--scene ... --seed ..." to change)
	@$(PY) experiments/run.py $(RUN_ARGS)

runs: ## List run folders by status (complete, failed, interrupted, terminated, running, dead)
	@$(PY) -m objslam.runs $(RUNS_ARGS)

test: setup test-rust test-py ## Run all tests (cargo tests in the release profile + pytest)

test-fast: setup test-rust-unit ## Rust unit tests + the pytest tests that do not run the simulator
	$(PY) -m pytest -q -m "not slow" tests

# Without the rerun feature, so the heavy rerun tree is not rebuilt with the test profile's feature
# set (the recorder is tested from Python, through the bindings built by `make setup`).
test-rust: ## Rust tests only (release profile, shared with maturin's build)
	cargo test --release -p objslam-core

test-rust-unit: ## Rust unit tests only (the library's own tests, no integration tests)
	cargo test --release -p objslam-core --lib

test-py: ## Python tests only (needs `make setup`)
	$(PY) -m pytest -q tests

FUZZ_CASES ?= 20000
fuzz: setup ## Fuzz the JSON readers and native entry points at length (FUZZ_CASES per property, default 20000)
	PROPTEST_CASES=$(FUZZ_CASES) cargo test --release -p objslam-core --test fuzz_json
	OBJSLAM_FUZZ_CASES=$(FUZZ_CASES) $(PY) -m pytest -q tests/test_fuzz.py

bench: setup ## Benchmarks (criterion + Python references in one run) → reports/bench.json
	$(PY) experiments/bench.py

benchmark: setup ## Exploration benchmark: hard + test scenes × 7 strategies × 9 seeds → reports/exploration.json
	$(PY) experiments/benchmark.py $(BENCHMARK_ARGS)

associate: setup ## Association ablation (scenes × modes) → reports/association.json
	$(PY) experiments/ablations.py associate $(ABLATION_ARGS)

parameterize: setup ## Parameterization stages (raw → iForest → lines → refined) → reports/parameterization.json
	$(PY) experiments/ablations.py parameterize $(ABLATION_ARGS)

slam: setup ## Pose accuracy: scenes × pose sources (slam, kinematics) → reports/slam.json
	$(PY) experiments/ablations.py slam $(ABLATION_ARGS)

grasp: setup ## Grasp success: 7 scenes × seeds × map sources (estimated, ground_truth, init_only) → reports/grasping.json
	$(PY) experiments/grasp.py $(GRASP_ARGS)

grasp-robustness: setup ## Grasp success vs an injected map centre error (0-9 mm), blind approach vs contact retries → runs/grasp_robustness/report/ (studies/grasp_robustness)
	$(PY) experiments/grasp_robustness.py --run --out runs/grasp_robustness/report $(ROBUSTNESS_ARGS)

place: setup ## Placement tasks on the maps of the last grasp sweep (runs/grasp_sweep.json) → reports/placement.json
	$(PY) experiments/place.py $(PLACE_ARGS)

match: ## Scene matching vs shared-object ratio (500 trials per row) → reports/scene_matching.json
	cargo run --release -p objslam-core --example match_experiment -- --scenes scenes --out reports --other-seeds 1,2,3

match-sim: setup ## Scene matching, part (b): maps of two simulator runs per scene (7 scenes × 2 Init episodes) → sim_pairs in reports/scene_matching.json
	$(PY) experiments/match_sim.py $(MATCH_SIM_ARGS)

features: setup ## ORB features vs OpenCV (repeatability, match precision, time) on photographs and SAPIEN renders → reports/features.json
	$(PY) experiments/features.py $(FEATURES_ARGS)

reloc: setup ## Relocalisation vs parallax, objects vs appearance (hard + test scenes; RELOC_ARGS) → reports/relocalisation.json
	$(PY) experiments/reloc.py $(RELOC_ARGS)

ar: setup ## AR on exploration maps vs the simulator's truth: occlusion IoU, drop rest error → reports/ar.json
	$(PY) experiments/ar.py $(AR_ARGS)

sensor: setup ## Depth sensor error vs distance and the arm prior's pose error, per preset (realistic, ideal), from SAPIEN renders → reports/sensor.json
	$(PY) experiments/sensor.py $(SENSOR_ARGS)

report: ## Report of the latest run folder → reports/foundation_run.json
	$(PY) experiments/report_run.py

reports-index: ## Regenerate reports/README.md (one line per report: question, headline figure, command)
	python3 experiments/report_index.py

view: ## Open the latest run's recording in the Rerun viewer (no display, or WEB=1: serve a web viewer and print its address)
	@test -e runs/latest/run.rrd || { echo "no runs/latest/run.rrd: run 'make run' first"; exit 1; }
	@if [ -z "$(WEB)" ] && { [ -n "$$DISPLAY" ] || [ -n "$$WAYLAND_DISPLAY" ] || [ "$$(uname)" = Darwin ]; }; then \
		.venv/bin/rerun runs/latest/run.rrd; \
	else \
		echo "serving a web viewer: open http://127.0.0.1:9090/?url=rerun%2Bhttp%3A%2F%2F127.0.0.1%3A9876%2Fproxy"; \
		echo "  (remote machine: ssh -L 9090:localhost:9090 -L 9876:localhost:9876 <host>, then open the same address; Ctrl-C stops)"; \
		.venv/bin/rerun --serve-web --port 9876 --web-viewer-port 9090 runs/latest/run.rrd; \
	fi

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
