//! Fig. 9a and Fig. 9b as `plant characterize` writes them: the loop plot (density panels, not a
//! blob of thousands of lines) and the command / physical time series beside it.

use bowden_kinematics::{JointsDeg, N_JOINTS};
use bowden_plant::characterize::{timeseries_path, FIG_9A_SAMPLES};
use bowden_plant::{Characterization, CharacterizeOptions};

/// Commands sweeping every joint, and a physical angle that lags them by a dead band.
fn samples(n: usize) -> (Vec<JointsDeg>, Vec<JointsDeg>) {
    let cmd: Vec<JointsDeg> = (0..n)
        .map(|k| core::array::from_fn(|j| 40.0 * ((k as f64) * 0.02 * (1.0 + j as f64 * 0.3)).sin()))
        .collect();
    let mut z: JointsDeg = [0.0; N_JOINTS];
    let phy = cmd
        .iter()
        .map(|c| {
            for j in 0..N_JOINTS {
                z[j] = z[j].clamp(c[j] - 8.0, c[j] + 8.0);
            }
            z
        })
        .collect();
    (cmd, phy)
}

fn svg(path: &std::path::Path) -> String {
    let text = std::fs::read_to_string(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    assert!(text.trim_start().starts_with("<svg") && text.trim_end().ends_with("</svg>"));
    assert_eq!(text.matches("<text").count(), text.matches("</text>").count());
    assert!(!text.contains("NaN"));
    text
}

#[test]
fn loop_plot_writes_fig9b_density_and_fig9a_beside_it() {
    let (cmd, phy) = samples(6000);
    let c = Characterization::from_samples("synthetic".into(), CharacterizeOptions::default(), cmd, phy);
    let dir = tempfile::tempdir().unwrap();
    let plot = dir.path().join("loops.svg");
    c.write_loop_plot(&plot).unwrap();
    let ts = timeseries_path(&plot);
    assert_eq!(ts, dir.path().join("loops_timeseries.svg"));

    let loops = svg(&plot);
    assert!(
        loops.contains("Fig. 9b") && loops.contains("density"),
        "no density panels"
    );
    // The whole run is binned, not drawn as 6000-point lines: the top panels hold rectangles,
    // and only the two 400-command panels (and axes) are polylines.
    assert!(loops.matches("<rect").count() > 100, "density bins missing");
    let longest = loops
        .split("<polyline")
        .skip(1)
        .map(|p| p.split("/>").next().unwrap_or("").matches(',').count())
        .max()
        .unwrap_or(0);
    assert!(
        longest <= 400,
        "a polyline of {longest} points: the whole run drawn as lines"
    );

    let fig9a = svg(&ts);
    for label in [
        "Fig. 9a", "q1 [deg]", "q2 [deg]", "q3 [deg]", "q4 [deg]", "q5 [deg]", "q_cmd", "q_phy",
    ] {
        assert!(fig9a.contains(label), "Fig. 9a lacks {label:?}");
    }
    assert!(fig9a.contains(&format!("first {FIG_9A_SAMPLES} of 6000 commands")));
}
