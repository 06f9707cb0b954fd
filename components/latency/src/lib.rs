//! bowden's one latency statistic: [`LatencyHistogram`], an HdrHistogram with fixed bounds
//! (recording never allocates, so it may sit on the real-time path), and [`Percentiles`], what
//! every bench, status sample and exit summary reports of it (and serialises to JSON). The
//! runtime's schedulers, the IPC, bridge, compensator, camera, estimator and adaptation
//! benches all use these two types.

use hdrhistogram::Histogram;
use std::fmt;

/// Highest latency tracked, ns (10 s); larger values saturate.
pub const MAX_TRACKED_NS: u64 = 10_000_000_000;

/// Percentiles of a latency distribution, ns (3 significant digits, as the histogram keeps
/// them); all zero for an empty one.
#[derive(Debug, Clone, Copy, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Percentiles {
    pub count: u64,
    pub p50_ns: u64,
    pub p99_ns: u64,
    pub p999_ns: u64,
    pub max_ns: u64,
    pub mean_ns: f64,
}

impl Percentiles {
    /// The percentiles of `values_ns` (a histogram is built; values saturate at its bounds).
    pub fn of(values_ns: impl IntoIterator<Item = u64>) -> Self {
        let mut h = LatencyHistogram::new();
        for v in values_ns {
            h.record(v);
        }
        h.percentiles()
    }

    /// `ns` in microseconds, for tables.
    pub fn us(ns: u64) -> f64 {
        ns as f64 / 1e3
    }
}

impl fmt::Display for Percentiles {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "n={} p50={} p99={} p99.9={} max={}",
            self.count,
            fmt_ns(self.p50_ns),
            fmt_ns(self.p99_ns),
            fmt_ns(self.p999_ns),
            fmt_ns(self.max_ns)
        )
    }
}

/// `1234` → `1.23µs`, for tables.
pub fn fmt_ns(ns: u64) -> String {
    if ns < 1_000 {
        format!("{ns}ns")
    } else if ns < 1_000_000 {
        format!("{:.2}µs", ns as f64 / 1e3)
    } else if ns < 1_000_000_000 {
        format!("{:.2}ms", ns as f64 / 1e6)
    } else {
        format!("{:.2}s", ns as f64 / 1e9)
    }
}

/// A latency histogram, 3 significant digits, 1 ns .. 10 s.
#[derive(Clone)]
pub struct LatencyHistogram {
    h: Histogram<u64>,
}

impl Default for LatencyHistogram {
    fn default() -> Self {
        Self::new()
    }
}

impl fmt::Debug for LatencyHistogram {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "LatencyHistogram({})", self.percentiles())
    }
}

impl LatencyHistogram {
    pub fn new() -> Self {
        let mut h = Histogram::<u64>::new_with_bounds(1, MAX_TRACKED_NS, 3).expect("static histogram bounds are valid");
        h.auto(false);
        Self { h }
    }

    /// Records one value; saturates at the bounds. Allocation-free.
    #[inline]
    pub fn record(&mut self, ns: u64) {
        self.h.saturating_record(ns.clamp(1, MAX_TRACKED_NS));
    }

    pub fn count(&self) -> u64 {
        self.h.len()
    }

    pub fn reset(&mut self) {
        self.h.reset();
    }

    /// Adds another histogram's counts.
    pub fn merge(&mut self, other: &LatencyHistogram) {
        // Same bounds by construction: add cannot fail.
        let _ = self.h.add(&other.h);
    }

    pub fn percentiles(&self) -> Percentiles {
        if self.h.is_empty() {
            return Percentiles::default();
        }
        Percentiles {
            count: self.h.len(),
            p50_ns: self.h.value_at_quantile(0.5),
            p99_ns: self.h.value_at_quantile(0.99),
            p999_ns: self.h.value_at_quantile(0.999),
            max_ns: self.h.max(),
            mean_ns: self.h.mean(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn percentiles_of_a_known_distribution() {
        // 1..=1000 µs: the median is 500 µs, p99 990 µs, the max 1000 µs, to 3 digits.
        let p = Percentiles::of((1..=1000).map(|k| k * 1_000));
        assert_eq!(p.count, 1000);
        let close = |got: u64, want: u64| (got as f64 - want as f64).abs() <= want as f64 * 1e-3;
        assert!(close(p.p50_ns, 500_000), "{p:?}");
        assert!(close(p.p99_ns, 990_000), "{p:?}");
        assert!(close(p.p999_ns, 999_000), "{p:?}");
        assert!(close(p.max_ns, 1_000_000), "{p:?}");
        assert!((p.mean_ns - 500_500.0).abs() < 500.0, "{p:?}");
        assert_eq!(Percentiles::of([]), Percentiles::default());
    }

    #[test]
    fn recording_saturates_and_merging_adds() {
        let mut a = LatencyHistogram::new();
        a.record(0);
        a.record(u64::MAX);
        assert_eq!(a.count(), 2);
        assert!(a.percentiles().max_ns >= MAX_TRACKED_NS - MAX_TRACKED_NS / 1000);
        let mut b = LatencyHistogram::new();
        b.record(5);
        b.merge(&a);
        assert_eq!(b.count(), 3);
        b.reset();
        assert_eq!(b.count(), 0);
    }

    #[test]
    fn json_names_every_field_in_ns() {
        let p = Percentiles::of([1_000, 2_000]);
        let v: serde_json::Value = serde_json::to_value(p).unwrap();
        for k in ["count", "p50_ns", "p99_ns", "p999_ns", "max_ns", "mean_ns"] {
            assert!(v.get(k).is_some(), "{k} in {v}");
        }
        assert_eq!(fmt_ns(1234), "1.23µs");
    }
}
