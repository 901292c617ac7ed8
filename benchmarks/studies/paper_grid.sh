#!/usr/bin/env bash
# The paper's experiment: 5 methods x 5 trials on HalfCheetah-v5, Hopper-v5 (1 demo) and
# WaypointNav-v0 (5 demos), 300k PPO steps, then Table I and Fig. 1-2 in docs/. Resumable: rerun it
# to continue; finished runs are skipped, interrupted ones continue from their checkpoints. Only the
# runs' small records (config, state, eval.csv, final_eval.csv, pretrain.csv, progress logs) are
# tracked by git.
#
#   bash benchmarks/studies/paper_grid.sh               # the tuned entries (hyperparams/cmzdril-tuned.yml) -> results/runs
#   HYPERPARAMS=hyperparams/cmzdril-paper.yml RUNS=results/runs_paper_faithful bash benchmarks/studies/paper_grid.sh
#                                                # the paper-faithful setting (raw inputs, 100 BC epochs)
#
# BC, CMZ-DRIL and no reward (the comparisons the claims rest on) run first on every env and trial,
# then DRIL and the env-reward bound. The MuJoCo envs evaluate every 5 PPO updates (a 5 x 1000-step
# evaluation costs more than a training epoch there), WaypointNav-v0 after every update; each run ends
# with a final evaluation of every pool episode it did not train on.
#
# Where a task's entry in hyperparams/cmzdril-tuned.yml changed after this grid ran (HalfCheetah-v5,
# Walker2d-v5, WaypointNav-v0), its runs in results/runs are the ones the entry's study made (its
# commands are in docs/new_tasks.md; WaypointNav-v0's evaluate every 5 updates); rerunning this
# script skips them as finished.
set -euo pipefail
cd "$(dirname "$0")/../.."
workers=${WORKERS:-2}
hyperparams=${HYPERPARAMS:-hyperparams/cmzdril-tuned.yml}
runs=${RUNS:-results/runs}
cli=${SB3_CMZDRIL:-sb3-cmzdril}
for methods in bc,cmz,zero dril,env; do
    $cli benchmark --env HalfCheetah-v5,Hopper-v5 --methods "$methods" --trials 5 \
        --timesteps 300000 --workers "$workers" --eval-every 5 --hyperparams "$hyperparams" -o "$runs"
    $cli benchmark --env sb3_cmzdril:WaypointNav-v0 --methods "$methods" --trials 5 \
        --timesteps 300000 --workers "$workers" --eval-every 1 --hyperparams "$hyperparams" -o "$runs"
done
