"""The committed run records (results/, each study one NAME.tar.xz unpacked beside it) and expert
metadata (experts/): compact, portable, and the published runs are what the shipped hyperparameters make."""

import json
import re
import subprocess
from pathlib import Path

import pytest

from cmzdril_lab.records_store import SUFFIX, materialize_all

ROOT = Path(__file__).resolve().parent.parent


@pytest.fixture(scope="module", autouse=True)
def unpacked():
    """Every archived study, unpacked (once; again only when its archive changed)."""
    return materialize_all(ROOT / "results")


def test_the_run_records_are_a_few_compressed_files_and_the_repository_stays_small():
    tracked = subprocess.run(["git", "ls-files"], cwd=ROOT, capture_output=True, text=True, check=True).stdout
    files = tracked.splitlines()
    if not files:  # not a git checkout (an sdist): nothing to count
        pytest.skip("not a git checkout")
    in_results = [f for f in files if f.startswith("results/")]
    assert sum(f.endswith(SUFFIX) for f in in_results) >= 10
    assert len([f for f in in_results if not f.endswith(SUFFIX)]) <= 40 and len(files) <= 800
#: An absolute POSIX path at the start of a JSON string or after a space (a command's argument).
ABSOLUTE = re.compile(r'(?:"|\s)/(?:work|home|root|tmp|Users|opt|usr|mnt|data)/')


def test_committed_records_hold_no_absolute_paths_of_the_machine_that_made_them():
    offenders = []
    for folder in ("results", "experts"):
        for path in (ROOT / folder).rglob("*"):
            if path.suffix in {".json", ".jsonl", ".md", ".csv", ".yml", ".txt"} and path.is_file():
                if ABSOLUTE.search(path.read_text(encoding="utf-8", errors="replace")):
                    offenders.append(str(path.relative_to(ROOT)))
    assert offenders == []


def test_the_run_records_live_apart_from_the_documentation_source():
    assert (ROOT / "results" / f"runs{SUFFIX}").is_file() and (ROOT / "results" / "runs").is_dir()
    assert not list((ROOT / "docs").glob("runs*")) and not (ROOT / "docs" / "tuning").exists()


#: The folders whose rows the docs call the package defaults: the published grid, its trials 5-9 and the
#: task nobody here tuned for (results/untuned: the `default` entry).
DEFAULTS_FOLDERS = ("runs", "runs_cmz_trials5-9", "runs_dril_trials5-9", "runs_sac_trials5-9", "runs_bc_trials10",
                    "untuned")


def test_the_published_runs_are_what_the_shipped_hyperparameters_make():
    # A row labelled "package defaults" must come from the shipped YAML as it is now: a default that
    # changes moves the runs it replaces out of these folders (and rerunning the grid resumes, not refuses).
    from sb3_cmzdril.hyperparams import load_hyperparams
    from sb3_cmzdril.training.run_folder import as_stored
    from sb3_cmzdril.training.spec import default_hyperparams_name, effective_values

    checked, stale = 0, []
    for folder in DEFAULTS_FOLDERS:
        for path in sorted((ROOT / "results" / folder).glob("*/*/trial*/config.json")):
            config = json.loads(path.read_text())
            shipped = ROOT / "hyperparams" / f"{default_hyperparams_name(config['method'])}.yml"
            entry = load_hyperparams(shipped, config["env_id"], config["method"])
            checked += 1
            method = config["method"]
            if (effective_values(as_stored({"values": entry.raw})["values"], method)
                    != effective_values(config["hyperparams_values"], method)):
                stale.append(str(path.relative_to(ROOT)))
    assert checked > 200 and stale == []


def test_the_constraints_file_names_the_versions_the_published_records_were_made_with():
    from sb3_cmzdril.shipped import published_versions, version_differences

    pins = published_versions()
    assert {"gymnasium", "mujoco", "numpy", "stable-baselines3", "torch"} <= set(pins)
    made_with = {json.dumps({k: v for k, v in json.loads(path.read_text())["versions"].items()
                             if k not in ("python", "sb3_cmzdril")}, sort_keys=True)
                 for path in (ROOT / "results" / "runs").glob("*/*/trial*/config.json")}
    assert len(made_with) == 1  # the grid was made with one set of versions
    assert version_differences(json.loads(made_with.pop())) == []
