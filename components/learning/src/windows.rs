//! From a dataset to training windows: which series is input and which is target (eq. 17,
//! 18), the 80/20 split by contiguous blocks, the normalisation statistics, and the
//! windows themselves with the paper's left zero padding.
//!
//! Padding is in raw degrees: before the first sample the history is 0°, exactly what the
//! compensator's history buffer holds at start-up; the padded rows are then normalised
//! like every other row (inside the exported graph, the normalisation is the first op).

use serde::{Deserialize, Serialize};

use crate::arch::Direction;
use crate::dataset::Dataset;

/// Where the physical (measured) joint angles come from.
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
pub enum PhySource {
    /// The vision estimate (`q_phy_*`), as the paper.
    #[default]
    Vision,
    /// The simulator's truth (`q_true_*`), simulated data only.
    Truth,
}

/// Per-joint affine normalisation: `(q − mean) / sd`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Normaliser {
    pub mean: Vec<f64>,
    pub sd: Vec<f64>,
}

impl Normaliser {
    /// Mean and population SD per joint of the given rows (`J` values each). A joint that
    /// does not move gets SD 1 (no division by ~0).
    pub fn fit<'a>(rows: impl Iterator<Item = &'a [f64]>, joints: usize) -> Self {
        let mut n = 0usize;
        let mut sum = vec![0.0; joints];
        let mut sum2 = vec![0.0; joints];
        let rows: Vec<&[f64]> = rows.collect();
        for r in &rows {
            n += 1;
            for j in 0..joints {
                sum[j] += r[j];
            }
        }
        // Rounded to f32: the exported graph stores f32, and the model must be trained with
        // exactly the normalisation it ships with.
        let mean: Vec<f64> = sum.iter().map(|s| (s / n.max(1) as f64) as f32 as f64).collect();
        for r in &rows {
            for j in 0..joints {
                sum2[j] += (r[j] - mean[j]).powi(2);
            }
        }
        let sd = sum2
            .iter()
            .map(|s| {
                let sd = (s / n.max(1) as f64).sqrt();
                if sd > 1e-6 {
                    sd as f32 as f64
                } else {
                    1.0
                }
            })
            .collect();
        Self { mean, sd }
    }

    pub fn joints(&self) -> usize {
        self.mean.len()
    }

    #[inline]
    pub fn apply(&self, j: usize, v_deg: f64) -> f32 {
        ((v_deg - self.mean[j]) / self.sd[j]) as f32
    }

    #[inline]
    pub fn invert(&self, j: usize, v: f32) -> f64 {
        v as f64 * self.sd[j] + self.mean[j]
    }
}

/// How to split a sequence into training and validation.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct SplitConfig {
    /// Fraction of samples in validation (paper: 0.2).
    pub val_fraction: f64,
    /// Number of contiguous validation blocks: the sequence is cut into this many equal
    /// segments and the last `val_fraction` of each is validation (1 = the last 20 %).
    pub val_blocks: usize,
}

impl Default for SplitConfig {
    fn default() -> Self {
        Self {
            val_fraction: 0.2,
            val_blocks: 1,
        }
    }
}

/// Why windows could not be made.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum WindowError {
    #[error("the dataset has no q_true columns; --phy-source truth needs simulated data")]
    NoTruth,
    #[error("the dataset has {joints} joints but the model expects {expected}")]
    Joints { joints: usize, expected: usize },
    #[error("val_fraction {0} is not in (0, 1)")]
    Fraction(f64),
    #[error("val_blocks must be at least 1")]
    Blocks,
    #[error("sequence length {0} must be at least 1")]
    SeqLen(usize),
    #[error("history decimation {0} must be at least 1")]
    Decimation(usize),
    #[error("no valid measurement in the dataset")]
    NoValid,
    #[error(
        "too little data: {train} training and {val} validation windows of length {seq_len} from {samples} samples"
    )]
    TooFew {
        train: usize,
        val: usize,
        seq_len: usize,
        samples: usize,
    },
}

/// Windows ready for training: the padded normalised input series, normalised targets,
/// and which target indices are in which split.
#[derive(Debug, Clone)]
pub struct WindowSet {
    pub joints: usize,
    pub seq_len: usize,
    pub direction: Direction,
    pub norm_in: Normaliser,
    pub norm_out: Normaliser,
    /// `(L − 1 + N) × J`: L − 1 padding rows (0° normalised), then every sample's input.
    xs: Vec<f32>,
    /// `N × J` normalised targets.
    ys: Vec<f32>,
    /// Raw degrees of input and target, `N × J` each (identity baselines, reports).
    pub input_deg: Vec<f64>,
    pub target_deg: Vec<f64>,
    pub train: Vec<usize>,
    pub val: Vec<usize>,
    /// Windows dropped because their span crosses a train/validation boundary.
    pub purged: usize,
    /// Samples whose measurement was invalid (filled for inputs, never a target).
    pub invalid_samples: usize,
    /// Largest history decimation of the training windows (1: every window reads consecutive
    /// samples, as the paper; see [`Self::set_decimation`]).
    pub decimation: usize,
    /// Per sample, the newest command turning point strictly before it (sample 0 counts as
    /// one): where a decimated history must stop so that it skips only monotone stretches.
    turn_before: Vec<usize>,
    /// Per sample, whether it lies in a validation block.
    val_mask: Vec<bool>,
}

impl WindowSet {
    pub fn build(
        ds: &Dataset,
        direction: Direction,
        seq_len: usize,
        split: SplitConfig,
        phy: PhySource,
    ) -> Result<Self, WindowError> {
        Self::build_split(ds, direction, seq_len, Some(split), phy)
    }

    /// Every valid target in `train`, `val` empty, nothing purged: the caller assigns the
    /// windows (`bowden adapt` holds out the newest rows itself), and sets the normalisation
    /// with [`Self::with_normalisers`] (the one fitted here is over all samples).
    pub fn build_unsplit(
        ds: &Dataset,
        direction: Direction,
        seq_len: usize,
        phy: PhySource,
    ) -> Result<Self, WindowError> {
        Self::build_split(ds, direction, seq_len, None, phy)
    }

    // Long: windows, normalisation and the split built together so every window's statistics come from its own side of the split.
    fn build_split(
        ds: &Dataset,
        direction: Direction,
        seq_len: usize,
        split: Option<SplitConfig>,
        phy: PhySource,
    ) -> Result<Self, WindowError> {
        let unsplit = split.is_none();
        let split = split.unwrap_or_default();
        if seq_len == 0 {
            return Err(WindowError::SeqLen(seq_len));
        }
        if !(split.val_fraction > 0.0 && split.val_fraction < 1.0) {
            return Err(WindowError::Fraction(split.val_fraction));
        }
        if split.val_blocks == 0 {
            return Err(WindowError::Blocks);
        }
        let j = ds.joints;
        let n = ds.len();
        let phy_raw: &[f64] = match phy {
            PhySource::Vision => &ds.q_phy_deg,
            PhySource::Truth => ds.q_true_deg.as_deref().ok_or(WindowError::NoTruth)?,
        };
        let valid: Vec<bool> = match phy {
            PhySource::Vision => ds.valid.clone(),
            PhySource::Truth => vec![true; n],
        };
        let first_valid = valid.iter().position(|&v| v).ok_or(WindowError::NoValid)?;
        // An invalid measurement inside an input history is replaced by the last valid one
        // (the first valid one before any): the history stays a sequence in time.
        let mut phy_filled = vec![0.0; n * j];
        let mut last = first_valid;
        for i in 0..n {
            if valid[i] {
                last = i;
            }
            let src = if valid[i] { i } else { last };
            phy_filled[i * j..(i + 1) * j].copy_from_slice(&phy_raw[src * j..(src + 1) * j]);
        }
        let (input_deg, target_deg) = match direction {
            Direction::Forward => (ds.q_cmd_deg.clone(), phy_filled),
            Direction::Inverse => (phy_filled, ds.q_cmd_deg.clone()),
        };

        // Split labels: true = validation.
        let mut is_val = vec![false; n];
        for b in 0..if unsplit { 0 } else { split.val_blocks } {
            let start = b * n / split.val_blocks;
            let end = (b + 1) * n / split.val_blocks;
            let len = end - start;
            let n_val = ((len as f64) * split.val_fraction).round() as usize;
            for v in &mut is_val[end - n_val.min(len)..end] {
                *v = true;
            }
        }
        // A window (target t) spans samples t−L+1 ..= t; keep it only if the whole span
        // (clamped at 0: padding belongs to no split) is in one split.
        let mut train = Vec::new();
        let mut val = Vec::new();
        let mut purged = 0;
        // Last index where the label changed, to test a span in O(1).
        let mut last_change = 0usize;
        for t in 0..n {
            if t > 0 && is_val[t] != is_val[t - 1] {
                last_change = t;
            }
            if !valid[t] {
                continue;
            }
            let span_start = (t + 1).saturating_sub(seq_len);
            if span_start < last_change {
                purged += 1;
                continue;
            }
            if is_val[t] {
                val.push(t);
            } else {
                train.push(t);
            }
        }
        if train.is_empty() || (val.is_empty() && !unsplit) {
            return Err(WindowError::TooFew {
                train: train.len(),
                val: val.len(),
                seq_len,
                samples: n,
            });
        }
        // Statistics from training samples only (no leak of validation into the model).
        let mut in_train = vec![false; n];
        for &t in &train {
            in_train[(t + 1).saturating_sub(seq_len)..=t].fill(true);
        }
        let norm_in = Normaliser::fit(
            (0..n).filter(|&i| in_train[i]).map(|i| &input_deg[i * j..(i + 1) * j]),
            j,
        );
        let norm_out = Normaliser::fit(train.iter().map(|&t| &target_deg[t * j..(t + 1) * j]), j);

        let mut xs = Vec::with_capacity((seq_len - 1 + n) * j);
        for _ in 0..seq_len - 1 {
            for k in 0..j {
                xs.push(norm_in.apply(k, 0.0));
            }
        }
        for i in 0..n {
            for k in 0..j {
                xs.push(norm_in.apply(k, input_deg[i * j + k]));
            }
        }
        let mut ys = Vec::with_capacity(n * j);
        for i in 0..n {
            for k in 0..j {
                ys.push(norm_out.apply(k, target_deg[i * j + k]));
            }
        }
        Ok(Self {
            joints: j,
            seq_len,
            direction,
            norm_in,
            norm_out,
            xs,
            ys,
            input_deg,
            target_deg,
            train,
            val,
            purged,
            invalid_samples: valid.iter().filter(|&&v| !v).count(),
            decimation: 1,
            turn_before: Vec::new(),
            val_mask: is_val,
        })
    }

    /// Number of samples (targets, valid or not) in the set.
    pub fn samples(&self) -> usize {
        self.target_deg.len() / self.joints
    }

    /// The commanded series, `N × J` degrees (the input of a forward model, the target of an
    /// inverse one).
    pub fn commands_deg(&self) -> &[f64] {
        match self.direction {
            Direction::Forward => &self.input_deg,
            Direction::Inverse => &self.target_deg,
        }
    }

    /// Trains on histories decimated by up to `max_decimation` samples per model step
    /// (training windows only: validation always reads consecutive samples, the data's own
    /// spacing). Each decimated step skips at most `s − 1` samples and never a turning point of
    /// the commands (a sample where some joint reverses; sample 0 counts as one), so between
    /// two samples of a decimated history every joint moves one way only.
    ///
    /// Why this is sound: a rate-independent hysteresis operator (play/Prandtl–Ishlinskii,
    /// Preisach, Bouc–Wen with rate-independent parameters) commutes with reparametrisation in
    /// time, and its memory is the sequence of input extrema (Brokate & Sprekels, *Hysteresis
    /// and Phase Transitions*, 1996, §2.2; Visintin, *Differential Models of Hysteresis*, 1994).
    /// A monotone stretch commanded in one step or in many leaves the same output, so the
    /// decimated window is a history the robot could have been commanded, and its recorded
    /// target is what the robot would have done — up to rate-dependent effects (creep,
    /// friction dynamics) that the dataset's 0.5 s pauses keep small. What it adds is what
    /// eq. (16) lacks: steps several times the dataset's spacing, which the compensator sends
    /// whenever it crosses a dead band.
    ///
    /// Training windows whose decimated span would read a validation sample are dropped (and
    /// counted in `purged`; a later call with a smaller decimation does not bring them back, so
    /// call it once, after building). Errors on `max_decimation = 0`.
    pub fn set_decimation(&mut self, max_decimation: usize) -> Result<(), WindowError> {
        if max_decimation == 0 {
            return Err(WindowError::Decimation(max_decimation));
        }
        self.decimation = max_decimation;
        if max_decimation == 1 {
            self.turn_before.clear();
            return Ok(());
        }
        let (n, j) = (self.samples(), self.joints);
        let cmd = self.commands_deg();
        // Last non-zero direction of each joint (0 = not moved yet).
        let mut dir = vec![0.0f64; j];
        let mut turn_before = vec![0usize; n];
        let mut last_turn = 0usize;
        for i in 1..n {
            turn_before[i] = last_turn;
            // Is sample i a turning point: does some joint reverse between (i−1 → i) and
            // (i → i+1)?
            let mut turns = false;
            for k in 0..j {
                let d = cmd[i * j + k] - cmd[(i - 1) * j + k];
                if d != 0.0 {
                    dir[k] = d.signum();
                }
                if i + 1 < n {
                    let next = cmd[(i + 1) * j + k] - cmd[i * j + k];
                    turns |= next * dir[k] < 0.0;
                }
            }
            if turns {
                last_turn = i;
            }
        }
        self.turn_before = turn_before;
        // Drop training windows whose widest history reads a validation sample.
        let mut val_prefix = vec![0usize; n + 1];
        for i in 0..n {
            val_prefix[i + 1] = val_prefix[i] + self.val_mask[i] as usize;
        }
        let before = self.train.len();
        let mut train = std::mem::take(&mut self.train);
        train.retain(|&t| {
            let mut start = t;
            for _ in 1..self.seq_len {
                match self.previous(start, max_decimation) {
                    Some(p) => start = p,
                    None => break,
                }
            }
            val_prefix[t + 1] == val_prefix[start]
        });
        self.purged += before - train.len();
        self.train = train;
        Ok(())
    }

    /// The sample before `i` in a history decimated by `s` (`None`: the zero padding).
    #[inline]
    fn previous(&self, i: usize, s: usize) -> Option<usize> {
        if i == 0 {
            return None;
        }
        if s == 1 {
            return Some(i - 1);
        }
        // Never skip the newest turning point: a decimated step spans a monotone stretch.
        Some(i.saturating_sub(s).max(self.turn_before[i]))
    }

    /// The samples window `id` reads (an id as [`Self::gather`] takes it), oldest first;
    /// `None` is the zero padding before the first sample.
    pub fn history(&self, id: usize) -> Vec<Option<usize>> {
        let n = self.samples();
        let (t, s) = (id % n, id / n + 1);
        let mut rows = vec![None; self.seq_len];
        let mut i = Some(t);
        for row in rows.iter_mut().rev() {
            *row = i;
            i = i.and_then(|i| self.previous(i, s));
        }
        rows
    }

    /// The training ids of one epoch: each of `targets` with a history decimation drawn
    /// uniformly from 1..=`decimation` (encoded as `t + (s − 1)·N`, what [`Self::gather`]
    /// reads). With decimation 1 the ids are the targets themselves.
    pub fn decimated_ids(&self, targets: &[usize], rng: &mut impl rand::Rng, out: &mut Vec<usize>) {
        out.clear();
        let n = self.samples();
        if self.decimation <= 1 {
            out.extend_from_slice(targets);
            return;
        }
        out.extend(targets.iter().map(|&t| t + rng.random_range(0..self.decimation) * n));
    }

    /// Largest command step of each joint inside the decimated training histories (one model
    /// step): `None` when the windows are not decimated.
    pub fn decimated_cmd_step_max_deg(&self) -> Option<Vec<f64>> {
        if self.decimation <= 1 {
            return None;
        }
        let j = self.joints;
        let cmd = self.commands_deg();
        let mut m = vec![0.0f64; j];
        for &t in &self.train {
            for s in 2..=self.decimation {
                if let Some(p) = self.previous(t, s) {
                    for k in 0..j {
                        m[k] = m[k].max((cmd[t * j + k] - cmd[p * j + k]).abs());
                    }
                }
            }
        }
        Some(m)
    }

    /// The same windows under another model's normalisation (fine-tuning keeps the
    /// normalisation the model was trained and exported with; `bowden adapt`).
    pub fn with_normalisers(mut self, norm_in: Normaliser, norm_out: Normaliser) -> Result<Self, WindowError> {
        let j = self.joints;
        if norm_in.joints() != j || norm_out.joints() != j {
            return Err(WindowError::Joints {
                joints: j,
                expected: norm_in.joints(),
            });
        }
        let n = self.target_deg.len() / j;
        let pad = self.seq_len - 1;
        for i in 0..pad {
            for k in 0..j {
                self.xs[i * j + k] = norm_in.apply(k, 0.0);
            }
        }
        for i in 0..n {
            for k in 0..j {
                self.xs[(pad + i) * j + k] = norm_in.apply(k, self.input_deg[i * j + k]);
                self.ys[i * j + k] = norm_out.apply(k, self.target_deg[i * j + k]);
            }
        }
        self.norm_in = norm_in;
        self.norm_out = norm_out;
        Ok(self)
    }

    /// Drops the windows that reach into the zero padding before the first sample: data
    /// gathered mid-operation had a real history there, which the padding would misstate.
    pub fn drop_padded(&mut self) {
        let first = self.seq_len - 1;
        self.train.retain(|&t| t >= first);
        self.val.retain(|&t| t >= first);
    }

    /// The normalised window of target `t`: `L × J`, oldest first.
    #[inline]
    pub fn window(&self, t: usize) -> &[f32] {
        &self.xs[t * self.joints..(t + self.seq_len) * self.joints]
    }

    /// The normalised target of `t`.
    #[inline]
    pub fn target(&self, t: usize) -> &[f32] {
        &self.ys[t * self.joints..(t + 1) * self.joints]
    }

    /// The raw-degree window of target `t` (0° before the first sample).
    pub fn window_deg(&self, t: usize) -> Vec<f64> {
        let (l, j) = (self.seq_len, self.joints);
        let mut w = vec![0.0; l * j];
        for r in 0..l {
            if let Some(s) = (t + r + 1).checked_sub(l) {
                w[r * j..(r + 1) * j].copy_from_slice(&self.input_deg[s * j..(s + 1) * j]);
            }
        }
        w
    }

    /// Copies the windows and targets of `ids` into `x` (`[b][L][J]`) and `y` (`[b][J]`).
    /// An id is a target index, or `t + (s − 1)·N` for target `t` with its history decimated
    /// by `s` ([`Self::decimated_ids`]).
    pub fn gather(&self, ids: &[usize], x: &mut [f32], y: &mut [f32]) {
        let (l, j) = (self.seq_len, self.joints);
        let lj = l * j;
        let n = self.samples();
        for (r, &id) in ids.iter().enumerate() {
            let (t, s) = (id % n, id / n + 1);
            let xw = &mut x[r * lj..(r + 1) * lj];
            if s == 1 {
                xw.copy_from_slice(self.window(t));
            } else {
                // Newest row last; rows before the first sample are the padding (xs row 0).
                let mut i = Some(t);
                for row in (0..l).rev() {
                    let src = i.map_or(0, |i| i + l - 1);
                    xw[row * j..(row + 1) * j].copy_from_slice(&self.xs[src * j..(src + 1) * j]);
                    i = i.and_then(|i| self.previous(i, s));
                }
            }
            y[r * j..(r + 1) * j].copy_from_slice(self.target(t));
        }
    }

    /// Span of samples (inclusive) that window `t` reads.
    pub fn span(&self, t: usize) -> (usize, usize) {
        ((t + 1).saturating_sub(self.seq_len), t)
    }

    /// RMSE per joint (degrees) of predicting the target by the newest input (the identity
    /// model q_phy = q_cmd: the raw hysteresis) over the given windows.
    pub fn identity_rmse_deg(&self, ids: &[usize]) -> Vec<f64> {
        let j = self.joints;
        let mut s = vec![0.0; j];
        for &t in ids {
            let (inp, tgt) = (
                &self.input_deg[t * j..(t + 1) * j],
                &self.target_deg[t * j..(t + 1) * j],
            );
            for ((acc, a), b) in s.iter_mut().zip(inp).zip(tgt) {
                *acc += (a - b).powi(2);
            }
        }
        s.iter().map(|v| (v / ids.len().max(1) as f64).sqrt()).collect()
    }
}

/// √(mean of the per-joint mean squares): the overall RMSE over joints and samples.
pub fn overall_rmse(per_joint: &[f64]) -> f64 {
    (per_joint.iter().map(|r| r * r).sum::<f64>() / per_joint.len().max(1) as f64).sqrt()
}
