//! `bowden sweep` in pieces, as a cluster scheduler runs it (issue #16 item 1): `--plan`
//! numbers and fingerprints the runs, four `--shard I/4` processes train them into one output
//! directory, `--merge` writes the same sweep.json, sweep.md and sweep.svg, byte for byte, as
//! one local `bowden sweep`; a shard killed mid-write is redone; runs made from other data are
//! refused by name.

use crate::cli_support;
use cli_support::{bowden, fails_with, ok, repo, transfer_recipe};
use std::path::Path;
use std::process::{Command, Stdio};

use bowden_learning::synthetic::hysteretic_dataset;

fn synthetic_dir(dir: &Path, n: usize, seed: u64) -> String {
    hysteretic_dataset(n, 5, seed)
        .write_dir(dir, "synthetic", Some(seed), None, serde_json::Value::Null)
        .unwrap();
    dir.display().to_string()
}

/// One architecture × 2 directions × 2 L × 2 seeds = 8 runs of 2 epochs.
fn sweep_args<'a>(data: &'a str, out: &'a str) -> Vec<&'a str> {
    vec![
        "sweep",
        "--archs",
        "tcn",
        "--tcn-blocks",
        "relu-linear",
        "--seq-lens",
        "8,12",
        "--seeds",
        "2",
        "--directions",
        "forward,inverse",
        "--epochs",
        "2",
        "--data",
        data,
        "--out",
        out,
    ]
}

/// Starts the shards as separate processes at once, as a job array does, and waits for all.
fn run_shards(base: &[&str], shards: &[usize], of: usize) {
    let children: Vec<_> = shards
        .iter()
        .map(|i| {
            let shard = format!("{i}/{of}");
            Command::new(env!("CARGO_BIN_EXE_bowden"))
                .current_dir(repo())
                .args(base)
                .args(["--shard", &shard, "--jobs", "1"])
                .stdout(Stdio::piped())
                .stderr(Stdio::piped())
                .spawn()
                .expect("start a shard")
        })
        .collect();
    for (i, c) in shards.iter().zip(children) {
        let out = c.wait_with_output().expect("wait for a shard");
        let stdout = ok(&out);
        assert!(
            stdout.contains(&format!("shard {i}/{of} (indices ≡ {i} mod {of})")),
            "{stdout}"
        );
    }
}

fn read(p: &Path) -> Vec<u8> {
    std::fs::read(p).unwrap_or_else(|e| panic!("{}: {e}", p.display()))
}

fn plan_json(args: &[&str]) -> serde_json::Value {
    serde_json::from_str(&ok(&bowden(&[args, &["--plan", "--json"]].concat()))).unwrap()
}

#[test]
// Long: one scenario end to end; its steps depend on each other's files.
fn four_shards_merge_into_the_local_sweep_byte_for_byte_and_a_killed_shard_is_redone() {
    let tmp = tempfile::tempdir().unwrap();
    let data = synthetic_dir(&tmp.path().join("data"), 900, 11);
    let local = tmp.path().join("local");
    let shared = tmp.path().join("shared");
    let (local_s, shared_s) = (local.display().to_string(), shared.display().to_string());

    // The local sweep, then resumed: sweep.json is the resumed one's, so a reuse count or
    // --jobs leaking into it (the merge below runs with --jobs 1) would break the comparison.
    let local_args = sweep_args(&data, &local_s);
    ok(&bowden(&[&local_args[..], &["--jobs", "2"]].concat()));
    let resumed = ok(&bowden(&[&local_args[..], &["--jobs", "2"]].concat()));
    assert!(resumed.contains("8 runs, 8 reused"), "{resumed}");

    // The plan: 8 runs numbered in order, fingerprinted, all pending in the empty directory;
    // `--jobs` is no part of it.
    let args = sweep_args(&data, &shared_s);
    let plan = plan_json(&args);
    let runs = plan["runs"].as_array().unwrap();
    assert_eq!(runs.len(), 8);
    for (i, r) in runs.iter().enumerate() {
        assert_eq!(r["index"], i);
        assert_eq!(r["status"], "pending");
        assert_eq!(r["fingerprint"].as_str().unwrap().len(), 16);
    }
    assert_eq!(runs[1]["file"], "runs/tcn-relu-linear_forward_L8_s1.json");
    let jobs_plan = plan_json(&[&args[..], &["--jobs", "3"]].concat());
    assert_eq!(jobs_plan, plan);
    let table = ok(&bowden(&[&args[..], &["--plan"]].concat()));
    assert!(
        table.contains(plan["fingerprint"].as_str().unwrap()) && table.contains("tcn-relu-linear_inverse_L12_s1"),
        "{table}"
    );

    // Three of four shards: the merge refuses and lists what the fourth owes.
    run_shards(&args, &[0, 1, 2], 4);
    fails_with(
        &bowden(&[&args[..], &["--merge"]].concat()),
        &["2 of 8 runs missing (indices 3, 7;", "--run K"],
    );
    assert!(!shared.join("sweep.json").exists());
    run_shards(&args, &[3], 4);
    let merged = ok(&bowden(&[&args[..], &["--merge", "--jobs", "1"]].concat()));
    assert!(merged.contains("8 runs merged"), "{merged}");
    for f in ["sweep.json", "sweep.md", "sweep.svg"] {
        assert!(
            read(&local.join(f)) == read(&shared.join(f)),
            "{f}: the merged shards differ from the local sweep"
        );
    }
    let done = plan_json(&args);
    assert!(
        done["runs"].as_array().unwrap().iter().all(|r| r["status"] == "done"),
        "{done}"
    );
    // Each run file carries its plan fingerprint.
    let run1: serde_json::Value =
        serde_json::from_slice(&read(&shared.join("runs/tcn-relu-linear_forward_L8_s1.json"))).unwrap();
    assert_eq!(run1["fingerprint"], runs[1]["fingerprint"]);

    // Shard 1 killed mid-way: run 1's file cut short (a file system without atomic rename, or
    // a writer of old), run 5's write never renamed (a stale temporary file), run 5's result
    // gone. The merge names the cut file; rerunning shard 1 redoes runs 1 and 5 and removes the
    // temporary file; the merge is again byte-identical.
    let runs_dir = shared.join("runs");
    let cut = runs_dir.join("tcn-relu-linear_forward_L8_s1.json");
    let text = read(&cut);
    std::fs::write(&cut, &text[..text.len() / 3]).unwrap();
    let r5 = runs_dir.join("tcn-relu-linear_inverse_L8_s1.json");
    assert!(r5.exists(), "run 5 is inverse L=8 seed 1");
    std::fs::remove_file(&r5).unwrap();
    let stale = runs_dir.join(".tcn-relu-linear_inverse_L8_s1.json.tmp-4242");
    std::fs::write(&stale, "{\"key\": {\"arch\": \"tcn\"").unwrap();
    fails_with(
        &bowden(&[&args[..], &["--merge"]].concat()),
        &[
            &format!("{} (run 1): not a complete run file", cut.display()),
            "1 of 8 runs missing (indices 5;",
        ],
    );
    let status = plan_json(&args);
    assert!(
        status["runs"][1]["status"]
            .as_str()
            .unwrap()
            .starts_with("redo: not a complete run file"),
        "{status}"
    );
    assert_eq!(status["runs"][5]["status"], "pending");
    let before = std::fs::metadata(runs_dir.join("tcn-relu-linear_forward_L12_s1.json"))
        .unwrap()
        .modified()
        .unwrap();
    let rerun = ok(&bowden(&[&args[..], &["--shard", "1/4"]].concat()));
    assert!(rerun.contains("run 1: redone, its file was unusable"), "{rerun}");
    assert!(rerun.contains("(2 trained, 0 kept)"), "{rerun}");
    assert!(
        !stale.exists(),
        "the stale temporary file is removed once run 5 is complete"
    );
    // Run 3 is shard 3's: untouched.
    assert_eq!(
        std::fs::metadata(runs_dir.join("tcn-relu-linear_forward_L12_s1.json"))
            .unwrap()
            .modified()
            .unwrap(),
        before
    );
    // A rerun of a finished shard trains nothing.
    let again = ok(&bowden(&[&args[..], &["--shard", "1/4"]].concat()));
    assert!(again.contains("(0 trained, 2 kept)"), "{again}");
    ok(&bowden(&[&args[..], &["--merge"]].concat()));
    assert!(read(&local.join("sweep.json")) == read(&shared.join("sweep.json")));

    // Selections out of range are refused with the plan's size.
    fails_with(&bowden(&[&args[..], &["--run", "8"]].concat()), &["--run 8", "8 runs"]);
    fails_with(
        &bowden(&[&args[..], &["--shard", "4/4"]].concat()),
        &["--shard \"4/4\"", "I/N"],
    );
}

#[test]
fn merge_refuses_a_run_made_from_other_data() {
    let tmp = tempfile::tempdir().unwrap();
    let data = synthetic_dir(&tmp.path().join("data"), 900, 11);
    let other = synthetic_dir(&tmp.path().join("other"), 900, 12);
    let out = tmp.path().join("sweep").display().to_string();
    let args = sweep_args(&data, &out);
    // Runs 0–7 from the right data, through the one-run form a job array can also use...
    for k in 0..8 {
        ok(&bowden(&[&args[..], &["--run", &k.to_string()]].concat()));
    }
    // ...then run 2 redone by a job pointed at another dataset.
    let wrong = sweep_args(&other, &out);
    let stdout = ok(&bowden(&[&wrong[..], &["--run", "2"]].concat()));
    assert!(
        stdout.contains("run 2: redone, its file was unusable") && stdout.contains("made from different data"),
        "{stdout}"
    );
    let file = Path::new(&out).join("runs/tcn-relu-linear_forward_L12_s0.json");
    fails_with(
        &bowden(&[&args[..], &["--merge"]].concat()),
        &[
            &format!("{} (run 2): made from different data", file.display()),
            "1 run file(s) not from this sweep",
        ],
    );
    assert!(!Path::new(&out).join("sweep.json").exists());
}

/// `bench transfer` in shards: two units (a quick capstan unit and one whose plant file the
/// simulator refuses), one shard each as separate processes; the merge names a missing or
/// foreign outcome file, and otherwise reports what a local run over the same directory does.
#[test]
fn transfer_shards_merge_into_the_local_report() {
    let tmp = tempfile::tempdir().unwrap();
    let r = repo();
    let plant = std::fs::read_to_string(r.join("configs/plant.toml")).unwrap();
    assert!(plant.contains("\nplays = 6\n"));
    std::fs::write(
        tmp.path().join("plant-broken.toml"),
        plant.replace("\nplays = 6\n", "\nplays = \"six\"\n"),
    )
    .unwrap();
    let cfg = tmp.path().join("transfer.toml");
    std::fs::write(
        &cfg,
        format!(
            r#"{recipe}

[[family]]
name = "capstan"
plant = "{plant}"
heldout_units = [4242]

[[family]]
name = "broken"
plant = "plant-broken.toml"
heldout_units = [1]
"#,
            recipe = transfer_recipe(true),
            plant = r.join("configs/plant.toml").display(),
        ),
    )
    .unwrap();
    let out = tmp.path().join("out");
    let (cfg_s, out_s) = (cfg.display().to_string(), out.display().to_string());
    let args = ["bench", "transfer", "--config", &cfg_s, "--out", &out_s, "--quick"];
    let plan: serde_json::Value =
        serde_json::from_str(&ok(&bowden(&[&args[..], &["--plan", "--json"]].concat()))).unwrap();
    let units = plan["units"].as_array().unwrap();
    assert_eq!(units.len(), 2);
    assert_eq!(
        (units[0]["family"].as_str(), units[0]["unit"].as_u64()),
        (Some("capstan"), Some(4242))
    );
    assert!(units.iter().all(|u| u["status"] == "pending"), "{plan}");

    let shards: Vec<_> = ["0/2", "1/2"]
        .iter()
        .map(|s| {
            Command::new(env!("CARGO_BIN_EXE_bowden"))
                .current_dir(repo())
                .args(args)
                .args(["--shard", s, "--jobs", "1"])
                .stdout(Stdio::piped())
                .stderr(Stdio::piped())
                .spawn()
                .expect("start a shard")
        })
        .collect();
    let outs: Vec<_> = shards.into_iter().map(|c| c.wait_with_output().unwrap()).collect();
    let first = ok(&outs[0]);
    assert!(first.contains("unit 0 capstan/unit-4242: ok"), "{first}");
    // The broken unit's shard fails, as its unit did; its outcome is on record for the merge.
    fails_with(&outs[1], &["shard 1/2", "1 of 1 unit(s) failed"]);
    assert!(String::from_utf8_lossy(&outs[1].stdout).contains("unit 1 broken/unit-1: FAILED at step collect"));

    // A missing outcome, then one of another config: refused by index and by name.
    let broken = out.join("units/broken/unit-1/outcome.json");
    let saved = std::fs::read_to_string(&broken).unwrap();
    std::fs::remove_file(&broken).unwrap();
    fails_with(
        &bowden(&[&args[..], &["--merge"]].concat()),
        &["cannot merge: 1 of 2 units have no outcome.json (indices 1;"],
    );
    let fp = units[1]["fingerprint"].as_str().unwrap();
    std::fs::write(&broken, saved.replace(fp, "0000000000000000")).unwrap();
    fails_with(
        &bowden(&[&args[..], &["--merge"]].concat()),
        &[&format!("{} (unit 1): made with another config", broken.display())],
    );
    std::fs::write(&broken, &saved).unwrap();

    // The merge reports both units (and fails, as a local run does, for the broken one).
    fails_with(
        &bowden(&[&args[..], &["--merge"]].concat()),
        &["1 of 2 unit(s) failed (broken/unit-1 at collect)"],
    );
    let read_json = || -> serde_json::Value { serde_json::from_slice(&read(&out.join("transfer.json"))).unwrap() };
    let merged = read_json();
    assert_eq!(merged["merged"], true);
    assert!(!merged["units"][0]["rows"].as_array().unwrap().is_empty());
    // A local run over the same directory (every step's stamp current: nothing reruns) reports
    // the same results; only timings, load and the run's own settings differ.
    fails_with(&bowden(&args), &["1 of 2 unit(s) failed"]);
    let local = read_json();
    assert_eq!(local["merged"], false);
    for key in ["summary", "never_worse", "best_mode", "families", "recipe"] {
        assert_eq!(local[key], merged[key], "{key}");
    }
    for (l, m) in local["units"]
        .as_array()
        .unwrap()
        .iter()
        .zip(merged["units"].as_array().unwrap())
    {
        for key in ["family", "unit", "role", "status", "rows"] {
            assert_eq!(l[key], m[key], "{key}");
        }
    }
}
