//! Subcommands, one module per concern (and per owner).

pub mod adapt;
pub mod bench;
#[cfg(feature = "bridge")]
pub mod bridge;
pub mod camera;
pub mod collect;
pub mod compensate;
pub mod estimator;
pub mod evaluate;
pub mod kin;
pub mod learning;
pub mod learning_bench;
pub mod plant;
pub mod runtime;
pub mod runtime_bench;
pub mod shipped;
pub mod sweep;
pub mod trajectory;
pub mod transfer;
pub mod tune;

// Node glue for `bowden node ...` lives in `crate::nodes`.

use anyhow::{bail, Result};
use std::path::{Path, PathBuf};

/// Conventions every subcommand follows (README, "Conventions"):
///
/// - `--json` prints JSON on stdout instead of the human-readable output; `--json-out FILE`
///   also writes it to FILE;
/// - outputs that exist are not overwritten without `--force` ([`refuse_overwrite`]);
/// - enumerated values are listed in `--help` and matched case-insensitively ([`choice`]);
/// - shipped files are found by `crate::home`'s resolution order.
///
/// An option taking one of `values`, matched case-insensitively (with `ignore_case = true` on
/// the argument) and returned lower-case; `--help` lists them.
pub fn choice(values: &'static [&'static str]) -> impl clap::builder::TypedValueParser<Value = String> {
    clap::builder::TypedValueParser::map(clap::builder::PossibleValuesParser::new(values), |s: String| {
        s.to_ascii_lowercase()
    })
}

/// An option taking one of the names of the enumeration `E` (strum's spellings), matched
/// case-insensitively (with `ignore_case = true` on the argument); `--help` lists them and the
/// command receives the typed value.
pub fn typed<E>() -> impl clap::builder::TypedValueParser<Value = E>
where
    E: std::str::FromStr + strum::VariantNames + Clone + Send + Sync + 'static,
{
    typed_of::<E>(E::VARIANTS)
}

/// [`typed`] restricted to the variants spelled in `names` (e.g. the refinement modes of
/// `Mode`, without `uncalibrated`).
pub fn typed_of<E>(names: &'static [&'static str]) -> impl clap::builder::TypedValueParser<Value = E>
where
    E: std::str::FromStr + Clone + Send + Sync + 'static,
{
    clap::builder::TypedValueParser::try_map(clap::builder::PossibleValuesParser::new(names), |s: String| {
        // PossibleValuesParser matched one of `names`, all lower-case spellings of E.
        s.to_ascii_lowercase()
            .parse::<E>()
            .map_err(|_| format!("`{s}` is not one of: {}", names.join(", ")))
    })
}

/// Refuses to overwrite an earlier result: an error naming the first of `files` that exists,
/// the flag that allows it and the option that chooses another place (`flag`, e.g. `--out`).
pub fn refuse_overwrite(files: &[PathBuf], force: bool, flag: &str) -> Result<()> {
    if force {
        return Ok(());
    }
    if let Some(f) = files.iter().find(|f| f.exists()) {
        bail!(
            "{}: exists (an earlier run's output); pass --force to overwrite it, or choose another {flag}",
            f.display()
        );
    }
    Ok(())
}

/// A dataset directory argument (`--data`): the common mistake of naming its `dataset.csv` or
/// `manifest.json` gets a hint instead of "Not a directory".
pub fn dataset_dir<'a>(flag: &str, p: &'a Path) -> Result<&'a Path> {
    if p.is_file() {
        let parent = p
            .parent()
            .filter(|d| !d.as_os_str().is_empty())
            .unwrap_or(Path::new("."));
        bail!(
            "{flag} {}: expected the dataset DIRECTORY (containing dataset.csv and manifest.json); you gave \
             the file{}",
            p.display(),
            if p.file_name()
                .is_some_and(|n| n == "dataset.csv" || n == "manifest.json")
            {
                format!(": use {flag} {}", parent.display())
            } else {
                String::new()
            }
        );
    }
    Ok(p)
}

/// An output dataset directory (`--out` of `collect`, `import`): not an existing file, and
/// no dataset in it unless `force`.
pub fn dataset_out(p: &Path, force: bool) -> Result<()> {
    if p.is_file() {
        bail!(
            "--out {}: expected a DIRECTORY to write dataset.csv and manifest.json into; this is a file",
            p.display()
        );
    }
    refuse_overwrite(&[p.join("dataset.csv"), p.join("manifest.json")], force, "--out")
}

/// A command that ran to its end but whose result is a documented non-zero exit code (`bowden
/// run`: a fault recovered, not recovered, an e-stop); what it found is already printed.
#[derive(Debug, thiserror::Error)]
#[error("{why} (exit code {code})")]
pub struct ExitCode {
    pub code: u8,
    pub why: String,
}
