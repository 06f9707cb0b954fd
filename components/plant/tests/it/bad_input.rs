//! Bad input is refused with a typed error naming what and where, and leaves the state as it was.

use crate::common;

use bowden_kinematics::Robot;
use bowden_plant::{ConfigError, Plant, PlantConfig, PlantError};
use common::state_bytes;

/// The shipped plant of every hysteresis family: the checks below hold for each.
fn every_family() -> Vec<PlantConfig> {
    let mut out = vec![PlantConfig::paper_default()];
    for file in ["plant-boucwen.toml", "plant-lugre.toml", "plant-preisach.toml"] {
        out.push(PlantConfig::load(format!("{}/../../configs/{file}", env!("CARGO_MANIFEST_DIR"))).unwrap());
    }
    out
}

fn warmed_up(config: &PlantConfig) -> (Robot, Plant) {
    let robot = Robot::paper_default();
    let mut plant = Plant::new(&robot, config, 3);
    for q in [[20.0, -10.0, 15.0, -20.0, 5.0], [-5.0, 12.0, -8.0, -3.0, 25.0]] {
        plant.settle_joints(&q, 0.3, 0.01).unwrap();
    }
    plant.step_joints(&[0.0, 0.0, 0.0, -5.0, 5.0], 0.01).unwrap(); // mid-settling
    (robot, plant)
}

#[test]
fn rejected_commands_leave_the_state_untouched() {
    for config in every_family() {
        rejected_commands_leave(&config);
    }
}

fn rejected_commands_leave(config: &PlantConfig) {
    let (robot, mut plant) = warmed_up(config);
    let good = robot.cables().displacements_mm(&[10.0, 10.0, 10.0, -10.0, 10.0]);
    let before = state_bytes(&plant);
    let (lo, hi) = plant.command_range_mm();

    let mut nan = good;
    nan[4] = f64::NAN;
    assert!(matches!(
        plant.step(&nan, 0.01),
        Err(PlantError::NonFiniteCommand { cable: 5, value_mm }) if value_mm.is_nan()
    ));
    let mut inf = good;
    inf[9] = f64::INFINITY;
    assert!(matches!(
        plant.step(&inf, 0.01),
        Err(PlantError::NonFiniteCommand { cable: 10, .. })
    ));
    let mut far = good;
    far[0] = hi[0] + 1.0;
    match plant.step(&far, 0.01) {
        Err(PlantError::CommandOutOfRange {
            cable: 1,
            value_mm,
            max_mm,
            ..
        }) => {
            assert_eq!(value_mm, far[0]);
            assert_eq!(max_mm, hi[0]);
        }
        other => panic!("expected out of range, got {other:?}"),
    }
    let mut low = good;
    low[6] = lo[6] - 0.01;
    assert!(matches!(
        plant.step(&low, 0.01),
        Err(PlantError::CommandOutOfRange { cable: 7, .. })
    ));
    for dt in [0.0, -0.01, f64::NAN, f64::INFINITY, 1e6] {
        assert!(
            matches!(plant.step(&good, dt), Err(PlantError::InvalidDt { .. })),
            "dt {dt}"
        );
        assert!(
            matches!(plant.settle(&good, 0.5, dt), Err(PlantError::InvalidDt { .. })),
            "dt {dt}"
        );
    }
    for d in [-1.0, f64::NAN] {
        assert!(matches!(
            plant.settle(&good, d, 0.01),
            Err(PlantError::InvalidDuration { .. })
        ));
    }
    assert!(matches!(
        plant.settle(&nan, 0.5, 0.01),
        Err(PlantError::NonFiniteCommand { .. })
    ));
    assert!(matches!(
        plant.step_joints(&[f64::NAN, 0.0, 0.0, 0.0, 0.0], 0.01),
        Err(PlantError::NonFiniteCommand { .. })
    ));
    assert_eq!(
        state_bytes(&plant),
        before,
        "a rejected input must not change the state"
    );

    // The messages say what and where.
    let msg = plant.step(&far, 0.01).unwrap_err().to_string();
    assert!(msg.contains("w1") && msg.contains("outside"), "{msg}");
    let msg = plant.step(&good, -1.0).unwrap_err().to_string();
    assert!(msg.contains("dt = -1"), "{msg}");

    // And the plant goes on normally afterwards.
    plant.step(&good, 0.01).unwrap();
    assert_ne!(state_bytes(&plant), before);
}

#[test]
fn commands_at_the_joint_limits_are_accepted() {
    let robot = Robot::paper_default();
    for config in every_family() {
        let mut plant = Plant::new(&robot, &config, 3);
        let lim = robot.config.limits.clone();
        for q in [lim.q_min_deg, lim.q_max_deg, [60.0, -60.0, 44.0, -50.0, 50.0]] {
            let q = robot.clamp_to_limits(&q);
            plant.step_joints(&q, 0.01).unwrap();
        }
    }
}

fn parse(text: &str) -> Result<PlantConfig, ConfigError> {
    PlantConfig::parse(text, std::path::Path::new("test/plant.toml"))
}

fn shipped() -> String {
    std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/../../configs/plant.toml")).unwrap()
}

#[test]
fn config_errors_name_the_file_and_field() {
    assert_eq!(parse(&shipped()).unwrap(), PlantConfig::paper_default());
    let cases = [
        (
            "friction_coefficient = 0.12",
            "friction_coefficient = -0.12",
            "sheath.friction_coefficient",
        ),
        ("length_mm = 2500.0", "length_mm = 0.0", "sheath.length_mm"),
        (
            "time_constant_s = 0.08",
            "time_constant_s = 0.0",
            "dynamics.time_constant_s",
        ),
        ("plays = 6", "plays = 0", "hysteresis.plays"),
        ("plays = 6", "plays = 17", "hysteresis.plays"),
        (
            "threshold_spread = 0.8",
            "threshold_spread = 1.0",
            "hysteresis.threshold_spread",
        ),
        ("relative_sd = 0.05", "relative_sd = 0.5", "variation.relative_sd"),
        ("margin_mm = 0.5", "margin_mm = -1.0", "command.margin_mm"),
        (
            "gain = [1.0, 1.0, 1.0, 1.0, 1.0]",
            "gain = [1.0, 1.0, 0.0, 1.0, 1.0]",
            "joints.gain[2]",
        ),
        (
            "[0.0,  0.05, 0.0,  0.0, 0.0]",
            "[0.5,  0.05, 0.0,  0.0, 0.0]",
            "joints.coupling[0][0]",
        ),
        ("max_mm = 1.0", "max_mm = nan", "drift.max_mm"),
    ];
    for (from, to, field) in cases {
        let text = shipped();
        assert!(text.contains(from), "fixture: {from}");
        let err = parse(&text.replacen(from, to, 1)).unwrap_err();
        let msg = err.to_string();
        assert!(msg.contains("test/plant.toml") && msg.contains(field), "{to}: {msg}");
        assert!(matches!(err, ConfigError::Invalid { .. }));
    }
    let wrap = shipped().replacen("wrap_deg = [240.0, 240.0", "wrap_deg = [240.0, -1.0", 1);
    assert!(parse(&wrap).unwrap_err().to_string().contains("sheath.wrap_deg[1]"));
    let t0 = shipped().replacen("pretension_n = [9.8", "pretension_n = [inf", 1);
    assert!(parse(&t0).unwrap_err().to_string().contains("cables.pretension_n[0]"));

    // Unknown fields, wrong lengths and malformed TOML are parse errors naming the file.
    let unknown = shipped().replacen("[body]\n", "[body]\nfriction = 1.0\n", 1);
    let e = parse(&unknown).unwrap_err();
    assert!(
        matches!(e, ConfigError::Parse { .. }) && e.to_string().contains("friction"),
        "{e}"
    );
    let short = shipped().replacen("gain = [1.0, 1.0, 1.0, 1.0, 1.0]", "gain = [1.0, 1.0]", 1);
    assert!(matches!(parse(&short), Err(ConfigError::Parse { .. })));
    assert!(matches!(parse("name = "), Err(ConfigError::Parse { .. })));
    let missing = PlantConfig::load("/nonexistent/plant.toml").unwrap_err();
    assert!(matches!(missing, ConfigError::Io { .. }) && missing.to_string().contains("/nonexistent/plant.toml"));
}
