//! The support of the training data: where the commands of the dataset a model learned from
//! lie, how far they moved in one model step, and how far the physical angles were from the
//! commands. Written into the model file at `train` (ONNX metadata props), read by the
//! compensator, which keeps every candidate command inside it: a learned model is only
//! trustworthy where it was trained (docs/architecture.md, "Safe refinement").
//!
//! The prop names are the model contract's (`bowden_interfaces::model::keys::SUPPORT_*`); the
//! compensator reads them with `bowden_interfaces::model::Support`.

use serde::{Deserialize, Serialize};

use crate::arch::Direction;
use crate::windows::WindowSet;

use bowden_interfaces::model::keys::{
    SUPPORT_CMD_MAX as KEY_CMD_MAX, SUPPORT_CMD_MIN as KEY_CMD_MIN, SUPPORT_CMD_STEP_MAX as KEY_CMD_STEP_MAX,
    SUPPORT_GAP_MAX as KEY_GAP_MAX,
};

/// Quantile of |q_cmd − q_phy| taken as the largest gap: the vision estimate has rare
/// outliers that are not hysteresis.
pub const GAP_QUANTILE: f64 = 0.999;

/// Per-joint extent of the training data, degrees.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct DataSupport {
    /// Smallest and largest command of each joint in the training samples.
    pub cmd_min_deg: Vec<f64>,
    pub cmd_max_deg: Vec<f64>,
    /// Largest |Δq_cmd| of each joint between consecutive training samples (one model step).
    pub cmd_step_max_deg: Vec<f64>,
    /// The `GAP_QUANTILE` quantile of |q_cmd − q_phy| per joint over the training targets.
    pub gap_max_deg: Vec<f64>,
}

impl DataSupport {
    /// From the training samples of a window set (validation samples are not looked at).
    pub fn from_windows(ws: &WindowSet) -> Self {
        let j = ws.joints;
        let (cmd, phy) = match ws.direction {
            Direction::Forward => (&ws.input_deg, &ws.target_deg),
            Direction::Inverse => (&ws.target_deg, &ws.input_deg),
        };
        let mut cmd_min_deg = vec![f64::INFINITY; j];
        let mut cmd_max_deg = vec![f64::NEG_INFINITY; j];
        let mut cmd_step_max_deg = vec![0.0f64; j];
        let mut gaps: Vec<Vec<f64>> = vec![Vec::with_capacity(ws.train.len()); j];
        let mut prev: Option<usize> = None;
        for &t in &ws.train {
            for k in 0..j {
                let c = cmd[t * j + k];
                cmd_min_deg[k] = cmd_min_deg[k].min(c);
                cmd_max_deg[k] = cmd_max_deg[k].max(c);
                let g = (c - phy[t * j + k]).abs();
                if g.is_finite() {
                    gaps[k].push(g);
                }
                if prev == Some(t.wrapping_sub(1)) {
                    let d = (c - cmd[(t - 1) * j + k]).abs();
                    cmd_step_max_deg[k] = cmd_step_max_deg[k].max(d);
                }
            }
            prev = Some(t);
        }
        // Decimated histories step further than consecutive samples: the model saw those too.
        if let Some(dec) = ws.decimated_cmd_step_max_deg() {
            for (m, d) in cmd_step_max_deg.iter_mut().zip(dec) {
                *m = m.max(d);
            }
        }
        let gap_max_deg = gaps
            .iter_mut()
            .map(|g| {
                if g.is_empty() {
                    return 0.0;
                }
                g.sort_by(|a, b| a.total_cmp(b));
                let idx = ((g.len() - 1) as f64 * GAP_QUANTILE).round() as usize;
                g[idx.min(g.len() - 1)]
            })
            .collect();
        Self {
            cmd_min_deg,
            cmd_max_deg,
            cmd_step_max_deg,
            gap_max_deg,
        }
    }

    /// The metadata props, in a fixed order; values with 17 significant digits (round trip).
    pub fn to_props(&self) -> Vec<(&'static str, String)> {
        let join = |v: &[f64]| v.iter().map(|x| format!("{x:?}")).collect::<Vec<_>>().join(",");
        vec![
            (KEY_CMD_MIN, join(&self.cmd_min_deg)),
            (KEY_CMD_MAX, join(&self.cmd_max_deg)),
            (KEY_CMD_STEP_MAX, join(&self.cmd_step_max_deg)),
            (KEY_GAP_MAX, join(&self.gap_max_deg)),
        ]
    }

    /// Reads the props back: `None` when the file carries none of them (a model trained
    /// elsewhere); an error naming the key when they are partial or malformed. The one reader
    /// of the contract ([`bowden_interfaces::model::Support`]), which the compensator uses too.
    pub fn from_props<'a>(
        get: impl Fn(&str) -> Option<&'a str>,
        joints: usize,
    ) -> Result<Option<Self>, bowden_interfaces::model::ContractError> {
        Ok(
            bowden_interfaces::model::Support::from_props(get, joints)?.map(|s| Self {
                cmd_min_deg: s.cmd_min_deg[..joints].to_vec(),
                cmd_max_deg: s.cmd_max_deg[..joints].to_vec(),
                cmd_step_max_deg: s.cmd_step_max_deg[..joints].to_vec(),
                gap_max_deg: s.gap_max_deg[..joints].to_vec(),
            }),
        )
    }
}

/// Writes `support` into an existing model file's metadata props (replacing any support props
/// it had), leaving the graph and weights byte for byte as they were: for models trained
/// before `train` recorded the support (`bowden stamp-support`).
pub fn stamp_file(path: &std::path::Path, support: &DataSupport) -> Result<(), crate::onnx::OnnxError> {
    use prost::Message;
    let bytes = std::fs::read(path).map_err(|source| crate::onnx::OnnxError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    let mut proto =
        tract_onnx::pb::ModelProto::decode(bytes.as_slice()).map_err(|source| crate::onnx::OnnxError::Decode {
            path: path.to_path_buf(),
            source,
        })?;
    let keys = [KEY_CMD_MIN, KEY_CMD_MAX, KEY_CMD_STEP_MAX, KEY_GAP_MAX];
    proto.metadata_props.retain(|p| !keys.contains(&p.key.as_str()));
    for (k, v) in support.to_props() {
        proto.metadata_props.push(tract_onnx::pb::StringStringEntryProto {
            key: k.to_string(),
            value: v,
        });
    }
    let tmp = path.with_extension("onnx.tmp");
    std::fs::write(&tmp, proto.encode_to_vec()).map_err(|source| crate::onnx::OnnxError::Io {
        path: tmp.clone(),
        source,
    })?;
    std::fs::rename(&tmp, path).map_err(|source| crate::onnx::OnnxError::Io {
        path: path.to_path_buf(),
        source,
    })
}
