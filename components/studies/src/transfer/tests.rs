use super::*;

fn cfg(text: &str) -> std::result::Result<TransferConfig, String> {
    let c: TransferConfig = toml::from_str(text).map_err(|e| e.to_string())?;
    c.validate()?;
    Ok(c)
}

const OK: &str = r#"
seed = 1
[recipe]
samples = 100
excitation = "mixed"
archs = ["tcn"]
epochs = 3
seq_len = 80
repeats = 1
trajectories = ["circle"]
controllers = ["uncalibrated", "paper"]
tune = false
base_controller = "configs/controller.toml"
[[family]]
name = "a"
plant = "configs/plant.toml"
heldout_units = [1, 2]
"#;

#[test]
fn config_errors_name_the_field() {
    assert!(cfg(OK).is_ok());
    let e = cfg(&OK.replace("samples = 100", "samples = 1")).unwrap_err();
    assert!(e.contains("recipe.samples"), "{e}");
    let e = cfg(&OK.replace("samples = 100", "sampels = 100")).unwrap_err();
    assert!(e.contains("sampels"), "{e}");
    let e = cfg(&OK.replace("[\"tcn\"]", "[\"cnn\"]")).unwrap_err();
    assert!(e.contains("recipe.archs[0]"), "{e}");
    let e = cfg(&OK.replace("[\"uncalibrated\", \"paper\"]", "[\"paper\"]")).unwrap_err();
    assert!(e.contains("recipe.controllers"), "{e}");
    let e = cfg(&OK.replace("heldout_units = [1, 2]", "heldout_units = [1, 2]\ntuning_units = [2]")).unwrap_err();
    assert!(e.contains("family[0].heldout_units"), "{e}");
    let per_arch = |t: &str| OK.replace("[[family]]", &format!("[recipe.per_arch.{t}\n[[family]]"));
    let e = cfg(&per_arch("lstm]\nepochs = 5")).unwrap_err();
    assert!(e.contains("recipe.per_arch.lstm"), "{e}");
    let e = cfg(&per_arch("tcn]\nepochs = 0")).unwrap_err();
    assert!(e.contains("recipe.per_arch.tcn"), "{e}");
    let e = cfg(&per_arch("tcn]\nepoch = 5")).unwrap_err();
    assert!(e.contains("epoch"), "{e}");
}

fn row(controller: &str, trajectory: &str, pct: f64) -> Row {
    let six = Six {
        position_vision: Some(pct),
        position_truth: Some(pct),
        orientation_vision: Some(pct),
        orientation_truth: Some(pct),
        joint_vision: Some(pct),
        joint_truth: Some(pct),
    };
    Row {
        trajectory: trajectory.into(),
        controller: controller.into(),
        error: six,
        uncalibrated: six,
        reduction_pct: six,
    }
}

fn unit(family: &str, n: u64, rows: Vec<Row>) -> UnitOutcome {
    UnitOutcome {
        family: family.into(),
        model: family.into(),
        unit: n,
        role: Role::HeldOut,
        dir: PathBuf::new(),
        status: "ok".into(),
        failure: None,
        steps: Vec::new(),
        wall_seconds: 0.0,
        rows,
    }
}

/// `OK` with `recipe_lines` added to `[recipe]` and a `[recipe.feedback]` table.
fn ok_with_feedback(recipe_lines: &str) -> String {
    OK.replace(
        "[[family]]",
        &format!(
            "{recipe_lines}[recipe.feedback]\nconfig = \"configs/controller-feedback.toml\"\ncamera_fps = 10.0\n[[family]]"
        ),
    )
}

#[test]
fn feedback_controllers_are_reported_and_judged_by_the_goals() {
    let with_fb = ok_with_feedback("");
    let r = cfg(&with_fb).unwrap().recipe;
    assert_eq!(calibrated(&r), ["paper", "paper+fb"]);
    let e = cfg(&with_fb.replace("camera_fps = 10.0", "camera_fps = 0.0")).unwrap_err();
    assert!(e.contains("recipe.feedback.camera_fps"), "{e}");
    let e = cfg(&with_fb.replace("camera_fps = 10.0", "camera_fps = 10.0\ngain = 1")).unwrap_err();
    assert!(e.contains("gain"), "{e}");
    // paper: one cell below 60 %; paper+fb: all ≥ 60 %, median 80 %.
    let a = unit(
        "a",
        1,
        vec![
            row("paper", "circle", 70.0),
            row("paper+fb", "circle", 80.0),
            row("paper", "zigzag", 59.0),
            row("paper+fb", "zigzag", 61.0),
        ],
    );
    let b = unit(
        "a",
        2,
        vec![row("paper", "circle", 90.0), row("paper+fb", "circle", 90.0)],
    );
    let g = goals(&[&a, &b], &r);
    assert_eq!((g[0].controller.as_str(), g[0].met), ("paper", false));
    assert_eq!((g[0].below_60, g[0].checks), (6, 18));
    assert_eq!(g[0].worst_pct, 59.0);
    assert!(g[0].worst_at.starts_with("a 1 zigzag"), "{}", g[0].worst_at);
    assert_eq!((g[1].controller.as_str(), g[1].met), ("paper+fb", true));
    assert_eq!(g[1].lowest_median_pct, 80.0);
    // A median below 75 % fails even with every cell ≥ 60 %.
    let c = unit("a", 3, vec![row("paper+fb", "circle", 61.0)]);
    let g = goals(&[&a, &c], &r);
    assert!(!g[1].met && g[1].below_60 == 0, "{:?}", g[1]);
    assert_eq!(best_mode(&[&a, &b], &r, false).as_deref(), Some("paper+fb"));
    assert_eq!(best_mode(&[&a, &b], &r, true).as_deref(), Some("paper"));
}

#[test]
fn further_path_sets_are_controllers_of_their_own_but_never_the_headline() {
    let with_sets = ok_with_feedback("trajectory_sets = { large = \"configs/trajectories/large\" }\n");
    let r = cfg(&with_sets).unwrap().recipe;
    assert_eq!(calibrated(&r), ["paper", "paper+fb", "paper@large", "paper+fb@large"]);
    let e = cfg(&with_sets.replace("large =", "\"../up\" =")).unwrap_err();
    assert!(e.contains("recipe.trajectory_sets"), "{e}");
    // The large paths' goals are checked on their own rows; the best mode (the plot, the
    // headline) comes from the shipped paths only, however well the others did.
    let a = unit(
        "a",
        1,
        vec![
            row("paper", "circle", 50.0),
            row("paper+fb", "circle", 70.0),
            row("paper@large", "circle", 80.0),
            row("paper+fb@large", "circle", 95.0),
        ],
    );
    let g = goals(&[&a], &r);
    let met: Vec<(&str, bool)> = g.iter().map(|g| (g.controller.as_str(), g.met)).collect();
    assert_eq!(
        met,
        [
            ("paper", false),
            ("paper+fb", false),
            ("paper@large", true),
            ("paper+fb@large", true)
        ]
    );
    assert_eq!(best_mode(&[&a], &r, false).as_deref(), Some("paper+fb"));
    assert_eq!(best_mode(&[&a], &r, true).as_deref(), Some("paper"));
}

#[test]
fn controller_with_feedback_adds_the_table() {
    let dir = tempfile::tempdir().unwrap();
    let (c, f, o) = (
        dir.path().join("c.toml"),
        dir.path().join("f.toml"),
        dir.path().join("o.toml"),
    );
    std::fs::write(&c, "mode = \"newton\"\nmodel_fwd = \"models/f.onnx\"\n").unwrap();
    std::fs::write(&f, "mode = \"paper\"\n[feedback]\nenabled = true\ngain = 0.8\n").unwrap();
    controller_with_feedback(&c, &f, &o).unwrap();
    let t: toml::Table = toml::from_str(&std::fs::read_to_string(&o).unwrap()).unwrap();
    assert_eq!(t["mode"].as_str(), Some("newton"), "the unit's settings stay");
    assert_eq!(t["model_fwd"].as_str(), Some("models/f.onnx"));
    assert_eq!(t["feedback"]["gain"].as_float(), Some(0.8));
    std::fs::write(&f, "[feedback]\nenabled = false\n").unwrap();
    let e = format!("{:#}", controller_with_feedback(&c, &f, &o).unwrap_err());
    assert!(e.contains("enabled = true"), "{e}");
    std::fs::write(&f, "mode = \"paper\"\n").unwrap();
    let e = format!("{:#}", controller_with_feedback(&c, &f, &o).unwrap_err());
    assert!(e.contains("no [feedback] table"), "{e}");
}

#[test]
fn the_fingerprint_covers_the_files_the_recipe_names() {
    let r = cfg(OK).unwrap().recipe;
    let fam = Family {
        name: "a".into(),
        model: "plant".into(),
        plant: PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../configs/plant.toml"),
        tuning_units: Vec::new(),
        heldout_units: vec![1],
    };
    let plan = UnitPlan {
        family: 0,
        unit: 1,
        role: Role::HeldOut,
        dir: PathBuf::new(),
    };
    let fp = |files: &str| unit_fingerprint(&r, files, 1, &fam, &plan).unwrap();
    assert_eq!(
        fp("base\u{1e}[feedback]\ngain = 0.8"),
        fp("base\u{1e}[feedback]\ngain = 0.8")
    );
    // Another feedback gain or base controller: shards made with it are not merged.
    assert_ne!(
        fp("base\u{1e}[feedback]\ngain = 0.8"),
        fp("base\u{1e}[feedback]\ngain = 0.5")
    );
    assert_ne!(fp("base\u{1e}"), fp("other base\u{1e}"));
}

#[test]
fn inverse_architectures_are_validated() {
    let with = |j: &str| OK.replace("archs = [\"tcn\"]", &format!("archs = [\"tcn\"]\ninverse_archs = {j}"));
    let c = cfg(&with("[\"lstm\"]")).unwrap();
    assert_eq!(c.recipe.inverse_archs, ["lstm"]);
    assert_candidate_list_is_validated("inverse_archs");
    let text = with("[\"lstm\"]").replace("[[family]]", "[recipe.per_arch.lstm]\nepochs = 30\n[[family]]");
    assert_eq!(cfg(&text).unwrap().recipe.training("lstm"), (30, None));
}

#[test]
fn judge_architectures_are_validated() {
    let with = |j: &str| OK.replace("archs = [\"tcn\"]", &format!("archs = [\"tcn\"]\njudge_archs = {j}"));
    assert!(cfg(&with("[\"lstm\"]")).is_ok());
    let e = cfg(&with("[\"rnn\"]")).unwrap_err();
    assert!(e.contains("recipe.judge_archs[0]"), "{e}");
    let e = cfg(&with("[\"lstm\", \"lstm\"]")).unwrap_err();
    assert!(e.contains("twice"), "{e}");
    // per_arch may name a judge.
    let text = with("[\"lstm\"]").replace("[[family]]", "[recipe.per_arch.lstm]\nepochs = 30\n[[family]]");
    assert_eq!(cfg(&text).unwrap().recipe.training("lstm"), (30, None));
}

#[test]
fn a_judge_of_a_candidate_architecture_is_trained_apart_with_its_own_seed() {
    let text = OK.replace(
        "archs = [\"tcn\"]",
        "archs = [\"tcn\"]\nforward_archs = [\"lstm\"]\njudge_archs = [\"lstm\"]\ninverse_archs = [\"lstm\"]",
    );
    let c = cfg(&text).unwrap();
    let jobs = c.recipe.training_jobs();
    // step, file, role, seed, direction: one line per trained model.
    let got: Vec<String> = jobs
        .iter()
        .map(|j| format!("{} {} {:?} {:?} {}", j.step, j.file, j.role, j.seed, j.direction))
        .collect();
    assert_eq!(c.recipe.seq_len, 80);
    assert_eq!(
        got,
        [
            "tcn-forward tcn_forward_L80.onnx Forward None forward",
            "tcn-inverse tcn_inverse_L80.onnx Inverse None inverse",
            "lstm-forward lstm_forward_L80.onnx Forward None forward",
            "lstm-forward-judge lstm_forward_judge_L80.onnx Judge Some(1) forward",
            "lstm-inverse lstm_inverse_L80.onnx Inverse None inverse",
        ]
    );
    // The judge's training says its seed; the candidates' do not (their stamps stay).
    let (data, model) = (Path::new("/u/data"), Path::new("/u/models/m.onnx"));
    let judge = c
        .recipe
        .train_args("lstm", "forward", jobs[3].seed, 2, data, model)
        .join(" ");
    assert!(judge.contains("--seed 1"), "{judge}");
    assert!(!c
        .recipe
        .train_args("lstm", "forward", None, 2, data, model)
        .contains(&"--seed".to_string()));
    let c = cfg(&text.replace("epochs = 3", "epochs = 3\njudge_seed = 7")).unwrap();
    assert_eq!(c.recipe.training_jobs()[3].seed, Some(7));
    let e = cfg(&text.replace("epochs = 3", "epochs = 3\njudge_seed = 0")).unwrap_err();
    assert!(e.contains("recipe.judge_seed"), "{e}");
    // A judge of an architecture nobody sends commands with is the one training, as before.
    let c = cfg(&OK.replace("archs = [\"tcn\"]", "archs = [\"tcn\"]\njudge_archs = [\"lstm\"]")).unwrap();
    let judge = &c.recipe.training_jobs()[2];
    assert_eq!(
        (judge.step.as_str(), judge.role, judge.seed),
        ("lstm-forward", ModelRole::Judge, None)
    );
    // forward_archs is validated like inverse_archs.
    assert_candidate_list_is_validated("forward_archs");
}

/// `recipe.FIELD` (a list of further candidate architectures) refuses an architecture of
/// `archs`, an unknown one and one given twice, naming the field.
fn assert_candidate_list_is_validated(field: &str) {
    let with = |v: &str| OK.replace("archs = [\"tcn\"]", &format!("archs = [\"tcn\"]\n{field} = {v}"));
    let e = cfg(&with("[\"tcn\"]")).unwrap_err();
    assert!(
        e.contains(&format!("recipe.{field}")) && e.contains("both directions"),
        "{e}"
    );
    let e = cfg(&with("[\"gru\"]")).unwrap_err();
    assert!(e.contains(&format!("recipe.{field}[0]")), "{e}");
    let e = cfg(&with("[\"lstm\", \"lstm\"]")).unwrap_err();
    assert!(e.contains("twice"), "{e}");
}

#[test]
fn the_recipe_decimation_reaches_every_training_and_is_validated() {
    let (data, model) = (Path::new("/u/data"), Path::new("/u/models/m.onnx"));
    let args = |c: &TransferConfig| -> Vec<String> {
        c.recipe
            .training_jobs()
            .iter()
            .map(|job| {
                c.recipe
                    .train_args(&job.arch, job.direction, job.seed, 2, data, model)
                    .join(" ")
            })
            .collect()
    };
    // Absent: auto, as train's own default, and passed so a stamp says which.
    let c = cfg(OK).unwrap();
    assert_eq!(c.recipe.decimation, DecimationRule::Auto);
    assert!(
        args(&c).iter().all(|a| a.contains("--decimation auto")),
        "{:?}",
        args(&c)
    );
    for (key, want) in [
        ("decimation = 4", "--decimation 4"),
        ("decimation = \"auto\"", "--decimation auto"),
    ] {
        let text = OK.replace("epochs = 3", &format!("epochs = 3\n{key}\njudge_archs = [\"tcn\"]"));
        let c = cfg(&text).unwrap();
        let a = args(&c);
        assert_eq!(a.len(), c.recipe.training_jobs().len());
        assert!(a.iter().all(|a| a.contains(want)), "{key}: {a:?}");
    }
    for bad in ["decimation = 0", "decimation = \"four\""] {
        let e = cfg(&OK.replace("epochs = 3", &format!("epochs = 3\n{bad}"))).unwrap_err();
        assert!(e.contains("decimation"), "{bad}: {e}");
    }
    // The shipped paper-protocol recipe is a valid config and lets train decide (4 on its
    // eq. (16) data).
    let shipped = std::fs::read_to_string(
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../../configs/transfer-paper-protocol.toml"),
    )
    .unwrap();
    let c = cfg(&shipped).unwrap();
    assert_eq!(
        (c.recipe.decimation, c.recipe.samples, c.recipe.epochs),
        (DecimationRule::Auto, 1802, 30)
    );
    assert_eq!(c.recipe.excitation, ExcitationKind::Paper);
}

#[test]
fn per_arch_training_overrides_only_its_architecture() {
    let text = OK
        .replace("archs = [\"tcn\"]", "archs = [\"tcn\", \"lstm\"]\nearly_stop = 40")
        .replace(
            "[[family]]",
            "[recipe.per_arch.lstm]\nepochs = 30\nearly_stop = 8\n[[family]]",
        );
    let c = cfg(&text).unwrap();
    assert_eq!(c.recipe.training("tcn"), (3, Some(40)));
    assert_eq!(c.recipe.training("lstm"), (30, Some(8)));
    let q = c.recipe.quick();
    assert_eq!((q.training("tcn"), q.training("lstm")), ((2, None), (2, None)));
    // Without `precision` no train step says --precision (their stamps stay as they were).
    let (data, model) = (Path::new("/u/data"), Path::new("/u/models/m.onnx"));
    for a in ["tcn", "lstm"] {
        assert!(!c
            .recipe
            .train_args(a, "forward", None, 2, data, model)
            .contains(&"--precision".to_string()));
    }
    // With it, only that architecture trains in bf16.
    let c = cfg(&text.replace("early_stop = 8\n", "early_stop = 8\nprecision = \"bf16\"\n")).unwrap();
    let lstm = c.recipe.train_args("lstm", "inverse", None, 2, data, model).join(" ");
    assert!(
        lstm.contains("--epochs 30 --early-stop 8 ") && lstm.contains(" --precision bf16"),
        "{lstm}"
    );
    let tcn = c.recipe.train_args("tcn", "inverse", None, 2, data, model).join(" ");
    assert!(!tcn.contains("--precision"), "{tcn}");
    let e = cfg(&text.replace("early_stop = 8\n", "early_stop = 8\nprecision = \"f16\"\n")).unwrap_err();
    assert!(e.contains("f16") && e.contains("precision"), "{e}");
}

#[test]
fn stats_and_reductions() {
    let s = stat(vec![3.0, 1.0, 2.0, f64::NAN, 10.0]).unwrap();
    assert_eq!((s.n, s.min, s.median, s.max), (4, 1.0, 2.5, 10.0));
    let u = Six {
        position_truth: Some(10.0),
        ..Default::default()
    };
    let c = Six {
        position_truth: Some(4.0),
        position_vision: Some(1.0),
        ..Default::default()
    };
    let r = Six::zip(&u, &c, reduction_pct);
    assert_eq!(r.position_truth, Some(60.0));
    assert_eq!(r.position_vision, None);
}

#[test]
fn unit_plant_sets_the_unit() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("p.toml");
    std::fs::write(&p, "name = \"x\"\n[variation]\nrelative_sd = 0.05\nunit = 3\n").unwrap();
    let t: toml::Table = toml::from_str(&unit_plant_text(&p, 77).unwrap()).unwrap();
    assert_eq!(t["variation"]["unit"].as_integer(), Some(77));
    assert_eq!(t["variation"]["relative_sd"].as_float(), Some(0.05));
    std::fs::write(&p, "name = \"x\"\n").unwrap();
    let t: toml::Table = toml::from_str(&unit_plant_text(&p, 5).unwrap()).unwrap();
    assert_eq!(t["variation"]["unit"].as_integer(), Some(5));
}
