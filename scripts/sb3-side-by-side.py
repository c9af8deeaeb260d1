"""Our learner side by side with Stable-Baselines3 on the dexstack environments (issue #14).

Run through scripts/sb3-side-by-side.sh, which makes the throwaway venv (.venv-sb3, or VENV=...: CPU
torch, stable-baselines3, onnx + onnxscript, dm_control, matplotlib and the dexstack wheel) and runs
everything in order.
Subcommands, each one process, one learner thread:

    speed  --steps N                       env steps/s: dexstack (one env, VectorEnv N=2) for Grasp
                                           and Stack beside dm_control's lift_brick_features and
                                           stack_2_bricks_features, random actions, this process
    sb3    --algo sac|td3 --task reach|grasp --transitions N [--variant default|zoo] --out DIR
                                           trains SB3 on dexstack, evaluates the deterministic policy
                                           every --eval-every transitions on the 30 selection starts of
                                           `trainer train` (episode seeds from 2,000,000), keeps the
                                           best, then evaluates the last and the best on the 100 starts
                                           of `trainer eval` (episode seeds from 1,000,000)
                                           and (issue #31) exports the best and the last actor to
                                           ONNX, imports them as best.dxpl / last.dxpl and runs
                                           `trainer eval` on the same 100 starts, with and without
                                           the CAN quantisation (see export-onnx)
    export-onnx --algo td3|sac --model ZIP --task T --out DIR [--python-eval --reward R]
                                           the same for an existing SB3 zip (an old run): the
                                           deterministic actor through `torch.onnx.export`,
                                           `dexstack.Policy.from_onnx`, DIR/NAME.onnx, DIR/NAME.dxpl,
                                           `trainer eval`; adds success_NAME_runtime... to
                                           DIR/result.json when there is one (else DIR/NAME-runtime.json)
    ours   --out DIR -- TRAINER-ARGS...    runs `trainer train TRAINER-ARGS --quiet --out DIR`, times
                                           its selection lines (the same 30 starts), then `trainer
                                           eval` of the exported policy.dxpl on the same 100 starts
    plot   RUNS...                         success against transitions and against wall-clock
    table  RUNS...                         the learning table (markdown)

Every run folder gets curve.csv (transitions, wall_s, cpu_s, success on the 30 starts) and
result.json (final success over 100 starts, wall and CPU seconds, uptime's load before and after).

SB3 through the runtime (issue #31): `export_actor` wraps `model.policy.actor` in a module whose
forward is the deterministic action in [-1, 1] (TD3: `actor(obs)`; SAC: `actor(obs,
deterministic=True)`, the tanh of the Gaussian's mean), written as the actor's own layers so that
neither SB3's `obs.float()` (a `Cast` the importer refuses, kept by the TorchScript exporter) nor
SAC's distribution objects (which the torch.export-based exporter cannot convert) are traced; it
checks the wrapper against those SB3 calls, exports with `torch.onnx.export` (the default,
torch.export-based exporter, which needs `onnxscript`, with `external_data=False`: by default it
writes the weights into a side file, which the importer refuses; `dynamo=False`, the TorchScript
exporter, when onnxscript is missing), imports the model with `dexstack.Policy.from_onnx`, records
the largest difference of the runtime's actions from the wrapper's on 1,000 observations (a warning
above 1e-4; f32 against f32, ~1e-5 seen), and runs `trainer eval
NAME.dxpl --episodes 100 --seed 1000000 --threads 1` with and without the CAN quantisation.
`trainer eval` uses the task's default reward (Reach: sparse-reach), so only success is compared
with the Python evaluation (the same predicate at the last step, the same starts); with
`--actions` it prints each episode's outcome and writes every command, so the two are also
compared start by start and step by step (result.json: *_same_outcome_starts, *_action_*).
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import re
import resource
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
TRAINER = Path(os.environ.get("TRAINER", ROOT / "target" / "release" / "trainer"))
SELECTION_SEED = 2_000_000  # trainer::train_run::SELECTION_SEED: the checkpoint selection's starts
EVAL_SEED = 1_000_000  # `trainer eval --seed`'s default
TASK_IDS = {"reach": "Reach", "grasp": "Grasp", "stack": "Stack", "stack-in-hand": "StackInHand"}


def load() -> str:
    return Path("/proc/loadavg").read_text().split()[0] if Path("/proc/loadavg").exists() else "?"


def cpu_self() -> float:
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


def cpu_children() -> float:
    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


# ---------------------------------------------------------------- environment speed


def cmd_speed(a) -> None:
    # The two bench scripts have dashes in their names: load them by path.
    import importlib.util

    def by_path(name, file):
        spec = importlib.util.spec_from_file_location(name, ROOT / "scripts" / file)
        mod = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(mod)
        return mod

    bench_dex = by_path("bench_dexstack", "bench-dexstack.py")
    bench_dmc = by_path("bench_dm_control", "bench-dm-control.py")
    rows = []
    for task in a.tasks.split(","):
        l0 = load()
        one = bench_dex.single(task, a.steps)
        vec = bench_dex.vector(task, a.steps, 2)
        rows.append({"env": f"dexstack {task}", "one_env_steps_per_s": round(one, 1),
                     "vector_n2_steps_per_s": round(vec, 1), "load": l0})
        print(json.dumps(rows[-1]), flush=True)
    for name in a.dm_control.split(","):
        l0 = load()
        r = bench_dmc.bench(name, a.steps)
        r["load"] = l0
        rows.append(r)
        print(json.dumps(r), flush=True)
    write_json(Path(a.out), {"steps": a.steps, "rows": rows, "date": now()})


# ---------------------------------------------------------------- SB3


def sb3_kwargs(algo: str, variant: str, n_actions: int) -> dict:
    """Hyperparameters: SB3's defaults (TD3 with SB3's documented Gaussian action noise 0.1, since
    its default is no noise at all), or the zoo's settings for its robotic-arm tasks (FetchReach /
    parking in hyperparams/her.yml: gamma 0.95, lr 1e-3, batch 256, 1,000 warm-up steps, 256-256-256,
    TD3 noise 0.2), without HER (the dexstack tasks are not goal-conditioned)."""
    import numpy as np
    from stable_baselines3.common.noise import NormalActionNoise

    kw: dict = {}
    if variant == "zoo":
        kw.update(gamma=0.95, learning_rate=1e-3, batch_size=256, learning_starts=1000,
                  policy_kwargs={"net_arch": [256, 256, 256]})
    if algo == "td3":
        sigma = 0.2 if variant == "zoo" else 0.1
        kw["action_noise"] = NormalActionNoise(np.zeros(n_actions), sigma * np.ones(n_actions))
    return kw


def evaluate(model, env, seed: int, episodes: int) -> tuple[float, float]:
    """Success rate and mean return of the deterministic policy from episodes 0..n of `seed` (the
    starts `trainer eval --seed seed` uses); success is the predicate at the last step."""
    outcomes = evaluate_episodes(model, env, seed, episodes)
    return (sum(ok for _, ok in outcomes) / episodes, sum(r for r, _ in outcomes) / episodes)


def evaluate_episodes(model, env, seed: int, episodes: int,
                      actions: list | None = None) -> list[tuple[float, bool]]:
    """(return, success) of each episode i, started from `dexstack.episode_seed(seed, i)`: the
    start `trainer eval --seed seed` gives its episode i (`dex_env::seeds::episode_seed`, the one
    definition both use). With `actions`, each episode's [steps, 9] actions are appended to it."""
    import numpy as np

    import dexstack

    out = []
    for i in range(episodes):
        obs, _ = env.reset(options={"episode_seed": dexstack.episode_seed(seed, i)})
        truncated, ret, trace = False, 0.0, []
        while not truncated:
            action, _ = model.predict(obs, deterministic=True)
            trace.append(action)
            obs, reward, _, truncated, info = env.step(action)
            ret += reward
        out.append((ret, bool(info["success"])))
        if actions is not None:
            actions.append(np.asarray(trace, dtype=np.float32))
    return out


def cmd_sb3(a) -> None:
    import numpy as np
    import torch

    torch.set_num_threads(1)
    import gymnasium as gym
    import dexstack
    from stable_baselines3 import SAC, TD3
    from stable_baselines3.common.callbacks import BaseCallback

    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    env_id = f"dexstack/{TASK_IDS[a.task]}-v0"
    # Issue #27's protocol check: training episodes may start along the demonstrator's trajectories
    # and be cut short; evaluation always runs from the task's original starts at its full length.
    train_kw = {"start": a.start} if a.start != "original" else {}
    if a.episode_steps is not None:
        train_kw["episode_steps"] = a.episode_steps
    env = gym.make(env_id, reward=a.reward, **train_kw)
    eval_env = gym.make(env_id, reward=a.reward)
    algo = {"sac": SAC, "td3": TD3}[a.algo]
    kw = sb3_kwargs(a.algo, a.variant, env.action_space.shape[0])
    model = algo("MlpPolicy", env, seed=a.seed, device="cpu", verbose=0, **kw)
    record = {"learner": f"SB3 {a.algo.upper()} ({a.variant})", "task": a.task, "reward": a.reward,
              "start": a.start, "train_episode_steps": a.episode_steps,
              "transitions": a.transitions, "seed": a.seed, "torch": torch.__version__,
              "torch_threads": torch.get_num_threads(), "load_before": load(),
              "hyperparameters": {k: (v if k != "action_noise" else repr(v)) for k, v in kw.items()},
              "net_arch": str(model.policy.net_arch) if hasattr(model.policy, "net_arch") else None}
    rows: list[dict] = []
    best = {"success": -1.0, "ret": -1e300}
    t0, c0 = time.perf_counter(), cpu_self()
    eval_s = [0.0]

    def log_eval(n: int) -> None:
        te = time.perf_counter()
        s, r = evaluate(model, eval_env, SELECTION_SEED, a.eval_starts)
        eval_s[0] += time.perf_counter() - te
        rows.append({"transitions": n, "wall_s": round(time.perf_counter() - t0, 2),
                     "train_wall_s": round(time.perf_counter() - t0 - eval_s[0], 2),
                     "cpu_s": round(cpu_self() - c0, 2), "success": s, "mean_return": round(r, 4),
                     "load": load()})
        print(json.dumps(rows[-1]), flush=True)
        write_csv(out / "curve.csv", rows)  # as it goes: a run cut short keeps its curve
        if (s, r) > (best["success"], best["ret"]):
            best.update(success=s, ret=r, transitions=n)
            model.save(out / "best.zip")

    class Every(BaseCallback):
        def _on_step(self) -> bool:
            if self.num_timesteps % a.eval_every == 0:
                log_eval(self.num_timesteps)
            return True

    model.learn(total_timesteps=a.transitions, callback=Every())
    wall, cpu = time.perf_counter() - t0, cpu_self() - c0
    model.save(out / "last.zip")
    write_csv(out / "curve.csv", rows)
    last_actions: list = []
    best_actions: list = []
    last_eps = evaluate_episodes(model, eval_env, EVAL_SEED, a.final_episodes, last_actions)
    best_model = algo.load(out / "best.zip", device="cpu")
    best_eps = evaluate_episodes(best_model, eval_env, EVAL_SEED, a.final_episodes, best_actions)
    record.update({
        "wall_s": round(wall, 1), "cpu_s": round(cpu, 1), "eval_wall_s": round(eval_s[0], 1),
        "load_after": load(), "final_episodes": a.final_episodes, "final_seed": EVAL_SEED,
        "success_last": rate(last_eps), "success_best": rate(best_eps),
        "success_last_ci95": wilson(last_eps), "success_best_ci95": wilson(best_eps),
        "best_transitions": best["transitions"], "first_90": first_at(rows, 0.9),
    })
    write_json(out / "result.json", record)
    # Issue #31: the same two policies exported, imported and run by the runtime on the same starts.
    if not a.no_runtime:
        for name, m, eps, acts in (("best", best_model, best_eps, best_actions),
                                   ("last", model, last_eps, last_actions)):
            record.update(runtime_eval(m, a.algo, a.task, out, name, a.final_episodes, eps, acts))
            write_json(out / "result.json", record)
    print(json.dumps(record), flush=True)


# ---------------------------------------------------------------- SB3 through the runtime (#31)


def deterministic_actor(policy, algo: str):
    """A module whose forward is the deterministic action in [-1, 1] of an SB3 actor: TD3's
    `actor(obs)`, SAC's `actor(obs, deterministic=True)` (`SquashedDiagGaussianDistribution.mode`:
    the tanh of the Gaussian's mean), written as the actor's layers (see the module docs)."""
    import torch

    actor = policy.actor
    if algo == "sac" and getattr(actor, "use_sde", False):
        raise SystemExit("SAC with gSDE: its deterministic action is not tanh(mu); not supported")

    class DeterministicActor(torch.nn.Module):
        def __init__(self):
            super().__init__()
            self.actor = actor

        def forward(self, obs):
            features = self.actor.features_extractor(obs)  # FlattenExtractor: nn.Flatten
            if algo == "td3":
                return self.actor.mu(features)  # ..., Linear, Tanh
            return torch.tanh(self.actor.mu(self.actor.latent_pi(features)))

    return DeterministicActor().eval()


def export_actor(policy, algo: str, path: Path) -> dict:
    """Exports the deterministic actor of an SB3 policy to `path` (ONNX, batch axis dynamic);
    returns which exporter wrote it and the wrapper's largest difference from SB3's own calls."""
    import numpy as np
    import torch

    wrapper = deterministic_actor(policy, algo)
    n_obs = policy.observation_space.shape[0]
    check = torch.as_tensor(np.random.default_rng(0).normal(0, 1, (256, n_obs)), dtype=torch.float32)
    with torch.no_grad():
        ours = wrapper(check)
        sb3 = policy.actor(check) if algo == "td3" else policy.actor(check, deterministic=True)
    diff_sb3 = float((ours - sb3).abs().max())
    if diff_sb3 > 1e-6:
        raise SystemExit(f"the export wrapper differs from SB3's actor by {diff_sb3}")
    example = torch.zeros(1, n_obs, dtype=torch.float32)  # [1, 44]; the batch axis is dynamic
    names = {"input_names": ["obs"], "output_names": ["action"]}
    path.parent.mkdir(parents=True, exist_ok=True)
    try:
        # torch >= 2.9's default: the torch.export-based exporter (needs onnxscript). It writes
        # the weights into a side file (NAME.onnx.data) unless told not to; the importer wants
        # them inside. Its dynamic axes are `dynamic_shapes` (keyed by forward's argument).
        import onnxscript

        with torch.no_grad():
            torch.onnx.export(wrapper, (example,), str(path), external_data=False,
                              dynamic_shapes={"obs": {0: torch.export.Dim("batch")}}, **names)
        exporter = f"torch.onnx.export (default, torch.export-based; onnxscript {onnxscript.__version__})"
    except ModuleNotFoundError as e:
        print(f"default ONNX exporter unavailable ({e}); using dynamo=False", flush=True)
        with torch.no_grad():
            torch.onnx.export(wrapper, (example,), str(path), dynamo=False,
                              dynamic_axes={"obs": {0: "batch"}, "action": {0: "batch"}}, **names)
        exporter = "torch.onnx.export(dynamo=False) (TorchScript)"
    return {"exporter": exporter, "torch": torch.__version__, "wrapper_vs_sb3_max_abs": diff_sb3}


RUNTIME_EVAL = re.compile(r"(\d+)/(\d+) = ([\d.]+)% \(95% CI ([\d.]+)-([\d.]+)%\), mean return ([-\d.]+)")
EPISODE = re.compile(r"^episode (\d+) return ([-\d.e+]+) success (true|false)$", re.M)


def trainer_eval(policy: Path, task: str, episodes: int, seed: int, can: bool) -> dict:
    """`trainer eval` of a policy file, one thread, with each episode's outcome (`--actions`)."""
    actions = policy.with_name(f"{policy.stem}-actions{'' if can else '-no-can'}.txt")
    args = [str(TRAINER), "eval", str(policy), "--task", task, "--episodes", str(episodes),
            "--seed", str(seed), "--threads", "1", "--actions", str(actions)]
    if not can:
        args.append("--no-can-quantisation")
    t0, c0 = time.perf_counter(), cpu_children()
    e = subprocess.run(args, capture_output=True, text=True, cwd=ROOT)
    if e.returncode != 0:
        sys.exit(f"{' '.join(args)} failed ({e.returncode}):\n{e.stderr}")
    m = RUNTIME_EVAL.search(e.stdout)
    outcomes = [(float(r), ok == "true") for _, r, ok in EPISODE.findall(e.stdout)]
    # `episode step a0 .. a8`: each applied physical command (after the CAN quantisation when on).
    per_episode: dict[int, list] = {}
    for line in actions.read_text().splitlines():
        ep, _, *values = line.split()
        per_episode.setdefault(int(ep), []).append([float(v) for v in values])
    actions.unlink(missing_ok=True)  # 9 numbers per step: large, and not needed afterwards
    return {"successes": int(m[1]), "episodes": int(m[2]), "rate": int(m[1]) / int(m[2]),
            "actions": [per_episode.get(i, []) for i in range(len(outcomes))],
            "ci95": [round(float(m[4]) / 100, 4), round(float(m[5]) / 100, 4)], "mean_return": float(m[6]),
            "line": e.stdout.strip().splitlines()[-1], "outcomes": outcomes,
            "command": " ".join(["trainer", *args[1:]]).replace(f" --actions {actions}", ""),
            "wall_s": round(time.perf_counter() - t0, 1), "cpu_s": round(cpu_children() - c0, 1)}


def runtime_eval(sb3_model, algo: str, task: str, out: Path, name: str, episodes: int,
                 python_eps: list | None, python_actions: list | None = None) -> dict:
    """Exports `sb3_model`'s actor to out/NAME.onnx, imports it as out/NAME.dxpl and runs
    `trainer eval` on the `episodes` starts of EVAL_SEED, with and without the CAN quantisation;
    compared start by start with `python_eps` (the Python evaluation's outcomes) when given, and
    step by step with `python_actions` (its actions, [-1, 1]) when given."""
    import numpy as np
    import torch

    import dexstack

    onnx_path, dxpl = out / f"{name}.onnx", out / f"{name}.dxpl"
    info = export_actor(sb3_model.policy, algo, onnx_path)
    policy = dexstack.Policy.from_onnx(onnx_path, task=task, can_quantisation=False)
    policy.save(dxpl)
    # The runtime's actions against the wrapper's (both f32) on observations of the scale the
    # environment gives.
    obs = np.random.default_rng(1).normal(0, 1, (1000, 44)).astype(np.float32)
    with torch.no_grad():
        ref = deterministic_actor(sb3_model.policy, algo)(torch.as_tensor(obs)).numpy()
    ours = np.stack([policy.act(o) for o in obs])
    if np.abs(ours - ref).max() > 1e-4:
        print(f"warning: {dxpl} differs from the torch actor by {np.abs(ours - ref).max():.3g}", flush=True)
    scale = np.array([j[1] for j in policy.info()["action"]], np.float32)
    rec = {f"{name}_onnx": str(onnx_path.relative_to(ROOT) if onnx_path.is_relative_to(ROOT) else onnx_path),
           f"{name}_dxpl_layers": [list(layer) for layer in policy.info()["layers"]],
           f"{name}_runtime_vs_torch_max_abs": float(np.abs(ours - ref).max()),
           "onnx_exporter": info["exporter"], "export_torch": info["torch"],
           f"{name}_wrapper_vs_sb3_max_abs": info["wrapper_vs_sb3_max_abs"]}
    for can, suffix in ((True, ""), (False, "_no_can")):
        r = trainer_eval(dxpl, task, episodes, EVAL_SEED, can)
        key = f"success_{name}_runtime{suffix}"
        rec[key] = r["rate"]
        rec[f"{key}_ci95"] = r["ci95"]
        rec[f"{key}_line"] = r["line"]
        rec[f"{key}_command"] = r["command"]
        rec[f"{key}_eval_wall_s"] = r["wall_s"]
        if python_eps is not None and len(r["outcomes"]) == len(python_eps):
            rec[f"{key}_same_outcome_starts"] = sum(
                ok == p_ok for (_, ok), (_, p_ok) in zip(r["outcomes"], python_eps))
            rec[f"{key}_runtime_only"] = [i for i, ((_, ok), (_, p)) in
                                          enumerate(zip(r["outcomes"], python_eps)) if ok and not p]
            rec[f"{key}_python_only"] = [i for i, ((_, ok), (_, p)) in
                                         enumerate(zip(r["outcomes"], python_eps)) if p and not ok]
        if python_actions is not None:
            rec.update({f"{key}_{k}": v for k, v in
                        compare_actions(r["actions"], python_actions, scale).items()})
        print(json.dumps({key: r["rate"], "ci95": r["ci95"], "line": r["line"]}), flush=True)
    return rec


def compare_actions(runtime: list, python: list, scale) -> dict:
    """Step by step: the runtime's applied commands over each joint's scale against the Python
    evaluation's actions on the same starts. Equal until the two trajectories part (f32 sums in
    another order, or the CAN quantisation), then as far apart as the closed loop takes them."""
    import numpy as np

    first, worst, agree = [], [], 0
    for r, p in zip(runtime, python):
        r = np.asarray(r, np.float32) / scale
        if r.shape != p.shape:
            return {"actions_compared": False}
        d = np.abs(r - p).max(axis=1)
        first.append(float(d[0]))
        worst.append(float(d.max()))
        agree += bool(d.max() <= 1e-3)
    return {"action_step0_max_abs": max(first), "action_episode_max_abs_median": float(np.median(worst)),
            "action_max_abs": max(worst), "starts_within_1e-3_throughout": agree}


def cmd_export_onnx(a) -> None:
    """An existing SB3 zip through the runtime (old runs): export, import, `trainer eval`."""
    import torch

    torch.set_num_threads(1)
    from stable_baselines3 import SAC, TD3

    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    name = a.name or Path(a.model).stem
    model = {"sac": SAC, "td3": TD3}[a.algo].load(a.model, device="cpu")
    python_eps, python_actions = None, None
    rec: dict = {"model": str(a.model), "algo": a.algo, "task": a.task, "final_seed": EVAL_SEED,
                 "final_episodes": a.final_episodes, "date": now(), "load_before": load()}
    if a.python_eval:
        import gymnasium as gym

        import dexstack  # noqa: F401  (registers the environments)

        env = gym.make(f"dexstack/{TASK_IDS[a.task]}-v0", reward=a.reward or default_reward(a.task))
        python_actions = []
        python_eps = evaluate_episodes(model, env, EVAL_SEED, a.final_episodes, python_actions)
        rec[f"success_{name}_python"] = rate(python_eps)
        rec[f"success_{name}_python_ci95"] = wilson(python_eps)
    t0, c0 = time.perf_counter(), cpu_self() + cpu_children()
    rec.update(runtime_eval(model, a.algo, a.task, out, name, a.final_episodes, python_eps,
                            python_actions))
    rec["export_eval_wall_s"] = round(time.perf_counter() - t0, 1)
    rec["export_eval_cpu_s"] = round(cpu_self() + cpu_children() - c0, 1)
    result = out / "result.json"
    if result.exists() and not a.separate:
        merged = json.loads(result.read_text())
        own = ("model", "algo", "task", "final_seed", "final_episodes", "date", "load_before")
        merged.update({k: v for k, v in rec.items() if k not in own})
        merged.update({f"runtime_{k}": rec[k] for k in ("final_episodes", "date", "load_before")})
        write_json(result, merged)
        print(f"added the runtime figures of {name} to {result}")
    else:
        write_json(out / f"{name}-runtime.json", rec)
        print(f"wrote {out / f'{name}-runtime.json'}")
    print(json.dumps({k: v for k, v in rec.items() if "line" in k or k.startswith("success")}), flush=True)


def default_reward(task: str) -> str:
    """The side by side's reward of a task (scripts/sb3-side-by-side.sh's `reward`)."""
    return {"reach": "reach-shaping", "grasp": "full-composite"}.get(task) or sys.exit(
        f"give --reward for {task}")


# ---------------------------------------------------------------- ours


SELECTION = re.compile(r"selection at (\d+) transitions: (\d+)% \((\d+) starts\), return ([-\d.]+)")
EVAL = re.compile(r"(\d+)/(\d+) = ([\d.]+)%")


def cmd_ours(a) -> None:
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    args = [str(TRAINER), "train", *a.trainer_args, "--quiet", "--out", str(out)]
    record = {"learner": a.label, "command": " ".join(args[1:]), "load_before": load()}
    rows: list[dict] = []
    t0 = time.perf_counter()
    with open(out / "train.log", "w") as log, subprocess.Popen(
        args, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, cwd=ROOT
    ) as p:
        for line in p.stdout:
            log.write(line)
            log.flush()
            m = SELECTION.search(line)
            if m:
                rows.append({"transitions": int(m[1]), "wall_s": round(time.perf_counter() - t0, 2),
                             "success": int(m[2]) / 100, "mean_return": float(m[4]),
                             "starts": int(m[3]), "load": load()})
                print(json.dumps(rows[-1]), flush=True)
        rc = p.wait()
    wall, cpu = time.perf_counter() - t0, cpu_children()
    if rc != 0:
        sys.exit(f"trainer train failed ({rc}); see {out / 'train.log'}")
    write_csv(out / "curve.csv", rows)
    policy = out / "seed-0" / "policy.dxpl"
    finals = {}
    for name, extra in (("success_best", []), ("success_best_no_can", ["--no-can-quantisation"])):
        e = subprocess.run([str(TRAINER), "eval", str(policy), "--episodes", str(a.final_episodes),
                            "--threads", "1", *extra], capture_output=True, text=True, check=True, cwd=ROOT)
        m = EVAL.search(e.stdout)
        finals[name] = int(m[1]) / int(m[2])
        finals[name.replace("success", "eval_line")] = e.stdout.strip().splitlines()[-1]
    record.update({"wall_s": round(wall, 1), "cpu_s": round(cpu, 1), "load_after": load(),
                   "final_episodes": a.final_episodes, "final_seed": EVAL_SEED,
                   "first_90": first_at(rows, 0.9), **finals})
    write_json(out / "result.json", record)
    print(json.dumps(record), flush=True)


# ---------------------------------------------------------------- plots


def cmd_plot(a) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.ticker import FuncFormatter

    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(11, 4.2))
    for run in a.runs:
        run = Path(run)
        res = json.loads((run / "result.json").read_text())
        rows = list(csv.DictReader(open(run / "curve.csv")))
        if not rows:
            continue
        x = [int(r["transitions"]) for r in rows]
        # SB3's wall-clock without its own evaluations (30 episodes in Python every 5-10k); ours
        # includes its selection and its in-training evaluations (cheaper, but counted).
        w = [float(r.get("train_wall_s") or r["wall_s"]) / 60 for r in rows]
        y = [100 * float(r["success"]) for r in rows]
        style = "-" if res["learner"].startswith("ours") else "--"
        label = f"{res['learner']}, {x[-1] // 1000}k"
        ax1.plot(x, y, style, marker="o", ms=3, label=label)
        ax2.plot(w, y, style, marker="o", ms=3, label=label)
    ax1.set_xlabel("transitions")
    # Thousands ("50k"): at Grasp's budgets full numbers run into each other under the axis.
    ax1.xaxis.set_major_formatter(FuncFormatter(lambda v, _: f"{v / 1000:g}k" if v else "0"))
    ax2.set_xlabel("wall-clock (min; one thread on a shared 2-core machine)")
    for ax in (ax1, ax2):
        ax.set_ylabel("success on 30 fixed starts (%)")
        ax.set_ylim(-3, 103)
        ax.axhline(90, color="grey", lw=0.5)
        ax.grid(alpha=0.3)
    ax1.legend(fontsize=8, loc="best")
    fig.suptitle(a.title)
    fig.tight_layout()
    for ext in ("png", "svg"):
        fig.savefig(f"{a.out}.{ext}", dpi=120)
    print(f"wrote {a.out}.png, {a.out}.svg")


def cmd_table(a) -> None:
    """The learning table of docs/benchmarks.md, one markdown row per run folder."""
    print("| learner | transitions | curve: 30 starts, last point (best) | first >= 90% on the 30 starts: "
          "transitions, wall | final, 100 starts: best (last) | wall s | CPU s | load before-after |")
    print("|---|---:|---|---|---|---:|---:|---|")
    for run in a.runs:
        run = Path(run)
        res = json.loads((run / "result.json").read_text())
        rows = list(csv.DictReader(open(run / "curve.csv")))
        ys = [float(r["success"]) for r in rows]
        n = rows[-1]["transitions"] if rows else "-"
        f90 = res.get("first_90")
        f90 = f"{int(f90['transitions']):,}, {f90['wall_s']:.0f} s" if f90 else "not reached"
        if "success_last" in res:
            final = f"{100 * res['success_best']:.0f}% ({100 * res['success_last']:.0f}%)"
            if "success_best_runtime" in res:  # issue #31: the same actors through `trainer eval`
                final += (f"; trainer eval {100 * res['success_best_runtime']:.0f}% "
                          f"({100 * res['success_last_runtime']:.0f}%), no CAN quantisation "
                          f"{100 * res['success_best_runtime_no_can']:.0f}% "
                          f"({100 * res['success_last_runtime_no_can']:.0f}%)")
        else:
            final = f"{100 * res['success_best']:.0f}% (no CAN quantisation {100 * res['success_best_no_can']:.0f}%)"
        curve = f"{100 * ys[-1]:.0f}% ({100 * max(ys):.0f}%)" if ys else "-"
        print(f"| {res['learner']} | {int(n):,} | {curve} | {f90} | {final} | {res['wall_s']:.0f} | "
              f"{res['cpu_s']:.0f} | {res['load_before']}-{res['load_after']} |")


# ---------------------------------------------------------------- helpers


def rate(outcomes: list[tuple[float, bool]]) -> float:
    return sum(ok for _, ok in outcomes) / len(outcomes)


def wilson(outcomes: list[tuple[float, bool]]) -> list[float]:
    """95% Wilson score interval of the success rate (z = 1.96), as `trainer eval` prints it."""
    n, k, z = len(outcomes), sum(ok for _, ok in outcomes), 1.96
    p = k / n
    denom = 1 + z * z / n
    centre = (p + z * z / (2 * n)) / denom
    half = z * (p * (1 - p) / n + z * z / (4 * n * n)) ** 0.5 / denom
    return [round(max(0.0, centre - half), 4), round(min(1.0, centre + half), 4)]


def first_at(rows: list[dict], level: float):
    for r in rows:
        if r["success"] >= level:
            return {"transitions": r["transitions"], "wall_s": r["wall_s"]}
    return None


def now() -> str:
    return time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())


def write_json(path: Path, obj) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(obj, indent=1) + "\n")


def write_csv(path: Path, rows: list[dict]) -> None:
    with open(path, "w", newline="") as f:
        if rows:
            w = csv.DictWriter(f, fieldnames=list(rows[0]))
            w.writeheader()
            w.writerows(rows)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = p.add_subparsers(dest="cmd", required=True)
    s = sub.add_parser("speed")
    s.add_argument("--steps", type=int, default=3000)
    s.add_argument("--tasks", default="grasp,stack")
    s.add_argument("--dm-control", default="lift_brick_features,stack_2_bricks_features")
    s.add_argument("--out", default="runs/sb3-side-by-side/speed.json")
    s = sub.add_parser("sb3")
    s.add_argument("--algo", choices=["sac", "td3"], required=True)
    s.add_argument("--task", choices=list(TASK_IDS), required=True)
    s.add_argument("--reward", required=True, help="dexstack reward name (Reach: reach-shaping, as trainer's)")
    s.add_argument("--transitions", type=int, required=True)
    s.add_argument("--variant", choices=["default", "zoo"], default="default")
    s.add_argument("--start", choices=["original", "along-demonstrations"], default="original",
                   help="training episodes' starts (evaluation: always the original starts)")
    s.add_argument("--episode-steps", type=int,
                   help="training episodes' length (default: the task's, 50 along demonstrations)")
    s.add_argument("--seed", type=int, default=0)
    s.add_argument("--eval-every", type=int, default=5000)
    s.add_argument("--eval-starts", type=int, default=30)
    s.add_argument("--final-episodes", type=int, default=100)
    s.add_argument("--no-runtime", action="store_true",
                   help="skip the ONNX export and `trainer eval` of the best and last actors")
    s.add_argument("--out", required=True)
    s = sub.add_parser("export-onnx", help="an SB3 zip's actor through ONNX, the importer and `trainer eval`")
    s.add_argument("--algo", choices=["sac", "td3"], required=True)
    s.add_argument("--model", required=True, help="SB3 zip (best.zip, last.zip of a run folder)")
    s.add_argument("--task", choices=list(TASK_IDS), required=True)
    s.add_argument("--out", required=True, help="folder for NAME.onnx, NAME.dxpl (a run folder)")
    s.add_argument("--name", help="NAME (default: the zip's stem)")
    s.add_argument("--final-episodes", type=int, default=100)
    s.add_argument("--python-eval", action="store_true",
                   help="also evaluate the zip in Python on the same starts, start by start")
    s.add_argument("--reward", help="the Python evaluation's reward (default: the side by side's)")
    s.add_argument("--separate", action="store_true",
                   help="write OUT/NAME-runtime.json even when OUT/result.json exists")
    s = sub.add_parser("ours")
    s.add_argument("--label", required=True)
    s.add_argument("--final-episodes", type=int, default=100)
    s.add_argument("--out", required=True)
    s.add_argument("trainer_args", nargs=argparse.REMAINDER)
    s = sub.add_parser("plot")
    s.add_argument("--title", required=True)
    s.add_argument("--out", required=True, help="path without extension")
    s.add_argument("runs", nargs="+")
    s = sub.add_parser("table")
    s.add_argument("runs", nargs="+")
    a = p.parse_args()
    if a.cmd == "ours" and a.trainer_args and a.trainer_args[0] == "--":
        a.trainer_args = a.trainer_args[1:]
    {"speed": cmd_speed, "sb3": cmd_sb3, "export-onnx": cmd_export_onnx, "ours": cmd_ours,
     "plot": cmd_plot, "table": cmd_table}[a.cmd](a)


if __name__ == "__main__":
    main()
