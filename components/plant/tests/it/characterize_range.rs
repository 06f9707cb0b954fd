//! The paper's magnitudes (Table IV) under the default config, on a smaller seeded dataset:
//! MAE 10–16° and SD 7–11° on every joint, with history-dependent loops.

use crate::common;
use bowden_plant::PlantConfig;

#[test]
fn default_plant_lands_in_the_papers_range() {
    let r = common::lands_in_the_papers_range(&PlantConfig::paper_default());
    assert!(r.n_commands > 1500, "{} commands", r.n_commands);
    // The report and plot render.
    let dir = tempfile::tempdir().unwrap();
    let svg = dir.path().join("loops.svg");
    r.write_loop_plot(&svg).unwrap();
    let text = std::fs::read_to_string(&svg).unwrap();
    assert!(text.starts_with("<svg") && text.contains("q1") && text.contains("q3"));
    let json = serde_json::to_value(&r).unwrap();
    assert_eq!(json["joints"].as_array().unwrap().len(), 5);
    assert!(r.markdown_table().contains("| q5 |"));
}
