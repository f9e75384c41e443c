#!/usr/bin/env bash
# Time to a first answer on a fresh clone (issue 60): clone this repository's HEAD into a temporary
# directory, `make install` (a new .venv; pip's download cache may be warm), then the README's first
# command on the example control. Prints the two wall times and the total; run it on an otherwise idle
# machine.
#
#     scripts/time_to_first_answer.sh [WORKDIR]        (about 5 min on 2 cores)
set -euo pipefail
repo=$(git -C "$(dirname "$0")/.." rev-parse --show-toplevel)
work=${1:-$(mktemp -d)}
git clone --quiet "$repo" "$work/clone"
cd "$work/clone"
start=$(date +%s.%N)
make install > "$work/install.log" 2>&1
installed=$(date +%s.%N)
.venv/bin/forcdecode loop examples/control.frc --Ms-kA-m 800 --out out/control | tee "$work/loop.log"
answered=$(date +%s.%N)
python3 - "$start" "$installed" "$answered" "$(nproc)" <<'PY'
import sys
start, installed, answered, cores = map(float, sys.argv[1:])
print(f"install {installed - start:.0f} s, first answer {answered - installed:.0f} s, "
      f"total {answered - start:.0f} s on {cores:.0f} cores")
PY
