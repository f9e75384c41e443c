#!/usr/bin/env bash
# Run the effects bench's user path on one or more case sets in N one-core shards (process K runs shard
# K/N of each set in turn, pinned to one core where taskset exists, so the loop's default --workers is 1
# as on a laptop's single core). Resumable: a sample already in the store is not made again (a sample of
# several patches resumes from its finished patches), a case whose row is in OUT is not run again.
#
#   scripts/bench_shards.sh samples|loop N SECONDS SET [SET ...]
#
#   samples  make the sets' magnum.np samples into STORE/SET and run no loop (--samples-only)
#   loop     run the whole user path (`forcdecode loop` per case) on the samples in STORE/SET, rows in
#            OUT/user/SET/cases.jsonl; afterwards one run without shards writes the summary:
#            forcdecode bench effects --independent --set SET --samples-dir STORE/SET --effects-out OUT
#   SECONDS  > 0 stops every shard after that long (0: no limit)
#
# Environment: STORE (default docs/results/bench_samples), OUT (default docs/results/loop_bench_eval),
# CACHE (magnum.np's demag-kernel cache, default .cache/magnumnp), FORCDECODE (default forcdecode).
# Shard K's log is STORE/logs/MODE-SET-shard-K.log. Example, the eval samples on a 16-core machine:
#   scripts/bench_shards.sh samples 16 0 laptop-eval laptop-dev
set -euo pipefail
if [ $# -lt 4 ] || { [ "$1" != samples ] && [ "$1" != loop ]; }; then
    sed -n 2,19p "$0"; exit 2
fi
mode=$1; n=$2; seconds=$3; shift 3
export MODE=$mode N_SHARDS=$n FORCDECODE=${FORCDECODE:-forcdecode}
export STORE=${STORE:-docs/results/bench_samples} OUT=${OUT:-docs/results/loop_bench_eval} CACHE=${CACHE:-.cache/magnumnp}
export OMP_NUM_THREADS=1 MKL_NUM_THREADS=1 NUMBA_NUM_THREADS=1
mkdir -p "$CACHE" "$STORE/logs"
for set_name in "$@"; do mkdir -p "$STORE/$set_name"; done
shard() {  # shard K of every set named after it, one after the other
    local k=$1; shift
    local pin=""
    command -v taskset > /dev/null && pin="taskset -c $(( (k - 1) % CORES ))"
    for set_name in "$@"; do
        local what=(--samples-only)
        [ "$MODE" = loop ] && what=(--effects-out "$OUT")
        $pin $FORCDECODE bench effects --independent --set "$set_name" --shard "$k/$N_SHARDS" "${what[@]}" \
            --samples-dir "$STORE/$set_name" --cache-dir "$CACHE" >> "$STORE/logs/$MODE-$set_name-shard-$k.log" 2>&1 \
            || echo "shard $k/$N_SHARDS of $set_name stopped: exit $?" >> "$STORE/logs/$MODE-$set_name-shard-$k.log"
    done
}
export -f shard
export CORES=$(nproc)

pids=()
for k in $(seq 1 "$n"); do
    if [ "$seconds" -gt 0 ]; then
        timeout "$seconds" bash -c 'shard "$@"' _ "$k" "$@" &
    else
        bash -c 'shard "$@"' _ "$k" "$@" &
    fi
    pids+=($!)
done
for p in "${pids[@]}"; do wait "$p" || true; done
find "$STORE" "$OUT" -name '.*.tmp-*' -delete 2>/dev/null || true  # what a stopped process was writing
for set_name in "$@"; do
    echo "$set_name: $(find "$STORE/$set_name" -maxdepth 1 -name '*.npz' | wc -l) samples in $STORE/$set_name" \
         "$( [ "$MODE" = loop ] && echo ", $(cat "$OUT/user/$set_name/cases.jsonl" 2>/dev/null | wc -l) rows in $OUT/user/$set_name")"
done
