//! transfer.md.

use super::*;

/// `p` relative to the project directory when inside it (reports need not name the machine).
pub(super) fn shown(project: &Path, p: &Path) -> String {
    p.strip_prefix(project).unwrap_or(p).display().to_string()
}

pub(super) fn pct(v: Option<f64>) -> String {
    v.map_or_else(|| "—".into(), |v| format!("{v:+.1}"))
}

pub(super) fn secs(v: Option<StepTime>) -> String {
    v.map_or_else(|| "—".into(), |v| format!("{:.0} ({:.0})", v.seconds, v.cpu_seconds))
}

pub(super) fn units_list(families: &[Family], pick: fn(&Family) -> &Vec<u64>) -> String {
    let parts: Vec<String> = families
        .iter()
        .filter(|f| !pick(f).is_empty())
        .map(|f| {
            format!(
                "{} {}",
                f.name,
                pick(f).iter().map(|u| u.to_string()).collect::<Vec<_>>().join(", ")
            )
        })
        .collect();
    if parts.is_empty() {
        "none".into()
    } else {
        parts.join("; ")
    }
}

pub(super) fn reduction_table(out: &mut String, units: &[&UnitOutcome]) {
    let _ = write!(out, "| family | unit | trajectory | controller |");
    for (_, h) in METRICS {
        let _ = write!(out, " {h} |");
    }
    let _ = writeln!(out, "\n|---|---|---|---|---|---|---|---|---|---|");
    for u in units {
        if let Some(f) = &u.failure {
            let _ = writeln!(
                out,
                "| {} | {} | — | — | **failed** at step `{}` ({}) | | | | | |",
                u.family, u.unit, f.step, f.status
            );
            continue;
        }
        for row in &u.rows {
            let _ = write!(
                out,
                "| {} | {} | {} | {} |",
                u.family, u.unit, row.trajectory, row.controller
            );
            for i in 0..METRICS.len() {
                let _ = write!(out, " {} |", pct(row.reduction_pct.get(i)));
            }
            out.push('\n');
        }
    }
    out.push('\n');
}

pub(super) fn markdown(rep: &Report) -> String {
    let mut out = String::new();
    header(&mut out, rep);
    recipe(&mut out, rep);
    families(&mut out, rep);
    held_out(&mut out, rep);
    failures_timing_tuning(&mut out, rep);
    out
}

/// The title and what this run was.
fn header(out: &mut String, rep: &Report) {
    let r = &rep.recipe;
    let _ = writeln!(out, "# Transfer to unseen units\n");
    let _ = writeln!(
        out,
        "Every unit ran what a user runs with a new robot — `bowden collect` through the vision loop, \
         `bowden train`, {}, `bowden evaluate` — with the same recipe and no per-unit tuning.{}\n",
        if r.tune {
            "`bowden tune`"
        } else {
            "the base controller with the unit's first trained pair (`recipe.tune = false`, no `bowden tune`)"
        },
        if rep.quick {
            " **`--quick` recipe: a smoke test, the numbers say nothing about transfer.**"
        } else {
            ""
        }
    );
    let _ = writeln!(
        out,
        "- **Held-out units** (the results below): {}",
        units_list(&rep.families, |f| &f.heldout_units)
    );
    let _ = writeln!(
        out,
        "- **Tuning units** (looked at while choosing the recipe; never reported as results): {}",
        units_list(&rep.families, |f| &f.tuning_units)
    );
    let ran: Vec<String> = rep.units.iter().map(|u| format!("{}/{}", u.family, u.unit)).collect();
    let _ = writeln!(
        out,
        "- This run: `--units {}`, {} unit(s) ({}), {}; config `{}`, output `{}`.\n",
        match rep.units_selected {
            UnitSet::Tuning => "tuning",
            UnitSet::Heldout => "heldout",
            UnitSet::All => "all",
        },
        rep.units.len(),
        ran.join(", "),
        if rep.merged {
            "merged from the units' outcome files (run as shards, `--shard I/N`)".to_string()
        } else {
            format!("{} at once, train threads {}", rep.jobs, rep.train_threads)
        },
        shown(&rep.project_dir, &rep.config),
        shown(&rep.project_dir, &rep.out)
    );
}

/// The recipe, step by step, with the files each step reads.
fn recipe(out: &mut String, rep: &Report) {
    let r = &rep.recipe;
    let _ = writeln!(out, "## Recipe\n");
    let _ = writeln!(
        out,
        "1. plant: the family's plant file with `[variation] unit = N`\n\
         2. `bowden collect --samples {} --seed {} --excitation {}`\n\
         3. `bowden train --seq-len {} --epochs {}{}` for {} × forward, inverse{}{}\n\
         4. {}\n{}\
         5. `bowden evaluate --repeats {} --trajectories {} --controllers {}{}` on the unit's plant\n{}",
        r.samples,
        rep.seed,
        r.excitation,
        r.seq_len,
        r.epochs,
        r.early_stop.map(|e| format!(" --early-stop {e}")).unwrap_or_default()
            + &format!(" --decimation {}", r.decimation),
        r.archs.join(", "),
        r.per_arch
            .keys()
            .map(|a| {
                let (e, es) = r.training(a);
                let p = r.precision(a);
                format!(
                    "; {a}: `--epochs {e}{}{}`",
                    es.map(|x| format!(" --early-stop {x}")).unwrap_or_default(),
                    if p == Precision::F32 {
                        String::new()
                    } else {
                        format!(" --precision {p}")
                    }
                )
            })
            .collect::<String>(),
        if r.forward_archs.is_empty() {
            String::new()
        } else {
            format!("; further forward candidates: {}", r.forward_archs.join(", "))
        } + &if r.judge_archs.is_empty() {
            String::new()
        } else {
            let seeded: Vec<&str> = r
                .judge_archs
                .iter()
                .filter(|a| r.is_forward_candidate(a))
                .map(String::as_str)
                .collect();
            format!(
                "; judges (forward only, `tune --judge`): {}{}",
                r.judge_archs.join(", "),
                if seeded.is_empty() {
                    String::new()
                } else {
                    format!(
                        " ({} trained again with `--seed {}`, apart from the candidate)",
                        seeded.join(", "),
                        r.judge_seed
                    )
                }
            )
        } + &if r.inverse_archs.is_empty() {
            String::new()
        } else {
            format!("; further inverse candidates: {}", r.inverse_archs.join(", "))
        },
        if r.tune {
            format!(
                "`bowden tune --base {}` with every trained model",
                r.base_controller.display()
            )
        } else {
            format!(
                "controller: {} with the first forward/inverse pair (`recipe.tune = false`)",
                r.base_controller.display()
            )
        },
        r.closed_loop.as_ref().map_or_else(String::new, |cl| format!(
            "4b. a second round under that controller: `bowden collect --samples {} --seed {} --excitation {} \
             --controller-config <4.> --extend <2.>` (its configurations are targets; the commands the \
             compensator sent are recorded), then 3. and 4. again on the whole\n",
            cl.samples,
            rep.seed + 1,
            cl.excitation
        )),
        r.repeats,
        r.trajectories.join(","),
        r.controllers.join(","),
        r.max_points.map(|n| format!(" --max-points {n}")).unwrap_or_default(),
        r.feedback.as_ref().map_or_else(String::new, |f| format!(
            "6. the same with vision feedback (controllers `+fb`): the unit's controller plus the `[feedback]` \
             table of `{}`, `bowden evaluate --camera-fps {}` (frames during each held point)\n",
            shown(&rep.project_dir, &f.config),
            f.camera_fps
        )) + &r
            .trajectory_sets
            .iter()
            .map(|(name, d)| {
                format!(
                    "7. 5.{} again on the paths of `{}` (`--trajectories-dir`), reported as controllers `…@{name}`\n",
                    if r.feedback.is_some() { " and 6." } else { "" },
                    d.display()
                )
            })
            .collect::<String>(),
    );
}

/// The families: plant file, model, tuning and held-out units.
fn families(out: &mut String, rep: &Report) {
    let _ = writeln!(out, "## Families\n");
    let _ = writeln!(
        out,
        "| family | plant file | model | tuning units | held-out units |\n|---|---|---|---|---|"
    );
    for f in &rep.families {
        let l = |v: &Vec<u64>| {
            if v.is_empty() {
                "—".into()
            } else {
                v.iter().map(|u| u.to_string()).collect::<Vec<_>>().join(", ")
            }
        };
        let _ = writeln!(
            out,
            "| {} | {} | {} | {} | {} |",
            f.name,
            shown(&rep.project_dir, &f.plant),
            f.model,
            l(&f.tuning_units),
            l(&f.heldout_units)
        );
    }
    out.push('\n');
}

/// The held-out results: the reductions, per family, never-worse checks and goals.
fn held_out(out: &mut String, rep: &Report) {
    let held: Vec<&UnitOutcome> = rep.units.iter().filter(|u| u.role == Role::HeldOut).collect();
    let _ = writeln!(
        out,
        "## Held-out units: error reduction vs uncalibrated, % (+ = better)\n\n\
         Mean tip position and orientation error and joint MAE (mean over the joints) of each calibrated \
         controller against the uncalibrated robot on the same trajectory, measured by the vision estimate \
         and by the simulator's truth.\n"
    );
    if held.is_empty() {
        let _ = writeln!(out, "No held-out unit ran (`--units heldout` or `all` runs them).\n");
    } else {
        reduction_table(out, &held);
    }
    let _ = writeln!(
        out,
        "## Per family (held-out): median [min, max] of the reduction, % over units × trajectories\n"
    );
    if rep.summary.is_empty() {
        let _ = writeln!(out, "No results.\n");
    } else {
        let _ = write!(out, "| family | controller | units | pairs |");
        for (_, h) in METRICS {
            let _ = write!(out, " {h} |");
        }
        let _ = writeln!(out, "\n|---|---|---|---|---|---|---|---|---|---|");
        for s in &rep.summary {
            let n = s.reduction_pct.get("position_truth").map_or(0, |x| x.n);
            let _ = write!(out, "| {} | {} | {} | {} |", s.family, s.controller, s.units, n);
            for (key, _) in METRICS {
                let txt = s.reduction_pct.get(key).map_or_else(
                    || "—".into(),
                    |x| format!("{:+.1} [{:+.1}, {:+.1}]", x.median, x.min, x.max),
                );
                let _ = write!(out, " {txt} |");
            }
            out.push('\n');
        }
        out.push('\n');
    }
    let _ = writeln!(
        out,
        "## Never worse than uncalibrated (held-out)\n\nEvery (unit, trajectory, metric) of a calibrated \
         controller must have a reduction ≥ 0.\n"
    );
    let _ = writeln!(out, "| controller | checks | violations |\n|---|---|---|");
    for n in &rep.never_worse {
        let _ = writeln!(
            out,
            "| {} | {} | {} |",
            n.controller,
            n.checks,
            if n.violations.is_empty() {
                "none ✓".to_string()
            } else {
                format!("**{}**", n.violations.len())
            }
        );
    }
    out.push('\n');
    for n in &rep.never_worse {
        for v in &n.violations {
            let _ = writeln!(
                out,
                "- {}: {} unit {}, {}, {}: {:+.1} %",
                n.controller,
                v.family,
                v.unit,
                v.trajectory,
                METRICS
                    .iter()
                    .find(|m| m.0 == v.metric)
                    .map_or(v.metric.as_str(), |m| m.1),
                v.reduction_pct
            );
        }
    }
    if rep.never_worse.iter().any(|n| !n.violations.is_empty()) {
        out.push('\n');
    }
    if let Some(b) = &rep.best_mode {
        let _ = writeln!(
            out,
            "Best calibrated mode (median position reduction by truth over the held-out pairs): **{b}**{}; \
             `transfer.svg` plots its distribution per family.\n",
            match &rep.best_feed_forward {
                Some(f) if f != b => format!("; without vision feedback: **{f}**"),
                _ => String::new(),
            }
        );
    }
    if !rep.goals.is_empty() {
        let _ = writeln!(
            out,
            "## Goals (held-out)\n\nEvery reduction (position, orientation, joint MAE; vision and truth) ≥ \
             {GOAL_MIN_PCT:.0} % on every held-out unit and trajectory, and the median of each ≥ \
             {GOAL_MEDIAN_PCT:.0} %.\n\n\
             | controller | worst reduction | where | cells < {GOAL_MIN_PCT:.0} % | lowest median | of | met |\n\
             |---|---|---|---|---|---|---|"
        );
        for g in &rep.goals {
            let _ = writeln!(
                out,
                "| {} | {:+.1} % | {} | {} of {} | {:+.1} % | {} | {} |",
                g.controller,
                g.worst_pct,
                g.worst_at,
                g.below_60,
                g.checks,
                g.lowest_median_pct,
                g.lowest_median_metric,
                if g.met { "yes" } else { "**no**" }
            );
        }
        out.push('\n');
    }
}

/// Failed units, the time per step, and the tuning units' figures (not results).
fn failures_timing_tuning(out: &mut String, rep: &Report) {
    let tuning: Vec<&UnitOutcome> = rep.units.iter().filter(|u| u.role == Role::Tuning).collect();
    let failed: Vec<&UnitOutcome> = rep.units.iter().filter(|u| u.failure.is_some()).collect();
    if !failed.is_empty() {
        let _ = writeln!(out, "## Failures\n");
        for u in failed {
            let Some(f) = &u.failure else { continue };
            let _ = writeln!(
                out,
                "- {} unit {} ({}): step `{}` failed: {}{}{}",
                u.family,
                u.unit,
                u.role.label(),
                f.step,
                f.status,
                f.log
                    .as_ref()
                    .map(|l| format!("; log {}", l.display()))
                    .unwrap_or_default(),
                f.hint.as_ref().map(|h| format!("; {h}")).unwrap_or_default()
            );
            if !f.log_tail.is_empty() {
                let _ = writeln!(out, "\n  ```\n  {}\n  ```", f.log_tail.join("\n  "));
            }
        }
        out.push('\n');
    }
    let machine = if rep.merged {
        "on the machines that ran the shards".to_string()
    } else {
        format!(
            "on a machine with {} core(s), load average {} at the start",
            rep.cores,
            rep.load_average.map_or_else(|| "unknown".into(), |l| format!("{l:.2}"))
        )
    };
    let _ = writeln!(
        out,
        "## Timing per step\n\nWall seconds (CPU seconds of the subprocesses, user + system) {machine}. \
         `*`: steps skipped in this run (finished earlier: the times are the stamp's).\n"
    );
    let _ = writeln!(
        out,
        "| family | unit | collect | train | tune | evaluate | total |\n|---|---|---|---|---|---|---|"
    );
    for t in &rep.timing {
        let _ = writeln!(
            out,
            "| {} | {} | {} | {} | {} | {} | {}{} |",
            t.family,
            t.unit,
            secs(t.collect),
            secs(t.train),
            secs(t.tune),
            secs(t.evaluate),
            secs(Some(t.total)),
            if t.resumed > 0 {
                format!(" ({} step(s) *)", t.resumed)
            } else {
                String::new()
            }
        );
    }
    let mean = |f: fn(&TimingRow) -> Option<StepTime>| {
        let v: Vec<StepTime> = rep.timing.iter().filter_map(f).collect();
        let n = v.len() as f64;
        (!v.is_empty()).then(|| StepTime {
            seconds: v.iter().map(|t| t.seconds).sum::<f64>() / n,
            cpu_seconds: v.iter().map(|t| t.cpu_seconds).sum::<f64>() / n,
        })
    };
    if rep.timing.len() > 1 {
        let _ = writeln!(
            out,
            "| mean | | {} | {} | {} | {} | {} |",
            secs(mean(|t| t.collect)),
            secs(mean(|t| t.train)),
            secs(mean(|t| t.tune)),
            secs(mean(|t| t.evaluate)),
            secs(mean(|t| Some(t.total)))
        );
    }
    if rep.merged {
        let _ = writeln!(
            out,
            "\nWall time of the units (run as shards), summed: {:.0} s.\n",
            rep.wall_seconds
        );
    } else {
        let _ = writeln!(out, "\nWall time of this run: {:.0} s.\n", rep.wall_seconds);
    }
    if !tuning.is_empty() {
        let _ = writeln!(
            out,
            "## Tuning units (for choosing the recipe only; not results)\n\nReduction vs uncalibrated, %.\n"
        );
        reduction_table(out, &tuning);
    }
}
