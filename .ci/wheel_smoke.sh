#!/usr/bin/env bash
# The package as a user installs it: build the sdist and, from it, the wheel; install the wheel (not
# editable) into a fresh venv; from an empty folder run the commands a new user runs first, with the
# shipped demo pools, experts and hyperparameters the wheel carries. Tiny settings: a few minutes.
set -euo pipefail
repo="$(cd "$(dirname "$0")/.." && pwd)"
work="$(mktemp -d)"
trap 'rm -rf "$work"' EXIT
start=$SECONDS
step() { echo "== wheel smoke ($((SECONDS - start)) s): $*"; }

step "build the sdist, and the wheel from it"
python3 -m pip install --quiet build
python3 -m build --outdir "$work/dist" "$repo" > "$work/build.log" 2>&1 || { cat "$work/build.log"; exit 1; }
wheel=$(ls "$work"/dist/sb3_cmzdril-*.whl)
python3 -m build --wheel --outdir "$work/labdist" "$repo/lab" > "$work/build.log" 2>&1 || { cat "$work/build.log"; exit 1; }
labwheel=$(ls "$work"/labdist/sb3_cmzdril_lab-*.whl)
if python3 -m zipfile -l "$wheel" | grep -q cmzdril_lab; then echo "the library's wheel carries the lab"; exit 1; fi
# The README's Python blocks, shrunk exactly as tests/test_readme.py runs them.
python3 "$repo/tests/test_readme.py" "$work/readme" > /dev/null

step "a fresh venv (no system site-packages) with the wheel"
python3 -m venv "$work/venv"
export PATH="$work/venv/bin:$PATH" OMP_NUM_THREADS=1 MKL_NUM_THREADS=1
unset PYTHONPATH
# torch pinned first, as in .ci/run: pip finds the local CPU wheel where there is one.
python -m pip install --quiet torch==2.13.0
python -m pip install --quiet "${wheel}[experiments,zoo]"

mkdir "$work/empty"
cd "$work/empty"
test "$(python -c 'import sb3_cmzdril, pathlib; print(pathlib.Path(sb3_cmzdril.__file__).parent.parent)')" \
    = "$(python -c 'import sysconfig; print(sysconfig.get_paths()["purelib"])')"  # the wheel, not the checkout

step "sb3-cmzdril --version"
sb3-cmzdril --version

step "train on HalfCheetah-v5 with the shipped demo pool"
cat > "$work/tiny.yml" <<'YAML'
HalfCheetah-v5:
  n_timesteps: 1024
  policy: MlpPolicy
  n_steps: 512
  n_demos: 1
  ensemble_epochs: 20
  env_kwargs: "dict(max_episode_steps=100)"
YAML
sb3-cmzdril train --env HalfCheetah-v5 --reward cmz --hyperparams "$work/tiny.yml" --eval-episodes 2 --no-progress
test -f runs/HalfCheetah-v5/cmz/trial0/done.json

step "benchmark without the lab: one line, exit 2"
rc=0; sb3-cmzdril benchmark --env HalfCheetah-v5 2> "$work/moved.txt" || rc=$?
test "$rc" = 2 && grep -q "moved to the lab" "$work/moved.txt"

step "the lab's wheel beside the library's"
python -m pip install --quiet "${wheel}[experiments,zoo]" "$labwheel"

step "benchmark (one BC trial)"
sb3-cmzdril benchmark --env HalfCheetah-v5 --methods bc --trials 1 --hyperparams "$work/tiny.yml" --no-progress \
    -o bench
test -f bench/HalfCheetah-v5/bc/trial0/done.json

step "collect-demos from the shipped SAC expert"
sb3-cmzdril collect-demos --expert HalfCheetah-v5 --env HalfCheetah-v5 --episodes 1 -o demos.npz
python -c 'from sb3_cmzdril import Demonstrations; d = Demonstrations.load("demos.npz"); assert d.n_episodes == 1'

step "python -m sb3_cmzdril.zoo --help"
python -m sb3_cmzdril.zoo --help > /dev/null

for block in "$work"/readme/readme_*.py; do
    step "README block $(basename "$block")"
    python "$block"
done
step "done"
