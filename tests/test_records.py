"""The committed run records (results/) and expert metadata (experts/) are portable."""

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
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
    assert (ROOT / "results" / "runs").is_dir()
    assert not list((ROOT / "docs").glob("runs*")) and not (ROOT / "docs" / "tuning").exists()
