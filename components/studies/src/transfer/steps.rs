//! A unit's steps as subprocesses of `bowden`, with their stamps (skip what is done, redo what changed).

use super::*;

/// `UNIT/<step>.done`.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub(super) struct Stamp {
    pub(super) step: String,
    pub(super) command: String,
    pub(super) inputs_hash: String,
    /// Wall time.
    pub(super) seconds: f64,
    /// CPU time (user + system) of the subprocess and the children it waited for.
    #[serde(default)]
    pub(super) cpu_seconds: f64,
    pub(super) finished_unix_ms: u128,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub(super) enum StepStatus {
    Ran,
    Skipped,
    Failed,
}

#[derive(Debug, Clone, Serialize, Deserialize)]
pub(super) struct StepRecord {
    pub(super) step: String,
    pub(super) status: StepStatus,
    /// Wall and CPU time of this run, or (skipped) of the run that made the stamp.
    pub(super) seconds: f64,
    pub(super) cpu_seconds: f64,
    pub(super) command: String,
    pub(super) log: Option<PathBuf>,
}

#[derive(Debug, Clone, Serialize, Deserialize)]
pub(super) struct Failure {
    pub(super) step: String,
    pub(super) status: String,
    pub(super) log: Option<PathBuf>,
    pub(super) log_tail: Vec<String>,
    pub(super) hint: Option<String>,
}

/// What runs the step: a `bowden` subcommand, or an edit done here.
pub(super) enum Action<'a> {
    Exe(Vec<String>),
    Local(String, Box<dyn FnOnce() -> Result<()> + 'a>),
}

pub(super) struct Ctx {
    pub(super) exe: PathBuf,
    pub(super) project: PathBuf,
    pub(super) recipe: Recipe,
    pub(super) seed: u64,
    pub(super) threads: usize,
    pub(super) base_controller: PathBuf,
    /// `recipe.feedback.config`, resolved and checked to hold a `[feedback]` table.
    pub(super) feedback_config: Option<PathBuf>,
    /// `recipe.trajectory_sets`, resolved: (name, directory).
    pub(super) trajectory_sets: Vec<(String, PathBuf)>,
    pub(super) config_file: PathBuf,
    pub(super) mp: MultiProgress,
}

pub(super) fn quote(s: &str) -> String {
    if !s.is_empty() && s.chars().all(|c| c.is_ascii_alphanumeric() || "-_./,=:+@".contains(c)) {
        s.to_string()
    } else {
        format!("'{}'", s.replace('\'', r"'\''"))
    }
}

pub(super) fn command_line(args: &[String]) -> String {
    std::iter::once("bowden".to_string())
        .chain(args.iter().map(|a| quote(a)))
        .collect::<Vec<_>>()
        .join(" ")
}

pub(super) fn now_ms() -> u128 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_millis())
}

/// Temp file + rename: a reader sees the old file or the new one, never half of one.
pub(super) fn write_atomic(path: &Path, text: &str) -> Result<()> {
    let mut tmp = path.as_os_str().to_owned();
    tmp.push(".tmp");
    let tmp = PathBuf::from(tmp);
    std::fs::write(&tmp, text).with_context(|| format!("writing {}", tmp.display()))?;
    std::fs::rename(&tmp, path).with_context(|| format!("renaming {} to {}", tmp.display(), path.display()))
}

pub(super) fn remove_any(p: &Path) -> std::io::Result<()> {
    let r = if p.is_dir() {
        std::fs::remove_dir_all(p)
    } else {
        std::fs::remove_file(p)
    };
    match r {
        Err(e) if e.kind() != std::io::ErrorKind::NotFound => Err(e),
        _ => Ok(()),
    }
}

pub(super) fn log_tail(log: &Path, n: usize) -> Vec<String> {
    let text = std::fs::read_to_string(log).unwrap_or_default();
    // Progress bars of a child redraw with carriage returns: keep the last state of a line.
    let lines: Vec<String> = text
        .lines()
        .map(|l| l.rsplit('\r').next().unwrap_or("").trim_end().to_string())
        .filter(|l| !l.is_empty())
        .collect();
    lines[lines.len().saturating_sub(n)..].to_vec()
}

/// Runs one unit's steps in order; stops at the first failure.
pub(super) struct UnitRunner<'a> {
    pub(super) ctx: &'a Ctx,
    pub(super) plan: &'a UnitPlan,
    pub(super) label: String,
    pub(super) bar: &'a ProgressBar,
    pub(super) records: Vec<StepRecord>,
    pub(super) stamps: std::collections::BTreeMap<String, Stamp>,
    pub(super) total_steps: usize,
}

impl UnitRunner<'_> {
    pub(super) fn stamp_path(&self, step: &str) -> PathBuf {
        self.plan.dir.join(format!("{step}.done"))
    }

    /// Runs `step` unless its stamp says it finished with the same inputs: the arguments (the
    /// unit's directory written `$UNIT`, `--threads` left out: results do not depend on it),
    /// `extra` (contents of input files) and the stamps of the `upstream` steps it reads, and
    /// its main product `outputs[0]` still exists. A (re)run first removes all `outputs`.
    // Long: one stamped step: inputs hashed, skipped when unchanged, run as a subprocess, measured, stamped; the parts share the stamp's fields.
    pub(super) fn step(
        &mut self,
        step: &str,
        action: Action<'_>,
        extra: &str,
        upstream: &[String],
        outputs: &[PathBuf],
    ) -> std::result::Result<(), Failure> {
        let dir = self.plan.dir.display().to_string();
        let (command, hashed) = match &action {
            Action::Exe(args) => {
                let mut view = Vec::new();
                let mut skip = false;
                for a in args {
                    if std::mem::take(&mut skip) {
                        continue;
                    }
                    if a == "--threads" {
                        skip = true;
                        continue;
                    }
                    view.push(a.replace(&dir, "$UNIT"));
                }
                (command_line(args), view.join("\u{1f}"))
            }
            Action::Local(desc, _) => (desc.clone(), desc.replace(&dir, "$UNIT")),
        };
        let mut h = format!("{step}\u{1e}{hashed}\u{1e}{extra}");
        for u in upstream {
            match self.stamps.get(u) {
                Some(s) => {
                    let _ = write!(h, "\u{1e}{u}={}@{}", s.inputs_hash, s.finished_unix_ms);
                }
                None => {
                    let _ = write!(h, "\u{1e}{u}=none");
                }
            }
        }
        let hash = fnv1a64_hex(h.as_bytes());
        let stamp_path = self.stamp_path(step);
        let k = self.records.len() + 1;
        self.bar.set_message(format!("{step} ({k}/{})", self.total_steps));
        if let Some(s) = std::fs::read_to_string(&stamp_path)
            .ok()
            .and_then(|t| serde_json::from_str::<Stamp>(&t).ok())
        {
            if s.inputs_hash == hash && outputs.first().is_none_or(|o| o.exists()) {
                self.records.push(StepRecord {
                    step: step.into(),
                    status: StepStatus::Skipped,
                    seconds: s.seconds,
                    cpu_seconds: s.cpu_seconds,
                    command: s.command.clone(),
                    log: None,
                });
                self.stamps.insert(step.into(), s);
                return Ok(());
            }
        }
        let fail = |status: String, log: Option<PathBuf>, hint: Option<String>| {
            let log_tail = log.as_deref().map(|l| log_tail(l, 15)).unwrap_or_default();
            Failure {
                step: step.into(),
                status,
                log,
                log_tail,
                hint,
            }
        };
        // Unfinished or stale: the stamp goes first, then whatever a partial run left.
        let _ = remove_any(&stamp_path);
        for o in outputs {
            remove_any(o).map_err(|e| fail(format!("removing {}: {e}", o.display()), None, None))?;
        }
        let logs = self.plan.dir.join("logs");
        std::fs::create_dir_all(&logs).map_err(|e| fail(format!("creating {}: {e}", logs.display()), None, None))?;
        let log = logs.join(format!("{step}.log"));
        let t0 = Instant::now();
        let mut cpu_seconds = 0.0;
        match action {
            Action::Exe(args) => {
                let run = || -> std::io::Result<(std::process::ExitStatus, f64)> {
                    use std::io::Write as _;
                    let mut f = std::fs::File::create(&log)?;
                    writeln!(
                        f,
                        "$ cd {} && {}",
                        quote(&self.ctx.project.display().to_string()),
                        command
                    )?;
                    let f2 = f.try_clone()?;
                    run_measured(
                        std::process::Command::new(&self.ctx.exe)
                            .args(&args)
                            .current_dir(&self.ctx.project)
                            .stdin(Stdio::null())
                            .stdout(f)
                            .stderr(f2),
                    )
                };
                let (status, cpu) = run().map_err(|e| fail(format!("could not run: {e}"), Some(log.clone()), None))?;
                if !status.success() {
                    let text = std::fs::read_to_string(&log).unwrap_or_default();
                    let hint = (text.contains("unrecognized subcommand")
                        && args.first().map(String::as_str) == Some("tune"))
                    .then(|| {
                        format!(
                            "this bowden has no `tune` subcommand: set `recipe.tune = false` in {}",
                            self.ctx.config_file.display()
                        )
                    });
                    return Err(fail(status.to_string(), Some(log), hint));
                }
                cpu_seconds = cpu;
            }
            Action::Local(desc, f) => {
                let r = f();
                let _ = std::fs::write(
                    &log,
                    format!(
                        "{desc}\n{}\n",
                        r.as_ref().map_or_else(|e| format!("error: {e:#}"), |_| "done".into())
                    ),
                );
                if let Err(e) = r {
                    return Err(fail(format!("error: {e:#}"), Some(log), None));
                }
            }
        }
        let seconds = t0.elapsed().as_secs_f64();
        let stamp = Stamp {
            step: step.into(),
            command: command.clone(),
            inputs_hash: hash,
            seconds,
            cpu_seconds,
            finished_unix_ms: now_ms(),
        };
        let text = serde_json::to_string_pretty(&stamp).unwrap_or_default();
        write_atomic(&stamp_path, &text).map_err(|e| fail(format!("{e:#}"), Some(log.clone()), None))?;
        self.ctx
            .mp
            .suspend(|| eprintln!("{}: {step} {seconds:.1} s (CPU {cpu_seconds:.1} s)", self.label));
        self.records.push(StepRecord {
            step: step.into(),
            status: StepStatus::Ran,
            seconds,
            cpu_seconds,
            command,
            log: Some(log),
        });
        self.stamps.insert(step.into(), stamp);
        Ok(())
    }
}

/// Steps 3 and 4 of the recipe on one dataset: every model trained (the pair of each
/// architecture, the judges, the further inverse candidates), then `tune` (or the base
/// controller). `round` suffixes the step names, the models' directory and the controller
/// ("" for the first dataset). Returns the controller and the name of the step that wrote it.
pub(super) fn train_and_tune(
    runner: &mut UnitRunner,
    data: &Path,
    collect_step: &str,
    round: &str,
) -> std::result::Result<(PathBuf, String), Failure> {
    let ctx = runner.ctx;
    let r = &ctx.recipe;
    let dir = runner.plan.dir.clone();
    let s = |p: &Path| p.display().to_string();
    // 3. Train every architecture in both directions, the judges' forward models and the
    //    further inverse candidates.
    let models = dir.join(format!("models{round}"));
    let _ = std::fs::create_dir_all(&models);
    let (mut fwd, mut inv, mut judges) = (Vec::new(), Vec::new(), Vec::new());
    let mut trained = Vec::new();
    for job in r.training_jobs() {
        let model = models.join(&job.file);
        let (json, svg) = bowden_learning::report::sidecar_paths(&model);
        let args = r.train_args(&job.arch, job.direction, job.seed, ctx.threads, data, &model);
        let name = format!("train-{}{round}", job.step);
        runner.step(
            &name,
            Action::Exe(args),
            "",
            &[collect_step.into()],
            &[model.clone(), json, svg],
        )?;
        trained.push(name);
        match job.role {
            ModelRole::Forward => fwd.push(model),
            ModelRole::Inverse => inv.push(model),
            ModelRole::Judge => judges.push(model),
        }
    }
    // 4. Choose the settings.
    let tune_step = format!("tune{round}");
    let controller = dir.join(format!("controller{round}.toml"));
    let base_text = read_text(&ctx.base_controller);
    let join = |v: &[PathBuf]| v.iter().map(|p| s(p)).collect::<Vec<_>>().join(",");
    let action = if r.tune {
        let mut args: Vec<String> = vec![
            "tune".into(),
            "--data".into(),
            s(data),
            "--forward".into(),
            join(&fwd),
            "--inverse".into(),
            join(&inv),
        ];
        // Judges are never candidates (a judge of a candidate's architecture is trained
        // again with another seed), so every candidate is rated by models it did not use.
        if !judges.is_empty() {
            args.extend(["--judge".into(), join(&judges)]);
        }
        args.extend(["--base".into(), s(&ctx.base_controller), "--out".into(), s(&controller)]);
        Action::Exe(args)
    } else {
        let (f, i, c, b) = (
            fwd[0].clone(),
            inv[0].clone(),
            controller.clone(),
            ctx.base_controller.clone(),
        );
        Action::Local(
            format!(
                "recipe.tune = false: {} with model_fwd = {}, model_inv = {} → {}",
                b.display(),
                f.display(),
                i.display(),
                c.display()
            ),
            Box::new(move || controller_from_base(&b, &f, &i, &c)),
        )
    };
    runner.step(
        &tune_step,
        action,
        &base_text,
        &trained,
        &[controller.clone(), controller.with_extension("tune.json")],
    )?;
    Ok((controller, tune_step))
}

/// Runs `cmd` to its end: its exit status and the CPU time (user + system, s) it and the
/// children it waited for used.
pub(super) fn run_measured(cmd: &mut std::process::Command) -> std::io::Result<(std::process::ExitStatus, f64)> {
    use std::os::unix::process::ExitStatusExt as _;
    let child = cmd.spawn()?;
    let pid = child.id() as libc::pid_t;
    let mut status = 0;
    // SAFETY: `rusage` is plain old data, for which all zeroes is a valid value.
    let mut ru: libc::rusage = unsafe { std::mem::zeroed() };
    loop {
        // SAFETY: waits for our own child, writing into the two locals above.
        let r = unsafe { libc::wait4(pid, &mut status, 0, &mut ru) };
        if r == pid {
            break;
        }
        let e = std::io::Error::last_os_error();
        if e.kind() != std::io::ErrorKind::Interrupted {
            return Err(e);
        }
    }
    // Reaped above; dropping a `Child` neither waits nor kills.
    drop(child);
    let secs = |t: libc::timeval| t.tv_sec as f64 + t.tv_usec as f64 * 1e-6;
    Ok((
        std::process::ExitStatus::from_raw(status),
        secs(ru.ru_utime) + secs(ru.ru_stime),
    ))
}

pub(super) fn read_text(p: &Path) -> String {
    std::fs::read_to_string(p).unwrap_or_default()
}

/// The family's plant file with `[variation] unit = N`.
pub(super) fn unit_plant_text(family_plant: &Path, unit: u64) -> Result<String> {
    let text = std::fs::read_to_string(family_plant).with_context(|| format!("reading {}", family_plant.display()))?;
    let mut t: toml::Table = toml::from_str(&text).with_context(|| format!("parsing {}", family_plant.display()))?;
    let var = t
        .entry("variation")
        .or_insert_with(|| toml::Value::Table(toml::Table::new()));
    let Some(var) = var.as_table_mut() else {
        bail!("{}: `variation` is not a table", family_plant.display());
    };
    var.insert("unit".into(), toml::Value::Integer(i64::try_from(unit)?));
    Ok(format!(
        "# {} as manufactured unit {unit} (written by `bowden bench transfer`).\n{}",
        family_plant.display(),
        toml::to_string(&t)?
    ))
}

/// The unit's controller with the `[feedback]` table of `feedback_file` added (replacing one it
/// may have).
pub(super) fn controller_with_feedback(controller: &Path, feedback_file: &Path, out: &Path) -> Result<()> {
    let text = std::fs::read_to_string(controller).with_context(|| format!("reading {}", controller.display()))?;
    let mut t: toml::Table = toml::from_str(&text).with_context(|| format!("parsing {}", controller.display()))?;
    t.insert("feedback".into(), feedback_table(feedback_file)?);
    // Model paths are relative to the controller's own directory: `out` is written beside it.
    write_atomic(
        out,
        &format!(
            "# {} with the [feedback] settings of {} (written by `bowden bench transfer`).\n{}",
            controller.display(),
            feedback_file.display(),
            toml::to_string(&t)?
        ),
    )
}

/// The `[feedback]` table of a controller file, which must switch it on.
pub(super) fn feedback_table(file: &Path) -> Result<toml::Value> {
    let text = std::fs::read_to_string(file).with_context(|| format!("reading {}", file.display()))?;
    let t: toml::Table = toml::from_str(&text).with_context(|| format!("parsing {}", file.display()))?;
    match t.get("feedback") {
        Some(v @ toml::Value::Table(f)) if f.get("enabled").and_then(toml::Value::as_bool) == Some(true) => {
            Ok(v.clone())
        }
        Some(toml::Value::Table(_)) => bail!("{}: [feedback] does not set enabled = true", file.display()),
        _ => bail!("{}: no [feedback] table", file.display()),
    }
}

/// `recipe.tune = false`: the base controller with the unit's first forward/inverse models.
pub(super) fn controller_from_base(base: &Path, fwd: &Path, inv: &Path, out: &Path) -> Result<()> {
    let text = std::fs::read_to_string(base).with_context(|| format!("reading {}", base.display()))?;
    let mut t: toml::Table = toml::from_str(&text).with_context(|| format!("parsing {}", base.display()))?;
    for (k, p) in [("model_fwd", fwd), ("model_inv", inv)] {
        t.insert(k.into(), toml::Value::String(absolute(p).display().to_string()));
    }
    write_atomic(
        out,
        &format!(
            "# {} with this unit's models (written by `bowden bench transfer`, recipe.tune = false).\n{}",
            base.display(),
            toml::to_string(&t)?
        ),
    )
}

// Long: the steps of one unit in the order a user types them (collect, train, tune, evaluate, feedback, large paths), each a stamped subprocess.
pub(super) fn run_unit(ctx: &Ctx, families: &[Family], plan: &UnitPlan, bar: &ProgressBar) -> UnitOutcome {
    let fam = &families[plan.family];
    let label = format!("{}/unit-{}", fam.name, plan.unit);
    let r = &ctx.recipe;
    let mut runner = UnitRunner {
        ctx,
        plan,
        label: label.clone(),
        bar,
        records: Vec::new(),
        stamps: Default::default(),
        total_steps: {
            let train_and_tune = 1 + r.training_jobs().len();
            let rounds = if r.closed_loop.is_some() { 2 } else { 1 };
            let evaluations = if r.feedback.is_some() { 2 } else { 1 };
            rounds * (1 + train_and_tune)
                + evaluations * (1 + r.trajectory_sets.len())
                + usize::from(r.feedback.is_some())
        },
    };
    let t0 = Instant::now();
    let result = (|| -> std::result::Result<Vec<Row>, Failure> {
        let dir = &plan.dir;
        let local_fail = |step: &str, e: String| Failure {
            step: step.into(),
            status: e,
            log: None,
            log_tail: Vec::new(),
            hint: None,
        };
        // 1. The unit's plant file (rewritten only when it changes).
        let plant = dir.join("plant.toml");
        let text = unit_plant_text(&fam.plant, plan.unit).map_err(|e| local_fail("plant", format!("{e:#}")))?;
        std::fs::create_dir_all(dir).map_err(|e| local_fail("plant", format!("creating {}: {e}", dir.display())))?;
        if read_text(&plant) != text {
            write_atomic(&plant, &text).map_err(|e| local_fail("plant", format!("{e:#}")))?;
        }
        let s = |p: &Path| p.display().to_string();
        // 2. Collect through the vision loop.
        let data = dir.join("data");
        let collect = vec![
            "collect".into(),
            "--plant".into(),
            s(&plant),
            "--samples".into(),
            r.samples.to_string(),
            "--seed".into(),
            ctx.seed.to_string(),
            "--excitation".into(),
            r.excitation.as_str().into(),
            "--out".into(),
            s(&data),
        ];
        // The pipeline's own files (the subcommands' defaults) are inputs too.
        let pipeline_text = ["evaluate.toml", "robot.toml", "camera.toml", "markers.toml"]
            .iter()
            .map(|f| read_text(&ctx.project.join("configs").join(f)))
            .collect::<String>();
        let collect_inputs = format!("{text}{pipeline_text}");
        runner.step(
            "collect",
            Action::Exe(collect),
            &collect_inputs,
            &[],
            std::slice::from_ref(&data),
        )?;
        // 3–4. Train every model and choose the settings.
        let (mut controller, mut tune_step) = train_and_tune(&mut runner, &data, "collect", "")?;
        // 3b–4b. A second round under the compensator the first round made: its commands on
        //    this robot are added to the data and everything is trained and tuned again.
        if let Some(cl) = &r.closed_loop {
            let data2 = dir.join("data-closed-loop");
            let collect2 = vec![
                "collect".into(),
                "--plant".into(),
                s(&plant),
                "--samples".into(),
                cl.samples.to_string(),
                "--seed".into(),
                (ctx.seed + 1).to_string(),
                "--excitation".into(),
                cl.excitation.as_str().into(),
                "--controller-config".into(),
                s(&controller),
                "--extend".into(),
                s(&data),
                "--out".into(),
                s(&data2),
            ];
            runner.step(
                "collect-closed-loop",
                Action::Exe(collect2),
                &collect_inputs,
                &["collect".into(), tune_step.clone()],
                std::slice::from_ref(&data2),
            )?;
            (controller, tune_step) = train_and_tune(&mut runner, &data2, "collect-closed-loop", "-closed-loop")?;
        }
        // 5. Evaluate on the unseen trajectories.
        let eval = dir.join("eval");
        let summary = eval.join("summary.json");
        // `bowden evaluate` of `controller` on the unit's plant, the camera at `camera_fps`
        // (default: one frame per held point).
        let evaluate =
            |controller: &Path, camera_fps: Option<f64>, set: Option<&Path>, report: &Path, summary: &Path| {
                let mut args: Vec<String> = vec![
                    "evaluate".into(),
                    "--plant".into(),
                    s(&plant),
                    "--controller-config".into(),
                    s(controller),
                ];
                if let Some(f) = camera_fps {
                    args.extend(["--camera-fps".into(), f.to_string()]);
                }
                args.extend([
                    "--repeats".into(),
                    r.repeats.to_string(),
                    "--trajectories".into(),
                    r.trajectories.join(","),
                    "--controllers".into(),
                    r.controllers.join(","),
                ]);
                if let Some(d) = set {
                    args.extend(["--trajectories-dir".into(), s(d)]);
                }
                if let Some(n) = r.max_points {
                    args.extend(["--max-points".into(), n.to_string()]);
                }
                args.extend(["--report".into(), s(report), "--json-out".into(), s(summary)]);
                args
            };
        let args = evaluate(&controller, None, None, &eval, &summary);
        let eval_inputs = r
            .trajectories
            .iter()
            .fold(format!("{text}{pipeline_text}{}", read_text(&controller)), |acc, t| {
                acc + &read_text(&ctx.project.join("configs/trajectories").join(format!("{t}.toml")))
            });
        runner.step(
            "evaluate",
            Action::Exe(args),
            &eval_inputs,
            std::slice::from_ref(&tune_step),
            &[summary.clone(), eval.clone()],
        )?;
        // 6. The same controller with vision feedback, the camera fast enough to give it frames.
        if let (Some(fb), Some(fb_file)) = (&r.feedback, &ctx.feedback_config) {
            let fb_controller = dir.join("controller-feedback.toml");
            let (c, f, o) = (controller.clone(), fb_file.clone(), fb_controller.clone());
            runner.step(
                "feedback",
                Action::Local(
                    format!(
                        "{} with [feedback] of {} → {}",
                        controller.display(),
                        fb_file.display(),
                        fb_controller.display()
                    ),
                    Box::new(move || controller_with_feedback(&c, &f, &o)),
                ),
                &read_text(fb_file),
                std::slice::from_ref(&tune_step),
                std::slice::from_ref(&fb_controller),
            )?;
            let eval_fb = dir.join("eval-feedback");
            let summary_fb = eval_fb.join("summary.json");
            runner.step(
                "evaluate-feedback",
                Action::Exe(evaluate(
                    &fb_controller,
                    Some(fb.camera_fps),
                    None,
                    &eval_fb,
                    &summary_fb,
                )),
                &eval_inputs,
                &["feedback".into()],
                &[summary_fb.clone(), eval_fb.clone()],
            )?;
        }
        // 7. Both again on every further set of paths (e.g. at the paper's magnitude).
        for (name, set_dir) in &ctx.trajectory_sets {
            let set_inputs = r
                .trajectories
                .iter()
                .fold(format!("{text}{pipeline_text}{}", read_text(&controller)), |acc, t| {
                    acc + &read_text(&set_dir.join(format!("{t}.toml")))
                });
            let eval_set = dir.join(format!("eval-{name}"));
            let summary_set = eval_set.join("summary.json");
            runner.step(
                &format!("evaluate-{name}"),
                Action::Exe(evaluate(&controller, None, Some(set_dir), &eval_set, &summary_set)),
                &set_inputs,
                std::slice::from_ref(&tune_step),
                &[summary_set.clone(), eval_set.clone()],
            )?;
            if let Some(fb) = &r.feedback {
                let eval_fb = dir.join(format!("eval-feedback-{name}"));
                let summary_fb = eval_fb.join("summary.json");
                runner.step(
                    &format!("evaluate-feedback-{name}"),
                    Action::Exe(evaluate(
                        &dir.join("controller-feedback.toml"),
                        Some(fb.camera_fps),
                        Some(set_dir),
                        &eval_fb,
                        &summary_fb,
                    )),
                    &set_inputs,
                    &["feedback".into()],
                    &[summary_fb.clone(), eval_fb.clone()],
                )?;
            }
        }
        unit_rows(dir, r).map_err(|e| local_fail("report", format!("{e:#}")))
    })();
    let wall = t0.elapsed().as_secs_f64();
    let (rows, failure) = match result {
        Ok(rows) => (rows, None),
        Err(f) => (Vec::new(), Some(f)),
    };
    if let Some(f) = &failure {
        if !runner.records.iter().any(|x| x.step == f.step) {
            runner.records.push(StepRecord {
                step: f.step.clone(),
                status: StepStatus::Failed,
                seconds: 0.0,
                cpu_seconds: 0.0,
                command: String::new(),
                log: f.log.clone(),
            });
        }
    }
    UnitOutcome {
        family: fam.name.clone(),
        model: fam.model.clone(),
        unit: plan.unit,
        role: plan.role,
        dir: plan.dir.clone(),
        status: if failure.is_some() { "failed" } else { "ok" }.into(),
        failure,
        steps: runner.records,
        wall_seconds: wall,
        rows,
    }
}
