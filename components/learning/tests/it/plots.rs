//! The loss and sweep plots keep their legends off the data: one strip above the panels (no
//! legend box drawn inside a chart), the same entries once each.

use bowden_learning::report::plot_loss;
use bowden_learning::sweep::{plot_sweep, GroupStats, SweepConfig, SweepSummary};
use bowden_learning::windows::{PhySource, SplitConfig};
use bowden_learning::{Architecture, Direction, TcnBlock, TrainReport};

/// plotters draws an in-chart legend on a translucent white box.
const LEGEND_BOX: &str = r#"opacity="0.8""#;

fn read(path: &std::path::Path) -> String {
    let svg = std::fs::read_to_string(path).unwrap();
    assert!(svg.trim_start().starts_with("<svg") && svg.trim_end().ends_with("</svg>"));
    assert_eq!(svg.matches("<text").count(), svg.matches("</text>").count());
    svg
}

#[test]
fn loss_plot_legend_is_a_strip_above_the_panels() {
    let shipped = concat!(env!("CARGO_MANIFEST_DIR"), "/../../models/tcn_forward_L80.report.json");
    let report: TrainReport = serde_json::from_str(&std::fs::read_to_string(shipped).unwrap()).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("loss.svg");
    plot_loss(&path, &report).unwrap();
    let svg = read(&path);
    assert!(!svg.contains(LEGEND_BOX), "a legend box inside a chart");
    for label in [
        "train loss",
        "validation loss / RMSE",
        "identity (raw hysteresis)",
        "best epoch",
    ] {
        assert_eq!(
            svg.matches(&format!(">{label}<")).count() + svg.matches(&format!(">\n{label}\n<")).count(),
            1,
            "{label}"
        );
    }
}

#[test]
fn sweep_plot_legend_is_one_strip_with_one_colour_per_model() {
    let group = |model: &str, arch: Architecture, direction: Direction, seq_len: usize, rmse: f64| GroupStats {
        model: model.into(),
        arch,
        tcn_block: arch.has_tcn().then_some(TcnBlock::ReluLinear),
        direction,
        seq_len,
        params: 1000,
        n: 2,
        mean_rmse_deg: rmse,
        sd_rmse_deg: 0.3,
        runs_rmse_deg: vec![rmse - 0.3, rmse + 0.3],
        identity_rmse_deg: 12.0,
    };
    let mut groups = Vec::new();
    for d in [Direction::Forward, Direction::Inverse] {
        for (k, l) in [10usize, 50, 80].into_iter().enumerate() {
            groups.push(group("tcn", Architecture::Tcn, d, l, 4.0 - k as f64));
            groups.push(group("fnn", Architecture::Fnn, d, l, 6.0 + k as f64));
        }
    }
    // LSTM only in the inverse panel: still the same colour for the others.
    groups.push(group("lstm", Architecture::Lstm, Direction::Inverse, 80, 3.0));
    let summary = SweepSummary {
        format: "test".into(),
        config: SweepConfig {
            archs: vec![Architecture::Tcn, Architecture::Fnn, Architecture::Lstm],
            seq_lens: vec![10, 50, 80],
            seeds: 2,
            directions: vec![Direction::Forward, Direction::Inverse],
            tcn_blocks: vec![TcnBlock::ReluLinear],
            epochs: 1,
            early_stop: None,
            split: SplitConfig::default(),
            phy_source: PhySource::Vision,
            jobs: 1,
        },
        data: "synthetic".into(),
        runs: groups.len() * 2,
        reused: 0,
        groups,
        ranking: Default::default(),
        markdown: String::new(),
    };
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("sweep.svg");
    plot_sweep(&path, &summary).unwrap();
    let svg = read(&path);
    assert!(!svg.contains(LEGEND_BOX), "a legend box inside a chart");
    for label in ["tcn", "fnn", "lstm", "identity (raw hysteresis)"] {
        let n = svg.matches(&format!(">{label}<")).count() + svg.matches(&format!(">\n{label}\n<")).count();
        assert_eq!(n, 1, "{label}: once, in the strip");
    }
    assert!(svg.contains("forward model") && svg.contains("inverse model"));
}
