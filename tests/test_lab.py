"""The lab beside the library: its commands reached from ``sb3-cmzdril`` (or a one-line pointer where it
is not installed), the old import paths of what moved, and the compact run records it reads."""
from __future__ import annotations

import dataclasses
import io
import shlex
import subprocess
import sys
import tarfile
from pathlib import Path

import pytest

from sb3_cmzdril import UserError
from sb3_cmzdril.cli import main


def test_the_lab_commands_are_reached_from_the_library_command_line(capsys):
    with pytest.raises(SystemExit) as exit_info:
        main(["report", "--help"])
    assert exit_info.value.code == 0
    assert "--reference-runs" in capsys.readouterr().out


def test_without_the_lab_its_commands_answer_in_one_line(monkeypatch, capsys):
    import sb3_cmzdril.cli as cli

    monkeypatch.setattr(cli, "_plugin_commands", lambda: {})
    assert main(["benchmark", "--env", "HalfCheetah-v5", "--trials", "2"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "`benchmark` moved to the lab" in err[0] and "pip install -e lab/" in err[0]


def test_the_old_import_paths_resolve_to_the_moved_modules_with_a_warning():
    code = (
        "import warnings\n"
        "with warnings.catch_warnings(record=True) as caught:\n"
        "    warnings.simplefilter('always')\n"
        "    from sb3_cmzdril.experiments.run.spec import RunSpec\n"
        "    from sb3_cmzdril.experiments.report.records import load_runs\n"
        "    from sb3_cmzdril.experiments import plan_run\n"
        "import sb3_cmzdril.training.spec as spec, cmzdril_lab.report.records as records\n"
        "assert RunSpec is spec.RunSpec and load_runs is records.load_runs and plan_run is spec.plan_run\n"
        "messages = [str(w.message) for w in caught if w.category is FutureWarning]\n"
        "assert any('sb3_cmzdril.experiments.run.spec moved to sb3_cmzdril.training.spec' in m for m in messages)\n"
        "assert any('sb3_cmzdril.experiments.report moved to cmzdril_lab.report' in m for m in messages)\n"
    )
    subprocess.run([sys.executable, "-c", code], check=True)


# -- the compact records ------------------------------------------------------------------------------
def _study(root):
    folder = root / "study"
    for trial in range(2):
        run = folder / "Env-v0" / "cmz" / f"trial{trial}"
        (run / "logs").mkdir(parents=True)
        (run / "eval.csv").write_text(f"epoch,return\n0,{trial}\n")
        (run / "logs" / "progress_0.csv").write_text("a,b\n1,2\n")
    return folder


def _files(folder):
    return {p.relative_to(folder).as_posix(): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()
            and p.name != ".unpacked.json"}


def test_a_packed_study_unpacks_to_the_same_files_and_repacks_to_the_same_bytes(tmp_path):
    from cmzdril_lab.records_store import materialize, pack

    folder = _study(tmp_path)
    before = _files(folder)
    archive = pack(folder)
    data = archive.read_bytes()
    import shutil

    shutil.rmtree(folder)
    # Reading a run below the archived folder unpacks the whole study.
    assert materialize(folder / "Env-v0" / "cmz" / "trial1") == folder / "Env-v0" / "cmz" / "trial1"
    assert _files(folder) == before
    assert pack(folder).read_bytes() == data
    # A path outside any archived study is left alone.
    assert materialize(tmp_path / "elsewhere") == tmp_path / "elsewhere"


def test_an_unpacked_study_is_refreshed_when_its_archive_changes_but_never_over_unpacked_runs(tmp_path):
    import shutil

    from cmzdril_lab.records_store import materialize, pack

    folder = _study(tmp_path)
    pack(folder)
    copy = tmp_path / "copy"
    shutil.copytree(folder, copy / "study")
    (copy / "study" / "Env-v0" / "cmz" / "trial0" / "eval.csv").write_text("epoch,return\n0,42\n")
    new_archive = pack(copy / "study").read_bytes()
    (tmp_path / "study.tar.xz").write_bytes(new_archive)  # as a `git pull` brings a newer archive
    materialize(folder)
    assert (folder / "Env-v0" / "cmz" / "trial0" / "eval.csv").read_text() == "epoch,return\n0,42\n"
    # A run added after unpacking is the user's: a changed archive does not replace it.
    (folder / "Env-v0" / "cmz" / "trial2").mkdir()
    (folder / "Env-v0" / "cmz" / "trial2" / "eval.csv").write_text("epoch,return\n0,7\n")
    (tmp_path / "study.tar.xz").write_bytes(pack(_study(tmp_path / "other")).read_bytes())
    with pytest.raises(UserError, match="holds runs added or changed since it was unpacked"):
        materialize(folder)
    assert (folder / "Env-v0" / "cmz" / "trial2" / "eval.csv").exists()


def test_an_archive_member_outside_its_folder_is_refused(tmp_path):
    from cmzdril_lab.records_store import materialize

    buffer = io.BytesIO()
    with tarfile.open(fileobj=buffer, mode="w:xz") as tar:
        info = tarfile.TarInfo("../escaped.txt")
        info.size = 2
        tar.addfile(info, io.BytesIO(b"hi"))
    (tmp_path / "study.tar.xz").write_bytes(buffer.getvalue())
    with pytest.raises(UserError, match="'../escaped.txt' is not a plain file inside"):
        materialize(tmp_path / "study")
    assert not (tmp_path / "escaped.txt").exists() and not (tmp_path / "study").exists()


# -- the published numbers, from the compact records --------------------------------------------------
REPO = Path(__file__).resolve().parent.parent


def _published_command(page: Path) -> list[str]:
    """The report command a generated page names (its line ``    sb3-cmzdril report ...``), as arguments."""
    lines = [line.strip() for line in page.read_text(encoding="utf-8").splitlines()
             if line.startswith("    sb3-cmzdril report ")]
    assert len(lines) == 1, f"{page} names its report command once"
    return shlex.split(lines[0])[1:]


def _csv_cells(path: Path) -> list[list[object]]:
    """A CSV's cells, numbers rounded to 9 significant digits: the same table, whichever numpy summed it
    (the last digit of a float's repr moves between numpy versions; a published number does not)."""
    import csv

    def cell(text: str) -> object:
        try:
            number = float(text)
        except ValueError:
            return text
        return text if number != number else float(f"{number:.9g}")  # NaN as written: NaN != NaN

    with open(path, newline="", encoding="utf-8") as f:
        return [[cell(text) for text in row] for row in csv.reader(f)]


def _without(args: list[str], option: str) -> list[str]:
    if option not in args:
        return args
    at = args.index(option)
    return args[:at] + args[at + 2:]


#: runs folders a study copies together from the committed records (not committed themselves): the command
DERIVED_RUNS = {"results/default_grid": [sys.executable, str(REPO / "benchmarks" / "studies" / "one_default.py"),
                                         "--grid", str(REPO / "results" / "default_grid")]}


@pytest.mark.parametrize("page", ["docs/results.md", "docs/tuned/results.md", "docs/untuned/results.md"])
def test_the_published_tables_regenerate_from_the_compact_records_unchanged(page, tmp_path, monkeypatch):
    published = REPO / page
    args = _without(_without(_published_command(published), "-o"), "--readme")
    runs = args[1]  # args: report RUNS_DIR ...
    if runs in DERIVED_RUNS and not (REPO / runs).is_dir():
        # the script reads each task's action bounds from its env (which runs the default stands on)
        pytest.importorskip("mujoco", reason="the MuJoCo tasks' envs are in the test extra")
        pytest.importorskip("Box2D", reason="the Box2D tasks' envs are in the test extra")
        subprocess.run(DERIVED_RUNS[runs], check=True, capture_output=True)
    monkeypatch.chdir(REPO)  # the command names the records by their paths in the repository
    assert main([*args, "-o", str(tmp_path), "--no-figures"]) == 0
    csvs = sorted(p.name for p in tmp_path.glob("*.csv"))
    assert csvs and "final_table.csv" in csvs
    for name in csvs:
        assert _csv_cells(tmp_path / name) == _csv_cells(published.parent / name), name

    def table_rows(path: Path) -> list[str]:
        return [line for line in path.read_text(encoding="utf-8").splitlines() if line.startswith("|")]

    assert table_rows(tmp_path / "results.md") == table_rows(published)


# -- the grid's plan ---------------------------------------------------------------------------------
def test_a_grid_refuses_methods_that_would_split_a_trial_differently(tiny_experiment, tmp_path):
    from cmzdril_lab.run.grid import plan_grid
    from helpers import ENV

    hp = tmp_path / "per_method.yml"
    hp.write_text(tiny_experiment["hp"].read_text().replace("default:", f"{ENV}:", 1)
                  + "  per_method:\n    cmz:\n      n_demos: 2\n")
    with pytest.raises(UserError, match=r"trial 0: the methods would split the demo pool differently \(bc: 1 "
                                        r"training.*cmz: 2 training"):
        plan_grid(ENV, "bc,cmz", 1, tmp_path / "runs", demos_dir=tiny_experiment["demos_dir"], hyperparams=hp,
                  timesteps=256, n_eval_episodes=2)
    assert not (tmp_path / "runs").exists()


def test_a_grid_refuses_a_hyperparameter_file_that_none_of_its_methods_reads(tiny_experiment, tmp_path):
    from cmzdril_lab.run.grid import plan_grid
    from helpers import ENV

    with pytest.raises(UserError, match=r"--hyperparams .* is read by the PPO methods only and --methods has "
                                        r"none \(cmz-sac\); pass it as --sac-hyperparams"):
        plan_grid(ENV, "cmz-sac", 1, tmp_path / "runs", demos_dir=tiny_experiment["demos_dir"],
                  hyperparams=tiny_experiment["hp"], timesteps=256, n_eval_episodes=2)


def test_a_run_says_when_its_versions_differ_from_the_published_records(monkeypatch):
    import sb3_cmzdril.io
    from sb3_cmzdril.cli.train import published_versions_note as old_note
    from sb3_cmzdril.io import file_sha256
    from sb3_cmzdril.shipped import published_versions, shipped_demos
    from sb3_cmzdril.training.runs import published_versions_note

    pins = published_versions()
    same = {"gymnasium": pins["gymnasium"], "mujoco": pins["mujoco"], "numpy": pins["numpy"],
            "stable_baselines3": pins["stable-baselines3"], "torch": pins["torch"] + "+cpu", "python": "3.12.1"}
    published = {"demos_sha256": file_sha256(shipped_demos("HalfCheetah-v5"))}
    assert published_versions_note({**published, "versions": same}) is None
    note = published_versions_note({**published, "versions": {**same, "mujoco": "9.9.9"}})
    assert note is not None and f"mujoco 9.9.9 (published: {pins['mujoco']})" in note
    assert "pip install -c constraints/published.txt" in note
    # A user's own pool has no published records to differ from.
    own = REPO / "results" / "pools" / "tqc" / "Walker2d-v5" / "demos.npz"
    assert published_versions_note({"demos_sha256": file_sha256(own), "versions": {**same, "mujoco": "9.9.9"}}) is None
    # The name the command line had, deprecated: the same note of a pool and this machine's versions.
    monkeypatch.setattr(sb3_cmzdril.io, "versions", lambda: {**same, "mujoco": "9.9.9"})
    with pytest.warns(FutureWarning, match="published_versions_note moved to sb3_cmzdril.training.runs"):
        assert old_note(shipped_demos("HalfCheetah-v5")) == note


def test_a_report_says_which_runs_on_a_published_pool_were_made_with_other_versions(caplog):
    from cmzdril_lab.records_store import materialize
    from cmzdril_lab.report.records import load_runs, note_versions

    records = load_runs(materialize(REPO / "results" / "runs"))
    assert note_versions(records, REPO) == []  # the published grid itself
    changed = [dataclasses.replace(r, config={**r.config, "versions": {**r.config["versions"], "mujoco": "9.9.9"}})
               for r in records[:3]]
    (line,) = note_versions([*changed, *records[3:]], REPO)
    assert f"3 of {len(records)} runs were made with mujoco 9.9.9 (published: 4.0.0)" in line


def test_the_new_tasks_page_regenerates_from_the_compact_records_unchanged(tmp_path):
    script = REPO / "benchmarks" / "studies" / "new_tasks.py"
    subprocess.run([sys.executable, str(script), "--output", str(tmp_path), "--force"], cwd=REPO, check=True,
                   capture_output=True)

    def rows(path: Path) -> list[str]:
        return [line for line in path.read_text(encoding="utf-8").splitlines() if line.startswith("|")]

    published = rows(REPO / "docs" / "new_tasks.md")
    assert len(published) > 100 and rows(tmp_path / "new_tasks.md") == published


def test_the_one_default_page_table_is_what_the_records_give():
    # the script reads each task's action bounds from its env (the held-out NLL's units)
    pytest.importorskip("mujoco", reason="the MuJoCo tasks' envs are in the test extra")
    pytest.importorskip("Box2D", reason="the Box2D tasks' envs are in the test extra")
    script = REPO / "benchmarks" / "studies" / "one_default.py"
    result = subprocess.run([sys.executable, str(script), "--check"], cwd=REPO, capture_output=True, text=True)
    assert result.returncode == 0, result.stderr[-2000:]


def test_the_default_grid_replaces_a_folder_only_when_asked(tmp_path):
    script = REPO / "benchmarks" / "studies" / "one_default.py"
    (tmp_path / "mine.txt").write_text("mine")
    result = subprocess.run([sys.executable, str(script), "--grid", str(tmp_path)], cwd=REPO, capture_output=True,
                            text=True)
    assert result.returncode == 2
    assert result.stderr.strip() == f"{tmp_path} exists; pass --force to replace it"
    assert (tmp_path / "mine.txt").read_text() == "mine"


def test_an_archive_keeps_the_records_and_leaves_the_models_out(tmp_path):
    from cmzdril_lab.records_store import pack

    folder = _study(tmp_path)
    run = folder / "Env-v0" / "cmz" / "trial0"
    for name in ("model.zip", "model_lowest_u.zip", "lowest_u.pt", "replay_buffer.pkl", "log.txt", ".lock"):
        (run / name).write_bytes(b"x")
    with tarfile.open(pack(folder), "r:xz") as tar:
        names = sorted(tar.getnames())
    assert names == ["Env-v0/cmz/trial0/eval.csv", "Env-v0/cmz/trial0/logs/progress_0.csv",
                     "Env-v0/cmz/trial1/eval.csv", "Env-v0/cmz/trial1/logs/progress_0.csv"]


def test_the_labs_own_command_names_itself(capsys):
    from cmzdril_lab.cli import main as lab_main

    with pytest.raises(SystemExit) as exit_info:
        lab_main(["--help"])
    out = capsys.readouterr().out
    assert exit_info.value.code == 0 and out.startswith("usage: cmzdril-lab")
    assert "The sb3-cmzdril lab" in out and "pack" in out and "unpack" in out and "train-expert" not in out
