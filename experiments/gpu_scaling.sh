#!/usr/bin/env bash
# Issue 22's GPU row, for the next lent GPU (about 4 minutes): Go2's training rate on one device
# at growing env counts, up to the largest that fits, against BENCHMARKS' batched 4096-env runs.
#   bash experiments/gpu_scaling.sh            # ENVS="16384 65536" by default; LIMIT s per count
set -u
ENVS=${ENVS:-"16384 65536"}
LIMIT=${LIMIT:-95}
for n in $ENVS; do
    echo "== envs=$n"
    timeout "$LIMIT" python3 experiments/bench_devices.py exp=go2_from_scratch envs="$n" iterations=3 \
        engines=mjx devices=1 2>&1 | tail -n 8
done
