//! The model contract (docs/architecture.md §5): what an ONNX hysteresis model must look like for bowden
//! to load it. The writer of model files (`bowden-learning`, and PyTorch exporters that mirror
//! it) and the loader (`bowden-compensator`) share these names, so they are defined once, here:
//! a model file is an interface between tools as a sample is between processes.
//!
//! - one input, [`INPUT_NAME`], float32, shape `[1, L, J]`: the last L joint vectors in
//!   degrees, oldest first (left zero padding, in degrees, while the history is short);
//! - one output, [`OUTPUT_NAME`], float32, shape `[1, J]`, degrees;
//! - normalisation inside the graph (input and output each with its own mean and SD);
//! - metadata props ([`keys`]): `direction`, `seq_len`, `joints`, `architecture`, `units`
//!   and, for TCNs, `tcn_block`.

use serde::{Deserialize, Serialize};
use std::str::FromStr;
use strum::VariantNames;

/// Name of the graph input: f32 `[1, seq_len, joints]`, degrees, oldest first.
pub const INPUT_NAME: &str = "q_seq_deg";
/// Name of the graph output: f32 `[1, joints]`, degrees.
pub const OUTPUT_NAME: &str = "q_deg";
/// The only accepted value of the `units` metadata prop.
pub const UNITS_DEG: &str = "deg";
/// ONNX operator set the shipped files use (tract supports 9..=18).
pub const RECOMMENDED_OPSET: i64 = 17;
/// Largest number of joints a model may have (the sample types carry `MAX_JOINTS`).
pub const MAX_JOINTS: usize = crate::MAX_JOINTS;

/// Metadata prop keys (`ModelProto.metadata_props`).
pub mod keys {
    /// `forward` (q_cmd history → q_phy) or `inverse` (q_phy history → q_cmd).
    pub const DIRECTION: &str = "direction";
    /// L, the window length, decimal integer; must equal the input's second dimension.
    pub const SEQ_LEN: &str = "seq_len";
    /// J, the number of joints, decimal integer; must equal the input's third dimension.
    pub const JOINTS: &str = "joints";
    /// `fnn`, `lstm`, `tcn` or `tcn-lstm`.
    pub const ARCHITECTURE: &str = "architecture";
    /// Always `deg`.
    pub const UNITS: &str = "units";
    /// TCN block variant, required for `tcn` and `tcn-lstm`: `relu-relu` or `relu-linear`.
    pub const TCN_BLOCK: &str = "tcn_block";
    /// Optional: the support of the training data, `J` comma-separated degrees each (written
    /// by `bowden train`; all four or none). The compensator keeps its candidates inside it.
    /// Per joint: the smallest and largest training command,
    pub const SUPPORT_CMD_MIN: &str = "support_cmd_min_deg";
    pub const SUPPORT_CMD_MAX: &str = "support_cmd_max_deg";
    /// the largest |Δq_cmd| between consecutive training samples (one model step),
    pub const SUPPORT_CMD_STEP_MAX: &str = "support_cmd_step_max_deg";
    /// and the 99.9 % quantile of |q_cmd − q_phy| (the largest command-to-physical gap seen).
    pub const SUPPORT_GAP_MAX: &str = "support_gap_max_deg";
    /// Every key a loader requires for every architecture.
    pub const REQUIRED: [&str; 5] = [DIRECTION, SEQ_LEN, JOINTS, ARCHITECTURE, UNITS];
}

/// A metadata prop that is missing or does not parse.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum ContractError {
    #[error("metadata prop `{key}` is missing")]
    Missing { key: &'static str },
    #[error("metadata prop `{key}` = {value:?} is not valid (expected {expected})")]
    Invalid {
        key: &'static str,
        value: String,
        expected: String,
    },
}

/// The spellings of an enumeration of the contract, as `--help` and errors list them:
/// `forward, inverse`.
pub fn one_of<E: VariantNames>() -> String {
    E::VARIANTS.join(", ")
}

/// Parses a metadata prop's value: an error naming the key and every accepted spelling.
pub fn parse_prop<E: FromStr + VariantNames>(key: &'static str, value: &str) -> Result<E, ContractError> {
    value.parse().map_err(|_| ContractError::Invalid {
        key,
        value: value.to_string(),
        expected: format!("one of: {}", E::VARIANTS.join(" ")),
    })
}

/// What a model predicts from what (paper eq. 17, 18).
#[derive(
    Debug,
    Clone,
    Copy,
    PartialEq,
    Eq,
    Hash,
    PartialOrd,
    Ord,
    Serialize,
    Deserialize,
    strum::EnumString,
    strum::IntoStaticStr,
    strum::Display,
    strum::VariantNames,
    strum::VariantArray,
)]
#[serde(rename_all = "kebab-case")]
#[strum(serialize_all = "kebab-case")]
pub enum Direction {
    /// q_cmd history → q_phy (the plant's response).
    Forward,
    /// q_phy history → q_cmd (the command that produced it).
    Inverse,
}

/// The paper's four candidate architectures (§IV-C).
#[derive(
    Debug,
    Clone,
    Copy,
    PartialEq,
    Eq,
    Hash,
    PartialOrd,
    Ord,
    Serialize,
    Deserialize,
    strum::EnumString,
    strum::IntoStaticStr,
    strum::Display,
    strum::VariantNames,
    strum::VariantArray,
)]
#[serde(rename_all = "kebab-case")]
#[strum(serialize_all = "kebab-case")]
pub enum Architecture {
    Fnn,
    Lstm,
    Tcn,
    TcnLstm,
}

/// Where the ReLUs of a TCN residual block sit (docs/architecture.md §5).
#[derive(
    Debug,
    Clone,
    Copy,
    PartialEq,
    Eq,
    Hash,
    PartialOrd,
    Ord,
    Default,
    Serialize,
    Deserialize,
    strum::EnumString,
    strum::IntoStaticStr,
    strum::Display,
    strum::VariantNames,
    strum::VariantArray,
)]
#[serde(rename_all = "kebab-case")]
#[strum(serialize_all = "kebab-case")]
pub enum TcnBlock {
    /// ReLU between the two convolutions only; the second is linear (the default: a block
    /// can then add negative terms, so the output can fall below the input line).
    #[default]
    ReluLinear,
    /// ReLU after both convolutions, the paper read literally.
    ReluRelu,
}

impl Direction {
    /// The spelling in model files, file names and on the command line.
    pub fn as_str(self) -> &'static str {
        self.into()
    }
}

impl TcnBlock {
    /// The spelling in model files, file names and on the command line.
    pub fn as_str(self) -> &'static str {
        self.into()
    }
}

impl Architecture {
    /// The spelling in model files, file names and on the command line.
    pub fn as_str(self) -> &'static str {
        self.into()
    }

    /// True for architectures that contain a TCN and therefore need `tcn_block`.
    pub fn has_tcn(self) -> bool {
        matches!(self, Architecture::Tcn | Architecture::TcnLstm)
    }

    /// True for architectures that contain an LSTM.
    pub fn has_lstm(self) -> bool {
        matches!(self, Architecture::Lstm | Architecture::TcnLstm)
    }
}

/// The parsed metadata of a contract-following model.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ModelMetadata {
    pub direction: Direction,
    pub seq_len: usize,
    pub joints: usize,
    pub architecture: Architecture,
    /// Present iff the architecture has a TCN.
    pub tcn_block: Option<TcnBlock>,
}

impl ModelMetadata {
    /// The metadata props to write into `ModelProto.metadata_props`, in a fixed order.
    pub fn to_props(&self) -> Vec<(String, String)> {
        let mut v = vec![
            (keys::DIRECTION.to_string(), self.direction.as_str().to_string()),
            (keys::SEQ_LEN.to_string(), self.seq_len.to_string()),
            (keys::JOINTS.to_string(), self.joints.to_string()),
            (keys::ARCHITECTURE.to_string(), self.architecture.as_str().to_string()),
            (keys::UNITS.to_string(), UNITS_DEG.to_string()),
        ];
        if let Some(b) = self.tcn_block {
            v.push((keys::TCN_BLOCK.to_string(), b.as_str().to_string()));
        }
        v
    }

    /// Parses and checks the props; `get(key)` returns the value of a prop if present.
    pub fn from_props<'a>(get: impl Fn(&str) -> Option<&'a str>) -> Result<Self, ContractError> {
        let req = |key: &'static str| get(key).ok_or(ContractError::Missing { key });
        let direction = parse_prop(keys::DIRECTION, req(keys::DIRECTION)?)?;
        let seq_len = parse_count(keys::SEQ_LEN, req(keys::SEQ_LEN)?, 1, 100_000)?;
        let joints = parse_count(keys::JOINTS, req(keys::JOINTS)?, 1, MAX_JOINTS)?;
        let architecture: Architecture = parse_prop(keys::ARCHITECTURE, req(keys::ARCHITECTURE)?)?;
        let units = req(keys::UNITS)?;
        if units != UNITS_DEG {
            return Err(ContractError::Invalid {
                key: keys::UNITS,
                value: units.to_string(),
                expected: "\"deg\"".into(),
            });
        }
        let tcn_block = if architecture.has_tcn() {
            Some(parse_prop(keys::TCN_BLOCK, req(keys::TCN_BLOCK)?)?)
        } else {
            None
        };
        Ok(Self {
            direction,
            seq_len,
            joints,
            architecture,
            tcn_block,
        })
    }
}

/// Where the training data lay, per joint, degrees (see [`keys::SUPPORT_CMD_MIN`]). Fixed
/// arrays: the compensator's step reads it without allocating.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Support {
    pub joints: usize,
    pub cmd_min_deg: [f64; MAX_JOINTS],
    pub cmd_max_deg: [f64; MAX_JOINTS],
    pub cmd_step_max_deg: [f64; MAX_JOINTS],
    pub gap_max_deg: [f64; MAX_JOINTS],
}

impl Support {
    /// Reads the optional support props: `Ok(None)` when there are none, an error naming the
    /// key when some are missing or malformed.
    pub fn from_props<'a>(get: impl Fn(&str) -> Option<&'a str>, joints: usize) -> Result<Option<Self>, ContractError> {
        let all = [
            keys::SUPPORT_CMD_MIN,
            keys::SUPPORT_CMD_MAX,
            keys::SUPPORT_CMD_STEP_MAX,
            keys::SUPPORT_GAP_MAX,
        ];
        if all.iter().all(|k| get(k).is_none()) {
            return Ok(None);
        }
        if joints > MAX_JOINTS {
            return Err(ContractError::Invalid {
                key: keys::SUPPORT_CMD_MIN,
                value: format!("{joints} joints"),
                expected: format!("at most {MAX_JOINTS} joints"),
            });
        }
        let read = |key: &'static str| -> Result<[f64; MAX_JOINTS], ContractError> {
            let s = get(key).ok_or(ContractError::Missing { key })?;
            let bad = || ContractError::Invalid {
                key,
                value: s.to_string(),
                expected: "one finite number of degrees per joint, comma-separated".into(),
            };
            let mut out = [0.0; MAX_JOINTS];
            let mut n = 0;
            for part in s.split(',') {
                let v: f64 = part.trim().parse().map_err(|_| bad())?;
                if n >= joints || !v.is_finite() {
                    return Err(bad());
                }
                out[n] = v;
                n += 1;
            }
            if n != joints {
                return Err(bad());
            }
            Ok(out)
        };
        let s = Self {
            joints,
            cmd_min_deg: read(keys::SUPPORT_CMD_MIN)?,
            cmd_max_deg: read(keys::SUPPORT_CMD_MAX)?,
            cmd_step_max_deg: read(keys::SUPPORT_CMD_STEP_MAX)?,
            gap_max_deg: read(keys::SUPPORT_GAP_MAX)?,
        };
        for k in 0..joints {
            let ok = s.cmd_min_deg[k] <= s.cmd_max_deg[k] && s.cmd_step_max_deg[k] >= 0.0 && s.gap_max_deg[k] >= 0.0;
            if !ok {
                return Err(ContractError::Invalid {
                    key: keys::SUPPORT_CMD_MIN,
                    value: format!("joint {}: min {} max {}", k + 1, s.cmd_min_deg[k], s.cmd_max_deg[k]),
                    expected: "min ≤ max, steps and gaps ≥ 0".into(),
                });
            }
        }
        Ok(Some(s))
    }
}

fn parse_count(key: &'static str, value: &str, min: usize, max: usize) -> Result<usize, ContractError> {
    match value.trim().parse::<usize>() {
        Ok(n) if (min..=max).contains(&n) => Ok(n),
        _ => Err(ContractError::Invalid {
            key,
            value: value.to_string(),
            expected: if key == keys::JOINTS {
                format!("an integer in 1..={MAX_JOINTS} (MAX_JOINTS)")
            } else {
                "a positive integer".into()
            },
        }),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::collections::HashMap;

    #[test]
    fn props_round_trip() {
        let m = ModelMetadata {
            direction: Direction::Inverse,
            seq_len: 80,
            joints: 5,
            architecture: Architecture::Tcn,
            tcn_block: Some(TcnBlock::ReluLinear),
        };
        let props: HashMap<String, String> = m.to_props().into_iter().collect();
        let back = ModelMetadata::from_props(|k| props.get(k).map(|s| s.as_str())).unwrap();
        assert_eq!(back, m);
    }

    #[test]
    fn tcn_needs_block_and_units_must_be_deg() {
        let mut props: HashMap<&str, &str> = [
            ("direction", "forward"),
            ("seq_len", "80"),
            ("joints", "5"),
            ("architecture", "tcn"),
            ("units", "deg"),
        ]
        .into_iter()
        .collect();
        let get = |p: &HashMap<&str, &str>| ModelMetadata::from_props(|k| p.get(k).copied());
        assert_eq!(get(&props), Err(ContractError::Missing { key: keys::TCN_BLOCK }));
        props.insert("tcn_block", "relu-sigmoid");
        assert!(matches!(
            get(&props),
            Err(ContractError::Invalid { key: "tcn_block", .. })
        ));
        props.insert("tcn_block", "relu-relu");
        props.insert("units", "rad");
        assert!(matches!(get(&props), Err(ContractError::Invalid { key: "units", .. })));
        props.insert("units", "deg");
        props.insert("joints", "9");
        assert!(matches!(get(&props), Err(ContractError::Invalid { key: "joints", .. })));
        props.insert("joints", "5");
        assert_eq!(get(&props).unwrap().tcn_block, Some(TcnBlock::ReluRelu));
    }
}
