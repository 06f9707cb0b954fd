//! `bowden`: the command-line front end and launcher. Each subcommand is a few lines over
//! a component crate; the subcommands of one concern live in one module of `cmd/`.

mod cmd;
mod nodes;

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
    let cli = Cli::parse();
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
        Command::Bench { what } => cmd::bench::run(what),
    };
    match result {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            // One line, with the whole context chain: what failed, where, and why.
            eprintln!("error: {e:#}");
            std::process::ExitCode::FAILURE
        }
    }
}
