//! Shared helpers of the compensator's integration tests.
#![allow(dead_code)]

use std::path::PathBuf;

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
