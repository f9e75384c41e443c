#!/usr/bin/env bash
# Make the magnum.np samples of one or more effects-bench sets with N processes of one core each
# (process K makes shard K/N of each set in turn; resumable: a sample already in the store is not made
# again; a sample stopped half-way is made again from its start). The loop is not run.
#
#   scripts/make_bench_samples.sh N STORE CACHE SECONDS SET [SET ...]
#
# STORE/SET holds each set's samples (one .npz per sample, written atomically; samples.jsonl: one line
# per case); CACHE is magnum.np's demag-kernel cache; SECONDS > 0 stops every process after that long
# (0: no limit); process K's log is STORE/logs/SET-shard-K.log. FORCDECODE names the command
# (default: forcdecode). Example, the committed store on a 2-core machine:
#   scripts/make_bench_samples.sh 2 docs/results/bench_samples cache/magnumnp 0 laptop-eval laptop-dev
set -euo pipefail
if [ $# -lt 5 ]; then
    sed -n 2,12p "$0"; exit 2
fi
n=$1; store=$2; cache=$3; seconds=$4; shift 4
export FORCDECODE=${FORCDECODE:-forcdecode} N_SHARDS=$n STORE=$store CACHE=$cache
export OMP_NUM_THREADS=1 MKL_NUM_THREADS=1 NUMBA_NUM_THREADS=1
mkdir -p "$cache" "$store/logs"
for set_name in "$@"; do mkdir -p "$store/$set_name"; done

shard() {  # shard K of every set named after it, one after the other
    local k=$1; shift
    for set_name in "$@"; do
        $FORCDECODE bench effects --independent --set "$set_name" --shard "$k/$N_SHARDS" --samples-only \
            --samples-dir "$STORE/$set_name" --cache-dir "$CACHE" >> "$STORE/logs/$set_name-shard-$k.log" 2>&1 \
            || echo "shard $k/$N_SHARDS of $set_name stopped: exit $?" >> "$STORE/logs/$set_name-shard-$k.log"
    done
}
export -f shard

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
find "$store" -name '.*.tmp-*' -delete  # what a stopped process was writing
for set_name in "$@"; do
    echo "$set_name: $(find "$store/$set_name" -name '*.npz' | wc -l) samples in $store/$set_name"
done
