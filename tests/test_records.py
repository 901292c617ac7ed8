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


#: The folders whose rows the docs call the published grid (its trials 5-9 among them): its tuned entries make
#: them (hyperparams/cmzdril-tuned.yml, cmzdril_sac-tuned.yml), by the shipped file each learner reads.
PUBLISHED_FOLDERS = ("runs", "runs_cmz_trials5-9", "runs_dril_trials5-9", "runs_sac_trials5-9", "runs_bc_trials10")
TUNED = {"cmzdril.yml": ROOT / "hyperparams" / "cmzdril-tuned.yml",
         "cmzdril_sac.yml": ROOT / "hyperparams" / "cmzdril_sac-tuned.yml"}
#: Folders made with a YAML of their own: the tasks nobody here tuned for, on the defaults before 0.3.0, and
#: the paper-faithful grid.
STUDY_YAMLS = {"untuned": ROOT / "benchmarks" / "studies" / "untuned.yml",
               "runs_paper_faithful": ROOT / "hyperparams" / "cmzdril-paper.yml"}


def test_the_published_runs_are_what_the_shipped_hyperparameters_make():
    # A published row must come from the YAML its command names as that YAML is now, read by this version
    # (a record of an older one ran with that version's defaults): a default or an entry that changes moves
    # the runs it replaces out of these folders (and rerunning the grid resumes, not refuses).
    from sb3_cmzdril.hyperparams import load_hyperparams
    from sb3_cmzdril.training.run_folder import as_stored
    from sb3_cmzdril.training.spec import default_hyperparams_name, effective_values, record_made

    checked, stale = 0, []
    for folder in (*PUBLISHED_FOLDERS, *STUDY_YAMLS):
        for path in sorted((ROOT / "results" / folder).glob("*/*/trial*/config.json")):
            config = json.loads(path.read_text())
            method = config["method"]
            shipped = ROOT / "hyperparams" / f"{default_hyperparams_name(method)}.yml"
            yaml_file = (STUDY_YAMLS[folder] if folder in STUDY_YAMLS and shipped.name == "cmzdril.yml" else
                         TUNED[shipped.name] if folder in PUBLISHED_FOLDERS else shipped)
            entry = load_hyperparams(yaml_file, config["env_id"], method)
            checked += 1
            if (effective_values(as_stored({"values": entry.raw})["values"], method)
                    != effective_values(config["hyperparams_values"], method, **record_made(config))):
                stale.append(str(path.relative_to(ROOT)))
    assert checked > 200 and stale == []


def test_a_record_of_an_older_version_reads_a_default_it_left_out_as_that_version_had_it():
    from sb3_cmzdril.training.spec import effective_values, learner_defaults

    assert learner_defaults("cmz")["absorbing"] == "auto"
    assert learner_defaults("cmz", "0.2.0")["absorbing"] is False
    assert learner_defaults("cmz", "0.3.0.dev0")["absorbing"] == "auto"
    # within 0.1.0, a run made before standardisation and held-out early stopping existed ran without them
    early = learner_defaults("cmz", "0.1.0", "2026-11-21T07:31:25+0000")
    assert (early["standardize_observations"], early["bc_validation_fraction"], early["log_std_floor"]) == \
        (False, 0.0, None)
    later = learner_defaults("cmz", "0.1.0", "2026-11-21T18:56:23+00:00")
    assert (later["standardize_observations"], later["bc_validation_fraction"], later["log_std_floor"]) == \
        (True, 0.2, -1.0)
    # a 0.2.0 run that left absorbing out ran without the absorbing state: this version states it
    assert effective_values({"n_timesteps": 1e6}, "cmz", "0.2.0") == {
        "n_timesteps": 1e6, "absorbing": False, "cmz_clip_quantile": None, "disagreement": "std",
        "standardize_observations": True, "bc_epochs_per_update": 1}
    # the same entry now is another run; one that states the old values is the same run
    assert effective_values({"n_timesteps": 1e6}, "cmz") == {"n_timesteps": 1e6}
    assert effective_values({"n_timesteps": 1e6, "absorbing": False, "cmz_clip_quantile": None,
                             "disagreement": "std", "standardize_observations": True, "bc_epochs_per_update": 1},
                            "cmz") == effective_values({"n_timesteps": 1e6}, "cmz", "0.2.0")
    # a record that stated a default since adopted is the run that leaves it out now
    assert "absorbing" not in effective_values({"absorbing": "auto"}, "cmz", "0.2.0")


def test_the_constraints_file_names_the_versions_the_published_records_were_made_with():
    from sb3_cmzdril.shipped import published_versions, version_differences

    pins = published_versions()
    assert {"gymnasium", "mujoco", "numpy", "stable-baselines3", "torch"} <= set(pins)
    made_with = {json.dumps({k: v for k, v in json.loads(path.read_text())["versions"].items()
                             if k not in ("python", "sb3_cmzdril")}, sort_keys=True)
                 for path in (ROOT / "results" / "runs").glob("*/*/trial*/config.json")}
    assert len(made_with) == 1  # the grid was made with one set of versions
    assert version_differences(json.loads(made_with.pop())) == []
