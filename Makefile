# objslam — `make help` lists the targets. A fresh machine needs only `make run` and `make test`.
SHELL := /bin/bash
.DEFAULT_GOAL := help
PY := .venv/bin/python
CARGO_FEATURES := --features rerun
RUN_ARGS ?=

.PHONY: help setup run test test-rust test-py bench view lint fmt clean

help: ## List the targets
	@grep -E '^[a-zA-Z_-]+:.*## ' $(MAKEFILE_LIST) | awk 'BEGIN {FS = ":.*## "}; {printf "  \033[1m%-12s\033[0m %s\n", $$1, $$2}'

setup: ## Install everything from a bare Debian 12 machine (idempotent; seconds when done)
	@./scripts/setup.sh

run: setup ## Run the main job: one episode on scene 1 (RUN_ARGS="--scene ... --seed ..." to change)
	@$(PY) experiments/run.py $(RUN_ARGS)

test: setup test-rust test-py ## Run all tests (cargo tests in the release profile + pytest)

test-rust: ## Rust tests only (release profile: shares the dependency build with maturin)
	cargo test --release -p objslam-core $(CARGO_FEATURES)

test-py: ## Python tests only (needs `make setup`)
	$(PY) -m pytest -q tests

bench: setup ## Benchmarks (criterion + Python references in one run) → reports/bench.{md,json}
	$(PY) experiments/bench.py

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
