//! Command sequences by the paper's eq. (16), and a synthetic hysteretic "robot" for tests
//! and benchmarks that must not depend on the simulated plant: per joint a play operator
//! (backlash of a cable in its sheath) with gain and a small cross-coupling, plus seeded
//! measurement noise.

use rand::Rng;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};

use crate::dataset::Dataset;

/// Eq. (16): between consecutive waypoints p_i, p_{i+1}, the points
/// p_i + j·step·(p_{i+1} − p_i)/‖p_{i+1} − p_i‖ for j = 0 ..= ⌊‖p_{i+1} − p_i‖ / step⌋.
/// The paper's step is 3·√5 (3° on each of 5 joints). Returns `n × J` row-major.
pub fn eq16_commands(waypoints: &[Vec<f64>], step: f64) -> Vec<f64> {
    let mut out = Vec::new();
    for w in waypoints.windows(2) {
        let (a, b) = (&w[0], &w[1]);
        let dist = a.iter().zip(b).map(|(x, y)| (y - x).powi(2)).sum::<f64>().sqrt();
        if dist == 0.0 {
            out.extend_from_slice(a);
            continue;
        }
        let n = (dist / step).floor() as usize;
        for j in 0..=n {
            let s = j as f64 * step / dist;
            out.extend(a.iter().zip(b).map(|(x, y)| x + s * (y - x)));
        }
    }
    out
}

/// Uniformly random waypoints inside `[q_min, q_max]` per joint.
pub fn random_waypoints(n: usize, q_min: &[f64], q_max: &[f64], rng: &mut ChaCha8Rng) -> Vec<Vec<f64>> {
    (0..n)
        .map(|_| {
            q_min
                .iter()
                .zip(q_max)
                .map(|(&lo, &hi)| rng.random_range(lo..=hi))
                .collect()
        })
        .collect()
}

/// A hysteretic sequence of `n` samples over `joints` joints, seeded: commands by eq. (16)
/// between random waypoints in ±50°, physical angles by a backlash (play) operator of
/// half-width 6 + 2k degrees on joint k, gain 0.9, 5 % coupling from the previous joint,
/// and N(0, 0.3°) measurement noise (`q_true` holds the noise-free angle).
pub fn hysteretic_dataset(n: usize, joints: usize, seed: u64) -> Dataset {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let step = 3.0 * (joints as f64).sqrt();
    let lo = vec![-50.0; joints];
    let hi = vec![50.0; joints];
    let mut cmd = Vec::with_capacity(n * joints);
    let mut last = random_waypoints(1, &lo, &hi, &mut rng).remove(0);
    while cmd.len() < n * joints {
        let next = random_waypoints(1, &lo, &hi, &mut rng).remove(0);
        let seg = eq16_commands(&[last.clone(), next.clone()], step);
        cmd.extend(seg);
        last = next;
    }
    cmd.truncate(n * joints);
    let noise = Normal::new(0.0, 0.3).unwrap_or_else(|_| unreachable!("constant parameters"));
    let mut state = vec![0.0f64; joints];
    let mut truth = Vec::with_capacity(n * joints);
    let mut phy = Vec::with_capacity(n * joints);
    for i in 0..n {
        for k in 0..joints {
            let r = 6.0 + 2.0 * k as f64;
            let x = cmd[i * joints + k];
            state[k] = state[k].clamp(x - r, x + r);
        }
        for k in 0..joints {
            let coupling = if k > 0 { 0.05 * state[k - 1] } else { 0.0 };
            let q = 0.9 * state[k] + coupling;
            truth.push(q);
            phy.push(q + noise.sample(&mut rng));
        }
    }
    Dataset {
        joints,
        t_ns: (0..n as i64).map(|i| i * 500_000_000).collect(),
        q_cmd_deg: cmd,
        q_phy_deg: phy,
        q_true_deg: Some(truth),
        valid: vec![true; n],
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn eq16_spacing_and_count() {
        let step = 3.0 * 5f64.sqrt();
        let a = vec![0.0; 5];
        let b = vec![30.0, -30.0, 10.0, 0.0, 5.0];
        let c = vec![30.0, -30.0, 10.0, 20.0, 5.0];
        let d1 = (900.0 + 900.0 + 100.0 + 25.0f64).sqrt();
        let cmds = eq16_commands(&[a.clone(), b.clone(), c], step);
        let n1 = (d1 / step).floor() as usize + 1;
        let n2 = (20.0 / step).floor() as usize + 1;
        assert_eq!(cmds.len(), (n1 + n2) * 5);
        // Within a segment, consecutive commands are exactly `step` apart in joint space.
        for i in 0..n1 - 1 {
            let d: f64 = (0..5).map(|k| (cmds[(i + 1) * 5 + k] - cmds[i * 5 + k]).powi(2)).sum();
            assert!((d.sqrt() - step).abs() < 1e-9);
        }
        assert_eq!(&cmds[..5], &a[..]);
        assert_eq!(&cmds[n1 * 5..n1 * 5 + 5], &b[..]);
    }

    #[test]
    fn synthetic_is_seeded_and_hysteretic() {
        let a = hysteretic_dataset(500, 5, 3);
        assert_eq!(a, hysteretic_dataset(500, 5, 3));
        assert_ne!(a.q_phy_deg, hysteretic_dataset(500, 5, 4).q_phy_deg);
        a.validate(std::path::Path::new("synthetic")).unwrap();
        let mae: f64 = a
            .q_cmd_deg
            .iter()
            .zip(&a.q_phy_deg)
            .map(|(c, p)| (c - p).abs())
            .sum::<f64>()
            / 2500.0;
        assert!(mae > 3.0, "mean |q_cmd − q_phy| = {mae}");
    }
}
