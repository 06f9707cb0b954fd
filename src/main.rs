//! `bowden`: the command-line front end and launcher. Each subcommand is a few lines over
//! a component crate; the subcommands of one concern live in one module of `cmd/`.

mod cmd;
mod home;

/// Every process of the `bowden` binary counts its allocations per thread; node processes also
/// serve small allocations (iceoryx2's per-sample `Rc`) from a pre-faulted pool.
#[global_allocator]
static ALLOC: bowden_runtime::alloc::RtAlloc = bowden_runtime::alloc::RtAlloc;

use clap::{Parser, Subcommand};

/// Hysteresis compensation for cable-driven continuum manipulators (Park et al., RA-L 2024).
#[derive(Parser)]
#[command(name = "bowden", version, about, propagate_version = true)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    #[command(flatten)]
    Kinematics(cmd::kin::Command),
    #[command(flatten)]
    Plant(cmd::plant::Command),
    #[command(flatten)]
    Camera(cmd::camera::Command),
    #[command(flatten)]
    Estimator(cmd::estimator::Command),
    #[command(flatten)]
    Compensate(cmd::compensate::Command),
    #[command(flatten)]
    Runtime(cmd::runtime::Command),
    #[command(flatten)]
    Learning(cmd::learning::Command),
    #[command(flatten)]
    Collect(cmd::collect::Command),
    #[command(flatten)]
    Evaluate(cmd::evaluate::Command),
    #[command(flatten)]
    Tune(cmd::tune::Command),
    #[command(flatten)]
    Trajectory(cmd::trajectory::Command),
    #[command(flatten)]
    Shipped(cmd::shipped::Command),
    #[command(flatten)]
    Adapt(cmd::adapt::Command),
    /// Latency and throughput benchmarks printing percentiles.
    Bench {
        #[command(subcommand)]
        what: cmd::bench::Command,
    },
}

fn main() -> std::process::ExitCode {
    // Like every Unix tool: a closed pipe (`bowden ... | head`) ends the process quietly
    // instead of making `println!` panic.
    // SAFETY: resetting a signal disposition to its default before any thread exists.
    unsafe {
        libc::signal(libc::SIGPIPE, libc::SIG_DFL);
    }
    // Before any thread and any Zenoh call: the bridge's network runtime layout (the user's
    // ZENOH_RUNTIME wins).
    #[cfg(feature = "bridge")]
    bowden_bridge::use_bowden_zenoh_runtime();
    let cli = Cli::parse_from(legacy_json_file(std::env::args_os().collect()));
    let result = match cli.command {
        Command::Kinematics(c) => cmd::kin::run(c),
        Command::Plant(c) => cmd::plant::run(c),
        Command::Camera(c) => cmd::camera::run(c),
        Command::Estimator(c) => cmd::estimator::run(c),
        Command::Compensate(c) => cmd::compensate::run(c),
        Command::Runtime(c) => cmd::runtime::run(c),
        Command::Learning(c) => cmd::learning::run(c),
        Command::Collect(c) => cmd::collect::run(c),
        Command::Evaluate(c) => cmd::evaluate::run(c),
        Command::Tune(c) => cmd::tune::run(c),
        Command::Trajectory(c) => cmd::trajectory::run(c),
        Command::Shipped(c) => cmd::shipped::run(c),
        Command::Adapt(c) => cmd::adapt::run(c),
        Command::Bench { what } => cmd::bench::run(what),
    };
    match result {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) if e.downcast_ref::<cmd::ExitCode>().is_some() => {
            let code = e.downcast_ref::<cmd::ExitCode>().map_or(1, |c| c.code);
            eprintln!("bowden: {e}");
            std::process::ExitCode::from(code)
        }
        Err(e) => {
            eprintln!("error: {}", error_line(&e));
            std::process::ExitCode::FAILURE
        }
    }
}

/// One line with the whole context chain (what failed, where, and why), each cause once: an
/// error whose message already quotes its source (thiserror's `#[error("{path}: {source}")]`)
/// is not followed by that source again, so the OS's text appears once.
fn error_line(e: &anyhow::Error) -> String {
    let mut line = String::new();
    for cause in e.chain() {
        let text = cause.to_string();
        if text.is_empty() || line.contains(&text) {
            continue;
        }
        if !line.is_empty() {
            line.push_str(": ");
        }
        line.push_str(&text);
    }
    line
}

/// `--json FILE` was the file form on `evaluate`, `bench ipc` and `bench cycle`; it is
/// `--json-out FILE` now (`--json` alone prints JSON on stdout, as on every command). The old
/// spelling is still understood there, with a note (`bowden bench transfer` runs
/// `evaluate ... --json FILE`). Those commands take no positional argument, so a word after
/// `--json` can only be the old file.
fn legacy_json_file(mut args: Vec<std::ffi::OsString>) -> Vec<std::ffi::OsString> {
    let word = |i: usize| args.get(i).and_then(|a| a.to_str());
    let old_form = matches!(
        (word(1), word(2)),
        (Some("evaluate"), _) | (Some("bench"), Some("ipc" | "cycle"))
    );
    if !old_form {
        return args;
    }
    let mut i = 2;
    while i + 1 < args.len() {
        if args[i] == "--" {
            break;
        }
        let next_is_value = args[i + 1].to_str().is_some_and(|n| !n.starts_with('-'));
        if args[i] == "--json" && next_is_value {
            eprintln!(
                "note: `--json {}` is the old spelling of `--json-out {0}` (`--json` alone prints JSON on stdout)",
                args[i + 1].to_string_lossy()
            );
            args[i] = "--json-out".into();
        }
        i += 1;
    }
    args
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::CommandFactory;

    /// Every option and argument of every (visible) subcommand says what it is.
    #[test]
    fn every_option_has_help() {
        fn walk(c: &clap::Command, path: &str, missing: &mut Vec<String>) {
            for a in c.get_arguments() {
                let id = a.get_id().as_str();
                if a.is_hide_set() || id == "help" || id == "version" {
                    continue;
                }
                if a.get_help().is_none() && a.get_long_help().is_none() {
                    missing.push(format!("{path} --{}", a.get_long().unwrap_or(id)));
                }
            }
            for s in c.get_subcommands() {
                if !s.is_hide_set() {
                    walk(s, &format!("{path} {}", s.get_name()), missing);
                }
            }
        }
        let cli = Cli::command();
        cli.clone().debug_assert();
        let mut missing = Vec::new();
        walk(&cli, "bowden", &mut missing);
        assert!(missing.is_empty(), "options without help: {missing:#?}");
    }

    #[test]
    fn an_error_quoting_its_source_prints_it_once() {
        #[derive(Debug, thiserror::Error)]
        #[error("{path}: cannot read: {source}")]
        struct Io {
            path: String,
            source: std::io::Error,
        }
        let e: anyhow::Error = Io {
            path: "configs/robot.toml".into(),
            source: std::io::Error::from_raw_os_error(2),
        }
        .into();
        let line = error_line(&e.context("loading the robot"));
        assert_eq!(line.matches("os error 2").count(), 1, "{line}");
        assert!(
            line.starts_with("loading the robot: configs/robot.toml: cannot read: "),
            "{line}"
        );
    }

    #[test]
    fn the_old_json_file_form_becomes_json_out() {
        let args = |v: &[&str]| v.iter().map(std::ffi::OsString::from).collect::<Vec<_>>();
        assert_eq!(
            legacy_json_file(args(&["bowden", "evaluate", "--json", "s.json", "--report", "r"])),
            args(&["bowden", "evaluate", "--json-out", "s.json", "--report", "r"])
        );
        for unchanged in [
            &["bowden", "evaluate", "--json", "--report", "r"][..],
            &["bowden", "run", "--json", "configs/sim.toml"],
            &["bowden", "bench", "cycle", "--json"],
        ] {
            assert_eq!(legacy_json_file(args(unchanged)), args(unchanged));
        }
    }
}
