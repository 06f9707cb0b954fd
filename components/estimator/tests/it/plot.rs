//! `bowden estimator eval`'s SVG names every per-marker bar by its marker (r0 … g0), not by an
//! index.

use crate::common;

use bowden_estimator::eval::{run_eval, EvalOptions};
use bowden_interfaces::marker;

#[test]
fn per_marker_bars_are_named_by_their_markers() {
    let mut est = common::estimator();
    let mut src = common::camera(7);
    let opts = EvalOptions {
        frames: 4,
        seed: 7,
        hint_offset_deg: Some(15.0),
    };
    let rep = run_eval(&mut est, &mut src, &opts, |_| {}).expect("evaluation runs");
    let path = std::env::temp_dir().join(format!("bowden-estimator-plot-{}.svg", std::process::id()));
    rep.write_svg(&path).unwrap();
    let svg = std::fs::read_to_string(&path).unwrap();
    let _ = std::fs::remove_file(&path);
    assert!(svg.trim_start().starts_with("<svg") && svg.trim_end().ends_with("</svg>"));
    assert_eq!(svg.matches("<text").count(), svg.matches("</text>").count());
    // Each name is its own label (one text element), under its bar.
    for name in marker::NAMES {
        let n = svg.matches(&format!(">{name}<")).count() + svg.matches(&format!(">\n{name}\n<")).count();
        assert_eq!(n, 1, "marker {name}: {n} labels");
    }
    assert!(svg.contains("sphere-centre RMS error per marker"));
}
