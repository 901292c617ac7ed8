#!/usr/bin/env bash
# Tasks nobody here tuned for, run as a new user would: a published RL Zoo agent records the demo pool,
# the grid runs with the package defaults before 0.3.0 (the paper's settings, kept in
# benchmarks/studies/untuned.yml; D14, the rules that replaced them: docs/one_default.md), and the report
# goes to docs/untuned/. BipedalWalker-v3, Ant-v5,
# MountainCarContinuous-v0 and BipedalWalkerHardcore-v3 here;
# Pendulum-v1 by benchmarks/studies/untuned_pendulum.sh, which this script calls before the report.
# Resumable: rerun it to continue; finished runs are skipped, an existing pool is kept.
#
#   bash benchmarks/studies/untuned_task.sh      # ZOO=path/to/rl-trained-agents if the clone is elsewhere
#
# ZOO (default: rl-trained-agents in the repository root, as experts/README.md has it) is a clone of
# https://github.com/DLR-RM/rl-trained-agents; the pool in results/untuned was recorded from commit
# cd35bde610f4045bf2e0731c8f4c88d22df8fc85. Only the pool needs it. The expert is the zoo's A2C agent
# (301.3 +/- 0.8 over the pool's 30 deterministic episodes): the copy of the zoo at hand had no model
# file for its SAC, TD3 and TQC agents of this env, and its PPO and TRPO agents scored 205 +/- 133 and
# 213 +/- 132 over the same episodes (docs/untuned/discussion.md). BipedalWalker-v3 needs Box2D
# (pip install "gymnasium[box2d]"). About 12 CPU-minutes a PPO run on a 2-core machine, 2 at a time.
source "$(dirname "$0")/untuned_common.sh"
env_id=BipedalWalker-v3
record_pool "$env_id"
$cli benchmark --env "$env_id" --methods bc,cmz,env,dril --trials 5 --timesteps 300000 --eval-every 5 \
    --hyperparams "$hyperparams" --workers "$workers" --no-progress --demos-dir "$untuned" -o "$untuned"
# The off-policy method, one trial, by this command since its kept policy is, where the expert ends its
# episodes, the check whose episodes last as long as the expert's (results/tuning/goal-tasks-u-alone: the
# same training keeping the lowest u alone, a rule that never shipped). Before that, the same training made
# the study results/tuning/BW-sac-auto-tie-u (the `default` entry's disagreement: auto and longest_tie_break:
# lowest_u by --set, before the entry took them); the entry before's run (trials 0-2 asked, stopped after 0)
# is in results/tuning/BW-sac-default-before.
$cli benchmark --env "$env_id" --methods cmz-sac --trials 0-0 --eval-every 5 --workers 1 --no-progress \
    --demos-dir "$untuned" -o "$untuned"
# Ant-v5, from the zoo's ARS agent of Ant-v3 (collect-demos pads its contact-force inputs with the zeros it
# saw in training; its A2C agent ends lower in the zoo's own evaluations.npz, its PPO agent needs the
# TimeFeatureWrapper collect-demos does not apply, and the clone had no model file for its SAC, TD3 and TQC).
# BC and CMZ-DRIL only (the other methods were not run for time).
record_pool Ant-v5 ars/Ant-v3_1
$cli benchmark --env Ant-v5 --methods bc,cmz --trials 5 --timesteps 300000 --eval-every 5 \
    --hyperparams "$hyperparams" --workers "$workers" --no-progress --demos-dir "$untuned" -o "$untuned"
# MountainCarContinuous-v0, from the zoo's SAC agent (94.7 +/- 1.1 over the pool's 30 episodes, 100 steps on
# average): its expert, like BipedalWalker-v3's, ends the episode at the goal. BC (trials 0-9), the off-policy method
# and PPO's CMZ-DRIL (trials 0-4), and the RL ceiling (PPO on the env's reward, trials 0-2; DRIL, no reward and
# env-sac were not run, for time).
record_pool MountainCarContinuous-v0 sac/MountainCarContinuous-v0_1
$cli benchmark --env MountainCarContinuous-v0 --methods bc --trials 0-9 --eval-every 5 --workers "$workers" \
    --hyperparams "$hyperparams" --no-progress --demos-dir "$untuned" -o "$untuned"
$cli benchmark --env MountainCarContinuous-v0 --methods cmz-sac --trials 0-4 --eval-every 5 \
    --workers "$workers" --no-progress --demos-dir "$untuned" -o "$untuned"
$cli benchmark --env MountainCarContinuous-v0 --methods cmz --trials 0-4 --timesteps 300000 --eval-every 5 \
    --hyperparams "$hyperparams" --workers "$workers" --no-progress --demos-dir "$untuned" -o "$untuned"
$cli benchmark --env MountainCarContinuous-v0 --methods env --trials 0-2 --timesteps 300000 --eval-every 5 \
    --hyperparams "$hyperparams" --workers "$workers" --no-progress --demos-dir "$untuned" -o "$untuned"
# BipedalWalkerHardcore-v3 (stumps, pits and stairs on the course), from the zoo's PPO agent (138.8 +/- 123.2 over the
# pool's 30 episodes, 12 of them falls; its A2C agent 110.1 +/- 134.0, and the clone had no model file for its SAC,
# TD3 and TQC agents): a task nobody tuned for where cloning one episode fails. BC (trials 0-9), the off-policy
# method, PPO's CMZ-DRIL and the RL ceiling (PPO on the env's reward; run as --trials 0-0, 1-2 and then 0-4),
# trials 0-4; DRIL, no reward and env-sac were not run.
record_pool BipedalWalkerHardcore-v3 ppo/BipedalWalkerHardcore-v3_1
$cli benchmark --env BipedalWalkerHardcore-v3 --methods bc --trials 0-9 --eval-every 5 --workers "$workers" \
    --hyperparams "$hyperparams" --no-progress --demos-dir "$untuned" -o "$untuned"
$cli benchmark --env BipedalWalkerHardcore-v3 --methods cmz-sac --trials 0-4 --eval-every 5 \
    --workers "$workers" --no-progress --demos-dir "$untuned" -o "$untuned"
$cli benchmark --env BipedalWalkerHardcore-v3 --methods cmz --trials 0-4 --timesteps 300000 --eval-every 5 \
    --hyperparams "$hyperparams" --workers "$workers" --no-progress --demos-dir "$untuned" -o "$untuned"
$cli benchmark --env BipedalWalkerHardcore-v3 --methods env --trials 0-4 --timesteps 300000 --eval-every 5 \
    --hyperparams "$hyperparams" --workers "$workers" --no-progress --demos-dir "$untuned" -o "$untuned"
# Pendulum-v1, where cloning one episode fails: its own script (the package defaults and the zoo's PPO settings).
bash benchmarks/studies/untuned_pendulum.sh
$cli report "$untuned" -o docs/untuned --no-paper --label "tasks nobody here tuned for, the package defaults" \
    --discussion docs/untuned/discussion.md --force
