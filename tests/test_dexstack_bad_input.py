"""Bad input to the dexstack package: a clear Python exception (ValueError, or Gymnasium's own
error class where it defines one), the environment unchanged and still usable, never a crash."""
import gymnasium as gym
import numpy as np
import pytest

import dexstack
from conftest import ROOT

POLICY = ROOT / "policies" / "grasp.dxpl"


def fresh():
    env = gym.make("dexstack/Reach-v0")
    obs, _ = env.reset(seed=0)
    return env, obs


def assert_unchanged_and_usable(env, obs):
    """The failed call did not move the simulation: stepping now equals stepping a twin that never
    saw the bad input."""
    twin, twin_obs = fresh()
    assert np.array_equal(obs, twin_obs)
    a = np.full(9, 0.5, np.float32)
    assert np.array_equal(env.step(a)[0], twin.step(a)[0])


BAD_ACTIONS = [
    ("shape (8,)", np.zeros(8, np.float32), "shape"),
    ("shape (1, 9)", np.zeros((1, 9), np.float32), "shape"),
    ("scalar", 0.0, "shape"),
    ("complex", np.zeros(9, np.complex64), "dtype"),
    ("bool", np.zeros(9, bool), "dtype"),
    ("str", np.array(["a"] * 9), "dtype"),
    ("object", np.array([None] * 9, dtype=object), "dtype"),
    ("NaN", np.array([0, 0, 0, np.nan, 0, 0, 0, 0, 0], np.float32), r"action\[3\] = nan is not finite"),
    ("inf", np.array([0, 0, 0, 0, 0, 0, 0, 0, -np.inf], np.float32), r"action\[8\] = -inf"),
    ("f64 beyond f32", np.array([1e300] + [0] * 8, np.float64), r"action\[0\] = 1e\+300"),
    ("ragged", [[0.0], [1.0, 2.0]], "cannot be read|shape|dtype"),
]


@pytest.mark.parametrize("name,action,message", BAD_ACTIONS, ids=[b[0] for b in BAD_ACTIONS])
def test_bad_actions_raise_and_leave_the_env_usable(name, action, message):
    env, obs = fresh()
    with pytest.raises(ValueError, match=message) as err:
        env.step(action)
    assert isinstance(err.value, gym.error.InvalidAction) and isinstance(err.value, dexstack.InvalidAction)
    assert_unchanged_and_usable(env, obs)


def test_bad_actions_to_the_vector_env():
    vec = dexstack.VectorEnv(num_envs=2, task="reach")
    obs, _ = vec.reset(seed=0)
    for bad, message in [(np.zeros((3, 9), np.float32), "shape"), (np.zeros(9, np.float32), "shape"),
                         (np.zeros((2, 9), np.complex128), "dtype")]:
        with pytest.raises(ValueError, match=message):
            vec.step(bad)
    nan = np.zeros((2, 9), np.float32)
    nan[1, 4] = np.nan
    with pytest.raises(ValueError, match=r"action\[1, 4\] = nan"):
        vec.step(nan)
    # Nothing moved: the first good step equals that of a fresh vector env.
    twin = dexstack.VectorEnv(num_envs=2, task="reach")
    twin.reset(seed=0)
    a = np.full((2, 9), 0.3, np.float32)
    assert np.array_equal(vec.step(a)[0], twin.step(a)[0])


def test_step_before_reset():
    for env in [gym.make("dexstack/Grasp-v0"), dexstack.JacoEnv(task="grasp"), dexstack.VectorEnv(2, task="grasp")]:
        shape = env.action_space.shape
        with pytest.raises(gym.error.ResetNeeded):
            env.step(np.zeros(shape, np.float32))
        env.reset(seed=1)
        env.step(np.zeros(shape, np.float32))


def test_unknown_task_reward_start_and_options():
    with pytest.raises(gym.error.NameNotFound):
        gym.make("dexstack/Lift-v0")
    with pytest.raises(ValueError, match="unknown task `lift`"):
        dexstack.JacoEnv(task="lift")
    with pytest.raises(ValueError, match="unknown task"):
        dexstack.Demonstrator("lift")
    with pytest.raises(ValueError, match="unknown reward `dense`.*full-composite"):
        gym.make("dexstack/Stack-v0", reward="dense")
    with pytest.raises(ValueError, match="unknown start scheme `teleport`"):
        gym.make("dexstack/Stack-v0", start="teleport")
    with pytest.raises(ValueError, match=r"in-hand probability 1.5 is not in \[0, 1\]"):
        gym.make("dexstack/Stack-v0", start="mixture", in_hand_probability=1.5)
    for steps in [0, -3, 2.5, True]:
        with pytest.raises(ValueError, match="episode_steps"):
            gym.make("dexstack/Stack-v0", episode_steps=steps)
    with pytest.raises(ValueError, match="num_envs"):
        dexstack.VectorEnv(num_envs=0, task="reach")
    with pytest.raises(ValueError, match="unknown demonstrator kind"):
        dexstack.Demonstrator("reach", kind="oracle")
    env, obs = fresh()
    for options in [{"episode_seed": -1}, {"episode_seed": 2**64}, {"episode_seed": "1"}, {"seed": 1}]:
        with pytest.raises(ValueError):
            env.reset(options=options)
    with pytest.raises(TypeError):
        dexstack.Demonstrator("reach").act(object())


def test_corrupt_or_mismatched_policy_files(tmp_path, policies):
    good = POLICY.read_bytes()
    flipped = bytearray(good)
    flipped[len(good) // 2] ^= 0x40
    for name, data in [("empty", b""), ("garbage", b"not a policy file" * 10), ("truncated", good[:1000]),
                       ("flipped", bytes(flipped)), ("header only", good[:24])]:
        with pytest.raises(ValueError, match="policy"):
            dexstack.Policy(data)
        path = tmp_path / f"{name.replace(' ', '-')}.dxpl"
        path.write_bytes(data)
        with pytest.raises(ValueError):
            dexstack.Policy(path)
    with pytest.raises(ValueError, match="does not match the Jaco cell"):
        dexstack.Policy(policies["mismatched"])
    with pytest.raises(ValueError, match="is a grasp policy, not a stack one"):
        dexstack.Policy(POLICY, task="stack")
    with pytest.raises(FileNotFoundError):
        dexstack.Policy(tmp_path / "missing.dxpl")
    policy = dexstack.Policy(good)
    for obs, message in [(np.zeros(43, np.float32), "shape"), (np.zeros(44, np.complex64), "dtype"),
                         (np.full(44, np.nan, np.float32), "not finite")]:
        with pytest.raises(ValueError, match=message):
            policy.act(obs)
    a = policy.act(np.zeros(44, np.float32))
    assert a.shape == (9,) and a.dtype == np.float32 and np.all(np.abs(a) <= 1)
