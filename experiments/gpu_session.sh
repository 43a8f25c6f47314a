#!/usr/bin/env bash
# One lent GPU's session (2026-12-04, one NVIDIA H200): three programs at once, each writing its
# run folder under $RUNS, their logs under $LOGS.
#   A. Table IV's Go2 -> A1 row with 3 seeds: Go2 source, then A1 from scratch, with the paper's
#      transfer (L2) and with the semantic transfer (L2@semantic_actor).
#   B, C. Go2 on the full command ranges with the command curriculum (exp=go2_full_range, which
#      holds the settings these runs were made with) at two bars, 0.6 and 0.8, at a GPU budget (docs/command_grid.md measured 0.8 on CPU).
# Compiles run on the host's cores side by side; the GPU takes the three programs' kernels in
# turn (BENCHMARKS.md, "On a GPU"), so the wall time is about the sum of their env steps.
#
#   SCALE=paper SRC_IT=300 TGT_IT=200 JOY_IT=500 MEM_A=0.45 MEM_J=0.2 bash experiments/gpu_session.sh   # the GPU run
#   SCALE=smoke SRC_IT=2 TGT_IT=2 JOY_IT=2 ENGINE=mujoco bash experiments/gpu_session.sh  # CPU dry run
#
# The next lease (issue 23's open question, docs/table4.md): program A alone with the Go2 source
# under domain randomization, then issue 22's GPU row (experiments/gpu_scaling.sh, about 4 min):
#   PROGRAMS=a SRC_DR=true MEM_A=0.9 bash experiments/gpu_session.sh && bash experiments/gpu_scaling.sh
set -u
SCALE=${SCALE:-paper}
SRC_IT=${SRC_IT:-300}
TGT_IT=${TGT_IT:-200}
JOY_IT=${JOY_IT:-600}
ENGINE=${ENGINE:-mjx}
RUNS=${RUNS:-runs_gpu}
LOGS=${LOGS:-$RUNS/logs}
LIMIT=${LIMIT:-560}
# GPU memory per process (unset on CPU): A holds 9 runs of 4096 envs, B and C one each.
MEM_A=${MEM_A:-}
MEM_J=${MEM_J:-}
PROGRAMS=${PROGRAMS:-abc}  # which of A, B, C to run
SRC_DR=${SRC_DR:-false}    # domain randomization in A's Go2 source stage (envs.randomization's defaults)
mkdir -p "$LOGS"
FINAL=$(( SRC_IT < 60 ? 0 : 30 ))

A= B= C=
if [[ $PROGRAMS == *a* ]]; then
    env ${MEM_A:+XLA_PYTHON_CLIENT_MEM_FRACTION=$MEM_A} timeout "$LIMIT" python -m ptrl_jax.run exp=go2_to_a1 scale="$SCALE" engine="$ENGINE" runs_dir="$RUNS" \
        source.ppo.num_iterations="$SRC_IT" source.ppo.final_noise_iterations="$FINAL" \
        target.ppo.num_iterations="$TGT_IT" target.ppo.final_noise_iterations="$FINAL" \
        source.env.randomization.enabled="$SRC_DR" \
        "freeze_presets=[L2,L2@semantic_actor,scratch]" > "$LOGS/a_go2_to_a1.log" 2>&1 &
    A=$!
fi

joystick() {  # $1: the gain judge's bar, $2: log name
    env ${MEM_J:+XLA_PYTHON_CLIENT_MEM_FRACTION=$MEM_J} timeout "$LIMIT" python -m ptrl_jax.run exp=go2_full_range scale="$SCALE" engine="$ENGINE" runs_dir="$RUNS" seeds=1 \
        name="go2_full_range_gain$1" \
        target.ppo.num_iterations="$JOY_IT" target.ppo.final_noise_iterations="$FINAL" \
        target.env.commands.curriculum_threshold="$1" > "$LOGS/$2.log" 2>&1
}
if [[ $PROGRAMS == *b* ]]; then joystick 0.6 b_gain06 & B=$!; fi
if [[ $PROGRAMS == *c* ]]; then joystick 0.8 c_gain08 & C=$!; fi
for p in A B C; do
    pid=${!p}
    if [[ -n $pid ]]; then wait "$pid"; echo "$p rc=$?"; fi
done
