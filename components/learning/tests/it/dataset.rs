//! The dataset format and the import of external logs: round trips, and clear errors for
//! bad columns, bad shapes, corrupt files.

use bowden_learning::dataset::{import_csv, import_npy, AngleUnit, Dataset, DatasetError, ImportOptions};
use bowden_learning::npy::{write_npy_f32, write_npy_f64};
use bowden_learning::synthetic::hysteretic_dataset;

#[test]
fn csv_and_manifest_round_trip_bit_for_bit() {
    let dir = tempfile::tempdir().unwrap();
    let mut ds = hysteretic_dataset(300, 5, 1);
    ds.valid[17] = false;
    ds.q_phy_deg[17 * 5 + 2] = f64::NAN;
    let m = ds
        .write_dir(
            dir.path(),
            "synthetic",
            Some(1),
            Some("abc".into()),
            serde_json::json!({"note": "test"}),
        )
        .unwrap();
    assert_eq!((m.samples, m.valid_samples, m.joints, m.has_truth), (300, 299, 5, true));
    let csv = std::fs::read_to_string(dir.path().join("dataset.csv")).unwrap();
    let header = csv.lines().next().unwrap();
    assert!(header.starts_with("t_ns,q_cmd_1,q_cmd_2,q_cmd_3,q_cmd_4,q_cmd_5,q_phy_1,"));
    assert!(header.ends_with("q_true_5,valid"));
    let (back, m2) = Dataset::read_dir(dir.path()).unwrap();
    assert_eq!(m, m2);
    assert_eq!(back.q_cmd_deg, ds.q_cmd_deg);
    assert_eq!(back.q_true_deg, ds.q_true_deg);
    assert_eq!(back.valid, ds.valid);
    assert!(back.q_phy_deg[17 * 5 + 2].is_nan());
    // Same data, same bytes.
    let dir2 = tempfile::tempdir().unwrap();
    ds.write_dir(
        dir2.path(),
        "synthetic",
        Some(1),
        Some("abc".into()),
        serde_json::json!({"note": "test"}),
    )
    .unwrap();
    assert_eq!(csv, std::fs::read_to_string(dir2.path().join("dataset.csv")).unwrap());
}

#[test]
fn edited_csv_is_detected() {
    let dir = tempfile::tempdir().unwrap();
    hysteretic_dataset(50, 3, 2)
        .write_dir(dir.path(), "synthetic", None, None, serde_json::Value::Null)
        .unwrap();
    let p = dir.path().join("dataset.csv");
    let text = std::fs::read_to_string(&p).unwrap();
    std::fs::write(&p, &text[..text.len() - 40]).unwrap();
    let e = Dataset::read_dir(dir.path()).unwrap_err();
    assert!(matches!(e, DatasetError::HashMismatch { .. }), "{e}");
    assert!(e.to_string().contains("dataset.csv"), "{e}");
    std::fs::write(dir.path().join("manifest.json"), "{ not json").unwrap();
    let e = Dataset::read_dir(dir.path()).unwrap_err();
    assert!(
        matches!(e, DatasetError::Json { .. }) && e.to_string().contains("manifest.json"),
        "{e}"
    );
}

fn write(path: &std::path::Path, text: &str) {
    std::fs::write(path, text).unwrap();
}

#[test]
fn csv_import_with_named_columns_units_and_selection() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("log.csv");
    write(
        &p,
        "time,cmd_a,cmd_b,cmd_c,meas_a,meas_b,meas_c\n\
         0,0.1,0.2,0.3,0.11,0.19,0.31\n\
         10,0.2,0.3,0.4,0.21,,0.41\n\
         20,0.3,0.4,0.5,0.31,0.39,0.52\n",
    );
    let opts = ImportOptions {
        unit: AngleUnit::Rad,
        joints: Some(vec![3, 1]),
        cmd_columns: Some(vec!["cmd_a".into(), "cmd_b".into(), "cmd_c".into()]),
        phy_columns: Some(vec!["meas_a".into(), "meas_b".into(), "meas_c".into()]),
        time_column: Some("time".into()),
        ..Default::default()
    };
    let ds = import_csv(&p, &opts).unwrap();
    assert_eq!(ds.joints, 2);
    assert_eq!(ds.t_ns, vec![0, 10, 20]);
    assert!((ds.cmd(0)[0] - 0.3f64.to_degrees()).abs() < 1e-12); // joint 3 first
    assert!((ds.cmd(0)[1] - 0.1f64.to_degrees()).abs() < 1e-12);
    // The empty measurement of joint 2 is not selected: the sample stays valid.
    assert_eq!(ds.valid, vec![true, true, true]);
    let all = import_csv(
        &p,
        &ImportOptions {
            joints: None,
            ..opts.clone()
        },
    )
    .unwrap();
    assert_eq!(
        all.valid,
        vec![true, false, true],
        "a missing measurement flags its sample"
    );
}

#[test]
fn csv_import_bad_column_or_value_names_it() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("log.csv");
    write(&p, "t_ns,q_cmd_1,q_cmd_2,q_phy_1,q_phy_2\n0,1,2,1,2\n1,1,2,1,2\n");
    let opts = ImportOptions {
        cmd_columns: Some(vec!["q_cmd_1".into(), "q_cmd_3".into()]),
        ..Default::default()
    };
    let e = import_csv(&p, &opts).unwrap_err();
    assert!(
        matches!(&e, DatasetError::Table(bowden_tables::TableError::MissingColumn { column, .. }) if column == "q_cmd_3"),
        "{e}"
    );
    assert!(
        e.to_string().contains("log.csv") && e.to_string().contains("q_cmd_3"),
        "{e}"
    );

    write(&p, "t_ns,q_cmd_1,q_phy_1\n0,1.5,1\n1,abc,2\n");
    let e = import_csv(&p, &ImportOptions::default()).unwrap_err();
    assert!(e.to_string().contains(":3") && e.to_string().contains("\"abc\""), "{e}");

    write(&p, "t_ns,q_cmd_1,q_phy_1\n0,1.5,1\n1,2\n");
    let e = import_csv(&p, &ImportOptions::default()).unwrap_err();
    assert!(e.to_string().contains("2 fields"), "{e}");

    write(&p, "t_ns,q_cmd_1,q_phy_1\n0,nan,1\n");
    let e = import_csv(&p, &ImportOptions::default()).unwrap_err();
    assert!(matches!(e, DatasetError::NotFinite { .. }), "{e}");

    write(&p, "t_ns,q_cmd_1,q_cmd_2,q_phy_1\n0,1,2,1\n");
    let e = import_csv(&p, &ImportOptions::default()).unwrap_err();
    assert!(e.to_string().contains("2 command columns but 1 measured"), "{e}");

    write(&p, "t_ns,q_cmd_1,q_phy_1\n0,1,1\n");
    let e = import_csv(
        &p,
        &ImportOptions {
            joints: Some(vec![2]),
            ..Default::default()
        },
    )
    .unwrap_err();
    assert!(matches!(e, DatasetError::JointSelection { .. }), "{e}");
}

#[test]
fn npy_pair_import() {
    let dir = tempfile::tempdir().unwrap();
    let (c, p) = (dir.path().join("cmd.npy"), dir.path().join("phy.npy"));
    let cmd: Vec<f64> = (0..12).map(|i| i as f64 * 0.01).collect();
    let mut phy: Vec<f32> = cmd.iter().map(|v| (*v + 0.001) as f32).collect();
    phy[7] = f32::NAN;
    write_npy_f64(&c, 4, 3, &cmd).unwrap();
    write_npy_f32(&p, 4, 3, &phy).unwrap();
    let ds = import_npy(
        &c,
        &p,
        &ImportOptions {
            unit: AngleUnit::Rad,
            joints: Some(vec![1, 2]),
            ..Default::default()
        },
    )
    .unwrap();
    assert_eq!((ds.len(), ds.joints), (4, 2));
    assert!((ds.cmd(1)[1] - 0.04f64.to_degrees()).abs() < 1e-12);
    // Row 2, joint 2 (index 7) is NaN: that sample is invalid, the others are not.
    assert_eq!(ds.valid, vec![true, true, false, true]);
    let out = tempfile::tempdir().unwrap();
    ds.write_dir(out.path(), "import-npy", None, None, serde_json::Value::Null)
        .unwrap();
    assert_eq!(Dataset::read_dir(out.path()).unwrap().0.valid, ds.valid);
}

#[test]
fn npy_bad_shape_is_a_clear_error() {
    let dir = tempfile::tempdir().unwrap();
    let (c, p) = (dir.path().join("cmd.npy"), dir.path().join("phy.npy"));
    write_npy_f64(&c, 4, 3, &[0.0; 12]).unwrap();
    write_npy_f64(&p, 4, 2, &[0.0; 8]).unwrap();
    let e = import_npy(&c, &p, &ImportOptions::default()).unwrap_err();
    assert!(matches!(e, DatasetError::Shape { .. }), "{e}");
    let msg = e.to_string();
    assert!(
        msg.contains("phy.npy") && msg.contains("(4, 2)") && msg.contains("(4, 3)"),
        "{msg}"
    );

    std::fs::write(&p, b"not an npy file at all").unwrap();
    let e = import_npy(&c, &p, &ImportOptions::default()).unwrap_err();
    assert!(
        e.to_string().contains("phy.npy") && e.to_string().contains("magic"),
        "{e}"
    );

    write_npy_f64(&p, 4, 3, &[0.0; 12]).unwrap();
    let e = import_npy(
        &c,
        &p,
        &ImportOptions {
            joints: Some(vec![1, 4]),
            ..Default::default()
        },
    )
    .unwrap_err();
    assert!(e.to_string().contains("joint 4"), "{e}");
}

/// A log as spreadsheets and rig software write it: a byte-order mark, CRLF line ends, quoted
/// names, a quoted free-text column holding commas, blank lines. Read as the plain form is.
#[test]
fn csv_import_reads_quoted_commas_bom_and_crlf_like_the_plain_form() {
    let dir = tempfile::tempdir().unwrap();
    let plain = dir.path().join("plain.csv");
    write(&plain, "t_ns,q_cmd_1,q_phy_1,note\n0,1.5,1.25,a\n1000,2,1.75,b\n");
    let rig = dir.path().join("rig.csv");
    write(
        &rig,
        "\u{feff}\"t_ns\",\"q_cmd_1\",\"q_phy_1\",\"note\"\r\n0,1.5,1.25,\"start, slow\"\r\n\r\n1000,2,1.75,\"said \"\"go\"\", then ran\"\r\n",
    );
    let a = import_csv(&plain, &ImportOptions::default()).unwrap();
    let b = import_csv(&rig, &ImportOptions::default()).unwrap();
    assert_eq!(a, b);
    assert_eq!(b.q_cmd_deg, [1.5, 2.0]);
    assert_eq!(b.t_ns, [0, 1000]);
    // The same log with the note unquoted has a comma too many on that line: refused there.
    write(&rig, "t_ns,q_cmd_1,q_phy_1,note\r\n0,1.5,1.25,start, slow\r\n");
    let e = import_csv(&rig, &ImportOptions::default()).unwrap_err();
    assert!(e.to_string().contains("rig.csv:2: 5 fields, the header has 4"), "{e}");
}
