//! History buffers of desired and of sent commands, sampled at the model's time step.
//!
//! The models were trained on the dataset of eq. (16): consecutive commands 3·√5 deg apart in
//! joint space (3 deg per joint), not one control period apart. A 1 kHz loop moves fractions
//! of a degree per cycle, so appending every cycle would show the model a window covering 80 ms
//! of nearly constant input, a distribution it never learned. The rule here:
//!
//! - `distance` (default): a new entry is appended each time the desired command has moved at
//!   least `step_deg` (Euclidean, joint space) from the last entry. With `interpolate`, a move
//!   of n steps in one cycle appends n entries spaced exactly `step_deg` apart along the
//!   segment (as eq. 16 interpolates), and the sent-command history is interpolated at the same
//!   fractions; without it, one entry holding the current values.
//! - `every_step`: every call appends (for targets that already come at the dataset's step).
//!
//! Windows start as zeros (left zero padding in degrees, as the paper pads). The current
//! target itself is never in the history: it is the window's newest column.

use bowden_interfaces::model::MAX_JOINTS;

/// When a new history entry is taken.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum HistoryRule {
    EveryStep,
    Distance { step_deg: f64, interpolate: bool },
}

/// Relative slack on the distance test, so commands spaced exactly one step apart (the
/// dataset's own trajectories) are not missed by rounding.
const STEP_SLACK: f64 = 1e-9;

#[derive(Debug, Clone)]
pub struct History {
    rule: HistoryRule,
    j: usize,
    /// Number of rows kept (max L − 1 over the models).
    rows: usize,
    desired: Vec<f64>,
    sent: Vec<f64>,
    anchor_desired: [f64; MAX_JOINTS],
    anchor_sent: [f64; MAX_JOINTS],
    has_anchor: bool,
    appended_total: u64,
}

impl History {
    pub fn new(rule: HistoryRule, joints: usize, rows: usize) -> Self {
        assert!(joints <= MAX_JOINTS);
        Self {
            rule,
            j: joints,
            rows,
            desired: vec![0.0; rows * joints],
            sent: vec![0.0; rows * joints],
            anchor_desired: [0.0; MAX_JOINTS],
            anchor_sent: [0.0; MAX_JOINTS],
            has_anchor: false,
            appended_total: 0,
        }
    }

    /// Back to all zeros (start-up padding).
    pub fn reset(&mut self) {
        self.desired.fill(0.0);
        self.sent.fill(0.0);
        self.has_anchor = false;
        self.appended_total = 0;
    }

    pub fn rule(&self) -> HistoryRule {
        self.rule
    }

    /// Entries appended since the last reset.
    pub fn appended_total(&self) -> u64 {
        self.appended_total
    }

    /// The newest `n` rows of desired commands, oldest first (`n·J` values).
    pub fn desired_tail(&self, n: usize) -> &[f64] {
        &self.desired[(self.rows - n) * self.j..]
    }

    /// The newest `n` rows of sent commands, oldest first.
    pub fn sent_tail(&self, n: usize) -> &[f64] {
        &self.sent[(self.rows - n) * self.j..]
    }

    fn push(&mut self, d: &[f64], s: &[f64]) {
        let j = self.j;
        if self.rows == 0 {
            return;
        }
        self.desired.copy_within(j.., 0);
        self.sent.copy_within(j.., 0);
        let at = (self.rows - 1) * j;
        self.desired[at..at + j].copy_from_slice(&d[..j]);
        self.sent[at..at + j].copy_from_slice(&s[..j]);
        self.anchor_desired[..j].copy_from_slice(&d[..j]);
        self.anchor_sent[..j].copy_from_slice(&s[..j]);
        self.has_anchor = true;
        self.appended_total += 1;
    }

    /// Records the step's desired and sent commands; returns how many entries were appended.
    pub fn record(&mut self, q_desired: &[f64], q_sent: &[f64]) -> usize {
        let j = self.j;
        match self.rule {
            HistoryRule::EveryStep => {
                self.push(q_desired, q_sent);
                1
            }
            HistoryRule::Distance { step_deg, interpolate } => {
                if !self.has_anchor {
                    self.push(q_desired, q_sent);
                    return 1;
                }
                let mut d2 = 0.0;
                for c in 0..j {
                    let e = q_desired[c] - self.anchor_desired[c];
                    d2 += e * e;
                }
                let dist = d2.sqrt();
                if dist < step_deg * (1.0 - STEP_SLACK) {
                    return 0;
                }
                if !interpolate {
                    self.push(q_desired, q_sent);
                    return 1;
                }
                let n = ((dist / step_deg) * (1.0 + STEP_SLACK)).floor().max(1.0) as usize;
                // Only the newest `rows` entries can survive; skip the others.
                let first = n.saturating_sub(self.rows.max(1)) + 1;
                let a_d = self.anchor_desired;
                let a_s = self.anchor_sent;
                let mut d = [0.0f64; MAX_JOINTS];
                let mut s = [0.0f64; MAX_JOINTS];
                for k in first..=n {
                    let f = (k as f64 * step_deg / dist).min(1.0);
                    for c in 0..j {
                        d[c] = a_d[c] + f * (q_desired[c] - a_d[c]);
                        s[c] = a_s[c] + f * (q_sent[c] - a_s[c]);
                    }
                    self.push(&d, &s);
                }
                n - first + 1
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn distance_rule_samples_at_the_model_step() {
        let step = 3.0 * 5f64.sqrt();
        let mut h = History::new(
            HistoryRule::Distance {
                step_deg: step,
                interpolate: false,
            },
            5,
            4,
        );
        assert_eq!(h.record(&[0.0; 5], &[0.5; 5]), 1, "first target is recorded");
        // 1 kHz-like creep: 0.3 deg per joint per cycle; √5·0.3·k ≥ 3√5 at k = 10.
        let mut n = 0;
        for k in 1..=10 {
            let q = [0.3 * k as f64; 5];
            n += h.record(&q, &q);
            assert_eq!(n, usize::from(k == 10), "cycle {k}");
        }
        assert_eq!(&h.desired_tail(2)[5..], &[3.0; 5]);
        assert_eq!(&h.desired_tail(2)[..5], &[0.0; 5]);
        assert_eq!(&h.sent_tail(2)[..5], &[0.5; 5]);
        // Exactly one dataset step (3 deg per joint) is appended despite rounding.
        assert_eq!(h.record(&[6.0; 5], &[6.0; 5]), 1);
    }

    fn approx(a: &[f64], b: &[f64]) {
        assert_eq!(a.len(), b.len());
        assert!(a.iter().zip(b).all(|(x, y)| (x - y).abs() < 1e-12), "{a:?} vs {b:?}");
    }

    #[test]
    fn interpolation_spaces_entries_one_step_apart() {
        let mut h = History::new(
            HistoryRule::Distance {
                step_deg: 1.0,
                interpolate: true,
            },
            2,
            3,
        );
        h.record(&[0.0, 0.0], &[0.0, 0.0]);
        // A jump of 3.5 steps along x: 3 entries at x = 1, 2, 3; sent interpolated alike.
        assert_eq!(h.record(&[3.5, 0.0], &[7.0, 0.0]), 3);
        approx(h.desired_tail(3), &[1.0, 0.0, 2.0, 0.0, 3.0, 0.0]);
        approx(h.sent_tail(3), &[2.0, 0.0, 4.0, 0.0, 6.0, 0.0]);
        // Anchor is x = 3: 0.6 more is not a step.
        assert_eq!(h.record(&[3.6, 0.0], &[7.0, 0.0]), 0);
        // A jump of 10 steps keeps only the newest 3 rows.
        assert_eq!(h.record(&[13.0, 0.0], &[13.0, 0.0]), 3);
        approx(h.desired_tail(3), &[11.0, 0.0, 12.0, 0.0, 13.0, 0.0]);
        h.reset();
        assert_eq!(h.desired_tail(3), &[0.0; 6]);
    }

    #[test]
    fn every_step_appends_always() {
        let mut h = History::new(HistoryRule::EveryStep, 1, 2);
        assert_eq!(h.record(&[1.0], &[2.0]), 1);
        assert_eq!(h.record(&[1.0], &[2.0]), 1);
        assert_eq!(h.desired_tail(2), &[1.0, 1.0]);
        assert_eq!(h.appended_total(), 2);
    }
}
