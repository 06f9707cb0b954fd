//! `bowden shipped`: where the shipped configs and models are found (the resolution order of
//! `crate::home`, which every command uses), the built-in files, and a copy of them to edit.

use crate::home::{self, SHIPPED};
use anyhow::{Context, Result};
use clap::{Args, Subcommand};
use std::path::PathBuf;

#[derive(Subcommand)]
pub enum Command {
    /// Where shipped files (configs/**, models/**) are found: the order every command looks in,
    /// and the files built into this binary. `--extract DIR` copies them out to edit; point
    /// $BOWDEN_HOME at DIR to use the edited copy from anywhere.
    Shipped(ShippedArgs),
}

#[derive(Args)]
pub struct ShippedArgs {
    /// Copy the built-in configs/ and models/ into DIR (created if missing).
    #[arg(long, value_name = "DIR")]
    extract: Option<PathBuf>,
    /// With --extract: overwrite files in DIR that differ from the built-in ones.
    #[arg(long)]
    force: bool,
    /// Print JSON on stdout instead of the text.
    #[arg(long)]
    json: bool,
}

pub fn run(c: Command) -> Result<()> {
    let Command::Shipped(a) = c;
    if let Some(dir) = &a.extract {
        let differing: Vec<PathBuf> = SHIPPED
            .iter()
            .map(|(rel, bytes)| (dir.join(rel), bytes))
            .filter(|(p, bytes)| p.exists() && std::fs::read(p).ok().as_deref() != Some(**bytes))
            .map(|(p, _)| p)
            .collect();
        super::refuse_overwrite(&differing, a.force, "DIR")?;
        home::extract(dir).with_context(|| format!("--extract {}", dir.display()))?;
        eprintln!(
            "{}: {} files (configs/, models/); use them from anywhere with {}={}",
            dir.display(),
            SHIPPED.len(),
            home::HOME_ENV,
            std::fs::canonicalize(dir).unwrap_or_else(|_| dir.clone()).display()
        );
        return Ok(());
    }
    let cwd = std::env::current_dir().context("the working directory")?;
    let home_dir = std::env::var_os(home::HOME_ENV)
        .filter(|v| !v.is_empty())
        .map(PathBuf::from);
    let builtin = home::builtin_root()?;
    let bytes: usize = SHIPPED.iter().map(|(_, b)| b.len()).sum();
    if a.json {
        let files: Vec<serde_json::Value> = SHIPPED
            .iter()
            .map(|(rel, b)| serde_json::json!({"path": rel, "bytes": b.len()}))
            .collect();
        println!(
            "{}",
            serde_json::to_string_pretty(&serde_json::json!({
                "order": ["as given (absolute, or relative to the working directory)", "$BOWDEN_HOME", "built-in"],
                "working_directory": cwd,
                "bowden_home": home_dir,
                "builtin_extracted_to": builtin,
                "builtin_files": files,
            }))?
        );
        return Ok(());
    }
    println!("Every command looks for a config, trajectory or model file it is given (or defaults to) in:");
    println!(
        "  1. the path as given: absolute, or relative to the working directory ({})",
        cwd.display()
    );
    match &home_dir {
        Some(h) => println!("  2. under ${}: {}", home::HOME_ENV, h.display()),
        None => println!("  2. under ${} (unset)", home::HOME_ENV),
    }
    println!(
        "  3. the {} files built into this binary ({:.1} MB), extracted to {}",
        SHIPPED.len(),
        bytes as f64 / 1e6,
        builtin.display()
    );
    println!(
        "Paths inside a config file are relative to that file, so a file's neighbours come from the same place.\n"
    );
    println!("Built-in files:");
    for (rel, b) in SHIPPED {
        println!("  {rel:<50} {:>9} B", b.len());
    }
    Ok(())
}
