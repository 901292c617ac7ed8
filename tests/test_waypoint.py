"""WaypointNav-v0 (our PyUXV stand-in) and its reactive expert."""
from __future__ import annotations

import math
import warnings
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest

import sb3_cmzdril  # noqa: F401  (registers the env)
from sb3_cmzdril.data.demos import Demonstrations
from sb3_cmzdril.envs.waypoint import POSITION_SLICE, WaypointField, WaypointNavEnv, obs_dim, obs_index
from sb3_cmzdril.envs.waypoint_expert import WaypointReactiveExpert

ENV_ID = "sb3_cmzdril:WaypointNav-v0"
# A RuntimeWarning (division by zero, NaN in sqrt) in the vectorised lidar is a bug: fail on it.
pytestmark = pytest.mark.filterwarnings("error::RuntimeWarning")


def make(**kwargs) -> gym.Env:
    return gym.make(ENV_ID, **kwargs)


def scene(env: gym.Env, centres=(), radii=(), start=(0.0, 0.0), goal=(5.0, 5.0), heading=0.0) -> np.ndarray:
    """Reset ``env`` on a hand-built field; returns the first observation."""
    f = WaypointField(np.array(centres, dtype=float).reshape(-1, 2), np.array(radii, dtype=float),
                      np.array(start, dtype=float), np.array(goal, dtype=float), heading)
    obs, _ = env.reset(options={"field": f})
    return obs


def run_expert(env: gym.Env, seed: int):
    expert = WaypointReactiveExpert.from_env(env)
    obs, _ = env.reset(seed=seed)
    observations, rewards, done = [obs], [], False
    while not done:
        action, _ = expert.predict(obs)
        obs, reward, terminated, truncated, info = env.step(action)
        observations.append(obs)
        rewards.append(reward)
        done = terminated or truncated
    return np.array(observations), np.array(rewards), info


def lidar_reference(env: WaypointNavEnv) -> np.ndarray:
    """Ranges / lidar_range by a plain loop over beams, obstacles and walls (the slow, obvious way)."""
    f, x, y, out = env.field, env._x, env._y, []
    for alpha in env.beam_angles:
        ux, uy = math.cos(env._heading + alpha), math.sin(env._heading + alpha)
        best = env.lidar_range
        for wall_t in ((env.half - x) / ux if ux > 0 else (-env.half - x) / ux if ux < 0 else math.inf,
                       (env.half - y) / uy if uy > 0 else (-env.half - y) / uy if uy < 0 else math.inf):
            best = min(best, wall_t)
        for (cx, cy), r in zip(f.centres, f.radii, strict=True):
            b = ux * (cx - x) + uy * (cy - y)
            disc = b * b - ((cx - x) ** 2 + (cy - y) ** 2 - r * r)
            if disc >= 0 and b - math.sqrt(disc) > 0:
                best = min(best, b - math.sqrt(disc))
        out.append(best / env.lidar_range)
    return np.array(out)


# -- API, checkers, registration ------------------------------------------------------------------
def test_make_spaces_and_layout():
    env = make()
    base = env.unwrapped
    assert isinstance(base, WaypointNavEnv)
    obs, info = env.reset(seed=3)
    assert obs.shape == (base.n_beams + 8,) == env.observation_space.shape == (obs_dim(base.n_beams),)
    assert obs.dtype == np.float32 and env.observation_space.contains(obs)
    assert env.action_space.shape == (2,) and np.all(env.action_space.low == -1) and np.all(env.action_space.high == 1)
    f, idx = base.field, obs_index(base.n_beams)
    np.testing.assert_allclose(obs[POSITION_SLICE], f.start / (base.arena_size / 2), rtol=1e-6)
    np.testing.assert_allclose(info["position"], f.start)
    assert obs[idx["heading_sin"]] == pytest.approx(math.sin(f.start_heading), abs=1e-6)
    assert obs[idx["heading_cos"]] == pytest.approx(math.cos(f.start_heading), abs=1e-6)
    assert obs[idx["goal_distance"]] == pytest.approx(np.linalg.norm(f.goal - f.start) / base.diagonal, rel=1e-5)
    assert obs[idx["speed"]] == 0.0
    assert env.spec.max_episode_steps is None  # the env truncates itself at max_steps


def test_gymnasium_and_sb3_checkers():
    from gymnasium.utils.env_checker import check_env as gym_check
    from stable_baselines3.common.env_checker import check_env as sb3_check

    env = make()
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # any checker warning fails the test
        gym_check(env.unwrapped)
        sb3_check(make().unwrapped, warn=True)


def test_registration_is_idempotent_and_expert_registered():
    import importlib

    import sb3_cmzdril.envs as envs
    from sb3_cmzdril.experts import SCRIPTED_EXPERTS

    importlib.reload(envs)  # a second registration attempt must be a no-op, not an error
    assert "WaypointNav-v0" in gym.registry
    factory = SCRIPTED_EXPERTS["waypoint-reactive"]
    expert = factory(make(n_beams=12))
    assert isinstance(expert, WaypointReactiveExpert) and expert.n_beams == 12


def test_make_kwargs_change_options():
    env = make(n_beams=7, n_obstacles=3, arena_size=30.0, max_steps=5, lidar_range=5.0)
    base = env.unwrapped
    obs, _ = env.reset(seed=0)
    assert obs.shape == (7 + 8,) and env.observation_space.shape == (15,)
    assert base.field.n_obstacles == 3 and base.arena_size == 30.0 and base.lidar_range == 5.0
    assert np.all(np.abs(base.field.centres) < 15.0)
    for t in range(5):
        _, _, terminated, truncated, _ = env.step(np.array([0.0, -1.0], dtype=np.float32))  # stand still
        assert not terminated and truncated == (t == 4)
    empty = make(n_obstacles=0)
    obs, _ = empty.reset(seed=1)
    assert obs.shape == (40,) and empty.unwrapped.field.n_obstacles == 0
    assert empty.step(np.zeros(2, dtype=np.float32))[0].shape == (40,)


@pytest.mark.parametrize("kwargs, match", [
    ({"n_beams": 0}, "n_beams"), ({"n_beams": 2.5}, "n_beams"), ({"n_obstacles": -1}, "n_obstacles"),
    ({"arena_size": 5.0}, "arena_size"), ({"max_steps": 0}, "max_steps"), ({"lidar_range": -1.0}, "lidar_range"),
    ({"max_speed": float("nan")}, "max_speed"), ({"max_speed": 20.0}, "pass through"),
    ({"render_mode": "human"}, "render_mode"),
])
def test_bad_options_raise(kwargs, match):
    with pytest.raises(ValueError, match=match):
        WaypointNavEnv(**kwargs)


def test_too_many_obstacles_is_a_clear_error():
    with pytest.raises(RuntimeError, match="could not place"):
        WaypointNavEnv(n_obstacles=60).reset(seed=0)


def test_bad_actions_and_order():
    env = WaypointNavEnv()
    with pytest.raises(RuntimeError, match="reset"):
        env.step(np.zeros(2))
    env.reset(seed=0)
    for bad in (np.zeros(3), np.zeros((1, 2)), [0.0]):
        with pytest.raises(ValueError, match="shape"):
            env.step(bad)
    with pytest.raises(ValueError, match="NaN"):
        env.step(np.array([np.nan, 0.0]))
    env.step([0.0, 5.0])  # plain lists work; out-of-range values are clipped like SB3 does
    assert env._speed == env.max_speed
    with pytest.raises(ValueError, match="unknown reset options"):
        env.reset(options={"n_beams": 3})
    with pytest.raises(ValueError, match="overlaps"):
        scene(env, centres=[(0.5, 0.0)], radii=[0.5])
    with pytest.raises(ValueError, match="inside the arena"):
        scene(env, start=(10.0, 0.0))


# -- scenes and sensing ---------------------------------------------------------------------------
def test_lidar_single_obstacle_and_walls():
    env = WaypointNavEnv(n_beams=8, lidar_range=8.0)  # beams every 45 degrees, beam 0 straight ahead
    # Heading 90 deg; obstacle of radius 1 whose near edge is 3 m away at body bearing +45 deg (beam 1).
    heading, bearing, gap, r = math.pi / 2, math.pi / 4, 3.0, 1.0
    c = (gap + r) * np.array([math.cos(heading + bearing), math.sin(heading + bearing)])
    obs = scene(env, centres=[c], radii=[r], start=(0.0, 0.0), heading=heading)
    lidar = obs[:8] * env.lidar_range
    assert lidar[1] == pytest.approx(gap, abs=1e-5)
    assert np.all(lidar[[0, 2, 3, 4, 5, 6, 7]] == pytest.approx(8.0))  # walls at 10 m are out of range
    # Walls: at (6, -8) heading 0, beam 0 sees x = 10 at 4 m, beam 6 (-90 deg) sees y = -10 at 2 m,
    # beam 7 (-45 deg) the corner region: min(4 / cos45, 2 / sin45) = 2 * sqrt(2).
    obs = scene(env, start=(6.0, -8.0), heading=0.0)
    lidar = obs[:8] * env.lidar_range
    assert lidar[0] == pytest.approx(4.0, abs=1e-5)
    assert lidar[6] == pytest.approx(2.0, abs=1e-5)
    assert lidar[7] == pytest.approx(2.0 * math.sqrt(2.0), abs=1e-5)
    assert lidar[2] == pytest.approx(8.0)  # +90 deg: wall 18 m away


def test_lidar_matches_reference_loop():
    env = WaypointNavEnv(n_beams=24, n_obstacles=10)
    rng = np.random.default_rng(0)
    for seed in range(5):
        env.reset(seed=seed)
        for _ in range(10):
            env.step(rng.uniform(-1, 1, size=2)) if not env._done else env.reset()
            np.testing.assert_allclose(env._ranges, lidar_reference(env), atol=1e-9)


def test_collision_goal_and_wall_termination():
    env = WaypointNavEnv()
    full = np.array([0.0, 1.0])
    # Obstacle edge 1 m ahead, full speed 0.25 m/step: after 3 steps the vehicle disc (radius 0.25)
    # touches it, after 4 it overlaps (contact is overlap, strictly).
    scene(env, centres=[(2.0, 0.0)], radii=[1.0], start=(0.0, 0.0), goal=(6.0, 0.0), heading=0.0)
    steps, terminated = 0, False
    while not terminated and steps < 10:
        _, reward, terminated, truncated, info = env.step(full)
        steps += 1
    assert steps == 4 and info["collision"] and not info["is_success"] and not info["out_of_bounds"]
    assert reward == pytest.approx(0.25 - env.time_penalty - env.crash_penalty)
    with pytest.raises(RuntimeError, match="ended"):
        env.step(full)
    # Goal 1 m ahead, goal radius 0.5: reached after 2 steps.
    scene(env, start=(0.0, 0.0), goal=(1.0, 0.0), heading=0.0)
    rewards = [env.step(full) for _ in range(2)]
    _, reward, terminated, _, info = rewards[-1]
    assert terminated and info["is_success"] and not info["collision"]
    assert reward == pytest.approx(0.25 - env.time_penalty + env.goal_bonus)
    # Wall: 1 m from the east wall heading east; the vehicle disc crosses it on step 4.
    scene(env, start=(9.0, 0.0), goal=(0.0, 0.0), heading=0.0)
    steps, terminated = 0, False
    while not terminated and steps < 10:
        obs, _, terminated, _, info = env.step(full)
        steps += 1
    assert steps == 4 and info["out_of_bounds"] and info["collision"]
    assert env.observation_space.contains(obs)
    # A fast vehicle ends a step beyond the wall or inside an obstacle: the terminal observation
    # still lies in the observation space (ranges clipped at 0, position at +-1).
    fast = WaypointNavEnv(max_speed=7.0)
    for start, centres in (((9.5, 0.0), []), ((0.0, 0.0), [(1.0, 0.0)])):
        scene(fast, centres=centres, radii=[0.5] * len(centres), start=start, goal=(-5.0, 0.0), heading=0.0)
        obs, _, terminated, _, info = fast.step(full)
        assert terminated and info["collision"] and fast.observation_space.contains(obs)


# -- determinism and the expert -------------------------------------------------------------------
def test_same_seed_same_field_and_expert_trajectory():
    env_a, env_b = make(), make()
    obs_a, rew_a, info_a = run_expert(env_a, seed=11)
    obs_b, rew_b, info_b = run_expert(env_b, seed=11)
    np.testing.assert_array_equal(obs_a, obs_b)
    np.testing.assert_array_equal(rew_a, rew_b)
    np.testing.assert_array_equal(env_a.unwrapped.field.centres, env_b.unwrapped.field.centres)
    env_b.reset(seed=12)
    assert not np.array_equal(env_a.unwrapped.field.centres, env_b.unwrapped.field.centres)
    # Replaying a field through reset options gives the same episode again.
    field = env_a.unwrapped.field
    expert = WaypointReactiveExpert.from_env(env_a)
    obs, _ = env_b.reset(options={"field": field})
    replay = [obs]
    for _ in range(len(obs_a) - 1):
        obs = env_b.step(expert.predict(obs)[0])[0]
        replay.append(obs)
    np.testing.assert_array_equal(np.array(replay), obs_a)


def test_shipped_demo_pool_replays_exactly():
    """The shipped pool's episodes come back to the bit from their reset seeds and recorded actions:
    the fields a seed draws, the lidar, the dynamics and the rewards are all unchanged."""
    pool = Path(__file__).resolve().parents[1] / "experts" / "WaypointNav-v0" / "demos.npz"
    demos = Demonstrations.load(pool)
    env = make()
    for i in range(demos.n_episodes):
        ep = demos.episode(i)
        obs, _ = env.reset(seed=ep["seed"])
        replay, rewards = [obs], []
        for t, action in enumerate(ep["actions"]):
            obs, reward, terminated, truncated, _ = env.step(action)
            last = t == len(ep["actions"]) - 1
            assert (terminated or truncated) == last, f"episode {i} ends at step {t}, recorded {len(ep['actions'])}"
            replay.append(obs)
            rewards.append(reward)
        np.testing.assert_array_equal(np.array(replay[:-1]), ep["observations"], err_msg=f"episode {i}")
        np.testing.assert_array_equal(np.array(rewards, dtype=np.float32), ep["rewards"], err_msg=f"episode {i}")


def test_waypoint_field_has_one_definition():
    from sb3_cmzdril.envs import WaypointField as from_package
    from sb3_cmzdril.envs.waypoint_field import WaypointField as from_module

    assert WaypointField is from_package is from_module


def test_expert_reaches_goal_and_return_telescopes():
    env = make()
    base = env.unwrapped
    for seed in range(4):
        obs, rewards, info = run_expert(env, seed)
        assert info["is_success"] and not info["collision"]
        assert 30 <= len(rewards) <= 150
        d0 = np.linalg.norm(base.field.goal - base.field.start)
        progress = base.progress_weight * (d0 - info["goal_distance"])
        expected = progress - base.time_penalty * len(rewards) + base.goal_bonus
        assert rewards.sum() == pytest.approx(expected, abs=1e-6)
        np.testing.assert_allclose(obs[:, POSITION_SLICE] * base.half, base.trajectory, atol=1e-5)


def test_expert_predict_shapes_and_observation_only():
    env = make(n_beams=16)
    expert = WaypointReactiveExpert.from_env(env)
    obs, _ = env.reset(seed=0)
    single, state = expert.predict(obs)
    assert single.shape == (2,) and single.dtype == np.float32 and state is None
    batch = np.stack([env.step(single)[0], obs, obs])
    actions, _ = expert.predict(batch, episode_start=np.zeros(3, bool), deterministic=True)
    assert actions.shape == (3, 2) and np.all(np.abs(actions) <= 1)
    np.testing.assert_array_equal(actions[1], single)
    np.testing.assert_array_equal(actions[0], expert.predict(batch[0])[0])
    with pytest.raises(ValueError, match="shape"):
        expert.predict(np.zeros(5))
    with pytest.raises(ValueError, match="NaN"):
        expert.predict(np.full_like(obs, np.nan))
    with pytest.raises(ValueError, match="WaypointNav"):
        WaypointReactiveExpert.from_env(gym.make("Pendulum-v1"))


def test_expert_turns_towards_clear_goal_and_around_blocker():
    env = WaypointNavEnv()
    expert = WaypointReactiveExpert.from_env(env)
    # Goal straight ahead, nothing in the way: no turn, full throttle.
    action, _ = expert.predict(scene(env, start=(-5.0, 0.0), goal=(5.0, 0.0), heading=0.0))
    assert action[0] == pytest.approx(0.0, abs=1e-6) and action[1] == pytest.approx(1.0)
    # An obstacle on the line to the goal: it steers off the line, keeping speed.
    action, _ = expert.predict(
        scene(env, centres=[(-2.0, 0.0)], radii=[1.0], start=(-5.0, 0.0), goal=(5.0, 0.0), heading=0.0)
    )
    assert abs(action[0]) > 0.5 and action[1] > 0.0


# -- rendering and plotting -----------------------------------------------------------------------
def test_render_rgb_array():
    env = make(render_mode="rgb_array")
    env.reset(seed=0)
    env.step(env.action_space.sample())
    frame = env.render()
    assert frame.shape == (400, 400, 3) and frame.dtype == np.uint8
    assert len(np.unique(frame.reshape(-1, 3), axis=0)) > 3
    assert make().unwrapped.metadata["render_modes"] == ["rgb_array"]


def test_plot_trajectories(tmp_path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from sb3_cmzdril.envs.plotting import plot_trajectories

    env = make()
    obs, _, _ = run_expert(env, seed=2)
    ax = plot_trajectories(env, {"expert": env.unwrapped.trajectory, "agent (obs)": obs[:, -2:]}, normalised=False)
    ax2 = plot_trajectories(env.unwrapped.field, {"expert": obs[:, -2:]}, normalised=True)
    assert len(ax.lines) >= 4 and len(ax2.lines) >= 3
    ax.figure.savefig(tmp_path / "paths.png")
    assert (tmp_path / "paths.png").stat().st_size > 1000
    with pytest.raises(ValueError, match=r"\(T, 2\)"):
        plot_trajectories(env, {"bad": np.zeros((3, 3))})
    plt.close("all")


def test_expert_drives_a_vec_env():
    from stable_baselines3.common.env_util import make_vec_env

    venv = make_vec_env(ENV_ID, n_envs=3, seed=0)
    expert = WaypointReactiveExpert.from_env(venv.envs[0])
    obs = venv.reset()
    successes = 0
    for _ in range(120):
        actions, _ = expert.predict(obs)
        assert actions.shape == (3, 2)
        obs, _, dones, infos = venv.step(actions)
        successes += sum(bool(info["is_success"]) for info, done in zip(infos, dones, strict=True) if done)
    assert successes >= 3
    venv.close()
