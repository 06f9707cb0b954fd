//! The paper's figures written by `write_report` (Fig. 12: three views, vision and truth, the
//! orientation error; Fig. 13: q4 and q5) and the "bowden vs the paper" section of report.md,
//! on synthetic runs (no pipeline).

use bowden_evaluation::report::{markdown, summarise, write_report};
use bowden_evaluation::{PointRecord, RunRecord};
use bowden_kinematics::{JointsDeg, Robot};
use std::path::PathBuf;

const CONTROLLERS: [&str; 3] = ["uncalibrated", "paper", "newton"];

/// A run whose reached joints miss the desired ones by `miss` degrees (vision a little more),
/// the vision estimate missing at every 7th point.
fn run(robot: &Robot, trajectory: &str, controller: &str, miss: f64) -> RunRecord {
    let points = (0..24)
        .map(|k| {
            let s = k as f64 / 23.0 * std::f64::consts::TAU;
            let desired: JointsDeg = [
                10.0 * s.sin(),
                8.0 * s.cos(),
                5.0 * (2.0 * s).sin(),
                -12.0 + 6.0 * s.sin(),
                12.0 + 6.0 * s.sin(),
            ];
            let truth: JointsDeg = core::array::from_fn(|j| desired[j] + miss * (1.0 + 0.1 * j as f64));
            let est: JointsDeg = core::array::from_fn(|j| truth[j] + 0.05);
            let ee = robot.fk(&est).ee;
            let q = ee.rotation.quaternion();
            let valid = k % 7 != 3;
            PointRecord {
                q_desired_deg: desired,
                q_cmd_deg: desired,
                q_true_deg: truth,
                q_est_deg: valid.then_some(est),
                ee_est: valid.then_some((ee.translation.vector.into(), [q.w, q.i, q.j, q.k])),
                q_predicted_deg: None,
                refine_iterations: 0,
                t_sim_ns: 0,
            }
        })
        .collect::<Vec<_>>();
    RunRecord {
        trajectory: trajectory.into(),
        controller: controller.into(),
        repeat: 0,
        seed: 1,
        invalid_estimates: points.iter().filter(|p| p.q_est_deg.is_none()).count(),
        points,
        ticks: 0,
    }
}

fn scratch(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("bowden-figures-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    dir
}

/// Well-formed enough for a viewer: one root element, every text element closed, no NaN.
fn assert_svg(path: &std::path::Path) -> String {
    let text = std::fs::read_to_string(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    assert!(
        text.trim_start().starts_with("<svg"),
        "{}: no <svg> root",
        path.display()
    );
    assert!(text.trim_end().ends_with("</svg>"), "{}: not closed", path.display());
    assert_eq!(text.matches("<svg").count(), 1, "{}", path.display());
    assert_eq!(
        text.matches("<text").count(),
        text.matches("</text>").count(),
        "{}",
        path.display()
    );
    assert!(!text.contains("NaN") && !text.contains("inf"), "{}", path.display());
    text
}

#[test]
fn fig12_fig13_and_the_paper_side_by_side_are_written() {
    let robot = Robot::paper_default();
    let mut runs = Vec::new();
    for t in ["random", "zigzag"] {
        for (c, miss) in CONTROLLERS.iter().zip([6.0, 0.8, 0.7]) {
            runs.push(run(&robot, t, c, miss));
        }
    }
    let summary = summarise(&robot, &runs);
    let dir = scratch("report");
    let header = "synthetic runs";
    let files = write_report(&robot, &runs, &summary, header, &dir).unwrap();
    for t in ["random", "zigzag"] {
        for f in [format!("fig12_{t}.svg"), format!("fig13_{t}.svg")] {
            assert!(files.contains(&dir.join(&f)), "{f} not listed: {files:?}");
        }
    }

    // Fig. 12: three views per controller, vision and truth, position and orientation errors.
    let fig12 = assert_svg(&dir.join("fig12_zigzag.svg"));
    for label in [
        "x–y view",
        "x–z view",
        "y–z view",
        "reached by vision",
        "reached by truth",
        "tip position error along the path",
        "orientation error along the path",
        "desired",
        "Fig. 12",
    ] {
        assert!(fig12.contains(label), "fig12 lacks {label:?}");
    }
    for c in CONTROLLERS {
        assert!(fig12.contains(&format!("{c}: y–z view")), "fig12 lacks the {c} row");
    }
    // Vision is drawn per point (hollow circles): at least one per valid estimate.
    assert!(
        fig12.matches("<circle").count() >= 3 * 3 * 20,
        "fig12: vision points missing"
    );

    // Fig. 13: q4 and q5, desired vs reached, per controller, and the errors.
    let fig13 = assert_svg(&dir.join("fig13_zigzag.svg"));
    for label in ["q4", "q5", "vision", "truth", "Fig. 13", "q4 error", "q5 error"] {
        assert!(fig13.contains(label), "fig13 lacks {label:?}");
    }
    for c in CONTROLLERS {
        for q in ["q4", "q5"] {
            assert!(fig13.contains(&format!("{c}: {q}")), "fig13 lacks {c}: {q}");
        }
    }

    // report.md: the existing report unchanged, then the side-by-side with the paper's Table V.
    let md = std::fs::read_to_string(dir.join("report.md")).unwrap();
    let before = markdown(&summary, header);
    assert!(md.starts_with(&before), "report.md no longer starts with the report");
    let added = &md[before.len()..];
    assert!(added.starts_with("\n## bowden vs the paper (Table V)\n"), "{added}");
    for paper in [
        "13.70 mm / 31.17°",
        "5.29 mm / 11.21°",
        "11.86 mm / 24.74°",
        "5.47 mm / 10.41°",
        "16.16 mm / 34.89°",
        "5.64 mm / 12.58°",
        "+61.4 % / +64.0 %",
        "Why the absolute figures differ",
        "configs/trajectories/large",
    ] {
        assert!(added.contains(paper), "side-by-side lacks {paper:?}:\n{added}");
    }
    // No circle path in this run: its column is absent, the paper's circle values with it.
    assert!(!added.contains("13.46 mm / 33.88°"), "{added}");
    for c in CONTROLLERS {
        assert!(added.contains(&format!("| bowden: {c} (vision) |")), "{added}");
        assert!(added.contains(&format!("| bowden: {c} (truth) |")), "{added}");
    }
    // bowden's figures are this report's own: the average uncalibrated cell, by vision.
    let u = summary.cell("average", "uncalibrated").unwrap().task_vision;
    assert!(
        added.contains(&format!("{:.2} mm / {:.2}°", u.pos_mean_mm, u.rot_mean_deg)),
        "{added}"
    );
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn figures_skip_trajectories_without_a_repeat_0() {
    let robot = Robot::paper_default();
    let mut r = run(&robot, "circle", "uncalibrated", 5.0);
    r.repeat = 1;
    let dir = scratch("skip");
    std::fs::create_dir_all(&dir).unwrap();
    let runs = [r];
    assert!(bowden_evaluation::figures::fig12(&robot, &runs, "circle", &dir)
        .unwrap()
        .is_none());
    assert!(bowden_evaluation::figures::fig13(&runs, "circle", &dir)
        .unwrap()
        .is_none());
    let _ = std::fs::remove_dir_all(&dir);
}
