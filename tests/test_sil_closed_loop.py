"""A closed loop driven from Python: Python plays the plant (synthetic observations at 20 Hz,
integrating the commanded velocities), the controller node answers every observation over the bus.
And the Rust lockstep run (`hil-sim run`) is deterministic. Nothing here is timed: each step waits
for its answer (the latency is measured by the benchmarks, docs/benchmarks.md)."""
import math
import subprocess
import time

from conftest import ACTION_IDS, LIMITS, PERIOD, PlantTx, collect, decode_action, observation
JOINTS = list(LIMITS)


def test_closed_loop_episode_from_python(operational):
    s, bus = operational
    tx = PlantTx()
    q = [0.0] * 9
    answered = 0
    steps = 40
    next_t = time.monotonic()
    for step in range(steps):
        next_t += PERIOD
        obs = observation(step)
        # Joint state from the integrated commands (arm sin/cos, finger positions, velocities).
        obs[0:6] = [math.sin(a) for a in q[:6]]
        obs[6:12] = [math.cos(a) for a in q[:6]]
        obs[12:15] = q[6:9]
        tx.send(bus, obs)
        sample = tx.sample
        # Event-driven: until the answer's last action frame (a generous bound, not a deadline).
        got = collect(bus, 5.0, lambda m: m.arbitration_id == ACTION_IDS[2])
        actions = decode_action([m for _, m in got])
        if sample in actions:
            answered += 1
            a = actions[sample]
            for j, name in enumerate(JOINTS):
                v = a[name]
                assert math.isfinite(v) and abs(v) <= LIMITS[name] + 1e-3, (name, v)
                q[j] = max(-3.0, min(3.0, q[j] + v * PERIOD))
        time.sleep(max(0.0, next_t - time.monotonic()))
    # Every observation is answered, with its own sample.
    assert answered == steps
    assert any(abs(x) > 1e-3 for x in q), "the policy never moved the arm"
    d = s.diag()
    assert d["state"] == "Operational"
    assert int(d["evaluations"]) == steps
    assert int(d["e2e_errors"]) == 0 and int(d["wrong_sequence"]) == 0


def test_lockstep_run_is_deterministic(hil_sim, policies, tmp_path):
    def run(log):
        out = subprocess.run(
            [hil_sim, "run", "--policy", policies["good"], "--plant", "synthetic",
             "--episodes", "2", "--seed", "3", "--steps", "60", "--log", log],
            check=True, capture_output=True, text=True, timeout=60,
        ).stdout
        return [line for line in out.splitlines() if line.startswith(("episode", "success"))]

    a, b = run(tmp_path / "a.log"), run(tmp_path / "b.log")
    assert a == b and len(a) == 3
    assert "steps_without_action 0" in a[0]
    # The same frames with the same simulated timestamps (order between nodes within one
    # timestamp may differ, so compare sorted). Every controller frame answers a plant frame and
    # carries its bus time, the ones behind the frame the plant waits for too (the status TPDO
    # after the heartbeat, an emergency after the action frames): the bus takes what a node
    # writes at once as one event (hil-sim/src/bus/thread.rs), so the plant's next `time` cannot come
    # between them and stamp the rest with the next cycle.
    la = sorted((tmp_path / "a.log").read_text().splitlines())
    lb = sorted((tmp_path / "b.log").read_text().splitlines())
    only_a, only_b = sorted(set(la) - set(lb)), sorted(set(lb) - set(la))
    assert la == lb, f"only in run a: {only_a[:6]}, only in run b: {only_b[:6]}"
    assert len(la) > 2 * 60 * 19
