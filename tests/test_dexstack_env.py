"""The four Gymnasium ids of the dexstack package: registration, spaces, Gymnasium's env checker,
seeding, the time limit and the options (reward, start scheme, episode length)."""
import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import dexstack

IDS = ["dexstack/Reach-v0", "dexstack/Grasp-v0", "dexstack/StackInHand-v0", "dexstack/Stack-v0"]


@pytest.mark.parametrize("env_id", IDS)
def test_check_env_passes(env_id):
    env = gym.make(env_id)
    check_env(env.unwrapped, skip_render_check=True)
    env.close()


def test_spaces_are_float32_with_the_real_bounds():
    env = gym.make("dexstack/Grasp-v0")
    obs_space, act_space = env.observation_space, env.action_space
    assert obs_space.shape == (44,) and obs_space.dtype == np.float32
    assert act_space.shape == (9,) and act_space.dtype == np.float32
    assert np.all(act_space.low == -1) and np.all(act_space.high == 1)
    # sin, cos (0..12) and the two quaternions (27..31, 34..38) are in [-1, 1]; the rest unbounded.
    unit = np.zeros(44, dtype=bool)
    unit[0:12] = unit[27:31] = unit[34:38] = True
    assert np.all(obs_space.low[unit] == -1) and np.all(obs_space.high[unit] == 1)
    assert np.all(np.isinf(obs_space.low[~unit])) and np.all(np.isinf(obs_space.high[~unit]))


def test_seeding_follows_gymnasium():
    env = gym.make("dexstack/Reach-v0")
    a, ia = env.reset(seed=5)
    b, ib = env.reset(seed=5)
    c, ic = env.reset()  # continues the generator seeded with 5
    d, _ = env.reset(seed=6)
    assert a.dtype == np.float32 and np.array_equal(a, b) and ia["episode_seed"] == ib["episode_seed"]
    assert not np.array_equal(a, c) and not np.array_equal(a, d)
    # The episode seed is the Rust start seed: resetting to it directly gives the same start.
    e, ie = env.reset(options={"episode_seed": int(ic["episode_seed"])})
    assert np.array_equal(c, e) and ie["episode_seed"] == ic["episode_seed"]
    # Same seed and actions: same episode.
    def run(seed):
        env.reset(seed=seed)
        rng = np.random.default_rng(0)
        return [env.step(rng.uniform(-1, 1, 9).astype(np.float32)) for _ in range(5)]
    for (o1, r1, *_), (o2, r2, *_) in zip(run(9), run(9)):
        assert np.array_equal(o1, o2) and r1 == r2


def test_time_limit_truncates_and_info_has_the_predicates():
    env = gym.make("dexstack/Reach-v0")
    obs, info = env.reset(seed=0)
    assert set(info) >= {"episode_seed", "start", "success", "reach", "grasp", "stack"}
    assert info["start"] == "original"
    for t in range(1, 51):
        obs, reward, terminated, truncated, info = env.step(env.action_space.sample())
        assert terminated is False and truncated == (t == 50), t
        assert set(info) == {"success", "reach", "grasp", "stack"}
        assert isinstance(reward, float) and isinstance(info["success"], bool)
        assert info["success"] == info["reach"]  # Reach's success is the reach predicate
    with pytest.raises(gym.error.ResetNeeded):
        env.step(env.action_space.sample())
    env.reset()
    env.step(env.action_space.sample())  # usable again


def test_options_reward_start_and_episode_length():
    env = gym.make("dexstack/Grasp-v0", reward="full-composite", episode_steps=7)
    assert env.unwrapped.reward_name == "full-composite" and env.unwrapped.episode_steps == 7
    env.reset(seed=1)
    rewards = []
    for t in range(7):
        _, r, _, truncated, _ = env.step(np.zeros(9, np.float32))
        rewards.append(r)
    assert truncated and all(0 < r < 0.125 for r in rewards)  # 0.125 r_S1: far from the brick
    assert gym.make("dexstack/Grasp-v0").unwrapped.reward_name == "sparse-grasp"
    assert gym.make("dexstack/Reach-v0").unwrapped.episode_steps == 50
    demo = gym.make("dexstack/Stack-v0", start="along-demonstrations")
    assert demo.unwrapped.episode_steps == 50
    _, info = demo.reset(seed=3)
    assert info["start"] == "demonstration"
    k, n = info["demonstration_steps"]
    assert 1 <= k <= n <= 150
    mix = gym.make("dexstack/Stack-v0", start="mixture", in_hand_probability=1.0)
    _, info = mix.reset(seed=3)
    assert info["start"] == "in-hand"
    assert "full-composite" in dexstack.reward_names()


def test_demonstrator_solves_reach_through_a_wrapper():
    env = gym.make("dexstack/Reach-v0")
    demo = dexstack.Demonstrator("reach")
    env.reset(seed=11)
    truncated = False
    while not truncated:
        _, _, _, truncated, info = env.step(demo.act(env))
    assert info["success"]


def test_markov_demonstrator_and_unquantised_policy():
    env = dexstack.JacoEnv(task="reach")
    demo = dexstack.Demonstrator("Reach", kind="markov")
    env.reset(seed=12)
    truncated = False
    while not truncated:
        _, _, _, truncated, info = env.step(demo.act(env))
    assert info["success"]
    obs, _ = gym.make("dexstack/Grasp-v0").reset(seed=0)
    from conftest import ROOT
    exact = dexstack.Policy(ROOT / "policies" / "grasp.dxpl", can_quantisation=False).act(obs)
    can = dexstack.Policy(ROOT / "policies" / "grasp.dxpl").act(obs)
    assert exact.shape == can.shape == (9,) and np.abs(exact - can).max() < 0.05
    # ... but not equal: the CAN quantisation (of the observation and the action) did something.
    assert np.any(exact != can), "CAN quantisation left every action component unchanged"
