#!/usr/bin/env python3
"""PyTorch CPU reference for the learner's DDPG update (trainer/benches/learn_update.rs, "kernel").

Same work per update: target actor + target critic forward, critic forward/backward + Adam, actor
forward, critic forward/backward into the actor, actor backward + Adam, Polyak target update.
Actor 44-H-H-9 (ReLU, tanh), critic 53-H-H-1 (ReLU, linear), H = 256 unless given, f32, one thread.

Usage: python scripts/bench-torch.py [ROUNDS] [SECONDS] [HIDDEN]   (best round per batch size is printed)
"""
import sys
import time

import torch
from torch import nn

OBS, ACT = 44, 9


HIDDEN = int(sys.argv[3]) if len(sys.argv) > 3 else 256


def mlp(inp, out, out_act):
    h = HIDDEN
    layers = [nn.Linear(inp, h), nn.ReLU(), nn.Linear(h, h), nn.ReLU(), nn.Linear(h, out)]
    if out_act:
        layers.append(nn.Tanh())
    return nn.Sequential(*layers)


def rate(batch, seconds):
    torch.manual_seed(1)
    actor, critic = mlp(OBS, ACT, True), mlp(OBS + ACT, 1, False)
    t_actor, t_critic = mlp(OBS, ACT, True), mlp(OBS + ACT, 1, False)
    t_actor.load_state_dict(actor.state_dict())
    t_critic.load_state_dict(critic.state_dict())
    opt_a = torch.optim.Adam(actor.parameters(), lr=1e-4)
    opt_c = torch.optim.Adam(critic.parameters(), lr=1e-3)
    s = torch.rand(batch, OBS) * 2 - 1
    a = torch.rand(batch, ACT) * 2 - 1
    s2 = torch.rand(batch, OBS) * 2 - 1
    r = torch.rand(batch, 1)
    nd = torch.ones(batch, 1)
    tau = 0.005
    n = 0
    start = time.perf_counter()
    while time.perf_counter() - start < seconds:
        with torch.no_grad():
            y = r + 0.99 * nd * t_critic(torch.cat([s2, t_actor(s2)], 1))
        q = critic(torch.cat([s, a], 1))
        loss = 0.5 * ((q - y) ** 2).mean()
        opt_c.zero_grad(set_to_none=True)
        loss.backward()
        opt_c.step()
        pi_loss = -critic(torch.cat([s, actor(s)], 1)).mean()
        opt_a.zero_grad(set_to_none=True)
        pi_loss.backward()
        opt_a.step()
        with torch.no_grad():
            for net, tgt in ((actor, t_actor), (critic, t_critic)):
                for p, tp in zip(net.parameters(), tgt.parameters()):
                    tp.lerp_(p, tau)
        n += 1
    return n / (time.perf_counter() - start)


def main():
    rounds = int(sys.argv[1]) if len(sys.argv) > 1 else 5
    seconds = float(sys.argv[2]) if len(sys.argv) > 2 else 1.0
    torch.set_num_threads(1)
    best = {64: 0.0, 256: 0.0}
    for i in range(rounds):
        for b in best:
            u = rate(b, seconds)
            best[b] = max(best[b], u)
            print(f"round {i} torch batch {b}: {u:.0f}/s", file=sys.stderr)
    print(f"torch {torch.__version__} 1 thread, hidden layers {HIDDEN}-{HIDDEN}")
    for b, u in best.items():
        print(f"| PyTorch | {b} | {u:.0f} |")


if __name__ == "__main__":
    main()
