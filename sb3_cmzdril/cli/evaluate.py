"""The ``evaluate`` command: a model against expert episodes, with the episodes, env_kwargs and
VecNormalize statistics of the model's run folder where it has them."""
from __future__ import annotations

from sb3_cmzdril.errors import MissingFileError, UserError


def add_evaluate(sub) -> None:
    p = sub.add_parser(
        "evaluate",
        help="replay expert episodes' starts with a model: return, Fréchet distance and action MSE per episode",
        description=(
            "Evaluate a model zip (a run's model.zip, CMZDRIL's or CMZDRILSAC's, or any SB3 model such as an "
            "expert) against expert episodes: each episode's reset seed is replayed with the model's "
            "deterministic actions and compared with the expert's path (discrete Fréchet distance) and actions (MSE). "
            "The demo pool, env_kwargs and VecNormalize statistics are taken from the model's run folder "
            "(config.json, vecnormalize.pkl) when it has them."
        ),
    )
    p.add_argument("--model", required=True, help="model zip")
    p.add_argument("--env", required=True, help="environment id")
    p.add_argument(
        "--demos",
        default=None,
        help="demonstrations npz (default: the demo pool in config.json beside the model, "
        "else experts/<EnvName>/demos.npz)",
    )
    p.add_argument(
        "--episodes",
        default=None,
        help="comma-separated episode indices of the demos file (default: for a run's model, the run's "
        "held-out eval_episodes of its config.json; otherwise all)",
    )
    p.add_argument(
        "--env-kwargs",
        default=None,
        help='e.g. "dict(max_steps=200)" (default: env_kwargs of config.json beside the model, if any)',
    )
    p.add_argument(
        "--vecnormalize",
        default=None,
        help="VecNormalize statistics (default: vecnormalize.pkl beside the model, if any; required for a run "
        "that normalised)",
    )
    p.set_defaults(func=_run_evaluate)


def _run_evaluate(args) -> int:
    from pathlib import Path

    from sb3_cmzdril.experts import check_env_id, load_demonstrations
    from sb3_cmzdril.experts.loading import note_code_on_load
    from sb3_cmzdril.hyperparams import parse_env_kwargs
    from sb3_cmzdril.metrics import evaluate_against_expert
    from sb3_cmzdril.metrics.evaluation import make_env
    from sb3_cmzdril.training.run_folder import CONFIG_FILE
    from sb3_cmzdril.training.runs import load_evaluation_model
    from sb3_cmzdril.training.spec import default_demos_path

    check_env_id(args.env)
    model_path = Path(args.model)
    if not model_path.is_file():
        raise MissingFileError(f"model file not found: {model_path}")
    _check_model_zip(model_path)
    # A run folder's config.json knows how the model was trained and evaluated.
    run_config = _run_config(model_path.parent / CONFIG_FILE)
    if args.env_kwargs is not None:
        env_kwargs = parse_env_kwargs(args.env_kwargs)
    else:
        env_kwargs = run_config.get("env_kwargs") or {}
    make_env(args.env, env_kwargs).close()  # kwargs the env does not take: one line now, not a traceback later
    demos_path = Path(args.demos or run_config.get("demos") or default_demos_path(args.env))
    demos = load_demonstrations(demos_path)
    indices, which = _evaluation_episodes(args.episodes, demos.n_episodes, demos_path, run_config)
    vecnormalize, vecnormalize_note = _evaluation_statistics(args.vecnormalize, model_path, run_config)
    selected = demos.select(indices)
    print(f"episodes {','.join(map(str, indices))} of {demos_path}: {which}")
    if vecnormalize_note:  # before it is loaded: a pickle the user may not have named
        print(vecnormalize_note)
    note_code_on_load()
    model, transform = load_evaluation_model(model_path, args.env, env_kwargs, vecnormalize)
    result = evaluate_against_expert(model, args.env, selected, obs_transform=transform, env_kwargs=env_kwargs or None)

    from rich.console import Console
    from rich.table import Table

    table = Table(title=f"{model_path} on {args.env}: {selected.n_episodes} episodes of {demos_path}")
    for column in ("episode", "seed", "return", "expert return", "Fréchet", "action MSE", "length"):
        table.add_column(column, justify="right")
    for row, index in enumerate(indices):
        table.add_row(
            str(index),
            str(int(result.seeds[row])),
            f"{result.returns[row]:.2f}",
            f"{result.expert_returns[row]:.2f}",
            f"{result.frechet[row]:.4g}",
            f"{result.episode_action_mse[row]:.4g}",
            str(int(result.lengths[row])),
        )
    table.add_section()
    table.add_row(
        "mean",
        "",
        f"{result.mean_return:.2f} ± {result.std_return:.2f}",
        f"{float(result.expert_returns.mean()):.2f}",
        f"{result.mean_frechet:.4g}",
        f"{result.action_mse:.4g}",
        f"{result.mean_length:.1f}",
    )
    Console().print(table)
    return 0


#: config.json entries ``evaluate`` reads, with the JSON type each must have (None: absent).
_CONFIG_TYPES: dict[str, tuple[type, str]] = {
    "env_kwargs": (dict, "an object"),
    "demos": (str, "a path"),
    "demos_sha256": (str, "a string"),
    "eval_episodes": (list, "a list of episode indices"),
    "hyperparams_values": (dict, "an object"),
}


def _run_config(path) -> dict:
    """The run's config.json beside the model ({} when there is none), checked entry by entry: a
    hand-edited file must fail here with its name, not as a traceback deep in the evaluation."""
    from sb3_cmzdril.io import read_json

    if not path.is_file():
        return {}
    config = read_json(path)  # a JSON object, or a ValueError naming the file
    for key, (kind, what) in _CONFIG_TYPES.items():
        value = config.get(key)
        if value is not None and not isinstance(value, kind):
            raise UserError(f"{path}: {key} must be {what}, got {value!r}")
    held_out = config.get("eval_episodes") or []
    if not all(isinstance(i, int) and not isinstance(i, bool) for i in held_out):
        raise UserError(f"{path}: eval_episodes must be a list of episode indices, got {held_out!r}")
    return config


def _check_model_zip(path) -> None:
    """A model zip as SB3 writes it (its ``data`` entry a JSON object), else a ValueError naming the
    model file (the loaders that follow would call it an expert's or report a bare zip error)."""
    import json
    import zipfile

    try:
        with zipfile.ZipFile(path) as zf:
            data = json.loads(zf.read("data").decode("utf-8"))
    except (zipfile.BadZipFile, KeyError, ValueError, OSError) as e:
        raise UserError(f"model file {path} is corrupt, truncated or not an SB3 model zip: {e}") from None
    if not isinstance(data, dict):
        raise UserError(f"model file {path} is not an SB3 model zip: its data entry is not a JSON object")


def _evaluation_episodes(text: str | None, n_pool: int, demos_path, run_config: dict):
    """``(episode indices, how they were chosen)`` for ``evaluate``.

    Without ``--episodes``, a run's model is evaluated on the run's held-out episodes only: its
    training episodes would flatter it. They are indices into the run's pool, so they are used only
    on that very file (same path and sha256).
    """
    from pathlib import Path

    from sb3_cmzdril.io import file_sha256

    if text:
        try:
            indices = [int(i) for i in text.split(",") if i.strip()]
        except ValueError:
            raise UserError(f"--episodes must be comma-separated integers, got {text!r}") from None
        bad = [i for i in indices if not 0 <= i < n_pool]
        if bad or not indices:
            raise UserError(f"--episodes {text}: {demos_path} has {n_pool} episodes, numbered 0 to {n_pool - 1}")
        return indices, "as asked (--episodes)"
    held_out = run_config.get("eval_episodes")
    if held_out and run_config.get("demos") and Path(run_config["demos"]).resolve() == Path(demos_path).resolve():
        if run_config.get("demos_sha256") not in (None, file_sha256(demos_path)):
            raise UserError(
                f"{demos_path} changed since the run was trained (sha256 differs from its config.json): its held-out "
                "episodes cannot be told apart; pass --episodes"
            )
        bad = [i for i in held_out if not 0 <= i < n_pool]
        if bad:
            raise UserError(
                f"eval_episodes {bad} of the run's config.json are not episodes of {demos_path} ({n_pool} episodes, "
                f"numbered 0 to {n_pool - 1}); pass --episodes"
            )
        return [int(i) for i in held_out], "the run's held-out episodes (eval_episodes of its config.json)"
    note = " (not the run's demo pool: no held-out split applies)" if held_out else ""
    return list(range(n_pool)), f"all {n_pool} episodes{note}"


def _evaluation_statistics(path: str | None, model_path, run_config: dict):
    """``(VecNormalize statistics file or None, a line saying which)`` for ``evaluate``.

    A policy trained on normalised observations and fed raw ones acts nonsensically, and its
    numbers would still print: a missing --vecnormalize file is an error, statistics beside the
    model are used (and said so), and a run whose config.json says it normalised needs them.
    """
    from pathlib import Path

    from sb3_cmzdril.training.run_folder import VECNORMALIZE_FILE

    if path is not None:
        if not Path(path).is_file():
            raise MissingFileError(f"VecNormalize statistics not found: {path}")
        return Path(path), f"observations normalised with {path} (--vecnormalize)"
    beside = Path(model_path).parent / VECNORMALIZE_FILE
    if beside.is_file():
        return beside, f"observations normalised with {beside}, found beside the model"
    if _normalises_observations((run_config.get("hyperparams_values") or {}).get("normalize")):
        raise MissingFileError(
            f"{model_path} was trained on VecNormalize'd observations (normalize in its config.json) but {beside} "
            "is missing; pass the statistics with --vecnormalize"
        )
    return None, None


def _normalises_observations(normalize) -> bool:
    """Whether a zoo ``normalize`` entry (True, a dict, or its string form) normalises observations."""
    from sb3_cmzdril.hyperparams import safe_eval

    if isinstance(normalize, str):
        normalize = safe_eval(normalize)
    if isinstance(normalize, dict):
        return bool(normalize.get("norm_obs", True))
    return bool(normalize)


__all__ = ["add_evaluate"]
