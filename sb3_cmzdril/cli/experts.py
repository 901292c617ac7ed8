"""The expert commands: ``train-expert`` (an SB3 expert, resumable) and ``collect-demos`` (a demo pool)."""
from __future__ import annotations


def add_train_expert(sub) -> None:
    p = sub.add_parser(
        "train-expert",
        help="train an SB3 expert (SAC by default) with rl-zoo hyperparameters; resumable",
        description=(
            "Train an expert with rl-zoo-style hyperparameters (the shipped hyperparams/<algo>.yml "
            "unless --hyperparams is given). The best model by periodic deterministic evaluation is "
            "OUTPUT/model.zip; OUTPUT/metadata.json records how it was made. Checkpoints go to "
            "OUTPUT/checkpoints/; running the same command again resumes from the last one and trains "
            "until --timesteps in total. An existing expert is never replaced without --force."
        ),
    )
    p.add_argument("--env", required=True, help="environment id (anything gym.make accepts)")
    p.add_argument("--algo", default="sac", help="sac (default), td3, ddpg, ppo, a2c or dqn")
    p.add_argument(
        "--timesteps", type=int, default=None, help="total training steps (default: n_timesteps from the YAML)"
    )
    p.add_argument("--seed", type=int, default=0)
    p.add_argument(
        "--hyperparams", default=None, help="zoo-format YAML (default: the shipped hyperparams/<algo>.yml)"
    )
    p.add_argument("-o", "--output", default=None, help="output folder (default: experts/<EnvId>)")
    p.add_argument("--eval-freq", type=int, default=10_000, help="evaluate every N steps (default 10000)")
    p.add_argument("--eval-episodes", type=int, default=5, help="episodes per periodic evaluation (default 5)")
    p.add_argument("--final-eval-episodes", type=int, default=10, help="episodes of the final evaluation (default 10)")
    p.add_argument("--checkpoint-freq", type=int, default=20_000, help="checkpoint every N steps (default 20000)")
    p.add_argument("--threads", type=int, default=1, help="torch threads (default 1)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar / progress lines")
    p.add_argument("-v", "--verbose", type=int, default=0, help="SB3 verbosity (0, 1 or 2)")
    p.add_argument(
        "--force",
        action="store_true",
        help="train even where OUTPUT holds an expert without checkpoints (replacing it), or a finished "
        "one with fewer steps than --timesteps (continuing it)",
    )
    p.set_defaults(func=_run_train_expert)


def _run_train_expert(args) -> int:
    from sb3_cmzdril.experts import command_line, train_expert

    path = train_expert(
        args.env,
        algo=args.algo,
        timesteps=args.timesteps,
        seed=args.seed,
        hyperparams_path=args.hyperparams,
        output_dir=args.output,
        eval_freq=args.eval_freq,
        n_eval_episodes=args.eval_episodes,
        checkpoint_freq=args.checkpoint_freq,
        progress_bar=not args.no_progress,
        final_eval_episodes=args.final_eval_episodes,
        n_threads=args.threads,
        command=command_line(),
        verbose=args.verbose,
        force=args.force,
    )
    print(path)
    return 0


def add_collect_demos(sub) -> None:
    p = sub.add_parser(
        "collect-demos",
        help="record deterministic expert episodes into a demonstrations npz",
        description=(
            "Run an expert deterministically for K episodes (episode i reset with seed S+i) and save "
            "observations, actions, rewards and seeds; OUTPUT.json beside OUTPUT.npz records how the pool was "
            "made. --expert is an SB3 or sb3-contrib model zip (any algorithm; older SB3 zips that pickle gym "
            "load too; a CMZDRIL run's model.zip too), a folder holding model.zip, an RL Zoo "
            "agent's folder (<Env>.zip with <Env>/config.yml and vecnormalize.pkl: the expert sees "
            "normalised observations, the pool records raw ones), a Hugging Face Hub agent hf://ORG/REPO "
            "(e.g. hf://sb3/sac-Walker2d-v3; the hub extra), the env id of a shipped expert "
            "(HalfCheetah-v5), or the name of a registered scripted expert. Model zips and pickles can run "
            "code when loaded: use only experts you trust."
        ),
    )
    p.add_argument(
        "--expert",
        required=True,
        help="model zip, folder with model.zip, RL Zoo agent folder, hf://ORG/REPO, shipped expert's env id, "
        "or scripted expert name",
    )
    p.add_argument("--env", required=True, help="environment id")
    p.add_argument("--episodes", type=int, default=1, help="number of episodes (default 1)")
    p.add_argument("--seed", type=int, default=0, help="reset seed of the first episode (default 0)")
    p.add_argument(
        "-o", "--output", required=True,
        help="output pool NAME.npz (its record goes to NAME.json beside it; neither may be an expert's file)",
    )
    p.add_argument(
        "--env-kwargs",
        default=None,
        help='keyword arguments of gym.make, recorded with the pool; the runs that train on it need the same '
        'env_kwargs in their YAML entry (e.g. "dict(continuous=True)" for LunarLander-v3)',
    )
    p.add_argument(
        "--force",
        action="store_true",
        help="replace an existing OUTPUT and its record OUTPUT.json",
    )
    p.set_defaults(func=_run_collect_demos)


def _run_collect_demos(args) -> int:
    from sb3_cmzdril.experts import collect_demos
    from sb3_cmzdril.hyperparams import parse_env_kwargs

    env_kwargs = None if args.env_kwargs is None else parse_env_kwargs(args.env_kwargs)
    collect_demos(args.expert, args.env, n_episodes=args.episodes, seed=args.seed, output=args.output,
                  env_kwargs=env_kwargs, force=args.force)
    return 0


__all__ = ["add_collect_demos", "add_train_expert"]
