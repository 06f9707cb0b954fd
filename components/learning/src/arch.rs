//! The paper's four architectures (§IV-C): what they are, their parameters and how they
//! start. Parameters live in one flat `f32` vector with a named layout whose names and
//! shapes are PyTorch's (`tcn.blocks.0.c1.weight` is `[J, J, 3]`, LSTM weights are
//! `[4H, in]` with gates in PyTorch's i, f, g, o order), so the optimiser, the gradient
//! reduction across threads and the ONNX export all see one plain array.

use rand::Rng;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

/// LSTM hidden size (paper: 128).
pub const LSTM_HIDDEN: usize = 128;
/// Hidden width of the LSTM's head (paper: "128 and 64 neurons": the LSTM's 128, then 64).
pub const HEAD_HIDDEN: usize = 64;
/// FNN hidden width (paper: 128, 128).
pub const FNN_HIDDEN: usize = 128;
/// TCN kernel size k and dilation base d (paper: 3 and 2).
pub const TCN_KERNEL: usize = 3;
pub const TCN_DILATION_BASE: usize = 2;

// The architectures, directions and TCN block variants are the model contract's: one
// definition for the writer (this crate) and the loader (the compensator).
pub use bowden_interfaces::model::{Architecture, Direction, TcnBlock};

/// Number of TCN residual blocks for a sequence length, eq. (20):
/// ⌈log_d((L−1)(d−1)/(2k−2) + 1)⌉, computed in integers (the smallest n with
/// (2k−2)·dⁿ ≥ (L−1)(d−1) + (2k−2)) so exact powers do not depend on float rounding.
/// At least one block.
pub fn tcn_num_blocks(seq_len: usize) -> usize {
    let (k, d) = (TCN_KERNEL, TCN_DILATION_BASE);
    let rhs = seq_len.saturating_sub(1) * (d - 1) + (2 * k - 2);
    let mut n = 0;
    let mut lhs = 2 * k - 2;
    while lhs < rhs {
        lhs *= d;
        n += 1;
    }
    n.max(1)
}

/// Dilation of block `b` (0-based): d^b.
pub fn tcn_dilation(block: usize) -> usize {
    TCN_DILATION_BASE.pow(block as u32)
}

/// One architecture at one sequence length and joint count.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
pub struct ModelSpec {
    pub arch: Architecture,
    pub seq_len: usize,
    pub joints: usize,
    pub tcn_block: TcnBlock,
}

/// One named tensor inside the flat parameter vector.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ParamTensor {
    pub name: String,
    pub shape: Vec<usize>,
    pub offset: usize,
    /// PyTorch's default init bound: U(−bound, bound).
    pub init_bound_inv_sqrt: usize,
}

impl ParamTensor {
    pub fn len(&self) -> usize {
        self.shape.iter().product()
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    pub fn range(&self) -> std::ops::Range<usize> {
        self.offset..self.offset + self.len()
    }
}

/// The named layout of a model's parameters.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ParamLayout {
    pub tensors: Vec<ParamTensor>,
    pub total: usize,
}

impl ParamLayout {
    fn push(&mut self, name: String, shape: Vec<usize>, fan_in: usize) {
        let t = ParamTensor {
            name,
            shape,
            offset: self.total,
            init_bound_inv_sqrt: fan_in,
        };
        self.total += t.len();
        self.tensors.push(t);
    }

    pub fn get(&self, name: &str) -> Option<&ParamTensor> {
        self.tensors.iter().find(|t| t.name == name)
    }

    /// The range of a tensor that the layout is known to have.
    pub fn range(&self, name: &str) -> std::ops::Range<usize> {
        match self.get(name) {
            Some(t) => t.range(),
            None => panic!("parameter layout has no tensor {name:?} (an internal naming error)"),
        }
    }
}

impl ModelSpec {
    pub fn new(arch: Architecture, seq_len: usize, joints: usize, tcn_block: TcnBlock) -> Self {
        Self {
            arch,
            seq_len,
            joints,
            tcn_block,
        }
    }

    pub fn tcn_blocks(&self) -> usize {
        if self.arch.has_tcn() {
            tcn_num_blocks(self.seq_len)
        } else {
            0
        }
    }

    /// The parameter layout, in PyTorch's names and shapes.
    pub fn layout(&self) -> ParamLayout {
        let j = self.joints;
        let h = LSTM_HIDDEN;
        let mut l = ParamLayout {
            tensors: Vec::new(),
            total: 0,
        };
        if self.arch.has_tcn() {
            for b in 0..self.tcn_blocks() {
                for c in ["c1", "c2"] {
                    l.push(
                        format!("tcn.blocks.{b}.{c}.weight"),
                        vec![j, j, TCN_KERNEL],
                        j * TCN_KERNEL,
                    );
                    l.push(format!("tcn.blocks.{b}.{c}.bias"), vec![j], j * TCN_KERNEL);
                }
            }
        }
        if self.arch.has_lstm() {
            l.push("lstm.weight_ih_l0".into(), vec![4 * h, j], h);
            l.push("lstm.weight_hh_l0".into(), vec![4 * h, h], h);
            l.push("lstm.bias_ih_l0".into(), vec![4 * h], h);
            l.push("lstm.bias_hh_l0".into(), vec![4 * h], h);
            l.push("fc.0.weight".into(), vec![HEAD_HIDDEN, h], h);
            l.push("fc.0.bias".into(), vec![HEAD_HIDDEN], h);
            l.push("fc.2.weight".into(), vec![j, HEAD_HIDDEN], HEAD_HIDDEN);
            l.push("fc.2.bias".into(), vec![j], HEAD_HIDDEN);
        }
        if self.arch == Architecture::Fnn {
            let n_in = j * self.seq_len;
            l.push("net.1.weight".into(), vec![FNN_HIDDEN, n_in], n_in);
            l.push("net.1.bias".into(), vec![FNN_HIDDEN], n_in);
            l.push("net.3.weight".into(), vec![FNN_HIDDEN, FNN_HIDDEN], FNN_HIDDEN);
            l.push("net.3.bias".into(), vec![FNN_HIDDEN], FNN_HIDDEN);
            l.push("net.5.weight".into(), vec![j, FNN_HIDDEN], FNN_HIDDEN);
            l.push("net.5.bias".into(), vec![j], FNN_HIDDEN);
        }
        l
    }

    pub fn param_count(&self) -> usize {
        self.layout().total
    }

    /// PyTorch's default initialisation (Conv1d, Linear, LSTM: U(−1/√fan, 1/√fan) with
    /// fan = fan-in, or the hidden size for LSTM weights), from a seeded ChaCha8 stream.
    pub fn init_params(&self, seed: u64) -> Vec<f32> {
        let layout = self.layout();
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let mut p = vec![0.0f32; layout.total];
        for t in &layout.tensors {
            let bound = 1.0 / (t.init_bound_inv_sqrt as f64).sqrt();
            for v in &mut p[t.range()] {
                *v = rng.random_range(-bound..bound) as f32;
            }
        }
        p
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn eq20_block_counts() {
        let got: Vec<usize> = [10, 50, 65, 80, 100, 120].iter().map(|&l| tcn_num_blocks(l)).collect();
        assert_eq!(got, vec![2, 4, 5, 5, 5, 5]);
        // Exact powers: (L−1)/4 + 1 = 2 at L = 5 → exactly one block; L = 6 needs two.
        assert_eq!(tcn_num_blocks(5), 1);
        assert_eq!(tcn_num_blocks(6), 2);
        assert_eq!(tcn_num_blocks(1), 1);
    }

    #[test]
    fn init_is_seeded_and_bounded() {
        let spec = ModelSpec::new(Architecture::Tcn, 80, 5, TcnBlock::ReluLinear);
        let a = spec.init_params(7);
        assert_eq!(a, spec.init_params(7));
        assert_ne!(a, spec.init_params(8));
        let bound = 1.0 / 15f32.sqrt();
        assert!(a.iter().all(|v| v.abs() <= bound));
    }
}
