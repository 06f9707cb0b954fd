//! The refinements of one compensation step, generic over a small window-model trait so they
//! run on the ONNX models (incremental or tract) and on toy models in tests alike.
//!
//! - [`paper_refine`]: Algorithm 1 of the paper, lines 2–6, exactly. Line 6 of the
//!   published algorithm reads `q_cal[idx] ← q_cal[idx] − α·loss`, subtracting the whole loss
//!   vector from one component; the only reading that type-checks, and the one §IV-D describes
//!   ("iteratively updated by subtracting α·loss until the absolute value of individual joint
//!   losses fall below Thr"), is per joint: `q_cal[idx] −= α·loss[idx]`. That is what runs.
//! - [`newton_refine`]: Levenberg–Marquardt on the forward model with its exact J×J Jacobian
//!   with respect to the newest input, with a fixed-step fallback where the Jacobian is
//!   singular (dead ReLUs) and step rejection with damping increase.
//!
//! Both are bounded: at most M model evaluations, stop at the threshold, or when the caller's
//! `out_of_time` says the time budget is spent. Neither allocates.

use bowden_interfaces::model::MAX_JOINTS;

/// A window model `[L, J] → [J]` whose first `L−1` inputs are fixed while the newest varies.
pub trait WindowModel {
    fn joints(&self) -> usize;
    fn seq_len(&self) -> usize;
    /// Sets the fixed part of the window: `(L−1)·J` values, oldest first, degrees.
    fn set_history(&mut self, history_deg: &[f64]);
    /// The history gained exactly one entry (`history_deg` is the new history). Models that
    /// can reuse work do; the default recomputes.
    fn shift_history(&mut self, history_deg: &[f64]) {
        self.set_history(history_deg)
    }
    /// Output (degrees) for `last_deg` as the newest input.
    fn eval(&mut self, last_deg: &[f64], out_deg: &mut [f64]);
    /// Output and Jacobian ∂out/∂last, row-major J×J (`jac[r·J + c]` = ∂out_r/∂last_c).
    fn eval_jacobian(&mut self, last_deg: &[f64], out_deg: &mut [f64], jac: &mut [f64]);
}

/// Why a refinement stopped. Codes 0–3 are those of `JointCommand::stop_reason`.
#[derive(
    Debug,
    Clone,
    Copy,
    PartialEq,
    Eq,
    Default,
    strum::EnumString,
    strum::IntoStaticStr,
    strum::Display,
    strum::VariantNames,
    strum::VariantArray,
)]
#[repr(u32)]
#[strum(serialize_all = "kebab-case")]
pub enum StopReason {
    /// No refinement ran (uncalibrated mode).
    #[default]
    None = 0,
    /// Every joint's |loss| is within the threshold (paper: Thr; newton: tolerance), or newton's
    /// last accepted step was within its step tolerance.
    Threshold = 1,
    /// M iterations done.
    MaxIterations = 2,
    /// The time budget is spent; the best candidate so far is returned.
    Budget = 3,
    /// Newton could not reduce the loss any further (damping at its maximum), or the model
    /// returned a non-finite value.
    Stalled = 4,
    /// The target was rejected (wrong length or non-finite); the last command is held.
    RejectedInput = 5,
}

impl StopReason {
    pub fn code(self) -> u32 {
        self as u32
    }
    /// The spelling in configs, reports and on the command line.
    pub fn as_str(self) -> &'static str {
        self.into()
    }
}

/// Algorithm 1's parameters (paper §V: Q = 5 joints, M = 50, α = 0.001, Thr = 4 deg).
#[derive(Debug, Clone, Copy, PartialEq, serde::Deserialize, serde::Serialize)]
#[serde(deny_unknown_fields)]
pub struct PaperParams {
    /// M: iterations (= forward evaluations).
    pub iterations: u32,
    /// α: step size.
    pub alpha: f64,
    /// Thr: a joint is updated only while its |loss| exceeds this, degrees.
    pub threshold_deg: f64,
}

impl Default for PaperParams {
    fn default() -> Self {
        Self {
            iterations: 50,
            alpha: 0.001,
            threshold_deg: 4.0,
        }
    }
}

fn is_off(v: &f64) -> bool {
    *v == 0.0
}

/// Levenberg–Marquardt parameters.
#[derive(Debug, Clone, Copy, PartialEq, serde::Deserialize, serde::Serialize)]
#[serde(deny_unknown_fields)]
pub struct NewtonParams {
    /// Forward evaluations at most (each gives the output and the Jacobian).
    pub max_evals: u32,
    /// Stop when every joint's |loss| ≤ this, degrees.
    pub tolerance_deg: f64,
    /// Initial damping λ of (JᵀJ + λI)δ = −Jᵀr (J is ≈ identity-scaled, deg/deg).
    pub damping_init: f64,
    /// λ multiplier after a rejected step.
    pub damping_increase: f64,
    /// λ multiplier after an accepted step.
    pub damping_decrease: f64,
    /// λ never goes below this.
    pub damping_min: f64,
    /// Give up ("stalled") when λ exceeds this.
    pub damping_max: f64,
    /// Largest change of any joint in one step, degrees (trust region).
    pub max_step_deg: f64,
    /// Fallback step δ = −β·loss when JᵀJ is singular (dead ReLUs); halved on rejection.
    pub fallback_step: f64,
    /// Start from the inverse model's estimate (as Algorithm 1), else from q_desired.
    pub init_from_inverse: bool,
    /// Weight μ of a prior toward the starting point q₀ (the inverse model's estimate):
    /// minimises |f(q) − q_desired|² + μ²|q − q₀|² (deg/deg). A learned forward model is only
    /// trustworthy near the commands it was trained on; where its response to the newest input
    /// is flat (a dead band), plain Gauss–Newton takes large steps into commands where the model
    /// is wrong. 0 = plain Gauss–Newton.
    #[serde(default)]
    pub prior_weight: f64,
    /// Stop when an accepted step moved no joint by more than this, degrees (0 = off). With a
    /// prior the loss seldom reaches `tolerance_deg` (the optimum balances the model's residual
    /// against the prior), so without it every step runs all `max_evals`, the last ones by
    /// ever smaller steps: the usual step-size test of Levenberg–Marquardt (Madsen, Nielsen &
    /// Tingleff 2004, §3.2). Absent = 0, and 0 is not written (configs and reports read and
    /// write as before it existed).
    #[serde(default, skip_serializing_if = "is_off")]
    pub step_tolerance_deg: f64,
}

impl Default for NewtonParams {
    fn default() -> Self {
        Self {
            max_evals: 8,
            tolerance_deg: 0.05,
            damping_init: 1e-3,
            damping_increase: 10.0,
            damping_decrease: 0.3,
            damping_min: 1e-9,
            damping_max: 1e6,
            max_step_deg: 20.0,
            fallback_step: 0.5,
            init_from_inverse: true,
            prior_weight: 0.0,
            step_tolerance_deg: 0.0,
        }
    }
}

/// What a refinement did.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct RefineResult {
    /// Iterations of the loop (paper: = forward evaluations; newton: accepted + rejected steps).
    pub iterations: u32,
    /// Forward-model evaluations.
    pub evals: u32,
    pub stop: StopReason,
    /// max_j |f(q) − q_desired| at the last evaluated candidate, degrees.
    pub loss_max_abs_deg: f64,
    /// True when `pred` holds the forward prediction at the returned `q`.
    pub pred_at_q: bool,
}

fn max_abs(v: &[f64]) -> f64 {
    v.iter()
        .fold(0.0f64, |m, x| if x.abs() > m || x.is_nan() { x.abs() } else { m })
}

/// Algorithm 1, lines 2–6. `q` holds line 1's result (the inverse model's estimate) on entry
/// and q_calibrated on return; `pred` the last forward prediction. `project` maps every
/// candidate into the admissible set before it is evaluated (the safe refinement's support;
/// a no-op runs the algorithm literally). `observer(iteration, q, loss)` sees every iteration
/// before its update (tests use it; the compensator passes a no-op).
#[allow(clippy::too_many_arguments)]
pub fn paper_refine<M: WindowModel + ?Sized>(
    fwd: &mut M,
    q_desired: &[f64],
    q: &mut [f64],
    p: &PaperParams,
    pred: &mut [f64],
    project: &mut impl FnMut(&mut [f64]),
    out_of_time: &mut impl FnMut() -> bool,
    observer: &mut impl FnMut(u32, &[f64], &[f64]),
) -> RefineResult {
    let j = q.len();
    let mut loss = [0.0f64; MAX_JOINTS];
    let loss = &mut loss[..j];
    let mut r = RefineResult {
        stop: StopReason::MaxIterations,
        ..Default::default()
    };
    project(q);
    for it in 1..=p.iterations {
        fwd.eval(q, pred);
        r.evals += 1;
        r.iterations = it;
        for c in 0..j {
            loss[c] = pred[c] - q_desired[c];
        }
        r.loss_max_abs_deg = max_abs(loss);
        observer(it, q, loss);
        if !r.loss_max_abs_deg.is_finite() {
            r.stop = StopReason::Stalled;
            r.pred_at_q = true;
            return r;
        }
        let mut updated = false;
        for c in 0..j {
            if loss[c].abs() > p.threshold_deg {
                q[c] -= p.alpha * loss[c];
                updated = true;
            }
        }
        if !updated {
            // Every later iteration would compute the same loss and change nothing.
            r.stop = StopReason::Threshold;
            r.pred_at_q = true;
            return r;
        }
        project(q);
        if it < p.iterations && out_of_time() {
            r.stop = StopReason::Budget;
            return r;
        }
    }
    r
}

/// Solves the SPD system `a·x = b` (n×n, row-major) in place by Cholesky; false if not SPD.
fn cholesky_solve(a: &mut [f64], b: &mut [f64], n: usize) -> bool {
    // The robot's five joints get a copy with n known, which the compiler unrolls: the same
    // operations in the same order, so the same bits.
    if n == 5 {
        cholesky_solve_n(a, b, 5)
    } else {
        cholesky_solve_n(a, b, n)
    }
}

#[inline(always)]
fn cholesky_solve_n(a: &mut [f64], b: &mut [f64], n: usize) -> bool {
    for c in 0..n {
        let mut d = a[c * n + c];
        for k in 0..c {
            d -= a[c * n + k] * a[c * n + k];
        }
        if d.is_nan() || d <= 0.0 {
            return false;
        }
        let d = d.sqrt();
        a[c * n + c] = d;
        for r in c + 1..n {
            let mut s = a[r * n + c];
            for k in 0..c {
                s -= a[r * n + k] * a[c * n + k];
            }
            a[r * n + c] = s / d;
        }
    }
    for r in 0..n {
        let mut s = b[r];
        for k in 0..r {
            s -= a[r * n + k] * b[k];
        }
        b[r] = s / a[r * n + r];
    }
    for r in (0..n).rev() {
        let mut s = b[r];
        for k in r + 1..n {
            s -= a[k * n + r] * b[k];
        }
        b[r] = s / a[r * n + r];
    }
    b.iter().all(|v| v.is_finite())
}

/// Whether the normal matrix `a` (j×j) is numerically singular: its Cholesky factor, with a
/// 1e-10·trace nudge, fails or has a pivot² below 1e-8·trace.
fn probe_singular(a: &[f64], trace: f64, j: usize) -> bool {
    let mut probe = [0.0f64; MAX_JOINTS * MAX_JOINTS];
    let mut rhs = [0.0f64; MAX_JOINTS];
    probe[..j * j].copy_from_slice(&a[..j * j]);
    for c in 0..j {
        probe[c * j + c] += 1e-10 * trace.max(1e-300);
    }
    if !cholesky_solve(&mut probe[..j * j], &mut rhs[..j], j) {
        return true;
    }
    // Pivots: the smallest diagonal of the Cholesky factor relative to trace.
    let min_piv = (0..j)
        .map(|c| probe[c * j + c] * probe[c * j + c])
        .fold(f64::INFINITY, f64::min);
    min_piv < 1e-8 * trace
}

/// Damped Gauss–Newton (Levenberg–Marquardt) on `f(q) = q_desired`. `q` holds the initial
/// estimate on entry and the best candidate on return (every accepted step lowers ‖loss‖², so
/// the current point is the best); `pred` the prediction there. `project` maps a candidate
/// into the admissible set (joint limits).
// Long: one regularised Gauss–Newton solve with its line search and stopping rules, allocation-free on the real-time path.
pub fn newton_refine<M: WindowModel + ?Sized>(
    fwd: &mut M,
    q_desired: &[f64],
    q: &mut [f64],
    p: &NewtonParams,
    pred: &mut [f64],
    project: &mut impl FnMut(&mut [f64]),
    out_of_time: &mut impl FnMut() -> bool,
) -> RefineResult {
    let j = q.len();
    let mut jac = [0.0f64; MAX_JOINTS * MAX_JOINTS];
    let mut jac_new = [0.0f64; MAX_JOINTS * MAX_JOINTS];
    let mut res = [0.0f64; MAX_JOINTS];
    let mut pred_new = [0.0f64; MAX_JOINTS];
    let mut q_new = [0.0f64; MAX_JOINTS];
    let mut a = [0.0f64; MAX_JOINTS * MAX_JOINTS];
    let mut g = [0.0f64; MAX_JOINTS];
    let (jac, jac_new, res) = (&mut jac[..j * j], &mut jac_new[..j * j], &mut res[..j]);
    let (pred_new, q_new, a, g) = (&mut pred_new[..j], &mut q_new[..j], &mut a[..j * j], &mut g[..j]);

    let mut r = RefineResult {
        pred_at_q: true,
        ..Default::default()
    };
    project(q);
    let mut q0 = [0.0f64; MAX_JOINTS];
    q0[..j].copy_from_slice(q);
    let mu2 = p.prior_weight * p.prior_weight;
    let prior = |q: &[f64]| -> f64 { mu2 * q.iter().zip(&q0).map(|(a, b)| (a - b) * (a - b)).sum::<f64>() };
    fwd.eval_jacobian(q, pred, jac);
    r.evals = 1;
    for c in 0..j {
        res[c] = pred[c] - q_desired[c];
    }
    let mut cost: f64 = res.iter().map(|v| v * v).sum::<f64>() + prior(q);
    r.loss_max_abs_deg = max_abs(res);
    if !cost.is_finite() {
        r.stop = StopReason::Stalled;
        return r;
    }
    let mut lambda = p.damping_init;
    let mut beta = p.fallback_step;
    loop {
        if r.loss_max_abs_deg <= p.tolerance_deg {
            r.stop = StopReason::Threshold;
            return r;
        }
        if r.evals >= p.max_evals {
            r.stop = StopReason::MaxIterations;
            return r;
        }
        if out_of_time() {
            r.stop = StopReason::Budget;
            return r;
        }
        // JᵀJ, its conditioning, and g = −Jᵀr.
        let mut trace = 0.0;
        for c1 in 0..j {
            for c2 in 0..j {
                let mut s = 0.0;
                for k in 0..j {
                    s += jac[k * j + c1] * jac[k * j + c2];
                }
                a[c1 * j + c2] = s;
            }
            // The prior adds μ²I to JᵀJ and −μ²(q − q₀) to the gradient.
            a[c1 * j + c1] += mu2;
            trace += a[c1 * j + c1];
            let mut s = 0.0;
            for k in 0..j {
                s += jac[k * j + c1] * res[k];
            }
            g[c1] = -s - mu2 * (q[c1] - q0[c1]);
        }
        // Singular JᵀJ (a joint the model does not respond to: dead ReLUs): fall back to the
        // fixed step, as Algorithm 1 but with a usable size. With the prior, every pivot² of
        // the probe is at least μ² (the smallest eigenvalue of JᵀJ + μ²I): when μ² clears the
        // 1e-8·trace threshold (with a factor 2 against rounding, ~1e-15·trace here) the probe
        // cannot fail and is skipped.
        let conditioned = mu2 >= 2e-8 * trace;
        let singular = trace.is_nan() || trace <= 0.0 || (!conditioned && probe_singular(a, trace, j));
        let mut used_fallback = false;
        if singular {
            for c in 0..j {
                g[c] = -beta * res[c];
            }
            used_fallback = true;
        } else {
            for c in 0..j {
                a[c * j + c] += lambda * (1.0 + a[c * j + c]);
            }
            if !cholesky_solve(a, g, j) {
                for c in 0..j {
                    g[c] = -beta * res[c];
                }
                used_fallback = true;
            }
        }
        let step_max = max_abs(g);
        let scale = if step_max > p.max_step_deg {
            p.max_step_deg / step_max
        } else {
            1.0
        };
        for c in 0..j {
            q_new[c] = q[c] + scale * g[c];
        }
        project(q_new);
        fwd.eval_jacobian(q_new, pred_new, jac_new);
        r.evals += 1;
        r.iterations += 1;
        let mut cost_new = prior(q_new);
        for c in 0..j {
            let d = pred_new[c] - q_desired[c];
            cost_new += d * d;
        }
        // A fallback step is taken when it does not make things worse: in a flat (dead) region
        // the loss stays put until the model responds again.
        if cost_new.is_finite() && (cost_new < cost || (used_fallback && cost_new <= cost)) {
            let moved = q
                .iter()
                .zip(q_new.iter())
                .fold(0.0f64, |m, (a, b)| m.max((a - b).abs()));
            q.copy_from_slice(q_new);
            pred.copy_from_slice(pred_new);
            jac.copy_from_slice(jac_new);
            for c in 0..j {
                res[c] = pred[c] - q_desired[c];
            }
            cost = cost_new;
            r.loss_max_abs_deg = max_abs(res);
            lambda = (lambda * p.damping_decrease).max(p.damping_min);
            if p.step_tolerance_deg > 0.0 && moved <= p.step_tolerance_deg {
                r.stop = StopReason::Threshold;
                return r;
            }
        } else if used_fallback {
            beta *= 0.5;
            lambda *= p.damping_increase;
        } else {
            lambda *= p.damping_increase;
            if lambda > p.damping_max {
                r.stop = StopReason::Stalled;
                return r;
            }
        }
        if lambda > p.damping_max {
            r.stop = StopReason::Stalled;
            return r;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Toy forward model: out = 2·last + 0.1·(sum of history of that joint). Its exact inverse
    /// is known; the history term makes the window matter.
    struct Toy {
        j: usize,
        l: usize,
        hist_sum: Vec<f64>,
        evals: usize,
    }
    impl Toy {
        fn new(j: usize, l: usize) -> Self {
            Self {
                j,
                l,
                hist_sum: vec![0.0; j],
                evals: 0,
            }
        }
    }
    impl WindowModel for Toy {
        fn joints(&self) -> usize {
            self.j
        }
        fn seq_len(&self) -> usize {
            self.l
        }
        fn set_history(&mut self, h: &[f64]) {
            self.hist_sum.iter_mut().for_each(|v| *v = 0.0);
            for (i, v) in h.iter().enumerate() {
                self.hist_sum[i % self.j] += v;
            }
        }
        fn eval(&mut self, last: &[f64], out: &mut [f64]) {
            self.evals += 1;
            for c in 0..self.j {
                out[c] = 2.0 * last[c] + 0.1 * self.hist_sum[c];
            }
        }
        fn eval_jacobian(&mut self, last: &[f64], out: &mut [f64], jac: &mut [f64]) {
            self.eval(last, out);
            jac.iter_mut().for_each(|v| *v = 0.0);
            for c in 0..self.j {
                jac[c * self.j + c] = 2.0;
            }
        }
    }

    #[test]
    fn algorithm1_reproduces_hand_computed_sequence() {
        // History [1, 2] per row → hist_sum = [1, 2]; f(q) = 2q + [0.1, 0.2].
        // Desired d = [10, 1]. Inverse estimate (deliberately poor): q0 = 0.4·d = [4, 0.4].
        // α = 0.1, Thr = 0.5, M = 3:
        //  it1: f = [8.1, 1.0]  loss = [-1.9, 0.0]   → q = [4.19, 0.4]  (joint 2 within Thr)
        //  it2: f = [8.48, 1.0] loss = [-1.52, 0.0]  → q = [4.342, 0.4]
        //  it3: f = [8.784,1.0] loss = [-1.216, 0.0] → q = [4.4636, 0.4]
        let mut toy = Toy::new(2, 2);
        toy.set_history(&[1.0, 2.0]);
        let d = [10.0, 1.0];
        let mut q = [4.0, 0.4];
        let mut pred = [0.0; 2];
        let p = PaperParams {
            iterations: 3,
            alpha: 0.1,
            threshold_deg: 0.5,
        };
        let mut seen: Vec<(u32, [f64; 2], [f64; 2])> = Vec::new();
        let r = paper_refine(
            &mut toy,
            &d,
            &mut q,
            &p,
            &mut pred,
            &mut |_| {},
            &mut || false,
            &mut |it, q, l| seen.push((it, [q[0], q[1]], [l[0], l[1]])),
        );
        let want = [
            (1, [4.0, 0.4], [-1.9, 0.0]),
            (2, [4.19, 0.4], [-1.52, 0.0]),
            (3, [4.342, 0.4], [-1.216, 0.0]),
        ];
        assert_eq!(seen.len(), 3);
        for (s, w) in seen.iter().zip(want) {
            assert_eq!(s.0, w.0);
            for c in 0..2 {
                assert!((s.1[c] - w.1[c]).abs() < 1e-12, "{s:?} vs {w:?}");
                assert!((s.2[c] - w.2[c]).abs() < 1e-12, "{s:?} vs {w:?}");
            }
        }
        assert!((q[0] - 4.4636).abs() < 1e-12 && q[1] == 0.4, "{q:?}");
        assert_eq!(r.stop, StopReason::MaxIterations);
        assert_eq!((r.iterations, r.evals), (3, 3));
        assert!(!r.pred_at_q, "the last update was not evaluated");
    }

    #[test]
    fn paper_stops_at_threshold_and_budget() {
        let mut toy = Toy::new(2, 2);
        toy.set_history(&[0.0, 0.0]);
        let p = PaperParams {
            iterations: 50,
            alpha: 0.25,
            threshold_deg: 0.5,
        };
        // f = 2q; from q = 0 towards d = [4, -4]: q ← q − 0.25(2q − d) = q/2 + d/4 → converges.
        let mut q = [0.0, 0.0];
        let mut pred = [0.0; 2];
        let r = paper_refine(
            &mut toy,
            &[4.0, -4.0],
            &mut q,
            &p,
            &mut pred,
            &mut |_| {},
            &mut || false,
            &mut |_, _, _| {},
        );
        assert_eq!(r.stop, StopReason::Threshold);
        assert!(r.iterations < 10 && r.loss_max_abs_deg <= 0.5, "{r:?}");
        assert!(r.pred_at_q);
        // Budget: the clock says "spent" on the 4th check → 4 iterations.
        let mut checks = 0;
        let mut q = [0.0, 0.0];
        let p = PaperParams {
            threshold_deg: 0.0,
            ..p
        };
        let r = paper_refine(
            &mut toy,
            &[4.0, -4.0],
            &mut q,
            &p,
            &mut pred,
            &mut |_| {},
            &mut || {
                checks += 1;
                checks >= 4
            },
            &mut |_, _, _| {},
        );
        assert_eq!((r.stop, r.iterations), (StopReason::Budget, 4));
        // M: with a threshold of 0 nothing converges exactly in floating point within 7.
        let p = PaperParams { iterations: 7, ..p };
        let r = paper_refine(
            &mut toy,
            &[4.0, -4.0],
            &mut [0.0, 0.0],
            &p,
            &mut pred,
            &mut |_| {},
            &mut || false,
            &mut |_, _, _| {},
        );
        assert_eq!((r.stop, r.iterations, r.evals), (StopReason::MaxIterations, 7, 7));
    }

    #[test]
    fn newton_solves_the_toy_in_two_evaluations() {
        let mut toy = Toy::new(3, 2);
        toy.set_history(&[1.0, 2.0, 3.0]);
        let d = [10.0, -5.0, 0.3];
        let mut q = [0.0; 3];
        let mut pred = [0.0; 3];
        let p = NewtonParams {
            damping_init: 1e-9,
            ..Default::default()
        };
        let r = newton_refine(&mut toy, &d, &mut q, &p, &mut pred, &mut |_| {}, &mut || false);
        assert_eq!(r.stop, StopReason::Threshold);
        assert_eq!(r.evals, 2, "{r:?}");
        for c in 0..3 {
            assert!((2.0 * q[c] + 0.1 * (c as f64 + 1.0) - d[c]).abs() < 1e-6);
        }
    }

    #[test]
    fn prior_solves_the_regularised_problem() {
        // Toy: f(q) = 2q + h. With the prior, the minimiser of |2q + h − d|² + μ²|q − q₀|² is
        // q = (2(d − h) + μ²q₀) / (4 + μ²), per joint: checked in closed form.
        let mut toy = Toy::new(2, 2);
        toy.set_history(&[1.0, 2.0]);
        let d = [10.0, -5.0];
        let q0 = [1.0, 1.0];
        let mut q = q0;
        let mut pred = [0.0; 2];
        let mu: f64 = 1.5;
        let p = NewtonParams {
            damping_init: 1e-9,
            prior_weight: mu,
            max_evals: 20,
            ..Default::default()
        };
        newton_refine(&mut toy, &d, &mut q, &p, &mut pred, &mut |_| {}, &mut || false);
        let h = [0.1, 0.2];
        for c in 0..2 {
            let want = (2.0 * (d[c] - h[c]) + mu * mu * q0[c]) / (4.0 + mu * mu);
            assert!((q[c] - want).abs() < 1e-6, "joint {c}: {} vs {want}", q[c]);
        }
        // μ = 0 is plain Gauss–Newton: the model's answer exactly.
        let mut q = q0;
        let p0 = NewtonParams { prior_weight: 0.0, ..p };
        newton_refine(&mut toy, &d, &mut q, &p0, &mut pred, &mut |_| {}, &mut || false);
        assert!((2.0 * q[0] + h[0] - d[0]).abs() < 1e-6);
    }

    /// A model with a dead joint (zero Jacobian column) but which still responds when moved
    /// far: out = max(q, 0) per joint. At q < 0 the Jacobian is zero → the fallback step.
    struct Relu1;
    impl WindowModel for Relu1 {
        fn joints(&self) -> usize {
            1
        }
        fn seq_len(&self) -> usize {
            1
        }
        fn set_history(&mut self, _: &[f64]) {}
        fn eval(&mut self, last: &[f64], out: &mut [f64]) {
            out[0] = last[0].max(0.0);
        }
        fn eval_jacobian(&mut self, last: &[f64], out: &mut [f64], jac: &mut [f64]) {
            self.eval(last, out);
            jac[0] = if last[0] > 0.0 { 1.0 } else { 0.0 };
        }
    }

    /// With a prior the residual never reaches the tolerance: without a step tolerance a call
    /// goes on until its damping gives up; with one it stops once the steps are that small, at
    /// a point within about that distance of where the full run ends.
    #[test]
    fn a_step_tolerance_ends_a_converged_prior_run_early() {
        let d = [10.0, -5.0, 0.3];
        let run = |step_tolerance_deg: f64| {
            let mut toy = Toy::new(3, 2);
            toy.set_history(&[1.0, 2.0, 3.0]);
            let (mut q, mut pred) = ([0.0; 3], [0.0; 3]);
            let p = NewtonParams {
                max_evals: 40,
                prior_weight: 1.0,
                damping_init: 1.0,
                step_tolerance_deg,
                ..Default::default()
            };
            let r = newton_refine(&mut toy, &d, &mut q, &p, &mut pred, &mut |_| {}, &mut || false);
            (r, q)
        };
        let (full, q_full) = run(0.0);
        // The linear toy's optimum is reached exactly; the full run then spends its remaining
        // evaluations on rejected steps until the damping gives up.
        assert_eq!(full.stop, StopReason::Stalled, "{full:?}");
        let (short, q_short) = run(1e-3);
        assert_eq!(short.stop, StopReason::Threshold, "{short:?}");
        assert!(short.evals * 2 < full.evals, "{short:?} vs {full:?}");
        for c in 0..3 {
            assert!((q_short[c] - q_full[c]).abs() < 1e-2, "{q_short:?} vs {q_full:?}");
        }
    }

    #[test]
    fn newton_falls_back_when_the_jacobian_is_singular() {
        let mut q = [-3.0];
        let mut pred = [0.0];
        let p = NewtonParams {
            fallback_step: 1.0,
            ..Default::default()
        };
        let r = newton_refine(&mut Relu1, &[2.0], &mut q, &p, &mut pred, &mut |_| {}, &mut || false);
        assert_eq!(r.stop, StopReason::Threshold, "{r:?}");
        assert!((q[0] - 2.0).abs() < 0.05);
    }

    #[test]
    fn newton_respects_limits_and_budget() {
        let mut toy = Toy::new(1, 1);
        toy.set_history(&[]);
        let mut q = [0.0];
        let mut pred = [0.0];
        // Target needs q = 50 but limits stop at 10: stalls at the boundary.
        let r = newton_refine(
            &mut toy,
            &[100.0],
            &mut q,
            &NewtonParams::default(),
            &mut pred,
            &mut |q| q[0] = q[0].clamp(-10.0, 10.0),
            &mut || false,
        );
        assert_eq!(q[0], 10.0);
        assert!(
            matches!(r.stop, StopReason::Stalled | StopReason::MaxIterations),
            "{r:?}"
        );
        let r = newton_refine(
            &mut toy,
            &[100.0],
            &mut [0.0],
            &NewtonParams::default(),
            &mut pred,
            &mut |_| {},
            &mut || true,
        );
        assert_eq!((r.stop, r.evals), (StopReason::Budget, 1));
    }
}
