#!/usr/bin/env bash
# Regenerates the seven benchmark scenes with the seeded generator (python -m objslam.scene).
# The committed scenes/*.toml are the benchmark; rerun this only to change them deliberately.
set -euo pipefail
cd "$(dirname "$0")"
G="../.venv/bin/python -m objslam.scene"
$G --seed 101 --n 4  --name scene01 --character "sparse: 4 objects, well apart" --min-gap 0.08 --out scene01.toml
$G --seed 102 --n 6  --name scene02 --character "6 objects" --min-gap 0.06 --out scene02.toml
$G --seed 103 --n 8  --name scene03 --character "8 objects" --min-gap 0.05 --out scene03.toml
$G --seed 104 --n 10 --name scene04 --character "10 objects" --min-gap 0.04 --out scene04.toml
$G --seed 105 --n 12 --name scene05 --character "dense: 12 objects" --min-gap 0.03 --region 0.32,0.70,-0.32,0.32 --out scene05.toml
$G --seed 306 --n 7  --name scene06 --character "mixed large and small: keyboard and books among blocks and cans" \
   --classes keyboard,book,block,block,can,cup --min-gap 0.04 --out scene06.toml
$G --seed 107 --n 8  --name scene07 --character "crowded to one side, close together: tall bottles occlude small blocks" \
   --classes bottle,bottle,block,block,cup,can --region 0.38,0.66,0.02,0.30 --min-gap 0.012 --out scene07.toml
