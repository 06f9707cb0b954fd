//! Frame-render latency over a seeded set of workspace configurations, as percentiles
//! (`bowden bench camera`). The criterion bench (`cargo bench --bench camera`) measures one
//! fixed scene; this one varies the scene the way the runtime does.

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::Serialize;
use std::time::Instant;

use bowden_kinematics::JointsDeg;

use crate::{CameraError, SyntheticCamera};
use bowden_interfaces::config::ConfigError;
use bowden_latency::{LatencyHistogram, Percentiles};

/// Render latency of one camera over many frames.
#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct RenderLatency {
    pub frames: u64,
    pub width: u32,
    pub height: u32,
    /// Wall time per frame.
    #[serde(flatten)]
    pub latency: Percentiles,
    /// Frames per second at the median latency.
    pub fps_at_p50: f64,
}

impl RenderLatency {
    pub fn to_markdown(&self) -> String {
        let ms = |ns: u64| ns as f64 / 1e6;
        format!(
            "| frames | size | p50 ms | p99 ms | p99.9 ms | max ms | mean ms | fps at p50 |\n\
             |---:|---:|---:|---:|---:|---:|---:|---:|\n\
             | {} | {}x{} | {:.3} | {:.3} | {:.3} | {:.3} | {:.3} | {:.0} |\n",
            self.frames,
            self.width,
            self.height,
            ms(self.latency.p50_ns),
            ms(self.latency.p99_ns),
            ms(self.latency.p999_ns),
            ms(self.latency.max_ns),
            self.latency.mean_ns / 1e6,
            self.fps_at_p50
        )
    }
}

/// Seeded configurations uniformly inside the robot's joint limits (jaws not crossed).
pub fn workspace_configurations(cam: &SyntheticCamera, n: usize, seed: u64) -> Vec<JointsDeg> {
    let lim = &cam.robot().config.limits;
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    (0..n)
        .map(|_| {
            let mut q = [0.0; 5];
            for (j, v) in q.iter_mut().enumerate() {
                *v = rng.random_range(lim.q_min_deg[j]..=lim.q_max_deg[j]);
            }
            if q[4] - q[3] < lim.min_jaw_opening_deg {
                q = cam.robot().clamp_to_limits(&q);
            }
            q
        })
        .collect()
}

/// Renders `frames` frames (cycling through `qs`) into an interfaces payload and records
/// each frame's wall time; `progress` is called with the frames done since its last call.
pub fn render_latency(
    cam: &mut SyntheticCamera,
    qs: &[JointsDeg],
    frames: u64,
    progress: &mut dyn FnMut(u64),
) -> Result<RenderLatency, CameraError> {
    if qs.is_empty() {
        return Err(
            ConfigError::invalid("<bench>", "configurations", "need at least one configuration to render").into(),
        );
    }
    let mut payload = vec![0u8; cam.payload_len()];
    let mut hist = LatencyHistogram::new();
    for k in 0..frames {
        let q = qs[(k as usize) % qs.len()];
        let t = Instant::now();
        cam.render_into_payload(&q, k, &mut payload)?;
        hist.record(t.elapsed().as_nanos() as u64);
        if k % 16 == 15 {
            progress(16);
        }
    }
    progress(frames % 16);
    let latency = hist.percentiles();
    Ok(RenderLatency {
        frames,
        width: cam.width(),
        height: cam.height(),
        latency,
        fps_at_p50: 1e9 / latency.p50_ns.max(1) as f64,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::CameraConfig;
    use bowden_kinematics::{markers::MarkerGeometry, Robot};

    #[test]
    fn latency_report_is_consistent_and_configurations_respect_limits() {
        let mut cam = SyntheticCamera::new(
            Robot::paper_default(),
            MarkerGeometry::paper_default(),
            CameraConfig::paper_default(),
            1,
        );
        let qs = workspace_configurations(&cam, 20, 3);
        assert!(qs.iter().all(|q| cam.robot().check_limits(q).is_ok()));
        assert_eq!(qs, workspace_configurations(&cam, 20, 3));
        let mut done = 0;
        let r = render_latency(&mut cam, &qs, 21, &mut |n| done += n).expect("bench");
        assert_eq!((r.frames, done, r.width, r.height), (21, 21, 640, 480));
        let l = r.latency;
        assert!(l.count == 21 && l.p50_ns <= l.p99_ns && l.p99_ns <= l.p999_ns && l.p999_ns <= l.max_ns);
        assert!(r.to_markdown().contains("| 21 | 640x480 |"));
        assert!(render_latency(&mut cam, &[], 1, &mut |_| {}).is_err());
    }
}
