//! The synthetic RGBD camera: renders the 7 marker spheres, the manipulator body and a
//! background into caller-provided buffers, then applies a D435-like sensor model.
//!
//! Rendering is analytic ray casting restricted to each primitive's conservative screen
//! bounding box, with a z-buffer: exact depth and normals per pixel, cost proportional to
//! the pixels each primitive covers. The static background (the camera and the plane do not
//! move) is rendered once at construction and copied in each frame.

use bowden_interfaces::{RgbdFrameHeader, SampleHeader, N_MARKERS};
use bowden_kinematics::markers::MarkerGeometry;
use bowden_kinematics::{JointsDeg, Robot};
use nalgebra::{Isometry3, Point3, Vector3};
use rand::{RngCore, SeedableRng};
use rand_chacha::ChaCha8Rng;

use crate::config::{CameraConfig, Intrinsics};
use crate::noise::{
    color_noise_table, gauss_table, linear_to_srgb_table, mix64, srgb_to_linear, GAUSS_BITS, LIN_TO_SRGB_LEN,
};
use crate::record::StreamInfo;
use crate::CameraError;

/// What each pixel of the last render shows ([`SyntheticCamera::labels`]): the low 7 bits
/// name the surface, bit 7 says the sensor returned no depth there for a geometric reason
/// (silhouette, edge, stereo shadow; random dropout and range limits are not flagged).
pub mod label {
    pub const BACKGROUND: u8 = 0;
    /// Marker `i` (index as in `bowden_interfaces::marker`) is label `MARKER0 + i`.
    pub const MARKER0: u8 = 1;
    pub const BODY: u8 = 8;
    pub const JAW_LEFT: u8 = 9;
    pub const JAW_RIGHT: u8 = 10;
    pub const SHAFT: u8 = 11;
    /// Nothing (the background plane is not hit): black, no depth.
    pub const VOID: u8 = 12;
    pub const WHAT_MASK: u8 = 0x7f;
    pub const NO_DEPTH: u8 = 0x80;
    /// The label of marker `i`.
    pub const fn marker(i: usize) -> u8 {
        MARKER0 + i as u8
    }
}

/// Closest distance along the optical axis anything is rendered at, mm.
const NEAR_MM: f32 = 1.0;

#[derive(Debug, Clone, Copy)]
enum Shape {
    Sphere { c: [f32; 3], r: f32 },
    Capsule { a: [f32; 3], b: [f32; 3], r: f32 },
}

#[derive(Debug, Clone, Copy)]
struct Prim {
    shape: Shape,
    label: u8,
    /// Linear albedo.
    albedo: [f32; 3],
}

/// Inclusive pixel rectangle.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Rect {
    u0: usize,
    u1: usize,
    v0: usize,
    v1: usize,
}

impl Rect {
    fn union(self, o: Rect) -> Rect {
        Rect {
            u0: self.u0.min(o.u0),
            u1: self.u1.max(o.u1),
            v0: self.v0.min(o.v0),
            v1: self.v1.max(o.v1),
        }
    }
    fn grow(self, by: usize, w: usize, h: usize) -> Rect {
        Rect {
            u0: self.u0.saturating_sub(by),
            u1: (self.u1 + by).min(w - 1),
            v0: self.v0.saturating_sub(by),
            v1: (self.v1 + by).min(h - 1),
        }
    }
}

/// Precomputed shading constants.
#[derive(Debug, Clone)]
struct Shader {
    light: [f32; 3],
    ambient: f32,
    diffuse: f32,
    specular: f32,
    shininess: f32,
    cos_grazing: f32,
    lin_to_srgb: Vec<u8>,
}

impl Shader {
    /// sRGB colour of a surface with normal `n` seen along the (unnormalised) ray `d`.
    #[inline]
    fn shade(&self, albedo: &[f32; 3], n: [f32; 3], d: [f32; 3], inv_dlen: f32) -> [u8; 3] {
        let l = self.light;
        let ndl = (n[0] * l[0] + n[1] * l[1] + n[2] * l[2]).max(0.0);
        let k = self.ambient + self.diffuse * ndl;
        let mut spec = 0.0;
        if self.specular > 0.0 && ndl > 0.0 {
            // Blinn–Phong half vector between the light and the view direction (−d).
            let h = [l[0] - d[0] * inv_dlen, l[1] - d[1] * inv_dlen, l[2] - d[2] * inv_dlen];
            let hl = (h[0] * h[0] + h[1] * h[1] + h[2] * h[2]).sqrt();
            if hl > 1e-6 {
                let ndh = ((n[0] * h[0] + n[1] * h[1] + n[2] * h[2]) / hl).max(0.0);
                // Schlick's rational stand-in for ndh^shininess: no powf per pixel.
                let s = self.shininess;
                spec = self.specular * ndh / (s - s * ndh + ndh);
            }
        }
        let scale = (LIN_TO_SRGB_LEN - 1) as f32;
        let enc = |a: f32| {
            let lin = (a * k + spec).clamp(0.0, 1.0);
            self.lin_to_srgb[(lin * scale + 0.5) as usize]
        };
        [enc(albedo[0]), enc(albedo[1]), enc(albedo[2])]
    }
}

/// Where a frame's depth plane goes: a `u16` slice or the little-endian bytes of a payload.
trait DepthSink {
    fn row(&mut self, v: usize, w: usize, f: impl FnMut(usize) -> u16);
}

struct U16Sink<'a>(&'a mut [u16]);
impl DepthSink for U16Sink<'_> {
    #[inline]
    fn row(&mut self, v: usize, w: usize, mut f: impl FnMut(usize) -> u16) {
        for (u, out) in self.0[v * w..(v + 1) * w].iter_mut().enumerate() {
            *out = f(u);
        }
    }
}

struct LeBytesSink<'a>(&'a mut [u8]);
impl DepthSink for LeBytesSink<'_> {
    #[inline]
    fn row(&mut self, v: usize, w: usize, mut f: impl FnMut(usize) -> u16) {
        for (u, out) in self.0[2 * v * w..2 * (v + 1) * w].chunks_exact_mut(2).enumerate() {
            out.copy_from_slice(&f(u).to_le_bytes());
        }
    }
}

/// A D435-like RGBD camera rendering the paper's robot and markers.
///
/// Construction allocates every buffer; [`render`](Self::render) and
/// [`render_into_payload`](Self::render_into_payload) allocate nothing.
#[derive(Debug, Clone)]
pub struct SyntheticCamera {
    robot: Robot,
    markers: MarkerGeometry,
    cfg: CameraConfig,
    seed: u64,
    w: usize,
    h: usize,
    /// T^cam_base.
    cam_from_base: Isometry3<f64>,
    /// Ray direction (x/z, y/z) of each column / row, camera frame.
    ray_x: Vec<f32>,
    ray_y: Vec<f32>,
    bg_rgb: Vec<u8>,
    bg_z: Vec<f32>,
    bg_label: Vec<u8>,
    zbuf: Vec<f32>,
    labels: Vec<u8>,
    prims: Vec<Prim>,
    centreline: Vec<Point3<f64>>,
    shader: Shader,
    marker_albedo: [[f32; 3]; N_MARKERS],
    body_albedo: [f32; 3],
    jaw_albedo: [f32; 3],
    shaft_albedo: [f32; 3],
    rng_base: ChaCha8Rng,
    noise_row: Vec<u8>,
    gauss: Vec<f32>,
    /// Noisy 8-bit value for (clean value, 8 random bits): one lookup per channel.
    color_lut: Vec<u8>,
    dropout_threshold: u32,
}

fn lin3(rgb: [u8; 3]) -> [f32; 3] {
    [srgb_to_linear(rgb[0]), srgb_to_linear(rgb[1]), srgb_to_linear(rgb[2])]
}

fn f32x3(p: &Point3<f64>) -> [f32; 3] {
    [p.x as f32, p.y as f32, p.z as f32]
}

impl SyntheticCamera {
    /// Builds the camera for a robot and its markers. `seed` selects the noise: frame `k`
    /// of seed `s` is always the same bytes, whatever was rendered before.
    ///
    /// Panics if `cfg` is invalid, which a config from [`CameraConfig::load`] or
    /// [`CameraConfig::paper_default`] never is; use [`try_new`](Self::try_new) for a
    /// config assembled in code.
    pub fn new(robot: Robot, markers: MarkerGeometry, cfg: CameraConfig, seed: u64) -> Self {
        match Self::try_new(robot, markers, cfg, seed) {
            Ok(cam) => cam,
            Err(e) => panic!("SyntheticCamera::new: {e}"),
        }
    }

    /// [`new`](Self::new) that validates `cfg` first and says which field is wrong.
    pub fn try_new(robot: Robot, markers: MarkerGeometry, cfg: CameraConfig, seed: u64) -> Result<Self, CameraError> {
        cfg.validate(std::path::Path::new("<camera config>"))?;
        Ok(Self::build(robot, markers, cfg, seed))
    }

    fn build(robot: Robot, markers: MarkerGeometry, cfg: CameraConfig, seed: u64) -> Self {
        let k = cfg.intrinsics;
        let (w, h) = (k.width_px as usize, k.height_px as usize);
        let cam_from_base = cfg.pose.camera_in_base().inverse();
        let ray_x = (0..w).map(|u| ((u as f64 - k.cx_px) / k.fx_px) as f32).collect();
        let ray_y = (0..h).map(|v| ((v as f64 - k.cy_px) / k.fy_px) as f32).collect();
        let c = &cfg.color;
        let l = Vector3::from(c.light_dir_cam).normalize();
        let shader = Shader {
            light: [l.x as f32, l.y as f32, l.z as f32],
            ambient: c.ambient as f32,
            diffuse: c.diffuse as f32,
            specular: c.specular as f32,
            shininess: c.shininess as f32,
            cos_grazing: cfg.depth.silhouette_grazing_deg.to_radians().cos() as f32,
            lin_to_srgb: linear_to_srgb_table(),
        };
        let a = &cfg.appearance;
        let (red, blue, yellow, green) = (lin3(a.red_rgb), lin3(a.blue_rgb), lin3(a.yellow_rgb), lin3(a.green_rgb));
        let marker_albedo = [red, red, blue, red, blue, yellow, green];
        // A few spare entries: the centre line has one point per hinge plus base and pivot.
        let n_centre = 2 + 2 * robot.config.segment1.modules as usize + robot.config.segment2.modules as usize + 2;
        let mut cam = Self {
            markers,
            seed,
            w,
            h,
            cam_from_base,
            ray_x,
            ray_y,
            bg_rgb: vec![0; w * h * 3],
            bg_z: vec![f32::INFINITY; w * h],
            bg_label: vec![label::VOID; w * h],
            zbuf: vec![f32::INFINITY; w * h],
            labels: vec![label::VOID; w * h],
            prims: Vec::with_capacity(N_MARKERS + n_centre + 4),
            centreline: Vec::with_capacity(n_centre),
            shader,
            marker_albedo,
            body_albedo: lin3(a.body_rgb),
            jaw_albedo: lin3(a.jaw_rgb),
            shaft_albedo: lin3(a.shaft_rgb),
            rng_base: ChaCha8Rng::seed_from_u64(seed),
            noise_row: vec![0; w * 8],
            gauss: gauss_table(),
            color_lut: color_noise_table(c.read_noise_dn, c.shot_noise_gain_dn),
            dropout_threshold: (cfg.depth.dropout_prob * 65536.0).round() as u32,
            robot,
            cfg,
        };
        cam.render_background();
        cam
    }

    pub fn width(&self) -> u32 {
        self.w as u32
    }
    pub fn height(&self) -> u32 {
        self.h as u32
    }
    pub fn intrinsics(&self) -> &Intrinsics {
        &self.cfg.intrinsics
    }
    pub fn config(&self) -> &CameraConfig {
        &self.cfg
    }
    pub fn robot(&self) -> &Robot {
        &self.robot
    }
    pub fn markers(&self) -> &MarkerGeometry {
        &self.markers
    }
    pub fn seed(&self) -> u64 {
        self.seed
    }
    /// Millimetres per depth count.
    pub fn depth_unit_mm(&self) -> f64 {
        self.cfg.depth.unit_mm
    }
    /// Bytes of an interfaces RGBD payload for this camera (RGB8 plane + u16 depth plane).
    pub fn payload_len(&self) -> usize {
        RgbdFrameHeader::payload_len_for(self.w as u32, self.h as u32)
    }

    /// Ground truth T^cam_base: maps robot-base points to the camera frame (what eq. 6–7
    /// estimate from the base spheres).
    pub fn base_in_camera(&self) -> Isometry3<f64> {
        self.cam_from_base
    }

    /// Ground-truth centres of the 7 markers in the camera frame, mm, for configuration `q`.
    pub fn marker_centres_cam_mm(&self, q_phy_deg: &JointsDeg) -> [Point3<f64>; N_MARKERS] {
        let fk = self.robot.fk(q_phy_deg);
        self.markers
            .centres_base_mm(&fk)
            .map(|p| self.cam_from_base.transform_point(&p))
    }

    /// What each pixel of the last render shows (see [`label`]).
    pub fn labels(&self) -> &[u8] {
        &self.labels
    }

    /// Size, intrinsics and depth unit of this camera's stream (what a recording stores).
    pub fn stream_info(&self) -> StreamInfo {
        let k = &self.cfg.intrinsics;
        StreamInfo {
            width: self.w as u32,
            height: self.h as u32,
            fx: k.fx_px,
            fy: k.fy_px,
            cx: k.cx_px,
            cy: k.cy_px,
            depth_unit_mm: self.cfg.depth.unit_mm,
        }
    }

    /// The header of a frame of this camera.
    pub fn header(&self, seq: u64, tick: u64, t_origin_ns: u64) -> RgbdFrameHeader {
        self.stream_info().header(SampleHeader { seq, tick, t_origin_ns })
    }

    fn check_q(q: &JointsDeg) -> Result<(), CameraError> {
        match q.iter().position(|v| !v.is_finite()) {
            Some(j) => Err(CameraError::NonFiniteJoint {
                joint: j + 1,
                value_deg: q[j],
            }),
            None => Ok(()),
        }
    }

    fn check_len(&self, buffer: &'static str, got: usize, expected: usize) -> Result<(), CameraError> {
        if got == expected {
            Ok(())
        } else {
            Err(CameraError::BufferSize {
                buffer,
                expected,
                got,
                width: self.w as u32,
                height: self.h as u32,
            })
        }
    }

    /// Renders frame `frame_index` of configuration `q_phy_deg` into `rgb` (RGB8,
    /// width·height·3 bytes, row-major from the top left) and `depth_mm` (width·height
    /// depth counts of `depth_unit_mm`, 0 = no depth). Allocates nothing.
    pub fn render(
        &mut self,
        q_phy_deg: &JointsDeg,
        frame_index: u64,
        rgb: &mut [u8],
        depth_mm: &mut [u16],
    ) -> Result<(), CameraError> {
        Self::check_q(q_phy_deg)?;
        let px = self.w * self.h;
        self.check_len("rgb", rgb.len(), px * 3)?;
        self.check_len("depth", depth_mm.len(), px)?;
        self.draw(q_phy_deg, rgb);
        self.sense(frame_index, rgb, &mut U16Sink(depth_mm));
        Ok(())
    }

    /// Renders into an interfaces payload: the RGB8 plane then the little-endian u16 depth
    /// plane (`RgbdFrameHeader` layout). Allocates nothing.
    pub fn render_into_payload(
        &mut self,
        q_phy_deg: &JointsDeg,
        frame_index: u64,
        payload: &mut [u8],
    ) -> Result<(), CameraError> {
        Self::check_q(q_phy_deg)?;
        let px = self.w * self.h;
        self.check_len("payload", payload.len(), px * 5)?;
        let (rgb, depth) = payload.split_at_mut(px * 3);
        self.draw(q_phy_deg, rgb);
        self.sense(frame_index, rgb, &mut LeBytesSink(depth));
        Ok(())
    }

    /// The noise-free scene: shaded colour into `rgb`, depth into the z-buffer, labels.
    fn draw(&mut self, q: &JointsDeg, rgb: &mut [u8]) {
        rgb.copy_from_slice(&self.bg_rgb);
        self.zbuf.copy_from_slice(&self.bg_z);
        self.labels.copy_from_slice(&self.bg_label);
        self.build_primitives(q);
        let mut dirty: Option<Rect> = None;
        for i in 0..self.prims.len() {
            let p = self.prims[i];
            if let Some(r) = self.raster(&p, rgb) {
                dirty = Some(dirty.map_or(r, |d| d.union(r)));
            }
        }
        if let Some(d) = dirty {
            self.invalidate_edges(d);
            if self.cfg.depth.stereo_shadow {
                self.stereo_shadow(d);
            }
        }
    }

    /// Spheres and capsules of this configuration, in the camera frame.
    fn build_primitives(&mut self, q: &JointsDeg) {
        let t = self.cam_from_base;
        let fk = self.robot.fk(q);
        self.prims.clear();
        let centres = self.markers.centres_base_mm(&fk);
        let radii = self.markers.radii_mm();
        for i in 0..N_MARKERS {
            self.prims.push(Prim {
                shape: Shape::Sphere {
                    c: f32x3(&t.transform_point(&centres[i])),
                    r: radii[i] as f32,
                },
                label: label::marker(i),
                albedo: self.marker_albedo[i],
            });
        }
        let body_r = self.robot.config.hinge.module_radius_mm as f32;
        self.robot.centerline(q, &mut self.centreline);
        for k in 1..self.centreline.len() {
            let (a, b) = (self.centreline[k - 1], self.centreline[k]);
            self.prims.push(Prim {
                shape: Shape::Capsule {
                    a: f32x3(&t.transform_point(&a)),
                    b: f32x3(&t.transform_point(&b)),
                    r: body_r,
                },
                label: label::BODY,
                albedo: self.body_albedo,
            });
        }
        let jaw_len = self.robot.config.forceps.jaw_length_mm;
        let jaw_r = self.cfg.appearance.jaw_radius_mm as f32;
        for (frame, lab) in [(&fk.jaw_left, label::JAW_LEFT), (&fk.jaw_right, label::JAW_RIGHT)] {
            let a = t.transform_point(&(frame * Point3::origin()));
            let b = t.transform_point(&(frame * Point3::new(0.0, 0.0, jaw_len)));
            self.prims.push(Prim {
                shape: Shape::Capsule {
                    a: f32x3(&a),
                    b: f32x3(&b),
                    r: jaw_r,
                },
                label: lab,
                albedo: self.jaw_albedo,
            });
        }
        let shaft = self.cfg.appearance.shaft_length_mm;
        if shaft > 0.0 {
            let a = t.transform_point(&Point3::origin());
            let b = t.transform_point(&Point3::new(-shaft, 0.0, 0.0));
            self.prims.push(Prim {
                shape: Shape::Capsule {
                    a: f32x3(&a),
                    b: f32x3(&b),
                    r: body_r,
                },
                label: label::SHAFT,
                albedo: self.shaft_albedo,
            });
        }
    }

    /// Conservative pixel rectangle of a camera-frame box (None when off screen or behind).
    fn screen_rect(&self, lo: [f32; 3], hi: [f32; 3]) -> Option<Rect> {
        if lo.iter().chain(hi.iter()).any(|v| !v.is_finite()) || hi[2] <= NEAR_MM {
            return None;
        }
        let (z_near, z_far) = (lo[2].max(NEAR_MM), hi[2]);
        // Extremes of x/z over the box: largest x over the nearest z when x > 0, etc.
        let max_over = |v: f32| if v > 0.0 { v / z_near } else { v / z_far };
        let min_over = |v: f32| if v < 0.0 { v / z_near } else { v / z_far };
        let k = &self.cfg.intrinsics;
        let u_lo = k.fx_px as f32 * min_over(lo[0]) + k.cx_px as f32;
        let u_hi = k.fx_px as f32 * max_over(hi[0]) + k.cx_px as f32;
        let v_lo = k.fy_px as f32 * min_over(lo[1]) + k.cy_px as f32;
        let v_hi = k.fy_px as f32 * max_over(hi[1]) + k.cy_px as f32;
        let (wf, hf) = ((self.w - 1) as f32, (self.h - 1) as f32);
        if u_hi < 0.0 || v_hi < 0.0 || u_lo > wf || v_lo > hf {
            return None;
        }
        Some(Rect {
            u0: u_lo.ceil().max(0.0) as usize,
            u1: u_hi.floor().min(wf) as usize,
            v0: v_lo.ceil().max(0.0) as usize,
            v1: v_hi.floor().min(hf) as usize,
        })
        .filter(|r| r.u0 <= r.u1 && r.v0 <= r.v1)
    }

    /// Ray casts one primitive over its screen rectangle with the z-test; returns the rectangle.
    fn raster(&mut self, p: &Prim, rgb: &mut [u8]) -> Option<Rect> {
        let w = self.w;
        match p.shape {
            Shape::Sphere { c, r } => {
                let rect = self.screen_rect([c[0] - r, c[1] - r, c[2] - r], [c[0] + r, c[1] + r, c[2] + r])?;
                let k = c[0] * c[0] + c[1] * c[1] + c[2] * c[2] - r * r;
                let inv_r = 1.0 / r;
                for v in rect.v0..=rect.v1 {
                    let by = self.ray_y[v];
                    for u in rect.u0..=rect.u1 {
                        let ax = self.ray_x[u];
                        // |t·d − c|² = r² with d = (ax, by, 1): t is the z depth directly.
                        let dd = ax * ax + by * by + 1.0;
                        let dc = ax * c[0] + by * c[1] + c[2];
                        let disc = dc * dc - dd * k;
                        if disc < 0.0 {
                            continue;
                        }
                        let t = (dc - disc.sqrt()) / dd;
                        let i = v * w + u;
                        // NaN t (degenerate ray) fails `visible` too.
                        if !visible(t, self.zbuf[i]) {
                            continue;
                        }
                        let n = [(t * ax - c[0]) * inv_r, (t * by - c[1]) * inv_r, (t - c[2]) * inv_r];
                        self.put(i, t, n, [ax, by, 1.0], dd, p, rgb);
                    }
                }
                Some(rect)
            }
            Shape::Capsule { a, b, r } => {
                let lo = [a[0].min(b[0]) - r, a[1].min(b[1]) - r, a[2].min(b[2]) - r];
                let hi = [a[0].max(b[0]) + r, a[1].max(b[1]) + r, a[2].max(b[2]) + r];
                let rect = self.screen_rect(lo, hi)?;
                let ba = [b[0] - a[0], b[1] - a[1], b[2] - a[2]];
                let baba = dot(ba, ba);
                if baba < 1e-12 {
                    // Degenerate: a sphere.
                    let s = Prim {
                        shape: Shape::Sphere { c: a, r },
                        ..*p
                    };
                    return self.raster(&s, rgb);
                }
                let oa = [-a[0], -a[1], -a[2]]; // ray origin (0) − a
                let baoa = dot(ba, oa);
                let oaoa = dot(oa, oa);
                let ob = [-b[0], -b[1], -b[2]];
                let obob = dot(ob, ob);
                let rr = r * r;
                let inv_r = 1.0 / r;
                for v in rect.v0..=rect.v1 {
                    let by = self.ray_y[v];
                    for u in rect.u0..=rect.u1 {
                        let ax = self.ray_x[u];
                        let d = [ax, by, 1.0];
                        let dd = ax * ax + by * by + 1.0;
                        let bard = dot(ba, d);
                        let rdoa = dot(d, oa);
                        // Infinite cylinder about the axis, then the end caps (Quílez).
                        let qa = baba * dd - bard * bard;
                        let qb = baba * rdoa - baoa * bard;
                        let qc = baba * oaoa - baoa * baoa - rr * baba;
                        let hq = qb * qb - qa * qc;
                        // Outside the infinite cylinder the ray misses the capsule (unless it
                        // runs parallel to the axis, where the quadratic degenerates).
                        let axial = qa <= 1e-6 * baba * dd;
                        if hq < 0.0 && !axial {
                            continue;
                        }
                        let mut t = f32::INFINITY;
                        let mut n = [0.0f32; 3];
                        if !axial {
                            let tc = (-qb - hq.sqrt()) / qa;
                            let y = baoa + tc * bard;
                            if y > 0.0 && y < baba {
                                t = tc;
                                let s = y / baba;
                                n = [
                                    (tc * ax - a[0] - ba[0] * s) * inv_r,
                                    (tc * by - a[1] - ba[1] * s) * inv_r,
                                    (tc - a[2] - ba[2] * s) * inv_r,
                                ];
                            }
                        }
                        if !t.is_finite() {
                            // Nearest hit of the two end spheres.
                            for (cen, oc, ococ) in [(a, oa, oaoa), (b, ob, obob)] {
                                let hb = dot(d, oc);
                                let disc = hb * hb - dd * (ococ - rr);
                                if disc >= 0.0 {
                                    let ts = (-hb - disc.sqrt()) / dd;
                                    if ts < t {
                                        t = ts;
                                        n = [
                                            (ts * ax - cen[0]) * inv_r,
                                            (ts * by - cen[1]) * inv_r,
                                            (ts - cen[2]) * inv_r,
                                        ];
                                    }
                                }
                            }
                        }
                        let i = v * w + u;
                        // NaN t (degenerate ray) fails `visible` too.
                        if !visible(t, self.zbuf[i]) {
                            continue;
                        }
                        self.put(i, t, n, d, dd, p, rgb);
                    }
                }
                Some(rect)
            }
        }
    }

    /// Writes a visible surface sample (already z-tested).
    #[inline]
    #[allow(clippy::too_many_arguments)]
    fn put(&mut self, i: usize, t: f32, n: [f32; 3], d: [f32; 3], dd: f32, p: &Prim, rgb: &mut [u8]) {
        let inv_dlen = 1.0 / dd.sqrt();
        let c = self.shader.shade(&p.albedo, n, d, inv_dlen);
        rgb[3 * i..3 * i + 3].copy_from_slice(&c);
        self.zbuf[i] = t;
        // cos of the angle between the normal and the direction back to the camera.
        let cos_view = -dot(n, d) * inv_dlen;
        self.labels[i] = if cos_view < self.shader.cos_grazing {
            p.label | label::NO_DEPTH
        } else {
            p.label
        };
    }

    /// Stereo matching fails across depth discontinuities: pixels within
    /// `edge_invalid_px` of a jump larger than `edge_jump_mm` get no depth.
    fn invalidate_edges(&mut self, dirty: Rect) {
        let band = self.cfg.depth.edge_invalid_px as usize;
        if band == 0 {
            return;
        }
        let jump = self.cfg.depth.edge_jump_mm as f32;
        let (w, h) = (self.w, self.h);
        let r = dirty.grow(1, w, h);
        let reach = band - 1;
        for v in r.v0..=r.v1 {
            for u in r.u0..=r.u1 {
                let i = v * w + u;
                let z = self.zbuf[i];
                let right = u + 1 < w && is_jump(z, self.zbuf[i + 1], jump);
                let down = v + 1 < h && is_jump(z, self.zbuf[i + w], jump);
                if right || down {
                    let (du, dv) = (usize::from(right), usize::from(down));
                    let ur = (u.saturating_sub(reach), (u + du + reach).min(w - 1));
                    let vr = (v.saturating_sub(reach), (v + dv + reach).min(h - 1));
                    for vv in vr.0..=vr.1 {
                        for l in &mut self.labels[vv * w + ur.0..=vv * w + ur.1] {
                            *l |= label::NO_DEPTH;
                        }
                    }
                }
            }
        }
    }

    /// The second imager sits `stereo_baseline_mm` to the right: a point it cannot see (a
    /// nearer surface maps onto or left of it in its image) has no disparity, hence no
    /// depth. Scanning each row right to left, a pixel is occluded when its position in the
    /// right image is not left of every position seen so far.
    fn stereo_shadow(&mut self, dirty: Rect) {
        let fb = (self.cfg.intrinsics.fx_px * self.cfg.depth.stereo_baseline_mm) as f32;
        let w = self.w;
        for v in dirty.v0..=dirty.v1 {
            let mut min_xr = f32::INFINITY;
            for u in (0..w).rev() {
                let i = v * w + u;
                let z = self.zbuf[i];
                if !z.is_finite() {
                    continue;
                }
                let xr = u as f32 - fb / z;
                if xr >= min_xr {
                    self.labels[i] |= label::NO_DEPTH;
                } else {
                    min_xr = xr;
                }
            }
        }
    }

    /// Sensor model: colour noise on every pixel, depth quantisation with Z²-growing noise,
    /// range limits and dropouts. Random bits come from ChaCha8 on stream `frame_index`
    /// of the seed, a fixed number per pixel, so a frame depends only on (seed, index, scene).
    fn sense<D: DepthSink>(&mut self, frame_index: u64, rgb: &mut [u8], depth: &mut D) {
        let mut rng = self.rng_base.clone();
        rng.set_stream(frame_index);
        rng.set_word_pos(0);
        let dc = &self.cfg.depth;
        let (floor, coeff) = (dc.noise_floor_mm as f32, dc.noise_coeff_per_mm as f32);
        let (zmin, zmax) = (dc.min_mm as f32, dc.max_mm as f32);
        let inv_unit = (1.0 / dc.unit_mm) as f32;
        let drop_thr = self.dropout_threshold;
        let mask = (1u64 << GAUSS_BITS) - 1;
        let w = self.w;
        for v in 0..self.h {
            rng.fill_bytes(&mut self.noise_row);
            let noise = &self.noise_row;
            let gauss = &self.gauss;
            let lut = &self.color_lut;
            let row_rgb = &mut rgb[3 * v * w..3 * (v + 1) * w];
            for (px, nb) in row_rgb.chunks_exact_mut(3).zip(noise.chunks_exact(8)) {
                let bits = le_u64(nb);
                // Bits 0–23: colour (8 per channel); 24–35: depth noise; 48–63: dropout.
                for (c, ch) in px.iter_mut().enumerate() {
                    *ch = lut[(*ch as usize) << 8 | ((bits >> (8 * c)) & 0xff) as usize];
                }
            }
            let zrow = &self.zbuf[v * w..(v + 1) * w];
            let lrow = &self.labels[v * w..(v + 1) * w];
            depth.row(v, w, |u| {
                let bits = le_u64(&noise[8 * u..8 * u + 8]);
                let z = zrow[u];
                if lrow[u] & label::NO_DEPTH != 0 || !z.is_finite() || ((bits >> 48) as u32) < drop_thr {
                    return 0;
                }
                let g = gauss[((bits >> 24) & mask) as usize];
                let zm = z + (floor + coeff * z * z) * g;
                if zm < zmin || zm > zmax {
                    0
                } else {
                    (zm * inv_unit + 0.5) as u16
                }
            });
        }
    }

    /// The static background plane (textured, Lambertian), rendered once.
    fn render_background(&mut self) {
        let b = self.cfg.background;
        let t = self.cam_from_base;
        let n_base = Vector3::from(b.normal_base).normalize();
        let p_base = Point3::from(b.point_base_mm);
        let n_cam = t.rotation * n_base;
        let p_cam = t.transform_point(&p_base);
        let base_from_cam = t.inverse();
        // Two in-plane axes for the texture coordinates.
        let helper = if n_base.x.abs() < 0.9 {
            Vector3::x()
        } else {
            Vector3::y()
        };
        let e1 = n_base.cross(&helper).normalize();
        let e2 = n_base.cross(&e1);
        let albedo = lin3(b.rgb);
        let l = self.shader.light;
        let light = Vector3::new(l[0] as f64, l[1] as f64, l[2] as f64);
        let scale = (LIN_TO_SRGB_LEN - 1) as f64;
        let plane_d = n_cam.dot(&p_cam.coords);
        for v in 0..self.h {
            for u in 0..self.w {
                let i = v * self.w + u;
                let d = Vector3::new(self.ray_x[u] as f64, self.ray_y[v] as f64, 1.0);
                let denom = n_cam.dot(&d);
                let tz = if denom.abs() > 1e-12 {
                    plane_d / denom
                } else {
                    f64::INFINITY
                };
                if !(tz.is_finite() && tz > NEAR_MM as f64) {
                    continue; // VOID: black, no depth
                }
                let hit_base = base_from_cam.transform_point(&Point3::from(d * tz));
                let rel = hit_base - p_base;
                let (s, r) = (rel.dot(&e1), rel.dot(&e2));
                let checker = ((s / b.checker_mm).floor() as i64 + (r / b.checker_mm).floor() as i64) & 1;
                let cell = mix64(
                    ((s / b.grain_mm).floor() as i64 as u64).wrapping_mul(0x1_0000_0001)
                        ^ (r / b.grain_mm).floor() as i64 as u64,
                );
                let grain = (cell >> 11) as f64 / (1u64 << 53) as f64 * 2.0 - 1.0;
                let tex =
                    (1.0 + if checker == 1 {
                        b.checker_contrast
                    } else {
                        -b.checker_contrast
                    }) * (1.0 + b.grain_contrast * grain);
                let n_face = if denom < 0.0 { n_cam } else { -n_cam };
                let k = self.cfg.color.ambient + self.cfg.color.diffuse * n_face.dot(&light).max(0.0);
                for (out, a) in self.bg_rgb[3 * i..3 * i + 3].iter_mut().zip(albedo) {
                    let lin = (a as f64 * tex * k).clamp(0.0, 1.0);
                    *out = self.shader.lin_to_srgb[(lin * scale + 0.5) as usize];
                }
                self.bg_z[i] = tz as f32;
                let cos_view = -n_face.dot(&d) / d.norm();
                self.bg_label[i] = if (cos_view as f32) < self.shader.cos_grazing {
                    label::BACKGROUND | label::NO_DEPTH
                } else {
                    label::BACKGROUND
                };
            }
        }
    }
}

#[inline]
fn le_u64(b: &[u8]) -> u64 {
    let mut a = [0u8; 8];
    a.copy_from_slice(b);
    u64::from_le_bytes(a)
}

#[inline]
fn dot(a: [f32; 3], b: [f32; 3]) -> f32 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

/// In front of the near plane and of what the z-buffer holds (false for NaN).
#[inline]
fn visible(t: f32, z_held: f32) -> bool {
    matches!(t.partial_cmp(&NEAR_MM), Some(std::cmp::Ordering::Greater)) && t < z_held
}

#[inline]
fn is_jump(a: f32, b: f32, jump: f32) -> bool {
    match (a.is_finite(), b.is_finite()) {
        (true, true) => (a - b).abs() > jump,
        (false, false) => false,
        // Something against nothing (no surface hit) is an edge as well.
        _ => true,
    }
}
