#!/usr/bin/env bash
# Regenerates the hard suite (scenes/hard/hard01..07.toml: tuning) and the test split
# (scenes/test/test01..07.toml: reporting only, never tuned on) with the seeded hard-scene generator
# (python -m objslam.scene --hard; objslam.clutter). Same generator settings for both, other seeds.
# The committed files are the benchmark; rerun this only to change them deliberately.
set -euo pipefail
cd "$(dirname "$0")"
PY="${PYTHON:-../.venv/bin/python}"
G="$PY -m objslam.scene --hard --n-range 14,18 --mesh-fraction 0.5"
for i in 1 2 3 4 5 6 7; do
  $G --seed $((2000 + i)) --name "hard0$i" --out "hard/hard0$i.toml"
  $G --seed $((3000 + i)) --name "test0$i" --out "test/test0$i.toml"
done
