//! ONNX: export → tract → same outputs as the trained model (≤ 1e-4 deg), for every
//! architecture; the PyTorch fixtures load into the fused kernels and reproduce PyTorch's
//! numbers; our TCN file follows the fixtures' contract.

use std::path::PathBuf;

use bowden_learning::arch::{Architecture, Direction, ModelSpec, TcnBlock};
use bowden_learning::onnx::{read_metadata, ModelFile, TractModel, INPUT_NAME, OUTPUT_NAME};
use bowden_learning::windows::Normaliser;
use prost::Message;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

fn fixtures_dir() -> PathBuf {
    if let Ok(p) = std::env::var("BOWDEN_FIXTURES") {
        return PathBuf::from(p);
    }
    // The copy in the repository (tests/fixtures/pytorch), so the tests are self-contained.
    let p = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../tests/fixtures/pytorch");
    assert!(
        p.join("tcn_forward_L80_J5_s0.onnx").exists(),
        "PyTorch fixtures not found at {} (set BOWDEN_FIXTURES)",
        p.display()
    );
    p
}

fn random_model(spec: ModelSpec, seed: u64) -> ModelFile {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let j = spec.joints;
    let norm = |rng: &mut ChaCha8Rng| Normaliser {
        // f32-representable, as the trainer's statistics are.
        mean: (0..j).map(|_| rng.random_range(-10.0f32..10.0) as f64).collect(),
        sd: (0..j).map(|_| rng.random_range(5.0f32..30.0) as f64).collect(),
    };
    ModelFile {
        spec,
        direction: Direction::Inverse,
        params: spec.init_params(seed),
        norm_in: norm(&mut rng),
        norm_out: norm(&mut rng),
        support: None,
    }
}

#[test]
fn export_round_trip_every_architecture() {
    let dir = tempfile::tempdir().unwrap();
    let cases = [
        ModelSpec::new(Architecture::Tcn, 80, 5, TcnBlock::ReluLinear),
        ModelSpec::new(Architecture::Tcn, 50, 5, TcnBlock::ReluRelu),
        ModelSpec::new(Architecture::Tcn, 10, 3, TcnBlock::ReluLinear),
        ModelSpec::new(Architecture::Lstm, 24, 5, TcnBlock::ReluLinear),
        ModelSpec::new(Architecture::TcnLstm, 24, 5, TcnBlock::ReluRelu),
        ModelSpec::new(Architecture::Fnn, 30, 5, TcnBlock::ReluLinear),
    ];
    let mut rng = ChaCha8Rng::seed_from_u64(99);
    for (i, spec) in cases.into_iter().enumerate() {
        let m = random_model(spec, i as u64);
        let path = dir.path().join(format!("m{i}.onnx"));
        m.save(&path).unwrap();
        // The file reads back to the same model.
        let back = ModelFile::load(&path).unwrap();
        assert!(back == m, "{spec:?}: the file does not read back to the same model");
        let tract = TractModel::load(&path, spec.seq_len, spec.joints).unwrap();
        let (l, j) = (spec.seq_len, spec.joints);
        let b = 4;
        let windows: Vec<f32> = (0..b * l * j).map(|_| rng.random_range(-60.0..60.0)).collect();
        let fused = m.predict_deg(&windows, b);
        let mut worst = 0.0f32;
        for r in 0..b {
            let out = tract.run(&windows[r * l * j..(r + 1) * l * j]).unwrap();
            assert_eq!(out.len(), j);
            for k in 0..j {
                worst = worst.max((out[k] - fused[r * j + k]).abs());
            }
        }
        assert!(worst <= 1e-4, "{:?}: tract vs fused differ by {worst} deg", spec);
    }
}

#[derive(serde::Deserialize)]
struct Fixture {
    input_q_seq_deg: Vec<Vec<Vec<f32>>>,
    output_q_deg: Vec<Vec<f32>>,
    params: usize,
}

#[test]
fn pytorch_fixtures_run_in_the_fused_kernels() {
    let dir = fixtures_dir();
    let mut seen = 0;
    for entry in std::fs::read_dir(&dir).unwrap() {
        let path = entry.unwrap().path();
        if path.extension().and_then(|e| e.to_str()) != Some("onnx") {
            continue;
        }
        let fx: Fixture = serde_json::from_str(&std::fs::read_to_string(path.with_extension("json")).unwrap()).unwrap();
        let m = ModelFile::load(&path).unwrap();
        assert_eq!(m.spec.param_count(), fx.params, "{}", path.display());
        let window: Vec<f32> = fx.input_q_seq_deg[0].iter().flatten().copied().collect();
        let ours = m.predict_deg(&window, 1);
        for (k, (a, b)) in ours.iter().zip(&fx.output_q_deg[0]).enumerate() {
            assert!(
                (a - b).abs() < 1e-4,
                "{}: joint {k}: fused {a} vs PyTorch {b}",
                path.display()
            );
        }
        // Re-exported by us, the same weights give the same numbers through tract.
        let tmp = tempfile::tempdir().unwrap();
        let re = tmp.path().join("re.onnx");
        m.save(&re).unwrap();
        let out = TractModel::load(&re, 80, 5).unwrap().run(&window).unwrap();
        for (a, b) in out.iter().zip(&fx.output_q_deg[0]) {
            assert!((a - b).abs() < 1e-4, "{}: re-export {a} vs PyTorch {b}", path.display());
        }
        seen += 1;
    }
    assert_eq!(seen, 8, "expected the 8 PyTorch fixtures in {}", dir.display());
}

fn io_of(path: &std::path::Path) -> (Vec<(String, Vec<i64>)>, Vec<String>) {
    let proto = tract_onnx::pb::ModelProto::decode(std::fs::read(path).unwrap().as_slice()).unwrap();
    let g = proto.graph.unwrap();
    let dims = |v: &tract_onnx::pb::ValueInfoProto| -> Vec<i64> {
        use tract_onnx::pb::{tensor_shape_proto::dimension::Value, type_proto};
        match v.r#type.as_ref().and_then(|t| t.value.as_ref()) {
            Some(type_proto::Value::TensorType(t)) => t
                .shape
                .as_ref()
                .map(|s| {
                    s.dim
                        .iter()
                        .map(|d| match &d.value {
                            Some(Value::DimValue(v)) => *v,
                            _ => -1,
                        })
                        .collect()
                })
                .unwrap_or_default(),
            None => vec![],
        }
    };
    (
        g.input.iter().map(|v| (v.name.clone(), dims(v))).collect(),
        g.output.iter().map(|v| v.name.clone()).collect(),
    )
}

#[test]
fn exported_tcn_follows_the_pytorch_contract() {
    let fixture = fixtures_dir().join("tcn-linear2_forward_L80_J5_s0.onnx");
    let tmp = tempfile::tempdir().unwrap();
    let ours = tmp.path().join("tcn.onnx");
    let mut m = random_model(ModelSpec::new(Architecture::Tcn, 80, 5, TcnBlock::ReluLinear), 5);
    m.direction = Direction::Forward;
    m.save(&ours).unwrap();

    let (fin, fout) = io_of(&fixture);
    let (oin, oout) = io_of(&ours);
    assert_eq!(fin, oin);
    assert_eq!(oin, vec![(INPUT_NAME.to_string(), vec![1, 80, 5])]);
    assert_eq!(fout, oout);
    assert_eq!(oout, vec![OUTPUT_NAME.to_string()]);

    let fmeta = read_metadata(&fixture).unwrap();
    let ometa = read_metadata(&ours).unwrap();
    for (k, v) in &fmeta {
        if k == "producer_note" {
            continue;
        }
        let mine = ometa.iter().find(|(ok, _)| ok == k).map(|(_, v)| v);
        assert_eq!(mine, Some(v), "metadata {k}");
    }
    // Both load through tract the same way and give a [1, 5] output for a [1, 80, 5] input.
    let w = vec![1.0f32; 400];
    assert_eq!(TractModel::load(&fixture, 80, 5).unwrap().run(&w).unwrap().len(), 5);
    assert_eq!(TractModel::load(&ours, 80, 5).unwrap().run(&w).unwrap().len(), 5);
}

#[test]
fn corrupt_onnx_gives_a_named_error() {
    let tmp = tempfile::tempdir().unwrap();
    let p = tmp.path().join("junk.onnx");
    std::fs::write(&p, b"\xff\xff\xff\xff not a protobuf").unwrap();
    let e = ModelFile::load(&p).unwrap_err();
    assert!(e.to_string().contains("junk.onnx"), "{e}");
    let m = random_model(ModelSpec::new(Architecture::Tcn, 20, 5, TcnBlock::ReluLinear), 1);
    let mut proto = m.to_proto();
    proto.metadata_props.retain(|p| p.key != "seq_len");
    std::fs::write(&p, proto.encode_to_vec()).unwrap();
    let e = ModelFile::load(&p).unwrap_err();
    assert!(e.to_string().contains("seq_len"), "{e}");
}
