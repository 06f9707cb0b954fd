//! Vision feedback (`[feedback]` of the controller config; docs/architecture.md, "Vision
//! feedback"): a bounded, leaky, anti-windup integrator of the measured tracking error, on
//! top of the learned feed-forward.
//!
//! Per joint k and per update (the mean of `frames_per_update` settled frames),
//!
//! ```text
//! e_k = r_k(t_capture) − q_est,k          r: the desired angles when the frame was taken
//! u_k ← clamp((1 − leak)·u_k + gain·e_k, ±integrator_max_deg)
//! ```
//!
//! and the compensator runs on `q_desired + u + b` (`apply = "target"`: the learned models
//! turn the corrected target into a command, dead band included) or adds `u + b` to its
//! command (`apply = "command"`).
//!
//! - **Two time scales.** `u` is local: a jump forgets it (`keep_on_jump`), because what the
//!   feed-forward leaves at one held point says little about the next one. `b` is the slow
//!   part, kept across jumps: an error common to every configuration — a cable that crept or
//!   slipped, an offset the models never saw — is learned once instead of at every held
//!   point. At each jump, the local correction the point just left needed (`u`, which the
//!   held frames drove to what the feed-forward and `b` left there) is averaged, per joint:
//!
//!   ```text
//!   m_k ← m_k + (u_k − m_k) / bias_window              the mean need over the last points
//!   x_k = sign(m_k)·max(|m_k| − bias_deadband_deg, 0)  the part beyond the dead band
//!   b_k ← clamp(b_k + bias_gain·x_k, ±bias_max_deg);  m_k ← m_k − Δb_k;  u_k ← u_k − Δb_k
//!   ```
//!
//!   The dead band keeps the configuration-dependent residual of a calibrated feed-forward
//!   (its mean over points falls inside it) out of `b`; `m` and `u` give up what `b` took,
//!   because the next points need that much less. Per point, with a constant need d and u
//!   converged, (m, d − b) evolves with determinant (1 − β)(1 − α) and Jury margin β·α > 0
//!   (α = 1/bias_window, β = bias_gain): stable for every α, β in (0, 1]. `b` moves only at
//!   jumps, so within a hold the loop is `u`'s alone. Off (`bias_gain = 0`) by default, and
//!   then the output is bit for bit that of `u` alone.
//!
//! - **Delay.** The estimate's header carries the tick of the target in force when the frame
//!   was captured (the camera stamps the tick of the plant state it rendered, which carries
//!   the tick of the command that produced it). A fixed ring of recent desired angles, keyed
//!   by tick, gives `r(t_capture)`: a frame is compared with what was wanted *then*, never
//!   with the newer target.
//! - **Reference lag.** With `reference_tau_ms > 0`, `r` is the desired angles passed through
//!   a first-order lag of that time constant, the settling the robot itself needs: the error
//!   then measures what the feed-forward left, not how far a moving robot lags.
//! - **Settling.** A frame captured less than `settle_ms` after the correction last changed,
//!   or after the target jumped by more than `jump_deg`, does not show the new state yet: it
//!   is not integrated (it still counts as a sign of visible markers). The test is on the
//!   capture time, so the camera's latency adds no delay to the loop: every update sees the
//!   settled effect of the previous one, and `gain + leak < 2` is the loop's stability bound
//!   (enforced at load).
//! - **Locality.** A jump also scales the correction by `keep_on_jump` (0 by default): what
//!   the feed-forward leaves at one held point says little about the next one 6.7° away.
//! - **Validity.** An estimate is used only with the right joint count, quality `valid`
//!   (or `partial` with `use_partial`: its valid joints only), finite angles, age ≤
//!   `max_age_ms`, a capture newer than the last one seen, a known tick, and every error
//!   within `max_error_deg`. Everything else is rejected and counted; nothing panics.
//! - **Anti-windup.** `u` is clamped per joint, and a joint whose last command sat at an
//!   upper (lower) bound — a joint limit or the training data's command range — does not
//!   integrate a positive (negative) error.
//! - **Marker loss.** While no usable estimate arrives the correction is held. After
//!   `loss_timeout_ms` without one it is reset to zero: the output is the feed-forward alone,
//!   bit for bit, until markers return. Each such fallback is counted.
//!
//! Everything is sized in [`Feedback::new`]; the per-cycle calls allocate nothing.

use bowden_interfaces::model::MAX_JOINTS;
use bowden_interfaces::JointEstimate;
use serde::Deserialize;

/// Where the correction goes.
#[derive(
    Debug,
    Clone,
    Copy,
    PartialEq,
    Eq,
    Deserialize,
    Default,
    strum::EnumString,
    strum::IntoStaticStr,
    strum::Display,
    strum::VariantNames,
    strum::VariantArray,
)]
#[serde(rename_all = "lowercase")]
#[strum(serialize_all = "lowercase")]
pub enum ApplyTo {
    /// The compensator runs on `q_desired + u`: the learned inverse turns the corrected
    /// target into a command, crossing the dead band where the robot needs it.
    #[default]
    Target,
    /// `u` is added to the feed-forward command (before the rate and joint limits).
    Command,
}

impl ApplyTo {
    /// The spelling in configs, reports and on the command line.
    pub fn as_str(self) -> &'static str {
        self.into()
    }
}

/// `[feedback]` of the controller config. Absent = disabled, and the compensator computes
/// exactly what it did without it.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct FeedbackConfig {
    /// Use the estimator's `JointEstimate` stream while running.
    pub enabled: bool,
    /// Where the correction goes (`target` or `command`).
    pub apply: ApplyTo,
    /// Integrator gain per update (deg of correction per deg of averaged error). Above
    /// `2 − leak` the loop diverges even with settled frames (refused at load); below 1 it is
    /// stable however little of the last change a frame shows.
    pub gain: f64,
    /// Per-joint bound of the correction, deg (anti-windup).
    pub integrator_max_deg: f64,
    /// Fraction of the correction forgotten per update, [0, 1).
    pub leak: f64,
    /// Frames captured less than this after the correction changed (or the target jumped)
    /// are not integrated, ms. Frames captured before the change never are.
    pub settle_ms: f64,
    /// A target step larger than this on any joint (between two consecutive targets) is a
    /// jump: like a correction change, it restarts the settle time, deg.
    pub jump_deg: f64,
    /// Fraction of the correction kept across a jump, [0, 1]: 0 forgets it (a correction is
    /// local to the configuration it was measured at), 1 keeps it.
    pub keep_on_jump: f64,
    /// Share of the averaged local correction beyond the dead band that the slow correction
    /// `b` (kept across jumps) takes at each jump, [0, 1] (0 = none).
    pub bias_gain: f64,
    /// Per-joint bound of the slow correction, deg (anti-windup).
    pub bias_max_deg: f64,
    /// The slow correction follows the mean of the local corrections the last this many held
    /// points needed (an exponential average, weight 1/N per point; 1 = the last point alone).
    pub bias_window: u32,
    /// Only the part of that mean beyond this is learned, deg: the configuration-dependent
    /// residual of a calibrated feed-forward averages to less, a slipped or crept cable does
    /// not.
    pub bias_deadband_deg: f64,
    /// Settled frames averaged into one update (1 = every settled frame updates): the
    /// estimate's noise enters the correction divided by √N.
    pub frames_per_update: u32,
    /// Time constant of the reference lag applied to the desired angles, ms (0 = none).
    pub reference_tau_ms: f64,
    /// Estimates older than this when they are read are skipped, ms.
    pub max_age_ms: f64,
    /// Without a usable estimate for this long the correction is reset (pure feed-forward), ms.
    pub loss_timeout_ms: f64,
    /// An estimate with any joint error beyond this is rejected as an outlier, deg.
    pub max_error_deg: f64,
    /// Use partial estimates (their valid joints only); otherwise they are skipped.
    pub use_partial: bool,
    /// Also correct the `uncalibrated` controller (by default it stays the paper's
    /// pass-through, the baseline every reduction is measured against).
    pub in_uncalibrated: bool,
}

impl Default for FeedbackConfig {
    /// Off; the other values are those of configs/controller-feedback-realtime.toml
    /// (configs/controller-feedback.toml raises the gain to 0.8: a 10 fps camera gives the
    /// loop 4 frames per held point).
    fn default() -> Self {
        Self {
            enabled: false,
            apply: ApplyTo::Target,
            gain: 0.5,
            integrator_max_deg: 5.0,
            leak: 0.0,
            settle_ms: 30.0,
            jump_deg: 1.0,
            keep_on_jump: 0.0,
            bias_gain: 0.0,
            bias_max_deg: 5.0,
            bias_window: 1,
            bias_deadband_deg: 0.0,
            frames_per_update: 1,
            reference_tau_ms: 80.0,
            max_age_ms: 200.0,
            loss_timeout_ms: 1000.0,
            max_error_deg: 45.0,
            use_partial: false,
            in_uncalibrated: false,
        }
    }
}

/// `gain + leak` must stay below this: the delay-free loop `u ← (1 − leak − gain)·u + gain·r`
/// (r: what the feed-forward leaves, bounded) is stable only for |1 − leak − gain| < 1, and
/// no timing makes a larger gain stable. (The slow correction moves only at jumps, between
/// holds, and has its own bound: `bias_gain` in [0, 1].)
pub const LOOP_GAIN_BOUND: f64 = 2.0;

impl FeedbackConfig {
    /// Checks every field: `Err((field, value, reason))`, the field named as in the file.
    pub fn check(&self) -> Result<(), (&'static str, String, &'static str)> {
        let in_range = |v: f64, lo: f64, hi: f64| v.is_finite() && v >= lo && v <= hi;
        if !(self.leak.is_finite() && self.leak >= 0.0 && self.leak < 1.0) {
            return Err(("feedback.leak", self.leak.to_string(), "must be in [0, 1)"));
        }
        if !(self.gain.is_finite() && self.gain > 0.0) {
            return Err(("feedback.gain", self.gain.to_string(), "must be a positive number"));
        }
        if !in_range(self.bias_gain, 0.0, 1.0) {
            return Err((
                "feedback.bias_gain",
                self.bias_gain.to_string(),
                "must be in [0, 1] (0 = no slow correction): the share of the averaged need b takes \
                 at each jump",
            ));
        }
        if self.gain + self.leak >= LOOP_GAIN_BOUND {
            return Err((
                "feedback.gain",
                self.gain.to_string(),
                "gain + leak must be < 2: above it the integrator diverges even on an ideal robot \
                 without delay (docs/architecture.md, \"Vision feedback\")",
            ));
        }
        if !(1..=10_000).contains(&self.bias_window) {
            return Err((
                "feedback.bias_window",
                self.bias_window.to_string(),
                "must be in 1..=10000",
            ));
        }
        if !in_range(self.bias_deadband_deg, 0.0, 45.0) {
            return Err((
                "feedback.bias_deadband_deg",
                self.bias_deadband_deg.to_string(),
                "must be in [0, 45]",
            ));
        }
        if !(self.bias_max_deg.is_finite() && self.bias_max_deg > 0.0 && self.bias_max_deg <= 45.0) {
            return Err((
                "feedback.bias_max_deg",
                self.bias_max_deg.to_string(),
                "must be in (0, 45]",
            ));
        }
        if !(self.integrator_max_deg.is_finite() && self.integrator_max_deg > 0.0 && self.integrator_max_deg <= 45.0) {
            return Err((
                "feedback.integrator_max_deg",
                self.integrator_max_deg.to_string(),
                "must be in (0, 45]",
            ));
        }
        if !in_range(self.settle_ms, 0.0, 10_000.0) {
            return Err((
                "feedback.settle_ms",
                self.settle_ms.to_string(),
                "must be in [0, 10000]",
            ));
        }
        if !(self.jump_deg.is_finite() && self.jump_deg > 0.0) {
            return Err((
                "feedback.jump_deg",
                self.jump_deg.to_string(),
                "must be a positive number",
            ));
        }
        if !in_range(self.keep_on_jump, 0.0, 1.0) {
            return Err((
                "feedback.keep_on_jump",
                self.keep_on_jump.to_string(),
                "must be in [0, 1]",
            ));
        }
        if !(1..=100).contains(&self.frames_per_update) {
            return Err((
                "feedback.frames_per_update",
                self.frames_per_update.to_string(),
                "must be in 1..=100",
            ));
        }
        if !in_range(self.reference_tau_ms, 0.0, 10_000.0) {
            return Err((
                "feedback.reference_tau_ms",
                self.reference_tau_ms.to_string(),
                "must be in [0, 10000] (0 = no reference lag)",
            ));
        }
        if !(self.max_age_ms.is_finite() && self.max_age_ms > 0.0 && self.max_age_ms <= 10_000.0) {
            return Err((
                "feedback.max_age_ms",
                self.max_age_ms.to_string(),
                "must be in (0, 10000]",
            ));
        }
        if !(self.loss_timeout_ms.is_finite() && self.loss_timeout_ms > 0.0 && self.loss_timeout_ms <= 600_000.0) {
            return Err((
                "feedback.loss_timeout_ms",
                self.loss_timeout_ms.to_string(),
                "must be in (0, 600000]",
            ));
        }
        if !(self.max_error_deg.is_finite() && self.max_error_deg > 0.0 && self.max_error_deg <= 180.0) {
            return Err((
                "feedback.max_error_deg",
                self.max_error_deg.to_string(),
                "must be in (0, 180]",
            ));
        }
        Ok(())
    }
}

/// What [`Feedback::observe`] did with one estimate.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Observation {
    /// Accepted: added to the average the next update integrates (once `frames_per_update`
    /// frames are in).
    Accepted,
    /// Usable, but captured before the last correction change had settled: only refreshes
    /// the marker-loss timer.
    Settling,
    /// Quality `invalid`, or no valid joint.
    Invalid,
    /// Quality `partial` without `use_partial`.
    Partial,
    /// A joint count other than the compensator's.
    WrongSize,
    /// A non-finite angle in a joint marked valid.
    NotFinite,
    /// Older than `max_age_ms`, or not newer than an estimate already seen.
    Stale,
    /// Its tick is not in the ring of recent targets (too old, or from before a restart).
    UnknownTick,
    /// A joint error beyond `max_error_deg`.
    Outlier,
}

/// Counters since [`Feedback::new`] (or [`Feedback::reset`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct FeedbackCounts {
    /// Estimates offered.
    pub estimates: u64,
    /// Frames integrated (integrator updates).
    pub updates: u64,
    /// Usable frames skipped while the last change settled.
    pub settling: u64,
    pub invalid: u64,
    pub partial: u64,
    pub wrong_size: u64,
    pub not_finite: u64,
    pub stale: u64,
    pub unknown_tick: u64,
    pub outliers: u64,
    /// Joint updates skipped because the command sat at a bound in the error's direction.
    pub windup_holds: u64,
    /// Joint updates that hit `integrator_max_deg`.
    pub clamped: u64,
    /// Joint updates of the slow correction that hit `bias_max_deg`.
    pub bias_clamped: u64,
    /// Marker-loss fallbacks to pure feed-forward.
    pub loss_episodes: u64,
}

impl FeedbackCounts {
    /// Estimates rejected as unusable (what the node reports as rejected samples).
    pub fn rejected(&self) -> u64 {
        self.invalid + self.partial + self.wrong_size + self.not_finite + self.outliers
    }
}

#[derive(Debug, Clone, Copy)]
struct RingEntry {
    tick: u64,
    used: bool,
    r: [f64; MAX_JOINTS],
}

const EMPTY: RingEntry = RingEntry {
    tick: 0,
    used: false,
    r: [0.0; MAX_JOINTS],
};

/// The feedback state of one compensator. See the module documentation.
#[derive(Debug, Clone)]
pub struct Feedback {
    cfg: FeedbackConfig,
    j: usize,
    ring: Vec<RingEntry>,
    reference: [f64; MAX_JOINTS],
    t_reference_ns: Option<u64>,
    last_desired: [f64; MAX_JOINTS],
    /// The local correction (forgotten on a jump) and the slow one (kept), and their sum,
    /// which is what is applied.
    u: [f64; MAX_JOINTS],
    b: [f64; MAX_JOINTS],
    total: [f64; MAX_JOINTS],
    /// An update happened since the last jump: `u` holds what that point needed.
    updated_since_jump: bool,
    /// Average local correction of the last points that `b` has not taken yet.
    bias_mean: [f64; MAX_JOINTS],
    zero: [f64; MAX_JOINTS],
    /// Sum and count per joint of the settled errors accepted since the last update, and the
    /// number of frames in it.
    acc_sum: [f64; MAX_JOINTS],
    acc_n: [u32; MAX_JOINTS],
    acc_frames: u32,
    /// Capture time of the newest estimate seen (ordering).
    last_capture_ns: Option<u64>,
    /// Capture time of the newest usable estimate (marker-loss timer).
    last_usable_ns: Option<u64>,
    /// When the correction last changed (the settle gate).
    t_change_ns: Option<u64>,
    t_start_ns: Option<u64>,
    lost: bool,
    upper_mask: u32,
    lower_mask: u32,
    u_abs_max: f64,
    b_abs_max: f64,
    counts: FeedbackCounts,
}

fn ms_to_ns(ms: f64) -> u64 {
    (ms * 1e6).round() as u64
}

impl Feedback {
    /// Sizes the ring of recent targets for `max_age_ms` at the pipeline's `period_ns` (at
    /// least 1 kHz is assumed, so a faster trajectory stage still finds its ticks). The only
    /// allocation of the feedback path.
    pub fn new(cfg: &FeedbackConfig, joints: usize, period_ns: u64) -> Self {
        let period = period_ns.clamp(1, 1_000_000);
        let cap = (ms_to_ns(cfg.max_age_ms).div_ceil(period) as usize + 8).min(1 << 16);
        Self::with_ring(cfg, joints, vec![EMPTY; cap])
    }

    pub fn config(&self) -> &FeedbackConfig {
        &self.cfg
    }

    /// Records the target of tick `tick` (finite, `joints` entries; the caller validated it)
    /// at time `now_ns`: advances the reference lag, stores it in the ring, and restarts the
    /// settle time on a jump.
    pub fn begin(&mut self, tick: u64, q_desired_deg: &[f64], now_ns: u64) {
        let j = self.j;
        if self.t_start_ns.is_some() {
            let jump = (0..j).any(|k| (q_desired_deg[k] - self.last_desired[k]).abs() > self.cfg.jump_deg);
            if jump {
                self.t_change_ns = Some(now_ns);
                self.clear_average();
                if self.cfg.bias_gain > 0.0 && self.updated_since_jump {
                    self.learn_slow_correction();
                }
                let keep = self.cfg.keep_on_jump;
                for v in self.u[..j].iter_mut() {
                    *v *= keep;
                }
                self.sum_correction();
                self.updated_since_jump = false;
            }
        }
        self.last_desired[..j].copy_from_slice(&q_desired_deg[..j]);
        self.t_start_ns.get_or_insert(now_ns);
        match self.t_reference_ns {
            Some(t0) if self.cfg.reference_tau_ms > 0.0 => {
                let dt_s = now_ns.saturating_sub(t0) as f64 * 1e-9;
                let a = 1.0 - (-dt_s / (self.cfg.reference_tau_ms * 1e-3)).exp();
                for k in 0..j {
                    self.reference[k] += a * (q_desired_deg[k] - self.reference[k]);
                }
            }
            _ => self.reference[..j].copy_from_slice(&q_desired_deg[..j]),
        }
        self.t_reference_ns = Some(now_ns);
        let cap = self.ring.len();
        let e = &mut self.ring[(tick % cap as u64) as usize];
        e.tick = tick;
        e.used = true;
        e.r = self.reference;
    }

    /// Checks one estimate at time `now_ns` and, if usable and settled, adds its error to the
    /// average the next [`Self::update`] integrates. Never panics; every rejection is counted.
    pub fn observe(&mut self, est: &JointEstimate, now_ns: u64) -> Observation {
        self.counts.estimates += 1;
        let obs = self.classify(est, now_ns);
        let c = &mut self.counts;
        match obs {
            Observation::Accepted => {}
            Observation::Settling => c.settling += 1,
            Observation::Invalid => c.invalid += 1,
            Observation::Partial => c.partial += 1,
            Observation::WrongSize => c.wrong_size += 1,
            Observation::NotFinite => c.not_finite += 1,
            Observation::Stale => c.stale += 1,
            Observation::UnknownTick => c.unknown_tick += 1,
            Observation::Outlier => c.outliers += 1,
        }
        obs
    }

    fn classify(&mut self, est: &JointEstimate, now_ns: u64) -> Observation {
        let j = self.j;
        if est.n_joints as usize != j {
            return Observation::WrongSize;
        }
        let all = (1u32 << j) - 1;
        let mask = match est.quality {
            JointEstimate::QUALITY_VALID => all,
            JointEstimate::QUALITY_PARTIAL if self.cfg.use_partial => est.joint_valid_mask & all,
            JointEstimate::QUALITY_PARTIAL => return Observation::Partial,
            _ => return Observation::Invalid,
        };
        if mask == 0 {
            return Observation::Invalid;
        }
        if (0..j).any(|k| mask & (1 << k) != 0 && !est.q_phy_deg[k].is_finite()) {
            return Observation::NotFinite;
        }
        let t_capture = est.header.t_origin_ns;
        if self.last_capture_ns.is_some_and(|t| t_capture <= t) {
            return Observation::Stale;
        }
        if now_ns.saturating_sub(t_capture) > ms_to_ns(self.cfg.max_age_ms) {
            self.last_capture_ns = Some(t_capture);
            return Observation::Stale;
        }
        let cap = self.ring.len();
        let entry = self.ring[(est.header.tick % cap as u64) as usize];
        if !(entry.used && entry.tick == est.header.tick) {
            return Observation::UnknownTick;
        }
        let mut e = [0.0f64; MAX_JOINTS];
        for k in 0..j {
            if mask & (1 << k) != 0 {
                e[k] = entry.r[k] - est.q_phy_deg[k];
                if !e[k].is_finite() || e[k].abs() > self.cfg.max_error_deg {
                    return Observation::Outlier;
                }
            }
        }
        self.last_capture_ns = Some(t_capture);
        self.last_usable_ns = Some(t_capture);
        if self.lost {
            // Markers are back: the correction restarts from zero.
            self.lost = false;
        }
        if self
            .t_change_ns
            .is_some_and(|t| t_capture < t.saturating_add(ms_to_ns(self.cfg.settle_ms)))
        {
            return Observation::Settling;
        }
        for k in 0..j {
            if mask & (1 << k) != 0 {
                self.acc_sum[k] += e[k];
                self.acc_n[k] += 1;
            }
        }
        self.acc_frames += 1;
        Observation::Accepted
    }

    /// Integrates the mean error of the accepted frames once `frames_per_update` are in, and
    /// applies the marker-loss timeout, at time `now_ns`. Returns the correction to apply:
    /// `u`, or zeros while markers are lost.
    pub fn update(&mut self, now_ns: u64) -> &[f64] {
        let j = self.j;
        if self.acc_frames >= self.cfg.frames_per_update {
            let (k_gain, keep, max) = (self.cfg.gain, 1.0 - self.cfg.leak, self.cfg.integrator_max_deg);
            let mut changed = false;
            let mut e = [0.0f64; MAX_JOINTS];
            for k in 0..j {
                if self.acc_n[k] > 0 {
                    e[k] = self.acc_sum[k] / f64::from(self.acc_n[k]);
                }
            }
            let present = |k: usize| self.acc_n[k] > 0;
            let mask: u32 = (0..j).filter(|&k| present(k)).fold(0, |m, k| m | (1 << k));
            self.clear_average();
            for k in 0..j {
                if mask & (1 << k) == 0 {
                    continue;
                }
                let bit = 1u32 << k;
                if (e[k] > 0.0 && self.upper_mask & bit != 0) || (e[k] < 0.0 && self.lower_mask & bit != 0) {
                    self.counts.windup_holds += 1;
                    continue;
                }
                let v = keep * self.u[k] + k_gain * e[k];
                let c = v.clamp(-max, max);
                if c != v {
                    self.counts.clamped += 1;
                }
                changed |= c != self.u[k];
                self.u[k] = c;
            }
            self.sum_correction();
            for k in 0..j {
                self.u_abs_max = self.u_abs_max.max(self.total[k].abs());
            }
            self.counts.updates += 1;
            self.updated_since_jump = true;
            if changed {
                self.t_change_ns = Some(now_ns);
            }
        }
        let since = self.last_usable_ns.or(self.t_start_ns).unwrap_or(now_ns);
        if !self.lost && now_ns.saturating_sub(since) > ms_to_ns(self.cfg.loss_timeout_ms) {
            self.lost = true;
            self.counts.loss_episodes += 1;
            if self.total[..j].iter().any(|&v| v != 0.0) {
                self.t_change_ns = Some(now_ns);
            }
            self.u = [0.0; MAX_JOINTS];
            self.b = [0.0; MAX_JOINTS];
            self.bias_mean = [0.0; MAX_JOINTS];
            self.sum_correction();
            self.clear_average();
        }
        if self.lost {
            &self.zero[..j]
        } else {
            &self.total[..j]
        }
    }

    /// At a jump: the local correction the point just left needed (`u`, which the held
    /// frames drove to what the feed-forward and `b` left there) enters the average `m`; `b`
    /// takes `bias_gain` of its part beyond the dead band, and `m` and `u` give up what `b`
    /// took.
    fn learn_slow_correction(&mut self) {
        let alpha = 1.0 / f64::from(self.cfg.bias_window);
        let (gain, band, max) = (self.cfg.bias_gain, self.cfg.bias_deadband_deg, self.cfg.bias_max_deg);
        for k in 0..self.j {
            let m = &mut self.bias_mean[k];
            *m += alpha * (self.u[k] - *m);
            let excess = m.signum() * (m.abs() - band).max(0.0);
            let w = self.b[k] + gain * excess;
            let b = w.clamp(-max, max);
            if b != w {
                self.counts.bias_clamped += 1;
            }
            let taken = b - self.b[k];
            *m -= taken;
            self.u[k] = (self.u[k] - taken).clamp(-self.cfg.integrator_max_deg, self.cfg.integrator_max_deg);
            self.b[k] = b;
            self.b_abs_max = self.b_abs_max.max(b.abs());
        }
    }

    /// `total = u + b`, what is applied. Without a slow correction `b` stays 0 and the sum
    /// is `u` bit for bit.
    fn sum_correction(&mut self) {
        for k in 0..self.j {
            self.total[k] = self.u[k] + self.b[k];
        }
    }

    fn clear_average(&mut self) {
        self.acc_sum = [0.0; MAX_JOINTS];
        self.acc_n = [0; MAX_JOINTS];
        self.acc_frames = 0;
    }

    /// The joints whose last command sat at an upper / lower bound (bit k = joint k), for the
    /// anti-windup of the next update.
    pub fn note_bounds(&mut self, upper_mask: u32, lower_mask: u32) {
        self.upper_mask = upper_mask;
        self.lower_mask = lower_mask;
    }

    /// The correction now applied (zeros while markers are lost).
    pub fn correction(&self) -> &[f64] {
        if self.lost {
            &self.zero[..self.j]
        } else {
            &self.total[..self.j]
        }
    }

    /// The slow correction `b` now held (zeros without `bias_gain`), deg.
    pub fn slow_correction(&self) -> &[f64] {
        &self.b[..self.j]
    }

    /// Markers lost for longer than the timeout: the output is pure feed-forward.
    pub fn lost(&self) -> bool {
        self.lost
    }

    /// Largest |u + b| reached, deg.
    pub fn u_abs_max(&self) -> f64 {
        self.u_abs_max
    }

    pub fn counts(&self) -> FeedbackCounts {
        self.counts
    }

    /// Forgets everything but the configuration (and keeps the ring's memory).
    pub fn reset(&mut self) {
        let mut ring = std::mem::take(&mut self.ring);
        ring.fill(EMPTY);
        let cfg = self.cfg.clone();
        *self = Self::with_ring(&cfg, self.j, ring);
    }

    fn with_ring(cfg: &FeedbackConfig, joints: usize, ring: Vec<RingEntry>) -> Self {
        Self {
            cfg: cfg.clone(),
            j: joints.min(MAX_JOINTS),
            ring,
            reference: [0.0; MAX_JOINTS],
            t_reference_ns: None,
            last_desired: [0.0; MAX_JOINTS],
            u: [0.0; MAX_JOINTS],
            b: [0.0; MAX_JOINTS],
            total: [0.0; MAX_JOINTS],
            updated_since_jump: false,
            bias_mean: [0.0; MAX_JOINTS],
            zero: [0.0; MAX_JOINTS],
            acc_sum: [0.0; MAX_JOINTS],
            acc_n: [0; MAX_JOINTS],
            acc_frames: 0,
            last_capture_ns: None,
            last_usable_ns: None,
            t_change_ns: None,
            t_start_ns: None,
            lost: false,
            upper_mask: 0,
            lower_mask: 0,
            u_abs_max: 0.0,
            b_abs_max: 0.0,
            counts: FeedbackCounts::default(),
        }
    }

    /// One line for a node's exit summary.
    pub fn summary(&self) -> String {
        let c = &self.counts;
        format!(
            "feedback: apply {}, gain {}, {} estimates, {} updates, {} settling, rejected {} (invalid {}, partial {}, \
             wrong size {}, non-finite {}, outliers {}), stale {}, unknown tick {}, anti-windup holds {}, at clamp {}, \
             marker-loss fallbacks {}, max |u + b| {:.3} deg, slow correction: gain {}, max |b| {:.3} deg, \
             at clamp {}, now {}",
            self.cfg.apply.as_str(),
            self.cfg.gain,
            c.estimates,
            c.updates,
            c.settling,
            c.rejected(),
            c.invalid,
            c.partial,
            c.wrong_size,
            c.not_finite,
            c.outliers,
            c.stale,
            c.unknown_tick,
            c.windup_holds,
            c.clamped,
            c.loss_episodes,
            self.u_abs_max,
            self.cfg.bias_gain,
            self.b_abs_max,
            c.bias_clamped,
            if self.lost {
                "feed-forward only (markers lost)"
            } else {
                "active"
            }
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const MS: u64 = 1_000_000;

    fn on() -> FeedbackConfig {
        FeedbackConfig {
            enabled: true,
            reference_tau_ms: 0.0,
            settle_ms: 0.0,
            ..FeedbackConfig::default()
        }
    }

    /// A valid 5-joint estimate of `q`, taken at tick `tick` / time `t_ns`.
    fn est(tick: u64, t_ns: u64, q: [f64; 5]) -> JointEstimate {
        let mut e = JointEstimate {
            n_joints: 5,
            quality: JointEstimate::QUALITY_VALID,
            joint_valid_mask: 0b11111,
            ..Default::default()
        };
        e.header.tick = tick;
        e.header.t_origin_ns = t_ns;
        e.q_phy_deg[..5].copy_from_slice(&q);
        e
    }

    #[test]
    fn default_is_off_and_valid() {
        let c = FeedbackConfig::default();
        assert!(!c.enabled);
        c.check().unwrap();
    }

    #[test]
    fn validation_names_the_field_and_refuses_an_unstable_gain() {
        let field = |f: &dyn Fn(&mut FeedbackConfig)| {
            let mut c = on();
            f(&mut c);
            c.check().err().map(|e| e.0)
        };
        // The hard bound: gain + leak < 2.
        assert_eq!(field(&|c| c.gain = 2.0), Some("feedback.gain"));
        assert_eq!(field(&|c| c.gain = 1.9), None);
        assert_eq!(
            field(&|c| {
                c.gain = 1.9;
                c.leak = 0.2
            }),
            Some("feedback.gain")
        );
        assert_eq!(field(&|c| c.bias_gain = -0.1), Some("feedback.bias_gain"));
        assert_eq!(field(&|c| c.bias_gain = 1.1), Some("feedback.bias_gain"));
        assert_eq!(field(&|c| c.bias_gain = f64::NAN), Some("feedback.bias_gain"));
        assert_eq!(field(&|c| c.bias_max_deg = 0.0), Some("feedback.bias_max_deg"));
        assert_eq!(field(&|c| c.bias_window = 0), Some("feedback.bias_window"));
        assert_eq!(
            field(&|c| c.bias_deadband_deg = -1.0),
            Some("feedback.bias_deadband_deg")
        );
        assert_eq!(field(&|c| c.gain = f64::NAN), Some("feedback.gain"));
        assert_eq!(field(&|c| c.gain = 0.0), Some("feedback.gain"));
        assert_eq!(field(&|c| c.leak = 1.0), Some("feedback.leak"));
        assert_eq!(
            field(&|c| c.integrator_max_deg = 0.0),
            Some("feedback.integrator_max_deg")
        );
        assert_eq!(field(&|c| c.settle_ms = -1.0), Some("feedback.settle_ms"));
        assert_eq!(field(&|c| c.jump_deg = 0.0), Some("feedback.jump_deg"));
        assert_eq!(field(&|c| c.keep_on_jump = 1.5), Some("feedback.keep_on_jump"));
        assert_eq!(field(&|c| c.frames_per_update = 0), Some("feedback.frames_per_update"));
        assert_eq!(
            field(&|c| c.reference_tau_ms = f64::INFINITY),
            Some("feedback.reference_tau_ms")
        );
        assert_eq!(field(&|c| c.max_age_ms = 0.0), Some("feedback.max_age_ms"));
        assert_eq!(field(&|c| c.loss_timeout_ms = -5.0), Some("feedback.loss_timeout_ms"));
        assert_eq!(field(&|c| c.max_error_deg = 0.0), Some("feedback.max_error_deg"));
    }

    #[test]
    fn a_frame_is_compared_with_the_target_of_its_own_tick() {
        let mut fb = Feedback::new(&on(), 5, MS);
        // Targets move 0.1° per tick; the frame of tick 10 arrives at tick 40.
        for t in 0..=40u64 {
            fb.begin(t, &[0.1 * t as f64; 5], t * MS);
        }
        let q_then = [1.0 - 0.3; 5]; // the robot 0.3° short of the target of tick 10
        assert_eq!(fb.observe(&est(10, 10 * MS, q_then), 40 * MS), Observation::Accepted);
        let u = fb.update(40 * MS);
        for &v in u {
            assert!((v - 0.5 * 0.3).abs() < 1e-12, "gain × the error at capture: {v}");
        }
    }

    #[test]
    fn unusable_estimates_are_rejected_counted_and_never_panic() {
        let mut fb = Feedback::new(&on(), 5, MS);
        for t in 0..5u64 {
            fb.begin(t, &[10.0; 5], t * MS);
        }
        let now = 5 * MS;
        let mut nan = est(1, MS, [10.0; 5]);
        nan.q_phy_deg[2] = f64::NAN;
        assert_eq!(fb.observe(&nan, now), Observation::NotFinite);
        let mut inf = est(1, MS, [10.0; 5]);
        inf.q_phy_deg[0] = f64::INFINITY;
        assert_eq!(fb.observe(&inf, now), Observation::NotFinite);
        let mut invalid = est(1, MS, [10.0; 5]);
        invalid.quality = JointEstimate::QUALITY_INVALID;
        invalid.q_phy_deg = [f64::NAN; MAX_JOINTS];
        assert_eq!(fb.observe(&invalid, now), Observation::Invalid);
        let mut garbage = est(1, MS, [10.0; 5]);
        garbage.quality = 77;
        assert_eq!(fb.observe(&garbage, now), Observation::Invalid);
        let mut partial = est(1, MS, [10.0; 5]);
        partial.quality = JointEstimate::QUALITY_PARTIAL;
        partial.joint_valid_mask = 0b00111;
        assert_eq!(fb.observe(&partial, now), Observation::Partial);
        let mut size = est(1, MS, [10.0; 5]);
        size.n_joints = 9;
        assert_eq!(fb.observe(&size, now), Observation::WrongSize);
        assert_eq!(fb.observe(&est(1, MS, [-40.0; 5]), now), Observation::Outlier);
        assert_eq!(fb.observe(&est(4000, 2 * MS, [10.0; 5]), now), Observation::UnknownTick);
        // Usable, then the same capture again, then one too old.
        assert_eq!(fb.observe(&est(3, 3 * MS, [10.0; 5]), now), Observation::Accepted);
        assert_eq!(fb.observe(&est(3, 3 * MS, [10.0; 5]), now), Observation::Stale);
        let late = 4 * MS + 201 * MS;
        assert_eq!(fb.observe(&est(4, 4 * MS, [10.0; 5]), late), Observation::Stale);
        let c = fb.counts();
        assert_eq!(
            (
                c.not_finite,
                c.invalid,
                c.partial,
                c.wrong_size,
                c.outliers,
                c.unknown_tick,
                c.stale
            ),
            (2, 2, 1, 1, 1, 1, 2)
        );
        assert_eq!(c.rejected(), 7);
        assert_eq!(c.estimates, 11);
        assert!(fb.update(now).iter().all(|v| v.is_finite()));
    }

    #[test]
    fn partial_estimates_update_their_valid_joints_when_allowed() {
        let cfg = FeedbackConfig {
            use_partial: true,
            ..on()
        };
        let mut fb = Feedback::new(&cfg, 5, MS);
        fb.begin(0, &[10.0; 5], 0);
        let mut p = est(0, 0, [9.0; 5]);
        p.quality = JointEstimate::QUALITY_PARTIAL;
        p.joint_valid_mask = 0b00101;
        p.q_phy_deg[1] = f64::NAN; // invalid joints may hold anything
        assert_eq!(fb.observe(&p, MS), Observation::Accepted);
        assert_eq!(fb.update(MS), &[0.5, 0.0, 0.5, 0.0, 0.0]);
    }

    #[test]
    fn frames_older_than_the_last_change_are_not_integrated() {
        let cfg = FeedbackConfig {
            settle_ms: 30.0,
            ..on()
        };
        let mut fb = Feedback::new(&cfg, 5, MS);
        fb.begin(0, &[0.0; 5], 0);
        assert_eq!(fb.observe(&est(0, 0, [-1.0; 5]), MS), Observation::Accepted);
        fb.update(MS); // the correction changes at 1 ms
        fb.begin(20, &[0.0; 5], 20 * MS);
        assert_eq!(fb.observe(&est(20, 20 * MS, [-1.0; 5]), 21 * MS), Observation::Settling);
        fb.begin(31, &[0.0; 5], 31 * MS);
        assert_eq!(fb.observe(&est(31, 31 * MS, [-1.0; 5]), 32 * MS), Observation::Accepted);
        // A target jump restarts the settle time: a frame from before it is not used.
        fb.update(32 * MS);
        fb.begin(100, &[0.0; 5], 100 * MS);
        fb.begin(101, &[5.0; 5], 101 * MS);
        assert_eq!(
            fb.observe(&est(100, 100 * MS, [0.0; 5]), 101 * MS),
            Observation::Settling
        );
        assert_eq!(fb.counts().settling, 2);
        // And the correction learned before the jump is forgotten (keep_on_jump = 0).
        assert_eq!(fb.correction(), &[0.0; 5]);
    }

    #[test]
    fn markers_lost_reset_the_correction_and_are_counted() {
        let mut fb = Feedback::new(&on(), 5, MS);
        fb.begin(0, &[10.0; 5], 0);
        fb.observe(&est(0, 0, [9.0; 5]), MS);
        assert_eq!(fb.update(MS), &[0.5; 5]);
        // Held while within the timeout...
        for t in (100..=1000).step_by(100) {
            fb.begin(t, &[10.0; 5], t * MS);
            assert_eq!(fb.update(t * MS), &[0.5; 5], "{t} ms");
        }
        assert!(!fb.lost());
        // ... then pure feed-forward.
        fb.begin(1001, &[10.0; 5], 1001 * MS);
        assert_eq!(fb.update(1001 * MS), &[0.0; 5]);
        assert!(fb.lost());
        assert_eq!(fb.counts().loss_episodes, 1);
        assert_eq!(fb.correction(), &[0.0; 5]);
        // Markers return: the correction restarts from zero.
        fb.begin(1100, &[10.0; 5], 1100 * MS);
        assert_eq!(
            fb.observe(&est(1100, 1100 * MS, [9.0; 5]), 1101 * MS),
            Observation::Accepted
        );
        assert_eq!(fb.update(1101 * MS), &[0.5; 5]);
        assert!(!fb.lost());
        assert_eq!(fb.counts().loss_episodes, 1);
    }

    #[test]
    fn no_estimate_at_all_falls_back_after_the_timeout() {
        let mut fb = Feedback::new(&on(), 5, MS);
        fb.begin(0, &[1.0; 5], 0);
        assert!(!fb.lost());
        fb.begin(2000, &[1.0; 5], 2000 * MS);
        assert_eq!(fb.update(2000 * MS), &[0.0; 5]);
        assert!(fb.lost());
        assert_eq!(fb.counts().loss_episodes, 1);
    }

    #[test]
    fn the_integrator_is_clamped_and_does_not_wind_up_against_a_bound() {
        let cfg = FeedbackConfig {
            gain: 1.0,
            integrator_max_deg: 2.0,
            ..on()
        };
        let mut fb = Feedback::new(&cfg, 5, MS);
        let mut t = 0;
        let mut step = |fb: &mut Feedback, q: f64| {
            t += 1;
            fb.begin(t, &[10.0; 5], t * MS);
            fb.observe(&est(t, t * MS, [q; 5]), t * MS);
            fb.update(t * MS)[0]
        };
        assert_eq!(step(&mut fb, 7.0), 2.0); // error 3°, clamped to 2
        assert_eq!(step(&mut fb, 7.0), 2.0);
        assert!(fb.counts().clamped >= 2);
        // The command sits at an upper bound on joint 1: a positive error is not integrated
        // there, a negative one is.
        fb.note_bounds(0b00001, 0);
        let holds = fb.counts().windup_holds;
        assert_eq!(step(&mut fb, 9.5), 2.0);
        assert_eq!(fb.counts().windup_holds, holds + 1);
        assert_eq!(step(&mut fb, 10.5), 1.5);
        assert!(fb.u_abs_max() <= 2.0);
    }

    #[test]
    fn frames_are_averaged_and_the_reference_lags() {
        let cfg = FeedbackConfig {
            frames_per_update: 2,
            reference_tau_ms: 80.0,
            ..on()
        };
        let mut fb = Feedback::new(&cfg, 5, MS);
        fb.begin(0, &[0.0; 5], 0);
        // A 0.5° step (not a jump): the reference gets 1 − e^(−10/80) of it after 10 ms.
        fb.begin(10, &[0.5; 5], 10 * MS);
        let r10 = 0.5 * (1.0 - (-10.0f64 / 80.0).exp());
        assert_eq!(
            fb.observe(&est(10, 10 * MS, [r10 - 0.2; 5]), 11 * MS),
            Observation::Accepted
        );
        assert_eq!(fb.update(11 * MS), &[0.0; 5], "one frame of two");
        fb.begin(11, &[0.5; 5], 11 * MS);
        let r11 = r10 + (0.5 - r10) * (1.0 - (-1.0f64 / 80.0).exp());
        fb.observe(&est(11, 11 * MS, [r11 - 0.4; 5]), 12 * MS);
        for &v in fb.update(12 * MS) {
            assert!((v - 0.5 * 0.3).abs() < 1e-9, "gain × the mean error: {v}");
        }
    }

    #[test]
    fn reset_forgets_everything_but_keeps_the_ring() {
        let mut fb = Feedback::new(&on(), 5, MS);
        let cap = fb.ring.len();
        fb.begin(0, &[1.0; 5], 0);
        fb.observe(&est(0, 0, [0.0; 5]), MS);
        fb.update(MS);
        fb.reset();
        assert_eq!(fb.ring.len(), cap);
        assert_eq!(fb.correction(), &[0.0; 5]);
        assert_eq!(fb.counts(), FeedbackCounts::default());
        assert_eq!(fb.observe(&est(0, 0, [0.0; 5]), MS), Observation::UnknownTick);
    }
}
