//! Cable slack (`[drift]`): a sudden slip of one cable steps its joint at exactly its time and
//! not before, creep grows linearly from its start to its maximum, bad slack fields name the
//! field, the scenario files say what they do, and plants without slack (every shipped robot)
//! compute exactly what they did before slips and `start_s` existed.

use crate::common;

use bowden_kinematics::{Robot, N_JOINTS};
use bowden_plant::config::SlipConfig;
use bowden_plant::{ConfigError, Plant, PlantConfig};
use std::path::Path;

fn config(file: &str) -> PlantConfig {
    PlantConfig::load(format!("{}/../../configs/{file}", env!("CARGO_MANIFEST_DIR"))).unwrap()
}

fn families() -> Vec<PlantConfig> {
    [
        "plant.toml",
        "plant-boucwen.toml",
        "plant-lugre.toml",
        "plant-preisach.toml",
    ]
    .iter()
    .map(|f| config(f))
    .collect()
}

/// FNV-1a over every state the plant exposes after each of 40 eq. (16) commands held 0.5 s.
fn fingerprint(cfg: &PlantConfig) -> u64 {
    let robot = Robot::paper_default();
    let mut plant = Plant::new(&robot, cfg, 7);
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    for q in common::commands(&robot, 40, 3) {
        for _ in 0..5 {
            plant.step_joints(&q, 0.1).unwrap();
        }
        for b in common::state_bytes(&plant) {
            h = (h ^ u64::from(b)).wrapping_mul(0x100_0000_01b3);
        }
    }
    h
}

#[test]
fn plants_without_slack_and_creep_from_the_start_are_unchanged() {
    // Fingerprints taken with the plant as it was before slips and `start_s` were added: drift
    // off, and creep from t = 0 (3–12 mm/h, capped at 0.5 mm) as before.
    let expected = [
        ("plant.toml", 0x1b5f_fddf_0131_7244u64, 0xafc8_8653_e6b9_5501u64),
        ("plant-boucwen.toml", 0x9d36_9db7_ddac_4849, 0x5571_8187_69bd_70ad),
        ("plant-lugre.toml", 0x5849_a352_c00d_d77b, 0x4024_26b1_0e7d_0472),
        ("plant-robot2.toml", 0xc206_2a87_db44_1386, 0x7366_0001_72c5_7470),
    ];
    for (file, off, creep) in expected {
        let cfg = config(file);
        assert!(!cfg.drift.is_active() && cfg.drift.onset_s().is_none(), "{file}");
        assert_eq!(fingerprint(&cfg), off, "{file}: drift off");
        let mut c = cfg.clone();
        c.drift.rate_mm_per_hour = core::array::from_fn(|i| 3.0 + i as f64);
        c.drift.max_mm = 0.5;
        assert_eq!(fingerprint(&c), creep, "{file}: creep from t = 0");
        // A plant file written back has no slack fields it did not have.
        let text = toml::to_string(&cfg).unwrap();
        assert!(!text.contains("start_s") && !text.contains("slip"), "{file}");
    }
}

#[test]
fn slack_not_yet_due_changes_nothing() {
    let robot = Robot::paper_default();
    for cfg in families() {
        let mut late = cfg.clone();
        late.drift.rate_mm_per_hour = [30.0; 10];
        late.drift.start_s = 1000.0;
        late.drift.slip.push(SlipConfig {
            at_s: 999.0,
            cable: 5,
            mm: 1.0,
        });
        assert_eq!(late.drift.onset_s(), Some(999.0));
        let (mut a, mut b) = (Plant::new(&robot, &cfg, 3), Plant::new(&robot, &late, 3));
        for q in common::commands(&robot, 12, 5) {
            a.settle_joints(&q, 0.5, 0.01).unwrap();
            b.settle_joints(&q, 0.5, 0.01).unwrap();
            assert_eq!(common::state_bytes(&a), common::state_bytes(&b), "{}", cfg.name);
        }
        assert_eq!(b.cable_slack_mm(), [0.0; 10]);
    }
}

#[test]
fn a_slip_steps_its_joint_at_exactly_its_time_and_not_before() {
    let robot = Robot::paper_default();
    // A bent pose held throughout; w3 (q2 yaw, pulled for positive yaw) slips 0.5 mm at 2 s.
    let q_cmd = [25.0, 15.0, -10.0, 12.0, -8.0];
    for cfg in families() {
        let mut slipping = cfg.clone();
        slipping.drift.slip.push(SlipConfig {
            at_s: 2.0,
            cable: 3,
            mm: 0.5,
        });
        let (mut still, mut plant) = (Plant::new(&robot, &cfg, 11), Plant::new(&robot, &slipping, 11));
        let dt = 0.01;
        for _ in 0..199 {
            still.step_joints(&q_cmd, dt).unwrap();
            plant.step_joints(&q_cmd, dt).unwrap();
        }
        assert_eq!(plant.t_sim_ns(), 1_990_000_000);
        assert_eq!(
            common::state_bytes(&plant),
            common::state_bytes(&still),
            "{}: nothing before the slip",
            cfg.name
        );
        assert_eq!(plant.cable_slack_mm(), [0.0; 10]);
        // The step that ends at 2.0 s applies it: the equilibrium jumps, the joint starts to follow.
        still.step_joints(&q_cmd, dt).unwrap();
        plant.step_joints(&q_cmd, dt).unwrap();
        assert_eq!(plant.t_sim_ns(), 2_000_000_000);
        let mut slack = [0.0; 10];
        slack[2] = 0.5;
        assert_eq!(plant.cable_slack_mm(), slack);
        let jump = plant.q_quasi_static_deg()[1] - still.q_quasi_static_deg()[1];
        let moved = plant.q_phy_deg()[1] - still.q_phy_deg()[1];
        assert!(jump < -2.0, "{}: equilibrium of q2 moved {jump:.3}°", cfg.name);
        assert!(
            moved < 0.0 && moved > jump,
            "{}: q2 starts toward it: {moved:.3}°",
            cfg.name
        );
        // Settled: w3 sits 0.5 mm out over a 2 × 2 mm/rad lever = 7.2° less the elastic gain
        // loss; q2 moves most, and negative (less yaw).
        for _ in 0..100 {
            still.step_joints(&q_cmd, dt).unwrap();
            plant.step_joints(&q_cmd, dt).unwrap();
        }
        let d: Vec<f64> = (0..N_JOINTS)
            .map(|k| plant.q_phy_deg()[k] - still.q_phy_deg()[k])
            .collect();
        assert!(d[1] < -3.0 && d[1] > -9.0, "{}: q2 moved {:.3}°", cfg.name, d[1]);
        assert!(
            (0..N_JOINTS).all(|k| k == 1 || d[k].abs() < d[1].abs()),
            "{}: q2 moves most: {d:?}",
            cfg.name
        );
    }
}

#[test]
fn creep_grows_linearly_from_its_start_to_its_maximum() {
    let robot = Robot::paper_default();
    let mut cfg = PlantConfig::paper_default();
    // 6 mm/h on w1..w4 from 10 s: 0.1 mm per minute, 1 mm after 10 minutes.
    cfg.drift.rate_mm_per_hour = [6.0, 6.0, 6.0, 6.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0];
    cfg.drift.max_mm = 1.0;
    cfg.drift.start_s = 10.0;
    assert_eq!(cfg.drift.onset_s(), Some(10.0));
    let mut plant = Plant::new(&robot, &cfg, 2026);
    let q_cmd = [20.0, -15.0, 0.0, 10.0, -10.0];
    plant.settle_joints(&q_cmd, 10.0, 0.05).unwrap();
    assert_eq!(plant.cable_slack_mm(), [0.0; 10], "none before start_s");
    let mut tension = vec![plant.cable_tension_n()];
    for minute in 1..=12 {
        plant.settle_joints(&q_cmd, 60.0, 0.5).unwrap();
        let s = plant.cable_slack_mm();
        let want = (0.1 * f64::from(minute)).min(1.0);
        for (i, &v) in s.iter().enumerate() {
            let w = if i < 4 { want } else { 0.0 };
            assert!((v - w).abs() < 1e-9, "minute {minute}: w{} slack {v} vs {w}", i + 1);
        }
        tension.push(plant.cable_tension_n());
    }
    // The pairs' pre-tension drops with the creep, evenly per minute until it stops: 0.2 mm more
    // per pair and minute over the pair's compliance (2 × 0.21 mm/N) ≈ 0.48 N.
    let per_cable = |i: usize| -> Vec<f64> { tension.iter().map(|t| t[i]).collect() };
    for i in 0..4 {
        let drops: Vec<f64> = per_cable(i).windows(2).map(|w| w[0] - w[1]).collect();
        for &d in &drops[..10] {
            assert!((d - 0.48).abs() < 0.1, "w{}: drops {drops:?}", i + 1);
        }
        for &d in &drops[10..] {
            assert!(d.abs() < 1e-6, "w{}: creep stops at max_mm: {drops:?}", i + 1);
        }
    }
    for i in 4..10 {
        let t = per_cable(i);
        assert!((t[0] - t[12]).abs() < 0.2, "w{} barely changes", i + 1);
    }
}

fn parse(text: &str) -> Result<PlantConfig, ConfigError> {
    PlantConfig::parse(text, Path::new("test/plant.toml"))
}

#[test]
fn bad_slack_fields_name_the_field() {
    let shipped = include_str!("../../../../configs/plant.toml");
    let slip = |at: &str, cable: &str, mm: &str| format!("\n[[drift.slip]]\nat_s = {at}\ncable = {cable}\nmm = {mm}\n");
    let good = slip("120.0", "3", "0.5");
    let ok = parse(&format!("{shipped}{good}")).unwrap();
    assert_eq!(
        ok.drift.slip,
        vec![SlipConfig {
            at_s: 120.0,
            cable: 3,
            mm: 0.5
        }]
    );
    let cases = [
        (slip("-1.0", "3", "0.5"), "drift.slip[0].at_s"),
        (slip("nan", "3", "0.5"), "drift.slip[0].at_s"),
        (slip("120.0", "0", "0.5"), "drift.slip[0].cable"),
        (slip("120.0", "11", "0.5"), "drift.slip[0].cable"),
        (slip("120.0", "3", "0.0"), "drift.slip[0].mm"),
        (slip("120.0", "3", "-0.5"), "drift.slip[0].mm"),
        (slip("120.0", "3", "inf"), "drift.slip[0].mm"),
        (format!("{good}{}", slip("130.0", "12", "0.5")), "drift.slip[1].cable"),
        (good.repeat(17), "drift.slip"),
    ];
    for (extra, field) in cases {
        let e = parse(&format!("{shipped}{extra}")).unwrap_err();
        let msg = e.to_string();
        assert!(
            matches!(e, ConfigError::Invalid { .. }) && msg.contains(field) && msg.contains("test/plant.toml"),
            "{extra}: {msg}"
        );
    }
    let cable0 = parse(&format!("{shipped}{}", slip("1.0", "0", "0.5")))
        .unwrap_err()
        .to_string();
    assert!(cable0.contains("1..=10"), "{cable0}");
    for bad in ["-5.0", "nan"] {
        let text = shipped.replacen("max_mm = 1.0\n", &format!("max_mm = 1.0\nstart_s = {bad}\n"), 1);
        let msg = parse(&text).unwrap_err().to_string();
        assert!(msg.contains("drift.start_s"), "{msg}");
    }
    // Unknown keys in a slip, and a missing one, are parse errors naming them.
    let unknown = format!("{shipped}\n[[drift.slip]]\nat_s = 1.0\ncable = 3\nmm = 0.5\nwhen = 2\n");
    let e = parse(&unknown).unwrap_err();
    assert!(
        matches!(e, ConfigError::Parse { .. }) && e.to_string().contains("when"),
        "{e}"
    );
    let missing = format!("{shipped}\n[[drift.slip]]\nat_s = 1.0\ncable = 3\n");
    let e = parse(&missing).unwrap_err();
    assert!(
        matches!(e, ConfigError::Parse { .. }) && e.to_string().contains("mm"),
        "{e}"
    );
}

#[test]
fn the_scenario_files_do_what_they_say() {
    let robot = Robot::paper_default();
    let base = config("plant.toml");
    for file in [
        "plant-slack-creep.toml",
        "plant-slack-slip.toml",
        "plant-lugre-slack-creep.toml",
    ] {
        let text = std::fs::read_to_string(format!("{}/../../configs/{file}", env!("CARGO_MANIFEST_DIR"))).unwrap();
        assert!(
            text.starts_with("# CABLE SLACK SCENARIO"),
            "{file}: says what it is for"
        );
        let cfg = config(file);
        assert_eq!(cfg.drift.onset_s(), Some(120.0), "{file}: two clean minutes first");
        if file.contains("lugre") {
            let mut plain = config("plant-lugre.toml");
            plain.name = cfg.name.clone();
            plain.drift = cfg.drift.clone();
            assert_eq!(cfg, plain, "{file}: plant-lugre.toml but for name and [drift]");
        } else {
            let mut plain = base.clone();
            plain.name = cfg.name.clone();
            plain.drift = cfg.drift.clone();
            assert_eq!(cfg, plain, "{file}: plant.toml but for name and [drift]");
            assert_eq!(
                cfg.variation.unit,
                Some(2026),
                "{file}: the unit the models were made on"
            );
        }
        // Slack at the end of a 15-minute session.
        let mut plant = Plant::new(&robot, &cfg, 1);
        plant.settle_joints(&[0.0; 5], 900.0, 1.0).unwrap();
        let s = plant.cable_slack_mm();
        if file.contains("creep") {
            assert_eq!(s, [1.0, 1.0, 1.0, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0], "{file}");
            // 1 mm accumulates over 10 minutes of creep: 0.5 mm at 420 s.
            let mut p = Plant::new(&robot, &cfg, 1);
            p.settle_joints(&[0.0; 5], 420.0, 1.0).unwrap();
            assert!((p.cable_slack_mm()[0] - 0.5).abs() < 1e-9, "{file}");
        } else {
            assert_eq!(s, [0.0, 0.0, 0.5, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0], "{file}");
        }
    }
}
