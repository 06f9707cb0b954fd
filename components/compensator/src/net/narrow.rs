//! The trial of a *narrow* network — every value at most [`LANES`] channels wide, as the
//! paper's TCN is (J = 5 channels throughout) — as one straight-line pass over register-sized
//! columns.
//!
//! The generic trial ([`IncrementalNet::eval`](super::IncrementalNet::eval)) walks the node
//! list, matches each `Op`, indexes a `Vec` per node and calls a feature-dispatched
//! matrix–vector product per convolution. For an 8-lane column that bookkeeping costs more
//! than the arithmetic (≈ 25 multiply-adds per convolution). Here a [`Plan`] is compiled once
//! from the [`Net`]: a flat list of steps over one contiguous array of columns, with each
//! convolution's newest-tap weights copied beside it, and the whole pass is one function
//! compiled for AVX so every step inlines.
//!
//! **Same bits.** A convolution's column is the generic path's own [`super::matvec_body`] on
//! one block; the affine, ReLU and add steps are the same IEEE operations in the same order
//! (no FMA). So [`Plan::eval`] and [`Plan::eval_jacobian`] return exactly what the generic
//! evaluator returns; tests compare the bits on every fixture and on random nets.

use super::{AffineOp, Net, NodeId, Op, LANES};

type Col = [f32; LANES];

// The convolution's weights sit inline so the pass reads the steps as one contiguous array; a
// box per step would add a pointer chase to the latency chain this module exists to shorten.
#[allow(clippy::large_enum_variant)]
#[derive(Debug, Clone)]
enum Step {
    Affine {
        src: NodeId,
        ops: Vec<(AffineOp, Col)>,
    },
    Relu {
        src: NodeId,
    },
    Add {
        a: NodeId,
        b: NodeId,
    },
    /// The newest tap of a causal convolution; the older taps and the bias are the window's
    /// `partial` of the same node.
    Conv {
        src: NodeId,
        c_in: usize,
        rows: [Col; LANES],
        relu: bool,
        residual: Option<NodeId>,
    },
    TakeLast {
        src: NodeId,
    },
}

/// A narrow net's trial, compiled: steps for nodes `1..n` in order (node 0 is the input).
#[derive(Debug, Clone)]
pub(crate) struct Plan {
    j: usize,
    output: NodeId,
    steps: Vec<Step>,
    /// The newest column (or the vector) of every node.
    vals: Vec<Col>,
    /// Tangents of every node: direction `d` of node `n` at `n·j + d`.
    tans: Vec<Col>,
    /// Per window: each convolution's bias plus its taps over prefix columns.
    partial: Vec<Col>,
}

impl Plan {
    /// The plan of `net`, if every node is at most [`LANES`] wide and of a kind a TCN is made
    /// of (input, affine, ReLU, add, convolution, last column); `None` otherwise (LSTM, dense
    /// heads, wider values), which the generic evaluator handles.
    pub(crate) fn compile(net: &Net) -> Option<Plan> {
        let j = net.joints;
        if j > LANES || net.nodes.is_empty() || !matches!(net.nodes[0].op, Op::Input) {
            return None;
        }
        let col = |v: &[f32]| -> Option<Col> { v.get(..LANES)?.try_into().ok() };
        let mut steps = Vec::with_capacity(net.nodes.len());
        for (id, node) in net.nodes.iter().enumerate() {
            if node.c > LANES {
                return None;
            }
            let step = match &node.op {
                Op::Input if id == 0 => continue,
                Op::Affine { src, steps } => Step::Affine {
                    src: *src,
                    ops: steps
                        .iter()
                        .map(|(op, c)| Some((*op, col(c)?)))
                        .collect::<Option<Vec<_>>>()?,
                },
                Op::Relu { src } => Step::Relu { src: *src },
                Op::Add { a, b } => Step::Add { a: *a, b: *b },
                Op::Conv {
                    src,
                    k,
                    c_in,
                    w,
                    relu,
                    residual,
                    ..
                } => {
                    if *c_in > LANES || *k == 0 {
                        return None;
                    }
                    // `w` is [k][c_in][LANES]: the newest tap is the last c_in rows.
                    let wk = w.get((k - 1) * c_in * LANES..k * c_in * LANES)?;
                    let mut rows = [[0.0f32; LANES]; LANES];
                    for (r, row) in rows.iter_mut().enumerate().take(*c_in) {
                        *row = col(&wk[r * LANES..])?;
                    }
                    Step::Conv {
                        src: *src,
                        c_in: *c_in,
                        rows,
                        relu: *relu,
                        residual: *residual,
                    }
                }
                Op::TakeLast { src } => Step::TakeLast { src: *src },
                Op::Input | Op::Lstm { .. } | Op::FlattenDense { .. } | Op::Dense { .. } => return None,
            };
            steps.push(step);
        }
        let n = net.nodes.len();
        Some(Plan {
            j,
            output: net.output,
            steps,
            vals: vec![[0.0; LANES]; n],
            tans: vec![[0.0; LANES]; n * j],
            partial: vec![[0.0; LANES]; n],
        })
    }

    /// Takes the window's partial sums (the generic evaluator's `partial`, one per node; only
    /// convolutions have one).
    pub(crate) fn load_partials(&mut self, partial: &[bowden_fastmath::AVec<f32>]) {
        for (dst, src) in self.partial.iter_mut().zip(partial) {
            if let Some(c) = src.get(..LANES) {
                dst.copy_from_slice(c);
            }
        }
    }

    /// The model's output for the newest input `last_deg` (the generic `eval`, bit for bit).
    pub(crate) fn eval(&mut self, last_deg: &[f64], out_deg: &mut [f64]) {
        #[cfg(target_arch = "x86_64")]
        if std::arch::is_x86_feature_detected!("avx") {
            // SAFETY: the CPU has AVX (checked just above).
            unsafe { self.eval_avx(last_deg, out_deg) };
            return;
        }
        self.eval_body(last_deg, out_deg)
    }

    /// [`Self::eval`] plus the Jacobian ∂out/∂last (row-major J×J), bit for bit the generic
    /// `eval_jacobian`.
    pub(crate) fn eval_jacobian(&mut self, last_deg: &[f64], out_deg: &mut [f64], jac: &mut [f64]) {
        #[cfg(target_arch = "x86_64")]
        if std::arch::is_x86_feature_detected!("avx") {
            // SAFETY: the CPU has AVX (checked just above).
            unsafe { self.eval_jacobian_avx(last_deg, out_deg, jac) };
            return;
        }
        self.eval_jacobian_body(last_deg, out_deg, jac)
    }

    /// The same arithmetic with 256-bit vectors: single-precision adds and multiplies round
    /// the same at any width, and FMA is not enabled, so the bits match the baseline build.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx")]
    unsafe fn eval_avx(&mut self, last_deg: &[f64], out_deg: &mut [f64]) {
        self.eval_body(last_deg, out_deg)
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx")]
    unsafe fn eval_jacobian_avx(&mut self, last_deg: &[f64], out_deg: &mut [f64], jac: &mut [f64]) {
        self.eval_jacobian_body(last_deg, out_deg, jac)
    }

    #[inline(always)]
    fn set_input(&mut self, last_deg: &[f64]) {
        let x = &mut self.vals[0];
        *x = [0.0; LANES];
        for (v, &d) in x.iter_mut().zip(last_deg).take(self.j) {
            *v = d as f32;
        }
    }

    #[inline(always)]
    fn read_out(&self, out_deg: &mut [f64]) {
        let y = &self.vals[self.output];
        for (o, &v) in out_deg.iter_mut().zip(y).take(self.j) {
            *o = v as f64;
        }
    }

    #[inline(always)]
    fn eval_body(&mut self, last_deg: &[f64], out_deg: &mut [f64]) {
        self.set_input(last_deg);
        let vals = &mut self.vals[..];
        for (i, step) in self.steps.iter().enumerate() {
            let y = value(step, vals, &self.partial[i + 1]);
            vals[i + 1] = y;
        }
        self.read_out(out_deg);
    }

    #[inline(always)]
    fn eval_jacobian_body(&mut self, last_deg: &[f64], out_deg: &mut [f64], jac: &mut [f64]) {
        let j = self.j;
        self.set_input(last_deg);
        // The input's tangents are the identity: ∂x_c/∂x_d = δ_cd.
        for d in 0..j {
            self.tans[d] = [0.0; LANES];
            self.tans[d][d] = 1.0;
        }
        let vals = &mut self.vals[..];
        let tans = &mut self.tans[..];
        for (i, step) in self.steps.iter().enumerate() {
            let n = i + 1;
            let y = value(step, vals, &self.partial[n]);
            vals[n] = y;
            let (before, rest) = tans.split_at_mut(n * j);
            tangent(step, &y, before, &mut rest[..j], j);
        }
        self.read_out(out_deg);
        let o = self.output;
        for r in 0..j {
            for c in 0..j {
                jac[r * j + c] = self.tans[o * j + c][r] as f64;
            }
        }
    }
}

/// The newest column of one step (the generic `trial` of the same node).
#[inline(always)]
fn value(step: &Step, vals: &[Col], partial: &Col) -> Col {
    match step {
        Step::Affine { src, ops } => {
            let mut y = vals[*src];
            for (op, c) in ops {
                for q in 0..LANES {
                    y[q] = match op {
                        AffineOp::Add => y[q] + c[q],
                        AffineOp::Sub => y[q] - c[q],
                        AffineOp::SubFrom => c[q] - y[q],
                        AffineOp::Mul => y[q] * c[q],
                        AffineOp::Div => y[q] / c[q],
                    };
                }
            }
            y
        }
        Step::Relu { src } => {
            let x = &vals[*src];
            let mut y = [0.0f32; LANES];
            for q in 0..LANES {
                y[q] = x[q].max(0.0);
            }
            y
        }
        Step::Add { a, b } => add(&vals[*a], &vals[*b]),
        Step::Conv {
            src,
            c_in,
            rows,
            relu,
            residual,
        } => product(partial, rows, &vals[*src], *c_in, *relu, residual.map(|r| &vals[r])),
        Step::TakeLast { src } => vals[*src],
    }
}

/// `x + z`, lane by lane.
#[inline(always)]
fn add(x: &Col, z: &Col) -> Col {
    let mut y = [0.0f32; LANES];
    for q in 0..LANES {
        y[q] = x[q] + z[q];
    }
    y
}

/// `init + Σ_r x[r]·rows[r]` over `r < c_in`, then the ReLU and the residual if given: the
/// generic evaluator's own [`super::matvec_body`] on one 8-lane block, so the sums are the same
/// by construction, not by copy.
#[inline(always)]
fn product(init: &Col, rows: &[Col; LANES], x: &Col, c_in: usize, relu: bool, res: Option<&Col>) -> Col {
    let mut y = [0.0f32; LANES];
    super::matvec_body(&mut y, init, rows.as_flattened(), &x[..c_in], relu, res.map(|r| &r[..]));
    y
}

/// The tangents of one step (the generic `tangent` of the same node): `dy[d]` from the
/// sources' tangents in `before` (node `m`'s direction `d` at `m·j + d`) and the step's own
/// value `y` for ReLU masks.
#[inline(always)]
fn tangent(step: &Step, y: &Col, before: &[Col], dy: &mut [Col], j: usize) {
    let mask = |v: &mut Col| {
        for q in 0..LANES {
            if y[q] <= 0.0 {
                v[q] = 0.0;
            }
        }
    };
    const ZERO: Col = [0.0; LANES];
    for d in 0..j {
        let t = match step {
            Step::Affine { src, ops } => {
                let mut t = before[src * j + d];
                for (op, c) in ops {
                    match op {
                        AffineOp::Add | AffineOp::Sub => {}
                        AffineOp::SubFrom => t.iter_mut().for_each(|v| *v = -*v),
                        AffineOp::Mul => t.iter_mut().zip(c).for_each(|(v, k)| *v *= k),
                        AffineOp::Div => t.iter_mut().zip(c).for_each(|(v, k)| *v /= k),
                    }
                }
                t
            }
            Step::Relu { src } => {
                let mut t = before[src * j + d];
                mask(&mut t);
                t
            }
            Step::Add { a, b } => add(&before[a * j + d], &before[b * j + d]),
            Step::Conv {
                src,
                c_in,
                rows,
                relu,
                residual,
            } => {
                let mut t = product(&ZERO, rows, &before[src * j + d], *c_in, false, None);
                if *relu {
                    mask(&mut t);
                }
                match residual {
                    Some(r) => add(&t, &before[r * j + d]),
                    None => t,
                }
            }
            Step::TakeLast { src } => before[src * j + d],
        };
        dy[d] = t;
    }
}
