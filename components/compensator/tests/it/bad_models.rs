//! Bad model files give the documented, typed errors naming the file and the problem.

use crate::common;
use bowden_compensator::{LoadOptions, Model, ModelError};
use prost::Message;
use tract_onnx::pb;

fn fixture_proto(name: &str) -> pb::ModelProto {
    pb::ModelProto::decode(&*std::fs::read(common::fixture(name)).unwrap()).unwrap()
}

fn load_bytes(bytes: &[u8], name: &str) -> Result<Model, ModelError> {
    // Through a real file, as the compensator loads them.
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join(name);
    std::fs::write(&p, bytes).unwrap();
    let r = Model::load_with(&p, &LoadOptions::default());
    if let Err(e) = &r {
        let msg = e.to_string();
        assert!(msg.contains(name), "error must name the file: {msg}");
    }
    r
}

fn load_proto(p: &pb::ModelProto, name: &str) -> Result<Model, ModelError> {
    load_bytes(&p.encode_to_vec(), name)
}

const TCN: &str = "tcn-linear2_forward_L80_J5_s0";

#[test]
fn truncated_and_garbage_files_are_corrupt() {
    let bytes = std::fs::read(common::fixture(TCN)).unwrap();
    for cut in [bytes.len() / 3, bytes.len() / 2, bytes.len() - 7] {
        let e = load_bytes(&bytes[..cut], "truncated.onnx").unwrap_err();
        assert_eq!(e.kind(), "corrupt", "cut at {cut}: {e}");
        assert!(e.to_string().contains("corrupt or truncated"), "{e}");
    }
    // Deterministic garbage (an LCG), and a text file.
    let mut x = 12345u32;
    let garbage: Vec<u8> = (0..4096)
        .map(|_| {
            x = x.wrapping_mul(1_103_515_245).wrapping_add(12345);
            (x >> 16) as u8
        })
        .collect();
    assert_eq!(load_bytes(&garbage, "garbage.onnx").unwrap_err().kind(), "corrupt");
    let e = load_bytes(b"this is not an onnx file\n", "text.onnx").unwrap_err();
    assert!(matches!(e.kind(), "corrupt" | "no-graph"), "{e}");
    let e = Model::load("/nonexistent/model.onnx").unwrap_err();
    assert_eq!(e.kind(), "io");
    assert!(e.to_string().contains("/nonexistent/model.onnx"));
}

#[test]
fn missing_or_bad_metadata() {
    for key in ["direction", "seq_len", "joints", "architecture", "units", "tcn_block"] {
        let mut p = fixture_proto(TCN);
        p.metadata_props.retain(|m| m.key != key);
        let e = load_proto(&p, "nometa.onnx").unwrap_err();
        assert_eq!(e.kind(), "metadata", "{key}: {e}");
        assert!(e.to_string().contains(key) && e.to_string().contains("missing"), "{e}");
    }
    let mut p = fixture_proto(TCN);
    p.metadata_props
        .iter_mut()
        .find(|m| m.key == "direction")
        .unwrap()
        .value = "sideways".into();
    let e = load_proto(&p, "badmeta.onnx").unwrap_err();
    assert!(
        e.to_string().contains("sideways") && e.to_string().contains("forward"),
        "{e}"
    );
    // FNN and LSTM need no tcn_block.
    let mut p = fixture_proto("fnn_forward_L80_J5_s0");
    p.metadata_props.retain(|m| m.key != "tcn_block");
    load_proto(&p, "fnn.onnx").unwrap();
}

#[test]
fn metadata_that_contradicts_the_graph() {
    // A relu-linear TCN declared relu-relu.
    let mut p = fixture_proto(TCN);
    p.metadata_props
        .iter_mut()
        .find(|m| m.key == "tcn_block")
        .unwrap()
        .value = "relu-relu".into();
    let e = load_proto(&p, "liar.onnx").unwrap_err();
    assert_eq!(e.kind(), "metadata-mismatch", "{e}");
    assert!(e.to_string().contains("relu-linear"), "{e}");
    // An FNN declared an LSTM.
    let mut p = fixture_proto("fnn_forward_L80_J5_s0");
    p.metadata_props
        .iter_mut()
        .find(|m| m.key == "architecture")
        .unwrap()
        .value = "lstm".into();
    assert_eq!(load_proto(&p, "liar2.onnx").unwrap_err().kind(), "metadata-mismatch");
    // seq_len that disagrees with the input shape.
    let mut p = fixture_proto(TCN);
    p.metadata_props.iter_mut().find(|m| m.key == "seq_len").unwrap().value = "60".into();
    let e = load_proto(&p, "seqlen.onnx").unwrap_err();
    assert_eq!(e.kind(), "interface", "{e}");
    assert!(
        e.to_string().contains("seq_len = 60") && e.to_string().contains("[1, 60, 5]"),
        "{e}"
    );
}

#[test]
fn wrong_shape_or_names() {
    use pb::tensor_shape_proto::dimension::Value;
    // Input [1, 80, 4] (with joints = 5 in the metadata).
    let mut p = fixture_proto(TCN);
    let g = p.graph.as_mut().unwrap();
    if let Some(pb::type_proto::Value::TensorType(t)) = g.input[0].r#type.as_mut().unwrap().value.as_mut() {
        t.shape.as_mut().unwrap().dim[2].value = Some(Value::DimValue(4));
    }
    let e = load_proto(&p, "shape.onnx").unwrap_err();
    assert_eq!(e.kind(), "interface", "{e}");
    assert!(
        e.to_string().contains("[1, 80, 4]") && e.to_string().contains("q_seq_deg"),
        "{e}"
    );
    // A renamed input.
    let mut p = fixture_proto(TCN);
    let g = p.graph.as_mut().unwrap();
    let old = g.input[0].name.clone();
    g.input[0].name = "x".into();
    for n in &mut g.node {
        for i in &mut n.input {
            if *i == old {
                *i = "x".into();
            }
        }
    }
    let e = load_proto(&p, "names.onnx").unwrap_err();
    assert!(e.kind() == "interface" && e.to_string().contains("q_seq_deg"), "{e}");
    // Output [1, 5] declared but the graph computes [1, 80, 5]: drop the final Gather.
    let mut p = fixture_proto(TCN);
    let g = p.graph.as_mut().unwrap();
    let gather = g.node.iter().position(|n| n.op_type == "Gather").unwrap();
    let src = g.node[gather].input[0].clone();
    let dst = g.node[gather].output[0].clone();
    g.node.remove(gather);
    for n in &mut g.node {
        for i in &mut n.input {
            if *i == dst {
                *i = src.clone();
            }
        }
    }
    let e = load_proto(&p, "outshape.onnx").unwrap_err();
    assert!(matches!(e.kind(), "interface" | "tract"), "{e}");
}

#[test]
fn nan_weight_is_named() {
    let mut p = fixture_proto(TCN);
    let g = p.graph.as_mut().unwrap();
    let t = g
        .initializer
        .iter_mut()
        .find(|t| t.name == "core.blocks.2.c1.weight")
        .unwrap();
    t.raw_data[4 * 7..4 * 8].copy_from_slice(&f32::NAN.to_le_bytes());
    let e = load_proto(&p, "nan.onnx").unwrap_err();
    assert_eq!(e.kind(), "non-finite-weight", "{e}");
    let s = e.to_string();
    assert!(
        s.contains("core.blocks.2.c1.weight") && s.contains("element 7") && s.contains("NaN"),
        "{s}"
    );
    // Infinity in a normalisation constant too.
    let mut p = fixture_proto(TCN);
    let t = p
        .graph
        .as_mut()
        .unwrap()
        .initializer
        .iter_mut()
        .find(|t| t.name == "sd_in")
        .unwrap();
    t.raw_data[0..4].copy_from_slice(&f32::INFINITY.to_le_bytes());
    let e = load_proto(&p, "inf.onnx").unwrap_err();
    assert!(e.to_string().contains("sd_in") && e.to_string().contains("inf"), "{e}");
}

#[test]
fn unrecognised_graph_falls_back_to_tract() {
    // Replace the first ReLU by a Sigmoid: still a contract-following model, but not one the
    // incremental evaluator knows. It must load, run through tract, and say why.
    let mut p = fixture_proto(TCN);
    let g = p.graph.as_mut().unwrap();
    g.node.iter_mut().find(|n| n.op_type == "Relu").unwrap().op_type = "Sigmoid".into();
    let m = load_proto(&p, "sigmoid.onnx").unwrap();
    assert!(!m.is_incremental());
    assert!(
        m.unrecognised_reason().unwrap().contains("Sigmoid"),
        "{:?}",
        m.unrecognised_reason()
    );
    let y = m.eval_full(&[1.0; 400]).unwrap();
    assert!(y.iter().all(|v| v.is_finite()));
}

#[test]
fn non_causal_convolution_is_not_run_incrementally() {
    // Symmetric padding without the chomp: column t sees the future, so the prefix/trial split
    // would be wrong. Make conv 0 pad both sides by removing its causal pad and setting
    // pads = [1, 1] (same length output): the recogniser must refuse, tract still runs it.
    let mut p = fixture_proto(TCN);
    let g = p.graph.as_mut().unwrap();
    let ci = g.node.iter().position(|n| n.op_type == "Conv").unwrap();
    let pad_out = g.node[ci].input[0].clone();
    let pad = g.node.iter().find(|n| n.output[0] == pad_out).unwrap();
    assert_eq!(pad.op_type, "Pad");
    let pad_in = pad.input[0].clone();
    let conv = &mut g.node[ci];
    conv.input[0] = pad_in;
    conv.attribute.iter_mut().find(|a| a.name == "pads").unwrap().ints = vec![1, 1];
    let m = load_proto(&p, "noncausal.onnx").unwrap();
    assert!(!m.is_incremental(), "a non-causal conv must not be recognised");
    assert!(
        m.unrecognised_reason().unwrap().contains("causal"),
        "{:?}",
        m.unrecognised_reason()
    );
}

#[test]
fn incremental_that_disagrees_with_tract_is_refused() {
    // The fixtures agree with tract to ~1e-5 deg; demanding 1e-9 (and nothing relative) must
    // refuse them, naming the file, the difference and the tolerance.
    let opts = LoadOptions {
        tolerance_deg: 1e-9,
        relative: 0.0,
        ..LoadOptions::default()
    };
    let e = Model::load_with(common::fixture(TCN), &opts).unwrap_err();
    assert_eq!(e.kind(), "incremental-mismatch", "{e}");
    let s = e.to_string();
    assert!(s.contains(TCN) && s.contains("refusing") && s.contains("1.0e-9"), "{s}");
}

/// The load check's bound follows the outputs' scale (#42 item 4): f32 rounding in tract grows
/// with the size of the numbers, so a model with large outputs that is refused by a tight
/// absolute bound loads under the relative one, and a relative bound too tight for f32 is
/// refused like an absolute one.
#[test]
fn the_load_check_bound_is_relative_to_the_outputs_scale() {
    let tight_abs = LoadOptions {
        tolerance_deg: 1e-9,
        relative: 0.0,
        ..LoadOptions::default()
    };
    let diff = match Model::load_with(common::fixture(TCN), &tight_abs) {
        Err(bowden_compensator::ModelError::IncrementalMismatch {
            max_abs_diff_deg,
            scale_deg,
            ..
        }) => {
            assert!(scale_deg > 1.0, "outputs of degrees: {scale_deg}");
            (max_abs_diff_deg, scale_deg)
        }
        other => panic!("{:?}", other.err()),
    };
    // Relative: 4× the observed difference over the scale passes, a quarter of it fails.
    let rel_ok = 4.0 * diff.0 / diff.1;
    let m = Model::load_with(
        common::fixture(TCN),
        &LoadOptions {
            relative: rel_ok,
            ..tight_abs.clone()
        },
    )
    .expect("inside the relative bound");
    assert!(m.load_check_max_abs_diff_deg().unwrap() <= rel_ok * diff.1);
    let e = Model::load_with(
        common::fixture(TCN),
        &LoadOptions {
            relative: diff.0 / diff.1 / 4.0,
            ..tight_abs
        },
    )
    .unwrap_err();
    assert_eq!(e.kind(), "incremental-mismatch");
    // The default bound accepts every shipped fixture.
    for f in [
        "fnn_forward_L80_J5_s0",
        "lstm_forward_L80_J5_s0",
        TCN,
        "tcn-linear2_inverse_L80_J5_s0",
        "tcn-lstm_forward_L80_J5_s0",
        "tcn_forward_L80_J5_s0",
    ] {
        Model::load_with(common::fixture(f), &LoadOptions::default()).unwrap_or_else(|e| panic!("{f}: {e}"));
    }
}
