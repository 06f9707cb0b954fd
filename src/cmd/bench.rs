//! `bowden bench ...`: each concern contributes its benchmarks here.

use clap::Subcommand;

#[derive(Subcommand)]
pub enum Command {
    #[command(flatten)]
    Camera(super::camera::BenchCommand),
    #[command(flatten)]
    Compensate(super::compensate::BenchCommand),
    #[command(flatten)]
    Runtime(super::runtime_bench::BenchCommand),
    #[command(flatten)]
    Learning(super::learning_bench::BenchCommand),
    #[command(flatten)]
    Transfer(super::transfer::BenchCommand),
    #[command(flatten)]
    Swap(super::adapt::BenchCommand),
    #[cfg(feature = "bridge")]
    #[command(flatten)]
    Bridge(super::bridge::BenchCommand),
    /// One hop over the Zenoh bridge: needs a binary built with `--features bridge`.
    #[cfg(not(feature = "bridge"))]
    Bridge {
        #[arg(trailing_var_arg = true, allow_hyphen_values = true, hide = true)]
        args: Vec<String>,
    },
}

pub fn run(c: Command) -> anyhow::Result<()> {
    match c {
        Command::Camera(c) => super::camera::bench(c),
        Command::Compensate(c) => super::compensate::bench(c),
        Command::Runtime(c) => super::runtime_bench::bench(c),
        Command::Learning(c) => super::learning_bench::bench(c),
        Command::Transfer(c) => super::transfer::bench(c),
        Command::Swap(c) => super::adapt::bench(c),
        #[cfg(feature = "bridge")]
        Command::Bridge(c) => super::bridge::bench(c),
        #[cfg(not(feature = "bridge"))]
        Command::Bridge { .. } => anyhow::bail!("bench bridge: {}", bowden::registry::NO_BRIDGE),
    }
}
