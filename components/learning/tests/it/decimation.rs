//! Decimated training histories (`train --decimation`): a decimated window is a history the
//! robot could have been commanded, and its target what a rate-independent hysteresis would
//! have done after it; validation never leaks in; the support records the larger steps.

use bowden_learning::arch::{Architecture, Direction};
use bowden_learning::dataset::Dataset;
use bowden_learning::support::DataSupport;
use bowden_learning::train::{train, TrainConfig};
use bowden_learning::windows::{PhySource, SplitConfig, WindowSet};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

const J: usize = 3;
const HALF_WIDTH_DEG: [f64; J] = [6.0, 4.0, 7.5];

/// A play operator per joint (Prandtl–Ishlinskii's elementary hysteron): rate-independent,
/// its memory the input's extrema. Starts at 0 with the input at 0, as the padding says.
fn play(inputs: impl Iterator<Item = [f64; J]>) -> [f64; J] {
    inputs.fold([0.0; J], play_step)
}

fn play_step(z: [f64; J], x: [f64; J]) -> [f64; J] {
    std::array::from_fn(|k| z[k].max(x[k] - HALF_WIDTH_DEG[k]).min(x[k] + HALF_WIDTH_DEG[k]))
}

/// Eq. (16)-like commands (straight segments between random configurations, 3° grid steps)
/// and the play operator's output as the measured angles.
fn eq16_play_dataset(configs: usize, seed: u64) -> Dataset {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut cmd: Vec<[f64; J]> = vec![[0.0; J]];
    let mut a = [0.0; J];
    for _ in 0..configs {
        let b: [f64; J] = std::array::from_fn(|_| rng.random_range(-40.0..40.0));
        let dist = (0..J).map(|k| (b[k] - a[k]).powi(2)).sum::<f64>().sqrt();
        let steps = ((dist / (3.0 * (J as f64).sqrt())).floor() as usize).max(1);
        for s in 1..=steps {
            let f = s as f64 / steps as f64;
            cmd.push(std::array::from_fn(|k| a[k] + f * (b[k] - a[k])));
        }
        a = b;
    }
    let mut phy = Vec::with_capacity(cmd.len() * J);
    let mut z = [0.0; J];
    for &x in &cmd {
        z = play_step(z, x);
        phy.extend_from_slice(&z);
    }
    let n = cmd.len();
    Dataset {
        joints: J,
        t_ns: (0..n as i64).map(|i| i * 500_000_000).collect(),
        q_cmd_deg: cmd.iter().flatten().copied().collect(),
        q_phy_deg: phy,
        q_true_deg: None,
        valid: vec![true; n],
    }
}

fn row(ds: &Dataset, i: Option<usize>) -> [f64; J] {
    i.map_or([0.0; J], |i| std::array::from_fn(|k| ds.cmd(i)[k]))
}

#[test]
fn a_decimated_history_leaves_a_rate_independent_hysteresis_where_the_data_says() {
    let ds = eq16_play_dataset(150, 3);
    let l = 40;
    let mut w = WindowSet::build(&ds, Direction::Forward, l, SplitConfig::default(), PhySource::Vision).unwrap();
    w.set_decimation(4).unwrap();
    let n = w.samples();
    let mut rng = ChaCha8Rng::seed_from_u64(9);
    let (mut checked, mut longer_steps, mut naive_wrong) = (0, 0, 0);
    for _ in 0..600 {
        let t = w.train[rng.random_range(0..w.train.len())];
        let s = rng.random_range(2..=4usize);
        let hist = w.history(t + (s - 1) * n);
        assert_eq!(hist.len(), l);
        assert_eq!(hist[l - 1], Some(t), "the newest row is the target's own command");
        for pair in hist.windows(2) {
            if let (Some(a), Some(b)) = (pair[0], pair[1]) {
                assert!(b > a && b - a <= s, "a decimated step skips 0..{s} samples: {a} → {b}");
                longer_steps += (b - a > 1) as usize;
            }
        }
        // The play operator commanded along the decimated history ends where the dataset's
        // measurement (of the full history) says: the skipped samples changed nothing.
        let direct = play(hist.iter().map(|&i| row(&ds, i)));
        let recorded = ds.phy(t);
        for k in 0..J {
            assert!(
                (direct[k] - recorded[k]).abs() < 1e-9,
                "window {t} decimated by {s}: joint {k} {} vs recorded {}",
                direct[k],
                recorded[k]
            );
        }
        // Whereas a uniform decimation (every s-th sample, reversals skipped) often does not;
        // without its history the play operator starts from where the padding leaves it.
        let naive: Vec<Option<usize>> = (0..l).rev().map(|r| t.checked_sub(r * s)).collect();
        let z = play(naive.iter().map(|&i| row(&ds, i)));
        naive_wrong += (0..J).any(|k| (z[k] - recorded[k]).abs() > 1e-6) as usize;
        checked += 1;
    }
    assert_eq!(checked, 600);
    assert!(
        longer_steps > 600 * 10,
        "decimated histories step further ({longer_steps} longer steps)"
    );
    assert!(
        naive_wrong > 30,
        "uniform decimation would mislabel windows ({naive_wrong} of 600)"
    );
}

#[test]
fn decimation_one_reads_consecutive_samples_and_keeps_the_batch_ids() {
    let ds = eq16_play_dataset(60, 4);
    let mut w = WindowSet::build(&ds, Direction::Inverse, 20, SplitConfig::default(), PhySource::Vision).unwrap();
    w.set_decimation(1).unwrap();
    assert!(w.set_decimation(0).is_err(), "decimation 0 is refused");
    let t = w.train[w.train.len() / 2];
    let hist = w.history(t);
    assert_eq!(hist, (t + 1 - 20..=t).map(Some).collect::<Vec<_>>());
    let mut ids = Vec::new();
    w.decimated_ids(&w.train, &mut ChaCha8Rng::seed_from_u64(1), &mut ids);
    assert_eq!(ids, w.train);
    // gather of a decimated id copies exactly the rows of its history.
    w.set_decimation(3).unwrap();
    let n = w.samples();
    let id = t + 2 * n;
    let (mut x, mut y) = (vec![0.0f32; 20 * J], vec![0.0f32; J]);
    w.gather(&[id], &mut x, &mut y);
    for (r, i) in w.history(id).into_iter().enumerate() {
        let raw = i.map_or([0.0; J], |i| std::array::from_fn(|k| ds.phy(i)[k]));
        for k in 0..J {
            assert_eq!(x[r * J + k], w.norm_in.apply(k, raw[k]), "row {r} joint {k}");
        }
    }
    assert_eq!(&y[..], w.target(t));
}

#[test]
fn no_decimated_training_window_reads_a_validation_sample() {
    let ds = eq16_play_dataset(300, 5);
    let split = SplitConfig {
        val_fraction: 0.2,
        val_blocks: 4,
    };
    let plain = WindowSet::build(&ds, Direction::Forward, 30, split, PhySource::Vision).unwrap();
    let mut w = plain.clone();
    w.set_decimation(4).unwrap();
    let mut is_val = vec![false; ds.len()];
    for &t in &w.val {
        let (a, b) = w.span(t);
        is_val[a..=b].fill(true);
    }
    let n = w.samples();
    for &t in &w.train {
        for i in w.history(t + 3 * n).into_iter().flatten() {
            assert!(!is_val[i], "training target {t} reads validation sample {i}");
        }
    }
    assert!(w.train.len() < plain.train.len(), "wider histories purge more");
    assert_eq!(w.purged - plain.purged, plain.train.len() - w.train.len());
    assert_eq!(w.val, plain.val, "validation is untouched");
}

#[test]
fn the_support_records_the_steps_of_the_decimated_histories() {
    let ds = eq16_play_dataset(200, 6);
    let plain = WindowSet::build(&ds, Direction::Forward, 20, SplitConfig::default(), PhySource::Vision).unwrap();
    let mut w = plain.clone();
    w.set_decimation(4).unwrap();
    let (s1, s4) = (DataSupport::from_windows(&plain), DataSupport::from_windows(&w));
    for k in 0..J {
        let (a, b) = (s1.cmd_step_max_deg[k], s4.cmd_step_max_deg[k]);
        assert!(a > 0.0, "joint {k} moves");
        assert!(b > 2.0 * a && b <= 4.0 * a + 1e-9, "joint {k}: decimated {b} vs {a}");
    }
    assert_eq!(s1.cmd_min_deg, s4.cmd_min_deg);
    assert_eq!(s1.gap_max_deg, s4.gap_max_deg);
}

#[test]
fn training_refuses_windows_decimated_otherwise_than_its_config() {
    let ds = eq16_play_dataset(60, 7);
    let w = WindowSet::build(&ds, Direction::Forward, 10, SplitConfig::default(), PhySource::Vision).unwrap();
    let mut cfg = TrainConfig::paper(Architecture::Tcn, Direction::Forward, 10, 1, 0);
    cfg.decimation = 4;
    let e = train(&w, &cfg, None).unwrap_err().to_string();
    assert!(e.contains("decimated"), "{e}");
}
