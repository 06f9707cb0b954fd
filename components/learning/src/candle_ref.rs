//! The four architectures in candle (`candle_nn::lstm`, `candle_nn::linear`, `conv1d` on a
//! left-`pad_with_zeros` input), built on the same flat parameters as the fused kernels.
//! It is the reference the fused kernels' outputs and gradients are tested against, and a
//! training backend of its own (`--backend candle`), slow but independent.

use candle_core::{DType, Device, Module, Tensor, Var};
use candle_nn::rnn::RNN;
use candle_nn::{Optimizer, VarBuilder, VarMap};

use crate::arch::{tcn_dilation, Architecture, ModelSpec, ParamLayout, TcnBlock, HEAD_HIDDEN, LSTM_HIDDEN};

pub type CandleResult<T> = candle_core::Result<T>;

/// A model in candle whose variables are the layout's tensors.
pub struct CandleModel {
    pub spec: ModelSpec,
    layout: ParamLayout,
    varmap: VarMap,
    /// Variables in layout order.
    vars: Vec<Var>,
    lstm: Option<candle_nn::LSTM>,
    mlp: Vec<candle_nn::Linear>,
    device: Device,
    /// Use `Tensor::conv1d` for the TCN (forward checks only: candle 0.11.1's CPU conv1d
    /// ignores the contiguous copy it makes of a strided kernel, and its backward passes a
    /// transposed — strided — gradient as the kernel of the weight-gradient convolution,
    /// so conv1d weight gradients are wrong). The default computes the same convolution
    /// as one matmul per tap, whose autograd is right.
    pub conv1d_op: bool,
}

/// A causal dilated convolution (kernel 3) of an already left-padded `[b, C, L + 2d]` input
/// as Σ_kk W[:, :, kk] · x[:, :, kk·d .. kk·d + L].
fn causal_conv_by_taps(padded: &Tensor, w: &Tensor, d: usize, l: usize) -> CandleResult<Tensor> {
    let mut acc: Option<Tensor> = None;
    for kk in 0..crate::arch::TCN_KERNEL {
        let wk = w.narrow(2, kk, 1)?.squeeze(2)?.contiguous()?;
        let xk = padded.narrow(2, kk * d, l)?.contiguous()?;
        let term = wk.broadcast_matmul(&xk)?;
        acc = Some(match acc {
            None => term,
            Some(a) => (a + term)?,
        });
    }
    acc.ok_or_else(|| candle_core::Error::Msg("empty kernel".into()))
}

impl CandleModel {
    pub fn from_params(spec: ModelSpec, params: &[f32]) -> CandleResult<Self> {
        let device = Device::Cpu;
        let layout = spec.layout();
        if params.len() != layout.total {
            candle_core::bail!("{} parameters given, the layout has {}", params.len(), layout.total);
        }
        let varmap = VarMap::new();
        let mut vars = Vec::with_capacity(layout.tensors.len());
        {
            let mut data = varmap
                .data()
                .lock()
                .map_err(|_| candle_core::Error::Msg("varmap lock".into()))?;
            for t in &layout.tensors {
                let v = Var::from_tensor(&Tensor::from_slice(&params[t.range()], t.shape.as_slice(), &device)?)?;
                data.insert(t.name.clone(), v.clone());
                vars.push(v);
            }
        }
        let vb = VarBuilder::from_varmap(&varmap, DType::F32, &device);
        let j = spec.joints;
        let lstm = if spec.arch.has_lstm() {
            Some(candle_nn::lstm(j, LSTM_HIDDEN, Default::default(), vb.pp("lstm"))?)
        } else {
            None
        };
        let mlp = match spec.arch {
            Architecture::Lstm | Architecture::TcnLstm => vec![
                candle_nn::linear(LSTM_HIDDEN, HEAD_HIDDEN, vb.pp("fc.0"))?,
                candle_nn::linear(HEAD_HIDDEN, j, vb.pp("fc.2"))?,
            ],
            Architecture::Fnn => {
                let n_in = j * spec.seq_len;
                vec![
                    candle_nn::linear(n_in, crate::arch::FNN_HIDDEN, vb.pp("net.1"))?,
                    candle_nn::linear(crate::arch::FNN_HIDDEN, crate::arch::FNN_HIDDEN, vb.pp("net.3"))?,
                    candle_nn::linear(crate::arch::FNN_HIDDEN, j, vb.pp("net.5"))?,
                ]
            }
            Architecture::Tcn => Vec::new(),
        };
        Ok(Self {
            spec,
            layout,
            varmap,
            vars,
            lstm,
            mlp,
            device,
            conv1d_op: false,
        })
    }

    fn var(&self, name: &str) -> CandleResult<&Tensor> {
        let i = self
            .layout
            .tensors
            .iter()
            .position(|t| t.name == name)
            .ok_or_else(|| candle_core::Error::Msg(format!("no tensor {name}")))?;
        Ok(self.vars[i].as_tensor())
    }

    /// `x`: `[b, L, J]` → `[b, J]`, normalised units.
    pub fn forward(&self, x: &Tensor) -> CandleResult<Tensor> {
        let j = self.spec.joints;
        let l = self.spec.seq_len;
        let mut feat = x.clone();
        if self.spec.arch.has_tcn() {
            let mut z = x.transpose(1, 2)?.contiguous()?; // [b, J, L]
            for k in 0..self.spec.tcn_blocks() {
                let d = tcn_dilation(k);
                let conv = |inp: &Tensor, c: &str| -> CandleResult<Tensor> {
                    let w = self.var(&format!("tcn.blocks.{k}.{c}.weight"))?;
                    let b = self.var(&format!("tcn.blocks.{k}.{c}.bias"))?.reshape((1, j, 1))?;
                    let padded = inp.pad_with_zeros(2, 2 * d, 0)?;
                    let out = if self.conv1d_op {
                        padded.conv1d(w, 0, 1, d, 1)?
                    } else {
                        causal_conv_by_taps(&padded, w, d, l)?
                    };
                    out.broadcast_add(&b)
                };
                let h1 = conv(&z, "c1")?.relu()?;
                let mut h2 = conv(&h1, "c2")?;
                if self.spec.tcn_block == TcnBlock::ReluRelu {
                    h2 = h2.relu()?;
                }
                z = (z + h2)?;
            }
            if self.spec.arch == Architecture::Tcn {
                return z.narrow(2, l - 1, 1)?.squeeze(2);
            }
            feat = z.transpose(1, 2)?.contiguous()?; // [b, L, J]
        }
        let mut h = match &self.lstm {
            Some(lstm) => {
                let states = lstm.seq(&feat)?;
                match states.last() {
                    Some(s) => s.h().clone(),
                    None => candle_core::bail!("empty sequence"),
                }
            }
            None => feat.flatten_from(1)?,
        };
        for (i, lin) in self.mlp.iter().enumerate() {
            h = lin.forward(&h)?;
            if i + 1 < self.mlp.len() {
                h = h.relu()?;
            }
        }
        Ok(h)
    }

    fn tensor(&self, data: &[f32], shape: &[usize]) -> CandleResult<Tensor> {
        Tensor::from_slice(data, shape, &self.device)
    }

    /// Outputs for `b` windows (`[b][L][J]` flat) as a flat `[b][J]`.
    pub fn predict(&self, x: &[f32], b: usize) -> CandleResult<Vec<f32>> {
        let xt = self.tensor(x, &[b, self.spec.seq_len, self.spec.joints])?;
        self.forward(&xt)?.flatten_all()?.to_vec1()
    }

    /// Mean-squared-error loss and its gradient with respect to every parameter, flattened
    /// in layout order.
    pub fn loss_and_grads(&self, x: &[f32], y: &[f32], b: usize) -> CandleResult<(f32, Vec<f32>)> {
        let xt = self.tensor(x, &[b, self.spec.seq_len, self.spec.joints])?;
        let yt = self.tensor(y, &[b, self.spec.joints])?;
        let loss = candle_nn::loss::mse(&self.forward(&xt)?, &yt)?;
        let grads = loss.backward()?;
        let mut flat = Vec::with_capacity(self.layout.total);
        for v in &self.vars {
            match grads.get(v.as_tensor()) {
                Some(g) => flat.extend(g.flatten_all()?.to_vec1::<f32>()?),
                None => flat.extend(std::iter::repeat_n(0.0f32, v.elem_count())),
            }
        }
        Ok((loss.to_scalar::<f32>()?, flat))
    }

    /// The current parameters, flattened in layout order.
    pub fn params(&self) -> CandleResult<Vec<f32>> {
        let mut flat = Vec::with_capacity(self.layout.total);
        for v in &self.vars {
            flat.extend(v.as_tensor().flatten_all()?.to_vec1::<f32>()?);
        }
        Ok(flat)
    }

    /// Adam (AdamW with weight decay 0) over this model's variables.
    pub fn adam(&self, lr: f64) -> CandleResult<candle_nn::AdamW> {
        candle_nn::AdamW::new(
            self.varmap.all_vars(),
            candle_nn::ParamsAdamW {
                lr,
                beta1: 0.9,
                beta2: 0.999,
                eps: 1e-8,
                weight_decay: 0.0,
            },
        )
    }

    /// One optimiser step on a batch; returns Σ (ŷ − y)².
    pub fn train_step(&self, opt: &mut candle_nn::AdamW, x: &[f32], y: &[f32], b: usize) -> CandleResult<f64> {
        let xt = self.tensor(x, &[b, self.spec.seq_len, self.spec.joints])?;
        let yt = self.tensor(y, &[b, self.spec.joints])?;
        let loss = candle_nn::loss::mse(&self.forward(&xt)?, &yt)?;
        opt.backward_step(&loss)?;
        Ok(loss.to_scalar::<f32>()? as f64 * (b * self.spec.joints) as f64)
    }
}
