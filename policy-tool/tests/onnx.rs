//! ONNX export and import: bit-exact round trips, int8 files as their dequantised twin, and every
//! refusal with its reason (onnxruntime's side is tests/test_onnx.py).
#![allow(clippy::unwrap_used, clippy::expect_used)] // tests may panic on failure

use dex_policy::{LayerDtype, PolicyView};
use dex_policy_tool::onnx_schema::{ModelProto, NodeProto, TensorProto, ValueInfoProto};
use dex_policy_tool::{
    ImportSettings, OnnxError, OutputUnits, export_onnx, import_onnx, onnx_model,
};
use prost::Message;

const ROOT: &str = env!("CARGO_MANIFEST_DIR");

fn read(path: &str) -> Vec<u8> {
    std::fs::read(format!("{ROOT}/../{path}")).unwrap()
}

fn cell() -> ImportSettings<'static> {
    ImportSettings::default()
}

#[test]
fn a_cell_policy_round_trips_byte_for_byte() {
    // The shipped Grasp clone takes the controller's task features too: its 58-wide input gives
    // the cell's layout followed by the feature fields.
    for path in ["runtime/tests/golden/jaco_64.dxpl", "policies/grasp.dxpl"] {
        let file = read(path);
        let onnx = export_onnx(&file).unwrap();
        let back = import_onnx(&onnx, &cell()).unwrap();
        assert_eq!(back.outputs, OutputUnits::Physical);
        assert_eq!(back.file, file, "{path}");
    }
}

#[test]
fn another_layout_round_trips_with_its_layout_file_and_is_refused_without() {
    let file = read("policy-format/tests/golden/small.dxpl");
    let onnx = export_onnx(&file).unwrap();
    let err = import_onnx(&onnx, &cell()).unwrap_err();
    assert!(
        matches!(
            err,
            OnnxError::InputWidth {
                expected: 44,
                got: 5,
                ..
            }
        ),
        "{err}"
    );
    let view = PolicyView::decode(&file).unwrap();
    let settings = ImportSettings {
        task: None,
        layout: Some(&view),
    };
    assert_eq!(import_onnx(&onnx, &settings).unwrap().file, file);
}

#[test]
fn an_int8_file_exports_as_its_dequantised_twin() {
    let file = read("policy-format/tests/golden/small_int8.dxpl");
    let view = PolicyView::decode(&file).unwrap();
    let model = onnx_model(&view).unwrap();
    let meta: Vec<_> = model
        .metadata_props
        .iter()
        .map(|p| p.key.as_str())
        .collect();
    assert!(meta.contains(&"dexstack.weights"));
    let back = import_onnx(
        &model.encode_to_vec(),
        &ImportSettings {
            task: None,
            layout: Some(&view),
        },
    )
    .unwrap();
    let f32_view = PolicyView::decode(&back.file).unwrap();
    let values: Vec<f32> = f32_view.values().iter().collect();
    let source: Vec<f32> = view.values().iter().collect();
    let mut int8_layers = 0;
    for (k, (q, f)) in view.layers().zip(f32_view.layers()).enumerate() {
        assert_eq!(f.dtype, LayerDtype::F32);
        if q.dtype != LayerDtype::Int8 {
            continue;
        }
        int8_layers += 1;
        let packed = view.int8_weights(k).unwrap();
        for i in 0..q.inputs {
            for j in 0..q.outputs {
                let qv = packed[dex_policy::int8::byte_index(q.inputs, i, j)];
                let scale = source[q.scales.unwrap() + j];
                assert_eq!(values[f.weights + i * f.outputs + j], f32::from(qv) * scale);
            }
        }
    }
    assert!(int8_layers > 0, "the golden has int8 layers to compare");
}

/// The exported model of the Jaco golden, to be broken in one way per test.
fn model() -> ModelProto {
    let file = read("runtime/tests/golden/jaco_64.dxpl");
    ModelProto::decode(export_onnx(&file).unwrap().as_slice()).unwrap()
}

fn refused(model: &ModelProto) -> OnnxError {
    import_onnx(&model.encode_to_vec(), &cell()).unwrap_err()
}

#[test]
fn an_unknown_operator_is_named_with_its_node() {
    let mut m = model();
    let g = m.graph.as_mut().unwrap();
    let relu = g.node.iter_mut().find(|n| n.op_type == "Relu").unwrap();
    relu.op_type = "Sigmoid".to_owned();
    let name = relu.name.clone();
    let err = refused(&m);
    let OnnxError::Unsupported { node, op, .. } = &err else {
        panic!("{err}")
    };
    assert_eq!((node.as_str(), op.as_str()), (name.as_str(), "Sigmoid"));
}

#[test]
fn two_outputs_a_branch_and_a_broken_chain_are_refused() {
    let mut m = model();
    let g = m.graph.as_mut().unwrap();
    g.output.push(ValueInfoProto {
        name: "layer0.out".to_owned(),
        ..ValueInfoProto::default()
    });
    assert!(matches!(refused(&m), OnnxError::Outputs(2)));

    let mut m = model();
    let g = m.graph.as_mut().unwrap();
    g.node.push(NodeProto {
        input: vec!["layer0.out".to_owned()],
        output: vec!["side".to_owned()],
        name: "side_branch".to_owned(),
        op_type: "Relu".to_owned(),
        ..NodeProto::default()
    });
    assert!(matches!(refused(&m), OnnxError::Branch(v) if v == "layer0.out"));

    let mut m = model();
    let g = m.graph.as_mut().unwrap();
    g.node.retain(|n| n.name != "layer1");
    assert!(matches!(refused(&m), OnnxError::Disconnected(_)));
}

#[test]
fn non_finite_weights_and_external_data_are_refused() {
    let mut m = model();
    let g = m.graph.as_mut().unwrap();
    let w = g
        .initializer
        .iter_mut()
        .find(|t| t.name == "layer1.weight")
        .unwrap();
    w.raw_data[8..12].copy_from_slice(&f32::NAN.to_le_bytes());
    assert!(matches!(refused(&m), OnnxError::NonFinite(n) if n == "layer1.weight"));

    let mut m = model();
    let g = m.graph.as_mut().unwrap();
    let w: &mut TensorProto = g
        .initializer
        .iter_mut()
        .find(|t| t.name == "layer0.weight")
        .unwrap();
    w.raw_data.clear();
    w.data_location = 1;
    assert!(matches!(refused(&m), OnnxError::Tensor { name, .. } if name == "layer0.weight"));

    assert!(matches!(
        import_onnx(b"\x08\x07not a model", &cell()).unwrap_err(),
        OnnxError::Decode(_)
    ));
}

#[test]
fn a_negative_normalisation_scale_and_an_asymmetric_clip_are_refused() {
    let mut m = model();
    let g = m.graph.as_mut().unwrap();
    let s = g
        .initializer
        .iter_mut()
        .find(|t| t.name == "obs_scale")
        .unwrap();
    s.raw_data[0..4].copy_from_slice(&(-1.0f32).to_le_bytes());
    let err = refused(&m);
    assert!(err.to_string().contains("must be positive"), "{err}");

    let mut m = model();
    let g = m.graph.as_mut().unwrap();
    let lo = g
        .initializer
        .iter_mut()
        .find(|t| t.name == "obs_clip_min")
        .unwrap();
    lo.raw_data = (-1.0f32).to_le_bytes().to_vec();
    let err = refused(&m);
    assert!(err.to_string().contains("symmetric"), "{err}");
}

#[test]
fn the_task_comes_from_the_flag_then_the_metadata() {
    let file = read("runtime/tests/golden/jaco_64.dxpl");
    let onnx = export_onnx(&file).unwrap();
    let task = PolicyView::decode(&file).unwrap().body().task;
    assert_eq!(import_onnx(&onnx, &cell()).unwrap().task, task);
    let other = ImportSettings {
        task: Some(dex_policy::Task::Reach),
        layout: None,
    };
    assert_eq!(
        import_onnx(&onnx, &other).unwrap().task,
        dex_policy::Task::Reach
    );
    let mut m = ModelProto::decode(onnx.as_slice()).unwrap();
    m.metadata_props.clear();
    assert!(matches!(refused(&m), OnnxError::NoTask));
}
