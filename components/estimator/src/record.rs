//! A frame's estimate as a serialisable record (for `bowden estimate --json`, logs and
//! reports): NaN values become `null`, statuses become words.

use crate::{Diagnostics, MarkerStatus};
use bowden_interfaces::{marker, JointEstimate, MarkerSet, N_MARKERS};
use bowden_kinematics::N_JOINTS;
use serde::Serialize;

fn opt(v: f64) -> Option<f64> {
    v.is_finite().then_some(v)
}

fn opt3(v: [f64; 3]) -> Option<[f64; 3]> {
    v.iter().all(|x| x.is_finite()).then_some(v)
}

/// One marker of a frame.
#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct MarkerRecord {
    pub name: &'static str,
    pub valid: bool,
    pub status: &'static str,
    pub centre_cam_mm: Option<[f64; 3]>,
    pub residual_mm: Option<f64>,
    pub inliers: u32,
    /// Standard deviation of the centre along its worst direction, mm.
    pub centre_sd_max_mm: Option<f64>,
    pub silhouette_edges: u32,
}

/// One frame's estimate.
#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct EstimateRecord {
    pub seq: u64,
    pub tick: u64,
    pub t_origin_ns: u64,
    /// "valid", "partial" or "invalid".
    pub quality: &'static str,
    pub joint_valid_mask: u32,
    /// q1..q5 in degrees, `null` where not determined.
    pub q_phy_deg: [Option<f64>; N_JOINTS],
    /// Predicted standard deviation of each joint, degrees (`null`: not determined).
    pub q_sd_deg: [Option<f64>; N_JOINTS],
    /// The paper's estimate (eq. 6–14 + IK) for comparison, `null` if not available.
    pub q_paper_deg: [Option<f64>; N_JOINTS],
    pub ee_pos_base_mm: Option<[f64; 3]>,
    pub ee_quat_base_wxyz: Option<[f64; 4]>,
    pub ik_iterations: u32,
    pub ik_residual_pos_mm: Option<f64>,
    pub ik_residual_rot_deg: Option<f64>,
    pub joint_fit_rms_mm: Option<f64>,
    pub base_rms_mm: Option<f64>,
    pub markers: [MarkerRecord; N_MARKERS],
}

/// Name of a `JointEstimate::quality` value.
pub fn quality_name(q: u32) -> &'static str {
    match q {
        JointEstimate::QUALITY_VALID => "valid",
        JointEstimate::QUALITY_PARTIAL => "partial",
        _ => "invalid",
    }
}

impl EstimateRecord {
    pub fn new(ms: &MarkerSet, je: &JointEstimate, diag: &Diagnostics) -> Self {
        let markers = core::array::from_fn(|m| {
            let valid = ms.valid_mask & (1 << m) != 0;
            let sd = if valid {
                let ev = diag.centre_cov_cam_mm2[m].symmetric_eigenvalues();
                opt(ev.max().max(0.0).sqrt())
            } else {
                None
            };
            MarkerRecord {
                name: marker::NAMES[m],
                valid,
                status: if valid {
                    MarkerStatus::Valid.label()
                } else {
                    diag.marker_status[m].label()
                },
                centre_cam_mm: if valid { opt3(ms.centre_cam_mm[m]) } else { None },
                residual_mm: if valid { opt(ms.residual_mm[m]) } else { None },
                inliers: ms.inliers[m],
                centre_sd_max_mm: sd,
                silhouette_edges: diag.silhouette_edges[m],
            }
        });
        let q = je.q_phy_deg;
        let quat = je.ee_quat_base_wxyz;
        Self {
            seq: je.header.seq,
            tick: je.header.tick,
            t_origin_ns: je.header.t_origin_ns,
            quality: quality_name(je.quality),
            joint_valid_mask: je.joint_valid_mask,
            q_phy_deg: core::array::from_fn(|k| {
                if je.joint_valid_mask & (1 << k) != 0 {
                    opt(q[k])
                } else {
                    None
                }
            }),
            q_sd_deg: core::array::from_fn(|k| opt(diag.joint_sigma_deg[k])),
            q_paper_deg: diag.q_paper_deg.map(opt),
            ee_pos_base_mm: opt3(je.ee_pos_base_mm),
            ee_quat_base_wxyz: quat.iter().all(|v| v.is_finite()).then_some(quat),
            ik_iterations: je.ik_iterations,
            ik_residual_pos_mm: opt(je.ik_residual_pos_mm),
            ik_residual_rot_deg: opt(je.ik_residual_rot_deg),
            joint_fit_rms_mm: opt(diag.joint_fit_rms_mm),
            base_rms_mm: opt(diag.base_rms_mm),
            markers,
        }
    }

    /// One line for people: quality, joints (– where not determined), markers found.
    pub fn summary_line(&self) -> String {
        let q: Vec<String> = self
            .q_phy_deg
            .iter()
            .map(|v| v.map_or("     –".to_string(), |x| format!("{x:6.2}")))
            .collect();
        let missing: Vec<String> = self
            .markers
            .iter()
            .filter(|m| !m.valid)
            .map(|m| format!("{} ({})", m.name, m.status))
            .collect();
        format!(
            "seq {:>6}  {:<7}  q = [{}] deg{}",
            self.seq,
            self.quality,
            q.join(", "),
            if missing.is_empty() {
                String::new()
            } else {
                format!("  missing: {}", missing.join(", "))
            }
        )
    }
}
