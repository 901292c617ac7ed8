"""BC against CMZ-DRIL beyond flat vectors: one image-observation task, one Dict-observation task.

    python benchmarks/studies/spaces_learning.py [--trials 3] [--timesteps 20000] [--n-demos 5,10]
        [--eval-episodes 30] [--output docs/spaces_learning.md]

The task, defined here: a point on an 8x8 grid must walk to a goal cell. Start and goal are drawn
from the reset seed; actions are Discrete(4) (up, down, left, right); reaching the goal pays 1 and
ends the episode, every other step costs 0.02, and an episode is cut at 24 steps. So a return near 1
is a quick success, below 0 a failure, and the success rate is the share of episodes reaching the
goal. Two views of the same task:

- ``image``: a (2, 16, 16) uint8 image, channel 0 the agent's cell and channel 1 the goal's (2x2
  pixels a cell), learned with ``CnnPolicy`` and a small features extractor (SB3's NatureCNN needs 36
  pixels a side): ``--image-extractor keypoints`` (default) ends in a spatial softmax that outputs
  image coordinates, ``small`` is the earlier flatten-and-linear CNN (see :class:`SmallCNN`);
- ``dict``: ``{"position": Box(0, 1, (2,)), "goal": Box(0, 1, (2,))}`` (cell coordinates / 7), learned
  with ``MultiInputPolicy``.

The expert is scripted: step along the axis with the larger distance to the goal (x on a tie).
For each task, demo count K of ``--n-demos`` and trial t: record K expert episodes (reset seeds
``1000 * t + i``), build a CMZDRIL model (seed t, CMZDRIL's defaults otherwise, PPO with 4 envs x
256 steps), ``pretrain()`` it (NLL behaviour cloning to the early stop, the ensemble fit): that
policy is BC, evaluated; then ``learn(--timesteps)`` from it on the CMZ-DRIL reward, evaluated again.
Evaluation: ``--eval-episodes`` episodes with reset seeds 100000+ (disjoint from every demo's),
deterministic actions, the env's true return and success rate; the scripted expert and uniform random
actions on the same seeds are the references. One process, one torch thread.

With the image task, the script also answers "is it the data or the image path?":
what the policy sees (pixel values of the demos and of the env, after SB3's preprocessing, and the
env's wrapper), and a supervised check: each extractor's policy cloned for ``--check-epochs`` epochs on
all steps of trial 0's demos (no early stop), its action accuracy on those steps and on
``CHECK_EPISODES`` new expert episodes (reset seeds 50000+). ``--no-check`` skips it.
"""
from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import torch as th
from gymnasium import spaces
from stable_baselines3.common.env_util import make_vec_env
from stable_baselines3.common.preprocessing import is_image_space_channels_first, preprocess_obs
from stable_baselines3.common.torch_layers import BaseFeaturesExtractor

from sb3_cmzdril import CMZDRIL, Demonstrations
from sb3_cmzdril.io import atomic_write_text, command_line
from sb3_cmzdril.policies import standardized_keys

ROOT = Path(__file__).resolve().parents[2]
GRID = 8
CELL_PX = 2
HORIZON = 3 * GRID
STEP_COST = 0.02
#: action -> (dx, dy): up, down, left, right
MOVES = np.array([[0, -1], [0, 1], [-1, 0], [1, 0]])
EVAL_SEED = 100_000
#: the supervised check's held-out expert episodes (reset seeds CHECK_SEED..)
CHECK_SEED = 50_000
CHECK_EPISODES = 100
#: (view, image extractor, demos) of the supervised check: each extractor from the benchmark's 10 demos,
#: the Dict view as the reference, and 10 times the data
CHECK_ROWS = [
    ("image", "small", 10),
    ("image", "keypoints", 10),
    ("dict", "keypoints", 10),
    ("image", "small", 100),
    ("image", "keypoints", 100),
]
TASKS = ("image", "dict")
#: (observation, the env acted in, a random generator) -> action
Policy = Callable[[Any, "GoalGrid", np.random.Generator], int]


class GoalGrid(gym.Env):
    """Walk to the goal cell; observed as an image or as a Dict of coordinates."""

    def __init__(self, view: str = "image") -> None:
        if view not in TASKS:
            raise ValueError(f"view must be one of {TASKS}, got {view!r}")
        self.view = view
        side = GRID * CELL_PX
        if view == "image":
            self.observation_space: spaces.Space = spaces.Box(0, 255, (2, side, side), np.uint8)
        else:
            coord = spaces.Box(0.0, 1.0, (2,), np.float32)
            self.observation_space = spaces.Dict({"position": coord, "goal": coord})
        self.action_space = spaces.Discrete(len(MOVES))
        self.agent = np.zeros(2, np.int64)
        self.goal = np.zeros(2, np.int64)
        self._t = 0

    def reset(self, *, seed: int | None = None, options: dict | None = None) -> tuple[Any, dict]:
        super().reset(seed=seed)
        cells = self.np_random.choice(GRID * GRID, size=2, replace=False)
        self.agent = np.array(divmod(int(cells[0]), GRID))
        self.goal = np.array(divmod(int(cells[1]), GRID))
        self._t = 0
        return self._obs(), {}

    def step(self, action: Any) -> tuple[Any, float, bool, bool, dict]:
        self.agent = np.clip(self.agent + MOVES[int(action)], 0, GRID - 1)
        self._t += 1
        at_goal = bool(np.array_equal(self.agent, self.goal))
        reward = 1.0 if at_goal else -STEP_COST
        return self._obs(), reward, at_goal, self._t >= HORIZON and not at_goal, {"is_success": at_goal}

    def _obs(self) -> Any:
        if self.view == "dict":
            scale = np.float32(GRID - 1)
            return {"position": self.agent.astype(np.float32) / scale, "goal": self.goal.astype(np.float32) / scale}
        image = np.zeros((2, GRID * CELL_PX, GRID * CELL_PX), np.uint8)
        for channel, (x, y) in enumerate((self.agent, self.goal)):
            image[channel, y * CELL_PX : (y + 1) * CELL_PX, x * CELL_PX : (x + 1) * CELL_PX] = 255
        return image


def expert_action(env: GoalGrid) -> int:
    """The scripted expert: close the larger gap first (x on a tie)."""
    dx, dy = env.goal - env.agent
    if abs(dx) >= abs(dy):
        return 3 if dx > 0 else 2
    return 1 if dy > 0 else 0


class SmallCNN(BaseFeaturesExtractor):
    """Two 3x3 stride-2 convolutions and a linear layer: NatureCNN's role for 16-pixel images.

    The extractor of the first version of this benchmark (``--image-extractor small``). The flatten and
    linear layer must learn every (agent cell, goal cell) pair on its own: from 10 demos it fits every
    demo step and picks the expert's action on new states at about chance (the supervised check)."""

    def __init__(self, observation_space: spaces.Box, features_dim: int = 64) -> None:
        super().__init__(observation_space, features_dim)
        channels = int(observation_space.shape[0])
        self.cnn = th.nn.Sequential(
            th.nn.Conv2d(channels, 16, 3, stride=2, padding=1),
            th.nn.ReLU(),
            th.nn.Conv2d(16, 32, 3, stride=2, padding=1),
            th.nn.ReLU(),
            th.nn.Flatten(),
        )
        with th.no_grad():
            n_flat = int(self.cnn(th.zeros(1, *observation_space.shape)).shape[1])
        self.linear = th.nn.Sequential(th.nn.Linear(n_flat, features_dim), th.nn.ReLU())

    def forward(self, observations: th.Tensor) -> th.Tensor:
        return self.linear(self.cnn(observations))


class KeypointCNN(BaseFeaturesExtractor):
    """Two 3x3 stride-1 convolutions, then a spatial softmax: each of ``n_keypoints`` feature maps
    becomes the expected (x, y) image coordinate of its activation (Levine et al. 2016, "End-to-end
    training of deep visuomotor policies"). Where things are, not which pixels are lit, is what
    the features carry, so the head sees coordinates as the Dict view's does."""

    def __init__(self, observation_space: spaces.Box, n_keypoints: int = 8) -> None:
        super().__init__(observation_space, 2 * n_keypoints)
        channels, height, width = (int(d) for d in observation_space.shape)
        self.cnn = th.nn.Sequential(
            th.nn.Conv2d(channels, 16, 3, padding=1),
            th.nn.ReLU(),
            th.nn.Conv2d(16, n_keypoints, 3, padding=1),
        )
        ys, xs = th.meshgrid(th.linspace(-1, 1, height), th.linspace(-1, 1, width), indexing="ij")
        self.register_buffer("xs", xs.reshape(-1))
        self.register_buffer("ys", ys.reshape(-1))

    def forward(self, observations: th.Tensor) -> th.Tensor:
        attention = self.cnn(observations).flatten(2).softmax(-1)  # (B, K, H * W)
        return th.cat([attention @ self.xs, attention @ self.ys], dim=1)


IMAGE_EXTRACTORS: dict[str, type[BaseFeaturesExtractor]] = {"keypoints": KeypointCNN, "small": SmallCNN}


def record_demos(view: str, seeds: list[int]) -> Demonstrations:
    """One expert episode per reset seed."""
    env = GoalGrid(view)
    episodes = []
    for seed in seeds:
        obs, _ = env.reset(seed=seed)
        observations, actions = [], []
        done = False
        while not done:
            action = expert_action(env)
            observations.append(obs)
            actions.append(action)
            obs, _, terminated, truncated, _ = env.step(action)
            done = terminated or truncated
        stacked: Any = np.stack(observations) if view == "image" else {
            k: np.stack([o[k] for o in observations]) for k in observations[0]
        }
        episodes.append({"observations": stacked, "actions": np.array(actions, np.int64)})
    return Demonstrations.from_episodes(episodes)


def evaluate(view: str, policy: Policy, n_episodes: int) -> dict[str, float]:
    """Mean true return and success rate (on the goal at the last step) over the evaluation seeds."""
    env = GoalGrid(view)
    returns, successes = [], []
    rng = np.random.default_rng(0)
    for i in range(n_episodes):
        obs, _ = env.reset(seed=EVAL_SEED + i)
        total, done = 0.0, False
        info: dict[str, Any] = {}
        while not done:
            obs, reward, terminated, truncated, info = env.step(policy(obs, env, rng))
            total += reward
            done = terminated or truncated
        returns.append(total)
        successes.append(bool(info["is_success"]))
    return {"return": float(np.mean(returns)), "success": float(np.mean(successes))}


def make_model(view: str, demos: Demonstrations, seed: int, image_extractor: str = "keypoints") -> CMZDRIL:
    venv = make_vec_env(GoalGrid, n_envs=4, seed=seed, env_kwargs={"view": view})
    if view == "image":
        policy = "CnnPolicy"
        extractor = IMAGE_EXTRACTORS[image_extractor]
        policy_kwargs: dict[str, Any] = {"features_extractor_class": extractor, "net_arch": [64]}
    else:
        policy, policy_kwargs = "MultiInputPolicy", {"net_arch": [64, 64]}
    return CMZDRIL(
        policy, venv, demonstrations=demos, n_steps=256, batch_size=64, policy_kwargs=policy_kwargs, seed=seed
    )


def model_policy(model: CMZDRIL) -> Policy:
    def act(obs: Any, _env: GoalGrid, _rng: np.random.Generator) -> int:
        action, _ = model.predict(obs, deterministic=True)
        return int(action)

    return act


def run_trial(view: str, n_demos: int, trial: int, args: argparse.Namespace) -> dict[str, Any]:
    demos = record_demos(view, [1000 * trial + i for i in range(n_demos)])
    start = time.perf_counter()
    model = make_model(view, demos, seed=trial, image_extractor=args.image_extractor)
    model.pretrain()
    bc = evaluate(view, model_policy(model), args.eval_episodes)
    bc_seconds = time.perf_counter() - start
    model.learn(args.timesteps)
    cmz = evaluate(view, model_policy(model), args.eval_episodes)
    row = {
        "trial": trial,
        "demo_steps": len(demos),
        "bc": bc,
        "cmz": cmz,
        "bc_epochs": int(model.pretrain_info.get("bc_epochs", -1)),
        "seconds": time.perf_counter() - start,
        "bc_seconds": bc_seconds,
    }
    print(
        f"{view}, {n_demos} demos, trial {trial}: BC {bc['return']:.2f} ({bc['success']:.0%}), "
        f"CMZ-DRIL {cmz['return']:.2f} ({cmz['success']:.0%}), {row['seconds']:.0f} s",
        flush=True,
    )
    return row


def action_accuracy(model: CMZDRIL, demos: Demonstrations) -> float:
    """Share of the demo steps on which the policy's most likely action is the expert's."""
    obs: Any = demos.observations
    device = model.policy.device
    tensors = {k: th.as_tensor(v, device=device) for k, v in obs.items()} if isinstance(obs, dict) else (
        th.as_tensor(obs, device=device)
    )
    with th.no_grad():
        dist: Any = model.policy.get_distribution(tensors).distribution
        chosen = dist.probs.argmax(1).cpu().numpy()
    return float(np.mean(chosen == demos.actions.reshape(-1)))


def supervised_check(view: str, extractor: str, n_demos: int, epochs: int) -> dict[str, Any]:
    """Clone trial 0's ``n_demos`` demos for ``epochs`` epochs on every step (no early stop: can the
    policy fit them at all?) and score its action accuracy on them and on new expert episodes."""
    demos = record_demos(view, list(range(n_demos)))
    model = make_model(view, demos, seed=0, image_extractor=extractor)
    model.demonstrations = demos.check_spaces(model.observation_space, model.action_space)
    for standardizer in model._standardizers():  # what pretrain() does first (Box parts of the Dict)
        standardizer.fit(model.demonstrations.observations)
    model.bc.set_demonstrations(model.demonstrations)
    start = time.process_time()
    nll = model.bc.train(epochs)
    held_out = record_demos(view, list(range(CHECK_SEED, CHECK_SEED + CHECK_EPISODES)))
    return {
        "view": view,
        "extractor": extractor if view == "image" else "MultiInputPolicy",
        "n_demos": n_demos,
        "steps": len(demos),
        "train_nll": nll[-1],
        "train_acc": action_accuracy(model, demos),
        "held_out_acc": action_accuracy(model, held_out),
        "held_out_steps": len(held_out),
        "cpu_seconds": time.process_time() - start,
    }


def preprocessing_check() -> dict[str, str]:
    """What the image policy is fed: the demos' and the env's pixel values, what SB3's preprocessing
    turns them into, and the env's wrapper (VecTransposeImage would mean a channel-order change)."""
    demos = record_demos("image", list(range(10)))
    model = make_model("image", demos, seed=0)
    assert model.env is not None
    env_obs: Any = model.env.reset()
    demo_obs: Any = demos.check_spaces(model.observation_space, model.action_space).observations
    seen: Any = preprocess_obs(th.as_tensor(demo_obs), model.observation_space, model.policy.normalize_images)
    values = lambda a: "{" + ", ".join(f"{v:g}" for v in np.unique(np.asarray(a))) + "}"  # noqa: E731
    return {
        "demo": f"{demo_obs.shape[1:]} {demo_obs.dtype}, values {values(demo_obs)}",
        "env": f"{env_obs.shape[1:]} {env_obs.dtype}, values {values(env_obs)}",
        "policy": f"{seen.dtype}, values {values(seen.numpy())} (normalize_images={model.policy.normalize_images})",
        "wrapper": type(model.get_env()).__name__,
        "channels_first": str(is_image_space_channels_first(model.observation_space)),  # type: ignore[arg-type]
        "standardized": str(standardized_keys(model.observation_space)),
    }


def check_section(checks: list[dict[str, Any]], seen: dict[str, str], epochs: int) -> str:
    """The generated part of docs/spaces_learning.md on the image view: data or image path."""
    lines = [
        "## The image view: data or image path",
        "",
        "What the image policy is fed (trial 0, 10 demos):",
        "",
        f"- demo observations: {seen['demo']}; the env's: {seen['env']}",
        f"- after SB3's `preprocess_obs`, as the policy sees both: {seen['policy']}",
        f"- the env's wrapper: {seen['wrapper']} (channel-first: {seen['channels_first']}, so SB3 adds no "
        "VecTransposeImage, and the demos go in the same channel order); the parts `DemoStandardizer` "
        f"standardises: {seen['standardized']} (images are left to SB3's scaling)",
        "",
        f"Supervised check: the policy cloned by the package's NLL behaviour cloning for {epochs} epochs on every",
        "step of trial 0's demos (no early stop), then its most likely action compared with the expert's on",
        f"those steps and on {CHECK_EPISODES} new expert episodes (reset seeds {CHECK_SEED}..). Same policy",
        "head (net_arch [64] for images, [64, 64] for the Dict) as in the tables below.",
        "",
        "| view | extractor | demos (steps) | train NLL | train accuracy | held-out accuracy (steps) | CPU (s) |",
        "|---|---|---|---|---|---|---|",
    ]
    for c in checks:
        lines.append(
            f"| {c['view']} | {c['extractor']} | {c['n_demos']} ({c['steps']}) | {c['train_nll']:.3f} | "
            f"{c['train_acc']:.0%} | {c['held_out_acc']:.0%} ({c['held_out_steps']}) | {c['cpu_seconds']:.0f} |"
        )
    return "\n".join(lines)


def fmt(result: dict[str, float]) -> str:
    return f"{result['return']:.2f} | {result['success']:.0%}"


def task_table(
    view: str, n_demos: int, rows: list[dict[str, Any]], expert: dict[str, float], random: dict[str, float]
) -> str:
    policy = "CnnPolicy, (2, 16, 16) uint8" if view == "image" else "MultiInputPolicy, Dict position/goal"
    lines = [
        f"**{view}, {n_demos} demos** ({policy})",
        "",
        "| | BC return | BC success | CMZ-DRIL return | CMZ-DRIL success | demo steps | BC epochs | run time (s) |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for row in rows:
        lines.append(
            f"| trial {row['trial']} | {fmt(row['bc'])} | {fmt(row['cmz'])} | "
            f"{row['demo_steps']} | {row['bc_epochs']} | {row['seconds']:.0f} |"
        )
    mean = {m: {k: float(np.mean([r[m][k] for r in rows])) for k in ("return", "success")} for m in ("bc", "cmz")}
    std = {m: float(np.std([r[m]["return"] for r in rows])) for m in ("bc", "cmz")}
    lines += [
        f"| **mean over {len(rows)} trials** (return std) | **{mean['bc']['return']:.2f}** ({std['bc']:.2f}) | "
        f"**{mean['bc']['success']:.0%}** | **{mean['cmz']['return']:.2f}** ({std['cmz']:.2f}) | "
        f"**{mean['cmz']['success']:.0%}** | | | |",
        f"| expert (scripted) | {fmt(expert)} | | | | | |",
        f"| random actions | {fmt(random)} | | | | | |",
    ]
    above = sum(r["cmz"]["return"] > r["bc"]["return"] for r in rows)
    below = sum(r["cmz"]["return"] < r["bc"]["return"] for r in rows)
    lines += [
        "",
        f"CMZ-DRIL's return above BC's in {above}, below in {below} of {len(rows)} trials; mean difference "
        f"{mean['cmz']['return'] - mean['bc']['return']:+.2f}.",
    ]
    return "\n".join(lines)


IMAGE_EXTRACTOR_TEXT = {
    "keypoints": "`KeypointCNN`: two 3x3 stride-1 convolutions to 8 feature maps, then a spatial softmax that "
    "gives each map's expected (x, y) image coordinate, 16 features (`--image-extractor keypoints`)",
    "small": "`SmallCNN`: two 3x3 stride-2 convolutions, flattened, a linear layer to 64 features "
    "(`--image-extractor small`)",
}


def render_doc(command: str, tables: str, args: argparse.Namespace, minutes: float, check: str = "") -> str:
    """docs/spaces_learning.md: what ran, how to rerun it, the numbers as measured."""
    check = f"\n{check}\n" if check else ""
    return f"""# Learning beyond flat vectors: an image task and a Dict task

Written by `{command}` ({minutes:.1f} min of wall time, one process, one torch thread, on a 2-core
machine shared with other jobs).

## The task

A point on an {GRID}x{GRID} grid must walk to a goal cell. Start and goal come from the reset seed;
actions are Discrete(4) (up, down, left, right); reaching the goal pays 1 and ends the episode, every
other step costs {STEP_COST}, and an episode is cut at {HORIZON} steps. So a return near 1 is a quick
success, below 0 a failure (-{STEP_COST * HORIZON:.2f} at worst); *success* is reaching the goal.

- **image**: a (2, 16, 16) uint8 image, channel 0 the agent's cell, channel 1 the goal's (2x2 pixels a
  cell); `CnnPolicy` with a small features extractor (SB3's NatureCNN needs 36 pixels a side):
  {IMAGE_EXTRACTOR_TEXT[args.image_extractor]}; net_arch [64]. The ensemble uses its own small CNN trunk.
- **dict**: `{{"position": Box(0, 1, (2,)), "goal": Box(0, 1, (2,))}}` (cell / {GRID - 1});
  `MultiInputPolicy`, net_arch [64, 64]; the policy's inputs are standardised with the demos' statistics
  (CMZDRIL's default, on the Box parts).

Expert: scripted, closes the larger gap first (x on a tie). Per task, demo count K
({", ".join(map(str, args.n_demos))}) and trial t: K expert episodes (reset seeds 1000t .. 1000t+K-1)
are the demonstrations; a
CMZDRIL model (seed t, CMZDRIL's defaults: alpha 10, g 0.99, 5 members, NLL pretraining to the early
stop, one BC epoch after every update; PPO with 4 envs x 256 steps, batch 64, PPO's other defaults) is
pretrained: that policy is **BC** and is evaluated; the same model then learns {args.timesteps:,} PPO
steps on the CMZ-DRIL reward and is evaluated again (**CMZ-DRIL**). Evaluation: {args.eval_episodes}
episodes with reset seeds {EVAL_SEED}.. (disjoint from every demo's), deterministic actions, the env's
true return. The expert and uniform random actions are evaluated on the same seeds.

Why 5 and 10 demonstrations (the default) and not 1-3: in a pilot run (Dict task, 2 trials, 10,000
steps, 20 evaluation episodes, same seeds) 3 demos (20-23 steps) left BC at 15% success (random
actions: 5%) and CMZ-DRIL below it (0% and 5%). `--n-demos` sets the counts.
{check}
## Results

Return: mean over the {args.eval_episodes} evaluation episodes; success: share of them ending on the goal.
Run time: the trial's pretraining, training and evaluations.

{tables}
"""


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--trials", type=int, default=3)
    parser.add_argument("--timesteps", type=int, default=20_000, help="PPO steps of CMZ-DRIL after pretraining")
    parser.add_argument("--n-demos", default="5,10", help="comma-separated demo counts (expert episodes per trial)")
    parser.add_argument("--eval-episodes", type=int, default=30)
    parser.add_argument("--tasks", default=",".join(TASKS), help=f"comma-separated, from {TASKS}")
    parser.add_argument("--output", type=Path, default=ROOT / "docs" / "spaces_learning.md")
    parser.add_argument(
        "--image-extractor", choices=sorted(IMAGE_EXTRACTORS), default="keypoints", help="the image policy's extractor"
    )
    parser.add_argument("--check-epochs", type=int, default=300, help="BC epochs of the supervised check")
    parser.add_argument("--no-check", action="store_true", help="skip the image view's data-or-path check")
    args = parser.parse_args(argv)
    tasks = [t for t in args.tasks.split(",") if t]
    try:
        args.n_demos = [int(n) for n in args.n_demos.split(",")]
    except ValueError:
        parser.error(f"--n-demos must be comma-separated integers, got {args.n_demos!r}")
    for name, value in (("--trials", args.trials), ("--timesteps", args.timesteps), ("--n-demos", min(args.n_demos))):
        if value < 1:
            parser.error(f"{name} must be at least 1, got {value}")
    if args.eval_episodes < 1:
        parser.error(f"--eval-episodes must be at least 1, got {args.eval_episodes}")
    if not tasks or set(tasks) - set(TASKS):
        parser.error(f"--tasks must name some of {TASKS}, got {args.tasks!r}")
    if args.check_epochs < 1:
        parser.error(f"--check-epochs must be at least 1, got {args.check_epochs}")
    th.set_num_threads(1)

    arguments = sys.argv[1:] if argv is None else argv
    command = command_line(["python", "benchmarks/studies/spaces_learning.py", *arguments])
    start = time.perf_counter()
    check = ""
    if "image" in tasks and not args.no_check:
        checks = [
            supervised_check(view, extractor, n, args.check_epochs)
            for view, extractor, n in CHECK_ROWS
        ]
        check = check_section(checks, preprocessing_check(), args.check_epochs)
        print(check, flush=True)
    sections = []
    for view in tasks:
        expert = evaluate(view, lambda _o, env, _r: expert_action(env), args.eval_episodes)
        random = evaluate(view, lambda _o, _a, rng: int(rng.integers(len(MOVES))), args.eval_episodes)
        for n_demos in args.n_demos:
            rows = [run_trial(view, n_demos, t, args) for t in range(args.trials)]
            sections.append(task_table(view, n_demos, rows, expert, random))
    minutes = (time.perf_counter() - start) / 60
    tables = "\n\n".join(sections)
    print(tables)
    atomic_write_text(args.output, render_doc(command, tables, args, minutes, check))
    print(f"wrote {args.output} ({minutes:.1f} min)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
