//! transfer.svg.

use super::*;

/// Best mode's position reduction per family, one point per (unit, trajectory): truth filled,
/// vision hollow; the legend sits beside the chart, off the data.
// Long: one SVG figure: axes, series per family and legend drawn in order.
pub(super) fn plot(path: &Path, rep: &Report, units: &[&UnitOutcome], which: &str) -> Result<()> {
    use plotters::prelude::*;
    use plotters::style::text_anchor::{HPos, Pos, VPos};
    let e = |x: String| anyhow!("{}: {x}", path.display());
    let mode = rep.best_mode.clone().unwrap_or_else(|| "no results".into());
    // Two series per family: the best mode by truth and by vision; or, when the best mode uses
    // vision feedback (whose loop drives the vision-measured error), the best feed-forward mode
    // and the best mode, both by truth.
    let series: [(String, bool, &str); 2] = match &rep.best_feed_forward {
        Some(ff) if *ff != mode => [
            (ff.clone(), true, "feed-forward"),
            (mode.clone(), true, "with vision feedback"),
        ],
        _ => [(mode.clone(), true, "by truth"), (mode.clone(), false, "by vision")],
    };
    let fams: Vec<&Family> = rep
        .families
        .iter()
        .filter(|f| units.iter().any(|u| u.family == f.name && !u.rows.is_empty()))
        .collect();
    // (family, k, value, series 0 or 1)
    let mut pts: Vec<(usize, usize, f64, bool)> = Vec::new();
    for (fi, f) in fams.iter().enumerate() {
        for (si, (c, truth, _)) in series.iter().enumerate() {
            let mut k = 0;
            for u in units.iter().filter(|u| u.family == f.name) {
                for row in u.rows.iter().filter(|r| r.controller == *c) {
                    let v = if *truth {
                        row.reduction_pct.position_truth
                    } else {
                        row.reduction_pct.position_vision
                    };
                    if let Some(v) = v {
                        pts.push((fi, k, v, si == 0));
                    }
                    k += 1;
                }
            }
        }
    }
    let title = if series[0].0 == series[1].0 {
        mode.clone()
    } else {
        format!("{} and {}", series[0].0, series[1].0)
    };
    let per_family = |fi: usize| pts.iter().filter(|p| p.0 == fi && p.3).count().max(1);
    let lo = pts.iter().map(|p| p.2).fold(0.0f64, f64::min);
    let hi = pts.iter().map(|p| p.2).fold(100.0f64, f64::max);
    let pad = 0.05 * (hi - lo).max(1.0);
    let n = fams.len().max(1);
    let width = (260 + 150 * n as u32).max(640);
    let root = SVGBackend::new(path, (width, 460)).into_drawing_area();
    root.fill(&WHITE).map_err(|x| e(x.to_string()))?;
    let (left, right) = root.split_horizontally(width - 200);
    let names: Vec<String> = fams
        .iter()
        .map(|f| {
            let k = units
                .iter()
                .filter(|u| u.family == f.name && !u.rows.is_empty())
                .count();
            format!("{} ({k} unit{})", f.name, if k == 1 { "" } else { "s" })
        })
        .collect();
    let mut chart = ChartBuilder::on(&left)
        .caption(
            format!("{title}: tip position error reduction vs uncalibrated, {which} units"),
            ("sans-serif", 15),
        )
        .margin(12)
        .x_label_area_size(36)
        .y_label_area_size(56)
        .build_cartesian_2d(-0.5f64..n as f64 - 0.5, (lo - pad)..(hi + pad))
        .map_err(|x| e(x.to_string()))?;
    chart
        .configure_mesh()
        .disable_x_mesh()
        .x_labels(0)
        .y_desc("reduction, % (+ = better)")
        .draw()
        .map_err(|x| e(x.to_string()))?;
    // Family names under their columns (the axis is categorical).
    let label_style = TextStyle::from(("sans-serif", 13).into_font()).pos(Pos::new(HPos::Center, VPos::Top));
    for (fi, name) in names.iter().enumerate() {
        let (px, py) = chart.backend_coord(&(fi as f64, lo - pad));
        left.draw(&Text::new(name.clone(), (px, py + 8), label_style.clone()))
            .map_err(|x| e(x.to_string()))?;
    }
    chart
        .draw_series(LineSeries::new(
            vec![(-0.5, 0.0), (n as f64 - 0.5, 0.0)],
            BLACK.mix(0.6).stroke_width(1),
        ))
        .map_err(|x| e(x.to_string()))?;
    let spread = |fi: usize, k: usize| {
        let m = per_family(fi);
        if m == 1 {
            0.0
        } else {
            0.18 * (k as f64 / (m - 1) as f64 - 0.5)
        }
    };
    let truth_c = RGBColor(31, 119, 180);
    let vision_c = RGBColor(214, 39, 40);
    chart
        .draw_series(
            pts.iter()
                .filter(|p| p.3)
                .map(|p| Circle::new((p.0 as f64 - 0.13 + spread(p.0, p.1), p.2), 4, truth_c.filled())),
        )
        .map_err(|x| e(x.to_string()))?;
    chart
        .draw_series(
            pts.iter()
                .filter(|p| !p.3)
                .map(|p| Circle::new((p.0 as f64 + 0.13 + spread(p.0, p.1), p.2), 4, vision_c.stroke_width(1))),
        )
        .map_err(|x| e(x.to_string()))?;
    for fi in 0..fams.len() {
        for (truth, c, dx) in [(true, truth_c, -0.13), (false, vision_c, 0.13)] {
            let v: Vec<f64> = pts.iter().filter(|p| p.0 == fi && p.3 == truth).map(|p| p.2).collect();
            if let Some(s) = stat(v) {
                let x = fi as f64 + dx;
                chart
                    .draw_series(LineSeries::new(
                        vec![(x - 0.13, s.median), (x + 0.13, s.median)],
                        c.stroke_width(2),
                    ))
                    .map_err(|x| e(x.to_string()))?;
            }
        }
    }
    // Legend panel.
    let text = ("sans-serif", 13).into_font();
    let items: [(String, u8); 4] = [
        (
            if series[0].0 == series[1].0 {
                "by truth (unit × trajectory)".to_string()
            } else {
                format!("{} ({}, truth)", series[0].0, series[0].2)
            },
            0,
        ),
        (
            if series[0].0 == series[1].0 {
                "by vision".to_string()
            } else {
                format!("{} (truth)", series[1].0)
            },
            1,
        ),
        ("median".into(), 2),
        ("0 = uncalibrated".into(), 3),
    ];
    for (i, (label, kind)) in items.iter().enumerate() {
        let y = 60 + 24 * i as i32;
        match kind {
            0 => right.draw(&Circle::new((16, y), 4, truth_c.filled())),
            1 => right.draw(&Circle::new((16, y), 4, vision_c.stroke_width(1))),
            2 => right.draw(&PathElement::new(vec![(6, y), (26, y)], truth_c.stroke_width(2))),
            _ => right.draw(&PathElement::new(vec![(6, y), (26, y)], BLACK.mix(0.6).stroke_width(1))),
        }
        .map_err(|x| e(x.to_string()))?;
        right
            .draw(&Text::new(label.to_string(), (34, y - 7), text.clone()))
            .map_err(|x| e(x.to_string()))?;
    }
    root.present().map_err(|x| e(x.to_string()))?;
    Ok(())
}
