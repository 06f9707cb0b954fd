//! `bowden bench transfer`: the command line of the transfer study, whose orchestration lives
//! in `bowden-studies` (components/studies).

use anyhow::{Context, Result};
use bowden_studies::transfer::{TransferOptions, UnitSet};
use clap::{Args, Subcommand};
use std::path::PathBuf;

#[derive(Subcommand)]
pub enum BenchCommand {
    /// Transfer to unseen units (issue #12): collect, train, tune and evaluate each unit of
    /// several plant families exactly as a user would (the `bowden` commands, as subprocesses;
    /// parallel, resumable), then the error reduction per unit, trajectory and controller, by
    /// vision and truth, as Markdown, JSON and SVG.
    Transfer(TransferArgs),
}

#[derive(Args, Debug)]
pub struct TransferArgs {
    /// Families, units and the recipe.
    #[arg(long, default_value = "configs/transfer.toml")]
    pub config: PathBuf,
    /// Output directory: transfer.md, transfer.json, transfer.svg and units/FAMILY/unit-N/.
    #[arg(long, default_value = "out/transfer")]
    pub out: PathBuf,
    /// Units run at once; each training gets cores / jobs threads (recipe.threads overrides).
    /// Why 2 suits 2 cores: docs/results/transfer/README.md.
    #[arg(long, default_value_t = 2)]
    pub jobs: usize,
    /// Which units to run: the held-out ones (the results), the tuning ones, or all.
    #[arg(long, default_value = "heldout", value_parser = super::typed::<UnitSet>(), ignore_case = true)]
    pub units: UnitSet,
    /// Only these families (names from the config, comma-separated).
    #[arg(long, value_delimiter = ',')]
    pub families: Vec<String>,
    /// At most N units, taken in turn from each family.
    #[arg(long)]
    pub max_units: Option<usize>,
    /// A tiny recipe for tests: 30 configurations, 2 epochs, L = 10, 1 repeat, 8 points per
    /// trajectory. Its numbers say nothing about transfer; use another --out.
    #[arg(long)]
    pub quick: bool,
    /// Print the selected units instead of running them: index, unit, role, directory,
    /// fingerprint (recipe and the controller files it names, seed, unit plant, version) and
    /// status in --out; --json for JSON.
    #[arg(long, conflicts_with_all = ["shard", "merge"])]
    pub plan: bool,
    /// Run only shard I of N of the selected units: those whose index (see --plan) ≡ I (mod N),
    /// e.g. "$SLURM_ARRAY_TASK_ID/$SLURM_ARRAY_TASK_COUNT"; each unit leaves UNIT/outcome.json,
    /// no report is written (see --merge). Exits non-zero if one of its units failed.
    #[arg(long, value_name = "I/N", conflicts_with = "merge")]
    pub shard: Option<String>,
    /// Run nothing: read every selected unit's outcome.json (refusing missing ones and ones of
    /// another config, by name) and write transfer.md, transfer.json and transfer.svg.
    #[arg(long)]
    pub merge: bool,
    /// With --plan: print the plan as JSON on stdout instead of the table.
    #[arg(long, requires = "plan")]
    pub json: bool,
    /// With --plan: also write the plan JSON to FILE.
    #[arg(long, value_name = "FILE", requires = "plan")]
    pub json_out: Option<PathBuf>,
    /// Overwrite --json-out if it exists.
    #[arg(long)]
    pub force: bool,
}

pub fn bench(c: BenchCommand) -> Result<()> {
    let BenchCommand::Transfer(a) = c;
    if a.plan {
        super::refuse_overwrite(a.json_out.as_slice(), a.force, "--json-out")?;
    }
    // The config by bowden's resolution order (docs/architecture.md §1): the shipped one is
    // found outside a checkout too, and then the built-in copy is the project the steps run in.
    let found = crate::home::resolve(&a.config)?;
    let builtin_root = match found.origin {
        crate::home::Origin::Builtin => crate::home::builtin_root().ok().map(PathBuf::from),
        crate::home::Origin::Given | crate::home::Origin::Home => None,
    };
    bowden_studies::transfer::transfer(TransferOptions {
        config: a.config,
        config_file: found.path,
        builtin_root,
        exe: std::env::current_exe().context("locating the bowden executable")?,
        out: a.out,
        jobs: a.jobs,
        units: a.units,
        families: a.families,
        max_units: a.max_units,
        quick: a.quick,
        plan: a.plan,
        shard: a.shard,
        merge: a.merge,
        json: a.json,
        json_out: a.json_out,
    })
}
