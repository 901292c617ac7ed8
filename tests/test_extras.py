"""The core install: the library imports and trains without any extra; a missing extra is named."""
from __future__ import annotations

import subprocess
import sys
import textwrap

import pytest

from sb3_cmzdril.extras import EXTRAS, MissingExtraError, require_extra

#: Top-level packages that only extras install.
EXTRA_ONLY = (
    "matplotlib", "mujoco", "ray", "tqdm", "rich", "minari", "rl_zoo3", "tensorboard", "jax", "huggingface_hub"
)


@pytest.mark.slow
def test_import_and_training_need_no_extra():
    # A fresh interpreter in which every extra-only package fails to import, as in a core install.
    script = textwrap.dedent(
        f"""
        import sys

        for name in {EXTRA_ONLY!r}:
            sys.modules[name] = None  # `import name` now fails as if it were not installed
        import numpy as np
        import sb3_cmzdril
        from sb3_cmzdril import CMZDRIL, Demonstrations
        rng = np.random.default_rng(0)
        demos = Demonstrations(rng.normal(size=(40, 3)), rng.uniform(-2, 2, size=(40, 1)), [20, 20])
        model = CMZDRIL("MlpPolicy", "Pendulum-v1", demonstrations=demos, n_steps=32, batch_size=32, n_epochs=1,
                        ensemble_size=2, ensemble_hidden=(8,), ensemble_epochs=1, bc_pretrain_epochs=1,
                        policy_kwargs=dict(net_arch=[8]), seed=0, device="cpu")
        model.learn(32)
        loaded = sorted(m for m, mod in sys.modules.items() if mod is not None and m.split(".")[0] in {EXTRA_ONLY!r})
        print("OK", model.num_timesteps, loaded, sb3_cmzdril.__version__)
        """
    )
    result = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr[-2000:]
    assert result.stdout.split()[:3] == ["OK", "32", "[]"]


@pytest.mark.slow
def test_progress_bars_and_the_command_line_name_the_experiments_extra():
    script = textwrap.dedent(
        f"""
        import sys

        for name in {EXTRA_ONLY!r}:
            sys.modules[name] = None
        import numpy as np
        from sb3_cmzdril import CMZDRIL, Demonstrations
        from sb3_cmzdril.cli import main
        from sb3_cmzdril.extras import MissingExtraError
        rng = np.random.default_rng(0)
        demos = Demonstrations(rng.normal(size=(40, 3)), rng.uniform(-2, 2, size=(40, 1)), [20, 20])
        model = CMZDRIL("MlpPolicy", "Pendulum-v1", demonstrations=demos, n_steps=32, batch_size=32,
                        ensemble_size=2, bc_pretrain_epochs=1, seed=0, device="cpu")
        try:
            model.pretrain(progress_bar=True)
        except MissingExtraError as e:
            print("PRETRAIN", e)
        print("CLI", main(["report", "nowhere"]))
        """
    )
    result = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr[-2000:]
    needs = "needs the 'experiments' extra: pip install 'sb3-cmzdril[experiments]'"
    assert f"PRETRAIN progress_bar=True {needs}" in result.stdout
    assert "CLI 2" in result.stdout
    assert f"sb3-cmzdril report: error: the sb3-cmzdril command line {needs}" in result.stderr


def test_require_extra_returns_the_module():
    assert require_extra("json", "experiments").dumps([1]) == "[1]"


def test_missing_module_names_the_extra(monkeypatch):
    monkeypatch.setitem(sys.modules, "ray", None)  # as if ray were not installed
    expected = r"^grid backend 'ray' needs the 'ray' extra: pip install 'sb3-cmzdril\[ray\]'$"
    with pytest.raises(MissingExtraError, match=expected):
        require_extra("ray", "ray", feature="grid backend 'ray'")
    assert issubclass(MissingExtraError, ImportError)  # `except ImportError` keeps working


def test_a_broken_installed_package_is_not_blamed_on_the_extra(tmp_path, monkeypatch):
    # The package is there but one of *its* imports fails: that error is the useful one.
    (tmp_path / "halfinstalled").mkdir()
    (tmp_path / "halfinstalled" / "__init__.py").write_text("import dependency_that_is_not_there_42\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    with pytest.raises(ModuleNotFoundError) as info:
        require_extra("halfinstalled", "experiments")
    assert not isinstance(info.value, MissingExtraError)
    assert info.value.name == "dependency_that_is_not_there_42"


def test_unknown_extra_is_a_caller_bug():
    with pytest.raises(ValueError, match="unknown extra 'plots'"):
        require_extra("json", "plots")
    assert "all" in EXTRAS and "test" in EXTRAS


def test_zoo_plugin_names_the_zoo_extra(monkeypatch):
    from sb3_cmzdril import zoo

    monkeypatch.setitem(sys.modules, "rl_zoo3", None)  # as if rl-zoo3 were not installed
    expected = r"sb3_cmzdril.zoo needs the 'zoo' extra: pip install 'sb3-cmzdril\[zoo\]'"
    with pytest.raises(MissingExtraError, match=expected):
        zoo.register()
