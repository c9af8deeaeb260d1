"""ONNX in and out of the policy format (issue #31), checked against onnxruntime.

Graphs are built here with `onnx.helper` in the shapes PyTorch's exporters write (Gemm with
transB = 1 as `nn.Linear` exports, MatMul + Add with Constant nodes as the dynamo exporter writes,
input normalisation, output scaling); no PyTorch is needed. Each imported file is run by the
runtime (`dexstack.Policy`, the controller's evaluator) and compared with onnxruntime on 10,000
observations. Tolerance: 1e-5 in the network's output units (the `[-1, 1]` action of the
environments; a joint's command is that times its scale, so 5e-5 rad/s-equivalent for a finger
whose scale is 5): both are f32 with different summation orders.
"""
import subprocess
from pathlib import Path

import numpy as np
import onnx
import onnxruntime as ort
import pytest
from onnx import TensorProto, helper, numpy_helper

import gymnasium as gym

import dexstack
from conftest import ROOT, cargo_target_dir

OBS, ACT = 44, 9
SCALE = np.array([0.628] * 3 + [0.838] * 3 + [5.0] * 3, np.float32)
TOL = 1e-5
N_OBS = 10_000


@pytest.fixture(scope="module")
def policy_cli() -> Path:
    subprocess.run(["cargo", "build", "-q", "-p", "dex-policy-tool", "--bin", "policy"],
                   cwd=ROOT, check=True)
    binary = cargo_target_dir() / "debug" / "policy"
    assert binary.exists(), binary
    return binary


def _init(name, array):
    return numpy_helper.from_array(np.asarray(array, dtype=np.float32), name)


def _model(nodes, inits, out="action", width=OBS, outputs=None, opset=17):
    graph = helper.make_graph(
        nodes, "policy",
        [helper.make_tensor_value_info("obs", TensorProto.FLOAT, ["batch", width])],
        outputs or [helper.make_tensor_value_info(out, TensorProto.FLOAT, ["batch", ACT])],
        inits,
    )
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", opset)])
    model.ir_version = 8
    onnx.checker.check_model(model)
    return model


def torch_linear_mlp(rng, hidden=(64, 64)):
    """What `torch.onnx.export` writes for an SB3 TD3 actor: Gemm(transB=1) + Relu, ..., Tanh."""
    nodes, inits, x, fan_in = [], [], "obs", OBS
    for k, width in enumerate(list(hidden) + [ACT]):
        w = rng.normal(0, 1 / np.sqrt(fan_in), (width, fan_in))  # nn.Linear: [out, in]
        b = rng.normal(0, 0.1, width)
        inits += [_init(f"l{k}.weight", w), _init(f"l{k}.bias", b)]
        nodes.append(helper.make_node("Gemm", [x, f"l{k}.weight", f"l{k}.bias"], [f"g{k}"],
                                      name=f"/actor/l{k}/Gemm", transB=1))
        act = "Relu" if k < len(hidden) else "Tanh"
        out = f"a{k}" if k < len(hidden) else "action"
        nodes.append(helper.make_node(act, [f"g{k}"], [out], name=f"/actor/{act}_{k}"))
        x, fan_in = out, width
    return _model(nodes, inits)


def dynamo_style_mlp(rng):
    """MatMul + Add with Constant nodes, Cast to float (SB3's `obs.float()`), Identity and
    Flatten, input normalisation (Sub, Mul,
    Clip), and an output scaling (Mul) with limits (Clip): physical commands."""
    mean = rng.normal(0, 1, OBS)
    inv_std = rng.uniform(0.5, 2.0, OBS)
    w0, b0 = rng.normal(0, 0.2, (OBS, 32)), rng.normal(0, 0.1, 32)
    w1, b1 = rng.normal(0, 0.3, (32, ACT)), rng.normal(0, 0.1, ACT)
    out_scale = SCALE * 0.9
    nodes = [
        helper.make_node("Constant", [], ["mean"], value=_init("mean_t", mean)),
        helper.make_node("Cast", ["obs"], ["obs32"], name="obs_float", to=TensorProto.FLOAT),
        helper.make_node("Flatten", ["obs32"], ["flat"], name="flatten", axis=1),
        helper.make_node("Sub", ["flat", "mean"], ["centred"], name="norm_sub"),
        helper.make_node("Mul", ["centred", "inv_std"], ["scaled"], name="norm_mul"),
        helper.make_node("Clip", ["scaled", "lo", "hi"], ["clipped"], name="norm_clip"),
        helper.make_node("MatMul", ["clipped", "w0"], ["m0"], name="mm0"),
        helper.make_node("Add", ["m0", "b0"], ["h0"], name="add0"),
        helper.make_node("Relu", ["h0"], ["r0"], name="relu0"),
        helper.make_node("Identity", ["r0"], ["r0i"], name="id"),
        helper.make_node("MatMul", ["r0i", "w1"], ["m1"], name="mm1"),
        helper.make_node("Add", ["m1", "b1"], ["h1"], name="add1"),
        helper.make_node("Tanh", ["h1"], ["t1"], name="tanh1"),
        helper.make_node("Mul", ["t1", "out_scale"], ["phys"], name="out_scale"),
        helper.make_node("Clip", ["phys", "alo", "ahi"], ["action"], name="out_clip"),
    ]
    inits = [_init("inv_std", inv_std), _init("lo", -4.0), _init("hi", 4.0), _init("w0", w0),
             _init("b0", b0), _init("w1", w1), _init("b1", b1), _init("out_scale", out_scale),
             _init("alo", -3.0), _init("ahi", 3.0)]
    return _model(nodes, inits), mean, inv_std


def _runtime_actions(policy, obs):
    return np.stack([policy.act(o) for o in obs])


def _ort(model_bytes, obs):
    session = ort.InferenceSession(model_bytes, providers=["CPUExecutionProvider"])
    name = session.get_inputs()[0].name
    return session.run(None, {name: obs})[0]


def test_a_torch_style_actor_imports_and_matches_onnxruntime():
    rng = np.random.default_rng(1)
    model = torch_linear_mlp(rng)
    data = model.SerializeToString()
    policy = dexstack.Policy.from_onnx(data, task="grasp", can_quantisation=False)
    assert policy.task == "grasp"
    info = policy.info()
    assert info["layers"] == [(64, "relu", "f32"), (64, "relu", "f32"), (9, "tanh", "f32")]
    obs = rng.normal(0, 1.5, (N_OBS, OBS)).astype(np.float32)
    ours = _runtime_actions(policy, obs)
    theirs = _ort(data, obs)  # normalised actions: the graph ends with tanh
    assert np.abs(ours - theirs).max() <= TOL


def test_a_graph_with_normalisation_and_output_scaling_folds_into_the_file():
    rng = np.random.default_rng(2)
    model, mean, inv_std = dynamo_style_mlp(rng)
    data = model.SerializeToString()
    policy = dexstack.Policy.from_onnx(data, task="stack", can_quantisation=False)
    obs = (mean + rng.normal(0, 3, (N_OBS, OBS)) / inv_std).astype(np.float32)
    physical = _ort(data, obs)
    # `act` is the command over the cell's joint scale.
    ours = _runtime_actions(policy, obs)
    assert np.abs(ours - physical / SCALE).max() <= TOL
    # Some observations were clipped and some commands limited, so both were exercised.
    assert (np.abs((obs - mean) * inv_std) > 4).any()
    assert (np.abs(physical) >= 3.0 - 1e-6).any()


@pytest.mark.parametrize("path, task", [("policies/grasp.dxpl", "grasp"),
                                        ("runtime/tests/golden/jaco_64.dxpl", "stack")])
def test_a_cell_policy_round_trips_bit_for_bit_and_runs_in_onnxruntime(tmp_path, path, task):
    source = (ROOT / path).read_bytes()
    policy = dexstack.Policy(source, can_quantisation=False)
    exported = policy.to_onnx(tmp_path / "grasp.onnx")
    model = onnx.load(tmp_path / "grasp.onnx")
    onnx.checker.check_model(model, full_check=True)
    meta = {p.key: p.value for p in model.metadata_props}
    assert meta["dexstack.task"] == task
    assert "finger_1" in model.graph.output[0].doc_string
    assert "arm_joint_sin[0]" in model.graph.input[0].doc_string
    again = dexstack.Policy.from_onnx(exported, can_quantisation=False)
    assert again.to_bytes() == source
    init = {t.name: numpy_helper.to_array(t) for t in model.graph.initializer}
    rng = np.random.default_rng(3)
    obs = (init["obs_mean"][:OBS] + init["obs_scale"][:OBS] * rng.normal(0, 1, (N_OBS, OBS))).astype(np.float32)
    # A policy that takes the task features: the graph's input is the observation followed by
    # them, as dexstack.task_features computes them (the runtime's own function).
    inputs = obs
    if init["obs_mean"].shape[0] > OBS:
        assert init["obs_mean"].shape[0] == OBS + 14
        names = [n for n, _ in dexstack.TASK_FEATURE_FIELDS]
        assert names[0] in model.graph.input[0].doc_string
        inputs = np.concatenate([obs, np.stack([dexstack.task_features(o) for o in obs])], axis=1)
    ours = _runtime_actions(policy, obs)
    theirs = _ort(exported, inputs) / SCALE
    assert np.abs(ours - theirs).max() <= TOL


def test_task_features_ignore_a_half_turn_of_a_brick_and_need_44_values():
    env = gym.make("dexstack/Stack-v0")
    obs, _ = env.reset(options={"episode_seed": 5})
    f = dexstack.task_features(obs)
    assert f.shape == (14,) and f.dtype == np.float32 and np.isfinite(f).all()
    turned = obs.copy()
    w, x, y, z = turned[27:31]
    turned[27:31] = [-z, -y, x, w]  # brick 1 turned by half a turn about the world z: (0, 0, 0, 1) * q
    g = dexstack.task_features(turned)
    assert np.abs(f - g).max() < 1e-5
    assert np.abs(f[:2] - g[:2]).max() == 0  # the hand's own yaw does not involve the brick
    with pytest.raises(ValueError, match="44"):
        dexstack.task_features(obs[:40])


def test_round_trip_of_a_torch_style_import_is_bit_exact():
    rng = np.random.default_rng(4)
    first = dexstack.Policy.from_onnx(torch_linear_mlp(rng).SerializeToString(), task="reach")
    second = dexstack.Policy.from_onnx(first.to_onnx(), task="reach")
    assert second.to_bytes() == first.to_bytes()


def _refused(model, match, task="grasp"):
    with pytest.raises(ValueError, match=match):
        dexstack.Policy.from_onnx(model.SerializeToString(), task=task)


def test_unsupported_operators_are_refused_by_node_name():
    rng = np.random.default_rng(5)
    model = torch_linear_mlp(rng)
    model.graph.node[1].op_type = "Sigmoid"
    _refused(model, r"/actor/Relu_0.*Sigmoid.*not an operator")


def test_a_cast_to_anything_but_float_is_refused():
    rng = np.random.default_rng(11)
    model = torch_linear_mlp(rng)
    cast = helper.make_node("Cast", ["a0"], ["a0i"], name="to_int", to=TensorProto.INT64)
    model.graph.node[2].input[0] = "a0i"
    model.graph.node.insert(2, cast)
    _refused(model, r"to_int.*Cast.*float", task="grasp")


def test_a_wrong_input_width_is_refused():
    rng = np.random.default_rng(6)
    w = rng.normal(size=(40, ACT))
    model = _model([helper.make_node("MatMul", ["obs", "w"], ["action"], name="mm")],
                   [_init("w", w)], width=40)
    _refused(model, r"takes 40 inputs.*44 observation values")


def test_a_graph_with_two_outputs_is_refused():
    rng = np.random.default_rng(7)
    model = torch_linear_mlp(rng)
    extra = helper.make_tensor_value_info("a0", TensorProto.FLOAT, ["batch", 64])
    model.graph.output.append(extra)
    _refused(model, r"2 outputs")


def test_a_nan_weight_is_refused():
    rng = np.random.default_rng(8)
    model = torch_linear_mlp(rng)
    w = numpy_helper.to_array(model.graph.initializer[0]).copy()
    w[3, 5] = np.nan
    model.graph.initializer[0].CopyFrom(numpy_helper.from_array(w, "l0.weight"))
    _refused(model, r"l0.weight.*NaN")


def test_an_offset_after_the_last_activation_is_refused():
    rng = np.random.default_rng(9)
    model = torch_linear_mlp(rng)
    model.graph.node[-1].output[0] = "t"
    model.graph.node.append(helper.make_node("Add", ["t", "off"], ["action"], name="shift"))
    model.graph.initializer.append(_init("off", np.full(ACT, 0.5)))
    _refused(model, r"shift.*offset")


def test_the_cli_imports_and_exports_and_writes_nothing_on_refusal(policy_cli, tmp_path):
    rng = np.random.default_rng(10)
    good = tmp_path / "actor.onnx"
    onnx.save(torch_linear_mlp(rng), good)
    out = tmp_path / "actor.dxpl"
    done = subprocess.run([policy_cli, "import", good, "--out", out, "--task", "grasp"],
                          capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    assert "normalised actions" in done.stdout and "44 -> 64 relu -> 64 relu -> 9 tanh" in done.stdout
    assert subprocess.run([policy_cli, "verify", out]).returncode == 0
    back = tmp_path / "back.onnx"
    done = subprocess.run([policy_cli, "export-onnx", out, "--out", back], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    onnx.checker.check_model(onnx.load(back), full_check=True)

    bad = onnx.load(good)
    bad.graph.node[0].op_type = "Conv"
    onnx.save(bad, tmp_path / "bad.onnx")
    refused = tmp_path / "refused.dxpl"
    done = subprocess.run([policy_cli, "import", tmp_path / "bad.onnx", "--out", refused,
                           "--task", "grasp"], capture_output=True, text=True)
    assert done.returncode != 0
    assert "Conv" in done.stderr and "/actor/l0/Gemm" in done.stderr
    assert not refused.exists()
    (tmp_path / "junk.onnx").write_bytes(b"\x08\x07not a model at all")
    done = subprocess.run([policy_cli, "import", tmp_path / "junk.onnx", "--out", refused,
                           "--task", "grasp"], capture_output=True, text=True)
    assert done.returncode != 0 and not refused.exists()
    done = subprocess.run([policy_cli, "import", good, "--out", refused], capture_output=True, text=True)
    assert done.returncode != 0 and "no task" in done.stderr and not refused.exists()
