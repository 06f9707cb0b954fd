//! Shared helpers of the compensator's integration tests.
#![allow(dead_code)]

use bowden_compensator::{LoadOptions, Model, ModelError};
use prost::Message;
use std::path::PathBuf;
use tract_onnx::pb;

/// `tests/fixtures/pytorch/` of the repository (copied from ../shared so tests are
/// self-contained).
pub fn fixture_dir() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../tests/fixtures/pytorch")
}

pub fn fixture(name: &str) -> PathBuf {
    fixture_dir().join(format!("{name}.onnx"))
}

pub const ALL: [&str; 8] = [
    "tcn_forward_L80_J5_s0",
    "tcn_inverse_L80_J5_s0",
    "tcn-linear2_forward_L80_J5_s0",
    "tcn-linear2_inverse_L80_J5_s0",
    "fnn_forward_L80_J5_s0",
    "lstm_forward_L80_J5_s0",
    "tcn-lstm_forward_L80_J5_s0",
    "tcn-lstm-linear2_forward_L80_J5_s0",
];

/// PyTorch's input window (L·J, oldest first) and output for a fixture.
pub fn pytorch_io(name: &str) -> (Vec<f32>, Vec<f32>) {
    let text = std::fs::read_to_string(fixture_dir().join(format!("{name}.json"))).unwrap();
    let v: serde_json::Value = serde_json::from_str(&text).unwrap();
    let flat = |x: &serde_json::Value| -> Vec<f32> {
        let mut out = Vec::new();
        fn rec(x: &serde_json::Value, out: &mut Vec<f32>) {
            match x {
                serde_json::Value::Array(a) => a.iter().for_each(|y| rec(y, out)),
                serde_json::Value::Number(n) => out.push(n.as_f64().unwrap() as f32),
                _ => panic!("unexpected json"),
            }
        }
        rec(x, &mut out);
        out
    };
    (flat(&v["input_q_seq_deg"]), flat(&v["output_q_deg"]))
}

/// A fixture with metadata props added (as `bowden train` writes the support).
pub fn with_props(name: &str, props: &[(&str, &str)]) -> Result<Model, ModelError> {
    let bytes = std::fs::read(fixture(name)).unwrap();
    let mut proto = pb::ModelProto::decode(bytes.as_slice()).unwrap();
    for (k, v) in props {
        proto.metadata_props.push(pb::StringStringEntryProto {
            key: k.to_string(),
            value: v.to_string(),
        });
    }
    Model::from_bytes(
        &proto.encode_to_vec(),
        &format!("{name}+support"),
        None,
        &LoadOptions::default(),
    )
}

/// The support a `with_support` fixture claims: commands within ±RANGE, steps ≤ STEP, gaps ≤ GAP.
pub const RANGE: f64 = 25.0;
pub const STEP: f64 = 4.0;
pub const GAP: f64 = 6.0;

pub fn supported(name: &str) -> Model {
    let five = |v: f64| vec![format!("{v}"); 5].join(",");
    let (lo, hi, step, gap) = (five(-RANGE), five(RANGE), five(STEP), five(GAP));
    with_props(
        name,
        &[
            ("support_cmd_min_deg", &lo),
            ("support_cmd_max_deg", &hi),
            ("support_cmd_step_max_deg", &step),
            ("support_gap_max_deg", &gap),
        ],
    )
    .unwrap()
}
