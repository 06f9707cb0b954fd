//! `--plan`, `--shard` and `--merge`: unit fingerprints and outcome files.

use super::*;

/// `UNIT/outcome.json`: what a unit's run reported, for `--merge` to read back.
#[derive(Debug, Serialize, Deserialize)]
pub(super) struct OutcomeFile {
    pub(super) format: String,
    /// [`unit_fingerprint`] of the run that wrote it.
    pub(super) fingerprint: String,
    pub(super) outcome: UnitOutcome,
}

pub(super) const OUTCOME_FORMAT: &str = "bowden-transfer-unit/1";

pub(super) fn outcome_path(p: &UnitPlan) -> PathBuf {
    p.dir.join("outcome.json")
}

/// FNV-1a 64 (hex) of what a unit's outcome depends on: the bowden version, the seed, the
/// recipe and the files it names (`recipe_files`: the base controller's and the feedback
/// config's text), the family, the unit's plant text and its role. Like the stamps, not the
/// binary itself: after changing the code, use another `--out`.
pub(super) fn unit_fingerprint(
    recipe: &Recipe,
    recipe_files: &str,
    seed: u64,
    fam: &Family,
    p: &UnitPlan,
) -> Result<String> {
    #[derive(Serialize)]
    struct Identity<'a> {
        version: &'a str,
        seed: u64,
        recipe: &'a Recipe,
        recipe_files: &'a str,
        family: &'a str,
        plant: &'a str,
        unit: u64,
        role: Role,
    }
    // A plant file that cannot be read fails its unit at the `plant` step, not the plan.
    let plant = unit_plant_text(&fam.plant, p.unit).unwrap_or_else(|e| format!("unreadable: {e:#}"));
    let id = Identity {
        version: env!("CARGO_PKG_VERSION"),
        seed,
        recipe,
        recipe_files,
        family: &fam.name,
        plant: &plant,
        unit: p.unit,
        role: p.role,
    };
    Ok(fnv1a64_hex(&serde_json::to_vec(&id)?))
}

pub(super) enum OutcomeState {
    Done(Box<UnitOutcome>),
    Missing,
    /// There, but not a complete outcome of this unit and config: why.
    Bad(String),
}

pub(super) fn read_outcome(p: &UnitPlan, fingerprint: &str) -> OutcomeState {
    let text = match std::fs::read_to_string(outcome_path(p)) {
        Ok(t) => t,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return OutcomeState::Missing,
        Err(e) => return OutcomeState::Bad(format!("cannot read: {e}")),
    };
    match serde_json::from_str::<OutcomeFile>(&text) {
        Err(e) => OutcomeState::Bad(format!("not a complete outcome file ({e})")),
        Ok(f) if f.format != OUTCOME_FORMAT => {
            OutcomeState::Bad(format!("format {:?}, expected {OUTCOME_FORMAT:?}", f.format))
        }
        Ok(f) if f.fingerprint != fingerprint => OutcomeState::Bad(format!(
            "made with another config, recipe, seed, plant or bowden version (fingerprint {} ≠ {fingerprint})",
            f.fingerprint
        )),
        Ok(f) => OutcomeState::Done(Box::new(f.outcome)),
    }
}

/// Every planned unit's outcome, or an error listing the missing ones by index and naming each
/// file that is not this plan's. A finished unit's rows are read again from its evaluation's
/// summary.json, as the run that made them did: serde_json's float parsing is not exact to the
/// last bit, so rows read back from outcome.json could differ from a local run's in the 17th
/// digit.
pub(super) fn load_outcomes(plans: &[UnitPlan], fingerprints: &[String], recipe: &Recipe) -> Result<Vec<UnitOutcome>> {
    let (mut units, mut missing, mut bad) = (Vec::new(), Vec::new(), Vec::new());
    for (k, (p, fp)) in plans.iter().zip(fingerprints).enumerate() {
        match read_outcome(p, fp) {
            OutcomeState::Done(mut u) if u.failure.is_none() => match unit_rows(&p.dir, recipe) {
                Ok(rows) => {
                    u.rows = rows;
                    units.push(*u);
                }
                Err(e) => bad.push(format!("{} (unit {k}): {e:#}", outcome_path(p).display())),
            },
            OutcomeState::Done(u) => units.push(*u),
            OutcomeState::Missing => missing.push(k.to_string()),
            OutcomeState::Bad(why) => bad.push(format!("{} (unit {k}): {why}", outcome_path(p).display())),
        }
    }
    let mut parts = Vec::new();
    if !missing.is_empty() {
        parts.push(format!(
            "{} of {} units have no outcome.json (indices {}; rerun their shards)",
            missing.len(),
            plans.len(),
            missing.join(", ")
        ));
    }
    if !bad.is_empty() {
        parts.push(format!(
            "{} outcome file(s) not from this plan (rerun their shards, which replace them):\n  {}",
            bad.len(),
            bad.join("\n  ")
        ));
    }
    if !parts.is_empty() {
        bail!("cannot merge: {}", parts.join("; "));
    }
    Ok(units)
}

pub(super) fn print_unit_plan(
    a: &TransferOptions,
    plans: &[UnitPlan],
    families: &[Family],
    fingerprints: &[String],
) -> Result<()> {
    let units: Vec<serde_json::Value> = plans
        .iter()
        .zip(fingerprints)
        .enumerate()
        .map(|(k, (p, fp))| {
            let status = match read_outcome(p, fp) {
                OutcomeState::Done(u) if u.failure.is_some() => "failed".to_string(),
                OutcomeState::Done(_) => "done".to_string(),
                OutcomeState::Missing => "pending".to_string(),
                OutcomeState::Bad(why) => format!("redo: {why}"),
            };
            serde_json::json!({
                "index": k,
                "family": families[p.family].name,
                "unit": p.unit,
                "role": p.role,
                "dir": p.dir,
                "fingerprint": fp,
                "status": status,
            })
        })
        .collect();
    let plan = serde_json::json!({
        "format": "bowden-transfer-plan/1",
        "sharding": SHARDING.replace("runs", "units"),
        "units": units,
    });
    let json = serde_json::to_string_pretty(&plan)?;
    if let Some(j) = &a.json_out {
        std::fs::write(j, format!("{json}\n")).with_context(|| format!("{}", j.display()))?;
    }
    if a.json {
        println!("{json}");
        return Ok(());
    }
    println!(
        "bench transfer plan: {} units; sharding {}",
        plans.len(),
        SHARDING.replace("runs", "units")
    );
    println!(
        "{:>5}  {:32}  {:8}  {:16}  status",
        "index", "unit", "role", "fingerprint"
    );
    for (k, (u, p)) in units.iter().zip(plans).enumerate() {
        println!(
            "{k:>5}  {:32}  {:8}  {:16}  {}",
            format!("{}/unit-{}", families[p.family].name, p.unit),
            p.role.label(),
            u["fingerprint"].as_str().unwrap_or(""),
            u["status"].as_str().unwrap_or("")
        );
    }
    Ok(())
}
