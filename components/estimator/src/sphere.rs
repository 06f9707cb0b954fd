//! Step 2 of §IV-A: the centre of a sphere of known radius from one colour component.
//!
//! 1. **Depth fit**: RANSAC over 3-point hypotheses with the known radius (MSAC scoring on
//!    the orthogonal distance) rejects outliers (background depth at the silhouette, colour
//!    bleeding); then Gauss–Newton on the inliers in the *depth domain*: the residual of a
//!    pixel is its measured depth minus the depth at which its ray enters the sphere. A
//!    stereo camera's noise is along the ray, in Z; the orthogonal distance |p − c| − r is
//!    biased under that noise (E|p − c| grows by σ²·sin²θ / 2r at incidence θ, which pulls
//!    the centre ~0.15 mm towards the camera for a 2 mm sphere at D435 noise), the depth
//!    residual is not.
//! 2. **Silhouette**: the colour mask's outline is the cone of rays tangent to the sphere;
//!    its axis is the direction of the centre. Edge points (midway between a mask pixel and
//!    its outside 4-neighbour) are unit rays; a circle on the unit sphere through them
//!    (w·e = 1, axis = w/|w|) is fitted by RANSAC and least squares. Edges where the surface
//!    beyond is nearer than the sphere are occlusion boundaries, not silhouette, and are
//!    dropped before the fit. The cone's opening is left free (it would fix the depth only
//!    very weakly and is biased by how the mask is thresholded).
//! 3. **Combined**: when the silhouette is well covered and agrees with the depth fit, the
//!    centre is on the silhouette axis at the range the depth residuals give (the outline
//!    places the centre laterally to a few hundredths of a millimetre, depth cannot);
//!    otherwise the depth fit stands. Either way the centre's covariance is reported: from
//!    the depth fit's normal equations, or the range variance along the axis plus the
//!    circle fit's axis covariance across it (a partial outline is uncertain along its
//!    symmetry line only).
//! 4. **Little depth** ([`fit_from_silhouette`]): a sphere with too few depth points for
//!    step 1 but a good outline takes its direction from the outline and its range from a
//!    few depths, or (jaw spheres only) from the outline's angular size, as a line of sight
//!    with a loose range.
//!
//! Allocation-free: hypotheses are scored in place; inliers are re-derived from the current
//! estimate instead of being stored.

use nalgebra::{Matrix3, Vector3};
use rand::Rng;
use rand_chacha::ChaCha8Rng;

/// Parameters of one fit (from `[estimator]`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SphereFitParams {
    pub iterations: u32,
    /// Inlier threshold: orthogonal distance for RANSAC, depth residual afterwards, mm.
    pub inlier_mm: f64,
    pub max_score_points: u32,
    pub min_inliers: u32,
    pub min_inlier_fraction: f64,
    pub max_rms_mm: f64,
    /// The iterations run on at most this many points (evenly strided); the final step and
    /// the statistics use every inlier.
    pub max_fit_points: u32,
}

/// An accepted fit.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SphereFit {
    /// Centre in the points' frame (camera), mm.
    pub centre: Vector3<f64>,
    /// Covariance of the centre, mm².
    pub cov: Matrix3<f64>,
    /// RMS depth residual of the inliers, mm.
    pub rms_mm: f64,
    pub inliers: u32,
    /// Points with depth offered to the fit.
    pub points: u32,
    /// Silhouette edge points that support the centre's direction (0: depth fit only).
    pub silhouette_edges: u32,
    /// The range comes from the outline's angular size, not from depth: the line of sight
    /// is sure, the range is not (see [`fit_from_silhouette`]).
    pub direction_only: bool,
}

/// Why a fit was refused.
#[derive(Debug, Clone, Copy, PartialEq, thiserror::Error)]
pub enum FitFailure {
    #[error("only {points} points with valid depth (need {needed})")]
    TooFewPoints { points: u32, needed: u32 },
    #[error("no RANSAC hypothesis explains the points")]
    NoHypothesis,
    #[error("{inliers} inliers of {points} points (need {needed} and {fraction:.0}%)", fraction = min_fraction * 100.0)]
    TooFewInliers {
        inliers: u32,
        points: u32,
        needed: u32,
        min_fraction: f64,
    },
    #[error("least squares did not converge (degenerate point set)")]
    Degenerate,
    #[error("RMS depth residual {rms_mm:.3} mm exceeds {max_mm} mm")]
    ResidualTooLarge { rms_mm: f64, max_mm: f64 },
}

/// Candidate centre of a sphere of radius `r` through three points: of the two on the
/// normal of their plane through the circumcentre, the one farther from the camera (the
/// origin), since the camera sees the cap that faces it.
fn centre_from_three(a: &Vector3<f64>, b: &Vector3<f64>, c: &Vector3<f64>, r: f64) -> Option<Vector3<f64>> {
    let ab = b - a;
    let ac = c - a;
    let n = ab.cross(&ac);
    let n2 = n.norm_squared();
    if n2 == 0.0 || n2 < 1e-12 * ab.norm_squared() * ac.norm_squared() {
        return None;
    }
    let to_m = (n.cross(&ab) * ac.norm_squared() + ac.cross(&n) * ab.norm_squared()) / (2.0 * n2);
    let rho2 = to_m.norm_squared();
    // Noise can push three points of a small cap slightly outside a circle of radius r:
    // accept up to 20 % and put the centre on their plane then.
    if rho2 > 1.44 * r * r {
        return None;
    }
    let m = a + to_m;
    let h = (r * r - rho2).max(0.0).sqrt();
    let mut nhat = n / n2.sqrt();
    if nhat.dot(&m) < 0.0 {
        nhat = -nhat;
    }
    Some(m + nhat * h)
}

/// MSAC cost (truncated squared orthogonal distance) and inlier count over every
/// `stride`-th point.
#[inline]
fn msac_cost(points: &[Vector3<f64>], stride: usize, c: &Vector3<f64>, r: f64, t2: f64) -> (f64, u32) {
    let (mut cost, mut n) = (0.0, 0u32);
    let mut i = 0;
    while i < points.len() {
        let e = (points[i] - c).norm() - r;
        let e2 = e * e;
        if e2 < t2 {
            n += 1;
            cost += e2;
        } else {
            cost += t2;
        }
        i += stride;
    }
    (cost, n)
}

/// Hypotheses RANSAC still needs, after finding one with inlier fraction `eps`, to have
/// drawn an all-inlier sample of `k` points with 99.9 % probability.
pub(crate) fn ransac_needed(eps: f64, k: i32) -> u32 {
    let p_good = eps.clamp(0.0, 1.0).powi(k);
    if p_good >= 1.0 - 1e-12 {
        return 0;
    }
    if p_good <= 1e-12 {
        return u32::MAX;
    }
    ((1.0f64 - 0.999).ln() / (1.0 - p_good).ln())
        .ceil()
        .min(u32::MAX as f64) as u32
}

/// Depth at which the pixel ray of `p` (camera frame, Z = depth) enters the sphere (c, r),
/// and its gradient with respect to c; `None` if the ray misses or grazes the sphere.
#[inline]
fn ray_depth(p: &Vector3<f64>, c: &Vector3<f64>, r: f64) -> Option<(f64, Vector3<f64>)> {
    let d = Vector3::new(p.x / p.z, p.y / p.z, 1.0);
    let a = d.norm_squared();
    let b = d.dot(c);
    let disc = b * b - a * (c.norm_squared() - r * r);
    if disc < 0.0 {
        return None;
    }
    let t = (b - disc.sqrt()) / a;
    let n = d * t - c;
    let nd = n.dot(&d);
    // Near-tangent rays: the depth is ill-defined and its gradient unbounded.
    if nd.abs() < 0.15 * r * a.sqrt() {
        return None;
    }
    Some((t, n / nd))
}

/// Result of the depth-domain least squares.
#[derive(Debug, Clone, Copy)]
struct DepthFit {
    centre: Vector3<f64>,
    /// Σ g gᵀ over the inliers (g = ∂depth/∂c): the information matrix up to σ².
    info: Matrix3<f64>,
    rms: f64,
}

fn is_depth_inlier(p: &Vector3<f64>, c: &Vector3<f64>, r: f64, t: f64) -> bool {
    ray_depth(p, c, r).is_some_and(|(z, _)| (p.z - z).abs() < t)
}

/// Moves the inliers of `c` to the front of `points`; returns how many there are. Depth
/// inliers, or (`geometric`) points within `t` of the surface, as RANSAC scored them.
fn partition_inliers(points: &mut [Vector3<f64>], c: &Vector3<f64>, r: f64, t: f64, geometric: bool) -> usize {
    let mut k = 0;
    for i in 0..points.len() {
        let inlier = if geometric {
            ((points[i] - c).norm() - r).abs() < t
        } else {
            is_depth_inlier(&points[i], c, r, t)
        };
        if inlier {
            points.swap(i, k);
            k += 1;
        }
    }
    k
}

/// Gauss–Newton on Σ (z − depth(c))² over `inliers`, from `c0`, at most `iterations` steps.
fn refine_depth(inliers: &[Vector3<f64>], c0: &Vector3<f64>, r: f64, iterations: u32) -> Option<DepthFit> {
    let mut c = *c0;
    for _ in 0..iterations {
        let mut a = Matrix3::zeros();
        let mut g = Vector3::zeros();
        for p in inliers {
            let Some((z, grad)) = ray_depth(p, &c, r) else {
                continue;
            };
            a += grad * grad.transpose();
            g += grad * (p.z - z);
        }
        let step = a.cholesky()?.solve(&g);
        if !step.iter().all(|v| v.is_finite()) {
            return None;
        }
        c += step;
        // A micrometre is far below the noise; Gauss–Newton is quadratic here anyway.
        if step.norm() < 1e-6 {
            break;
        }
    }
    let (mut n, mut ss, mut info) = (0u32, 0.0, Matrix3::zeros());
    for p in inliers {
        if let Some((z, grad)) = ray_depth(p, &c, r) {
            n += 1;
            ss += (p.z - z) * (p.z - z);
            info += grad * grad.transpose();
        }
    }
    if n == 0 {
        return None;
    }
    Some(DepthFit {
        centre: c,
        info,
        rms: (ss / n as f64).sqrt(),
    })
}

/// The depth part of a fit, kept for [`combine_with_silhouette`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DepthOnlyFit {
    pub fit: SphereFit,
    radius_mm: f64,
}

/// Step 1: RANSAC and depth-domain least squares on the points with depth. Reorders
/// `points`: on success the depth inliers come first (`fit.inliers` of them).
pub fn fit_depth(
    points: &mut [Vector3<f64>],
    radius_mm: f64,
    p: &SphereFitParams,
    rng: &mut ChaCha8Rng,
) -> Result<DepthOnlyFit, FitFailure> {
    let n = points.len();
    let needed = p.min_inliers.max(3);
    if n < needed as usize {
        return Err(FitFailure::TooFewPoints {
            points: n as u32,
            needed,
        });
    }
    let r = radius_mm;
    let t2 = p.inlier_mm * p.inlier_mm;
    let stride = n.div_ceil(p.max_score_points.max(3) as usize).max(1);
    let scored = n.div_ceil(stride) as f64;

    // Hypothesis 0 is deterministic: for a cap seen head-on the points' mean depth lies 2r/3
    // in front of the centre (mean of √(r² − ρ²) over a disc).
    let mean = points.iter().fold(Vector3::zeros(), |s, q| s + q) / n as f64;
    let mut best = mean + mean.normalize() * (2.0 * r / 3.0);
    let (mut best_cost, best_n) = msac_cost(points, stride, &best, r, t2);
    // At least a few draws even when hypothesis 0 looks good: with a loose threshold a
    // centre off by a fraction of a small radius still has most points "inside".
    const MIN_DRAWS: u32 = 12;
    let mut needed_iters = ransac_needed(best_n as f64 / scored, 3)
        .max(MIN_DRAWS)
        .min(p.iterations);
    let mut it = 0;
    while it < needed_iters {
        it += 1;
        let i = rng.random_range(0..n);
        let j = rng.random_range(0..n);
        let k = rng.random_range(0..n);
        if i == j || j == k || i == k {
            continue;
        }
        let Some(c) = centre_from_three(&points[i], &points[j], &points[k], r) else {
            continue;
        };
        let (cost, n_in) = msac_cost(points, stride, &c, r, t2);
        if cost < best_cost {
            best_cost = cost;
            best = c;
            needed_iters = needed_iters.min(ransac_needed(n_in as f64 / scored, 3).max(MIN_DRAWS));
        }
    }
    if !best.iter().all(|v| v.is_finite()) {
        return Err(FitFailure::NoHypothesis);
    }
    let too_few = |inliers: u32| FitFailure::TooFewInliers {
        inliers,
        points: n as u32,
        needed,
        min_fraction: p.min_inlier_fraction,
    };
    // Least squares on the inliers of an evenly strided subset (gathered to the front),
    // re-selecting them from the refined centre until the set is stable (at most three
    // rounds).
    let fit_stride = n.div_ceil(p.max_fit_points.max(needed) as usize).max(1);
    let m = n.div_ceil(fit_stride);
    for i in 1..m {
        points.swap(i, i * fit_stride);
    }
    let m_needed = (needed as usize).min(m);
    let mut sel = best;
    let mut last_k = usize::MAX;
    for round in 0..3 {
        // The RANSAC centre may be off by a fraction of the radius, enough for rays at the
        // rim to miss it: the first selection uses RANSAC's own criterion.
        let k = partition_inliers(&mut points[..m], &sel, r, p.inlier_mm, round == 0);
        if k < m_needed || (k as f64) < p.min_inlier_fraction * m as f64 {
            return Err(too_few((k * fit_stride).min(n) as u32));
        }
        let f = refine_depth(&points[..k], &sel, r, 20).ok_or(FitFailure::Degenerate)?;
        sel = f.centre;
        if k == last_k {
            break;
        }
        last_k = k;
    }
    // Every point: final inlier set (first in `points`), one more step, the statistics.
    let k = partition_inliers(points, &sel, r, p.inlier_mm, false);
    if k < needed as usize || (k as f64) < p.min_inlier_fraction * n as f64 {
        return Err(too_few(k as u32));
    }
    let f = refine_depth(&points[..k], &sel, r, if fit_stride > 1 { 2 } else { 0 }).ok_or(FitFailure::Degenerate)?;
    let k = k as u32;
    if f.rms > p.max_rms_mm {
        return Err(FitFailure::ResidualTooLarge {
            rms_mm: f.rms,
            max_mm: p.max_rms_mm,
        });
    }
    let cov = f.info.try_inverse().ok_or(FitFailure::Degenerate)? * (f.rms * f.rms).max(1e-4);
    Ok(DepthOnlyFit {
        fit: SphereFit {
            centre: f.centre,
            cov,
            rms_mm: f.rms,
            inliers: k,
            points: n as u32,
            silhouette_edges: 0,
            direction_only: false,
        },
        radius_mm: r,
    })
}

/// A circle on the unit sphere: the silhouette cone of a sphere.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Silhouette {
    /// Unit direction of the cone's axis (towards the centre).
    pub axis: Vector3<f64>,
    /// Sine of the cone's half-angle.
    pub sin_half_angle: f64,
    /// RMS angular distance of the inlier edges to the cone, rad.
    pub rms_rad: f64,
    pub inliers: u32,
    /// Mean resultant length of the inliers' directions around the axis: ~0 for a complete
    /// outline, → 1 for a short arc (which fixes the axis poorly).
    pub arc_concentration: f64,
    /// Covariance of the axis (a unit vector, so it lies across the axis), rad²: from the
    /// least-squares fit's normal equations and scatter, so a partial arc is uncertain along
    /// its symmetry line and sure across it. At least the half-pixel quantisation of edges.
    pub axis_cov: Matrix3<f64>,
    /// Standard deviation of the half-angle from the fit's scatter, rad.
    pub half_angle_sd: f64,
}

/// Angular distance of edge ray `e` from the cone (axis, half-angle with sine `sin_ha`).
/// Both angles are a few degrees at most, where the sine is the angle to 1e-6 relative:
/// no trigonometry per edge.
#[inline]
fn cone_residual(axis: &Vector3<f64>, sin_ha: f64, e: &Vector3<f64>) -> f64 {
    axis.cross(e).norm() - sin_ha
}

fn sin_from_cos(c: f64) -> f64 {
    (1.0 - c * c).max(0.0).sqrt()
}

/// Fits the silhouette cone to edge rays `edges` (unit vectors). `inlier_rad` is the
/// angular inlier threshold; edge positions are quantised to half a pixel, so about one
/// pixel's angle.
// Long: one RANSAC sphere fit with its inlier refinement, allocation-free on the real-time path.
pub fn fit_silhouette(
    edges: &[Vector3<f64>],
    inlier_rad: f64,
    iterations: u32,
    rng: &mut ChaCha8Rng,
) -> Option<Silhouette> {
    let n = edges.len();
    if n < 8 {
        return None;
    }
    let t2 = inlier_rad * inlier_rad;
    // The cone w·e = 1 (axis = w/|w|, cos of the half-angle = 1/|w|); a sphere seen from
    // outside subtends less than 60°.
    let from_w = |w: &Vector3<f64>| -> Option<(Vector3<f64>, f64)> {
        let norm = w.norm();
        let cos_a = 1.0 / norm;
        (norm.is_finite() && cos_a < 1.0 && cos_a > 0.5).then(|| (w / norm, sin_from_cos(cos_a)))
    };
    let score = |axis: &Vector3<f64>, sin_ha: f64| -> (f64, u32) {
        let (mut cost, mut k) = (0.0, 0u32);
        for e in edges {
            let r2 = cone_residual(axis, sin_ha, e).powi(2);
            if r2 < t2 {
                cost += r2;
                k += 1;
            } else {
                cost += t2;
            }
        }
        (cost, k)
    };
    let lsq = |axis_sel: Option<(Vector3<f64>, f64)>| -> Option<(Vector3<f64>, f64)> {
        let mut a = Matrix3::zeros();
        let mut b = Vector3::zeros();
        for e in edges {
            if let Some((ax, sh)) = axis_sel {
                if cone_residual(&ax, sh, e).abs() >= inlier_rad {
                    continue;
                }
            }
            a += e * e.transpose();
            b += e;
        }
        from_w(&(a.try_inverse()? * b))
    };
    // Hypothesis 0: least squares over every edge; RANSAC only runs as long as a sample
    // could still beat the best (a clean outline needs none).
    let mut best: Option<(Vector3<f64>, f64, f64)> = None;
    let mut needed = iterations;
    if let Some((ax, sh)) = lsq(None) {
        let (c, k) = score(&ax, sh);
        best = Some((ax, sh, c));
        needed = ransac_needed(k as f64 / n as f64, 3).min(iterations);
    }
    let mut it = 0;
    while it < needed {
        it += 1;
        let (i, j, k) = (rng.random_range(0..n), rng.random_range(0..n), rng.random_range(0..n));
        if i == j || j == k || i == k {
            continue;
        }
        let m = Matrix3::from_rows(&[edges[i].transpose(), edges[j].transpose(), edges[k].transpose()]);
        let Some(w) = m.try_inverse().map(|mi| mi * Vector3::repeat(1.0)) else {
            continue;
        };
        let Some((ax, sh)) = from_w(&w) else {
            continue;
        };
        let (c, k_in) = score(&ax, sh);
        if best.is_none_or(|b| c < b.2) {
            best = Some((ax, sh, c));
            needed = needed.min(ransac_needed(k_in as f64 / n as f64, 3));
        }
    }
    let (mut axis, mut sin_ha, _) = best?;
    for _ in 0..3 {
        let (ax, sh) = lsq(Some((axis, sin_ha)))?;
        let moved = (ax - axis).norm();
        axis = ax;
        sin_ha = sh;
        if moved < 1e-12 {
            break;
        }
    }
    let (mut ss, mut k, mut dir) = (0.0, 0u32, Vector3::zeros());
    let (mut m, mut alg_ss) = (Matrix3::zeros(), 0.0);
    let cos_ha = sin_from_cos(sin_ha);
    let w = axis / cos_ha;
    for e in edges {
        let res = cone_residual(&axis, sin_ha, e);
        if res.abs() < inlier_rad {
            ss += res * res;
            k += 1;
            let radial = e - axis * axis.dot(e);
            let len = radial.norm();
            if len > 0.0 {
                dir += radial / len;
            }
            m += e * e.transpose();
            alg_ss += (w.dot(e) - 1.0).powi(2);
        }
    }
    if k < 4 {
        return None;
    }
    // Linear least squares w·e = 1: cov(w) = s²·(Σ e eᵀ)⁻¹ with the residual variance s²
    // (three parameters), but never below the edge quantisation (uniform over a pixel,
    // seen through the cone: sin α times the angle). The axis w/|w| moves across itself by
    // the part of δw perpendicular to it, divided by |w|.
    let pixel_rad = inlier_rad;
    let s2_floor = (sin_ha / cos_ha * pixel_rad).powi(2) / 12.0;
    let s2 = if k > 3 {
        (alg_ss / (k - 3) as f64).max(s2_floor)
    } else {
        s2_floor
    };
    let cov_w = m.try_inverse()? * s2;
    let p_perp = Matrix3::identity() - axis * axis.transpose();
    let axis_cov = p_perp * cov_w * p_perp * (cos_ha * cos_ha);
    // cos α = 1/|w|: δ(cos α) = −cos²α·(a·δw), δα = −δ(cos α)/sin α.
    let var_norm_w = (axis.transpose() * cov_w * axis)[0];
    let half_angle_sd = var_norm_w.max(0.0).sqrt() * cos_ha * cos_ha / sin_ha.max(1e-12);
    if !(axis_cov.iter().all(|v| v.is_finite()) && half_angle_sd.is_finite()) {
        return None;
    }
    Some(Silhouette {
        axis,
        sin_half_angle: sin_ha,
        rms_rad: (ss / k as f64).sqrt(),
        inliers: k,
        arc_concentration: dir.norm() / k as f64,
        axis_cov,
        half_angle_sd,
    })
}

/// Gates of the silhouette step.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SilhouetteGates {
    /// Least inlier edges.
    pub min_edges: u32,
    /// Largest arc concentration (see [`Silhouette::arc_concentration`]).
    pub max_arc_concentration: f64,
    /// Largest distance between the depth fit's centre and the silhouette axis, in units of
    /// the depth fit's lateral standard deviation (at least `min_agreement_mm`), beyond which
    /// the two disagree and the centre's covariance grows by their difference.
    pub agreement_sigmas: f64,
    pub min_agreement_mm: f64,
    /// Angular size of one pixel, rad.
    pub pixel_rad: f64,
    /// Allowed systematic error of an outline's apparent radius, rad: the range uncertainty
    /// of a sphere known by its outline alone (see [`outline_range`]).
    pub size_bias_rad: f64,
    /// Whether a result may be a line of sight only ([`SphereFit::direction_only`]); the base
    /// frame needs true centres, the joint fit can use lines of sight.
    pub allow_direction_only: bool,
}

/// Range of a sphere of radius `r` from its outline alone, ρ = r / sin α, and its standard
/// deviation (fit scatter and `size_bias_rad`, through δρ = −ρ·cot α·δα).
pub fn outline_range(sil: &Silhouette, r: f64, size_bias_rad: f64) -> (f64, f64) {
    let sin_a = sil.sin_half_angle.max(1e-9);
    let rho = r / sin_a;
    let cot_a = sin_from_cos(sin_a) / sin_a;
    (
        rho,
        rho * cot_a * (sil.half_angle_sd.powi(2) + size_bias_rad.powi(2)).sqrt(),
    )
}

/// A line of sight from the outline, with the range of [`outline_range`].
fn line_of_sight(sil: &Silhouette, r: f64, size_bias_rad: f64, rms_mm: f64, inliers: u32, points: u32) -> SphereFit {
    let (rho, sd) = outline_range(sil, r, size_bias_rad);
    let a = sil.axis;
    SphereFit {
        centre: a * rho,
        cov: a * a.transpose() * (sd * sd) + sil.axis_cov * (rho * rho),
        rms_mm,
        inliers,
        points,
        silhouette_edges: sil.inliers,
        direction_only: true,
    }
}

/// Step 3: puts the centre on the silhouette axis at the range the depth residuals give,
/// when the silhouette is good and agrees with the depth fit; returns the depth fit
/// otherwise.
pub fn combine_with_silhouette(
    depth: &DepthOnlyFit,
    points: &[Vector3<f64>],
    sil: Option<&Silhouette>,
    gates: &SilhouetteGates,
) -> SphereFit {
    let base = depth.fit;
    let Some(s) = sil else {
        return base;
    };
    if s.inliers < gates.min_edges || s.arc_concentration > gates.max_arc_concentration {
        return base;
    }
    let a = s.axis;
    let c_d = base.centre;
    let lateral = c_d - a * a.dot(&c_d);
    // Depth-only lateral standard deviation: the largest variance across the axis.
    let p_perp = Matrix3::identity() - a * a.transpose();
    let lat_var = (p_perp * base.cov * p_perp).symmetric_eigenvalues().max();
    let allowed = (gates.agreement_sigmas * lat_var.max(0.0).sqrt()).max(gates.min_agreement_mm);
    // When the two disagree, one of them is wrong. On the synthetic camera it has been the
    // depth fit every time (a small cap seen in part, with depths of the occluder's edge
    // among its points; the outline's edges next to a nearer surface are already dropped):
    // a jaw sphere then keeps the outline's line of sight only, with the loose range of its
    // size. A base sphere (large, many points) keeps the fusion, its covariance grown by
    // the disagreement so that nothing rests on it with false confidence.
    let disagree = lateral.norm() > allowed;
    if disagree && gates.allow_direction_only {
        return line_of_sight(
            s,
            depth.radius_mm,
            gates.size_bias_rad,
            base.rms_mm,
            base.inliers,
            base.points,
        );
    }
    let disagreement = if disagree {
        lateral * lateral.transpose()
    } else {
        Matrix3::zeros()
    };
    // Information-form fusion: the depth fit (all three directions) and the outline (the
    // centre is on its axis: two directions across it, sure to its axis covariance). For a
    // small sphere the outline dominates across the line of sight and depth along it; for a
    // large, close one both carry lateral information of similar weight.
    let Some(i_d) = base.cov.try_inverse() else {
        return base;
    };
    let rho = a.dot(&c_d);
    let eig = (s.axis_cov * (rho * rho)).symmetric_eigen();
    let mut i_s = Matrix3::zeros();
    for k in 0..3 {
        let l = eig.eigenvalues[k];
        // The axis direction itself has (numerically) zero variance: no information there.
        if l > 1e-12 && eig.eigenvectors.column(k).dot(&a).abs() < 0.5 {
            let v = eig.eigenvectors.column(k);
            i_s += v * v.transpose() / l;
        }
    }
    let c_line = a * rho;
    let info = i_d + i_s;
    let Some(cov) = info.try_inverse() else {
        return base;
    };
    let c = cov * (i_d * c_d + i_s * c_line);
    if !c.iter().all(|v| v.is_finite()) {
        return base;
    }
    let (r, inliers) = (depth.radius_mm, &points[..(base.inliers as usize).min(points.len())]);
    let (mut n, mut ss) = (0u32, 0.0);
    for p in inliers {
        if let Some((z, _)) = ray_depth(p, &c, r) {
            n += 1;
            ss += (p.z - z) * (p.z - z);
        }
    }
    SphereFit {
        centre: c,
        cov: cov + disagreement,
        rms_mm: if n > 0 { (ss / n as f64).sqrt() } else { base.rms_mm },
        inliers: n.max(1),
        points: base.points,
        silhouette_edges: s.inliers,
        direction_only: false,
    }
}

/// Centre of a sphere with too few depth points for [`fit_depth`] but a good silhouette
/// (a 2 mm sphere half in a stereo shadow keeps its outline in colour): the outline gives
/// the direction, a robust one-dimensional fit of the few depths the range. The range must
/// agree with the outline's angular size (ρ = r / sin α) within 10 % or three of its
/// standard deviations, so a stray background depth cannot place the sphere.
///
/// With fewer than `min_points` usable depths and `gates.allow_direction_only`, the range is
/// ρ = r / sin α itself, with a standard deviation that includes `gates.size_bias_rad` (a
/// systematic error of the outline's apparent radius: how a real camera's blur and the
/// colour thresholds place the mask edge). That is about 10 % of the range: the result is
/// flagged [`SphereFit::direction_only`], a line of sight with a loose range, and at least
/// one depth reading must agree with it. Reorders `points` (inliers first).
pub fn fit_from_silhouette(
    points: &mut [Vector3<f64>],
    radius_mm: f64,
    sil: &Silhouette,
    gates: &SilhouetteGates,
    inlier_mm: f64,
    min_points: u32,
) -> Option<SphereFit> {
    if sil.inliers < gates.min_edges || sil.arc_concentration > gates.max_arc_concentration {
        return None;
    }
    let (a, r) = (sil.axis, radius_mm);
    let (rho_alpha, sd_rho_alpha) = outline_range(sil, r, gates.size_bias_rad);
    let tol_rho = (0.1 * rho_alpha).max(3.0 * sd_rho_alpha);
    // Each point's own range (one Newton step from the outline's).
    let t0 = |rho: f64, p: &Vector3<f64>| ray_depth(p, &(a * rho), r).map(|(z, g)| (z, g.dot(&a)));
    let mut rho_i = [0.0f64; 64];
    let mut m = 0;
    for p in points.iter() {
        if m == rho_i.len() {
            break;
        }
        if let Some((z, h)) = t0(rho_alpha, p) {
            if h.abs() > 1e-9 {
                rho_i[m] = rho_alpha + (p.z - z) / h;
                m += 1;
            }
        }
    }
    if m >= min_points as usize {
        if let Some(fit) = range_from_depths(points, &mut rho_i[..m], a, r, inlier_mm, min_points) {
            let rho = a.dot(&fit.0);
            if (rho - rho_alpha).abs() <= tol_rho {
                return Some(SphereFit {
                    centre: fit.0,
                    cov: a * a.transpose() * fit.1 + sil.axis_cov * (rho * rho),
                    rms_mm: fit.2,
                    inliers: fit.3,
                    points: points.len() as u32,
                    silhouette_edges: sil.inliers,
                    direction_only: false,
                });
            }
        }
    }
    if !gates.allow_direction_only {
        return None;
    }
    let agree = rho_i[..m].iter().filter(|x| (**x - rho_alpha).abs() <= tol_rho).count() as u32;
    if agree == 0 {
        return None;
    }
    let (mut ss, mut n) = (0.0, 0u32);
    for p in points.iter() {
        if let Some((z, _)) = t0(rho_alpha, p) {
            if (p.z - z).abs() <= tol_rho {
                ss += (p.z - z).powi(2);
                n += 1;
            }
        }
    }
    let rms = (ss / n.max(1) as f64).sqrt();
    Some(line_of_sight(
        sil,
        r,
        gates.size_bias_rad,
        rms,
        agree,
        points.len() as u32,
    ))
}

/// The range along `a` from a few depths: median of the points' own ranges `rho_i`, then
/// Gauss–Newton on the inliers. Returns (centre, range variance, RMS, inliers).
fn range_from_depths(
    points: &mut [Vector3<f64>],
    rho_i: &mut [f64],
    a: Vector3<f64>,
    r: f64,
    inlier_mm: f64,
    min_points: u32,
) -> Option<(Vector3<f64>, f64, f64, u32)> {
    let t0 = |rho: f64, p: &Vector3<f64>| ray_depth(p, &(a * rho), r).map(|(z, g)| (z, g.dot(&a)));
    rho_i.sort_unstable_by(f64::total_cmp);
    let mut rho = rho_i[rho_i.len() / 2];
    let mut k = 0;
    for i in 0..points.len() {
        if t0(rho, &points[i]).is_some_and(|(z, _)| (points[i].z - z).abs() < inlier_mm) {
            points.swap(i, k);
            k += 1;
        }
    }
    if k < min_points as usize || 2 * k < points.len() {
        return None;
    }
    let inliers = &points[..k];
    let sums = |rho: f64| {
        let (mut hh, mut hg, mut ss, mut n) = (0.0, 0.0, 0.0, 0u32);
        for p in inliers {
            if let Some((z, h)) = t0(rho, p) {
                hh += h * h;
                hg += h * (p.z - z);
                ss += (p.z - z) * (p.z - z);
                n += 1;
            }
        }
        (hh, hg, ss, n)
    };
    for _ in 0..10 {
        let (hh, hg, ..) = sums(rho);
        if hh <= 0.0 {
            return None;
        }
        rho += hg / hh;
        if (hg / hh).abs() < 1e-7 {
            break;
        }
    }
    let (hh, _, ss, n) = sums(rho);
    if n < min_points || hh <= 0.0 || !rho.is_finite() {
        return None;
    }
    // A few points say little about their own scatter (and one of them may sit on an
    // edge): assume at least half the inlier threshold per point.
    let rms = (ss / n as f64).sqrt();
    Some((a * rho, rms.max(inlier_mm / 2.0).powi(2) / hh, rms, n))
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;
    use rand_distr::{Distribution, Normal};

    fn params() -> SphereFitParams {
        SphereFitParams {
            iterations: 48,
            inlier_mm: 1.5,
            max_score_points: 200,
            min_inliers: 12,
            min_inlier_fraction: 0.5,
            max_rms_mm: 1.5,
            max_fit_points: 300,
        }
    }

    const F: f64 = 615.0;

    /// The cap of a sphere as a pinhole camera sees it: per pixel inside the outline, the
    /// back-projected point with Gaussian depth noise quantised to 1 mm (when
    /// `max_incidence_deg` allows depth there), and the outline's edge rays.
    fn cap(centre: Vector3<f64>, r: f64, sigma: f64, rng: &mut ChaCha8Rng) -> (Vec<Vector3<f64>>, Vec<Vector3<f64>>) {
        let noise = Normal::new(0.0, sigma).unwrap();
        let (u0, v0) = (F * centre.x / centre.z, F * centre.y / centre.z);
        let rad_px = (F * r / centre.z).ceil() as i64 + 2;
        let hit = |u: f64, v: f64| {
            let d = Vector3::new(u / F, v / F, 1.0);
            let a = d.norm_squared();
            let b = d.dot(&centre);
            let disc = b * b - a * (centre.norm_squared() - r * r);
            (disc >= 0.0).then(|| {
                let t = (b - disc.sqrt()) / a;
                let n = (d * t - centre) / r;
                (t, -n.dot(&d) / a.sqrt())
            })
        };
        let (mut pts, mut edges) = (Vec::new(), Vec::new());
        for dv in -rad_px..=rad_px {
            for du in -rad_px..=rad_px {
                let (u, v) = ((u0.round() as i64 + du) as f64, (v0.round() as i64 + dv) as f64);
                let Some((t, cos_inc)) = hit(u, v) else { continue };
                for (nu, nv) in [(u + 1.0, v), (u - 1.0, v), (u, v + 1.0), (u, v - 1.0)] {
                    if hit(nu, nv).is_none() {
                        edges.push(Vector3::new((u + nu) / 2.0 / F, (v + nv) / 2.0 / F, 1.0).normalize());
                    }
                }
                if cos_inc < 72f64.to_radians().cos() {
                    continue;
                }
                let z = (t + noise.sample(rng)).round();
                pts.push(Vector3::new(u * z / F, v * z / F, z));
            }
        }
        (pts, edges)
    }

    fn gates() -> SilhouetteGates {
        SilhouetteGates {
            min_edges: 12,
            max_arc_concentration: 0.5,
            agreement_sigmas: 4.0,
            min_agreement_mm: 0.5,
            pixel_rad: 1.0 / F,
            size_bias_rad: 0.5 / F,
            allow_direction_only: true,
        }
    }

    /// Gates of a base sphere: no line-of-sight results.
    fn no_los() -> SilhouetteGates {
        SilhouetteGates {
            allow_direction_only: false,
            ..gates()
        }
    }

    #[test]
    fn exact_cap_gives_exact_centre() {
        let mut rng = ChaCha8Rng::seed_from_u64(1);
        let c = Vector3::new(12.0, -8.0, 240.0);
        // No noise, but depth quantised to 1 mm as the sensor does.
        let (mut pts, _) = cap(c, 5.0, 0.0, &mut rng);
        let fit = fit_depth(&mut pts, 5.0, &params(), &mut rng).unwrap().fit;
        // Quantised to 1 mm, the centre is still within a fraction of a millimetre.
        assert!((fit.centre - c).norm() < 0.2, "{:?}", fit.centre - c);
    }

    #[test]
    fn silhouette_recovers_the_axis_and_combination_beats_depth_alone() {
        let mut rng = ChaCha8Rng::seed_from_u64(2);
        let (mut e_depth, mut e_comb) = (0.0, 0.0);
        let trials = 30;
        for k in 0..trials {
            let c = Vector3::new(-20.0 + 1.3 * k as f64, 10.0 - 0.7 * k as f64, 210.0 + k as f64);
            let (mut pts, edges) = cap(c, 2.0, 0.5, &mut rng);
            // 15 % outliers: background depth behind the silhouette.
            let n_out = pts.len() * 15 / 100;
            for i in 0..n_out {
                let p = pts[i * 6 % pts.len()];
                pts.push(p * 1.3);
            }
            let d = fit_depth(&mut pts, 2.0, &params(), &mut rng).unwrap();
            let sil = fit_silhouette(&edges, 1.0 / F, 32, &mut rng).unwrap();
            assert!(sil.arc_concentration < 0.1, "{sil:?}");
            let axis_err = sil.axis.angle(&c.normalize()) * F;
            assert!(axis_err < 0.2, "silhouette axis off by {axis_err} px");
            let comb = combine_with_silhouette(&d, &pts, Some(&sil), &gates());
            assert!(comb.silhouette_edges > 0);
            e_depth += (d.fit.centre - c).norm_squared();
            e_comb += (comb.centre - c).norm_squared();
            // The reported covariance is of the right size: the error within ~4 sigma.
            let err = comb.centre - c;
            let m = err.transpose() * comb.cov.try_inverse().unwrap() * err;
            assert!(m[0] < 25.0, "trial {k}: Mahalanobis² {} for error {err:?}", m[0]);
        }
        let (rd, rc) = ((e_depth / trials as f64).sqrt(), (e_comb / trials as f64).sqrt());
        assert!(rc < 0.15, "combined RMS error {rc} mm (depth only {rd})");
        assert!(rc < rd, "combined {rc} vs depth only {rd}");
    }

    #[test]
    fn occluded_outline_is_not_trusted_blindly() {
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        let c = Vector3::new(5.0, 5.0, 220.0);
        let (mut pts, edges) = cap(c, 2.0, 0.5, &mut rng);
        // Keep a quarter of the outline: the arc fixes the axis poorly and is refused.
        let arc: Vec<_> = edges
            .iter()
            .copied()
            .filter(|e| e.x / e.z > c.x / c.z && e.y / e.z > c.y / c.z)
            .collect();
        let d = fit_depth(&mut pts, 2.0, &params(), &mut rng).unwrap();
        let sil = fit_silhouette(&arc, 1.0 / F, 32, &mut rng);
        let comb = combine_with_silhouette(&d, &pts, sil.as_ref(), &gates());
        assert_eq!(comb.silhouette_edges, 0, "{sil:?}");
        assert_eq!(comb.centre, d.fit.centre);
    }

    #[test]
    fn few_depth_points_with_a_full_outline() {
        let mut rng = ChaCha8Rng::seed_from_u64(6);
        let c = Vector3::new(-8.0, 6.0, 230.0);
        let (pts, edges) = cap(c, 2.0, 0.5, &mut rng);
        // Six depth points survive (the rest is in a stereo shadow), plus a background one.
        let mut few: Vec<_> = pts.iter().step_by(pts.len() / 6).take(6).copied().collect();
        few.push(few[0] * 1.3);
        assert!(matches!(
            fit_depth(&mut few.clone(), 2.0, &params(), &mut rng),
            Err(FitFailure::TooFewPoints { .. })
        ));
        let sil = fit_silhouette(&edges, 1.0 / F, 32, &mut rng).unwrap();
        let fit = fit_from_silhouette(&mut few, 2.0, &sil, &no_los(), 1.5, 4).unwrap();
        assert!(!fit.direction_only);
        assert!((fit.centre - c).norm() < 0.5, "{:?}", fit.centre - c);
        let lateral = (fit.centre - c) - c.normalize() * c.normalize().dot(&(fit.centre - c));
        assert!(lateral.norm() < 0.1, "lateral error {}", lateral.norm());
        assert_eq!(fit.inliers, 6, "the background point is not an inlier");
        // Depths that disagree with the outline's size are refused.
        let mut far: Vec<_> = few.iter().map(|p| p * 1.5).collect();
        assert!(fit_from_silhouette(&mut far.clone(), 2.0, &sil, &no_los(), 1.5, 4).is_none());
        assert!(fit_from_silhouette(&mut far, 2.0, &sil, &gates(), 1.5, 4).is_none());

        // Two depths: a line of sight with a loose range, if allowed.
        let mut two: Vec<_> = few[..2].to_vec();
        assert!(fit_from_silhouette(&mut two.clone(), 2.0, &sil, &no_los(), 1.5, 4).is_none());
        let fit = fit_from_silhouette(&mut two, 2.0, &sil, &gates(), 1.5, 4).unwrap();
        assert!(fit.direction_only);
        let err = fit.centre - c;
        let along = c.normalize().dot(&err);
        assert!(
            (err - c.normalize() * along).norm() < 0.1,
            "line of sight off by {err:?}"
        );
        let sd_range = (c.normalize().transpose() * fit.cov * c.normalize())[0].sqrt();
        assert!(
            sd_range > 5.0 && along.abs() < 3.0 * sd_range,
            "range error {along} mm, sd {sd_range} mm"
        );
    }

    #[test]
    fn failures_are_typed() {
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let mut few = vec![Vector3::new(0.0, 0.0, 100.0); 5];
        assert!(matches!(
            fit_depth(&mut few, 2.0, &params(), &mut rng),
            Err(FitFailure::TooFewPoints { points: 5, needed: 12 })
        ));
        // A slanted wall is not a 2 mm sphere.
        let mut wall = Vec::new();
        for i in 0..30 {
            for j in 0..30 {
                wall.push(Vector3::new(i as f64 * 0.4, j as f64 * 0.4, 300.0 + i as f64 * 0.4));
            }
        }
        let e = fit_depth(&mut wall, 2.0, &params(), &mut rng).unwrap_err();
        assert!(
            matches!(
                e,
                FitFailure::TooFewInliers { .. } | FitFailure::ResidualTooLarge { .. } | FitFailure::Degenerate
            ),
            "{e:?}"
        );
    }

    #[test]
    fn deterministic_for_a_seed() {
        let mut rng = ChaCha8Rng::seed_from_u64(4);
        let (mut pts, _) = cap(Vector3::new(3.0, 4.0, 250.0), 2.0, 0.5, &mut rng);
        let mut pts2 = pts.clone();
        let a = fit_depth(&mut pts, 2.0, &params(), &mut ChaCha8Rng::seed_from_u64(9)).unwrap();
        let b = fit_depth(&mut pts2, 2.0, &params(), &mut ChaCha8Rng::seed_from_u64(9)).unwrap();
        assert_eq!(a, b);
    }
}
