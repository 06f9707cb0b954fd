//! `bowden plant characterize` end to end: JSON on stdout, the loop plot on disk, one-line
//! errors naming the file and field.

use std::process::Command;

fn bowden() -> Command {
    Command::new(env!("CARGO_BIN_EXE_bowden"))
}

#[test]
fn characterize_prints_json_and_writes_the_plot() {
    let dir = tempfile::tempdir().unwrap();
    let svg = dir.path().join("loops.svg");
    let out = bowden()
        .args([
            "plant",
            "characterize",
            "--samples",
            "12",
            "--seed",
            "4",
            "--json",
            "--plot",
        ])
        .arg(&svg)
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let joints = v["joints"].as_array().unwrap();
    assert_eq!(joints.len(), 5);
    for j in joints {
        let mae = j["mae_deg"].as_f64().unwrap();
        assert!(mae > 0.0 && mae < 60.0, "{j}");
        assert!(j["sd_abs_deg"].as_f64().unwrap() > 0.0);
    }
    assert_eq!(v["options"]["n_configs"], 12);
    assert_eq!(v["options"]["plant_seed"], 4);
    assert!(std::fs::read_to_string(&svg).unwrap().starts_with("<svg"));

    // Same seed, same bytes.
    let again = bowden()
        .args([
            "plant",
            "characterize",
            "--samples",
            "12",
            "--seed",
            "4",
            "--json",
            "--force",
            "--plot",
        ])
        .arg(&svg)
        .output()
        .unwrap();
    assert_eq!(out.stdout, again.stdout);

    // The table names which SD it is.
    let table = bowden()
        .args(["plant", "characterize", "--samples", "5", "--force", "--plot"])
        .arg(&svg)
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&table.stdout);
    assert!(
        text.contains("standard deviation of |q_phy − q_cmd|") && text.contains("| q3 |"),
        "{text}"
    );
}

#[test]
fn bad_plant_file_is_a_one_line_error_naming_file_and_field() {
    let dir = tempfile::tempdir().unwrap();
    let cfg = dir.path().join("plant.toml");
    let shipped = std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/configs/plant.toml")).unwrap();
    std::fs::write(
        &cfg,
        shipped.replacen("time_constant_s = 0.08", "time_constant_s = -1.0", 1),
    )
    .unwrap();
    let out = bowden()
        .args(["plant", "characterize", "--samples", "5", "--config"])
        .arg(&cfg)
        .arg("--plot")
        .arg(dir.path().join("x.svg"))
        .output()
        .unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(err.trim_end().lines().count(), 1, "{err}");
    assert!(
        err.contains("plant.toml") && err.contains("dynamics.time_constant_s"),
        "{err}"
    );
}
