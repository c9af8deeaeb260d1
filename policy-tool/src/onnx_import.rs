//! An ONNX model of an MLP policy as a policy file the controller runs.
//!
//! The importer walks the graph from its one input to its one output, one node at a time, and
//! folds what it meets into the three things a policy file holds:
//!
//! - **before the first dense layer**: `Sub`, `Add`, `Mul`, `Div` by constants become the file's
//!   per-channel normalisation `z = (x - mean) / scale` (every scale must end up positive), and one
//!   symmetric `Clip` after them its `obs_clip`;
//! - **dense layers**: `Gemm` (any `alpha`, `beta`, `transB`; `transA = 0`) or `MatMul` by a
//!   constant `[in, out]` matrix with an optional `Add` of a bias; `Mul`/`Div`/`Add`/`Sub` by
//!   constants between a layer and its activation, or between an activation and the next layer,
//!   are folded into the weights; `Relu` or `Tanh` after a layer;
//! - **after the last layer**: `Mul`/`Div` by constants (the output scaling) and `Clip`, `Max`,
//!   `Min` by constants (the limits).
//!
//! `Identity`, `Flatten`, `Dropout` and `Cast` to float pass through; `Constant` nodes are
//! constants. Anything
//! else is refused with the node's name and operator.
//!
//! **Units of the output.** A graph that scales its last layer's output (a `Mul` or `Div` after
//! it) gives *physical* joint commands: the scale becomes each joint's `scale`, the limits its
//! `min`/`max` (the layout's where the graph has none), as the exporter writes them
//! ([`crate::onnx_export`]). A graph without output scaling gives *normalised* actions in
//! `[-1, 1]`, the action space of the `dexstack` environments and what a Stable-Baselines3 actor
//! ends with (`tanh`): the layout's scales and limits apply (a clamp in the graph is taken in the
//! same normalised units).

use std::collections::HashMap;

use dex_policy::{
    ActionJoint, Activation, Body, LayerSpec, MAX_ACTIONS, MAX_LAYERS, MAX_OBS_FIELDS, ObsField,
    PolicyView, Provenance, Task, encode_to_vec,
};
use prost::Message;

use crate::error::OnnxError;
use crate::onnx_export::META_PREFIX;
use crate::onnx_schema::{
    DATA_LOCATION_EXTERNAL, DATA_TYPE_DOUBLE, DATA_TYPE_FLOAT, GraphProto, ModelProto, NodeProto,
    TensorProto,
};

/// What the imported file is for and which layout it takes.
#[derive(Debug, Clone, Copy, Default)]
pub struct ImportSettings<'a> {
    /// The task; `None`: the layout file's, else the model's `dexstack.task` metadata.
    pub task: Option<Task>,
    /// A policy file whose observation and action layout (names, sizes, scales, limits, control
    /// period) the new file takes; `None`: the Jaco cell's (`dex_runtime::interface`).
    pub layout: Option<&'a PolicyView<'a>>,
}

/// Whether the graph's output is in physical or normalised units (see the module docs).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum OutputUnits {
    /// The graph scales its output: its scales (and limits) became the file's.
    Physical,
    /// The graph gives `[-1, 1]`-scaled actions: the layout's scales apply.
    Normalised,
}

/// An imported policy file and what the importer did to make it.
#[derive(Debug, Clone)]
pub struct Imported {
    /// The `.dxpl` bytes.
    pub file: Vec<u8>,
    /// Task written into the file.
    pub task: Task,
    /// `inputs -> outputs activation` per layer.
    pub layers: Vec<(usize, usize, Activation)>,
    /// How the output was read.
    pub outputs: OutputUnits,
    /// Operators folded into the normalisation, the weights or the action mapping, with counts.
    pub folded: Vec<(String, usize)>,
    /// `producer_name producer_version` of the model.
    pub producer: String,
}

/// Imports the ONNX model `model` (the bytes of a `.onnx` file).
pub fn import_onnx(model: &[u8], settings: &ImportSettings<'_>) -> Result<Imported, OnnxError> {
    let model = ModelProto::decode(model)?;
    let graph = model.graph.as_ref().ok_or(OnnxError::NoGraph)?;
    let meta: HashMap<&str, &str> = model
        .metadata_props
        .iter()
        .filter_map(|p| {
            p.key
                .strip_prefix(META_PREFIX)
                .map(|k| (k, p.value.as_str()))
        })
        .collect();
    let task = match (settings.task, settings.layout, meta.get("task")) {
        (Some(t), _, _) => t,
        (None, Some(view), _) => view.body().task,
        (None, None, Some(name)) => {
            Task::from_name(name).ok_or_else(|| OnnxError::UnknownTask((*name).to_owned()))?
        }
        (None, None, None) => return Err(OnnxError::NoTask),
    };
    let net = walk(graph)?;
    let (observation, layout_action, control_period_us) = match settings.layout {
        Some(view) => {
            let b = view.body();
            (b.observation.clone(), b.action.clone(), b.control_period_us)
        }
        // The cell's layout; a network as wide as the observation and the controller's task
        // features (what `export-onnx` writes for a policy that takes them) takes both.
        None => (
            match net.layers.first().map(|l| l.inputs) {
                Some(n) if dex_runtime::features::takes_features(n) => {
                    dex_runtime::features::policy_observation_with_features()
                }
                _ => dex_runtime::interface::policy_observation(),
            },
            dex_runtime::interface::policy_action(),
            dex_runtime::interface::CONTROL_PERIOD_US,
        ),
    };
    build(
        &model,
        &meta,
        task,
        net,
        &observation,
        &layout_action,
        control_period_us,
    )
}

/// A constant tensor as f32.
#[derive(Debug, Clone)]
struct Tensor {
    dims: Vec<usize>,
    data: Vec<f32>,
}

/// A dense layer being built: input-major weights.
#[derive(Debug, Clone)]
struct Dense {
    inputs: usize,
    outputs: usize,
    weights: Vec<f32>,
    bias: Vec<f32>,
    activation: Activation,
}

/// One normalisation step before the first layer, applied once the input width is known.
#[derive(Debug, Clone)]
enum PreOp {
    /// `z - c`.
    Sub(Tensor),
    /// `z + c`.
    Add(Tensor),
    /// `z * c`.
    Mul(Tensor),
    /// `z / c`.
    Div(Tensor),
}

/// Where the walk is.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Stage {
    /// Before the first dense layer.
    Pre,
    /// After a dense layer, before its activation.
    Linear,
    /// After an activation.
    Activated,
}

/// An element-wise `a * scale + offset` on a layer's activations, not yet folded anywhere.
#[derive(Debug, Clone, Default)]
struct Pending {
    scale: Option<Vec<f32>>,
    offset: Option<Vec<f32>>,
    /// Whether a `Mul` or `Div` contributed (the output is then in physical units).
    scaled: bool,
    /// First node that added an offset, for errors.
    offset_node: Option<(String, String)>,
}

/// What the walk found.
#[derive(Debug, Clone)]
struct Network {
    pre: Vec<(PreOp, String, String)>,
    clip: Option<f32>,
    layers: Vec<Dense>,
    pending: Pending,
    lower: Option<Vec<f32>>,
    upper: Option<Vec<f32>>,
    input_width: Option<usize>,
    folded: Vec<(String, usize)>,
}

fn node_id(node: &NodeProto) -> String {
    if node.name.is_empty() {
        node.output.first().cloned().unwrap_or_default()
    } else {
        node.name.clone()
    }
}

fn op_id(node: &NodeProto) -> String {
    if node.domain.is_empty() || node.domain == "ai.onnx" {
        node.op_type.clone()
    } else {
        format!("{}:{}", node.domain, node.op_type)
    }
}

fn unsupported(node: &NodeProto, why: impl Into<String>) -> OnnxError {
    OnnxError::Unsupported {
        node: node_id(node),
        op: op_id(node),
        why: why.into(),
    }
}

/// A tensor's values as f32 (FLOAT, or DOUBLE rounded), refusing external data and non-finite values.
fn tensor(t: &TensorProto, name: &str) -> Result<Tensor, OnnxError> {
    let bad = |why: &str| OnnxError::Tensor {
        name: name.to_owned(),
        why: why.to_owned(),
    };
    if t.data_location == DATA_LOCATION_EXTERNAL || !t.external_data.is_empty() {
        return Err(bad(
            "its data is in an external file; save the model with its weights inside \
             (onnx.save(model, path, save_as_external_data=False))",
        ));
    }
    if t.segment.is_some() {
        return Err(bad("segmented tensors are not supported"));
    }
    let dims = t
        .dims
        .iter()
        .map(|&d| usize::try_from(d).map_err(|_| bad("negative dimension")))
        .collect::<Result<Vec<_>, _>>()?;
    let count = dims
        .iter()
        .try_fold(1usize, |acc, &d| acc.checked_mul(d))
        .ok_or_else(|| bad("too many elements"))?;
    let data: Vec<f32> = match t.data_type {
        DATA_TYPE_FLOAT if !t.raw_data.is_empty() => t
            .raw_data
            .chunks_exact(4)
            .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
            .collect(),
        DATA_TYPE_FLOAT => t.float_data.clone(),
        DATA_TYPE_DOUBLE if !t.raw_data.is_empty() => t
            .raw_data
            .chunks_exact(8)
            .map(|b| f64::from_le_bytes([b[0], b[1], b[2], b[3], b[4], b[5], b[6], b[7]]) as f32)
            .collect(),
        DATA_TYPE_DOUBLE => t.double_data.iter().map(|&v| v as f32).collect(),
        other => {
            return Err(bad(&format!(
                "element type {other} is not float (1) or double (11)"
            )));
        }
    };
    if data.len() != count {
        return Err(bad(&format!(
            "holds {} values for a shape of {count}",
            data.len()
        )));
    }
    if data.iter().any(|v| !v.is_finite()) {
        return Err(OnnxError::NonFinite(name.to_owned()));
    }
    Ok(Tensor { dims, data })
}

/// `t` broadcast to `n` values along the last axis (a scalar, or `n` values with all other
/// dimensions 1).
fn broadcast(t: &Tensor, n: usize, node: &NodeProto) -> Result<Vec<f32>, OnnxError> {
    if t.data.len() == 1 {
        return Ok(vec![t.data[0]; n]);
    }
    let last = t.dims.last().copied().unwrap_or(1);
    if t.data.len() == n && last == n {
        return Ok(t.data.clone());
    }
    Err(unsupported(
        node,
        format!(
            "a constant of shape {:?} does not broadcast over {n} values",
            t.dims
        ),
    ))
}

/// The float attribute `name` of a node, or `default`.
fn attr_f(node: &NodeProto, name: &str, default: f32) -> f32 {
    node.attribute
        .iter()
        .find(|a| a.name == name)
        .map_or(default, |a| a.f)
}

/// The integer attribute `name` of a node, or `default`.
fn attr_i(node: &NodeProto, name: &str, default: i64) -> i64 {
    node.attribute
        .iter()
        .find(|a| a.name == name)
        .map_or(default, |a| a.i)
}

/// The constants of a graph: initializers and `Constant` nodes.
fn constants(graph: &GraphProto) -> Result<HashMap<String, Tensor>, OnnxError> {
    let mut out = HashMap::new();
    for t in &graph.initializer {
        out.insert(t.name.clone(), tensor(t, &t.name)?);
    }
    for node in graph.node.iter().filter(|n| n.op_type == "Constant") {
        let name = node
            .output
            .first()
            .ok_or_else(|| unsupported(node, "a Constant without output"))?;
        let value = if let Some(t) = node
            .attribute
            .iter()
            .find_map(|a| (a.name == "value").then_some(a.t.as_ref()).flatten())
        {
            tensor(t, name)?
        } else if let Some(a) = node.attribute.iter().find(|a| a.name == "value_float") {
            Tensor {
                dims: vec![],
                data: vec![a.f],
            }
        } else if let Some(a) = node.attribute.iter().find(|a| a.name == "value_floats") {
            Tensor {
                dims: vec![a.floats.len()],
                data: a.floats.clone(),
            }
        } else {
            return Err(unsupported(
                node,
                "only float tensor constants (value, value_float, value_floats)",
            ));
        };
        if value.data.iter().any(|v| !v.is_finite()) {
            return Err(OnnxError::NonFinite(name.clone()));
        }
        out.insert(name.clone(), value);
    }
    Ok(out)
}

/// Walks the chain of nodes from the graph's input to its output.
fn walk(graph: &GraphProto) -> Result<Network, OnnxError> {
    let consts = constants(graph)?;
    let initializer_names: Vec<&str> = graph.initializer.iter().map(|t| t.name.as_str()).collect();
    let inputs: Vec<_> = graph
        .input
        .iter()
        .filter(|i| !initializer_names.contains(&i.name.as_str()))
        .collect();
    if inputs.len() != 1 {
        return Err(OnnxError::Inputs(inputs.len()));
    }
    if graph.output.len() != 1 {
        return Err(OnnxError::Outputs(graph.output.len()));
    }
    let input = inputs[0];
    let output = graph.output[0].name.as_str();
    let input_type = input.r#type.as_ref().and_then(|t| t.tensor_type.as_ref());
    if let Some(t) = input_type
        && t.elem_type != DATA_TYPE_FLOAT
    {
        return Err(OnnxError::Tensor {
            name: input.name.clone(),
            why: format!("the input's element type is {}, not float (1)", t.elem_type),
        });
    }
    let input_width = input_type
        .and_then(|t| t.shape.as_ref())
        .and_then(|s| s.dim.last())
        .and_then(|d| d.dim_value)
        .and_then(|v| usize::try_from(v).ok());

    // Consumers of every computed value (constants are not values of the chain).
    let nodes: Vec<&NodeProto> = graph
        .node
        .iter()
        .filter(|n| n.op_type != "Constant")
        .collect();
    let mut consumers: HashMap<&str, Vec<usize>> = HashMap::new();
    for (i, n) in nodes.iter().enumerate() {
        for name in n.input.iter().filter(|s| !s.is_empty()) {
            if !consts.contains_key(name) {
                consumers.entry(name.as_str()).or_default().push(i);
            }
        }
    }

    let mut net = Network {
        pre: vec![],
        clip: None,
        layers: vec![],
        pending: Pending::default(),
        lower: None,
        upper: None,
        input_width,
        folded: vec![],
    };
    let mut stage = Stage::Pre;
    let mut cur = input.name.clone();
    let mut seen = 0usize;
    while cur != output {
        let next = match consumers.get(cur.as_str()).map(Vec::as_slice) {
            Some([one]) => *one,
            Some([]) | None => return Err(OnnxError::Disconnected(cur)),
            Some(_) => return Err(OnnxError::Branch(cur)),
        };
        seen += 1;
        if seen > nodes.len() {
            return Err(OnnxError::Disconnected(cur));
        }
        let node = nodes[next];
        if !(node.domain.is_empty() || node.domain == "ai.onnx") {
            return Err(unsupported(
                node,
                "operators of other domains are not supported",
            ));
        }
        let out = node
            .output
            .first()
            .filter(|o| !o.is_empty())
            .ok_or_else(|| unsupported(node, "a node without output"))?
            .clone();
        if node
            .output
            .iter()
            .skip(1)
            .any(|o| consumers.contains_key(o.as_str()))
        {
            return Err(unsupported(
                node,
                "only the first output of a node may be used",
            ));
        }
        step(&mut net, &mut stage, node, &cur, &consts)?;
        cur = out;
    }
    if net.layers.is_empty() {
        return Err(OnnxError::NoLayer);
    }
    Ok(net)
}

/// The constant operand of a binary node whose other operand is `cur`, and whether `cur` is the
/// first operand.
fn operand<'c>(
    node: &NodeProto,
    cur: &str,
    consts: &'c HashMap<String, Tensor>,
) -> Result<(&'c Tensor, bool), OnnxError> {
    let [a, b] = node.input.as_slice() else {
        return Err(unsupported(node, "expected two inputs"));
    };
    let (other, first) = if a == cur { (b, true) } else { (a, false) };
    if other == cur {
        return Err(unsupported(node, "both operands are the running value"));
    }
    let c = consts.get(other).ok_or_else(|| {
        unsupported(
            node,
            format!("operand {other:?} is computed, not a constant"),
        )
    })?;
    Ok((c, first))
}

fn count(folded: &mut Vec<(String, usize)>, what: &str) {
    match folded.iter_mut().find(|(w, _)| w == what) {
        Some((_, n)) => *n += 1,
        None => folded.push((what.to_owned(), 1)),
    }
}

/// One node of the chain.
fn step(
    net: &mut Network,
    stage: &mut Stage,
    node: &NodeProto,
    cur: &str,
    consts: &HashMap<String, Tensor>,
) -> Result<(), OnnxError> {
    let op = node.op_type.as_str();
    let limits_set = net.lower.is_some() || net.upper.is_some();
    match op {
        "Identity" | "Flatten" | "Dropout" | "Cast" => {
            if op == "Flatten" && attr_i(node, "axis", 1) != 1 {
                return Err(unsupported(
                    node,
                    "only Flatten with axis 1 (a no-op on [batch, n])",
                ));
            }
            // PyTorch's `obs.float()` (Stable-Baselines3 writes it) exports as a Cast to float: a
            // no-op on a float input; a cast to anything else is not.
            if op == "Cast" && attr_i(node, "to", 0) != i64::from(DATA_TYPE_FLOAT) {
                return Err(unsupported(
                    node,
                    "only a Cast to float (1) on the float observation",
                ));
            }
            count(&mut net.folded, &format!("{op} (no-op)"));
        }
        "Gemm" | "MatMul" => {
            if limits_set {
                return Err(unsupported(node, "a clamp between dense layers"));
            }
            let a = node.input.first().map(String::as_str);
            if a != Some(cur) {
                return Err(unsupported(
                    node,
                    "the running value must be the first operand",
                ));
            }
            let b_name = node.input.get(1).map(String::as_str).unwrap_or("");
            let b = consts.get(b_name).ok_or_else(|| {
                unsupported(node, format!("the weights {b_name:?} are not a constant"))
            })?;
            let [rows, cols] = b.dims.as_slice() else {
                return Err(unsupported(
                    node,
                    format!("weights of shape {:?}; expected 2-D", b.dims),
                ));
            };
            let (rows, cols) = (*rows, *cols);
            let (trans_a, trans_b, alpha, beta) = if op == "Gemm" {
                (
                    attr_i(node, "transA", 0),
                    attr_i(node, "transB", 0),
                    attr_f(node, "alpha", 1.0),
                    attr_f(node, "beta", 1.0),
                )
            } else {
                (0, 0, 1.0, 1.0)
            };
            if trans_a != 0 {
                return Err(unsupported(
                    node,
                    "transA = 1 (the input must be [batch, inputs])",
                ));
            }
            let (inputs, outputs) = if trans_b != 0 {
                (cols, rows)
            } else {
                (rows, cols)
            };
            let mut weights = vec![0.0f32; inputs * outputs];
            for i in 0..inputs {
                for j in 0..outputs {
                    let v = if trans_b != 0 {
                        b.data[j * cols + i]
                    } else {
                        b.data[i * cols + j]
                    };
                    weights[i * outputs + j] = if alpha == 1.0 { v } else { alpha * v };
                }
            }
            let mut bias = vec![0.0f32; outputs];
            if let Some(c_name) = node.input.get(2).filter(|s| !s.is_empty()) {
                let c = consts.get(c_name).ok_or_else(|| {
                    unsupported(node, format!("the bias {c_name:?} is not a constant"))
                })?;
                bias = broadcast(c, outputs, node)?;
                if beta != 1.0 {
                    bias.iter_mut().for_each(|v| *v *= beta);
                }
            }
            if trans_b != 0 {
                count(&mut net.folded, "Gemm transB (weights transposed)");
            }
            if let Some(prev) = net.layers.last()
                && prev.outputs != inputs
            {
                return Err(unsupported(
                    node,
                    format!(
                        "takes {inputs} inputs after a layer of {} outputs",
                        prev.outputs
                    ),
                ));
            }
            // Fold a pending a * scale + offset on the inputs into this layer.
            let pending = std::mem::take(&mut net.pending);
            if let Some(off) = &pending.offset {
                for (j, b) in bias.iter_mut().enumerate() {
                    let mut acc = *b;
                    for (i, o) in off.iter().enumerate().take(inputs) {
                        acc += o * weights[i * outputs + j];
                    }
                    *b = acc;
                }
            }
            if let Some(scale) = &pending.scale {
                for (i, s) in scale.iter().enumerate().take(inputs) {
                    for w in &mut weights[i * outputs..(i + 1) * outputs] {
                        *w *= s;
                    }
                }
            }
            net.layers.push(Dense {
                inputs,
                outputs,
                weights,
                bias,
                activation: Activation::Linear,
            });
            *stage = Stage::Linear;
        }
        "Relu" | "Tanh" => {
            match *stage {
                Stage::Pre => {
                    return Err(unsupported(
                        node,
                        "an activation before the first dense layer",
                    ));
                }
                Stage::Activated => {
                    return Err(unsupported(
                        node,
                        "a second activation, or one after an output scaling or clamp",
                    ));
                }
                Stage::Linear => {}
            }
            if let Some(layer) = net.layers.last_mut() {
                layer.activation = if op == "Relu" {
                    Activation::Relu
                } else {
                    Activation::Tanh
                };
            }
            *stage = Stage::Activated;
        }
        "Sub" | "Add" | "Mul" | "Div" => {
            let (c, first) = operand(node, cur, consts)?;
            match *stage {
                Stage::Pre => {
                    if net.clip.is_some() {
                        return Err(unsupported(node, "normalisation after the clip"));
                    }
                    let pre = match (op, first) {
                        ("Sub", true) => PreOp::Sub(c.clone()),
                        ("Add", _) => PreOp::Add(c.clone()),
                        ("Mul", _) => PreOp::Mul(c.clone()),
                        ("Div", true) => PreOp::Div(c.clone()),
                        _ => {
                            return Err(unsupported(
                                node,
                                "a constant minus or over the observation",
                            ));
                        }
                    };
                    net.pre.push((pre, node_id(node), op_id(node)));
                    count(&mut net.folded, &format!("{op} (normalisation)"));
                }
                Stage::Linear => {
                    // Between a layer and its activation: into the layer.
                    let Some(layer) = net.layers.last_mut() else {
                        return Err(unsupported(node, "no layer to fold into"));
                    };
                    let v = broadcast(c, layer.outputs, node)?;
                    let outputs = layer.outputs;
                    match (op, first) {
                        ("Add", _) => layer.bias.iter_mut().zip(&v).for_each(|(b, c)| *b += c),
                        ("Sub", true) => layer.bias.iter_mut().zip(&v).for_each(|(b, c)| *b -= c),
                        ("Mul", _) | ("Div", true) => {
                            let f: Vec<f32> = if op == "Mul" {
                                v
                            } else {
                                v.iter().map(|c| 1.0 / c).collect()
                            };
                            for row in layer.weights.chunks_exact_mut(outputs) {
                                row.iter_mut().zip(&f).for_each(|(w, s)| *w *= s);
                            }
                            layer.bias.iter_mut().zip(&f).for_each(|(b, s)| *b *= s);
                        }
                        _ => {
                            return Err(unsupported(node, "a constant minus or over a layer"));
                        }
                    }
                    count(&mut net.folded, &format!("{op} (into the layer)"));
                }
                Stage::Activated => {
                    if limits_set {
                        return Err(unsupported(node, "scaling after the output's clamp"));
                    }
                    let n = net.layers.last().map_or(0, |l| l.outputs);
                    let v = broadcast(c, n, node)?;
                    let p = &mut net.pending;
                    let scale = p.scale.get_or_insert_with(|| vec![1.0; n]);
                    let offset = p.offset.get_or_insert_with(|| vec![0.0; n]);
                    match (op, first) {
                        ("Mul", _) => {
                            scale.iter_mut().zip(&v).for_each(|(s, c)| *s *= c);
                            offset.iter_mut().zip(&v).for_each(|(o, c)| *o *= c);
                        }
                        ("Div", true) => {
                            scale.iter_mut().zip(&v).for_each(|(s, c)| *s /= c);
                            offset.iter_mut().zip(&v).for_each(|(o, c)| *o /= c);
                        }
                        ("Add", _) => offset.iter_mut().zip(&v).for_each(|(o, c)| *o += c),
                        ("Sub", true) => offset.iter_mut().zip(&v).for_each(|(o, c)| *o -= c),
                        _ => {
                            return Err(unsupported(
                                node,
                                "a constant minus or over an activation",
                            ));
                        }
                    }
                    if op == "Mul" || op == "Div" {
                        p.scaled = true;
                    } else if p.offset_node.is_none() {
                        // Offsets fold into a following layer; one left in the output is refused.
                        p.offset_node = Some((node_id(node), op_id(node)));
                    }
                    count(&mut net.folded, &format!("{op} (after an activation)"));
                }
            }
        }
        "Clip" | "Max" | "Min" => {
            let (lo, hi) = match op {
                "Clip" => {
                    let bound = |k: usize, attr: &str| -> Result<Option<Tensor>, OnnxError> {
                        if let Some(a) = node.attribute.iter().find(|a| a.name == attr) {
                            return Ok(Some(Tensor {
                                dims: vec![],
                                data: vec![a.f],
                            }));
                        }
                        match node.input.get(k).filter(|s| !s.is_empty()) {
                            None => Ok(None),
                            Some(name) => consts.get(name).cloned().map(Some).ok_or_else(|| {
                                unsupported(node, format!("bound {name:?} is not a constant"))
                            }),
                        }
                    };
                    (bound(1, "min")?, bound(2, "max")?)
                }
                _ => {
                    let (c, _) = operand(node, cur, consts)?;
                    if op == "Max" {
                        (Some(c.clone()), None)
                    } else {
                        (None, Some(c.clone()))
                    }
                }
            };
            if *stage == Stage::Pre {
                if op != "Clip" {
                    return Err(unsupported(node, "Max/Min before the first layer"));
                }
                let (Some(lo), Some(hi)) = (lo, hi) else {
                    return Err(unsupported(node, "a one-sided clip of the observation"));
                };
                let (l, h) = (lo.data.first().copied(), hi.data.first().copied());
                match (lo.data.len(), hi.data.len(), l, h) {
                    (1, 1, Some(l), Some(h)) if l == -h && h > 0.0 => net.clip = Some(h),
                    _ => {
                        return Err(unsupported(
                            node,
                            "the observation clip must be one symmetric bound [-c, c], c > 0",
                        ));
                    }
                }
                count(&mut net.folded, "Clip (normalisation)");
            } else {
                let Some(layer) = net.layers.last() else {
                    return Err(unsupported(node, "no layer before the clamp"));
                };
                let n = layer.outputs;
                if let Some(lo) = lo {
                    let v = broadcast(&lo, n, node)?;
                    let lower = net.lower.get_or_insert_with(|| vec![f32::NEG_INFINITY; n]);
                    lower.iter_mut().zip(&v).for_each(|(l, c)| *l = l.max(*c));
                }
                if let Some(hi) = hi {
                    let v = broadcast(&hi, n, node)?;
                    let upper = net.upper.get_or_insert_with(|| vec![f32::INFINITY; n]);
                    upper.iter_mut().zip(&v).for_each(|(u, c)| *u = u.min(*c));
                }
                *stage = Stage::Activated;
                count(&mut net.folded, &format!("{op} (action limits)"));
            }
        }
        _ => {
            return Err(unsupported(
                node,
                "not an operator of an MLP policy (the runtime runs Gemm/MatMul + Add, Relu, Tanh, \
                 and folds Sub/Add/Mul/Div/Clip/Max/Min by constants)",
            ));
        }
    }
    Ok(())
}

/// The normalisation `(mean, scale)` of `n` inputs from the steps before the first layer.
fn normalisation(net: &Network, n: usize) -> Result<(Vec<f32>, Vec<f32>), OnnxError> {
    let mut mean = vec![0.0f32; n];
    let mut scale = vec![1.0f32; n];
    for (op, node, op_name) in &net.pre {
        let err = |why: String| OnnxError::Unsupported {
            node: node.clone(),
            op: op_name.clone(),
            why,
        };
        let t = match op {
            PreOp::Sub(t) | PreOp::Add(t) | PreOp::Mul(t) | PreOp::Div(t) => t,
        };
        let c: Vec<f32> = if t.data.len() == 1 {
            vec![t.data[0]; n]
        } else if t.data.len() == n && t.dims.last() == Some(&n) {
            t.data.clone()
        } else {
            return Err(err(format!(
                "a constant of shape {:?} does not broadcast over {n} observation values",
                t.dims
            )));
        };
        for i in 0..n {
            match op {
                // z = (x - m) / s:  z - c = (x - (m + c s)) / s
                PreOp::Sub(_) => mean[i] += c[i] * scale[i],
                PreOp::Add(_) => mean[i] -= c[i] * scale[i],
                PreOp::Mul(_) => scale[i] /= c[i],
                PreOp::Div(_) => scale[i] *= c[i],
            }
        }
    }
    if let Some(i) = scale.iter().position(|s| !(s.is_finite() && *s > 0.0)) {
        return Err(OnnxError::Unsupported {
            node: net.pre.last().map(|p| p.1.clone()).unwrap_or_default(),
            op: net.pre.last().map(|p| p.2.clone()).unwrap_or_default(),
            why: format!(
                "the normalisation's scale of observation value {i} is {}; it must be positive",
                scale[i]
            ),
        });
    }
    Ok((mean, scale))
}

fn build(
    model: &ModelProto,
    meta: &HashMap<&str, &str>,
    task: Task,
    net: Network,
    observation: &heapless::Vec<ObsField<'_>, MAX_OBS_FIELDS>,
    layout_action: &heapless::Vec<ActionJoint<'_>, MAX_ACTIONS>,
    control_period_us: u32,
) -> Result<Imported, OnnxError> {
    let obs_dim: usize = observation.iter().map(|f| usize::from(f.size)).sum();
    let act_dim = layout_action.len();
    let first = net.layers.first().ok_or(OnnxError::NoLayer)?;
    for got in [Some(first.inputs), net.input_width].into_iter().flatten() {
        if got != obs_dim {
            return Err(OnnxError::InputWidth {
                expected: obs_dim,
                got,
                task: task.name(),
            });
        }
    }
    let last = net.layers.last().ok_or(OnnxError::NoLayer)?;
    if last.outputs != act_dim {
        return Err(OnnxError::OutputWidth {
            expected: act_dim,
            got: last.outputs,
            task: task.name(),
        });
    }
    if net.layers.len() > MAX_LAYERS || net.layers.iter().any(|l| l.outputs > usize::from(u16::MAX))
    {
        return Err(OnnxError::TooLarge(net.layers.len()));
    }
    if let Some(off) = &net.pending.offset
        && off.iter().any(|&o| o != 0.0)
    {
        let (node, op) = net.pending.offset_node.clone().unwrap_or_default();
        return Err(OnnxError::Unsupported {
            node,
            op,
            why: "an offset added after the last layer's activation; the runtime maps outputs by \
                  a scale and limits only"
                .to_owned(),
        });
    }
    let outputs = if net.pending.scaled {
        OutputUnits::Physical
    } else {
        OutputUnits::Normalised
    };
    let mut action: heapless::Vec<ActionJoint<'_>, MAX_ACTIONS> = heapless::Vec::new();
    for (j, l) in layout_action.iter().enumerate() {
        let (scale, min, max) = match (&net.pending.scale, outputs) {
            (Some(s), OutputUnits::Physical) => (
                s[j],
                net.lower.as_ref().map_or(l.min, |v| v[j].max(f32::MIN)),
                net.upper.as_ref().map_or(l.max, |v| v[j].min(f32::MAX)),
            ),
            _ => (
                l.scale,
                net.lower
                    .as_ref()
                    .map_or(l.min, |v| (v[j] * l.scale).max(f32::MIN)),
                net.upper
                    .as_ref()
                    .map_or(l.max, |v| (v[j] * l.scale).min(f32::MAX)),
            ),
        };
        let _ = action.push(ActionJoint {
            name: l.name,
            scale,
            min,
            max,
        });
    }
    let (mean, scale) = normalisation(&net, obs_dim)?;
    let mut values = mean;
    values.extend_from_slice(&scale);
    let mut layers = heapless::Vec::<LayerSpec, MAX_LAYERS>::new();
    for l in &net.layers {
        let _ = layers.push(LayerSpec::f32(l.outputs as u16, l.activation));
        values.extend_from_slice(&l.weights);
        values.extend_from_slice(&l.bias);
    }
    let producer = format!("{} {}", model.producer_name, model.producer_version)
        .trim()
        .to_owned();
    let trainer_version = match meta.get("trainer_version") {
        Some(v) => (*v).to_owned(),
        None if producer.is_empty() => "onnx import".to_owned(),
        None => format!("onnx import ({producer})"),
    };
    let parse_u64 = |k: &str| meta.get(k).and_then(|v| v.parse::<u64>().ok()).unwrap_or(0);
    let body = Body {
        task,
        observation: observation.clone(),
        obs_clip: net.clip.unwrap_or(f32::MAX),
        action,
        control_period_us,
        layers,
        provenance: Provenance {
            trainer_version: &trainer_version,
            seed: parse_u64("seed"),
            transitions: parse_u64("transitions"),
            success_rate: meta.get("success_rate").and_then(|v| v.parse::<f32>().ok()),
            eval_episodes: u32::try_from(parse_u64("eval_episodes")).unwrap_or(0),
        },
    };
    let file = encode_to_vec(&body, &values)?;
    Ok(Imported {
        file,
        task,
        layers: net
            .layers
            .iter()
            .map(|l| (l.inputs, l.outputs, l.activation))
            .collect(),
        outputs,
        folded: net.folded,
        producer,
    })
}
