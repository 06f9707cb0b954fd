//! Hand-written fused forward / backward kernels for the four architectures, batched, in
//! plain f32. They compute exactly what the PyTorch modules (and the candle reference in
//! [`crate::candle_ref`]) compute — the tests hold their outputs and gradients to candle's
//! autograd — at a fraction of the cost: no graph, no per-op allocation, one GEMM per LSTM
//! step, the TCN's 5-channel convolutions as shifted vector loops.

pub mod bf16;
pub mod gemm;
pub mod linear;
pub mod lstm;
pub mod simd;
pub mod tcn;

use crate::arch::{Architecture, ModelSpec, ParamLayout, FNN_HIDDEN, HEAD_HIDDEN, LSTM_HIDDEN};
pub use bowden_fastmath::AVec;
use lstm::{LstmDims, LstmGrads, LstmParamIdx, LstmPrepared, LstmWork};
use tcn::{TcnDims, TcnParamIdx, TcnScratch};

/// Arithmetic of the training products.
#[derive(
    Debug,
    Clone,
    Copy,
    Default,
    PartialEq,
    Eq,
    Hash,
    serde::Serialize,
    serde::Deserialize,
    strum::EnumString,
    strum::IntoStaticStr,
    strum::Display,
    strum::VariantNames,
    strum::VariantArray,
)]
#[serde(rename_all = "kebab-case")]
#[strum(serialize_all = "kebab-case")]
pub enum Precision {
    /// Everything in f32 (the default; what the tests hold to candle's autograd).
    #[default]
    F32,
    /// Mixed: the LSTM's recurrent products (h·W_hhᵀ, dg·W_hh, dW_hh: nine tenths of its
    /// arithmetic) with bf16 operands and f32 sums ([`bf16`]); everything else, the master
    /// weights, the optimiser and every forward pass outside training stay f32.
    Bf16,
}

impl Precision {
    /// The spelling in configs, reports and on the command line.
    pub fn as_str(self) -> &'static str {
        self.into()
    }
}

/// A fully connected layer's place in the parameter vector.
#[derive(Debug, Clone, Copy)]
struct Lin {
    w: usize,
    b: usize,
    n_in: usize,
    n_out: usize,
}

/// A model's structure: which kernels run, on which parameter ranges.
#[derive(Debug, Clone)]
pub struct Net {
    pub spec: ModelSpec,
    pub layout: ParamLayout,
    tcn: Option<(TcnDims, TcnParamIdx)>,
    lstm: Option<(LstmDims, LstmParamIdx)>,
    /// The fully connected stack: the LSTM head (fc.0, fc.2) or the FNN (net.1, 3, 5).
    /// ReLU after every layer but the last.
    mlp: Vec<Lin>,
    /// Arithmetic of [`Net::forward_backward`]; [`Net::forward`] is always f32.
    precision: Precision,
}

/// Weight copies in the orientation the GEMMs want; refresh with [`Net::prepare`] after
/// every parameter update.
#[derive(Debug, Clone, Default)]
pub struct Prepared {
    lstm: LstmPrepared,
    /// Wᵀ of each layer of `mlp`.
    lin_t: Vec<AVec<f32>>,
}

/// Per-thread buffers for up to `cap` windows.
#[derive(Debug, Clone)]
pub struct Workspace {
    cap: usize,
    tcn_cache: AVec<f32>,
    tcn_scratch: Option<TcnScratch>,
    dz_out: AVec<f32>,
    lstm: Option<LstmWork>,
    /// Output of each mlp layer (after ReLU), `[b][n_out]`.
    acts: Vec<AVec<f32>>,
    /// Gradient buffers, one per mlp layer input.
    dacts: Vec<AVec<f32>>,
    out: AVec<f32>,
    dout: AVec<f32>,
}

impl Workspace {
    pub fn capacity(&self) -> usize {
        self.cap
    }
}

impl Net {
    pub fn new(spec: ModelSpec) -> Self {
        let layout = spec.layout();
        let j = spec.joints;
        let tcn = spec.arch.has_tcn().then(|| {
            let blocks = spec.tcn_blocks();
            let dims = TcnDims::new(j, spec.seq_len, blocks, spec.tcn_block);
            let idx = TcnParamIdx {
                blocks: (0..blocks)
                    .map(|b| {
                        [
                            layout.range(&format!("tcn.blocks.{b}.c1.weight")).start,
                            layout.range(&format!("tcn.blocks.{b}.c1.bias")).start,
                            layout.range(&format!("tcn.blocks.{b}.c2.weight")).start,
                            layout.range(&format!("tcn.blocks.{b}.c2.bias")).start,
                        ]
                    })
                    .collect(),
            };
            (dims, idx)
        });
        let lstm = spec.arch.has_lstm().then(|| {
            (
                LstmDims {
                    t: spec.seq_len,
                    j,
                    h: LSTM_HIDDEN,
                },
                LstmParamIdx {
                    w_ih: layout.range("lstm.weight_ih_l0").start,
                    w_hh: layout.range("lstm.weight_hh_l0").start,
                    b_ih: layout.range("lstm.bias_ih_l0").start,
                    b_hh: layout.range("lstm.bias_hh_l0").start,
                },
            )
        });
        let lin = |name: &str, n_in: usize, n_out: usize| Lin {
            w: layout.range(&format!("{name}.weight")).start,
            b: layout.range(&format!("{name}.bias")).start,
            n_in,
            n_out,
        };
        let mlp = match spec.arch {
            Architecture::Lstm | Architecture::TcnLstm => {
                vec![lin("fc.0", LSTM_HIDDEN, HEAD_HIDDEN), lin("fc.2", HEAD_HIDDEN, j)]
            }
            Architecture::Fnn => vec![
                lin("net.1", j * spec.seq_len, FNN_HIDDEN),
                lin("net.3", FNN_HIDDEN, FNN_HIDDEN),
                lin("net.5", FNN_HIDDEN, j),
            ],
            Architecture::Tcn => Vec::new(),
        };
        Self {
            spec,
            layout,
            tcn,
            lstm,
            mlp,
            precision: Precision::F32,
        }
    }

    /// The same network training in `precision` (only architectures with an LSTM change).
    pub fn with_precision(mut self, precision: Precision) -> Self {
        self.precision = precision;
        self
    }

    fn mixed(&self) -> bool {
        self.precision == Precision::Bf16 && self.lstm.is_some()
    }

    pub fn param_count(&self) -> usize {
        self.layout.total
    }

    /// Buffers for batches of up to `cap` windows.
    pub fn workspace(&self, cap: usize) -> Workspace {
        let j = self.spec.joints;
        let (tcn_cache, tcn_scratch, dz_out) = match &self.tcn {
            Some((d, _)) => (
                AVec::from_elem(0.0, cap * d.cache_per_window()),
                Some(TcnScratch::new(d)),
                AVec::from_elem(0.0, d.c * d.t),
            ),
            None => (AVec::new(), None, AVec::new()),
        };
        Workspace {
            cap,
            tcn_cache,
            tcn_scratch,
            dz_out,
            lstm: self.lstm.as_ref().map(|(d, _)| LstmWork::new(d, cap)),
            acts: self.mlp.iter().map(|l| AVec::from_elem(0.0, cap * l.n_out)).collect(),
            dacts: self.mlp.iter().map(|l| AVec::from_elem(0.0, cap * l.n_in)).collect(),
            out: AVec::from_elem(0.0, cap * j),
            dout: AVec::from_elem(0.0, cap * j),
        }
    }

    pub fn prepared(&self, params: &[f32]) -> Prepared {
        let mut p = Prepared::default();
        self.prepare(params, &mut p);
        p
    }

    pub fn prepare(&self, params: &[f32], prep: &mut Prepared) {
        if let Some((d, idx)) = &self.lstm {
            prep.lstm.prepare(d, params, idx, self.mixed());
        }
        prep.lin_t.resize(self.mlp.len(), AVec::new());
        for (l, t) in self.mlp.iter().zip(prep.lin_t.iter_mut()) {
            lstm::transpose(&params[l.w..l.w + l.n_out * l.n_in], l.n_out, l.n_in, t);
        }
    }

    /// [`Net::prepare`] for a training step: with mixed precision it skips the f32 copies
    /// only an f32 forward pass reads ([`LstmPrepared::prepare_for_mixed_step`]); call
    /// [`Net::prepare`] before evaluating on them.
    pub fn prepare_for_step(&self, params: &[f32], prep: &mut Prepared) {
        match &self.lstm {
            Some((d, idx)) if self.mixed() => {
                prep.lstm.prepare_for_mixed_step(d, params, idx);
                prep.lin_t.resize(self.mlp.len(), AVec::new());
                for (l, t) in self.mlp.iter().zip(prep.lin_t.iter_mut()) {
                    lstm::transpose(&params[l.w..l.w + l.n_out * l.n_in], l.n_out, l.n_in, t);
                }
            }
            _ => self.prepare(params, prep),
        }
    }

    /// Model outputs (normalised units) for `b` windows `x` (`[b][L][J]`, normalised) into
    /// `out` (`[b][J]`).
    pub fn forward(&self, params: &[f32], prep: &Prepared, x: &[f32], b: usize, ws: &mut Workspace, out: &mut [f32]) {
        assert!(b <= ws.cap, "batch {b} exceeds workspace capacity {}", ws.cap);
        self.forward_inner(params, prep, x, b, ws, false);
        let j = self.spec.joints;
        out[..b * j].copy_from_slice(&ws.out[..b * j]);
    }

    fn forward_inner(&self, params: &[f32], prep: &Prepared, x: &[f32], b: usize, ws: &mut Workspace, mixed: bool) {
        let j = self.spec.joints;
        let l = self.spec.seq_len;
        if let Some((d, idx)) = &self.tcn {
            tcn::forward(d, params, idx, x, b, &mut ws.tcn_cache);
        }
        match self.spec.arch {
            Architecture::Tcn => {
                let Some((d, _)) = &self.tcn else { unreachable!() };
                for row in 0..b {
                    for ch in 0..j {
                        ws.out[row * j + ch] = tcn::output(d, &ws.tcn_cache, row, ch, l - 1);
                    }
                }
            }
            Architecture::Lstm | Architecture::TcnLstm => {
                let Some((ld, _)) = &self.lstm else { unreachable!() };
                let Some(work) = ws.lstm.as_mut() else { unreachable!() };
                // LSTM input [T][b][J]: the window itself, or the TCN's feature sequence.
                for row in 0..b {
                    for tt in 0..l {
                        for ch in 0..j {
                            work.xt[(tt * b + row) * j + ch] = match &self.tcn {
                                Some((d, _)) => tcn::output(d, &ws.tcn_cache, row, ch, tt),
                                None => x[(row * l + tt) * j + ch],
                            };
                        }
                    }
                }
                lstm::forward(ld, &prep.lstm, b, work, mixed);
                let h_last = work.h_last(ld, b);
                mlp_forward(&self.mlp, params, prep, h_last, b, &mut ws.acts);
                ws.out[..b * j].copy_from_slice(&ws.acts[self.mlp.len() - 1][..b * j]);
            }
            Architecture::Fnn => {
                mlp_forward(&self.mlp, params, prep, &x[..b * l * j], b, &mut ws.acts);
                ws.out[..b * j].copy_from_slice(&ws.acts[self.mlp.len() - 1][..b * j]);
            }
        }
    }

    /// Forward and backward for `b` windows against targets `y` (`[b][J]`, normalised).
    /// The loss gradient is `scale · (ŷ − y)` (scale = 2 / (batch · J) for a mean-squared
    /// error over the whole batch, also when it is split into shards); parameter gradients
    /// are accumulated into `grad`. Returns Σ (ŷ − y)².
    #[allow(clippy::too_many_arguments)]
    pub fn forward_backward(
        &self,
        params: &[f32],
        prep: &Prepared,
        x: &[f32],
        y: &[f32],
        b: usize,
        scale: f32,
        ws: &mut Workspace,
        grad: &mut [f32],
    ) -> f64 {
        assert!(b <= ws.cap, "batch {b} exceeds workspace capacity {}", ws.cap);
        assert_eq!(grad.len(), self.layout.total);
        let mixed = self.mixed();
        self.forward_inner(params, prep, x, b, ws, mixed);
        let j = self.spec.joints;
        let l = self.spec.seq_len;
        let mut sse = 0.0f64;
        for ((d, o), t) in ws.dout[..b * j].iter_mut().zip(&ws.out[..b * j]).zip(&y[..b * j]) {
            let e = o - t;
            sse += (e as f64) * (e as f64);
            *d = scale * e;
        }
        match self.spec.arch {
            Architecture::Tcn => {
                let Some((d, idx)) = &self.tcn else { unreachable!() };
                let Some(scratch) = ws.tcn_scratch.as_mut() else {
                    unreachable!()
                };
                ws.dz_out.fill(0.0);
                for row in 0..b {
                    for ch in 0..j {
                        ws.dz_out[ch * l + l - 1] = ws.dout[row * j + ch];
                    }
                    tcn::backward_window(d, params, idx, &ws.tcn_cache, row, &ws.dz_out, scratch, grad);
                }
            }
            Architecture::Lstm | Architecture::TcnLstm => {
                let Some((ld, lidx)) = &self.lstm else { unreachable!() };
                let Some(work) = ws.lstm.as_mut() else { unreachable!() };
                let h_last = work.h_last(ld, b);
                mlp_backward(
                    &self.mlp,
                    params,
                    h_last,
                    b,
                    &ws.acts,
                    &ws.dout,
                    &mut ws.dacts,
                    grad,
                    true,
                );
                let dh_last = &ws.dacts[0];
                let (lo, hi) = grad.split_at_mut(lidx.w_hh);
                let (w_hh, hi) = hi.split_at_mut(lidx.b_ih - lidx.w_hh);
                let (b_ih, b_hh) = hi.split_at_mut(lidx.b_hh - lidx.b_ih);
                let g4 = 4 * ld.h;
                let want_dx = self.tcn.is_some();
                lstm::backward(
                    ld,
                    params,
                    lidx,
                    &prep.lstm,
                    b,
                    dh_last,
                    work,
                    LstmGrads {
                        w_ih: &mut lo[lidx.w_ih..lidx.w_ih + g4 * ld.j],
                        w_hh,
                        b_ih,
                        b_hh: &mut b_hh[..g4],
                    },
                    want_dx,
                    mixed,
                );
                if let Some((d, idx)) = &self.tcn {
                    let Some(scratch) = ws.tcn_scratch.as_mut() else {
                        unreachable!()
                    };
                    for row in 0..b {
                        for tt in 0..l {
                            for ch in 0..j {
                                ws.dz_out[ch * l + tt] = work.dxt[(tt * b + row) * j + ch];
                            }
                        }
                        tcn::backward_window(d, params, idx, &ws.tcn_cache, row, &ws.dz_out, scratch, grad);
                    }
                }
            }
            Architecture::Fnn => {
                mlp_backward(
                    &self.mlp,
                    params,
                    &x[..b * l * j],
                    b,
                    &ws.acts,
                    &ws.dout,
                    &mut ws.dacts,
                    grad,
                    false,
                );
            }
        }
        sse
    }
}

fn mlp_forward(mlp: &[Lin], params: &[f32], prep: &Prepared, input: &[f32], b: usize, acts: &mut [AVec<f32>]) {
    for (i, l) in mlp.iter().enumerate() {
        let (done, rest) = acts.split_at_mut(i);
        let x: &[f32] = if i == 0 { input } else { &done[i - 1] };
        let y = &mut rest[0];
        linear::forward(x, b, l.n_in, &prep.lin_t[i], &params[l.b..l.b + l.n_out], l.n_out, y);
        if i + 1 < mlp.len() {
            linear::relu(&mut y[..b * l.n_out]);
        }
    }
}

/// Backward through the stack; `dacts[0]` receives dL/d(input) when `want_input_grad`.
#[allow(clippy::too_many_arguments)]
fn mlp_backward(
    mlp: &[Lin],
    params: &[f32],
    input: &[f32],
    b: usize,
    acts: &[AVec<f32>],
    dout: &[f32],
    dacts: &mut [AVec<f32>],
    grad: &mut [f32],
    want_input_grad: bool,
) {
    for i in (0..mlp.len()).rev() {
        let l = mlp[i];
        let x: &[f32] = if i == 0 { input } else { &acts[i - 1] };
        let (lo, hi) = dacts.split_at_mut(i + 1);
        let dy: &[f32] = if i + 1 == mlp.len() { dout } else { &hi[0] };
        let (gw, gb) = grad.split_at_mut(l.b);
        let dx = if i > 0 || want_input_grad {
            Some(&mut lo[i][..])
        } else {
            None
        };
        let has_dx = dx.is_some();
        linear::backward(
            x,
            b,
            l.n_in,
            &params[l.w..l.w + l.n_out * l.n_in],
            l.n_out,
            dy,
            &mut gw[l.w..l.w + l.n_out * l.n_in],
            &mut gb[..l.n_out],
            dx,
        );
        if i > 0 && has_dx {
            linear::relu_backward(&mut lo[i][..b * l.n_in], &acts[i - 1][..b * l.n_in]);
        }
    }
}
