#!/usr/bin/env bash
# The fast tests (pytest -m "not slow") where .ci/run's own run does not reach: Python 3.10 and 3.13
# with the newest dependencies, and Python 3.10 with the lowest versions pyproject.toml declares
# (.ci/floors.txt). Each job gets a fresh venv under a temporary folder, removed after it.
#
# Installs go through uv (`uv pip install`), not pip: on Python 3.10 pip's resolver backtracked for
# over 20 minutes over the test extra's tree (many newest releases need Python >= 3.11) where uv
# resolves the same tree in under a minute. uv reads no pip configuration: it installs from PyPI.
#
# Cost: torch has a local CPU wheel only for Python 3.11 (the one .ci/run uses); on 3.10 and 3.13 the
# installs take PyPI's CUDA build with its nvidia-* packages (about 3 GB to download, 4.7 GB
# installed). uv's download cache lives in the temporary folder too, shared by the jobs.
#
# The floors job installs every extra the tests use but the zoo: rl-zoo3's first release for SB3 2.9
# (the zoo extra's floor) cannot be installed beside stable-baselines3 2.4, the core floor, so
# tests/test_zoo.py skips there. The extras resolve to what uv finds beside the pinned floors.
set -euo pipefail
repo="$(cd "$(dirname "$0")/.." && pwd)"
work="$(mktemp -d)"
trap 'rm -rf "$work"' EXIT
unset PYTHONPATH
export UV_CACHE_DIR="$work/uv-cache"
# uv from the CI interpreter's packages (`python3 -m uv`: no PATH or shim to depend on), pinned as the
# lint extra pins ruff and mypy: a newer resolver may choose other versions.
python3 -m pip install --quiet "uv==0.13.9"
start=$SECONDS

# The interpreter for version $1 (3.10): python3.10 where it runs (pyenv's shim may exist and refuse),
# else pyenv's own copy.
interpreter() {
    local found
    for found in "$(command -v "python$1" || true)" "$HOME"/.pyenv/versions/"$1".*/bin/"python$1"; do
        if [ -n "$found" ] && [ -x "$found" ] && "$found" -c 'import venv' 2> /dev/null; then
            echo "$found"
            return
        fi
    done
    echo "matrix: no python$1 on this machine (needed for the fast tests on Python $1)" >&2
    return 1
}

# job NAME PYTHON_VERSION TORCH CONSTRAINTS EXTRAS [MORE_REQUIREMENTS...]
job() {
    local name="$1" version="$2" torch="$3" constraints="$4" extras="$5"
    shift 5
    local python venv="$work/$name" job_start=$SECONDS
    python="$(interpreter "$version")"
    echo "== matrix ($((SECONDS - start)) s): $name: Python $("$python" -c 'import platform; print(platform.python_version())')"
    "$python" -m venv "$venv"
    local pip=(python3 -m uv pip install --quiet --python "$venv/bin/python")
    if [ -n "$constraints" ]; then
        pip+=(-c "$constraints")
    fi
    # torch first and pinned, as in .ci/run (unpinned, the newest build), and pinned again beside the
    # package so that resolving its extras cannot move it.
    "${pip[@]}" "torch==$torch"
    "${pip[@]}" -e "$repo[$extras]" -e "$repo/lab" "torch==$torch" "$@"
    "$venv/bin/python" -c 'import gymnasium, numpy, scipy, stable_baselines3, torch, yaml
print("   ", ", ".join(f"{m.__name__} {m.__version__}" for m in (torch, stable_baselines3, gymnasium, numpy, scipy, yaml)))'
    (cd "$repo" && PATH="$venv/bin:$PATH" "$venv/bin/python" -m pytest -m "not slow" -p no:cacheprovider -q)
    rm -rf "$venv"
    echo "== matrix: $name passed in $((SECONDS - job_start)) s"
}

job py310 3.10 2.13.0 "" test
job py313 3.13 2.13.0 "" test
job floors 3.10 2.0.0 "$repo/.ci/floors.txt" experiments,ray,minari,contrib,hub \
    "pytest>=7.0" "pytest-xdist>=3.0" "tensorboard>=2.10" "minari[create]>=0.5,<0.6"
echo "== matrix: all passed in $((SECONDS - start)) s"
