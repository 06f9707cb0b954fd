//! `bowden collect` under the compensator (`--controller-config`) and added to an earlier
//! dataset (`--extend`): the second collection round of the transfer recipe (issue #12).

use crate::cli_support;
use bowden_learning::dataset::Dataset;
use cli_support::{bowden, fails_with, ok, repo, shm_files, shm_leaked_since};

fn row_count(dir: &std::path::Path) -> usize {
    Dataset::read_dir(dir).unwrap().0.len()
}

#[test]
fn a_closed_loop_round_records_the_compensators_commands_before_the_earlier_rows() {
    let shm_before = shm_files(&["bcol"]);
    let tmp = tempfile::tempdir().unwrap();
    let s = |p: &std::path::Path| p.display().to_string();
    let (first, second, plain) = (tmp.path().join("d1"), tmp.path().join("d2"), tmp.path().join("d3"));
    ok(&bowden(&[
        "collect",
        "--samples",
        "4",
        "--seed",
        "5",
        "--out",
        &s(&first),
    ]));
    // The same targets (configurations of seed 6) once under the shipped controller, added to
    // the first dataset, and once uncalibrated.
    let controller = repo().join("configs/controller.toml");
    let args = |out: &std::path::Path| {
        vec![
            "collect".to_string(),
            "--samples".into(),
            "4".into(),
            "--seed".into(),
            "6".into(),
            "--excitation".into(),
            "paper".into(),
            "--out".into(),
            s(out),
        ]
    };
    let mut closed = args(&second);
    closed.extend([
        "--controller-config".into(),
        s(&controller),
        "--extend".into(),
        s(&first),
    ]);
    let closed: Vec<&str> = closed.iter().map(String::as_str).collect();
    ok(&bowden(&closed));
    let uncal = args(&plain);
    ok(&bowden(&uncal.iter().map(String::as_str).collect::<Vec<_>>()));

    let (d1, _) = Dataset::read_dir(&first).unwrap();
    let (d2, m2) = Dataset::read_dir(&second).unwrap();
    let (d3, _) = Dataset::read_dir(&plain).unwrap();
    let new = d3.len();
    assert_eq!(d2.len(), new + d1.len(), "the new rows, then the earlier ones");
    let j = d1.joints;
    // The earlier dataset's rows come last, unchanged: its validation stretch stays its own.
    assert_eq!(d2.q_cmd_deg[new * j..], d1.q_cmd_deg[..]);
    assert_eq!(d2.valid[new..], d1.valid[..]);
    let phy_eq = d2.q_phy_deg[new * j..]
        .iter()
        .zip(&d1.q_phy_deg)
        .all(|(a, b)| a == b || (a.is_nan() && b.is_nan()));
    assert!(phy_eq, "the earlier measurements are kept bit for bit");
    assert!(d2.t_ns.windows(2).all(|w| w[0] < w[1]), "time runs on across the seam");
    // q_cmd is what the compensator sent for each target, not the target: the uncalibrated
    // run of the same targets commanded the targets themselves.
    let moved = (0..new * j)
        .filter(|&k| (d2.q_cmd_deg[k] - d3.q_cmd_deg[k]).abs() > 0.5)
        .count();
    assert!(
        moved > new * j / 2,
        "{moved} of {} commands differ from the targets",
        new * j
    );
    let p = &m2.provenance;
    assert_eq!(p["compensator_mode"], "newton", "{p}");
    assert_eq!(p["extends"]["first_row"].as_u64(), Some(new as u64), "{p}");
    assert_eq!(p["extends"]["rows"].as_u64(), Some(d1.len() as u64), "{p}");
    assert!(
        p["controller_config"].as_str().unwrap().ends_with("controller.toml"),
        "{p}"
    );

    // Mistakes name the flag.
    let mut same = args(&first);
    same.extend(["--extend".into(), s(&first), "--force".into()]);
    fails_with(
        &bowden(&same.iter().map(String::as_str).collect::<Vec<_>>()),
        &["--extend", "must differ from --out"],
    );
    let mut missing = args(&tmp.path().join("d4"));
    missing.extend(["--extend".into(), s(&tmp.path().join("nowhere"))]);
    fails_with(
        &bowden(&missing.iter().map(String::as_str).collect::<Vec<_>>()),
        &["--extend", "nowhere"],
    );
    let bad = tmp.path().join("bad.toml");
    std::fs::write(&bad, "mode = \"sideways\"\n").unwrap();
    let mut bad_args = args(&tmp.path().join("d5"));
    bad_args.extend(["--controller-config".into(), s(&bad)]);
    fails_with(
        &bowden(&bad_args.iter().map(String::as_str).collect::<Vec<_>>()),
        &["--controller-config", "bad.toml"],
    );
    assert_eq!(
        row_count(&first),
        d1.len(),
        "a refused run leaves the earlier data as it was"
    );
    assert!(shm_leaked_since(&shm_before, &["bcol"]).is_empty());
}
