//! `bowden bench ...`: each concern contributes its benchmarks here.

use clap::Subcommand;

#[derive(Subcommand)]
pub enum Command {
    #[command(flatten)]
    Camera(super::camera::BenchCommand),
    #[command(flatten)]
    Compensate(super::compensate::BenchCommand),
    #[command(flatten)]
    Runtime(super::runtime::BenchCommand),
    #[command(flatten)]
    Learning(super::learning::BenchCommand),
    #[command(flatten)]
    Transfer(super::transfer::BenchCommand),
    #[command(flatten)]
    Swap(super::adapt::BenchCommand),
    #[command(flatten)]
    Bridge(super::bridge::BenchCommand),
}

pub fn run(c: Command) -> anyhow::Result<()> {
    match c {
        Command::Camera(c) => super::camera::bench(c),
        Command::Compensate(c) => super::compensate::bench(c),
        Command::Runtime(c) => super::runtime::bench(c),
        Command::Learning(c) => super::learning::bench(c),
        Command::Transfer(c) => super::transfer::bench(c),
        Command::Swap(c) => super::adapt::bench(c),
        Command::Bridge(c) => super::bridge::bench(c),
    }
}
