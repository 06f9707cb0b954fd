//! Latency accounting: the one latency statistic of bowden ([`bowden_latency`]), re-exported
//! where the runtime's users have always found it.

pub use bowden_latency::{fmt_ns, LatencyHistogram, Percentiles, MAX_TRACKED_NS};
