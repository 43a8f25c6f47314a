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
mkdir -p "$LOGS"
FINAL=$(( SRC_IT < 60 ? 0 : 30 ))

env ${MEM_A:+XLA_PYTHON_CLIENT_MEM_FRACTION=$MEM_A} timeout "$LIMIT" python -m ptrl_jax.run exp=go2_to_a1 scale="$SCALE" engine="$ENGINE" runs_dir="$RUNS" \
    source.ppo.num_iterations="$SRC_IT" source.ppo.final_noise_iterations="$FINAL" \
    target.ppo.num_iterations="$TGT_IT" target.ppo.final_noise_iterations="$FINAL" \
    "freeze_presets=[L2,L2@semantic_actor,scratch]" > "$LOGS/a_go2_to_a1.log" 2>&1 &
A=$!

joystick() {  # $1: the gain judge's bar, $2: log name
    env ${MEM_J:+XLA_PYTHON_CLIENT_MEM_FRACTION=$MEM_J} timeout "$LIMIT" python -m ptrl_jax.run exp=go2_full_range scale="$SCALE" engine="$ENGINE" runs_dir="$RUNS" seeds=1 \
        name="go2_full_range_gain$1" \
        target.ppo.num_iterations="$JOY_IT" target.ppo.final_noise_iterations="$FINAL" \
        target.env.commands.curriculum_threshold="$1" > "$LOGS/$2.log" 2>&1
}
joystick 0.6 b_gain06 &
B=$!
joystick 0.8 c_gain08 &
C=$!
wait $A; echo "A rc=$?"
wait $B; echo "B rc=$?"
wait $C; echo "C rc=$?"
