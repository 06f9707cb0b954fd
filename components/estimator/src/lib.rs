//! Physical joint configuration from one RGBD frame (Park et al., RA-L 2024, §IV-A).
//!
//! The pipeline, per frame:
//! 1. **HSV thresholding** into the four marker colours and 8-connected components
//!    ([`segment`]); each marker takes the largest component of its colour and size class
//!    (base spheres are large, jaw spheres small: told apart by the physical area a
//!    component covers at its depth) whose sphere fit passes; r0 and r1 (both large red)
//!    are told apart by their distance to b0.
//! 2. **Back-projection** of the component's pixels with valid depth (pinhole model,
//!    pixel (u, v) centred at integer coordinates: x = (u − cx)·z/fx, y = (v − cy)·z/fy,
//!    z = depth·depth_unit, camera frame in mm) and **sphere centre by RANSAC** with the
//!    known radius, then least squares on the inliers ([`sphere`]): in the depth domain
//!    (the sensor's noise is along the ray), with the colour outline fixing the centre's
//!    direction where it is seen well. Each centre comes with its covariance.
//! 3. **Frames**: base from the three base spheres (eq. 6–7), the jaw pair (eq. 8–10 for
//!    both jaws), the end-effector (eq. 11–13) and T^base_EE (eq. 14) ([`geometry`]).
//! 4. **IK** (`robot.ik`, from the caller's hint, e.g. the command, as the paper does) for
//!    (q1, q2, q3, q_yaw), carried to the least-squares pose ([`joints::polish_pose_ik`]),
//!    and q4 = q_yaw − θ/2, q5 = q_yaw + θ/2: the paper's estimate, kept in
//!    [`Diagnostics::q_paper_deg`]. Then, by default (`refine_joints`), a least-squares fit
//!    of all five joints to the measured jaw centres, each weighted by its covariance
//!    ([`joints`]), which is what is reported.
//!
//! # Where this departs from the paper's text, and why
//! * Eq. 7 builds the base axes from two difference vectors without orthogonalising them;
//!   with noisy centres that is not a rotation. The base frame here is the least-squares
//!   rigid fit (Kabsch) of the three known sphere positions, equal to eq. 7 for exact
//!   centres; L_base is applied as the base-frame vector it is (rotated into the camera).
//! * Eq. 9 writes ŷ = x̂ × ẑ (left-handed; the right-handed frame has ŷ = ẑ × x̂), takes x̂
//!   from a sphere of the other jaw and corrects the sideways marker offset with R_x(ψ);
//!   eq. 13 places the tip with a (1 − cos θ/2) term along ẑ_f1, exact only along the
//!   bisector. With the offsets known (`MarkerGeometry`), the two jaws are fitted as one
//!   rigid pair sharing pivot and axis (pivot, bisector rotation, θ) by least squares; eq.
//!   11–13 then hold exactly: θ = ∠(ẑ_f1, ẑ_f2), R_EE = R_f1·R_x(θ/2), P_EE = pivot +
//!   d_fcps·ẑ_EE.
//! * The IK matches a 6-D pose with four joints under an arbitrary mm-per-radian weight
//!   and reads q4/q5 from θ alone; the measured quantities are the sphere centres. The
//!   joint-space fit over the centres is the statistically right estimate, and handles a
//!   hidden sphere where eq. 8–14 cannot be evaluated. On 1000 seeded frames it cuts the
//!   worst joint's RMS error from 0.72° (paper path) to 0.46°, and the largest joint error
//!   from 8.6° to 4.6° (`bowden estimator eval --frames 1000`).
//! * Sphere centres: a plain orthogonal-distance fit is biased towards the camera under
//!   depth noise (by σ²·sin²θ/2r); the fit here is in the depth domain, and the colour
//!   outline gives the lateral position (to a few hundredths of a millimetre, where depth
//!   gives a few tenths).
//!
//! # What is reported when something is missing
//! * An unusable frame (buffer sizes that do not match the header, non-finite or
//!   non-positive intrinsics, absurd dimensions) returns an [`EstimatorError`]; the outputs
//!   are still written, all invalid, so a caller ignoring the error sees no stale data.
//! * A marker that is not found, has too little valid depth, too few RANSAC inliers or too
//!   large a residual has its bit clear in `MarkerSet::valid_mask`, NaN centre and
//!   residual; [`Diagnostics::marker_status`] says why.
//! * A jaw sphere whose outline is seen but which has almost no depth (1–3 readings, e.g.
//!   in the stereo shadow of the other jaw), or whose depth fit disagrees with its outline,
//!   is [`MarkerStatus::DirectionOnly`]: not a reported centre (its range is only known to
//!   ~10 % from its apparent size), but its line of sight enters the joint-space fit with
//!   that covariance.
//! * The base frame needs all three base spheres, mutually consistent with the geometry
//!   (`base_distance_tol_mm`); otherwise no joint is reported (the jaws alone do not say
//!   where the base is), and the base spheres' valid bits are cleared when they disagree.
//! * With the base, each joint is reported when the jaw spheres determine it: the
//!   joint-space fit predicts every joint's standard deviation from the centres'
//!   covariances, and a joint is reported only below `joint_sigma_max_deg`. All four jaw
//!   spheres give all five joints; three (one hidden) still do in general; one jaw's two
//!   spheres give q1–q3 and that jaw's angle, not the other jaw's; one sphere alone gives
//!   nothing reliable. Quality is `QUALITY_VALID` (all five), `QUALITY_PARTIAL` (some) or
//!   `QUALITY_INVALID`.
//! * With two jaw spheres or fewer the fit is run from every start: a joint on which two
//!   solutions that fit equally well disagree is not reported
//!   ([`Diagnostics::ambiguous_joints`]).
//! * If the jaw spheres do not fit the robot model (RMS over their well-measured
//!   directions > `jaw_fit_rms_max_mm`, e.g. a wrong blob or a wrong depth), the fit is
//!   retried leaving each sphere out; if one leave-out fits, that sphere is flagged
//!   [`MarkerStatus::Inconsistent`] and the others are used; otherwise no joint is reported.
//! * A joint beyond its limits by more than `limit_margin_deg` is reported invalid.
//! * Invalid joints, and end-effector fields that could not be measured (they need all
//!   four jaw centres and all five joints), are NaN, never a stale or default number.
//!
//! The estimator is stateless between frames apart from reused buffers: the same frame
//! and hint always give the same output, bit for bit (RANSAC is seeded per marker). After
//! the first frame of a given size (or [`Estimator::reserve_frame`]), `estimate` does not
//! allocate.
//!
//! ```no_run
//! use bowden_estimator::{Estimator, EstimatorConfig};
//! use bowden_interfaces::{JointEstimate, MarkerSet, RgbdFrameHeader};
//! use bowden_kinematics::{markers::MarkerGeometry, Robot};
//! # fn frame() -> (RgbdFrameHeader, Vec<u8>) { (RgbdFrameHeader::default(), Vec::new()) }
//! let mut est = Estimator::new(Robot::paper_default(), MarkerGeometry::paper_default(),
//!                              EstimatorConfig::paper_default());
//! est.reserve_frame(640, 480); // real-time loops: no allocation from the first frame on
//! let (header, payload) = frame(); // RGB8 plane then little-endian u16 depth plane
//! let (mut markers, mut joints) = (MarkerSet::default(), JointEstimate::default());
//! let q_cmd_deg = [10.0, -5.0, 20.0, -10.0, 15.0]; // the command: the IK's start
//! match est.estimate_payload(&header, &payload, Some(q_cmd_deg), &mut markers, &mut joints) {
//!     Ok(()) if joints.quality == JointEstimate::QUALITY_VALID => println!("{:?}", &joints.q_phy_deg[..5]),
//!     Ok(()) => println!("joints determined: {:05b}", joints.joint_valid_mask),
//!     Err(e) => eprintln!("unusable frame: {e}"),
//! }
//! ```

// Fixed-size arrays indexed in parallel (joints, markers, their masks) read better as
// index loops than as zipped iterators.
#![allow(clippy::needless_range_loop)]

pub mod config;
pub mod eval;
pub mod geometry;
pub mod joints;
pub mod node;
pub mod record;
pub mod segment;
pub mod sphere;

use bowden_interfaces::{marker, JointEstimate, MarkerSet, RgbdFrameHeader, MAX_JOINTS, N_MARKERS};
use bowden_kinematics::ik::{pose_error, IkError, IkOptions};
use bowden_kinematics::markers::MarkerGeometry;
use bowden_kinematics::{JointsDeg, Robot, N_JOINTS};
use nalgebra::{Isometry3, Matrix3, Point3, Vector3};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

pub use config::{ConfigError, EstimatorConfig, EstimatorParams, HsvConfig, HsvRange};
pub use geometry::JawPair;
pub use segment::{Colour, DepthPlane, LeDepthBytes};
pub use sphere::{FitFailure, SphereFit, SphereFitParams};

/// Largest frame side accepted; a header claiming more is corrupt (and would make the
/// estimator allocate gigabytes).
pub const MAX_FRAME_SIDE: u32 = 8192;

/// A frame the estimator cannot use at all.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum EstimatorError {
    #[error("frame {width}x{height}: {plane} has {got} elements, the header implies {expected}")]
    FrameSize {
        width: u32,
        height: u32,
        plane: &'static str,
        expected: usize,
        got: usize,
    },
    #[error("frame header field `{field}` = {value}: {problem}")]
    BadHeader {
        field: &'static str,
        value: f64,
        problem: &'static str,
    },
}

/// Why a marker has no valid centre.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub enum MarkerStatus {
    /// Fitted and accepted.
    Valid,
    /// No component of its colour and size in the image.
    #[default]
    NotFound,
    /// Components were found but none gave an accepted sphere; the best attempt's reason.
    FitFailed(FitFailure),
    /// Only the line of sight is known (a jaw sphere with a good outline but almost no
    /// depth, or whose depth fit disagrees with its outline: its range comes from its
    /// apparent size, ~10 %). Not reported as a centre; the joint-space fit uses it,
    /// weighted by that covariance.
    DirectionOnly,
    /// The fitted centre does not project onto its component (a degenerate fit).
    OffBlob,
    /// r0/r1 could not be told apart (b0 missing).
    Ambiguous,
    /// The base triangle disagrees with the geometry, or the sphere was left out as the one
    /// that made the jaw centres inconsistent with the robot model.
    Inconsistent,
    /// The frame was unusable.
    BadFrame,
}

impl MarkerStatus {
    pub fn is_valid(&self) -> bool {
        matches!(self, MarkerStatus::Valid)
    }
    /// Short name for reports.
    pub fn label(&self) -> &'static str {
        match self {
            MarkerStatus::Valid => "valid",
            MarkerStatus::NotFound => "not found",
            MarkerStatus::FitFailed(FitFailure::TooFewPoints { .. }) => "too few depth points",
            MarkerStatus::FitFailed(FitFailure::NoHypothesis) => "no hypothesis",
            MarkerStatus::FitFailed(FitFailure::TooFewInliers { .. }) => "too few inliers",
            MarkerStatus::FitFailed(FitFailure::Degenerate) => "degenerate",
            MarkerStatus::FitFailed(FitFailure::ResidualTooLarge { .. }) => "residual too large",
            MarkerStatus::DirectionOnly => "direction only",
            MarkerStatus::OffBlob => "off blob",
            MarkerStatus::Ambiguous => "ambiguous",
            MarkerStatus::Inconsistent => "inconsistent",
            MarkerStatus::BadFrame => "bad frame",
        }
    }
}

/// Everything the estimator learned about the last frame, beyond the interface samples.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Diagnostics {
    pub marker_status: [MarkerStatus; N_MARKERS],
    /// Covariance of each valid centre, camera frame, mm² (zero where invalid).
    pub centre_cov_cam_mm2: [Matrix3<f64>; N_MARKERS],
    /// Silhouette edges that fixed each centre's direction (0: depth fit alone).
    pub silhouette_edges: [u32; N_MARKERS],
    /// Connected components kept, and dropped for exceeding `segment::MAX_BLOBS`.
    pub blobs: u32,
    pub dropped_blobs: u32,
    /// T^cam_base (eq. 6–7) when the base was found.
    pub base_in_camera: Option<Isometry3<f64>>,
    /// RMS distance of the three base centres to the fitted base frame, mm (NaN if none).
    pub base_rms_mm: f64,
    /// The jaw pair (eq. 8–11) in the base frame, when all four jaw spheres were valid.
    pub jaw_pair: Option<JawPair>,
    /// The paper's estimate: eq. 6–14, IK, q4/q5 from θ (NaN where not available).
    pub q_paper_deg: JointsDeg,
    /// RMS distance of the used jaw centres to the joint-space fit, mm (NaN if not run).
    pub joint_fit_rms_mm: f64,
    /// Predicted standard deviation of each joint (infinite if not determined).
    pub joint_sigma_deg: [f64; N_JOINTS],
    /// Jaw marker index (into `bowden_interfaces::marker`) left out as inconsistent.
    pub left_out_marker: Option<usize>,
    /// Bit k: joint k+1 was not reported because the few visible jaw spheres are matched
    /// equally well by configurations that differ in it.
    pub ambiguous_joints: u32,
}

impl Default for Diagnostics {
    fn default() -> Self {
        Self {
            marker_status: [MarkerStatus::NotFound; N_MARKERS],
            centre_cov_cam_mm2: [Matrix3::zeros(); N_MARKERS],
            silhouette_edges: [0; N_MARKERS],
            blobs: 0,
            dropped_blobs: 0,
            base_in_camera: None,
            base_rms_mm: f64::NAN,
            jaw_pair: None,
            q_paper_deg: [f64::NAN; N_JOINTS],
            joint_fit_rms_mm: f64::NAN,
            joint_sigma_deg: [f64::INFINITY; N_JOINTS],
            left_out_marker: None,
            ambiguous_joints: 0,
        }
    }
}

/// Colour of each marker, in `bowden_interfaces::marker` order (the paper's notation).
pub const MARKER_COLOURS: [Colour; N_MARKERS] = [
    Colour::Red,
    Colour::Red,
    Colour::Blue,
    Colour::Red,
    Colour::Blue,
    Colour::Yellow,
    Colour::Green,
];

/// Jaw markers in joint-fit order.
const JAW_MARKERS: [usize; 4] = [marker::LEFT_R2, marker::LEFT_B1, marker::RIGHT_Y0, marker::RIGHT_G0];

/// Points of one component offered to a sphere fit; a larger component (a sphere very
/// close to the camera) is sampled with an even stride. Bounds the buffer whatever the frame
/// size.
pub const MAX_SPHERE_POINTS: usize = 16384;
/// Silhouette edges collected per component (an outline has about 1.3 edges per pixel of
/// perimeter; more means a ragged, noisy mask, whose first edges suffice).
pub const MAX_SILHOUETTE_EDGES: usize = 16384;

/// Components of one colour and size class tried per marker, largest first.
const MAX_CANDIDATES: usize = 4;

/// IK seeds used when the caller gives no hint (after the hint-free IK start).
const FALLBACK_STARTS: [JointsDeg; 5] = [
    [0.0; 5],
    [30.0, 30.0, 20.0, 0.0, 0.0],
    [-30.0, -30.0, -20.0, 0.0, 0.0],
    [30.0, -30.0, -20.0, 0.0, 0.0],
    [-30.0, 30.0, 20.0, 0.0, 0.0],
];

/// The estimator: robot model, marker geometry, settings, and the per-frame buffers.
#[derive(Debug)]
pub struct Estimator {
    robot: Robot,
    geometry: MarkerGeometry,
    cfg: EstimatorConfig,
    seg: segment::Segmenter,
    points: Vec<Vector3<f64>>,
    edges: Vec<Vector3<f64>>,
    /// What the joint fit uses of each marker: centre and covariance, camera frame (valid
    /// centres and direction-only jaw spheres).
    meas: [Option<(Vector3<f64>, Matrix3<f64>)>; N_MARKERS],
    diag: Diagnostics,
    radii_mm: [f64; N_MARKERS],
    /// Physical area (mm²) above which a red/blue component is taken for a base sphere.
    large_area_mm2: f64,
    order: [u16; segment::MAX_BLOBS],
}

impl Estimator {
    pub fn new(robot: Robot, geometry: MarkerGeometry, cfg: EstimatorConfig) -> Self {
        let radii_mm = geometry.radii_mm();
        let disc = |r: f64| std::f64::consts::PI * r * r;
        // Geometric mean of the two disc areas: equally far (in ratio) from both.
        let large_area_mm2 = (disc(geometry.base_radius_mm) * disc(geometry.jaw_radius_mm)).sqrt();
        Self {
            robot,
            geometry,
            cfg,
            seg: segment::Segmenter::default(),
            points: Vec::new(),
            edges: Vec::new(),
            meas: [None; N_MARKERS],
            diag: Diagnostics::default(),
            radii_mm,
            large_area_mm2,
            order: [0; segment::MAX_BLOBS],
        }
    }

    pub fn config(&self) -> &EstimatorConfig {
        &self.cfg
    }
    pub fn robot(&self) -> &Robot {
        &self.robot
    }
    pub fn geometry(&self) -> &MarkerGeometry {
        &self.geometry
    }

    /// Diagnostics of the last `estimate` call.
    pub fn diagnostics(&self) -> &Diagnostics {
        &self.diag
    }

    /// Allocates the buffers for `width × height` frames now, so that the first frame of a
    /// real-time loop does not allocate either.
    pub fn reserve_frame(&mut self, width: u32, height: u32) {
        let (w, h) = (width.min(MAX_FRAME_SIDE) as usize, height.min(MAX_FRAME_SIDE) as usize);
        self.seg.reserve(w, h);
        if self.points.capacity() < MAX_SPHERE_POINTS {
            self.points.reserve_exact(MAX_SPHERE_POINTS - self.points.len());
        }
        if self.edges.capacity() < MAX_SILHOUETTE_EDGES {
            self.edges.reserve_exact(MAX_SILHOUETTE_EDGES - self.edges.len());
        }
    }

    /// Estimates from separate planes: `rgb` = width·height·3 bytes RGB8, `depth_mm` =
    /// width·height depth readings (in units of `header.depth_unit_mm`, 0 = none).
    /// `q_hint_deg` (e.g. the command) starts the IK; a non-finite hint is ignored.
    pub fn estimate(
        &mut self,
        header: &RgbdFrameHeader,
        rgb: &[u8],
        depth_mm: &[u16],
        q_hint_deg: Option<[f64; 5]>,
        markers_out: &mut MarkerSet,
        joints_out: &mut JointEstimate,
    ) -> Result<(), EstimatorError> {
        let checked = check_header(header).and_then(|n| {
            check_len(header, "rgb plane", n * 3, rgb.len())?;
            check_len(header, "depth plane", n, depth_mm.len())
        });
        self.run(header, checked, rgb, depth_mm, q_hint_deg, markers_out, joints_out)
    }

    /// Estimates from an interfaces payload: RGB8 plane, then the little-endian u16 depth
    /// plane at `header.depth_offset`.
    pub fn estimate_payload(
        &mut self,
        header: &RgbdFrameHeader,
        payload: &[u8],
        q_hint_deg: Option<[f64; 5]>,
        markers_out: &mut MarkerSet,
        joints_out: &mut JointEstimate,
    ) -> Result<(), EstimatorError> {
        let checked = check_header(header).and_then(|n| {
            let expected = RgbdFrameHeader::payload_len_for(header.width, header.height);
            check_len(header, "payload", expected, payload.len())?;
            if header.payload_len != expected as u64 {
                return Err(EstimatorError::BadHeader {
                    field: "payload_len",
                    value: header.payload_len as f64,
                    problem: "does not equal width·height·5",
                });
            }
            if header.depth_offset != (n * 3) as u64 {
                return Err(EstimatorError::BadHeader {
                    field: "depth_offset",
                    value: header.depth_offset as f64,
                    problem: "does not equal width·height·3",
                });
            }
            Ok(n)
        });
        let (rgb, depth) = match checked {
            Ok(n) => (&payload[..n * 3], &payload[n * 3..]),
            Err(_) => (&payload[..0], &payload[..0]),
        };
        self.run(
            header,
            checked,
            rgb,
            &LeDepthBytes(depth),
            q_hint_deg,
            markers_out,
            joints_out,
        )
    }

    #[allow(clippy::too_many_arguments)]
    fn run<D: DepthPlane + ?Sized>(
        &mut self,
        header: &RgbdFrameHeader,
        checked: Result<usize, EstimatorError>,
        rgb: &[u8],
        depth: &D,
        q_hint_deg: Option<[f64; 5]>,
        markers_out: &mut MarkerSet,
        joints_out: &mut JointEstimate,
    ) -> Result<(), EstimatorError> {
        init_outputs(header, markers_out, joints_out);
        self.diag = Diagnostics::default();
        self.meas = [None; N_MARKERS];
        if let Err(e) = checked {
            self.diag.marker_status = [MarkerStatus::BadFrame; N_MARKERS];
            return Err(e);
        }
        self.reserve_frame(header.width, header.height);
        let hint = q_hint_deg.filter(|q| q.iter().all(|v| v.is_finite()));
        self.detect_markers(header, rgb, depth, markers_out);
        self.estimate_joints(hint, markers_out, joints_out);
        Ok(())
    }

    // ---- steps 1–2: colour components → sphere centres ---------------------------------

    fn detect_markers<D: DepthPlane + ?Sized>(
        &mut self,
        h: &RgbdFrameHeader,
        rgb: &[u8],
        depth: &D,
        out: &mut MarkerSet,
    ) {
        let e = self.cfg.estimator;
        let unit = h.depth_unit_mm;
        // Depth range in raw units; readings outside it count as missing.
        let dmin = (e.depth_min_mm / unit).ceil().clamp(1.0, u16::MAX as f64) as u16;
        let dmax = (e.depth_max_mm / unit).floor().clamp(0.0, u16::MAX as f64) as u16;
        let (w, ht) = (h.width as usize, h.height as usize);
        self.seg.run(
            rgb,
            depth,
            w,
            ht,
            &self.cfg.hsv.ranges(),
            e.min_blob_pixels,
            (dmin, dmax),
            unit,
        );
        self.diag.blobs = self.seg.blobs.len() as u32;
        self.diag.dropped_blobs = self.seg.dropped_blobs;

        let mut centres: [Option<Vector3<f64>>; N_MARKERS] = [None; N_MARKERS];
        // Base spheres first (the jaw spheres' fragment test uses them): b0, then r0/r1.
        self.fit_marker(h, depth, (dmin, dmax), marker::BASE_B0, &mut centres, out);
        self.fit_base_reds(h, depth, (dmin, dmax), &mut centres, out);
        for m in JAW_MARKERS {
            self.fit_marker(h, depth, (dmin, dmax), m, &mut centres, out);
        }
    }

    /// Indices of the components that may be marker `m` (its colour and size class),
    /// largest first, into `self.order`; returns how many.
    fn candidates(&mut self, m: usize, fx: f64, fy: f64) -> usize {
        let colour = MARKER_COLOURS[m] as u8;
        let base = is_base(m);
        // Colours with both sphere sizes (red, blue) are split by physical area; every
        // candidate must also stay below a generous multiple of its sphere's disc (a
        // coloured object in the scene is not a marker).
        let mixed = (0..N_MARKERS).any(|o| MARKER_COLOURS[o] as u8 == colour && is_base(o) != base);
        let disc = std::f64::consts::PI * self.radii_mm[m] * self.radii_mm[m];
        let mut n = 0;
        for (i, b) in self.seg.blobs.iter().enumerate() {
            if b.colour != colour || b.n_depth == 0 {
                continue;
            }
            let area = b.area_mm2(fx, fy);
            let size_ok = !mixed || (area >= self.large_area_mm2) == base;
            if size_ok && area <= 4.0 * disc {
                self.order[n] = i as u16;
                n += 1;
            }
        }
        let blobs = &self.seg.blobs;
        self.order[..n].sort_unstable_by(|a, b| blobs[*b as usize].len.cmp(&blobs[*a as usize].len).then(a.cmp(b)));
        n
    }

    /// Fits one component as a sphere of marker `m`'s radius.
    fn fit_blob<D: DepthPlane + ?Sized>(
        &mut self,
        h: &RgbdFrameHeader,
        depth: &D,
        drange: (u16, u16),
        blob_index: usize,
        m: usize,
        attempt: usize,
    ) -> Result<SphereFit, MarkerStatus> {
        let e = self.cfg.estimator;
        let blob = self.seg.blobs[blob_index];
        let w = self.seg.width();
        self.points.clear();
        let stride = (blob.n_depth as usize).div_ceil(MAX_SPHERE_POINTS).max(1);
        let mut k = 0usize;
        for &p in self.seg.blob_pixels(&blob) {
            let p = p as usize;
            let d = depth.depth(p);
            if d == 0 || d < drange.0 || d > drange.1 {
                continue;
            }
            k += 1;
            if !(k - 1).is_multiple_of(stride) || self.points.len() == MAX_SPHERE_POINTS {
                continue;
            }
            let z = d as f64 * h.depth_unit_mm;
            let (u, v) = ((p % w) as f64, (p / w) as f64);
            self.points
                .push(Vector3::new((u - h.cx) * z / h.fx, (v - h.cy) * z / h.fy, z));
        }
        let params = SphereFitParams {
            iterations: e.ransac_iterations,
            inlier_mm: e.ransac_inlier_mm,
            max_score_points: e.ransac_max_points,
            min_inliers: e.min_inliers,
            min_inlier_fraction: e.min_inlier_fraction,
            max_rms_mm: e.max_fit_rms_mm,
            max_fit_points: e.max_fit_points,
        };
        // The sampler depends on the seed, the marker and the attempt only, so a frame's
        // answer does not depend on what was estimated before it.
        let stream = ((m as u64) << 8) | attempt as u64;
        let mut rng = ChaCha8Rng::seed_from_u64(e.seed ^ stream.wrapping_mul(0x9E37_79B9_7F4A_7C15));
        let gates = sphere::SilhouetteGates {
            min_edges: e.silhouette_min_edges,
            max_arc_concentration: e.silhouette_max_arc_concentration,
            agreement_sigmas: e.silhouette_agreement_sigmas,
            min_agreement_mm: e.silhouette_min_agreement_mm,
            pixel_rad: 1.0 / h.fx.max(h.fy),
            size_bias_rad: e.silhouette_size_bias_px / h.fx.max(h.fy),
            // The base frame needs true centres.
            allow_direction_only: !is_base(m),
        };
        let r = self.radii_mm[m];
        let fit = match sphere::fit_depth(&mut self.points, r, &params, &mut rng) {
            Ok(depth_fit) => {
                self.collect_edges(h, depth, drange, &blob, depth_fit.fit.centre.z);
                let sil = sphere::fit_silhouette(&self.edges, gates.pixel_rad, e.ransac_iterations, &mut rng);
                sphere::combine_with_silhouette(&depth_fit, &self.points, sil.as_ref(), &gates)
            }
            // Too little depth for a 3-D fit: the outline may still fix the direction, and a
            // few depths the range.
            Err(fail @ (FitFailure::TooFewPoints { .. } | FitFailure::TooFewInliers { .. })) => {
                // The sphere's centre lies about 2r/3 behind its visible points.
                self.collect_edges(h, depth, drange, &blob, blob.mean_depth_mm + 2.0 * r / 3.0);
                let sil = sphere::fit_silhouette(&self.edges, gates.pixel_rad, e.ransac_iterations, &mut rng);
                sil.and_then(|s| {
                    sphere::fit_from_silhouette(
                        &mut self.points,
                        r,
                        &s,
                        &gates,
                        e.ransac_inlier_mm,
                        e.silhouette_min_depth_points,
                    )
                })
                .ok_or(MarkerStatus::FitFailed(fail))?
            }
            Err(fail) => return Err(MarkerStatus::FitFailed(fail)),
        };
        // A jaw sphere fitted on depth alone is a small cap, usually seen in part (its
        // outline was not usable): its least-squares covariance is far too optimistic (on the
        // synthetic camera the squared Mahalanobis error averaged 35 instead of 3). A model
        // error of a quarter radius per axis covers it.
        let mut fit = fit;
        if !is_base(m) && fit.silhouette_edges == 0 {
            fit.cov += Matrix3::identity() * (0.25 * r).powi(2);
        }
        // The centre must project onto (or just beside) its component.
        let c = fit.centre;
        let (u, v) = (h.fx * c.x / c.z + h.cx, h.fy * c.y / c.z + h.cy);
        let margin = 2.0 + h.fx * self.radii_mm[m] / c.z;
        let inside = c.z > 0.0
            && u >= blob.u_min as f64 - margin
            && u <= blob.u_max as f64 + margin
            && v >= blob.v_min as f64 - margin
            && v <= blob.v_max as f64 + margin;
        if !inside {
            return Err(MarkerStatus::OffBlob);
        }
        Ok(fit)
    }

    /// Silhouette edge rays of a component: midway between each of its pixels and an
    /// outside 4-neighbour. An edge is dropped where the first depth reading beyond it (up
    /// to 3 px out) is nearer than the sphere's centre: that side is an occluder in front,
    /// and the edge is the occluder's outline, not the sphere's. Edges on the image border
    /// are dropped too.
    fn collect_edges<D: DepthPlane + ?Sized>(
        &mut self,
        h: &RgbdFrameHeader,
        depth: &D,
        drange: (u16, u16),
        blob: &segment::Blob,
        centre_depth_mm: f64,
    ) {
        const OCCLUDER_MARGIN_MM: f64 = 1.0;
        self.edges.clear();
        let (w, ht) = (self.seg.width() as i64, self.seg.height() as i64);
        let code = blob.colour + 1;
        for &p in self.seg.blob_pixels(blob) {
            if self.edges.len() + 4 > MAX_SILHOUETTE_EDGES {
                break;
            }
            let (u, v) = ((p as i64) % w, (p as i64) / w);
            for (du, dv) in [(1i64, 0i64), (-1, 0), (0, 1), (0, -1)] {
                let (uq, vq) = (u + du, v + dv);
                if uq < 0 || vq < 0 || uq >= w || vq >= ht {
                    continue;
                }
                if self.seg.class_at((vq * w + uq) as usize) == code {
                    continue;
                }
                let mut occluded = false;
                for k in 1..=3 {
                    let (uk, vk) = (u + k * du, v + k * dv);
                    if uk < 0 || vk < 0 || uk >= w || vk >= ht {
                        break;
                    }
                    let d = depth.depth((vk * w + uk) as usize);
                    if d != 0 && d >= drange.0 && d <= drange.1 {
                        occluded = (d as f64) * h.depth_unit_mm < centre_depth_mm - OCCLUDER_MARGIN_MM;
                        break;
                    }
                }
                if occluded {
                    continue;
                }
                let (ue, ve) = (u as f64 + 0.5 * du as f64, v as f64 + 0.5 * dv as f64);
                self.edges
                    .push(Vector3::new((ue - h.cx) / h.fx, (ve - h.cy) / h.fy, 1.0).normalize());
            }
        }
    }

    fn accept(
        &mut self,
        m: usize,
        fit: &SphereFit,
        centres: &mut [Option<Vector3<f64>>; N_MARKERS],
        out: &mut MarkerSet,
    ) {
        centres[m] = Some(fit.centre);
        self.meas[m] = Some((fit.centre, fit.cov));
        self.diag.centre_cov_cam_mm2[m] = fit.cov;
        self.diag.silhouette_edges[m] = fit.silhouette_edges;
        out.centre_cam_mm[m] = [fit.centre.x, fit.centre.y, fit.centre.z];
        out.residual_mm[m] = fit.rms_mm;
        out.inliers[m] = fit.inliers;
        out.valid_mask |= 1 << m;
        self.diag.marker_status[m] = MarkerStatus::Valid;
    }

    /// Marker `m` = the largest candidate component that fits. Jaw spheres skip a fit that
    /// lies inside a base sphere of the same colour (a fragment of it, e.g. split by the arm).
    fn fit_marker<D: DepthPlane + ?Sized>(
        &mut self,
        h: &RgbdFrameHeader,
        depth: &D,
        drange: (u16, u16),
        m: usize,
        centres: &mut [Option<Vector3<f64>>; N_MARKERS],
        out: &mut MarkerSet,
    ) {
        let n = self.candidates(m, h.fx, h.fy);
        for k in 0..n.min(MAX_CANDIDATES) {
            let bi = self.order[k] as usize;
            match self.fit_blob(h, depth, drange, bi, m, k) {
                Ok(fit) if fit.direction_only => {
                    self.meas[m] = Some((fit.centre, fit.cov));
                    self.diag.centre_cov_cam_mm2[m] = fit.cov;
                    self.diag.silhouette_edges[m] = fit.silhouette_edges;
                    self.diag.marker_status[m] = MarkerStatus::DirectionOnly;
                    return;
                }
                Ok(fit) => {
                    let fragment = (0..=marker::BASE_B0).any(|b| {
                        MARKER_COLOURS[b] == MARKER_COLOURS[m]
                            && b != m
                            && centres[b]
                                .is_some_and(|c| (c - fit.centre).norm() < self.radii_mm[b] + self.radii_mm[m] - 0.5)
                    });
                    if fragment {
                        self.diag.marker_status[m] = MarkerStatus::Inconsistent;
                        continue;
                    }
                    self.accept(m, &fit, centres, out);
                    return;
                }
                Err(status) => self.diag.marker_status[m] = status,
            }
        }
    }

    /// r0 and r1 are both large red spheres: fit the two largest that pass, then tell them
    /// apart by their distance to b0 (eq. 7: r1 is the one b0 sits above).
    fn fit_base_reds<D: DepthPlane + ?Sized>(
        &mut self,
        h: &RgbdFrameHeader,
        depth: &D,
        drange: (u16, u16),
        centres: &mut [Option<Vector3<f64>>; N_MARKERS],
        out: &mut MarkerSet,
    ) {
        let n = self.candidates(marker::BASE_R0, h.fx, h.fy);
        let mut fits: [Option<SphereFit>; 2] = [None, None];
        let mut found = 0;
        let mut last_err = MarkerStatus::NotFound;
        for k in 0..n.min(MAX_CANDIDATES) {
            let bi = self.order[k] as usize;
            match self.fit_blob(h, depth, drange, bi, marker::BASE_R0, k) {
                Ok(fit) => {
                    fits[found] = Some(fit);
                    found += 1;
                    if found == 2 {
                        break;
                    }
                }
                Err(s) => last_err = s,
            }
        }
        let g = &self.geometry;
        let d_r0_b0 = (Vector3::from(g.r0_base_mm) - Vector3::from(g.b0_base_mm)).norm();
        let d_r1_b0 = (Vector3::from(g.r1_base_mm) - Vector3::from(g.b0_base_mm)).norm();
        let Some(b0) = centres[marker::BASE_B0] else {
            let status = if found > 0 { MarkerStatus::Ambiguous } else { last_err };
            self.diag.marker_status[marker::BASE_R0] = status;
            self.diag.marker_status[marker::BASE_R1] = status;
            return;
        };
        // Cost of calling fit a "r0" and fit b "r1" (or a alone either).
        let miss = |f: &SphereFit, d: f64| ((f.centre - b0).norm() - d).abs();
        match fits {
            [Some(a), Some(b)] => {
                let straight = miss(&a, d_r0_b0) + miss(&b, d_r1_b0);
                let swapped = miss(&b, d_r0_b0) + miss(&a, d_r1_b0);
                let (f0, f1) = if straight <= swapped { (a, b) } else { (b, a) };
                self.accept(marker::BASE_R0, &f0, centres, out);
                self.accept(marker::BASE_R1, &f1, centres, out);
            }
            [Some(a), None] => {
                let (m, other) = if miss(&a, d_r0_b0) <= miss(&a, d_r1_b0) {
                    (marker::BASE_R0, marker::BASE_R1)
                } else {
                    (marker::BASE_R1, marker::BASE_R0)
                };
                self.accept(m, &a, centres, out);
                self.diag.marker_status[other] = last_err;
            }
            _ => {
                self.diag.marker_status[marker::BASE_R0] = last_err;
                self.diag.marker_status[marker::BASE_R1] = last_err;
            }
        }
    }

    // ---- steps 3–4: frames, IK, joint fit ----------------------------------------------

    fn invalidate_marker(&mut self, m: usize, out: &mut MarkerSet) {
        self.meas[m] = None;
        out.valid_mask &= !(1 << m);
        out.centre_cam_mm[m] = [f64::NAN; 3];
        out.residual_mm[m] = f64::NAN;
        self.diag.marker_status[m] = MarkerStatus::Inconsistent;
    }

    /// Eq. 6–7 (exact form, see [`geometry`]): T^cam_base, or `None`.
    fn base_frame(&mut self, ms: &mut MarkerSet) -> Option<Isometry3<f64>> {
        let base = [marker::BASE_R0, marker::BASE_R1, marker::BASE_B0];
        if base.iter().any(|&m| ms.valid_mask & (1 << m) == 0) {
            return None;
        }
        let g = &self.geometry;
        let model = [
            Vector3::from(g.r0_base_mm),
            Vector3::from(g.r1_base_mm),
            Vector3::from(g.b0_base_mm),
        ];
        let measured = base.map(|m| Vector3::from(ms.centre_cam_mm[m]));
        let tol = self.cfg.estimator.base_distance_tol_mm;
        let consistent = (0..3).all(|i| {
            let j = (i + 1) % 3;
            ((model[i] - model[j]).norm() - (measured[i] - measured[j]).norm()).abs() <= tol
        });
        let t = if consistent {
            geometry::kabsch(&model, &measured)
        } else {
            None
        };
        let Some(t) = t else {
            for m in base {
                self.invalidate_marker(m, ms);
            }
            return None;
        };
        self.diag.base_rms_mm = geometry::rms_distance(&t, &model, &measured);
        self.diag.base_in_camera = Some(t);
        Some(t)
    }

    // Long: the frame → joints pipeline stages (frames, IK, gates) in the order of the paper's section III.
    fn estimate_joints(&mut self, hint: Option<JointsDeg>, ms: &mut MarkerSet, je: &mut JointEstimate) {
        let Some(cam_base) = self.base_frame(ms) else {
            return;
        };
        let base_cam = cam_base.inverse();
        let rot = base_cam.rotation.to_rotation_matrix();
        let mut measured = [Vector3::zeros(); 4];
        let mut cov = [Matrix3::zeros(); 4];
        let mut use_mask = 0u8;
        for (i, &m) in JAW_MARKERS.iter().enumerate() {
            if let Some((c, c_cov)) = self.meas[m] {
                measured[i] = (base_cam * Point3::from(c)).coords;
                cov[i] = rot.matrix() * c_cov * rot.matrix().transpose();
                use_mask |= 1 << i;
            }
        }
        if use_mask == 0 {
            return;
        }
        let e = self.cfg.estimator;
        let obs = joints::JawObservations::new(measured, cov, use_mask, e.centre_sigma_floor_mm).unwrap_or_else(|| {
            joints::JawObservations::isotropic(measured, use_mask, e.centre_sigma_floor_mm.max(0.1))
        });

        // The paper's path (eq. 8–14 + IK) needs all four jaw spheres.
        let mut paper: Option<(JointsDeg, Isometry3<f64>, u32)> = None;
        let all_centres = JAW_MARKERS.iter().all(|&m| ms.valid_mask & (1 << m) != 0);
        if use_mask == 0b1111 && all_centres {
            let g = &self.geometry;
            let lm = [Vector3::from(g.r2_left_mm), Vector3::from(g.b1_left_mm)];
            let rm = [Vector3::from(g.y0_right_mm), Vector3::from(g.g0_right_mm)];
            if let Some(pair) =
                geometry::fit_jaw_pair(&lm, &rm, &[measured[0], measured[1]], &[measured[2], measured[3]])
            {
                self.diag.jaw_pair = Some(pair);
                if pair.rms_mm <= e.jaw_fit_rms_max_mm {
                    let ee = pair.end_effector(self.robot.config.forceps.jaw_length_mm);
                    let opts = IkOptions {
                        max_iterations: e.ik_max_iterations,
                        tol_pos_mm: e.ik_tol_pos_mm,
                        tol_rot_rad: e.ik_tol_rot_deg.to_radians(),
                        limit_margin_deg: None,
                        ..IkOptions::default()
                    };
                    let hint4 = hint.map(|q| [q[0], q[1], q[2], 0.5 * (q[3] + q[4])]);
                    let sol = match self.robot.ik(&ee, hint4, &opts) {
                        Ok(s) => Some((s.q_deg, s.iterations)),
                        // Not converged to the noise-level tolerance: still a starting point
                        // for the joint-space fit, whose residual gate judges the result.
                        Err(IkError::NotConverged {
                            best_q_deg, iterations, ..
                        }) => Some((best_q_deg, iterations)),
                        Err(IkError::OutsideLimits { q_deg, .. }) => Some((q_deg, 0)),
                        Err(IkError::NotFinite) => None,
                    };
                    if let Some((q4, iters)) = sol {
                        let q4 = joints::polish_pose_ik(
                            &self.robot,
                            &ee,
                            q4,
                            IkOptions::default().rot_weight_mm_per_rad,
                            e.ik_max_iterations,
                        );
                        let half = 0.5 * pair.opening_rad.to_degrees();
                        let q = [q4[0], q4[1], q4[2], q4[3] - half, q4[3] + half];
                        self.diag.q_paper_deg = q;
                        paper = Some((q, ee, iters));
                        je.ik_iterations = iters;
                        let p = ee.translation.vector;
                        je.ee_pos_base_mm = [p.x, p.y, p.z];
                        let r = ee.rotation;
                        je.ee_quat_base_wxyz = [r.w, r.i, r.j, r.k];
                    }
                }
            }
        }

        let (q, valid) = if e.refine_joints {
            match self.refine(hint, paper.map(|p| p.0), &obs, ms) {
                Some(r) => r,
                None => return,
            }
        } else {
            match paper {
                Some((q, ..)) => {
                    let fit = joints::fit_joints(&self.robot, &self.geometry, &obs, &q, 0);
                    self.diag.joint_fit_rms_mm = fit.rms_mm;
                    self.diag.joint_sigma_deg = fit.sigma_deg;
                    (q, if fit.rms_mm <= e.jaw_fit_rms_max_mm { 0b11111 } else { 0 })
                }
                None => return,
            }
        };
        // Physical angles far beyond the limits are not believed.
        let lim = &self.robot.config.limits;
        let mut mask = valid;
        for k in 0..N_JOINTS {
            if q[k] < lim.q_min_deg[k] - e.limit_margin_deg || q[k] > lim.q_max_deg[k] + e.limit_margin_deg {
                mask &= !(1 << k);
            }
        }
        for k in 0..N_JOINTS {
            if mask & (1 << k) != 0 {
                je.q_phy_deg[k] = q[k];
            }
        }
        je.joint_valid_mask = mask;
        je.quality = match mask.count_ones() {
            5 => JointEstimate::QUALITY_VALID,
            0 => JointEstimate::QUALITY_INVALID,
            _ => JointEstimate::QUALITY_PARTIAL,
        };
        if let Some((_, ee, _)) = paper {
            if mask == 0b11111 {
                let fk = self.robot.fk(&q);
                let (dp, dr) = pose_error(&ee, &fk.ee);
                je.ik_residual_pos_mm = dp.norm();
                je.ik_residual_rot_deg = dr.norm().to_degrees();
            }
        }
        if mask != 0b11111 {
            // The measured end-effector pose belongs to a complete estimate only.
            je.ee_pos_base_mm = [f64::NAN; 3];
            je.ee_quat_base_wxyz = [f64::NAN; 4];
        }
    }

    /// Joint-space fit from the best available start; leave-one-out when the jaw spheres
    /// disagree with the model. Returns the configuration and the mask of determined joints.
    // Long: one iterative refinement with its stopping rules, allocation-free on the real-time path.
    fn refine(
        &mut self,
        hint: Option<JointsDeg>,
        paper_q: Option<JointsDeg>,
        obs: &joints::JawObservations,
        ms: &mut MarkerSet,
    ) -> Option<(JointsDeg, u32)> {
        let e = self.cfg.estimator;
        let gate = e.jaw_fit_rms_max_mm;
        let use_mask = obs.use_mask;
        // Runs the fit from each start until one lands within half the gate; the best one.
        let run = |this: &Self, mask: u8, starts: &[JointsDeg]| -> Option<joints::JointFit> {
            let o = obs.with_mask(mask);
            let mut best: Option<joints::JointFit> = None;
            for q0 in starts {
                let fit = joints::fit_joints(&this.robot, &this.geometry, &o, q0, e.refine_max_iterations);
                if best.is_none_or(|b| fit.rms_mm < b.rms_mm) {
                    best = Some(fit);
                }
                if fit.rms_mm <= 0.5 * gate {
                    break;
                }
            }
            best
        };
        // The paper's IK answer, else the caller's hint; the fixed seeds only if those fail
        // (bounded work per frame either way).
        let mut primary = [[0.0; N_JOINTS]; 2];
        let mut n_primary = 0;
        for q in paper_q.iter().chain(hint.iter()) {
            primary[n_primary] = *q;
            n_primary += 1;
        }
        let mut fit = run(self, use_mask, &primary[..n_primary]);
        if fit.is_none_or(|f| f.rms_mm > gate) {
            if let Some(f) = run(self, use_mask, &FALLBACK_STARTS) {
                if fit.is_none_or(|b| f.rms_mm < b.rms_mm) {
                    fit = Some(f);
                }
            }
        }
        let mut fit = fit?;
        if fit.rms_mm > gate && use_mask.count_ones() >= 3 {
            // One wrong sphere (e.g. a mislabelled blob): find the leave-one-out that fits,
            // starting from the all-spheres fit.
            let start = [fit.q_deg];
            let mut best: Option<(joints::JointFit, usize)> = None;
            for i in 0..4 {
                if use_mask & (1 << i) == 0 {
                    continue;
                }
                if let Some(f) = run(self, use_mask & !(1 << i), &start) {
                    if f.rms_mm <= gate && best.is_none_or(|b| f.rms_mm < b.0.rms_mm) {
                        best = Some((f, i));
                    }
                }
            }
            if let Some((f, i)) = best {
                fit = f;
                self.invalidate_marker(JAW_MARKERS[i], ms);
                self.diag.left_out_marker = Some(JAW_MARKERS[i]);
            }
        }
        self.diag.joint_fit_rms_mm = fit.rms_mm;
        self.diag.joint_sigma_deg = fit.sigma_deg;
        if fit.rms_mm > gate {
            return None;
        }
        let mut valid = 0u32;
        for k in 0..N_JOINTS {
            if fit.sigma_deg[k] <= e.joint_sigma_max_deg {
                valid |= 1 << k;
            }
        }
        // Two jaw spheres or fewer: barely more numbers than joints. Two spheres near the jaw
        // axis pin the pivot's position but hardly its orientation, and one pivot position
        // is reached by two splits of the bend between the pitch joints q1 and q3 (like a
        // planar two-link arm's elbow up and down), each well determined locally. So the fit
        // is also run from a grid over (q1, q3), other joints as found; a joint on which two
        // solutions fitting as well (χ² within 9, i.e. 3σ) disagree is not reported,
        // whatever the hint.
        if use_mask.count_ones() <= 2 {
            let o = obs.with_mask(use_mask);
            let mut ambiguous = 0u32;
            const PITCH_GRID: [(f64, f64); 12] = [
                (-45.0, -30.0),
                (-45.0, 0.0),
                (-45.0, 30.0),
                (-15.0, -30.0),
                (-15.0, 0.0),
                (-15.0, 30.0),
                (15.0, -30.0),
                (15.0, 0.0),
                (15.0, 30.0),
                (45.0, -30.0),
                (45.0, 0.0),
                (45.0, 30.0),
            ];
            let mut starts = [[0.0; N_JOINTS]; 2 + FALLBACK_STARTS.len() + PITCH_GRID.len()];
            let mut n = 0;
            for q0 in primary[..n_primary].iter().chain(FALLBACK_STARTS.iter()) {
                starts[n] = *q0;
                n += 1;
            }
            for (q1, q3) in PITCH_GRID {
                starts[n] = [q1, fit.q_deg[1], q3, fit.q_deg[3], fit.q_deg[4]];
                n += 1;
            }
            for q0 in &starts[..n] {
                let other = joints::fit_joints(&self.robot, &self.geometry, &o, q0, e.refine_max_iterations);
                if other.rms_mm > gate || other.chi2 > fit.chi2 + 9.0 {
                    continue;
                }
                for k in 0..N_JOINTS {
                    let tol = (3.0 * fit.sigma_deg[k]).max(1.0);
                    if (other.q_deg[k] - fit.q_deg[k]).abs() > tol {
                        ambiguous |= 1 << k;
                    }
                }
            }
            self.diag.ambiguous_joints = ambiguous;
            valid &= !ambiguous;
        }
        Some((fit.q_deg, valid))
    }
}

fn is_base(m: usize) -> bool {
    m <= marker::BASE_B0
}

fn check_header(h: &RgbdFrameHeader) -> Result<usize, EstimatorError> {
    for (field, v) in [("width", h.width), ("height", h.height)] {
        if v == 0 || v > MAX_FRAME_SIDE {
            return Err(EstimatorError::BadHeader {
                field,
                value: v as f64,
                problem: "must be in 1..=8192 pixels",
            });
        }
    }
    for (field, v) in [("fx", h.fx), ("fy", h.fy), ("depth_unit_mm", h.depth_unit_mm)] {
        if !(v.is_finite() && v > 0.0) {
            return Err(EstimatorError::BadHeader {
                field,
                value: v,
                problem: "must be a positive finite number",
            });
        }
    }
    for (field, v) in [("cx", h.cx), ("cy", h.cy)] {
        if !v.is_finite() {
            return Err(EstimatorError::BadHeader {
                field,
                value: v,
                problem: "must be finite",
            });
        }
    }
    Ok(h.width as usize * h.height as usize)
}

fn check_len(h: &RgbdFrameHeader, plane: &'static str, expected: usize, got: usize) -> Result<usize, EstimatorError> {
    if expected != got {
        return Err(EstimatorError::FrameSize {
            width: h.width,
            height: h.height,
            plane,
            expected,
            got,
        });
    }
    Ok(h.width as usize * h.height as usize)
}

/// Both outputs as "nothing measured" for this frame: NaN values, empty masks.
fn init_outputs(h: &RgbdFrameHeader, ms: &mut MarkerSet, je: &mut JointEstimate) {
    *ms = MarkerSet {
        header: h.header,
        frame_seq: h.header.seq,
        centre_cam_mm: [[f64::NAN; 3]; N_MARKERS],
        residual_mm: [f64::NAN; N_MARKERS],
        inliers: [0; N_MARKERS],
        valid_mask: 0,
    };
    let mut q = [0.0; MAX_JOINTS];
    q[..N_JOINTS].fill(f64::NAN);
    *je = JointEstimate {
        header: h.header,
        frame_seq: h.header.seq,
        n_joints: N_JOINTS as u32,
        quality: JointEstimate::QUALITY_INVALID,
        q_phy_deg: q,
        joint_valid_mask: 0,
        ik_iterations: 0,
        ee_pos_base_mm: [f64::NAN; 3],
        ee_quat_base_wxyz: [f64::NAN; 4],
        ik_residual_pos_mm: f64::NAN,
        ik_residual_rot_deg: f64::NAN,
    };
}
