//! The further hysteresis families (`bouc-wen`, `lugre`; configs/plant-boucwen.toml and
//! configs/plant-lugre.toml): the paper's magnitudes, what makes each family what it is (rate
//! independence or rate dependence, dead band, asymmetry, widening with bend, creep), contact
//! and limits, and the validation of their tables. The checks every family shares (creep,
//! contact and limits, a complete state) include `preisach` too; its own are in `preisach.rs`.

// Loops over joint indices read like the maths they check.
#![allow(clippy::needless_range_loop)]

use crate::common;

use bowden_kinematics::{Robot, N_JOINTS};
use bowden_plant::{ConfigError, FamilyKind, Plant, PlantConfig};
use common::{commands, lands_in_the_papers_range, mean_abs_error, quasi_static_run, sweep};

fn file(name: &str) -> String {
    format!("{}/../../configs/{name}", env!("CARGO_MANIFEST_DIR"))
}

fn bouc_wen() -> PlantConfig {
    PlantConfig::load(file("plant-boucwen.toml")).unwrap()
}

fn lugre() -> PlantConfig {
    PlantConfig::load(file("plant-lugre.toml")).unwrap()
}

fn preisach() -> PlantConfig {
    PlantConfig::load(file("plant-preisach.toml")).unwrap()
}

#[test]
fn bouc_wen_plant_lands_in_the_papers_range() {
    let config = bouc_wen();
    assert_eq!(config.family, FamilyKind::BoucWen);
    lands_in_the_papers_range(&config);
}

#[test]
fn lugre_plant_lands_in_the_papers_range() {
    let config = lugre();
    assert_eq!(config.family, FamilyKind::Lugre);
    lands_in_the_papers_range(&config);
}

/// q1 swept 0 → +30 → −12 in 3° commands, the rest held.
fn path() -> Vec<[f64; 5]> {
    sweep([0.0, 0.0, 0.0, -10.0, 10.0], 0, 30.0, 3.0)
        .into_iter()
        .take(25)
        .collect()
}

/// Runs `path()` holding each command `hold_s` (1 ms steps): the quasi-static state right at the
/// end of the path, and q_phy after a further 3 s at the last command.
fn run_path(config: &PlantConfig, hold_s: f64) -> ([f64; 5], [f64; 5]) {
    let robot = Robot::paper_default();
    let mut plant = Plant::new(&robot, config, 1);
    let cmds = path();
    for q in &cmds {
        plant.settle_joints(q, hold_s, 0.001).unwrap();
    }
    let moving = plant.q_quasi_static_deg();
    plant.settle_joints(cmds.last().unwrap(), 3.0, 0.01).unwrap();
    (moving, plant.q_phy_deg())
}

#[test]
fn lugre_is_rate_dependent() {
    let config = lugre();
    let (slow_moving, slow_settled) = run_path(&config, 0.5);
    // 3° per 5 ms (600°/s): the cables' distal ends fall behind (viscous friction), and sliding
    // friction is the Coulomb level rather than the static one (Stribeck).
    let (fast_moving, fast_settled) = run_path(&config, 0.005);
    eprintln!("slow {slow_moving:?} {slow_settled:?}\nfast {fast_moving:?} {fast_settled:?}");
    assert!(
        (fast_moving[0] - slow_moving[0]).abs() > 1.0,
        "q1 at the end of the path: fast {} vs slow {}",
        fast_moving[0],
        slow_moving[0]
    );
    // Even the settled state remembers how fast the path was run (3° per 1 ms: the slider did
    // not reach the top of the sweep before the command turned).
    let (_, fastest_settled) = run_path(&config, 0.001);
    assert!(
        (fastest_settled[0] - slow_settled[0]).abs() > 0.3,
        "q1 settled: fastest {} vs slow {}",
        fastest_settled[0],
        slow_settled[0]
    );
}

#[test]
fn bouc_wen_is_rate_independent() {
    let config = bouc_wen();
    let (slow_moving, slow_settled) = run_path(&config, 0.5);
    for hold in [0.001, 0.005, 0.05] {
        let (moving, settled) = run_path(&config, hold);
        // The quasi-static state depends on the command path only: bit for bit.
        assert_eq!(moving, slow_moving, "hold {hold}");
        for j in 0..N_JOINTS {
            assert!((settled[j] - slow_settled[j]).abs() < 1e-6, "hold {hold} q{}", j + 1);
        }
    }
    // One large command and the same command reached in many small ones agree (the Bouc–Wen
    // state is sub-stepped on the command change, not on time).
    let robot = Robot::paper_default();
    let mut jump = Plant::new(&robot, &config, 1);
    let mut walk = Plant::new(&robot, &config, 1);
    let targets = [[40.0, -25.0, 30.0, -20.0, 30.0], [-10.0, 15.0, -20.0, 5.0, 35.0]];
    let mut from = [0.0; 5];
    for to in targets {
        jump.settle_joints(&to, 0.5, 0.01).unwrap();
        for k in 1..=40 {
            let q: [f64; 5] = core::array::from_fn(|j| from[j] + (to[j] - from[j]) * k as f64 / 40.0);
            walk.step_joints(&q, 0.001).unwrap();
        }
        walk.settle_joints(&to, 0.5, 0.01).unwrap();
        from = to;
        for j in 0..N_JOINTS {
            let (a, b) = (jump.q_phy_deg()[j], walk.q_phy_deg()[j]);
            assert!((a - b).abs() < 0.05, "q{}: one jump {a} vs small steps {b}", j + 1);
        }
    }
}

#[test]
fn lugre_steps_and_settles_at_any_dt() {
    let robot = Robot::paper_default();
    let config = lugre();
    let cmds = commands(&robot, 3, 7);
    let run = |dt: f64| {
        let mut plant = Plant::new(&robot, &config, 1);
        for q in &cmds {
            plant.settle_joints(q, 0.5, dt).unwrap();
        }
        plant.q_phy_deg()
    };
    let fine = run(0.001);
    for dt in [0.01, 0.05] {
        let coarse = run(dt);
        for j in 0..N_JOINTS {
            assert!(
                (coarse[j] - fine[j]).abs() < 0.3,
                "dt {dt} q{}: {} vs {}",
                j + 1,
                coarse[j],
                fine[j]
            );
        }
    }
}

#[test]
fn bouc_wen_stands_still_after_a_reversal_and_is_asymmetric() {
    let robot = Robot::paper_default();
    let mut cfg = bouc_wen();
    cfg.variation.relative_sd = 0.0;
    let mut plant = Plant::new(&robot, &cfg, 1);
    let cmds = sweep([0.0; 5], 0, 54.0, 3.0);
    let phy = quasi_static_run(&mut plant, &cmds);
    let top = 18;
    assert_eq!(cmds[top][0], 54.0);
    assert!(phy[top][0] < 54.0 - 5.0, "q1 lags on the way up: {}", phy[top][0]);
    let held = (top + 1..cmds.len())
        .take_while(|&k| (phy[k][0] - phy[top][0]).abs() < 0.5)
        .count();
    assert!(held >= 2, "dead band after reversal: only {held} steps held");
    // q1 lags an increasing command by more than a decreasing one (width_up > width_down):
    // measured against the elastic line through the loop's middle, at ±30° of command.
    let bottom = cmds.iter().position(|q| q[0] == -54.0).unwrap();
    let at = |from: usize, to: usize, c: f64| (from..to).find(|&k| cmds[k][0] == c).map(|k| phy[k][0]).unwrap();
    let down_at_30 = at(top, bottom, 30.0);
    let up_at_30 = at(bottom, cmds.len(), 30.0);
    let down_at_m30 = at(top, bottom, -30.0);
    let up_at_m30 = at(bottom, cmds.len(), -30.0);
    let middle_30 = 0.5 * (down_at_30 + up_at_30);
    let middle_m30 = 0.5 * (down_at_m30 + up_at_m30);
    eprintln!("+30: up {up_at_30} down {down_at_30}; -30: up {up_at_m30} down {down_at_m30}");
    // Symmetric bands would put the middle on a line through the origin.
    assert!(
        (middle_30 + middle_m30).abs() > 1.0,
        "asymmetric loop: middles {middle_30} and {middle_m30}"
    );
    assert!(down_at_30 - up_at_30 > 5.0, "a loop, not a line");
}

#[test]
fn bands_widen_with_the_bend_of_segment_1() {
    // The wrist swept with segment 1 straight and bent: it departs further from its command as
    // the cables crossing segment 1 wrap its hinges (bouc-wen: widening_per_rad; lugre: the
    // capstan exponent of the Coulomb level).
    let robot = Robot::paper_default();
    for mut cfg in [bouc_wen(), lugre()] {
        cfg.joints.coupling = [[0.0; 5]; 5];
        let deviation = |q1: f64| {
            let cmds = sweep([q1, 0.0, 0.0, -10.0, 10.0], 2, 42.0, 3.0);
            let mut plant = Plant::new(&robot, &cfg, 1);
            let phy = quasi_static_run(&mut plant, &cmds);
            mean_abs_error(&cmds, &phy, 2)
        };
        let (straight, bent) = (deviation(0.0), deviation(50.0));
        assert!(
            bent > straight + 1.5,
            "{}: q3 sweep deviation straight {straight} vs bent {bent}",
            cfg.name
        );
    }
}

#[test]
fn lugre_band_grows_with_sheath_curvature() {
    let robot = Robot::paper_default();
    let cmds = commands(&robot, 20, 3);
    let mae = |wrap: f64| {
        let mut cfg = lugre();
        cfg.sheath.wrap_deg = [wrap; 10];
        let phy = quasi_static_run(&mut Plant::new(&robot, &cfg, 1), &cmds);
        (0..N_JOINTS)
            .map(|j| mean_abs_error(&cmds, &phy, j))
            .collect::<Vec<_>>()
    };
    let (low, high) = (mae(120.0), mae(360.0));
    for j in 0..N_JOINTS {
        assert!(high[j] > low[j] + 1.0, "q{}: {} vs {}", j + 1, low[j], high[j]);
    }
}

#[test]
fn creep_drifts_every_family() {
    // w1 creeps (fast, to keep the test short), its antagonist w2 does not: segment 1 pitch
    // drifts negative, about 0.3 mm / (2·2 mm/rad) ≈ 4° less the elastic gain loss, as on the
    // capstan plant.
    let robot = Robot::paper_default();
    let q = [20.0, 0.0, 0.0, -10.0, 10.0];
    for base in [bouc_wen(), lugre(), preisach()] {
        let mut cfg = base.clone();
        cfg.drift.rate_mm_per_hour[0] = 30.0;
        cfg.drift.max_mm = 0.3;
        let mut plant = Plant::new(&robot, &cfg, 1);
        let mut still = Plant::new(&robot, &base, 1);
        plant.settle_joints(&q, 0.5, 0.01).unwrap();
        still.settle_joints(&q, 0.5, 0.01).unwrap();
        let before = plant.q_phy_deg()[0];
        assert!((before - still.q_phy_deg()[0]).abs() < 0.1, "{}", cfg.name);
        // A minute later (saturated at 0.3 mm after 36 s). The drift is what creep did: the
        // difference to the same plant without it.
        plant.settle_joints(&q, 60.0, 0.1).unwrap();
        still.settle_joints(&q, 30.0, 0.1).unwrap();
        let half_way = still.q_phy_deg()[0];
        still.settle_joints(&q, 30.0, 0.1).unwrap();
        let drift = plant.q_phy_deg()[0] - still.q_phy_deg()[0];
        assert!(drift < -1.5 && drift > -8.0, "{}: drift {drift}", cfg.name);
        // Without creep nothing moves: not at all for the families whose held state is static,
        // and for a delayed slip (preisach) only the rest of its bounded relaxation (after
        // 0.5 s, κ·e^{−0.5 s/τ} ≈ 5 % of the 20° step still to reach the contacts: ~1°), over
        // long before 30 s.
        let delayed_slip = base.preisach.as_ref().is_some_and(|p| p.relaxation_fraction > 0.0);
        let own = if delayed_slip { 2.0 } else { 0.1 };
        let moved = still.q_phy_deg()[0] - before;
        assert!(moved.abs() < own, "{}: no creep without drift ({moved})", cfg.name);
        assert!(
            (still.q_phy_deg()[0] - half_way).abs() < 1e-6,
            "{}: still without drift after 30 s",
            cfg.name
        );
    }
    // Creep beyond the pre-tension stretch is slack: the pair's band widens.
    let deviation = |cfg: &PlantConfig| {
        let mut plant = Plant::new(&robot, cfg, 1);
        plant.settle_joints(&[0.0, 0.0, 0.0, -10.0, 10.0], 60.0, 0.1).unwrap();
        let cmds = sweep([0.0, 0.0, 0.0, -10.0, 10.0], 0, 45.0, 3.0);
        let phy = quasi_static_run(&mut plant, &cmds);
        mean_abs_error(&cmds, &phy, 0)
    };
    for base in [bouc_wen(), lugre(), preisach()] {
        let mut slack = base.clone();
        // 4 mm on each cable of the q1 pair (after 36 s): beyond both files' pre-tension stretch.
        slack.drift.rate_mm_per_hour[0] = 400.0;
        slack.drift.rate_mm_per_hour[1] = 400.0;
        slack.drift.max_mm = 4.0;
        let (tight, loose) = (deviation(&base), deviation(&slack));
        assert!(
            loose > tight + 2.0,
            "{}: q1 deviation {tight} → {loose} with slack",
            base.name
        );
    }
}

#[test]
fn jaws_never_cross_and_joints_stay_in_limits_in_every_family() {
    let robot = Robot::paper_default();
    let lim = robot.config.limits.clone();
    for cfg in [bouc_wen(), lugre(), preisach()] {
        let mut plant = Plant::new(&robot, &cfg, 4);
        let mut cmds = sweep([0.0; 5], 2, 44.0, 4.0);
        cmds.extend(sweep([0.0, 0.0, 0.0, 5.0, 5.0], 1, 60.0, 6.0));
        cmds.extend(commands(&robot, 10, 8));
        for q in &cmds {
            plant.step_joints(q, 0.02).unwrap();
            plant.settle_joints(q, 0.3, 0.01).unwrap();
            let p = plant.q_phy_deg();
            assert!(
                p[4] - p[3] >= lim.min_jaw_opening_deg - 1e-9,
                "{}: jaws crossed: {p:?}",
                cfg.name
            );
            for j in 0..N_JOINTS {
                assert!(
                    p[j] >= lim.q_min_deg[j] - 1e-9 && p[j] <= lim.q_max_deg[j] + 1e-9,
                    "{}: q{} = {}",
                    cfg.name,
                    j + 1,
                    p[j]
                );
            }
        }
    }
}

#[test]
fn every_family_reports_a_complete_state() {
    let robot = Robot::paper_default();
    for cfg in [bouc_wen(), lugre(), preisach()] {
        let mut plant = Plant::new(&robot, &cfg, 1);
        let q = [12.0, -7.0, 9.0, -4.0, 6.0];
        plant.settle_joints(&q, 0.5, 0.01).unwrap();
        let mut s = bowden_interfaces::PlantState::default();
        plant.fill_state(&mut s);
        for j in 0..5 {
            assert!((s.q_cmd_deg[j] - q[j]).abs() < 1e-9, "decoded command");
        }
        assert_eq!(&s.q_phy_deg[..5], &plant.q_phy_deg());
        assert_eq!(&s.cable_tip_mm[..10], &plant.cable_tip_mm());
        assert!(plant.cable_tension_n().iter().all(|t| t.is_finite() && *t >= 0.0));
        assert!(plant.last_iterations() > 0 || cfg.family == FamilyKind::BoucWen);
        assert_eq!(s.t_sim_ns, 500_000_000);
    }
}

fn parse(text: &str) -> Result<PlantConfig, ConfigError> {
    PlantConfig::parse(text, std::path::Path::new("test/plant.toml"))
}

fn invalid_field(text: &str) -> String {
    match parse(text) {
        Err(ConfigError::Invalid { field, .. }) => field,
        other => panic!("expected an invalid field, got {other:?}"),
    }
}

#[test]
fn family_tables_are_validated_and_errors_name_the_field() {
    let bw = std::fs::read_to_string(file("plant-boucwen.toml")).unwrap();
    let lg = std::fs::read_to_string(file("plant-lugre.toml")).unwrap();
    let capstan = std::fs::read_to_string(file("plant.toml")).unwrap();
    // Files without `family` are the capstan plant, unchanged.
    assert_eq!(parse(&capstan).unwrap().family, FamilyKind::Capstan);
    assert_eq!(parse(&capstan).unwrap(), PlantConfig::paper_default());
    let robot2 = parse(&std::fs::read_to_string(file("plant-robot2.toml")).unwrap()).unwrap();
    assert_eq!(robot2.family, FamilyKind::Capstan);
    assert!(robot2.hysteresis.is_some() && robot2.bouc_wen.is_none() && robot2.lugre.is_none());

    let cases: [(&str, &str, &str, &str); 12] = [
        (&bw, "exponent = 1.0", "exponent = 0.5", "bouc_wen.exponent"),
        (&bw, "gamma = 0.5", "gamma = 0.4", "bouc_wen.gamma"),
        (&bw, "beta = 0.5", "beta = 0.6", "bouc_wen.gamma"),
        (
            &bw,
            "width_up_deg = [11.5, 7.0, 9.0",
            "width_up_deg = [11.5, 7.0, -1.0",
            "bouc_wen.width_up_deg[2]",
        ),
        (
            &bw,
            "width_down_deg = [7.0, 11.5, 7.0, 8.0, 11.0]",
            "width_down_deg = [7.0, 11.5, 7.0, 8.0, nan]",
            "bouc_wen.width_down_deg[4]",
        ),
        (
            &bw,
            "  [0.6, 0.6, 0.0],",
            "  [0.6, -0.6, 0.0],",
            "bouc_wen.widening_per_rad[2][1]",
        ),
        (
            &lg,
            "viscous_ns_per_mm = 0.08",
            "viscous_ns_per_mm = 0.0",
            "lugre.viscous_ns_per_mm",
        ),
        (
            &lg,
            "stribeck_ratio = 1.3",
            "stribeck_ratio = 0.9",
            "lugre.stribeck_ratio",
        ),
        (
            &lg,
            "stribeck_velocity_mm_per_s = 1.0",
            "stribeck_velocity_mm_per_s = -1.0",
            "lugre.stribeck_velocity_mm_per_s",
        ),
        (
            &lg,
            "bristle_stiffness_n_per_mm = 100.0",
            "bristle_stiffness_n_per_mm = 0.0",
            "lugre.bristle_stiffness_n_per_mm",
        ),
        (
            &lg,
            "free_play_mm = [0.1, 0.1, 0.08",
            "free_play_mm = [0.1, 0.1, -0.08",
            "lugre.free_play_mm[2]",
        ),
        (
            &lg,
            "bristle_damping_ns_per_mm = 0.2",
            "bristle_damping_ns_per_mm = -0.2",
            "lugre.bristle_damping_ns_per_mm",
        ),
    ];
    for (text, from, to, field) in cases {
        assert!(text.contains(from), "fixture: {from}");
        let changed = text.replacen(from, to, 1);
        assert_eq!(invalid_field(&changed), field, "{to}");
        let msg = parse(&changed).unwrap_err().to_string();
        assert!(msg.contains("test/plant.toml") && msg.contains(field), "{msg}");
    }

    // The selected family's table is required …
    let no_table = bw.replacen("\n[bouc_wen]\n", "\n[unused_bouc_wen]\n", 1);
    assert!(matches!(parse(&no_table), Err(ConfigError::Parse { .. })));
    let start = bw.find("\n[bouc_wen]\n").unwrap();
    let end = bw.find("\n[dynamics]\n").unwrap();
    let without = format!("{}{}", &bw[..start], &bw[end..]);
    assert_eq!(invalid_field(&without), "bouc_wen");
    assert!(parse(&without).unwrap_err().to_string().contains("required"));
    let lugre_as_capstan = lg.replacen("family = \"lugre\"\n", "", 1);
    assert_eq!(invalid_field(&lugre_as_capstan), "hysteresis");
    // … and another family's is refused, naming it.
    let both = format!("{bw}\n[hysteresis]\nplays = 6\nthreshold_spread = 0.8\n");
    assert_eq!(invalid_field(&both), "hysteresis");
    let msg = parse(&both).unwrap_err().to_string();
    assert!(msg.contains("capstan") && msg.contains("bouc-wen"), "{msg}");
    let lg_table = &lg[lg.find("\n[lugre]\n").unwrap()..lg.find("\n[dynamics]\n").unwrap()];
    assert_eq!(invalid_field(&format!("{capstan}\n{lg_table}")), "lugre");
    let bw_table = &bw[start..end];
    assert_eq!(invalid_field(&format!("{lg}\n{bw_table}")), "bouc_wen");

    // Unknown families and fields are parse errors naming them.
    let e = parse(&lg.replacen("family = \"lugre\"", "family = \"dahl\"", 1)).unwrap_err();
    assert!(
        matches!(e, ConfigError::Parse { .. }) && e.to_string().contains("dahl"),
        "{e}"
    );
    let e = parse(&lg.replacen("[lugre]\n", "[lugre]\nsigma3 = 1.0\n", 1)).unwrap_err();
    assert!(
        matches!(e, ConfigError::Parse { .. }) && e.to_string().contains("sigma3"),
        "{e}"
    );
}

#[test]
#[should_panic(expected = "without its [lugre] table")]
fn a_plant_refuses_an_unvalidated_family() {
    let mut cfg = PlantConfig::paper_default();
    cfg.family = FamilyKind::Lugre;
    let _ = Plant::new(&Robot::paper_default(), &cfg, 1);
}
