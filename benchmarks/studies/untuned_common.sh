# Sourced by the studies of tasks nobody here tuned for (untuned_task.sh, untuned_pendulum.sh): the
# repository root, the command, the runs folder, and the demo pool of a published RL Zoo agent.
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/../.."
zoo=${ZOO:-rl-trained-agents}
untuned=results/untuned
# CMZDRIL's defaults before 0.3.0, which the study ran on (PPO methods; cmz-sac reads its own file)
hyperparams=benchmarks/studies/untuned.yml
workers=${WORKERS:-2}
cli=${SB3_CMZDRIL:-sb3-cmzdril}
# The study's records are committed as results/untuned.tar.xz: unpack them before adding runs, and
# `cmzdril-lab pack results/untuned` afterwards to commit what the runs added.
if [ -f "$untuned.tar.xz" ]; then cmzdril-lab unpack "$untuned"; fi

# record_pool ENV_ID [AGENT]: the 30 deterministic episodes (reset seeds 0-29) of the zoo's agent AGENT
# (a folder of the zoo's clone; default: its A2C agent of ENV_ID) into results/untuned/ENV_ID/demos.npz;
# an existing pool is kept.
record_pool() {
    local pool=$untuned/$1/demos.npz
    if [ ! -f "$pool" ]; then
        $cli collect-demos --expert "$zoo/${2:-a2c/${1}_1}" --env "$1" --episodes 30 --seed 0 -o "$pool"
    fi
}
