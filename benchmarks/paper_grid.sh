#!/usr/bin/env bash
# The paper's experiment (issue 6): 5 methods x 5 trials on WaypointNav-v0, HalfCheetah-v5 and
# Hopper-v5, then Table I and Fig. 1-2 in docs/. Resumable: rerun it to continue; finished runs are
# skipped, interrupted ones continue from their checkpoints. Runs go to docs/runs/, where only their
# small records (eval.csv, config.json, state.json, done.json) are tracked by git.
# WaypointNav-v0 evaluates after every PPO update (its episodes are short); the MuJoCo envs every 5
# updates, since a 5 x 1000-step evaluation costs more than a training epoch there. Table I averages
# the evaluations that fall in each run's last 100 epochs.
set -euo pipefail
cd "$(dirname "$0")/.."
workers=${WORKERS:-2}
sb3-cmzdril benchmark --env sb3_cmzdril:WaypointNav-v0 --methods bc,zero,env,dril,cmz --trials 5 \
    --timesteps 300000 --workers "$workers" --eval-every 1 -o docs/runs
sb3-cmzdril benchmark --env HalfCheetah-v5,Hopper-v5 --methods bc,zero,env,dril,cmz --trials 5 \
    --timesteps 300000 --workers "$workers" --eval-every 5 -o docs/runs
sb3-cmzdril report docs/runs -o docs --discussion docs/discussion.md --readme README.md
