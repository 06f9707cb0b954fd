//! The kernels' reference: outputs, loss and gradients computed by candle's autograd (an
//! independent implementation of the four architectures, `bowden_learning::candle_ref`) for a
//! fixed set of models, batches and seeds, stored in `tests/data/candle/` so the default test
//! build does not compile candle (≈ 500 s of CPU, a fifth of a cold CI). `kernels_vs_candle`
//! (with `--features candle`) compares with candle directly and rewrites the files:
//!
//! ```text
//! cargo test -p bowden-learning --features candle -- --ignored write_candle_references
//! ```
//!
//! One file per case, `<name>.npy`, f32 (what candle computes in), one row: `[loss, out (b·J), grad (P), conv1d out
//! (b·J, TCN models only: candle's own conv1d op)]`.

use bowden_learning::arch::{Architecture, ModelSpec, TcnBlock};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use std::path::PathBuf;

/// A model, batch and seed the kernels are held to.
#[derive(Debug, Clone, Copy)]
pub struct Case {
    pub name: &'static str,
    pub spec: ModelSpec,
    pub b: usize,
    pub seed: u64,
}

pub fn cases() -> Vec<Case> {
    use Architecture::*;
    use TcnBlock::*;
    let c = |name, arch, l, j, block, b, seed| Case {
        name,
        spec: ModelSpec::new(arch, l, j, block),
        b,
        seed,
    };
    vec![
        c("tcn_relu_linear", Tcn, 20, 5, ReluLinear, 6, 1),
        c("tcn_relu_relu", Tcn, 20, 5, ReluRelu, 6, 2),
        c("tcn_paper_length", Tcn, 80, 5, ReluLinear, 3, 3),
        c("lstm", Lstm, 12, 5, ReluLinear, 5, 4),
        c("tcn_lstm_relu_relu", TcnLstm, 12, 5, ReluRelu, 4, 5),
        c("tcn_lstm_3_joints", TcnLstm, 10, 3, ReluLinear, 3, 6),
        c("fnn", Fnn, 16, 5, ReluLinear, 7, 7),
        // A da Vinci wrist has 3 cable-driven joints: nothing assumes J = 5.
        c("tcn_3_joints", Tcn, 33, 3, ReluLinear, 5, 8),
        c("lstm_3_joints", Lstm, 7, 3, ReluLinear, 9, 9),
        // The portable kernels' cases (tests/it/portable.rs).
        c("portable_tcn", Tcn, 20, 5, ReluRelu, 4, 21),
        c("portable_lstm", Lstm, 9, 5, ReluLinear, 4, 21),
        c("portable_tcn_lstm", TcnLstm, 9, 4, ReluLinear, 4, 21),
        c("portable_fnn", Fnn, 12, 5, ReluLinear, 4, 21),
    ]
}

pub fn case(name: &str) -> Case {
    cases().into_iter().find(|c| c.name == name).expect("a known case")
}

fn random(n: usize, scale: f32, rng: &mut ChaCha8Rng) -> Vec<f32> {
    (0..n).map(|_| rng.random_range(-scale..scale)).collect()
}

/// The case's parameters, inputs and targets (deterministic in its seed).
pub fn inputs(c: &Case) -> (Vec<f32>, Vec<f32>, Vec<f32>) {
    let mut rng = ChaCha8Rng::seed_from_u64(c.seed);
    let params = c.spec.init_params(c.seed);
    let x = random(c.b * c.spec.seq_len * c.spec.joints, 1.5, &mut rng);
    let y = random(c.b * c.spec.joints, 1.0, &mut rng);
    (params, x, y)
}

/// What candle computed for a case.
#[derive(Debug, Clone, PartialEq)]
pub struct Reference {
    pub loss: f64,
    pub out: Vec<f32>,
    pub grad: Vec<f32>,
    /// TCN models: the forward pass through candle's own conv1d op.
    pub conv1d_out: Option<Vec<f32>>,
}

pub fn path(c: &Case) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join(format!("tests/data/candle/{}.npy", c.name))
}

pub fn load(c: &Case) -> Reference {
    let p = path(c);
    let m = bowden_learning::npy::read_npy(&p).unwrap_or_else(|e| {
        panic!("{e}: regenerate with `cargo test -p bowden-learning --features candle -- --ignored write_candle_references`")
    });
    let n_out = c.b * c.spec.joints;
    let n_grad = c.spec.param_count();
    let tcn = c.spec.arch.has_tcn();
    let want = 1 + n_out + n_grad + if tcn { n_out } else { 0 };
    assert_eq!(
        m.data.len(),
        want,
        "{}: {} values, expected {want}",
        p.display(),
        m.data.len()
    );
    let f = |r: std::ops::Range<usize>| m.data[r].iter().map(|&v| v as f32).collect::<Vec<f32>>();
    Reference {
        loss: m.data[0],
        out: f(1..1 + n_out),
        grad: f(1 + n_out..1 + n_out + n_grad),
        conv1d_out: tcn.then(|| f(1 + n_out + n_grad..want)),
    }
}

#[cfg(feature = "candle")]
pub fn store(c: &Case, r: &Reference) {
    let mut row = vec![r.loss as f32];
    row.extend(&r.out);
    row.extend(&r.grad);
    if let Some(o) = &r.conv1d_out {
        row.extend(o);
    }
    let p = path(c);
    std::fs::create_dir_all(p.parent().unwrap()).unwrap();
    bowden_learning::npy::write_npy_f32(&p, 1, row.len(), &row).unwrap();
}
