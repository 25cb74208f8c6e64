#!/usr/bin/env bash
# Training speed on this machine: naive against chunked, fp32 against bf16, for the
# sizes of export/TRAINING.md's speed tables. Run it with nothing else running; the
# figures are ratios within each run (alternating batch by batch), not a timed test.
# Needs the [train] extra (scripts/setup with SCOTTI_EXTRAS=train) and one session
# file of the corpus (export/TRAINING.md, "The current corpus"); SESSION overrides it.
set -euo pipefail
cd "$(dirname "$0")/.."
SESSION=${SESSION:-data/corpus7/realistic/subject-000.ses}
OUT=${OUT:-/tmp/scotti-train-speed}
if [[ ! -f $SESSION ]]; then
  echo "train_speed: no session file $SESSION (make the corpus first, or set SESSION=...)" >&2
  exit 2
fi
cache=()
[[ -d data/cache7 ]] && cache=(--cache data/cache7)
speed() {  # name, config, threads, batches
  echo "== $1, $3 thread(s)"
  .venv/bin/scotti train "$SESSION" -o "$OUT" --config "$2" --batch 32 --stride 16 \
    --benchmark "$4" --threads "$3" --device cpu "${cache[@]}" 2>&1 | grep -E "windows/s"
}
speed small small 2 10
speed small small 1 10
arch() {  # the sweep's configuration of that name, as scotti train --config takes it
  .venv/bin/python -c 'import json, sys; sys.path.insert(0, "experiments")
from configs import CONFIGS; print(json.dumps(CONFIGS[sys.argv[1]]))' "$1"
}
speed E256-L2-T40 "$(arch E256-L2-T40)" 2 10
speed E256-L4-T40 "$(arch E256-L4-T40)" 2 10
speed paper paper 2 6
