//! Why a conversion between ONNX and a policy file failed.

/// Why an ONNX model could not be imported or a policy file exported.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum OnnxError {
    /// The bytes are not an ONNX model (protobuf decoding failed).
    #[error("not an ONNX model: {0}")]
    Decode(#[from] prost::DecodeError),
    /// The model has no graph.
    #[error("the ONNX model has no graph")]
    NoGraph,
    /// The graph does not have exactly one (non-initializer) input.
    #[error("the graph has {0} inputs; a policy takes one observation tensor")]
    Inputs(usize),
    /// The graph does not have exactly one output.
    #[error("the graph has {0} outputs; a policy gives one action tensor")]
    Outputs(usize),
    /// A node whose operator the runtime cannot run, or that sits where the importer cannot fold it.
    #[error("node {node:?} ({op}): {why}")]
    Unsupported {
        /// The node's name (or its first output's, when it has none).
        node: String,
        /// The node's operator, with its domain when not ONNX's.
        op: String,
        /// What is wrong.
        why: String,
    },
    /// A value is consumed by more than one node: the graph branches.
    #[error("value {0:?} feeds more than one node; a policy network is one chain of layers")]
    Branch(String),
    /// The chain of nodes from the input never reaches the graph's output.
    #[error("the chain of nodes from the input ends at {0:?}, not at the graph's output")]
    Disconnected(String),
    /// A tensor's type or storage is not one the importer reads.
    #[error("tensor {name:?}: {why}")]
    Tensor {
        /// Tensor name.
        name: String,
        /// What is wrong.
        why: String,
    },
    /// A weight, bias or constant is NaN or infinite.
    #[error("tensor {0:?} holds a NaN or infinite value")]
    NonFinite(String),
    /// The network's input width is not the layout's observation width.
    #[error("the network takes {got} inputs; the {task} layout has {expected} observation values")]
    InputWidth {
        /// Observation values of the layout.
        expected: usize,
        /// Inputs of the network.
        got: usize,
        /// Task of the layout.
        task: &'static str,
    },
    /// The network's output width is not the layout's action width.
    #[error("the network gives {got} outputs; the {task} layout has {expected} action joints")]
    OutputWidth {
        /// Action joints of the layout.
        expected: usize,
        /// Outputs of the network.
        got: usize,
        /// Task of the layout.
        task: &'static str,
    },
    /// The graph has no dense layer.
    #[error("the graph has no dense layer (Gemm or MatMul)")]
    NoLayer,
    /// More layers, or wider ones, than the policy format describes.
    #[error("the network has {0} layers or a layer wider than 65535; the format allows 8")]
    TooLarge(usize),
    /// Neither `--task` nor the model's metadata says which task the policy is for.
    #[error("no task: give one (reach, grasp, stack-in-hand, stack) or a layout file")]
    NoTask,
    /// The model's metadata names a task this toolkit does not know.
    #[error(
        "the model's metadata names the task {0:?}, which is not reach, grasp, stack-in-hand or stack"
    )]
    UnknownTask(String),
    /// The policy file (to export, or to take the layout from) is invalid.
    #[error("policy file: {0}")]
    Format(#[from] dex_policy::FormatError),
}
