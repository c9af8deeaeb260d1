//! A policy file as an ONNX model: what the controller computes, from the observation to the
//! joint commands, in operators every ONNX tool runs.
//!
//! The graph (opset [`OPSET`]) takes `observation` (`[batch, obs_dim]`, f32) and gives `action`
//! (`[batch, act_dim]`, the commands before the controller's safety envelope):
//!
//! ```text
//! Sub(obs_mean) -> Div(obs_scale) -> Clip(-obs_clip, obs_clip)        the file's normalisation
//! -> Gemm(layer{k}.weight [in, out], layer{k}.bias) -> Relu | Tanh    each layer
//! -> Mul(action_scale) -> Max(action_min) -> Min(action_max)          each joint's scale and limits
//! ```
//!
//! The f32 numbers are the file's, bit for bit, so [`crate::onnx_import`] gives the same file
//! back. An int8 layer is exported as its dequantised f32 twin (`w = q * scale`, per output): the
//! runtime's int8 kernel also rounds each layer's inputs to 16 bits, so an ONNX runtime's actions
//! for an int8 file differ from the controller's by that rounding (the metadata says so). The names
//! of the observation channels and action joints are in the input's and output's descriptions and
//! in the model's metadata (`dexstack.*`), which Netron shows.

use dex_policy::{Activation, LayerDtype, PolicyView};
use prost::Message;

use crate::error::OnnxError;
use crate::onnx_schema::{
    DATA_TYPE_FLOAT, GraphProto, ModelProto, NodeProto, OperatorSetIdProto, StringStringEntryProto,
    TensorProto, TensorShapeDimension, TensorShapeProto, TypeProto, TypeProtoTensor,
    ValueInfoProto,
};

/// The ONNX operator set the exporter writes (onnxruntime 1.14 and later, PyTorch's default).
pub const OPSET: i64 = 17;
/// The ONNX IR version the exporter writes (the one of opset 17).
pub const IR_VERSION: i64 = 8;
/// Name of the graph's input.
pub const INPUT: &str = "observation";
/// Name of the graph's output.
pub const OUTPUT: &str = "action";
/// Metadata key prefix of what the policy file says about itself.
pub const META_PREFIX: &str = "dexstack.";

/// The ONNX model of a policy file (the bytes of a `.onnx` file).
pub fn export_onnx(policy: &[u8]) -> Result<Vec<u8>, OnnxError> {
    let view = PolicyView::decode(policy)?;
    Ok(model(&view)?.encode_to_vec())
}

/// The ONNX model of a decoded policy file.
pub fn model(view: &PolicyView<'_>) -> Result<ModelProto, OnnxError> {
    let body = view.body();
    // Every stored word as f32 (the packed int8 words of int8 layers are not read as numbers).
    let values: Vec<f32> = view.values().iter().collect();
    let obs_dim = body.obs_dim();
    let mut g = Graph::default();

    g.constant("obs_mean", &[obs_dim], words(&values, 0, obs_dim)?);
    g.constant("obs_scale", &[obs_dim], words(&values, obs_dim, obs_dim)?);
    g.constant("obs_clip_min", &[], &[-body.obs_clip]);
    g.constant("obs_clip_max", &[], &[body.obs_clip]);
    let mut x = g.node("Sub", "normalise_sub", &[INPUT, "obs_mean"]);
    x = g.node("Div", "normalise_div", &[&x, "obs_scale"]);
    x = g.node(
        "Clip",
        "normalise_clip",
        &[&x, "obs_clip_min", "obs_clip_max"],
    );

    let mut int8 = false;
    for (k, layer) in view.layers().enumerate() {
        let spec = body.layers[k];
        let weights: Vec<f32> = match layer.dtype {
            LayerDtype::F32 => {
                words(&values, layer.weights, layer.inputs * layer.outputs)?.to_vec()
            }
            LayerDtype::Int8 => {
                int8 = true;
                dequantised(view, &values, k, layer)?
            }
        };
        let w = format!("layer{k}.weight");
        let b = format!("layer{k}.bias");
        g.constant(&w, &[layer.inputs, layer.outputs], &weights);
        g.constant(
            &b,
            &[layer.outputs],
            words(&values, layer.biases, layer.outputs)?,
        );
        x = g.node("Gemm", &format!("layer{k}"), &[&x, &w, &b]);
        let act = match spec.activation {
            Activation::Relu => Some("Relu"),
            Activation::Tanh => Some("Tanh"),
            Activation::Linear => None,
        };
        if let Some(op) = act {
            x = g.node(op, &format!("layer{k}.{}", op.to_lowercase()), &[&x]);
        }
    }

    let joints = &body.action;
    let act_dim = joints.len();
    g.constant(
        "action_scale",
        &[act_dim],
        &joints.iter().map(|j| j.scale).collect::<Vec<_>>(),
    );
    g.constant(
        "action_min",
        &[act_dim],
        &joints.iter().map(|j| j.min).collect::<Vec<_>>(),
    );
    g.constant(
        "action_max",
        &[act_dim],
        &joints.iter().map(|j| j.max).collect::<Vec<_>>(),
    );
    x = g.node("Mul", "action_scale_mul", &[&x, "action_scale"]);
    x = g.node("Max", "action_lower_limit", &[&x, "action_min"]);
    let last = g.nodes.len();
    g.node("Min", "action_upper_limit", &[&x, "action_max"]);
    g.nodes[last].output = vec![OUTPUT.to_owned()];

    let channels: Vec<String> = body
        .observation
        .iter()
        .flat_map(|f| (0..f.size).map(move |i| format!("{}[{i}]", f.name)))
        .collect();
    let joint_names: Vec<&str> = joints.iter().map(|j| j.name).collect();
    let graph = GraphProto {
        node: g.nodes,
        name: format!("dexstack {} policy", body.task.name()),
        initializer: g.initializers,
        doc_string: String::new(),
        input: vec![value_info(
            INPUT,
            obs_dim,
            format!(
                "observation, {obs_dim} values in this order: {}",
                channels.join(", ")
            ),
        )],
        output: vec![value_info(
            OUTPUT,
            act_dim,
            format!(
                "joint commands before the controller's safety envelope, in this order: {}",
                joint_names.join(", ")
            ),
        )],
        value_info: vec![],
    };
    Ok(ModelProto {
        ir_version: IR_VERSION,
        opset_import: vec![OperatorSetIdProto {
            domain: String::new(),
            version: OPSET,
        }],
        producer_name: "dex-policy-tool".to_owned(),
        producer_version: env!("CARGO_PKG_VERSION").to_owned(),
        domain: String::new(),
        model_version: i64::from(view.header().version),
        doc_string: format!(
            "{} policy exported from a .dxpl file (crc32 {:#010x}): observation -> normalisation -> \
             MLP -> joint commands",
            body.task.name(),
            view.header().crc
        ),
        graph: Some(graph),
        metadata_props: metadata(view, &channels, int8),
    })
}

/// `len` stored values from index `start` (a decoded file has them all; anything else is a
/// malformed body).
fn words(values: &[f32], start: usize, len: usize) -> Result<&[f32], OnnxError> {
    values
        .get(start..start + len)
        .ok_or(OnnxError::Format(dex_policy::FormatError::MalformedBody))
}

/// The f32 weights (input-major) of int8 layer `k`: `w[i][j] = q[j][i] * scale[j]`.
fn dequantised(
    view: &PolicyView<'_>,
    values: &[f32],
    k: usize,
    layer: dex_policy::LayerLayout,
) -> Result<Vec<f32>, OnnxError> {
    let malformed = OnnxError::Format(dex_policy::FormatError::MalformedBody);
    let q = view.int8_weights(k).ok_or(malformed)?;
    let scales = words(values, layer.scales.unwrap_or(usize::MAX), layer.outputs)?;
    let mut w = vec![0.0f32; layer.inputs * layer.outputs];
    for (j, s) in scales.iter().enumerate() {
        for i in 0..layer.inputs {
            let byte = dex_policy::int8::byte_index(layer.inputs, i, j);
            let qv = q
                .get(byte)
                .ok_or(OnnxError::Format(dex_policy::FormatError::MalformedBody))?;
            w[i * layer.outputs + j] = f32::from(*qv) * s;
        }
    }
    Ok(w)
}

/// The model's `dexstack.*` metadata: everything of the file's body that is not a number of
/// the network, so that [`crate::onnx_import`] can rebuild the same file.
fn metadata(view: &PolicyView<'_>, channels: &[String], int8: bool) -> Vec<StringStringEntryProto> {
    let body = view.body();
    let p = &body.provenance;
    let mut props = vec![
        ("format_version", view.header().version.to_string()),
        ("task", body.task.name().to_owned()),
        (
            "observation",
            body.observation
                .iter()
                .map(|f| format!("{}:{}", f.name, f.size))
                .collect::<Vec<_>>()
                .join(","),
        ),
        ("observation_channels", channels.join(",")),
        ("obs_clip", body.obs_clip.to_string()),
        (
            "action",
            body.action
                .iter()
                .map(|j| format!("{}:{}:{}:{}", j.name, j.scale, j.min, j.max))
                .collect::<Vec<_>>()
                .join(","),
        ),
        ("control_period_us", body.control_period_us.to_string()),
        ("crc32", format!("{:#010x}", view.header().crc)),
        (
            "layout_hash",
            format!("{:#010x}", view.header().layout_hash),
        ),
        ("trainer_version", p.trainer_version.to_owned()),
        ("seed", p.seed.to_string()),
        ("transitions", p.transitions.to_string()),
        ("eval_episodes", p.eval_episodes.to_string()),
    ];
    if let Some(rate) = p.success_rate {
        props.push(("success_rate", rate.to_string()));
    }
    if int8 {
        props.push((
            "weights",
            "int8 layers exported as their dequantised f32 twin (w = q * scale); the runtime's \
             int8 kernel also rounds each layer's inputs to 16 bits"
                .to_owned(),
        ));
    }
    props
        .into_iter()
        .map(|(k, v)| StringStringEntryProto {
            key: format!("{META_PREFIX}{k}"),
            value: v,
        })
        .collect()
}

fn value_info(name: &str, width: usize, doc: String) -> ValueInfoProto {
    ValueInfoProto {
        name: name.to_owned(),
        r#type: Some(TypeProto {
            tensor_type: Some(TypeProtoTensor {
                elem_type: DATA_TYPE_FLOAT,
                shape: Some(TensorShapeProto {
                    dim: vec![
                        TensorShapeDimension {
                            dim_value: None,
                            dim_param: Some("batch".to_owned()),
                        },
                        TensorShapeDimension {
                            dim_value: Some(width as i64),
                            dim_param: None,
                        },
                    ],
                }),
            }),
            denotation: String::new(),
        }),
        doc_string: doc,
    }
}

/// Nodes and initializers under construction.
#[derive(Default)]
struct Graph {
    nodes: Vec<NodeProto>,
    initializers: Vec<TensorProto>,
}

impl Graph {
    /// An f32 initializer (`raw_data`, little-endian: the file's bits).
    fn constant(&mut self, name: &str, dims: &[usize], data: &[f32]) {
        self.initializers.push(TensorProto {
            dims: dims.iter().map(|&d| d as i64).collect(),
            data_type: DATA_TYPE_FLOAT,
            name: name.to_owned(),
            raw_data: data.iter().flat_map(|v| v.to_le_bytes()).collect(),
            ..TensorProto::default()
        });
    }

    /// Appends a node whose one output is named after the node; returns that name.
    fn node(&mut self, op: &str, name: &str, inputs: &[&str]) -> String {
        let out = format!("{name}.out");
        self.nodes.push(NodeProto {
            input: inputs.iter().map(|s| (*s).to_owned()).collect(),
            output: vec![out.clone()],
            name: name.to_owned(),
            op_type: op.to_owned(),
            ..NodeProto::default()
        });
        out
    }
}
