"""Our learner side by side with Stable-Baselines3 on the dexstack environments (issue #14).

Run through scripts/sb3-side-by-side.sh, which makes the throwaway venv (.venv-sb3: CPU torch,
stable-baselines3, dm_control, matplotlib and the dexstack wheel) and runs everything in order.
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
    ours   --out DIR -- TRAINER-ARGS...    runs `trainer train TRAINER-ARGS --quiet --out DIR`, times
                                           its selection lines (the same 30 starts), then `trainer
                                           eval` of the exported policy.dxpl on the same 100 starts
    plot   RUNS...                         success against transitions and against wall-clock
    table  RUNS...                         the learning table (markdown)

Every run folder gets curve.csv (transitions, wall_s, cpu_s, success on the 30 starts) and
result.json (final success over 100 starts, wall and CPU seconds, uptime's load before and after).
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
    import dexstack

    ok, ret = 0, 0.0
    for i in range(episodes):
        obs, _ = env.reset(options={"episode_seed": dexstack.episode_seed(seed, i)})
        truncated = False
        while not truncated:
            action, _ = model.predict(obs, deterministic=True)
            obs, reward, _, truncated, info = env.step(action)
            ret += reward
        ok += bool(info["success"])
    return ok / episodes, ret / episodes


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
    env = gym.make(env_id, reward=a.reward)
    eval_env = gym.make(env_id, reward=a.reward)
    algo = {"sac": SAC, "td3": TD3}[a.algo]
    kw = sb3_kwargs(a.algo, a.variant, env.action_space.shape[0])
    model = algo("MlpPolicy", env, seed=a.seed, device="cpu", verbose=0, **kw)
    record = {"learner": f"SB3 {a.algo.upper()} ({a.variant})", "task": a.task, "reward": a.reward,
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
    last = evaluate(model, eval_env, EVAL_SEED, a.final_episodes)
    best_model = algo.load(out / "best.zip", device="cpu")
    best_eval = evaluate(best_model, eval_env, EVAL_SEED, a.final_episodes)
    record.update({
        "wall_s": round(wall, 1), "cpu_s": round(cpu, 1), "eval_wall_s": round(eval_s[0], 1),
        "load_after": load(), "final_episodes": a.final_episodes, "final_seed": EVAL_SEED,
        "success_last": last[0], "success_best": best_eval[0], "best_transitions": best["transitions"],
        "first_90": first_at(rows, 0.9),
    })
    write_json(out / "result.json", record)
    print(json.dumps(record), flush=True)


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
        else:
            final = f"{100 * res['success_best']:.0f}% (no CAN quantisation {100 * res['success_best_no_can']:.0f}%)"
        curve = f"{100 * ys[-1]:.0f}% ({100 * max(ys):.0f}%)" if ys else "-"
        print(f"| {res['learner']} | {int(n):,} | {curve} | {f90} | {final} | {res['wall_s']:.0f} | "
              f"{res['cpu_s']:.0f} | {res['load_before']}-{res['load_after']} |")


# ---------------------------------------------------------------- helpers


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
    s.add_argument("--seed", type=int, default=0)
    s.add_argument("--eval-every", type=int, default=5000)
    s.add_argument("--eval-starts", type=int, default=30)
    s.add_argument("--final-episodes", type=int, default=100)
    s.add_argument("--out", required=True)
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
    {"speed": cmd_speed, "sb3": cmd_sb3, "ours": cmd_ours, "plot": cmd_plot, "table": cmd_table}[a.cmd](a)


if __name__ == "__main__":
    main()
