"""The native vector environment (N Rust environments stepped on threads, GIL released) against
Gymnasium's SyncVectorEnv over N single dexstack environments: the same observations, rewards,
flags and infos, bit for bit, through several next-step autoresets."""
import gymnasium as gym
import numpy as np
import pytest

import dexstack

N = 3


def assert_same_infos(a, b):
    assert set(a) == set(b), (sorted(a), sorted(b))
    for key in a:
        if isinstance(a[key], dict):
            assert_same_infos(a[key], b[key])
        else:
            x, y = np.asarray(a[key]), np.asarray(b[key])
            assert x.dtype == y.dtype and np.array_equal(x, y), (key, x, y)


@pytest.mark.parametrize("reward", [None, "full-composite"])
def test_native_vector_env_equals_sync_vector_env(reward):
    kwargs = {"episode_steps": 6, **({"reward": reward} if reward else {})}
    native = gym.make_vec("dexstack/Grasp-v0", num_envs=N, vectorization_mode="vector_entry_point", **kwargs)
    sync = gym.make_vec("dexstack/Grasp-v0", num_envs=N, vectorization_mode="sync", **kwargs)
    assert isinstance(native.unwrapped, dexstack.VectorEnv) and native.unwrapped.threads >= 1
    assert native.metadata["autoreset_mode"] == sync.metadata["autoreset_mode"]
    assert native.observation_space == sync.observation_space
    assert native.action_space == sync.action_space
    (o1, i1), (o2, i2) = native.reset(seed=42), sync.reset(seed=42)
    assert np.array_equal(o1, o2)
    assert_same_infos(i1, i2)
    rng = np.random.default_rng(1)
    resets = 0
    for t in range(20):  # 6-step episodes: three autoresets per environment
        actions = rng.uniform(-1.2, 1.2, (N, 9)).astype(np.float32)
        a, b = native.step(actions), sync.step(actions)
        for x, y in zip(a[:4], b[:4]):
            assert x.dtype == y.dtype and np.array_equal(x, y), t
        assert_same_infos(a[4], b[4])
        resets += int(a[4].get("_episode_seed", np.zeros(N, bool)).sum())
    assert resets == 2 * N
    native.close()
    sync.close()


def test_native_vector_env_equals_single_envs_and_reseeds():
    vec = dexstack.VectorEnv(num_envs=2, task="reach", episode_steps=4, threads=2)
    singles = [dexstack.JacoEnv(task="reach", episode_steps=4) for _ in range(2)]
    obs, _ = vec.reset(seed=[7, 9])
    for k, (env, s) in enumerate(zip(singles, [7, 9])):
        o, _ = env.reset(seed=s)
        assert np.array_equal(obs[k], o)
    pending = [False, False]
    rng = np.random.default_rng(3)
    for t in range(9):
        actions = rng.uniform(-1, 1, (2, 9)).astype(np.float32)
        o, r, term, trunc, _ = vec.step(actions)
        for k, env in enumerate(singles):
            if pending[k]:
                ok, _ = env.reset()
                rk, tk = 0.0, False
                pending[k] = False
            else:
                ok, rk, _, tk, _ = env.step(actions[k])
                pending[k] = tk
            assert np.array_equal(o[k], ok) and r[k] == rk and trunc[k] == tk and not term[k], (t, k)
    # Same seed again: the same first observations.
    again, _ = vec.reset(seed=[7, 9])
    assert np.array_equal(again, obs)
