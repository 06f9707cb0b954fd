//! Latency accounting: HdrHistogram with fixed bounds (recording never allocates), percentiles
//! for status samples and exit summaries.

use hdrhistogram::Histogram;
use std::fmt;

/// Highest latency tracked, ns (10 s); larger values saturate.
pub const MAX_TRACKED_NS: u64 = 10_000_000_000;

/// Percentiles of a latency distribution, ns.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, serde::Serialize)]
pub struct Percentiles {
    pub count: u64,
    pub p50_ns: u64,
    pub p99_ns: u64,
    pub p999_ns: u64,
    pub max_ns: u64,
    pub mean_ns: u64,
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
            mean_ns: self.h.mean() as u64,
        }
    }
}
