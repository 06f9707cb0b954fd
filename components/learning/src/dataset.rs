//! The dataset format and the import of external logs.
//!
//! A dataset is a directory with two files:
//! - `dataset.csv`: one row per command, header `t_ns,q_cmd_1..J,q_phy_1..J[,q_true_1..J],valid`
//!   (pandas reads it as is: `pd.read_csv("dataset.csv")`). Angles in degrees; `q_phy` is the
//!   measured (vision) angle, `NaN` where the measurement failed; `q_true` is the simulator's
//!   truth and only present for simulated data; `valid` is 1 when `q_phy` is usable.
//! - `manifest.json`: format, counts, units, seed, config hash, provenance and a hash of the
//!   CSV bytes (a truncated or edited CSV is detected on load).
//!
//! Samples whose measurement is invalid are kept and flagged, never dropped: the command
//! sequence stays contiguous, which the windows of the sequence models need.

use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

use bowden_tables::{ReadOptions, Table, TableError, TableWriter};

use crate::npy::{self, NpyError};

pub const DATASET_CSV: &str = "dataset.csv";
pub const MANIFEST_JSON: &str = "manifest.json";
pub const FORMAT: &str = "bowden-dataset/1";

/// What can be wrong with a dataset or an import. Every variant names the file.
#[derive(Debug, thiserror::Error)]
pub enum DatasetError {
    #[error("{path}: cannot read or write: {source}")]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("{path}: {what}")]
    Manifest { path: PathBuf, what: String },
    #[error("{path}: invalid JSON: {source}")]
    Json {
        path: PathBuf,
        #[source]
        source: serde_json::Error,
    },
    /// The CSV itself: unreadable, malformed, a missing column or a field that is not a
    /// number (with file:line:column).
    #[error(transparent)]
    Table(#[from] TableError),
    #[error("{path}: row {row}, column {column:?}: {value} is not finite; commands must be known for every sample")]
    NotFinite {
        path: PathBuf,
        row: usize,
        column: String,
        value: f64,
    },
    #[error("{path}: the CSV does not match its manifest ({what}); the file was truncated or edited")]
    HashMismatch { path: PathBuf, what: String },
    #[error("{path}: {what}")]
    Shape { path: PathBuf, what: String },
    #[error("joint selection {selection:?} is invalid for {available} joints: {what}")]
    JointSelection {
        selection: Vec<usize>,
        available: usize,
        what: String,
    },
    #[error(transparent)]
    Npy(#[from] NpyError),
}

/// A recorded (or imported) sequence of command / measurement pairs, in degrees.
#[derive(Debug, Clone, PartialEq)]
pub struct Dataset {
    pub joints: usize,
    /// Monotonic time of each sample, ns.
    pub t_ns: Vec<i64>,
    /// `n × joints`, row-major.
    pub q_cmd_deg: Vec<f64>,
    /// `n × joints`, row-major; NaN allowed only where `valid` is false.
    pub q_phy_deg: Vec<f64>,
    /// Simulation truth, `n × joints`.
    pub q_true_deg: Option<Vec<f64>>,
    pub valid: Vec<bool>,
}

/// Units of the columns (always these; written so a reader does not have to guess).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Units {
    pub t: String,
    pub q: String,
}

impl Default for Units {
    fn default() -> Self {
        Self {
            t: "ns".into(),
            q: "deg".into(),
        }
    }
}

/// `manifest.json`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Manifest {
    pub format: String,
    pub joints: usize,
    pub samples: usize,
    pub valid_samples: usize,
    pub has_truth: bool,
    pub units: Units,
    pub columns: Vec<String>,
    /// Seed of the run that made the data (collect), if any.
    pub seed: Option<u64>,
    /// FNV-1a 64 of the configuration that made the data, hex.
    pub config_hash: Option<String>,
    /// `collect`, `import-csv`, `import-npy`, `synthetic`, ...
    pub source: String,
    /// Free-form: the command line, source files and their hashes, options.
    pub provenance: serde_json::Value,
    /// FNV-1a 64 of the CSV bytes, hex.
    pub csv_fnv1a64: String,
}

/// FNV-1a 64-bit hash, hex: a stable content hash without another dependency.
pub fn fnv1a64_hex(bytes: &[u8]) -> String {
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    for &b in bytes {
        h ^= b as u64;
        h = h.wrapping_mul(0x0000_0100_0000_01b3);
    }
    format!("{h:016x}")
}

impl Dataset {
    pub fn len(&self) -> usize {
        self.t_ns.len()
    }

    pub fn is_empty(&self) -> bool {
        self.t_ns.is_empty()
    }

    pub fn valid_count(&self) -> usize {
        self.valid.iter().filter(|&&v| v).count()
    }

    pub fn cmd(&self, i: usize) -> &[f64] {
        &self.q_cmd_deg[i * self.joints..(i + 1) * self.joints]
    }

    pub fn phy(&self, i: usize) -> &[f64] {
        &self.q_phy_deg[i * self.joints..(i + 1) * self.joints]
    }

    /// Checks the invariants; `origin` names the source in errors.
    pub fn validate(&self, origin: &Path) -> Result<(), DatasetError> {
        let n = self.len();
        let j = self.joints;
        let shape = |what: String| DatasetError::Shape {
            path: origin.to_path_buf(),
            what,
        };
        if j == 0 {
            return Err(shape("0 joints".into()));
        }
        if self.q_cmd_deg.len() != n * j || self.q_phy_deg.len() != n * j || self.valid.len() != n {
            return Err(shape(format!(
                "inconsistent lengths: {n} timestamps, {} command values, {} measured values, {} flags for {j} joints",
                self.q_cmd_deg.len(),
                self.q_phy_deg.len(),
                self.valid.len()
            )));
        }
        if let Some(t) = &self.q_true_deg {
            if t.len() != n * j {
                return Err(shape(format!("{} truth values for {n} samples × {j} joints", t.len())));
            }
        }
        for (i, w) in self.t_ns.windows(2).enumerate() {
            if w[1] < w[0] {
                return Err(shape(format!(
                    "t_ns goes backwards at row {}: {} after {}",
                    i + 1,
                    w[1],
                    w[0]
                )));
            }
        }
        for i in 0..n {
            for k in 0..j {
                let c = self.q_cmd_deg[i * j + k];
                if !c.is_finite() {
                    return Err(DatasetError::NotFinite {
                        path: origin.to_path_buf(),
                        row: i,
                        column: format!("q_cmd_{}", k + 1),
                        value: c,
                    });
                }
                let p = self.q_phy_deg[i * j + k];
                if self.valid[i] && !p.is_finite() {
                    return Err(shape(format!(
                        "row {i}: q_phy_{} = {p} but the sample is flagged valid",
                        k + 1
                    )));
                }
            }
        }
        Ok(())
    }

    /// The CSV column names for this dataset.
    pub fn columns(&self) -> Vec<String> {
        let mut cols = vec!["t_ns".to_string()];
        for prefix in ["q_cmd", "q_phy"] {
            cols.extend((1..=self.joints).map(|k| format!("{prefix}_{k}")));
        }
        if self.q_true_deg.is_some() {
            cols.extend((1..=self.joints).map(|k| format!("q_true_{k}")));
        }
        cols.push("valid".into());
        cols
    }

    /// The CSV text. Floats use Rust's shortest round-trip form, so a written dataset reads
    /// back bit for bit and the same data always gives the same bytes.
    pub fn to_csv(&self) -> String {
        let mut csv = TableWriter::new(&self.columns());
        let j = self.joints;
        let mut fields: Vec<String> = Vec::with_capacity(self.columns().len());
        let number = |v: f64| if v.is_nan() { "NaN".to_string() } else { v.to_string() };
        for i in 0..self.len() {
            fields.clear();
            fields.push(self.t_ns[i].to_string());
            fields.extend(self.q_cmd_deg[i * j..(i + 1) * j].iter().map(|&v| number(v)));
            fields.extend(self.q_phy_deg[i * j..(i + 1) * j].iter().map(|&v| number(v)));
            if let Some(t) = &self.q_true_deg {
                fields.extend(t[i * j..(i + 1) * j].iter().map(|&v| number(v)));
            }
            fields.push(if self.valid[i] { "1" } else { "0" }.to_string());
            csv.row(&fields);
        }
        csv.into_string()
    }

    /// Writes `dataset.csv` and `manifest.json` into `dir` (created if needed).
    pub fn write_dir(
        &self,
        dir: &Path,
        source: &str,
        seed: Option<u64>,
        config_hash: Option<String>,
        provenance: serde_json::Value,
    ) -> Result<Manifest, DatasetError> {
        self.validate(dir)?;
        std::fs::create_dir_all(dir).map_err(|source| DatasetError::Io {
            path: dir.to_path_buf(),
            source,
        })?;
        let csv = self.to_csv();
        let manifest = Manifest {
            format: FORMAT.into(),
            joints: self.joints,
            samples: self.len(),
            valid_samples: self.valid_count(),
            has_truth: self.q_true_deg.is_some(),
            units: Units::default(),
            columns: self.columns(),
            seed,
            config_hash,
            source: source.into(),
            provenance,
            csv_fnv1a64: fnv1a64_hex(csv.as_bytes()),
        };
        let csv_path = dir.join(DATASET_CSV);
        std::fs::write(&csv_path, csv.as_bytes()).map_err(|source| DatasetError::Io { path: csv_path, source })?;
        let man_path = dir.join(MANIFEST_JSON);
        let text = serde_json::to_string_pretty(&manifest).map_err(|source| DatasetError::Json {
            path: man_path.clone(),
            source,
        })?;
        std::fs::write(&man_path, text + "\n").map_err(|source| DatasetError::Io { path: man_path, source })?;
        Ok(manifest)
    }

    /// Reads a dataset directory written by [`Dataset::write_dir`], checking the CSV against
    /// its manifest.
    pub fn read_dir(dir: &Path) -> Result<(Dataset, Manifest), DatasetError> {
        let man_path = dir.join(MANIFEST_JSON);
        let text = std::fs::read_to_string(&man_path).map_err(|source| DatasetError::Io {
            path: man_path.clone(),
            source,
        })?;
        let manifest: Manifest = serde_json::from_str(&text).map_err(|source| DatasetError::Json {
            path: man_path.clone(),
            source,
        })?;
        if manifest.format != FORMAT {
            return Err(DatasetError::Manifest {
                path: man_path,
                what: format!("format {:?} is not {FORMAT:?}", manifest.format),
            });
        }
        let csv_path = dir.join(DATASET_CSV);
        let bytes = std::fs::read(&csv_path).map_err(|source| DatasetError::Io {
            path: csv_path.clone(),
            source,
        })?;
        let hash = fnv1a64_hex(&bytes);
        if hash != manifest.csv_fnv1a64 {
            return Err(DatasetError::HashMismatch {
                path: csv_path,
                what: format!("FNV-1a {hash} ≠ manifest {}", manifest.csv_fnv1a64),
            });
        }
        let table = Table::parse(&bytes, &csv_path, ReadOptions::default())?;
        let opts = ImportOptions::default();
        let ds = to_dataset(&table, &opts)?;
        if ds.joints != manifest.joints || ds.len() != manifest.samples || ds.q_true_deg.is_some() != manifest.has_truth
        {
            return Err(DatasetError::Manifest {
                path: man_path,
                what: format!(
                    "says {} joints, {} samples, truth {}; the CSV has {} joints, {} samples, truth {}",
                    manifest.joints,
                    manifest.samples,
                    manifest.has_truth,
                    ds.joints,
                    ds.len(),
                    ds.q_true_deg.is_some()
                ),
            });
        }
        Ok((ds, manifest))
    }
}

/// Angle unit of imported data.
#[derive(
    Debug,
    Clone,
    Copy,
    PartialEq,
    Eq,
    Default,
    Serialize,
    Deserialize,
    strum::EnumString,
    strum::IntoStaticStr,
    strum::Display,
    strum::VariantNames,
)]
#[serde(rename_all = "lowercase")]
#[strum(serialize_all = "lowercase")]
pub enum AngleUnit {
    #[default]
    Deg,
    Rad,
}

/// How to read external data.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ImportOptions {
    pub unit: AngleUnit,
    /// 1-based joints to keep, in this order (all when `None`).
    pub joints: Option<Vec<usize>>,
    /// CSV: command columns (default: every `q_cmd_<k>` column, by k).
    pub cmd_columns: Option<Vec<String>>,
    /// CSV: measured columns (default: every `q_phy_<k>` column, by k).
    pub phy_columns: Option<Vec<String>>,
    /// CSV: timestamp column in ns (default `t_ns` when present).
    pub time_column: Option<String>,
    /// CSV: validity column, nonzero = valid (default `valid` when present).
    pub valid_column: Option<String>,
    /// Sample period used to make timestamps when the data has none, ns.
    pub period_ns: i64,
}

impl Default for ImportOptions {
    fn default() -> Self {
        Self {
            unit: AngleUnit::Deg,
            joints: None,
            cmd_columns: None,
            phy_columns: None,
            time_column: None,
            valid_column: None,
            period_ns: 500_000_000,
        }
    }
}

impl ImportOptions {
    fn scale(&self) -> f64 {
        match self.unit {
            AngleUnit::Deg => 1.0,
            AngleUnit::Rad => 180.0 / std::f64::consts::PI,
        }
    }

    /// Maps a 1-based selection onto `available` columns (all when no selection).
    fn select(&self, available: usize) -> Result<Vec<usize>, DatasetError> {
        match &self.joints {
            None => Ok((0..available).collect()),
            Some(sel) => {
                let err = |what: String| DatasetError::JointSelection {
                    selection: sel.clone(),
                    available,
                    what,
                };
                if sel.is_empty() {
                    return Err(err("empty".into()));
                }
                let mut out = Vec::with_capacity(sel.len());
                for &k in sel {
                    if k == 0 || k > available {
                        return Err(err(format!("joint {k} is not in 1..={available}")));
                    }
                    if out.contains(&(k - 1)) {
                        return Err(err(format!("joint {k} is selected twice")));
                    }
                    out.push(k - 1);
                }
                Ok(out)
            }
        }
    }
}

/// The dataset in a table with named columns (a written dataset or an imported log).
fn to_dataset(table: &Table, opts: &ImportOptions) -> Result<Dataset, DatasetError> {
    let path = table.path.as_path();
    let named = |list: &Option<Vec<String>>, prefix: &str| -> Result<Vec<usize>, DatasetError> {
        let names = match list {
            Some(l) => l.clone(),
            None => table.numbered(&format!("{prefix}_")),
        };
        if names.is_empty() {
            // Names the first column the default layout expects.
            table.column(&format!("{prefix}_1"))?;
        }
        Ok(table.columns(&names)?)
    };
    let cmd_cols = named(&opts.cmd_columns, "q_cmd")?;
    let phy_cols = named(&opts.phy_columns, "q_phy")?;
    if cmd_cols.len() != phy_cols.len() {
        return Err(DatasetError::Shape {
            path: path.to_path_buf(),
            what: format!(
                "{} command columns but {} measured columns",
                cmd_cols.len(),
                phy_cols.len()
            ),
        });
    }
    let true_names = table.numbered("q_true_");
    let true_cols = if opts.cmd_columns.is_none() && true_names.len() == cmd_cols.len() {
        Some(table.columns(&true_names)?)
    } else {
        None
    };
    let time_col = match &opts.time_column {
        Some(n) => Some(table.column(n)?),
        None => table.find("t_ns"),
    };
    let valid_col = match &opts.valid_column {
        Some(n) => Some(table.column(n)?),
        None => table.find("valid"),
    };
    let sel = opts.select(cmd_cols.len())?;
    let scale = opts.scale();
    let n = table.rows.len();
    let j = sel.len();
    let mut ds = Dataset {
        joints: j,
        t_ns: Vec::with_capacity(n),
        q_cmd_deg: Vec::with_capacity(n * j),
        q_phy_deg: Vec::with_capacity(n * j),
        q_true_deg: true_cols.as_ref().map(|_| Vec::with_capacity(n * j)),
        valid: Vec::with_capacity(n),
    };
    for r in 0..n {
        let t = match time_col {
            Some(c) => table.i64(r, c)?,
            None => r as i64 * opts.period_ns,
        };
        ds.t_ns.push(t);
        let mut ok = match valid_col {
            Some(c) => {
                let v = table.f64_or_nan(r, c)?;
                v.is_finite() && v != 0.0
            }
            None => true,
        };
        for &k in &sel {
            ds.q_cmd_deg.push(table.f64_or_nan(r, cmd_cols[k])? * scale);
        }
        for &k in &sel {
            let v = table.f64_or_nan(r, phy_cols[k])? * scale;
            // A missing measurement in a log marks the sample invalid; it is kept.
            ok &= v.is_finite();
            ds.q_phy_deg.push(v);
        }
        if let (Some(cols), Some(out)) = (&true_cols, ds.q_true_deg.as_mut()) {
            for &k in &sel {
                out.push(table.f64_or_nan(r, cols[k])? * scale);
            }
        }
        ds.valid.push(ok);
    }
    ds.validate(path)?;
    Ok(ds)
}

/// Reads an external CSV log with named columns.
pub fn import_csv(path: &Path, opts: &ImportOptions) -> Result<Dataset, DatasetError> {
    let table = Table::read(path, ReadOptions::default())?;
    to_dataset(&table, opts)
}

/// Reads a pair of `.npy` arrays: commands and measurements, each `N × J` (a 1-D array is
/// one joint). Non-finite measurements mark their sample invalid; non-finite commands are
/// an error.
pub fn import_npy(cmd_path: &Path, phy_path: &Path, opts: &ImportOptions) -> Result<Dataset, DatasetError> {
    let cmd = npy::read_npy(cmd_path)?;
    let phy = npy::read_npy(phy_path)?;
    if (cmd.rows, cmd.cols) != (phy.rows, phy.cols) {
        return Err(DatasetError::Shape {
            path: phy_path.to_path_buf(),
            what: format!(
                "shape ({}, {}) differs from the command array {} ({}, {})",
                phy.rows,
                phy.cols,
                cmd_path.display(),
                cmd.rows,
                cmd.cols
            ),
        });
    }
    if cmd.rows == 0 {
        return Err(DatasetError::Shape {
            path: cmd_path.to_path_buf(),
            what: "no rows".into(),
        });
    }
    let sel = opts.select(cmd.cols)?;
    let scale = opts.scale();
    let n = cmd.rows;
    let j = sel.len();
    let mut ds = Dataset {
        joints: j,
        t_ns: (0..n as i64).map(|i| i * opts.period_ns).collect(),
        q_cmd_deg: Vec::with_capacity(n * j),
        q_phy_deg: Vec::with_capacity(n * j),
        q_true_deg: None,
        valid: Vec::with_capacity(n),
    };
    for r in 0..n {
        let mut ok = true;
        for &k in &sel {
            let c = cmd.get(r, k) * scale;
            if !c.is_finite() {
                return Err(DatasetError::NotFinite {
                    path: cmd_path.to_path_buf(),
                    row: r,
                    column: format!("joint {}", k + 1),
                    value: c,
                });
            }
            ds.q_cmd_deg.push(c);
            let p = phy.get(r, k) * scale;
            ok &= p.is_finite();
            ds.q_phy_deg.push(p);
        }
        ds.valid.push(ok);
    }
    ds.validate(cmd_path)?;
    Ok(ds)
}
