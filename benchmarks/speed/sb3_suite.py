"""SB3's own PPO tests with CMZDRIL standing in for PPO (``--algo sac``: its SAC tests with
CMZDRILSAC standing in for SAC): how much of a drop-in replacement each is.

    python benchmarks/speed/sb3_suite.py /path/to/stable-baselines3 [--algo sac] [--by-design] [-- pytest args]

The argument is a checkout of the stable-baselines3 repository (only its ``tests/`` and
``pyproject.toml`` are used; nothing is fetched or modified). The command runs pytest there with the
plugin beside this file (``sb3_suite_plugin.py``, ``-p sb3_suite_plugin``): before SB3's test
modules are imported it replaces ``stable_baselines3.PPO`` (``.SAC``) by a CMZDRIL (CMZDRILSAC) on
its defaults whose demonstrations are recorded from the model's own env with random actions (a few
hundred steps), and it keeps only that algorithm's cases: those parametrised with it, and
unparametrised tests whose code uses it and no other.

Cases that differ by design are counted apart (``--by-design`` lists them; the README's
"Spaces" paragraph says why): ``test_gae.py`` (it checks PPO's returns against the env reward, which
CMZDRIL replaces), ``test_identity.py`` (the algorithm must learn to a reward threshold in a few
thousand steps from the env reward), and ``test_tensorboard.py`` (the default run name is the
class's, ``CMZDRIL`` or ``CMZDRILSAC``).

The summary line at the end is pytest's; the counts go to docs/sb3_suite.md.
"""
from __future__ import annotations

import argparse
import os
import subprocess
import sys
from pathlib import Path


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("checkout", type=Path, help="a stable-baselines3 checkout (its tests/ are run)")
    parser.add_argument("--by-design", action="store_true", help="run the cases that differ by design instead")
    parser.add_argument("--algo", choices=("ppo", "sac"), default="ppo",
                        help="SB3's PPO cases with CMZDRIL in PPO's place, or its SAC cases with CMZDRILSAC")
    argv = sys.argv[1:] if argv is None else argv
    extra = argv[argv.index("--") + 1 :] if "--" in argv else []
    args = parser.parse_args(argv[: len(argv) - len(extra) - (1 if extra or "--" in argv else 0)])
    tests = args.checkout / "tests"
    if not tests.is_dir():
        print(f"error: {args.checkout} has no tests/ folder (is it a stable-baselines3 checkout?)", file=sys.stderr)
        return 2
    env = dict(os.environ)
    here = str(Path(__file__).resolve().parent)
    env["PYTHONPATH"] = os.pathsep.join([here, env.get("PYTHONPATH", "")]).rstrip(os.pathsep)
    env.setdefault("PYTHONHASHSEED", "0")
    env.setdefault("OMP_NUM_THREADS", "1")
    # Node ids among the pytest arguments (tests/test_x.py::case) replace the whole tests/ folder.
    targets = [] if any(not a.startswith("-") for a in extra) else [str(tests)]
    cmd = [sys.executable, "-m", "pytest", *targets, "-p", "sb3_suite_plugin", "-q", "-p", "no:cacheprovider"]
    # Modules whose optional dependencies are missing (ale_py for test_utils.py) hold no PPO case.
    cmd.append("--continue-on-collection-errors")
    cmd += ["--sb3-algo", args.algo]
    if args.by_design:
        cmd.append("--sb3-by-design")
    return subprocess.call(cmd + extra, cwd=args.checkout, env=env)


if __name__ == "__main__":
    sys.exit(main())
