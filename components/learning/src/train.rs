//! Training: Adam, lr 1e-3, batch 32, MSE (paper §IV-C), seeded shuffling, best-epoch
//! selection on validation RMSE in degrees, optional early stopping.
//!
//! Each batch is cut into a fixed number of shards ([`SHARDS`]) whose gradients are summed
//! in a fixed order, whatever the number of threads: one thread or two give the same bits.

use std::time::Instant;

use indicatif::ProgressBar;
use rand::seq::SliceRandom;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

use crate::adam::Adam;
use crate::arch::{Architecture, Direction, ModelSpec, TcnBlock};
#[cfg(feature = "candle")]
use crate::candle_ref::CandleModel;
use crate::helper::Helper;
use crate::kernels::{AVec, Net, Precision, Prepared, Workspace};
use crate::onnx::ModelFile;
use crate::windows::{overall_rmse, WindowSet};

/// Shards per batch (the unit of parallelism and of gradient summation order).
pub const SHARDS: usize = 2;

/// Which implementation computes the gradients.
#[derive(
    Debug,
    Clone,
    Copy,
    PartialEq,
    Eq,
    Default,
    Serialize,
    Deserialize,
    strum::EnumString,
    strum::IntoStaticStr,
    strum::Display,
    strum::VariantNames,
)]
#[serde(rename_all = "kebab-case")]
#[strum(serialize_all = "kebab-case")]
pub enum Backend {
    /// Hand-written fused kernels (default).
    #[default]
    Fused,
    /// candle's autograd (reference; slow for the LSTM).
    Candle,
}

/// Everything that defines a training run.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TrainConfig {
    pub arch: Architecture,
    pub direction: Direction,
    pub seq_len: usize,
    pub tcn_block: TcnBlock,
    pub epochs: usize,
    pub seed: u64,
    /// Stop after this many epochs without a better validation RMSE.
    pub early_stop: Option<usize>,
    pub batch_size: usize,
    pub lr: f64,
    pub backend: Backend,
    /// Worker threads (1 or 2 on this machine; results do not depend on it).
    pub threads: usize,
    /// Fine-tuning only: weight λ of the pull λ·‖θ − θ₀‖² towards the starting weights θ₀
    /// (L2-SP, Li, Grandvalet & Davoine 2018), added to the loss (mean squared error in
    /// normalised units). 0 = none. A few new windows then move the weights only as far as
    /// they must, instead of pulling a model trained on many thousands away from what it knew.
    /// Absent = 0, and 0 is not written, so reports read and write as before it existed.
    #[serde(default, skip_serializing_if = "is_zero")]
    pub anchor: f64,
    /// Arithmetic of the training steps ([`Precision`]): f32, or bf16 products with f32 sums
    /// for the LSTM's recurrent matrices. Absent = f32, and f32 is not written.
    #[serde(default, skip_serializing_if = "is_f32")]
    pub precision: Precision,
    /// Largest history decimation of the training windows ([`WindowSet::set_decimation`]):
    /// each epoch draws every training window's decimation uniformly from 1..=this, so an
    /// epoch is as long as without it. 1 = consecutive samples only (the paper). Absent = 1,
    /// and 1 is not written.
    #[serde(default = "one", skip_serializing_if = "is_one")]
    pub decimation: usize,
}

fn one() -> usize {
    1
}

fn is_one(v: &usize) -> bool {
    *v == 1
}

fn is_zero(v: &f64) -> bool {
    *v == 0.0
}

fn is_f32(p: &Precision) -> bool {
    *p == Precision::F32
}

impl TrainConfig {
    /// The paper's hyper-parameters for one architecture, direction and length.
    pub fn paper(arch: Architecture, direction: Direction, seq_len: usize, epochs: usize, seed: u64) -> Self {
        Self {
            arch,
            direction,
            seq_len,
            tcn_block: TcnBlock::default(),
            epochs,
            seed,
            early_stop: None,
            batch_size: 32,
            lr: 1e-3,
            backend: Backend::Fused,
            precision: Precision::F32,
            threads: 1,
            anchor: 0.0,
            decimation: 1,
        }
    }
}

#[derive(Debug, thiserror::Error)]
pub enum TrainError {
    #[error("invalid training configuration: {0}")]
    Config(String),
    #[error("the windows have seq_len {windows} and {wj} joints but the config asks for {cfg}")]
    Mismatch { windows: usize, wj: usize, cfg: usize },
    #[cfg(feature = "candle")]
    #[error("candle: {0}")]
    Candle(#[from] candle_core::Error),
    #[error("training diverged at epoch {epoch}: the loss is {loss}")]
    Diverged { epoch: usize, loss: f64 },
}

/// One epoch's numbers.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct EpochStats {
    /// 1-based.
    pub epoch: usize,
    /// Mean squared error on the training windows, normalised units.
    pub train_loss: f64,
    /// The same on validation.
    pub val_loss: f64,
    /// Validation RMSE over joints and windows, degrees.
    pub val_rmse_deg: f64,
    pub val_rmse_per_joint_deg: Vec<f64>,
    pub seconds: f64,
}

/// The result of a run: the best model and the curves.
#[derive(Debug, Clone)]
pub struct TrainOutcome {
    pub model: ModelFile,
    pub epochs: Vec<EpochStats>,
    /// 1-based epoch of the best validation RMSE.
    pub best_epoch: usize,
    pub stopped_early: bool,
    /// Validation loss (normalised MSE) and RMSE (deg) of the initial, untrained model.
    pub initial_val_loss: f64,
    pub initial_val_rmse_deg: f64,
}

impl TrainOutcome {
    pub fn best(&self) -> &EpochStats {
        &self.epochs[self.best_epoch - 1]
    }
}

/// Per-shard buffers of the fused engine.
struct Shard {
    ws: Workspace,
    grad: AVec<f32>,
    x: AVec<f32>,
    y: AVec<f32>,
    out: AVec<f32>,
}

#[allow(clippy::large_enum_variant)] // one per training run
enum Engine {
    Fused {
        net: Net,
        params: AVec<f32>,
        prep: Prepared,
        adam: Adam,
        shards: Vec<Shard>,
        /// The helper thread that runs the second shard and half of the optimiser (none with
        /// one thread). It lives as long as the engine: a thread spawned per batch cost more
        /// than a TCN shard's work (one thread 0.30 s per epoch, two 0.26 s), and it spins
        /// between forks rather than sleep ([`crate::helper`]).
        pool: Option<Helper>,
        /// λ and θ₀ of [`TrainConfig::anchor`] when fine-tuning with it.
        anchor: Option<(f32, Vec<f32>)>,
    },
    #[cfg(feature = "candle")]
    Candle {
        model: Box<CandleModel>,
        opt: Box<candle_nn::AdamW>,
        x: Vec<f32>,
        y: Vec<f32>,
    },
}

/// Runs `a` on this thread and `b` on the helper at the same time (or both here, `a` first,
/// without one), and returns both results.
fn fork2<RA, RB: Send>(helper: Option<&Helper>, a: impl FnOnce() -> RA, b: impl FnOnce() -> RB + Send) -> (RA, RB) {
    match helper {
        Some(h) => h.fork2(a, b),
        None => {
            let ra = a();
            (ra, b())
        }
    }
}

fn shard_ranges(n: usize) -> [(usize, usize); SHARDS] {
    let mut r = [(0, 0); SHARDS];
    let per = n.div_ceil(SHARDS);
    for (s, slot) in r.iter_mut().enumerate() {
        let a = (s * per).min(n);
        let b = ((s + 1) * per).min(n);
        *slot = (a, b);
    }
    r
}

impl Engine {
    fn new(spec: ModelSpec, cfg: &TrainConfig) -> Result<Self, TrainError> {
        let params = spec.init_params(cfg.seed);
        Ok(match cfg.backend {
            Backend::Fused => {
                let net = Net::new(spec).with_precision(cfg.precision);
                let prep = net.prepared(&params);
                // Evaluation runs in chunks of max(batch, 32) windows: room for either.
                let cap = cfg.batch_size.max(32).div_ceil(SHARDS);
                let (l, j) = (spec.seq_len, spec.joints);
                let threads = cfg.threads.clamp(1, SHARDS);
                let pool = if threads > 1 {
                    Some(
                        Helper::new("bowden-train-helper")
                            .map_err(|e| TrainError::Config(format!("starting the training helper thread: {e}")))?,
                    )
                } else {
                    None
                };
                let shards = (0..SHARDS)
                    .map(|_| Shard {
                        ws: net.workspace(cap),
                        grad: AVec::from_elem(0.0, net.param_count()),
                        x: AVec::from_elem(0.0, cap * l * j),
                        y: AVec::from_elem(0.0, cap * j),
                        out: AVec::from_elem(0.0, cap * j),
                    })
                    .collect();
                Engine::Fused {
                    adam: Adam::new(net.param_count(), cfg.lr),
                    net,
                    params: AVec::from_slice(&params),
                    prep,
                    shards,
                    pool,
                    anchor: None,
                }
            }
            #[cfg(not(feature = "candle"))]
            Backend::Candle => {
                return Err(TrainError::Config(
                    "the candle reference backend is not built in: build bowden with `--features candle`".into(),
                ))
            }
            #[cfg(feature = "candle")]
            Backend::Candle => {
                let model = CandleModel::from_params(spec, &params)?;
                let opt = model.adam(cfg.lr)?;
                let (l, j) = (spec.seq_len, spec.joints);
                Engine::Candle {
                    model: Box::new(model),
                    opt: Box::new(opt),
                    x: vec![0.0; cfg.batch_size * l * j],
                    y: vec![0.0; cfg.batch_size * j],
                }
            }
        })
    }

    /// One optimiser step on the windows `ids`; returns Σ (ŷ − y)² (normalised).
    fn step(&mut self, data: &WindowSet, ids: &[usize]) -> Result<f64, TrainError> {
        let j = data.joints;
        match self {
            Engine::Fused {
                net,
                params,
                prep,
                adam,
                shards,
                pool,
                anchor,
            } => {
                let scale = 2.0 / (ids.len() * j) as f32;
                let ranges = shard_ranges(ids.len());
                let run = |shard: &mut Shard, (a, b): (usize, usize)| -> f64 {
                    shard.grad.fill(0.0);
                    if a == b {
                        return 0.0;
                    }
                    let n = b - a;
                    data.gather(&ids[a..b], &mut shard.x, &mut shard.y);
                    net.forward_backward(
                        params,
                        prep,
                        &shard.x,
                        &shard.y,
                        n,
                        scale,
                        &mut shard.ws,
                        &mut shard.grad,
                    )
                };
                let sse = {
                    let (first, rest) = shards.split_at_mut(1);
                    let (a, b) = fork2(
                        pool.as_ref(),
                        || run(&mut first[0], ranges[0]),
                        || run(&mut rest[0], ranges[1]),
                    );
                    a + b
                };
                // The shards' gradients summed, the anchor's pull added and Adam applied,
                // each half of the parameters on its own thread: every element is updated
                // on its own, so the bits are those of one thread doing it all, and the
                // helper does not sit idle through the optimiser (≈ 80k parameters: a few
                // percent of a 2 ms batch).
                let (first, rest) = shards.split_at_mut(1);
                let rest: &[Shard] = rest;
                let anchor = anchor.as_ref();
                let (k, m, v) = adam.begin();
                let update = |lo: usize, p: &mut [f32], total: &mut [f32], m: &mut [f32], v: &mut [f32]| {
                    let hi = lo + p.len();
                    for s in rest {
                        for (t, g) in total.iter_mut().zip(&s.grad[lo..hi]) {
                            *t += g;
                        }
                    }
                    if let Some((lambda, theta0)) = anchor {
                        // d/dθ λ‖θ − θ₀‖² = 2λ(θ − θ₀).
                        let pull = 2.0 * *lambda;
                        for ((g, p), p0) in total.iter_mut().zip(p.iter()).zip(&theta0[lo..hi]) {
                            *g += pull * (p - p0);
                        }
                    }
                    k.apply(p, total, m, v);
                };
                let mid = params.len() / 2;
                let (p0, p1) = params.split_at_mut(mid);
                let (t0, t1) = first[0].grad.split_at_mut(mid);
                let (m0, m1) = m.split_at_mut(mid);
                let (v0, v1) = v.split_at_mut(mid);
                fork2(
                    pool.as_ref(),
                    || update(0, p0, t0, m0, v0),
                    || update(mid, p1, t1, m1, v1),
                );
                net.prepare_for_step(params, prep);
                Ok(sse)
            }
            #[cfg(feature = "candle")]
            Engine::Candle { model, opt, x, y } => {
                data.gather(ids, x, y);
                let n = ids.len();
                Ok(model.train_step(opt, &x[..n * data.seq_len * j], &y[..n * j], n)?)
            }
        }
    }

    /// Σ (ŷ − y)² per joint (normalised units) over the windows `ids`.
    fn evaluate(&mut self, data: &WindowSet, ids: &[usize], chunk: usize) -> Result<Vec<f64>, TrainError> {
        let j = data.joints;
        let mut sse = vec![0.0f64; j];
        match self {
            Engine::Fused {
                net,
                params,
                prep,
                shards,
                pool,
                ..
            } => {
                // The steps prepared only what a mixed-precision step reads; validation runs
                // the f32 forward pass.
                net.prepare(params, prep);
                for batch in ids.chunks(chunk) {
                    let ranges = shard_ranges(batch.len());
                    let run = |shard: &mut Shard, (a, b): (usize, usize)| -> Vec<f64> {
                        let mut e = vec![0.0f64; j];
                        if a == b {
                            return e;
                        }
                        let n = b - a;
                        data.gather(&batch[a..b], &mut shard.x, &mut shard.y);
                        net.forward(params, prep, &shard.x, n, &mut shard.ws, &mut shard.out);
                        for i in 0..n * j {
                            let d = (shard.out[i] - shard.y[i]) as f64;
                            e[i % j] += d * d;
                        }
                        e
                    };
                    let parts: Vec<Vec<f64>> = {
                        let (first, rest) = shards.split_at_mut(1);
                        let (a, b) = fork2(
                            pool.as_ref(),
                            || run(&mut first[0], ranges[0]),
                            || run(&mut rest[0], ranges[1]),
                        );
                        vec![a, b]
                    };
                    for p in parts {
                        for k in 0..j {
                            sse[k] += p[k];
                        }
                    }
                }
            }
            #[cfg(feature = "candle")]
            Engine::Candle { model, x, y, .. } => {
                for batch in ids.chunks(chunk) {
                    let n = batch.len();
                    data.gather(batch, x, y);
                    let out = model.predict(&x[..n * data.seq_len * j], n)?;
                    for i in 0..n * j {
                        let d = (out[i] - y[i]) as f64;
                        sse[i % j] += d * d;
                    }
                }
            }
        }
        Ok(sse)
    }

    fn params(&self) -> Result<Vec<f32>, TrainError> {
        match self {
            Engine::Fused { params, .. } => Ok(params.to_vec()),
            #[cfg(feature = "candle")]
            Engine::Candle { model, .. } => Ok(model.params()?),
        }
    }
}

/// Trains one model on prepared windows. `progress`, when given, is advanced once per epoch
/// (its length is set to the number of epochs).
pub fn train(data: &WindowSet, cfg: &TrainConfig, progress: Option<&ProgressBar>) -> Result<TrainOutcome, TrainError> {
    train_from(data, cfg, None, progress)
}

/// Fine-tunes `init` on `data` (the paper's proposal for cable slack: "fine-tuning it from a
/// pre-trained model with a small number of additional datasets"). The windows must carry
/// `init`'s normalisation ([`WindowSet::with_normalisers`]) and `cfg` its structure. The
/// outcome's `initial_val_rmse_deg` is `init`'s own validation RMSE on `data`, the yardstick
/// a fine-tuned model has to beat; its support stays `init`'s (the new data lies within it).
pub fn fine_tune(
    data: &WindowSet,
    cfg: &TrainConfig,
    init: &ModelFile,
    progress: Option<&ProgressBar>,
) -> Result<TrainOutcome, TrainError> {
    check_fits(data, cfg, init)?;
    let mut out = train_from(data, cfg, Some(&init.params), progress)?;
    out.model.support = init.support.clone();
    Ok(out)
}

/// Validation RMSE (deg, over joints) of `model` on the windows `ids` of `data`, which must
/// carry the model's normalisation.
pub fn rmse_deg(model: &ModelFile, data: &WindowSet, ids: &[usize]) -> Result<f64, TrainError> {
    let batch = TrainConfig::paper(model.spec.arch, model.direction, model.spec.seq_len, 1, 0).batch_size;
    Ok(overall_rmse(&rmse_per_joint_deg(model, data, ids, batch)?))
}

/// Validation RMSE per joint (deg) of `model` on the windows `ids` of `data` (which must carry
/// the model's normalisation), computed exactly as `train` computes its validation figure for
/// a run with batch size `batch_size`: the same forward pass, in chunks of the same size, in
/// normalised units scaled back by the output's standard deviation.
pub fn rmse_per_joint_deg(
    model: &ModelFile,
    data: &WindowSet,
    ids: &[usize],
    batch_size: usize,
) -> Result<Vec<f64>, TrainError> {
    let cfg = TrainConfig {
        tcn_block: model.spec.tcn_block,
        ..TrainConfig::paper(model.spec.arch, model.direction, model.spec.seq_len, 1, 0)
    };
    check_fits(data, &cfg, model)?;
    if ids.is_empty() {
        return Err(TrainError::Config("no windows to validate on".into()));
    }
    let mut engine = Engine::new(model.spec, &cfg)?;
    engine.set_params(&model.params)?;
    let sse = engine.evaluate(data, ids, batch_size.max(32))?;
    let n = ids.len() as f64;
    Ok((0..data.joints)
        .map(|k| (sse[k] / n).sqrt() * data.norm_out.sd[k])
        .collect())
}

/// Mean residual (target − prediction) per joint, deg, of `model` over the windows `ids` of
/// `data` (which must carry the model's normalisation): the offset a re-centred output would
/// remove (`bowden adapt`'s first step after cable slack).
pub fn mean_residual_deg(model: &ModelFile, data: &WindowSet, ids: &[usize]) -> Result<Vec<f64>, TrainError> {
    let cfg = TrainConfig {
        tcn_block: model.spec.tcn_block,
        ..TrainConfig::paper(model.spec.arch, model.direction, model.spec.seq_len, 1, 0)
    };
    check_fits(data, &cfg, model)?;
    if ids.is_empty() {
        return Err(TrainError::Config("no windows to average over".into()));
    }
    let net = Net::new(model.spec);
    let prep = net.prepared(&model.params);
    let (l, j) = (model.spec.seq_len, model.spec.joints);
    let chunk = 32;
    let mut ws = net.workspace(chunk);
    let mut x = vec![0.0f32; chunk * l * j];
    let mut y = vec![0.0f32; chunk * j];
    let mut out = vec![0.0f32; chunk * j];
    let mut sum = vec![0.0f64; j];
    for batch in ids.chunks(chunk) {
        let n = batch.len();
        data.gather(batch, &mut x, &mut y);
        net.forward(&model.params, &prep, &x, n, &mut ws, &mut out);
        for i in 0..n * j {
            sum[i % j] += (y[i] - out[i]) as f64;
        }
    }
    Ok((0..j)
        .map(|k| sum[k] / ids.len() as f64 * data.norm_out.sd[k])
        .collect())
}

fn check_fits(data: &WindowSet, cfg: &TrainConfig, init: &ModelFile) -> Result<(), TrainError> {
    let s = init.spec;
    if s.arch != cfg.arch || s.seq_len != cfg.seq_len || s.tcn_block != cfg.tcn_block || init.direction != cfg.direction
    {
        return Err(TrainError::Config(format!(
            "the model is a {} {} (L = {}, {}) but the run asks for a {} {} (L = {}, {})",
            init.direction, s.arch, s.seq_len, s.tcn_block, cfg.direction, cfg.arch, cfg.seq_len, cfg.tcn_block
        )));
    }
    if s.joints != data.joints || data.norm_in != init.norm_in || data.norm_out != init.norm_out {
        return Err(TrainError::Config(
            "the windows do not carry the model's joints and normalisation (WindowSet::with_normalisers)".into(),
        ));
    }
    Ok(())
}

// Long: the training loop (epochs, batches, validation, early stop, best weights) as one readable loop.
fn train_from(
    data: &WindowSet,
    cfg: &TrainConfig,
    init: Option<&[f32]>,
    progress: Option<&ProgressBar>,
) -> Result<TrainOutcome, TrainError> {
    if cfg.epochs == 0 {
        return Err(TrainError::Config("epochs must be at least 1".into()));
    }
    if cfg.batch_size == 0 {
        return Err(TrainError::Config("batch size must be at least 1".into()));
    }
    if !(cfg.lr > 0.0 && cfg.lr.is_finite()) {
        return Err(TrainError::Config(format!("learning rate {} is not positive", cfg.lr)));
    }
    if data.seq_len != cfg.seq_len {
        return Err(TrainError::Mismatch {
            windows: data.seq_len,
            wj: data.joints,
            cfg: cfg.seq_len,
        });
    }
    let spec = ModelSpec::new(cfg.arch, cfg.seq_len, data.joints, cfg.tcn_block);
    let mut engine = Engine::new(spec, cfg)?;
    if !(cfg.anchor >= 0.0 && cfg.anchor.is_finite()) {
        return Err(TrainError::Config(format!("anchor weight {} is not ≥ 0", cfg.anchor)));
    }
    if let Some(p) = init {
        engine.set_params(p)?;
        if cfg.anchor > 0.0 {
            engine.set_anchor(cfg.anchor as f32, p)?;
        }
    } else if cfg.anchor > 0.0 {
        return Err(TrainError::Config(
            "an anchor weight needs starting weights (fine-tuning)".into(),
        ));
    }
    if data.decimation != cfg.decimation {
        return Err(TrainError::Config(format!(
            "the windows are decimated up to {} but the config asks for {}",
            data.decimation, cfg.decimation
        )));
    }
    let mut rng = ChaCha8Rng::seed_from_u64(cfg.seed ^ 0x5eed_5eed_5eed_5eed);
    // A separate stream for the decimations, so that decimation 1 keeps the batch order (and
    // the trained bits) of before it existed.
    let mut rng_decimation = ChaCha8Rng::seed_from_u64(cfg.seed ^ 0xdec1_3a7e_dec1_3a7e);
    let mut order = data.train.clone();
    let mut ids = Vec::with_capacity(order.len());
    let j = data.joints;
    let mut epochs = Vec::with_capacity(cfg.epochs);
    let mut best: Option<(usize, f64, Vec<f32>)> = None;
    let mut stopped_early = false;
    if let Some(pb) = progress {
        pb.set_length(cfg.epochs as u64);
    }
    let n_val = data.val.len() as f64;
    let rmse_deg =
        |sse: &[f64]| -> Vec<f64> { (0..j).map(|k| (sse[k] / n_val).sqrt() * data.norm_out.sd[k]).collect() };
    let initial_sse = engine.evaluate(data, &data.val, cfg.batch_size.max(32))?;
    let initial_val_loss = initial_sse.iter().sum::<f64>() / (n_val * j as f64);
    let initial_val_rmse_deg = overall_rmse(&rmse_deg(&initial_sse));
    for epoch in 1..=cfg.epochs {
        let t0 = Instant::now();
        order.shuffle(&mut rng);
        data.decimated_ids(&order, &mut rng_decimation, &mut ids);
        let mut sse = 0.0;
        for batch in ids.chunks(cfg.batch_size) {
            sse += engine.step(data, batch)?;
        }
        let train_loss = sse / (order.len() * j) as f64;
        if !train_loss.is_finite() {
            return Err(TrainError::Diverged {
                epoch,
                loss: train_loss,
            });
        }
        let val_sse = engine.evaluate(data, &data.val, cfg.batch_size.max(32))?;
        let per_joint = rmse_deg(&val_sse);
        let val_rmse = overall_rmse(&per_joint);
        let stats = EpochStats {
            epoch,
            train_loss,
            val_loss: val_sse.iter().sum::<f64>() / (n_val * j as f64),
            val_rmse_deg: val_rmse,
            val_rmse_per_joint_deg: per_joint,
            seconds: t0.elapsed().as_secs_f64(),
        };
        let improved = best.as_ref().is_none_or(|(_, r, _)| val_rmse < *r);
        if improved {
            best = Some((epoch, val_rmse, engine.params()?));
        }
        if let Some(pb) = progress {
            let (be, br) = best.as_ref().map_or((0, f64::NAN), |(e, r, _)| (*e, *r));
            pb.set_message(format!(
                "train {:.4}  val {:.3}°  best {:.3}° @{}",
                stats.train_loss, stats.val_rmse_deg, br, be
            ));
            pb.inc(1);
        }
        epochs.push(stats);
        if let (Some(patience), Some((be, _, _))) = (cfg.early_stop, best.as_ref()) {
            if epoch - be >= patience && epoch < cfg.epochs {
                stopped_early = true;
                break;
            }
        }
    }
    let Some((best_epoch, _, params)) = best else {
        return Err(TrainError::Config("no epoch ran".into()));
    };
    Ok(TrainOutcome {
        model: ModelFile {
            spec,
            direction: cfg.direction,
            params,
            norm_in: data.norm_in.clone(),
            norm_out: data.norm_out.clone(),
            support: Some(crate::support::DataSupport::from_windows(data)),
        },
        epochs,
        best_epoch,
        stopped_early,
        initial_val_loss,
        initial_val_rmse_deg,
    })
}

impl Engine {
    /// Replaces the parameters (fine-tuning starts from a trained model's).
    fn set_anchor(&mut self, lambda: f32, theta0: &[f32]) -> Result<(), TrainError> {
        match self {
            Engine::Fused { anchor, .. } => {
                *anchor = Some((lambda, theta0.to_vec()));
                Ok(())
            }
            #[cfg(feature = "candle")]
            Engine::Candle { .. } => Err(TrainError::Config("fine-tuning runs on the fused backend only".into())),
        }
    }

    fn set_params(&mut self, p: &[f32]) -> Result<(), TrainError> {
        match self {
            Engine::Fused { net, params, prep, .. } => {
                if p.len() != params.len() {
                    return Err(TrainError::Config(format!(
                        "the model has {} parameters, the architecture {}",
                        p.len(),
                        params.len()
                    )));
                }
                params.copy_from_slice(p);
                net.prepare(params, prep);
            }
            #[cfg(feature = "candle")]
            Engine::Candle { .. } => {
                // The optimiser holds the candle variables: starting elsewhere would need both rebuilt.
                return Err(TrainError::Config("fine-tuning runs on the fused backend only".into()));
            }
        }
        Ok(())
    }
}

/// One model and its optimiser, stepped batch by batch (benchmarks).
pub struct Stepper {
    engine: Engine,
}

impl Stepper {
    pub fn new(joints: usize, cfg: &TrainConfig) -> Result<Self, TrainError> {
        let spec = ModelSpec::new(cfg.arch, cfg.seq_len, joints, cfg.tcn_block);
        Ok(Self {
            engine: Engine::new(spec, cfg)?,
        })
    }

    /// One forward / backward / Adam step on the windows `ids`; returns Σ (ŷ − y)².
    pub fn step(&mut self, data: &WindowSet, ids: &[usize]) -> Result<f64, TrainError> {
        self.engine.step(data, ids)
    }
}

/// CPU time used by this process so far (all threads), seconds.
pub fn process_cpu_seconds() -> f64 {
    let mut ts = libc::timespec { tv_sec: 0, tv_nsec: 0 };
    // SAFETY: `ts` is a valid timespec to write into; the clock id is a constant.
    let rc = unsafe { libc::clock_gettime(libc::CLOCK_PROCESS_CPUTIME_ID, &mut ts) };
    if rc != 0 {
        return f64::NAN;
    }
    ts.tv_sec as f64 + ts.tv_nsec as f64 * 1e-9
}

/// Wall-clock and process-CPU seconds of one training epoch over `data.train` (no
/// validation), after `warmup` batches: the numbers `bowden bench train` reports.
pub fn time_epoch(data: &WindowSet, cfg: &TrainConfig, warmup: usize) -> Result<(f64, f64), TrainError> {
    let spec = ModelSpec::new(cfg.arch, cfg.seq_len, data.joints, cfg.tcn_block);
    let mut engine = Engine::new(spec, cfg)?;
    let mut rng = ChaCha8Rng::seed_from_u64(cfg.seed);
    let mut order = data.train.clone();
    order.shuffle(&mut rng);
    for batch in order.chunks(cfg.batch_size).take(warmup) {
        engine.step(data, batch)?;
    }
    let c0 = process_cpu_seconds();
    let t0 = Instant::now();
    for batch in order.chunks(cfg.batch_size) {
        engine.step(data, batch)?;
    }
    Ok((t0.elapsed().as_secs_f64(), process_cpu_seconds() - c0))
}
