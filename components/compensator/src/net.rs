//! A small network IR for the recognised model graphs and its exact incremental evaluator.
//!
//! A window model maps `[L, J]` (degrees, oldest first) to `[J]`. During one control cycle
//! only the newest input column changes between refinement trials, and every operation
//! here is causal in time (column t depends on columns ≤ t only), so:
//!
//! - the **prefix** (columns `0..L-1` of every sequence value, the LSTM state after `L-1`
//!   steps, the partial sums of a flattening dense layer) is computed once per window;
//! - a **trial** of a new last input computes only column `L-1` of every sequence value and
//!   the vector tail of the network (≈ 750 multiply-adds for the paper's 800-parameter TCN).
//!
//! When the history gains exactly one entry, the window shifts by one column. A column whose
//! receptive field lies entirely inside the window is then the same function of the same
//! inputs as one column later in the old window, so it is moved, not recomputed
//! ([`IncrementalNet::shift_history`]); every column whose receptive field reaches the
//! window's left zero padding is recomputed. Nothing is carried across a window change that
//! depends on the padding: the paper's TCN has a receptive field of 125 > L = 80, so its last
//! blocks are always recomputed in full. The result is bit-identical to a full recomputation
//! (a test checks it).
//!
//! Forward-mode derivatives: [`IncrementalNet::eval_jacobian`] carries J tangent directions
//! (∂/∂ newest input) through the trial column in the same pass, giving the exact J×J
//! Jacobian the Gauss–Newton refinement needs.
//!
//! Arithmetic is f32 like the model; plain loops over 8-lane padded channel blocks that the
//! compiler turns into SIMD (no `mul_add`: without an FMA target feature it is a libm call).

use bowden_fastmath::AVec;
use std::sync::Arc;

mod activation;
mod narrow;

/// Channel counts are padded to a multiple of this so inner loops run on whole vectors.
pub(crate) const LANES: usize = 8;

pub(crate) fn padded(c: usize) -> usize {
    c.div_ceil(LANES) * LANES
}

pub(crate) type NodeId = usize;

/// One per-channel elementwise step `x ← x ∘ c`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum AffineOp {
    Add,
    /// x − c
    Sub,
    /// c − x
    SubFrom,
    Mul,
    /// x / c
    Div,
}

#[derive(Debug, Clone)]
pub(crate) enum Op {
    /// The window, raw degrees.
    Input,
    /// Per-channel constants applied in order (normalisation, de-normalisation, biases).
    Affine {
        src: NodeId,
        steps: Vec<(AffineOp, Vec<f32>)>,
    },
    Relu {
        src: NodeId,
    },
    Add {
        a: NodeId,
        b: NodeId,
    },
    /// Causal dilated Conv1d: y[t] = b + Σ_k W_k x[t − (K−1−k)·dil], zero before the window,
    /// then ReLU if `relu`, then `+ residual[t]` if set (a TCN block's residual add, fused).
    /// `w` is `[k][c_in][c_out_p]`, `b` is `[c_out_p]`.
    Conv {
        src: NodeId,
        k: usize,
        dil: usize,
        c_in: usize,
        w: AVec<f32>,
        b: AVec<f32>,
        relu: bool,
        residual: Option<NodeId>,
    },
    /// Single-layer forward LSTM (ONNX semantics, gates i, o, f, c), zero initial state; the
    /// value is the sequence of hidden states. `wr` is `[input + hidden][4·hp]` (the input
    /// weights W then the recurrent weights R, one row per input), `b` is `[4·hp]` (Wb + Rb),
    /// gate g at offset g·hp. `wb` holds the same weights blocked for [`matvec_blocked`]:
    /// `[4·hp / BLOCK][input + hidden][BLOCK]`, so each block of outputs reads its rows as one
    /// contiguous stream.
    Lstm {
        src: NodeId,
        input: usize,
        hidden: usize,
        wr: AVec<f32>,
        b: AVec<f32>,
        wb: AVec<f32>,
    },
    /// The last column of a sequence, as a vector.
    TakeLast {
        src: NodeId,
    },
    /// Dense layer over the flattened window: `w` is `[L][c_in][n_p]`, `b` is `[n_p]`.
    FlattenDense {
        src: NodeId,
        c_in: usize,
        w: AVec<f32>,
        b: AVec<f32>,
    },
    /// Dense layer on a vector: `w` is `[n_in][n_p]`, `b` is `[n_p]`.
    Dense {
        src: NodeId,
        n_in: usize,
        w: AVec<f32>,
        b: AVec<f32>,
        relu: bool,
    },
}

impl Op {
    pub(crate) fn sources(&self) -> Vec<NodeId> {
        match self {
            Op::Input => vec![],
            Op::Affine { src, .. }
            | Op::Relu { src }
            | Op::Lstm { src, .. }
            | Op::TakeLast { src }
            | Op::FlattenDense { src, .. }
            | Op::Dense { src, .. } => vec![*src],
            Op::Conv { src, residual, .. } => std::iter::once(*src).chain(*residual).collect(),
            Op::Add { a, b } => vec![*a, *b],
        }
    }

    fn sources_mut(&mut self) -> Vec<&mut NodeId> {
        match self {
            Op::Input => vec![],
            Op::Affine { src, .. }
            | Op::Relu { src }
            | Op::Lstm { src, .. }
            | Op::TakeLast { src }
            | Op::FlattenDense { src, .. }
            | Op::Dense { src, .. } => vec![src],
            Op::Conv { src, residual, .. } => std::iter::once(src).chain(residual.as_mut()).collect(),
            Op::Add { a, b } => vec![a, b],
        }
    }
}

#[derive(Debug, Clone)]
pub(crate) struct Node {
    pub op: Op,
    /// A sequence value (L columns) or a vector.
    pub seq: bool,
    /// Channels (sequence) or length (vector).
    pub c: usize,
}

/// A recognised network: nodes in topological order, node 0 is the input.
#[derive(Debug, Clone)]
pub struct Net {
    pub(crate) nodes: Vec<Node>,
    pub(crate) output: NodeId,
    pub(crate) seq_len: usize,
    pub(crate) joints: usize,
}

/// What the recogniser found, for reports and the metadata consistency check.
#[derive(Debug, Clone, PartialEq, Eq, Default)]
pub struct NetSummary {
    pub convs: usize,
    pub residual_blocks: usize,
    /// Residual blocks whose second convolution is followed by a ReLU.
    pub blocks_relu_after_second_conv: usize,
    pub lstm: bool,
    pub flatten_dense: bool,
    pub dense: usize,
    /// Receptive field of the output in time steps (None when an LSTM makes it unbounded).
    pub receptive_field: Option<usize>,
    /// Multiply-adds of one trial (newest column only).
    pub trial_macs: usize,
    /// Multiply-adds of a full prefix (L−1 columns).
    pub prefix_macs: usize,
}

impl Net {
    pub fn seq_len(&self) -> usize {
        self.seq_len
    }
    pub fn joints(&self) -> usize {
        self.joints
    }

    /// Removes nodes the output does not depend on, fuses `Conv`/`Dense` + `Relu`, fuses a
    /// residual `Add` into the convolution that feeds it, and merges chains of `Affine` steps.
    /// Keeps topological order.
    pub(crate) fn simplify(mut self) -> Net {
        loop {
            let users = self.users();
            let mut changed = false;
            for n in 0..self.nodes.len() {
                let fused = match &self.nodes[n].op {
                    Op::Relu { src } if users[*src] == 1 => match &self.nodes[*src].op {
                        // Not after a fused residual add: that ReLU would come after the add.
                        Op::Conv {
                            relu: false,
                            residual: None,
                            ..
                        }
                        | Op::Dense { relu: false, .. } => Some(*src),
                        _ => None,
                    },
                    _ => None,
                };
                if let Some(src) = fused {
                    match &mut self.nodes[src].op {
                        Op::Conv { relu, .. } | Op::Dense { relu, .. } => *relu = true,
                        _ => unreachable!(),
                    }
                    self.redirect(n, src);
                    changed = true;
                    break;
                }
                let residual = match &self.nodes[n].op {
                    Op::Add { a, b } if self.nodes[n].seq => {
                        let fusable = |conv: NodeId, other: NodeId| {
                            (users[conv] == 1
                                && other < conv
                                && self.nodes[other].c == self.nodes[conv].c
                                && matches!(self.nodes[conv].op, Op::Conv { residual: None, .. }))
                            .then_some((conv, other))
                        };
                        fusable(*b, *a).or_else(|| fusable(*a, *b))
                    }
                    _ => None,
                };
                if let Some((conv, other)) = residual {
                    if let Op::Conv { residual, .. } = &mut self.nodes[conv].op {
                        *residual = Some(other);
                    }
                    self.redirect(n, conv);
                    changed = true;
                    break;
                }
                let merged = match &self.nodes[n].op {
                    Op::Affine { src, steps } if users[*src] == 1 => match &self.nodes[*src].op {
                        Op::Affine { .. } => Some((*src, steps.clone())),
                        _ => None,
                    },
                    _ => None,
                };
                if let Some((src, steps)) = merged {
                    if let Op::Affine { steps: s0, .. } = &mut self.nodes[src].op {
                        s0.extend(steps);
                    }
                    self.redirect(n, src);
                    changed = true;
                    break;
                }
            }
            if !changed {
                break;
            }
        }
        self.prune()
    }

    fn users(&self) -> Vec<usize> {
        let mut u = vec![0; self.nodes.len()];
        for n in &self.nodes {
            for s in n.op.sources() {
                u[s] += 1;
            }
        }
        u[self.output] += 1;
        u
    }

    /// Makes every user of `from` use `to` instead (`from` becomes dead).
    fn redirect(&mut self, from: NodeId, to: NodeId) {
        for n in &mut self.nodes {
            for s in n.op.sources_mut() {
                if *s == from {
                    *s = to;
                }
            }
        }
        if self.output == from {
            self.output = to;
        }
    }

    fn prune(self) -> Net {
        let mut live = vec![false; self.nodes.len()];
        live[self.output] = true;
        live[0] = true;
        for n in (0..self.nodes.len()).rev() {
            if live[n] {
                for s in self.nodes[n].op.sources() {
                    live[s] = true;
                }
            }
        }
        let mut new_id = vec![usize::MAX; self.nodes.len()];
        let mut nodes = Vec::new();
        for (i, node) in self.nodes.into_iter().enumerate() {
            if live[i] {
                new_id[i] = nodes.len();
                let mut node = node;
                for s in node.op.sources_mut() {
                    *s = new_id[*s];
                }
                nodes.push(node);
            }
        }
        Net {
            nodes,
            output: new_id[self.output],
            seq_len: self.seq_len,
            joints: self.joints,
        }
    }

    /// Receptive field of every sequence node in columns (`usize::MAX` = unbounded).
    fn receptive_fields(&self) -> Vec<usize> {
        let mut rf = vec![0usize; self.nodes.len()];
        for (n, node) in self.nodes.iter().enumerate() {
            rf[n] = match &node.op {
                Op::Input => 1,
                Op::Affine { src, .. } | Op::Relu { src } | Op::TakeLast { src } => rf[*src],
                Op::Add { a, b } => rf[*a].max(rf[*b]),
                Op::Conv {
                    src, k, dil, residual, ..
                } => rf[*src]
                    .saturating_add((k - 1) * dil)
                    .max(residual.map_or(0, |r| rf[r])),
                Op::Lstm { .. } | Op::FlattenDense { .. } => usize::MAX,
                Op::Dense { src, .. } => rf[*src],
            };
        }
        rf
    }

    pub fn summary(&self) -> NetSummary {
        let l = self.seq_len;
        let mut s = NetSummary::default();
        let users = self.users();
        for node in &self.nodes {
            match &node.op {
                Op::Conv {
                    k,
                    c_in,
                    relu,
                    residual,
                    ..
                } => {
                    s.convs += 1;
                    // A trial computes only the last tap: the others read prefix columns.
                    s.trial_macs += c_in * node.c;
                    s.prefix_macs += (l - 1) * k * c_in * node.c;
                    if residual.is_some() {
                        s.residual_blocks += 1;
                        s.blocks_relu_after_second_conv += *relu as usize;
                    }
                }
                Op::Lstm { input, hidden, .. } => {
                    s.lstm = true;
                    // R·h_{L−2} is part of the prefix.
                    s.trial_macs += 4 * hidden * input;
                    s.prefix_macs += (l - 1) * 4 * hidden * (input + hidden);
                }
                Op::FlattenDense { c_in, .. } => {
                    s.flatten_dense = true;
                    s.trial_macs += c_in * node.c;
                    s.prefix_macs += (l - 1) * c_in * node.c;
                }
                Op::Dense { n_in, .. } => {
                    s.dense += 1;
                    s.trial_macs += n_in * node.c;
                }
                Op::Add { a, b } => {
                    // A residual block: Add(block input, conv path). The conv path is the operand
                    // produced by a convolution (possibly through a ReLU).
                    let relu_after = |id: NodeId| -> Option<bool> {
                        match &self.nodes[id].op {
                            Op::Conv { relu, .. } => Some(*relu),
                            Op::Relu { src } if users[*src] == 1 => match &self.nodes[*src].op {
                                Op::Conv { .. } => Some(true),
                                _ => None,
                            },
                            _ => None,
                        }
                    };
                    if node.seq {
                        if let Some(r) = relu_after(*b).or_else(|| relu_after(*a)) {
                            s.residual_blocks += 1;
                            if r {
                                s.blocks_relu_after_second_conv += 1;
                            }
                        }
                    }
                }
                _ => {}
            }
        }
        let rf = self.receptive_fields()[self.output];
        s.receptive_field = (rf != usize::MAX).then_some(rf);
        s
    }
}

/// The exact incremental evaluator of a [`Net`]: preallocated buffers, no allocation after
/// construction.
///
/// Sequence values are stored time-major, channels padded to [`LANES`], with `margin` zero
/// columns before column 0 (as many as the widest convolution reading the value reaches
/// back): the causal zero padding is read from memory instead of being branched around.
#[derive(Debug, Clone)]
pub struct IncrementalNet {
    net: Arc<Net>,
    l: usize,
    j: usize,
    /// Padded width of each node.
    cp: Vec<usize>,
    /// Zero columns before column 0 of each sequence node.
    margin: Vec<usize>,
    /// Offset of the newest column (sequence nodes) or 0 (vectors).
    last: Vec<usize>,
    /// Sequence nodes: (margin + L)·cp; vector nodes: cp.
    vals: Vec<AVec<f32>>,
    /// Tangents of the newest column / the vector: J·cp (direction j at j·cp).
    tans: Vec<AVec<f32>>,
    /// LSTM cell states per column (L·hp) and the gate activations of the last computed
    /// column (4·hp), which is the newest one when tangents are taken.
    lstm_c: Vec<AVec<f32>>,
    lstm_gates: Vec<AVec<f32>>,
    /// Scratch for one direction of LSTM gate tangents (4·hp).
    lstm_dz: AVec<f32>,
    /// What a trial adds its newest-column terms to, fixed per window: FlattenDense, the sum
    /// over the prefix columns (cp); Conv, bias + the taps reading prefix columns (cp); LSTM,
    /// bias + R·h_{L−2} (4·hp).
    partial: Vec<AVec<f32>>,
    /// The inputs of one matrix-vector product, gathered ([x; h] of an LSTM, the flattened
    /// prefix).
    xin: AVec<f32>,
    /// Zeros, as the initial value of tangent products.
    zeros: AVec<f32>,
    rf: Vec<usize>,
    prefix_valid: bool,
    /// The compiled trial of a narrow net (every value ≤ LANES channels: the TCNs), used by
    /// `eval` and `eval_jacobian` instead of the node walk; same bits (see [`narrow`]).
    narrow: Option<narrow::Plan>,
}

impl IncrementalNet {
    pub fn new(net: Arc<Net>) -> Self {
        let l = net.seq_len;
        let j = net.joints;
        let n = net.nodes.len();
        let mut margin = vec![0usize; n];
        for node in &net.nodes {
            if let Op::Conv { src, k, dil, .. } = &node.op {
                margin[*src] = margin[*src].max((k - 1) * dil);
            }
        }
        let mut cp = Vec::with_capacity(n);
        let mut vals = Vec::with_capacity(n);
        let mut tans = Vec::with_capacity(n);
        let mut lstm_c = Vec::with_capacity(n);
        let mut lstm_gates = Vec::with_capacity(n);
        let mut partial = Vec::with_capacity(n);
        let (mut dz_len, mut xin_len, mut zeros_len) = (0, 0, 0);
        for (id, node) in net.nodes.iter().enumerate() {
            let p = padded(node.c);
            cp.push(p);
            zeros_len = zeros_len.max(p);
            vals.push(AVec::from_elem(0.0, if node.seq { (margin[id] + l) * p } else { p }));
            tans.push(AVec::from_elem(0.0, j * p));
            let (c_state, gates) = match &node.op {
                Op::Lstm { input, hidden, .. } => {
                    dz_len = dz_len.max(4 * p);
                    zeros_len = zeros_len.max(4 * p);
                    xin_len = xin_len.max(input + hidden);
                    (AVec::from_elem(0.0, l * p), AVec::from_elem(0.0, 4 * p))
                }
                _ => (AVec::new(), AVec::new()),
            };
            lstm_c.push(c_state);
            lstm_gates.push(gates);
            if let Op::FlattenDense { c_in, .. } = &node.op {
                xin_len = xin_len.max(l * c_in);
            }
            partial.push(match node.op {
                Op::FlattenDense { .. } | Op::Conv { .. } => AVec::from_elem(0.0, p),
                Op::Lstm { .. } => AVec::from_elem(0.0, 4 * p),
                _ => AVec::new(),
            });
        }
        // The input's tangents are the identity: ∂x_i/∂x_j = δ_ij.
        for d in 0..j {
            tans[0][d * cp[0] + d] = 1.0;
        }
        let rf = net.receptive_fields();
        let last = (0..n)
            .map(|id| {
                if net.nodes[id].seq {
                    (margin[id] + l - 1) * cp[id]
                } else {
                    0
                }
            })
            .collect();
        Self {
            l,
            j,
            cp,
            margin,
            last,
            vals,
            tans,
            lstm_c,
            lstm_gates,
            lstm_dz: AVec::from_elem(0.0, dz_len),
            partial,
            xin: AVec::from_elem(0.0, xin_len),
            zeros: AVec::from_elem(0.0, zeros_len),
            rf,
            prefix_valid: false,
            narrow: narrow::Plan::compile(&net),
            net,
        }
    }

    /// Whether trials run through the compiled narrow plan (TCN-like nets ≤ 8 channels wide).
    pub fn is_narrow(&self) -> bool {
        self.narrow.is_some()
    }

    /// Evaluates trials by the generic node walk even where a narrow plan exists: the
    /// reference the plan is tested and benchmarked against.
    pub fn into_generic(mut self) -> Self {
        self.narrow = None;
        self
    }

    pub fn seq_len(&self) -> usize {
        self.l
    }
    pub fn joints(&self) -> usize {
        self.j
    }
    pub fn net(&self) -> &Net {
        &self.net
    }
    /// The shared network (an evaluator of the same model is `IncrementalNet::new` of it).
    pub fn net_arc(&self) -> &Arc<Net> {
        &self.net
    }

    /// Offset of column `t` of sequence node `n` in its buffer.
    #[inline]
    fn at(&self, n: NodeId, t: usize) -> usize {
        (self.margin[n] + t) * self.cp[n]
    }

    fn write_history(&mut self, history_deg: &[f64]) {
        let (l, j) = (self.l, self.j);
        assert_eq!(history_deg.len(), (l - 1) * j, "history must hold (L-1)·J values");
        let base = self.at(0, 0);
        let p = self.cp[0];
        let x = &mut self.vals[0];
        for t in 0..l - 1 {
            for c in 0..j {
                x[base + t * p + c] = history_deg[t * j + c] as f32;
            }
        }
    }

    /// Sets the fixed part of the window (`(L−1)·J` values, oldest first, degrees) and
    /// computes the prefix of every layer.
    pub fn set_history(&mut self, history_deg: &[f64]) {
        self.write_history(history_deg);
        for n in 1..self.net.nodes.len() {
            if self.net.nodes[n].seq {
                self.columns(n, 0, self.l - 1);
            }
            self.trial_partial(n);
        }
        self.prefix_valid = true;
        if let Some(plan) = &mut self.narrow {
            plan.load_partials(&self.partial);
        }
    }

    /// The history gained exactly one entry (`history_deg` is the new history, i.e. the old
    /// one shifted left by one row with the new entry last). Recomputes only the columns
    /// whose receptive field reaches the left zero padding, plus the new column L−2; moves
    /// the others. Bit-identical to [`Self::set_history`].
    pub fn shift_history(&mut self, history_deg: &[f64]) {
        if !self.prefix_valid {
            self.set_history(history_deg);
            return;
        }
        self.write_history(history_deg);
        let l = self.l;
        for n in 1..self.net.nodes.len() {
            if self.net.nodes[n].seq {
                // Columns t ≥ rf−1 (new indexing) see no padding in either window.
                let keep_from = self.rf[n].saturating_sub(1).min(l - 1);
                if keep_from < l - 2 {
                    let (a, b, c) = (self.at(n, keep_from + 1), self.at(n, l - 1), self.at(n, keep_from));
                    self.vals[n].copy_within(a..b, c);
                }
                self.columns(n, 0, keep_from.min(l - 2));
                if l >= 2 {
                    self.columns(n, l - 2, l - 1);
                }
            }
            self.trial_partial(n);
        }
        if let Some(plan) = &mut self.narrow {
            plan.load_partials(&self.partial);
        }
    }

    /// Marks the prefix stale (the next [`Self::shift_history`] recomputes in full).
    pub fn invalidate(&mut self) {
        self.prefix_valid = false;
    }

    fn set_last(&mut self, last_deg: &[f64]) {
        let j = self.j;
        assert_eq!(last_deg.len(), j);
        let base = self.at(0, self.l - 1);
        let x = &mut self.vals[0];
        for c in 0..j {
            x[base + c] = last_deg[c] as f32;
        }
    }

    /// Evaluates the model with `last_deg` as the newest input column: `out_deg` gets the
    /// model output (degrees). Requires [`Self::set_history`] first.
    pub fn eval(&mut self, last_deg: &[f64], out_deg: &mut [f64]) {
        debug_assert!(self.prefix_valid, "set_history before eval");
        if let Some(plan) = &mut self.narrow {
            assert_eq!(last_deg.len(), self.j);
            plan.eval(last_deg, out_deg);
            return;
        }
        self.set_last(last_deg);
        for n in 1..self.net.nodes.len() {
            self.trial(n);
        }
        self.read_out(out_deg);
    }

    /// Like [`Self::eval`], plus the Jacobian ∂out/∂last (row-major J×J, `jac[r·J + c]` =
    /// ∂out_r/∂last_c) by forward-mode differentiation in the same pass.
    pub fn eval_jacobian(&mut self, last_deg: &[f64], out_deg: &mut [f64], jac: &mut [f64]) {
        debug_assert!(self.prefix_valid, "set_history before eval");
        if let Some(plan) = &mut self.narrow {
            assert_eq!(last_deg.len(), self.j);
            plan.eval_jacobian(last_deg, out_deg, jac);
            return;
        }
        self.set_last(last_deg);
        for n in 1..self.net.nodes.len() {
            self.trial(n);
            self.tangent(n);
        }
        self.read_out(out_deg);
        let (o, j) = (self.net.output, self.j);
        let p = self.cp[o];
        for r in 0..j {
            for c in 0..j {
                jac[r * j + c] = self.tans[o][c * p + r] as f64;
            }
        }
    }

    fn read_out(&self, out_deg: &mut [f64]) {
        let o = self.net.output;
        let base = if self.net.nodes[o].seq {
            self.at(o, self.l - 1)
        } else {
            0
        };
        let v = &self.vals[o][base..];
        for (c, y) in out_deg.iter_mut().enumerate().take(self.j) {
            *y = v[c] as f64;
        }
    }

    /// Prefix columns `t0..t1` of sequence node `n`. Convolutions run four columns at a time
    /// through [`conv_cols`], whose per-column arithmetic does not depend on how columns are
    /// grouped, so a shifted prefix is bit-identical to a full one.
    fn columns(&mut self, n: NodeId, t0: usize, t1: usize) {
        if t0 >= t1 {
            return;
        }
        let net = &*self.net;
        let p = self.cp[n];
        let (y0, y1) = (self.at(n, t0), self.at(n, t1));
        match &net.nodes[n].op {
            Op::Conv {
                src,
                k,
                dil,
                c_in,
                w,
                b,
                relu,
                residual,
            } => {
                let ps = self.cp[*src];
                let ms = self.margin[*src];
                let res = residual.map(|r| (r, self.at(r, t0), self.at(r, t1)));
                let (before, rest) = self.vals.split_at_mut(n);
                let x = &before[*src];
                let y = &mut rest[0][y0..y1];
                let mut t = t0;
                let mut yo = 0;
                while t + 4 <= t1 {
                    conv_cols::<4>(&mut y[yo..yo + 4 * p], b, w, x, ps, *c_in, *k, *dil, ms + t);
                    t += 4;
                    yo += 4 * p;
                }
                while t < t1 {
                    conv_cols::<1>(&mut y[yo..yo + p], b, w, x, ps, *c_in, *k, *dil, ms + t);
                    t += 1;
                    yo += p;
                }
                if *relu {
                    relu_in_place(y);
                }
                if let Some((r, r0, r1)) = res {
                    for (v, a) in y.iter_mut().zip(&before[r][r0..r1]) {
                        *v += a;
                    }
                }
            }
            Op::Relu { src } => {
                let (x0, x1) = (self.at(*src, t0), self.at(*src, t1));
                let (before, rest) = self.vals.split_at_mut(n);
                for (yo, xo) in rest[0][y0..y1].iter_mut().zip(&before[*src][x0..x1]) {
                    *yo = xo.max(0.0);
                }
            }
            Op::Add { a, b } => {
                let (a0, a1) = (self.at(*a, t0), self.at(*a, t1));
                let (b0, b1) = (self.at(*b, t0), self.at(*b, t1));
                let (before, rest) = self.vals.split_at_mut(n);
                let it = rest[0][y0..y1]
                    .iter_mut()
                    .zip(&before[*a][a0..a1])
                    .zip(&before[*b][b0..b1]);
                for ((yo, ao), bo) in it {
                    *yo = ao + bo;
                }
            }
            Op::Affine { src, steps } => {
                let (x0, x1) = (self.at(*src, t0), self.at(*src, t1));
                let (before, rest) = self.vals.split_at_mut(n);
                let cols = rest[0][y0..y1]
                    .chunks_exact_mut(p)
                    .zip(before[*src][x0..x1].chunks_exact(p));
                for (y, x) in cols {
                    affine_from(y, x, steps);
                }
            }
            Op::Lstm { .. } => {
                for t in t0..t1 {
                    self.lstm_column(n, t);
                }
            }
            Op::Input | Op::TakeLast { .. } | Op::FlattenDense { .. } | Op::Dense { .. } => {
                unreachable!("not a sequence op")
            }
        }
    }

    /// The newest column (or the vector) of node `n` for a trial.
    #[inline(always)]
    fn trial(&mut self, n: NodeId) {
        let net = &*self.net;
        let p = self.cp[n];
        let yo = self.last[n];
        match &net.nodes[n].op {
            Op::Affine { src, steps } => {
                let xo = self.last[*src];
                let (before, rest) = self.vals.split_at_mut(n);
                affine_from(&mut rest[0][yo..yo + p], &before[*src][xo..xo + p], steps);
            }
            Op::Relu { src } => {
                let xo = self.last[*src];
                let (before, rest) = self.vals.split_at_mut(n);
                for (v, x) in rest[0][yo..yo + p].iter_mut().zip(&before[*src][xo..xo + p]) {
                    *v = x.max(0.0);
                }
            }
            Op::Add { a, b } => {
                let (ao, bo) = (self.last[*a], self.last[*b]);
                let (before, rest) = self.vals.split_at_mut(n);
                let it = rest[0][yo..yo + p]
                    .iter_mut()
                    .zip(&before[*a][ao..ao + p])
                    .zip(&before[*b][bo..bo + p]);
                for ((v, x), y) in it {
                    *v = x + y;
                }
            }
            Op::Conv {
                src,
                k,
                c_in,
                w,
                relu,
                residual,
                ..
            } => {
                // The taps reading prefix columns are in `partial`: only the newest is new.
                let xo = self.last[*src];
                let ro = residual.map(|r| (r, self.last[r]));
                let (before, rest) = self.vals.split_at_mut(n);
                let y = &mut rest[0][yo..yo + p];
                let res = ro.map(|(r, o)| &before[r][o..o + p]);
                let x = &before[*src][xo..xo + c_in];
                matvec_ex(y, &self.partial[n], &w[(k - 1) * c_in * p..], x, *relu, res);
            }
            Op::TakeLast { src } => {
                let xo = self.last[*src];
                let (before, rest) = self.vals.split_at_mut(n);
                rest[0][..p].copy_from_slice(&before[*src][xo..xo + p]);
            }
            Op::Lstm { .. } => self.lstm_column(n, self.l - 1),
            Op::FlattenDense { .. } | Op::Dense { .. } => self.vector(n),
            Op::Input => {}
        }
    }

    /// Column `t` of LSTM node `n` (one recurrence step; at t = L−1, a trial step using the
    /// per-window `partial`).
    fn lstm_column(&mut self, n: NodeId, t: usize) {
        let net = &*self.net;
        let p = self.cp[n];
        let yo = self.at(n, t);
        match &net.nodes[n].op {
            Op::Lstm {
                src,
                input,
                hidden,
                wb,
                b,
                ..
            } => {
                let rows = input + hidden;
                let xo = self.at(*src, t);
                let ho = if t > 0 { self.at(n, t - 1) } else { 0 };
                let (before, rest) = self.vals.split_at_mut(n);
                let y_all = &mut rest[0];
                let z = &mut self.lstm_gates[n];
                if t == self.l - 1 {
                    // Trial: b + R·h_{L−2} is in `partial`; only W·x_t is new.
                    matvec_blocked(z, &self.partial[n], wb, rows, 0, &before[*src][xo..xo + input]);
                } else {
                    let xs = &mut self.xin[..input + hidden];
                    xs[..*input].copy_from_slice(&before[*src][xo..xo + input]);
                    if t > 0 {
                        xs[*input..].copy_from_slice(&y_all[ho..ho + hidden]);
                    } else {
                        xs[*input..].fill(0.0);
                    }
                    matvec_blocked(z, b, wb, rows, 0, xs);
                }
                // Gate activations in place: i, o, f sigmoid; c̃ tanh.
                let (sig, th) = z.split_at_mut(3 * p);
                activation::gates(sig, th);
                let (gi, rest) = z.split_at(p);
                let (go, rest) = rest.split_at(p);
                let (gf, gc) = rest.split_at(p);
                let (c_prev_all, c_cur_all) = self.lstm_c[n].split_at_mut(t * p);
                let c_cur = &mut c_cur_all[..p];
                let h = &mut y_all[yo..yo + p];
                for q in 0..p {
                    let c_prev = if t > 0 { c_prev_all[(t - 1) * p + q] } else { 0.0 };
                    c_cur[q] = gf[q] * c_prev + gi[q] * gc[q];
                }
                activation::out_gate(h, go, c_cur);
            }
            _ => unreachable!("lstm_column on an LSTM"),
        }
    }

    /// The part of a trial's newest column that depends only on the prefix (see `partial`).
    fn trial_partial(&mut self, n: NodeId) {
        let net = &*self.net;
        let l = self.l;
        match &net.nodes[n].op {
            Op::FlattenDense { src, c_in, w, b } => {
                let ps = self.cp[*src];
                let base = self.at(*src, 0);
                let x = &self.vals[*src][base..];
                let rows = (l - 1) * c_in;
                let xs = &mut self.xin[..rows];
                for t in 0..l - 1 {
                    xs[t * c_in..(t + 1) * c_in].copy_from_slice(&x[t * ps..t * ps + c_in]);
                }
                matvec(&mut self.partial[n], b, w, xs);
            }
            Op::Conv {
                src,
                k,
                dil,
                c_in,
                w,
                b,
                ..
            } => {
                // Every tap but the last reads a column before L−1 (or the zero margin).
                let (ps, p) = (self.cp[*src], self.cp[n]);
                let col = self.margin[*src] + l - 1;
                let x = &self.vals[*src];
                let y = &mut self.partial[n];
                y.copy_from_slice(b);
                for kk in 0..k - 1 {
                    let xc = &x[(col - (k - 1 - kk) * dil) * ps..][..*c_in];
                    let mut acc = [0.0f32; LANES];
                    for ob in (0..p).step_by(LANES) {
                        acc.copy_from_slice(&y[ob..ob + LANES]);
                        for (i, &xv) in xc.iter().enumerate() {
                            let r = kk * c_in + i;
                            let row: &[f32; LANES] = w[r * p + ob..r * p + ob + LANES].try_into().expect("LANES");
                            for q in 0..LANES {
                                acc[q] += row[q] * xv;
                            }
                        }
                        y[ob..ob + LANES].copy_from_slice(&acc);
                    }
                }
            }
            Op::Lstm {
                input, hidden, wb, b, ..
            } => {
                let ho = if l >= 2 { self.at(n, l - 2) } else { 0 };
                let y = &mut self.partial[n];
                if l >= 2 {
                    let h = &self.vals[n][ho..ho + hidden];
                    matvec_blocked(y, b, wb, input + hidden, *input, h);
                } else {
                    y.copy_from_slice(b);
                }
            }
            _ => {}
        }
    }

    /// Computes vector node `n` (trial phase).
    fn vector(&mut self, n: NodeId) {
        let net = &*self.net;
        let l = self.l;
        let p = self.cp[n];
        let last = |s: NodeId| self.at(s, l - 1);
        match &net.nodes[n].op {
            Op::TakeLast { src } => {
                let xo = last(*src);
                let (before, rest) = self.vals.split_at_mut(n);
                rest[0][..p].copy_from_slice(&before[*src][xo..xo + p]);
            }
            Op::FlattenDense { src, c_in, w, .. } => {
                let xo = last(*src);
                let (before, rest) = self.vals.split_at_mut(n);
                let xc = &before[*src][xo..xo + c_in];
                matvec(&mut rest[0][..p], &self.partial[n], &w[(l - 1) * c_in * p..], xc);
            }
            Op::Dense { src, n_in, w, b, relu } => {
                let (before, rest) = self.vals.split_at_mut(n);
                let y = &mut rest[0][..p];
                matvec(y, b, w, &before[*src][..*n_in]);
                if *relu {
                    relu_in_place(y);
                }
            }
            Op::Affine { src, steps } => {
                let (before, rest) = self.vals.split_at_mut(n);
                let y = &mut rest[0][..p];
                y.copy_from_slice(&before[*src][..p]);
                apply_affine(y, steps);
            }
            Op::Relu { src } => {
                let (before, rest) = self.vals.split_at_mut(n);
                for (yo, xo) in rest[0][..p].iter_mut().zip(&before[*src][..p]) {
                    *yo = xo.max(0.0);
                }
            }
            Op::Add { a, b } => {
                let (before, rest) = self.vals.split_at_mut(n);
                for ((yo, ao), bo) in rest[0][..p].iter_mut().zip(&before[*a][..p]).zip(&before[*b][..p]) {
                    *yo = ao + bo;
                }
            }
            Op::Input | Op::Conv { .. } | Op::Lstm { .. } => unreachable!("not a vector op"),
        }
    }

    /// Tangents of node `n`'s newest column (or vector) from its sources' tangents.
    fn tangent(&mut self, n: NodeId) {
        let net = &*self.net;
        let (l, j) = (self.l, self.j);
        let p = self.cp[n];
        let node = &net.nodes[n];
        // The node's own newest value, for ReLU masks.
        let yo = if node.seq { self.at(n, l - 1) } else { 0 };
        let yv: &[f32] = &self.vals[n][yo..yo + p];
        let zeros = &self.zeros;
        let (before, rest) = self.tans.split_at_mut(n);
        let dy_all = &mut rest[0];
        let mask = |dy: &mut [f32]| {
            for (v, &yq) in dy.iter_mut().zip(yv) {
                if yq <= 0.0 {
                    *v = 0.0;
                }
            }
        };
        match &node.op {
            Op::Input => {}
            Op::Affine { src, steps } => {
                dy_all.copy_from_slice(&before[*src][..j * p]);
                for d in 0..j {
                    let dy = &mut dy_all[d * p..(d + 1) * p];
                    for (op, c) in steps {
                        match op {
                            AffineOp::Add | AffineOp::Sub => {}
                            AffineOp::SubFrom => dy.iter_mut().for_each(|v| *v = -*v),
                            AffineOp::Mul => dy.iter_mut().zip(c).for_each(|(v, k)| *v *= k),
                            AffineOp::Div => dy.iter_mut().zip(c).for_each(|(v, k)| *v /= k),
                        }
                    }
                }
            }
            Op::Relu { src } => {
                dy_all.copy_from_slice(&before[*src][..j * p]);
                for d in 0..j {
                    mask(&mut dy_all[d * p..(d + 1) * p]);
                }
            }
            Op::Add { a, b } => {
                for ((v, x), y) in dy_all.iter_mut().zip(&before[*a]).zip(&before[*b]) {
                    *v = x + y;
                }
            }
            Op::TakeLast { src } => dy_all.copy_from_slice(&before[*src][..j * p]),
            Op::Conv {
                src,
                k,
                c_in,
                w,
                relu,
                residual,
                ..
            } => {
                // Only the tap at offset 0 (kk = K−1) sees the newest column.
                let ps = self.cp[*src];
                let wk = &w[(k - 1) * c_in * p..];
                matvec_dirs(dy_all, &zeros[..p], wk, &before[*src], ps, *c_in, j);
                for d in 0..j {
                    let dy = &mut dy_all[d * p..(d + 1) * p];
                    if *relu {
                        mask(dy);
                    }
                    if let Some(r) = residual {
                        for (v, a) in dy.iter_mut().zip(&before[*r][d * p..(d + 1) * p]) {
                            *v += a;
                        }
                    }
                }
            }
            Op::Dense { src, n_in, w, relu, .. } => {
                let ps = self.cp[*src];
                matvec_dirs(dy_all, &zeros[..p], w, &before[*src], ps, *n_in, j);
                if *relu {
                    for d in 0..j {
                        mask(&mut dy_all[d * p..(d + 1) * p]);
                    }
                }
            }
            Op::FlattenDense { src, c_in, w, .. } => {
                let ps = self.cp[*src];
                let wl = &w[(l - 1) * c_in * p..];
                matvec_dirs(dy_all, &zeros[..p], wl, &before[*src], ps, *c_in, j);
            }
            Op::Lstm { src, input, wr, .. } => {
                // The previous state does not depend on the newest input: only x_t does.
                // dz = W dx; di = i(1−i)dz_i, do = o(1−o)dz_o, df = f(1−f)dz_f,
                // dg = (1−g²)dz_g; dc = df·c_prev + di·g + i·dg; dh = do·tanh c + o(1−tanh²c)dc.
                let ps = self.cp[*src];
                let g = &self.lstm_gates[n];
                let cst = &self.lstm_c[n];
                let dz = &mut self.lstm_dz[..4 * p];
                for d in 0..j {
                    matvec(dz, &zeros[..4 * p], wr, &before[*src][d * ps..d * ps + input]);
                    let dy = &mut dy_all[d * p..(d + 1) * p];
                    for q in 0..p {
                        let (gi, go, gf, gg) = (g[q], g[p + q], g[2 * p + q], g[3 * p + q]);
                        let di = gi * (1.0 - gi) * dz[q];
                        let dout = go * (1.0 - go) * dz[p + q];
                        let df = gf * (1.0 - gf) * dz[2 * p + q];
                        let dg = (1.0 - gg * gg) * dz[3 * p + q];
                        let c_prev = if l >= 2 { cst[(l - 2) * p + q] } else { 0.0 };
                        let dc = df * c_prev + di * gg + gi * dg;
                        let tc = activation::tanh(cst[(l - 1) * p + q]);
                        dy[q] = dout * tc + go * (1.0 - tc * tc) * dc;
                    }
                }
            }
        }
    }
}

/// `y = init + Σ_r x[r]·w[r·p .. r·p + p]` with `p = y.len()` (a multiple of [`LANES`]),
/// for the latency-bound trial: one block of LANES outputs at a time, the rows split over four
/// independent accumulators so the additions pipeline.
#[inline]
fn matvec(y: &mut [f32], init: &[f32], w: &[f32], x: &[f32]) {
    matvec_ex(y, init, w, x, false, None)
}

/// [`matvec`] followed by an optional ReLU and an optional residual add, in one pass.
#[inline]
fn matvec_ex(y: &mut [f32], init: &[f32], w: &[f32], x: &[f32], relu: bool, res: Option<&[f32]>) {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx") {
        // SAFETY: the CPU has AVX (checked just above).
        unsafe { matvec_avx(y, init, w, x, relu, res) };
        return;
    }
    matvec_body(y, init, w, x, relu, res)
}

/// The same arithmetic compiled with 256-bit vectors. IEEE single-precision adds and
/// multiplies round identically whatever the vector width, and no FMA is enabled, so results
/// are bit-identical to the SSE build.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx")]
unsafe fn matvec_avx(y: &mut [f32], init: &[f32], w: &[f32], x: &[f32], relu: bool, res: Option<&[f32]>) {
    matvec_body(y, init, w, x, relu, res)
}

#[inline(always)]
fn matvec_body(y: &mut [f32], init: &[f32], w: &[f32], x: &[f32], relu: bool, res: Option<&[f32]>) {
    let p = y.len();
    debug_assert!(p.is_multiple_of(LANES) && init.len() >= p && w.len() >= x.len() * p);
    let rows = x.len();
    for ob in (0..p).step_by(LANES) {
        let mut acc = [[0.0f32; LANES]; 4];
        let mut r = 0;
        while r + 4 <= rows {
            for (g, a) in acc.iter_mut().enumerate() {
                let row: &[f32; LANES] = w[(r + g) * p + ob..(r + g) * p + ob + LANES].try_into().expect("LANES");
                let xr = x[r + g];
                for q in 0..LANES {
                    a[q] += row[q] * xr;
                }
            }
            r += 4;
        }
        while r < rows {
            let row: &[f32; LANES] = w[r * p + ob..r * p + ob + LANES].try_into().expect("LANES");
            let xr = x[r];
            for q in 0..LANES {
                acc[0][q] += row[q] * xr;
            }
            r += 1;
        }
        let b: &[f32; LANES] = init[ob..ob + LANES].try_into().expect("LANES");
        let mut out = [0.0f32; LANES];
        for q in 0..LANES {
            out[q] = b[q] + ((acc[0][q] + acc[1][q]) + (acc[2][q] + acc[3][q]));
        }
        if relu {
            for v in out.iter_mut() {
                *v = v.max(0.0);
            }
        }
        if let Some(res) = res {
            let rb: &[f32; LANES] = res[ob..ob + LANES].try_into().expect("LANES");
            for q in 0..LANES {
                out[q] += rb[q];
            }
        }
        y[ob..ob + LANES].copy_from_slice(&out);
    }
}

/// The tangent products of a layer, one [`matvec`] per direction `d`:
/// `y[d·p ..][..p] = init + W · x[d·ps ..][..n_in]` for `d < dirs` (`p = init.len()`), under one
/// CPU-feature dispatch so the per-direction calls inline into one vectorised function (a
/// Jacobian trial makes J of them per layer, each only a few rows long). Each product's
/// arithmetic is [`matvec_body`]'s: bit-identical to calling [`matvec`] per direction.
#[inline]
fn matvec_dirs(y: &mut [f32], init: &[f32], w: &[f32], x: &[f32], ps: usize, n_in: usize, dirs: usize) {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx") {
        // SAFETY: the CPU has AVX (checked just above).
        unsafe { matvec_dirs_avx(y, init, w, x, ps, n_in, dirs) };
        return;
    }
    matvec_dirs_body(y, init, w, x, ps, n_in, dirs)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx")]
unsafe fn matvec_dirs_avx(y: &mut [f32], init: &[f32], w: &[f32], x: &[f32], ps: usize, n_in: usize, dirs: usize) {
    matvec_dirs_body(y, init, w, x, ps, n_in, dirs)
}

#[inline(always)]
fn matvec_dirs_body(y: &mut [f32], init: &[f32], w: &[f32], x: &[f32], ps: usize, n_in: usize, dirs: usize) {
    let p = init.len();
    for d in 0..dirs {
        matvec_body(
            &mut y[d * p..(d + 1) * p],
            init,
            w,
            &x[d * ps..d * ps + n_in],
            false,
            None,
        );
    }
}

/// Output lanes per block of [`matvec_blocked`]: two [`LANES`] blocks, one 64-byte cache line
/// of weights per row (and one AVX-512 register).
pub(crate) const BLOCK: usize = 2 * LANES;

/// `w` (`[rows][p]`, row-major) re-laid as `[p / BLOCK][rows][BLOCK]`.
pub(crate) fn block_rows(w: &[f32], rows: usize, p: usize) -> Vec<f32> {
    assert!(p.is_multiple_of(BLOCK) && w.len() == rows * p);
    let mut out = vec![0.0f32; rows * p];
    for blk in 0..p / BLOCK {
        for r in 0..rows {
            out[(blk * rows + r) * BLOCK..][..BLOCK].copy_from_slice(&w[r * p + blk * BLOCK..][..BLOCK]);
        }
    }
    out
}

/// [`matvec`] over rows `row0 .. row0 + x.len()` of weights blocked by [`block_rows`]
/// (`rows` rows in all), for the LSTM: its 4·hp × (input + hidden) matrix (512 × 133 for the
/// shipped inverse model) is read 79 times per prefix, and the row-major layout touches each
/// 64-byte line twice, half a line at a time, 2 KB apart. Here every output block streams its
/// rows contiguously. Per output lane the arithmetic is [`matvec_body`]'s, in the same order
/// (four accumulators over the rows ≡ 0, 1, 2, 3 mod 4, the tail into the first,
/// `init + ((a0 + a1) + (a2 + a3))`, no FMA), so results are bit-identical to [`matvec`] on the
/// row-major weights (a test checks it).
#[inline]
fn matvec_blocked(y: &mut [f32], init: &[f32], wb: &[f32], rows: usize, row0: usize, x: &[f32]) {
    #[cfg(target_arch = "x86_64")]
    {
        if std::arch::is_x86_feature_detected!("avx512f") {
            // SAFETY: the CPU has AVX-512F (checked just above).
            unsafe { matvec_blocked_avx512(y, init, wb, rows, row0, x) };
            return;
        }
        if std::arch::is_x86_feature_detected!("avx") {
            // SAFETY: the CPU has AVX (checked just above).
            unsafe { matvec_blocked_avx(y, init, wb, rows, row0, x) };
            return;
        }
    }
    matvec_blocked_body(y, init, wb, rows, row0, x)
}

/// [`matvec_blocked`] with 512-bit vectors (bit-identical: no FMA, IEEE lanes).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f")]
unsafe fn matvec_blocked_avx512(y: &mut [f32], init: &[f32], wb: &[f32], rows: usize, row0: usize, x: &[f32]) {
    matvec_blocked_body(y, init, wb, rows, row0, x)
}

/// [`matvec_blocked`] with 256-bit vectors (bit-identical, see [`matvec_avx`]).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx")]
unsafe fn matvec_blocked_avx(y: &mut [f32], init: &[f32], wb: &[f32], rows: usize, row0: usize, x: &[f32]) {
    matvec_blocked_body(y, init, wb, rows, row0, x)
}

#[inline(always)]
fn matvec_blocked_body(y: &mut [f32], init: &[f32], wb: &[f32], rows: usize, row0: usize, x: &[f32]) {
    let p = y.len();
    let n = x.len();
    debug_assert!(p.is_multiple_of(BLOCK) && init.len() >= p && row0 + n <= rows && wb.len() >= rows * p);
    for blk in 0..p / BLOCK {
        let w = &wb[(blk * rows + row0) * BLOCK..(blk * rows + row0 + n) * BLOCK];
        let mut acc = [[0.0f32; BLOCK]; 4];
        let mut r = 0;
        while r + 4 <= n {
            for (g, a) in acc.iter_mut().enumerate() {
                let row: &[f32; BLOCK] = w[(r + g) * BLOCK..(r + g + 1) * BLOCK].try_into().expect("BLOCK");
                let xr = x[r + g];
                for q in 0..BLOCK {
                    a[q] += row[q] * xr;
                }
            }
            r += 4;
        }
        while r < n {
            let row: &[f32; BLOCK] = w[r * BLOCK..(r + 1) * BLOCK].try_into().expect("BLOCK");
            let xr = x[r];
            for q in 0..BLOCK {
                acc[0][q] += row[q] * xr;
            }
            r += 1;
        }
        let b: &[f32; BLOCK] = init[blk * BLOCK..(blk + 1) * BLOCK].try_into().expect("BLOCK");
        let out = &mut y[blk * BLOCK..(blk + 1) * BLOCK];
        for q in 0..BLOCK {
            out[q] = b[q] + ((acc[0][q] + acc[1][q]) + (acc[2][q] + acc[3][q]));
        }
    }
}

/// `N` consecutive causal-conv columns (buffer columns `col..col+N` of the offset-0 tap),
/// one accumulator per column with taps and inputs in order, so a column gets the same bits
/// whatever `N` is; the N independent chains keep the pipeline full.
#[allow(clippy::too_many_arguments)]
#[inline]
fn conv_cols<const N: usize>(
    y: &mut [f32],
    b: &[f32],
    w: &[f32],
    x: &[f32],
    ps: usize,
    c_in: usize,
    k: usize,
    dil: usize,
    col: usize,
) {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx") {
        // SAFETY: the CPU has AVX (checked just above).
        unsafe { conv_cols_avx::<N>(y, b, w, x, ps, c_in, k, dil, col) };
        return;
    }
    conv_cols_body::<N>(y, b, w, x, ps, c_in, k, dil, col)
}

/// [`conv_cols`] with 256-bit vectors (bit-identical, see [`matvec_avx`]).
#[cfg(target_arch = "x86_64")]
#[allow(clippy::too_many_arguments)]
#[target_feature(enable = "avx")]
unsafe fn conv_cols_avx<const N: usize>(
    y: &mut [f32],
    b: &[f32],
    w: &[f32],
    x: &[f32],
    ps: usize,
    c_in: usize,
    k: usize,
    dil: usize,
    col: usize,
) {
    conv_cols_body::<N>(y, b, w, x, ps, c_in, k, dil, col)
}

#[allow(clippy::too_many_arguments)]
#[inline(always)]
fn conv_cols_body<const N: usize>(
    y: &mut [f32],
    b: &[f32],
    w: &[f32],
    x: &[f32],
    ps: usize,
    c_in: usize,
    k: usize,
    dil: usize,
    col: usize,
) {
    let p = b.len();
    debug_assert!(y.len() == N * p);
    for ob in (0..p).step_by(LANES) {
        let mut acc = [[0.0f32; LANES]; N];
        for a in acc.iter_mut() {
            a.copy_from_slice(&b[ob..ob + LANES]);
        }
        for kk in 0..k {
            let xc = &x[(col - (k - 1 - kk) * dil) * ps..][..(N - 1) * ps + c_in];
            for i in 0..c_in {
                let r = kk * c_in + i;
                let row: &[f32; LANES] = w[r * p + ob..r * p + ob + LANES].try_into().expect("LANES");
                for (c, a) in acc.iter_mut().enumerate() {
                    let xv = xc[c * ps + i];
                    for q in 0..LANES {
                        a[q] += row[q] * xv;
                    }
                }
            }
        }
        for (c, a) in acc.iter().enumerate() {
            y[c * p + ob..c * p + ob + LANES].copy_from_slice(a);
        }
    }
}

#[inline]
fn relu_in_place(y: &mut [f32]) {
    for v in y.iter_mut() {
        *v = v.max(0.0);
    }
}

/// `y = steps(x)`: the first step reads `x`, the others work in place (the same arithmetic as
/// copying then [`apply_affine`], without the copy).
fn affine_from(y: &mut [f32], x: &[f32], steps: &[(AffineOp, Vec<f32>)]) {
    let Some(((op, c), rest)) = steps.split_first() else {
        y.copy_from_slice(x);
        return;
    };
    let it = y.iter_mut().zip(x).zip(c);
    match op {
        AffineOp::Add => it.for_each(|((v, a), k)| *v = a + k),
        AffineOp::Sub => it.for_each(|((v, a), k)| *v = a - k),
        AffineOp::SubFrom => it.for_each(|((v, a), k)| *v = k - a),
        AffineOp::Mul => it.for_each(|((v, a), k)| *v = a * k),
        AffineOp::Div => it.for_each(|((v, a), k)| *v = a / k),
    }
    apply_affine(y, rest);
}

fn apply_affine(y: &mut [f32], steps: &[(AffineOp, Vec<f32>)]) {
    for (op, c) in steps {
        let it = y.iter_mut().zip(c);
        match op {
            AffineOp::Add => it.for_each(|(v, k)| *v += k),
            AffineOp::Sub => it.for_each(|(v, k)| *v -= k),
            AffineOp::SubFrom => it.for_each(|(v, k)| *v = k - *v),
            AffineOp::Mul => it.for_each(|(v, k)| *v *= k),
            AffineOp::Div => it.for_each(|(v, k)| *v /= k),
        }
    }
}

/// Builders that lay weights out padded for the evaluator (used by the recogniser and tests).
pub(crate) mod build {
    use super::*;

    /// Per-channel constants padded to `padded(c)`; padding lanes get `fill` (1 for Mul/Div so
    /// padding stays finite).
    pub fn channel_vec(c: &[f32], fill: f32) -> Vec<f32> {
        let mut v = vec![fill; padded(c.len())];
        v[..c.len()].copy_from_slice(c);
        v
    }

    /// Conv weights from `w_oik[o][i][k]` (ONNX/PyTorch OIK layout).
    pub fn conv(src: NodeId, c_out: usize, c_in: usize, k: usize, dil: usize, w_oik: &[f32], bias: &[f32]) -> Node {
        let p = padded(c_out);
        let mut w = AVec::from_elem(0.0, k * c_in * p);
        for o in 0..c_out {
            for i in 0..c_in {
                for kk in 0..k {
                    w[(kk * c_in + i) * p + o] = w_oik[(o * c_in + i) * k + kk];
                }
            }
        }
        let mut b = AVec::from_elem(0.0, p);
        b[..c_out].copy_from_slice(bias);
        Node {
            op: Op::Conv {
                src,
                k,
                dil,
                c_in,
                w,
                b,
                relu: false,
                residual: None,
            },
            seq: true,
            c: c_out,
        }
    }

    /// Dense from `w_no[n][i]` (PyTorch Linear layout).
    pub fn dense(src: NodeId, n_out: usize, n_in: usize, w_ni: &[f32], bias: &[f32]) -> Node {
        let p = padded(n_out);
        let mut w = AVec::from_elem(0.0, n_in * p);
        for o in 0..n_out {
            for i in 0..n_in {
                w[i * p + o] = w_ni[o * n_in + i];
            }
        }
        let mut b = AVec::from_elem(0.0, p);
        b[..n_out].copy_from_slice(bias);
        Node {
            op: Op::Dense {
                src,
                n_in,
                w,
                b,
                relu: false,
            },
            seq: false,
            c: n_out,
        }
    }

    /// Dense over the flattened window from `w[n][t][c]`.
    pub fn flatten_dense(src: NodeId, n_out: usize, l: usize, c_in: usize, w_ntc: &[f32], bias: &[f32]) -> Node {
        let p = padded(n_out);
        let mut w = AVec::from_elem(0.0, l * c_in * p);
        for o in 0..n_out {
            for t in 0..l {
                for i in 0..c_in {
                    w[(t * c_in + i) * p + o] = w_ntc[(o * l + t) * c_in + i];
                }
            }
        }
        let mut b = AVec::from_elem(0.0, p);
        b[..n_out].copy_from_slice(bias);
        Node {
            op: Op::FlattenDense { src, c_in, w, b },
            seq: false,
            c: n_out,
        }
    }

    /// LSTM from ONNX `W[4H][I]`, `R[4H][H]`, `B[8H]` (gates i, o, f, c).
    pub fn lstm(src: NodeId, input: usize, hidden: usize, w_onnx: &[f32], r_onnx: &[f32], b_onnx: &[f32]) -> Node {
        let p = padded(hidden);
        let mut wr = AVec::from_elem(0.0, (input + hidden) * 4 * p);
        let mut b = AVec::from_elem(0.0, 4 * p);
        for g in 0..4 {
            for h in 0..hidden {
                let row = g * hidden + h;
                let col = g * p + h;
                for i in 0..input {
                    wr[i * 4 * p + col] = w_onnx[row * input + i];
                }
                for i in 0..hidden {
                    wr[(input + i) * 4 * p + col] = r_onnx[row * hidden + i];
                }
                b[col] = b_onnx[row] + b_onnx[4 * hidden + row];
            }
        }
        let wb = block_rows(&wr, input + hidden, 4 * p);
        Node {
            op: Op::Lstm {
                src,
                input,
                hidden,
                wr,
                b,
                wb: AVec::from_slice(&wb),
            },
            seq: true,
            c: hidden,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    fn rand_vec(rng: &mut ChaCha8Rng, n: usize, s: f32) -> Vec<f32> {
        (0..n).map(|_| rng.random_range(-s..s)).collect()
    }

    /// A 3-block TCN-LSTM-ish net with every op kind, to exercise shift reuse and tangents.
    fn toy_net(l: usize, j: usize, with_lstm: bool) -> Net {
        let mut rng = ChaCha8Rng::seed_from_u64(7);
        let mut nodes = vec![Node {
            op: Op::Input,
            seq: true,
            c: j,
        }];
        nodes.push(Node {
            op: Op::Affine {
                src: 0,
                steps: vec![
                    (AffineOp::Sub, build::channel_vec(&rand_vec(&mut rng, j, 3.0), 0.0)),
                    (AffineOp::Div, build::channel_vec(&vec![20.0; j], 1.0)),
                ],
            },
            seq: true,
            c: j,
        });
        let mut x = 1;
        for (bi, dil) in [1usize, 2, 4].into_iter().enumerate() {
            let mut c1 = build::conv(
                x,
                j,
                j,
                3,
                dil,
                &rand_vec(&mut rng, j * j * 3, 0.5),
                &rand_vec(&mut rng, j, 0.2),
            );
            if let Op::Conv { relu, .. } = &mut c1.op {
                *relu = true;
            }
            nodes.push(c1);
            let c2 = build::conv(
                nodes.len() - 1,
                j,
                j,
                3,
                dil,
                &rand_vec(&mut rng, j * j * 3, 0.5),
                &rand_vec(&mut rng, j, 0.2),
            );
            nodes.push(c2);
            let c2id = nodes.len() - 1;
            let path = if bi % 2 == 0 {
                nodes.push(Node {
                    op: Op::Relu { src: c2id },
                    seq: true,
                    c: j,
                });
                nodes.len() - 1
            } else {
                c2id
            };
            nodes.push(Node {
                op: Op::Add { a: x, b: path },
                seq: true,
                c: j,
            });
            x = nodes.len() - 1;
        }
        let last = if with_lstm {
            let h = 6;
            nodes.push(build::lstm(
                x,
                j,
                h,
                &rand_vec(&mut rng, 4 * h * j, 0.5),
                &rand_vec(&mut rng, 4 * h * h, 0.5),
                &rand_vec(&mut rng, 8 * h, 0.2),
            ));
            let lid = nodes.len() - 1;
            nodes.push(Node {
                op: Op::TakeLast { src: lid },
                seq: false,
                c: h,
            });
            let t = nodes.len() - 1;
            let mut d = build::dense(t, 7, h, &rand_vec(&mut rng, 7 * h, 0.5), &rand_vec(&mut rng, 7, 0.1));
            if let Op::Dense { relu, .. } = &mut d.op {
                *relu = true;
            }
            nodes.push(d);
            nodes.push(build::dense(
                nodes.len() - 1,
                j,
                7,
                &rand_vec(&mut rng, 7 * j, 0.5),
                &rand_vec(&mut rng, j, 0.1),
            ));
            nodes.len() - 1
        } else {
            nodes.push(Node {
                op: Op::TakeLast { src: x },
                seq: false,
                c: j,
            });
            nodes.len() - 1
        };
        nodes.push(Node {
            op: Op::Affine {
                src: last,
                steps: vec![
                    (AffineOp::Mul, build::channel_vec(&vec![25.0; j], 1.0)),
                    (AffineOp::Add, build::channel_vec(&rand_vec(&mut rng, j, 5.0), 0.0)),
                ],
            },
            seq: false,
            c: j,
        });
        let output = nodes.len() - 1;
        Net {
            nodes,
            output,
            seq_len: l,
            joints: j,
        }
    }

    /// The evaluator under test: prefix from the first L−1 rows, trial with the last.
    fn incremental(net: &Net, window: &[f64]) -> Vec<f64> {
        let mut ev = IncrementalNet::new(Arc::new(net.clone()));
        let (l, j) = (net.seq_len, net.joints);
        ev.set_history(&window[..(l - 1) * j]);
        let mut out = vec![0.0; j];
        ev.eval(&window[(l - 1) * j..], &mut out);
        out
    }

    /// Independent reference: every column of every node over the whole window, in f64,
    /// straight from the definitions (explicit zero padding, no prefix/trial split).
    // Long: the reference (full-window) forward pass of every architecture, written out plainly to check the incremental evaluators against.
    fn reference(net: &Net, window: &[f64]) -> Vec<f64> {
        let (l, j) = (net.seq_len, net.joints);
        let mut vals: Vec<Vec<Vec<f64>>> = Vec::new(); // node → column (or [vector]) → channel
        for node in &net.nodes {
            let p = padded(node.c);
            let v: Vec<Vec<f64>> = match &node.op {
                Op::Input => (0..l).map(|t| window[t * j..(t + 1) * j].to_vec()).collect(),
                Op::Affine { src, steps } => vals[*src]
                    .iter()
                    .map(|x| {
                        x.iter()
                            .enumerate()
                            .map(|(c, &v)| {
                                steps.iter().fold(v, |v, (op, k)| {
                                    let k = k[c] as f64;
                                    match op {
                                        AffineOp::Add => v + k,
                                        AffineOp::Sub => v - k,
                                        AffineOp::SubFrom => k - v,
                                        AffineOp::Mul => v * k,
                                        AffineOp::Div => v / k,
                                    }
                                })
                            })
                            .collect()
                    })
                    .collect(),
                Op::Relu { src } => vals[*src]
                    .iter()
                    .map(|x| x.iter().map(|v| v.max(0.0)).collect())
                    .collect(),
                Op::Add { a, b } => vals[*a]
                    .iter()
                    .zip(&vals[*b])
                    .map(|(x, y)| x.iter().zip(y).map(|(u, v)| u + v).collect())
                    .collect(),
                Op::Conv {
                    src,
                    k,
                    dil,
                    c_in,
                    w,
                    b,
                    relu,
                    residual,
                } => {
                    let x = &vals[*src];
                    (0..l)
                        .map(|t| {
                            (0..node.c)
                                .map(|o| {
                                    let mut s = b[o] as f64;
                                    for kk in 0..*k {
                                        let back = (k - 1 - kk) * dil;
                                        let xv = if back > t {
                                            vec![0.0; *c_in]
                                        } else {
                                            x[t - back].clone()
                                        };
                                        for i in 0..*c_in {
                                            s += w[(kk * c_in + i) * p + o] as f64 * xv[i];
                                        }
                                    }
                                    let s = if *relu { s.max(0.0) } else { s };
                                    s + residual.map_or(0.0, |r| vals[r][t][o])
                                })
                                .collect()
                        })
                        .collect()
                }
                Op::Lstm {
                    src,
                    input,
                    hidden,
                    wr,
                    b,
                    ..
                } => {
                    let x = &vals[*src];
                    let (mut h, mut c) = (vec![0.0f64; *hidden], vec![0.0f64; *hidden]);
                    let sig = |v: f64| 1.0 / (1.0 + (-v).exp());
                    let mut seq = Vec::new();
                    for t in 0..l {
                        let gate = |g: usize, q: usize| {
                            let col = g * p + q;
                            let mut s = b[col] as f64;
                            for i in 0..*input {
                                s += wr[i * 4 * p + col] as f64 * x[t][i];
                            }
                            for i in 0..*hidden {
                                s += wr[(input + i) * 4 * p + col] as f64 * h[i];
                            }
                            s
                        };
                        let mut hn = vec![0.0; *hidden];
                        for q in 0..*hidden {
                            let (gi, go, gf, gc) =
                                (sig(gate(0, q)), sig(gate(1, q)), sig(gate(2, q)), gate(3, q).tanh());
                            c[q] = gf * c[q] + gi * gc;
                            hn[q] = go * c[q].tanh();
                        }
                        h = hn;
                        seq.push(h.clone());
                    }
                    seq
                }
                Op::TakeLast { src } => vec![vals[*src][l - 1].clone()],
                Op::FlattenDense { src, c_in, w, b } => vec![(0..node.c)
                    .map(|o| {
                        let mut s = b[o] as f64;
                        for t in 0..l {
                            for i in 0..*c_in {
                                s += w[(t * c_in + i) * p + o] as f64 * vals[*src][t][i];
                            }
                        }
                        s
                    })
                    .collect()],
                Op::Dense { src, n_in, w, b, relu } => vec![(0..node.c)
                    .map(|o| {
                        let mut s = b[o] as f64;
                        for i in 0..*n_in {
                            s += w[i * p + o] as f64 * vals[*src][0][i];
                        }
                        if *relu {
                            s.max(0.0)
                        } else {
                            s
                        }
                    })
                    .collect()],
            };
            vals.push(v);
        }
        let o = &vals[net.output];
        o[o.len() - 1][..j].to_vec()
    }

    #[test]
    fn incremental_matches_an_independent_reference() {
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        for with_lstm in [false, true] {
            let (l, j) = (24, 3);
            let net = toy_net(l, j, with_lstm);
            for w in 0..10 {
                // Half the windows start with zero padding.
                let zeros = if w % 2 == 0 { rng.random_range(0..l) } else { 0 };
                let window: Vec<f64> = (0..l * j)
                    .map(|i| {
                        if i / j < zeros {
                            0.0
                        } else {
                            rng.random_range(-50.0..50.0)
                        }
                    })
                    .collect();
                let a = incremental(&net, &window);
                let b = reference(&net, &window);
                for c in 0..j {
                    assert!(
                        (a[c] - b[c]).abs() < 1e-4 * (1.0 + b[c].abs()),
                        "lstm {with_lstm} w{w}: {a:?} vs {b:?}"
                    );
                }
            }
        }
    }

    #[test]
    fn shift_reuse_is_bit_identical_to_full_recompute() {
        for with_lstm in [false, true] {
            let (l, j) = (20, 3);
            let net = Arc::new(toy_net(l, j, with_lstm));
            let mut rng = ChaCha8Rng::seed_from_u64(11);
            let mut hist = vec![0.0f64; (l - 1) * j];
            let mut shifted = IncrementalNet::new(net.clone());
            let mut full = IncrementalNet::new(net.clone());
            shifted.set_history(&hist);
            for step in 0..60 {
                hist.copy_within(j.., 0);
                for c in 0..j {
                    hist[(l - 2) * j + c] = rng.random_range(-50.0..50.0);
                }
                shifted.shift_history(&hist);
                full.set_history(&hist);
                let last: Vec<f64> = (0..j).map(|_| rng.random_range(-50.0..50.0)).collect();
                let (mut a, mut b) = (vec![0.0; j], vec![0.0; j]);
                shifted.eval(&last, &mut a);
                full.eval(&last, &mut b);
                for c in 0..j {
                    assert_eq!(a[c].to_bits(), b[c].to_bits(), "step {step} joint {c} lstm {with_lstm}");
                }
            }
        }
    }

    #[test]
    fn jacobian_matches_finite_differences() {
        for (with_lstm, simplified) in [(false, false), (true, false), (false, true), (true, true)] {
            let (l, j) = (16, 3);
            // Simplified, a block's ReLU and residual add are fused into its second conv.
            let net = toy_net(l, j, with_lstm);
            let net = Arc::new(if simplified { net.simplify() } else { net });
            let mut ev = IncrementalNet::new(net);
            let mut rng = ChaCha8Rng::seed_from_u64(3);
            for _ in 0..20 {
                let hist: Vec<f64> = (0..(l - 1) * j).map(|_| rng.random_range(-40.0..40.0)).collect();
                ev.set_history(&hist);
                let q: Vec<f64> = (0..j).map(|_| rng.random_range(-40.0..40.0)).collect();
                let (mut y, mut jac) = (vec![0.0; j], vec![0.0; j * j]);
                ev.eval_jacobian(&q, &mut y, &mut jac);
                let mut y0 = vec![0.0; j];
                ev.eval(&q, &mut y0);
                assert_eq!(y, y0, "eval_jacobian's value equals eval's");
                let h = 1e-2;
                for c in 0..j {
                    let (mut qp, mut qm) = (q.clone(), q.clone());
                    qp[c] += h;
                    qm[c] -= h;
                    let (mut yp, mut ym) = (vec![0.0; j], vec![0.0; j]);
                    ev.eval(&qp, &mut yp);
                    ev.eval(&qm, &mut ym);
                    for r in 0..j {
                        let fd = (yp[r] - ym[r]) / (2.0 * h);
                        let an = jac[r * j + c];
                        // ReLU kinks inside ±h make central differences disagree; f32 noise
                        // is ~1e-3 here. A wrong formula is off by O(1).
                        assert!(
                            (fd - an).abs() < 2e-2 * (1.0 + an.abs()),
                            "lstm {with_lstm} simplified {simplified} d{r}/d{c}: fd {fd} vs {an}"
                        );
                    }
                }
            }
        }
    }

    /// Runs `a` (the narrow plan) and `b` (the node walk) through the same shifted windows and
    /// trials; every output and Jacobian entry must have the same bits.
    fn assert_narrow_matches_generic(net: Net, seed: u64, what: &str) {
        let (l, j) = (net.seq_len, net.joints);
        let net = Arc::new(net);
        let mut a = IncrementalNet::new(net.clone());
        assert!(a.is_narrow(), "{what}: no narrow plan");
        let mut b = IncrementalNet::new(net).into_generic();
        assert!(!b.is_narrow());
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let mut hist = vec![0.0f64; (l - 1) * j];
        let bits = |v: &[f64]| v.iter().map(|f| f.to_bits()).collect::<Vec<_>>();
        for step in 0..40 {
            hist.copy_within(j.., 0);
            for c in 0..j {
                hist[(l - 2) * j + c] = rng.random_range(-60.0..60.0);
            }
            // Every fifth window from scratch, the others shifted: both feed the plan.
            if step % 5 == 0 {
                a.set_history(&hist);
                b.set_history(&hist);
            } else {
                a.shift_history(&hist);
                b.shift_history(&hist);
            }
            for _ in 0..6 {
                let last: Vec<f64> = (0..j).map(|_| rng.random_range(-60.0..60.0)).collect();
                let (mut ya, mut yb) = (vec![0.0; j], vec![0.0; j]);
                a.eval(&last, &mut ya);
                b.eval(&last, &mut yb);
                assert_eq!(bits(&ya), bits(&yb), "{what} step {step}: eval");
                let (mut ja, mut jb) = (vec![0.0; j * j], vec![0.0; j * j]);
                a.eval_jacobian(&last, &mut ya, &mut ja);
                b.eval_jacobian(&last, &mut yb, &mut jb);
                assert_eq!(bits(&ya), bits(&yb), "{what} step {step}: eval_jacobian value");
                assert_eq!(bits(&ja), bits(&jb), "{what} step {step}: jacobian");
            }
        }
    }

    #[test]
    fn narrow_plan_is_bit_identical_to_the_node_walk() {
        for (l, j) in [(20usize, 3usize), (16, 5), (12, 8), (9, 1)] {
            let net = toy_net(l, j, false);
            assert_narrow_matches_generic(net.clone(), 31 + j as u64, &format!("toy L{l} J{j}"));
            // Simplified: ReLUs and residual adds fused into the convolutions.
            assert_narrow_matches_generic(net.simplify(), 37 + j as u64, &format!("simplified toy L{l} J{j}"));
        }
    }

    #[test]
    fn nets_wider_than_a_register_or_with_an_lstm_keep_the_node_walk() {
        assert!(!IncrementalNet::new(Arc::new(toy_net(10, 3, true))).is_narrow());
        assert!(!IncrementalNet::new(Arc::new(toy_net(10, 9, false))).is_narrow());
        assert!(IncrementalNet::new(Arc::new(toy_net(10, 8, false))).is_narrow());
    }

    #[test]
    fn blocked_matvec_is_bit_identical_to_row_major() {
        let mut rng = ChaCha8Rng::seed_from_u64(17);
        for (rows, p) in [(133usize, 512usize), (7, 32), (4, 16), (1, 48), (130, 64)] {
            let w = rand_vec(&mut rng, rows * p, 1.0);
            let init = rand_vec(&mut rng, p, 1.0);
            let wb = block_rows(&w, rows, p);
            for (row0, n) in [(0, rows), (0, rows.min(5)), (rows.min(5), rows - rows.min(5))] {
                let x = rand_vec(&mut rng, n, 3.0);
                let (mut a, mut b) = (vec![0.0f32; p], vec![0.0f32; p]);
                matvec(&mut a, &init, &w[row0 * p..(row0 + n) * p], &x);
                matvec_blocked(&mut b, &init, &wb, rows, row0, &x);
                let bits = |v: &[f32]| v.iter().map(|f| f.to_bits()).collect::<Vec<_>>();
                assert_eq!(bits(&a), bits(&b), "rows {rows} p {p} row0 {row0} n {n}");
            }
        }
    }

    #[test]
    fn direction_batched_matvec_is_bit_identical_to_one_per_direction() {
        let mut rng = ChaCha8Rng::seed_from_u64(19);
        for (n_in, p, ps, dirs) in [(5usize, 8usize, 8usize, 5usize), (13, 16, 16, 5), (3, 24, 8, 2)] {
            let w = rand_vec(&mut rng, n_in * p, 1.0);
            let init = rand_vec(&mut rng, p, 1.0);
            let x = rand_vec(&mut rng, dirs * ps, 2.0);
            let mut a = vec![0.0f32; dirs * p];
            for d in 0..dirs {
                matvec(&mut a[d * p..(d + 1) * p], &init, &w, &x[d * ps..d * ps + n_in]);
            }
            let mut b = vec![0.0f32; dirs * p];
            matvec_dirs(&mut b, &init, &w, &x, ps, n_in, dirs);
            let bits = |v: &[f32]| v.iter().map(|f| f.to_bits()).collect::<Vec<_>>();
            assert_eq!(bits(&a), bits(&b), "n_in {n_in} p {p} dirs {dirs}");
        }
    }

    #[test]
    fn zero_history_is_left_zero_padding() {
        // A conv's first columns must equal a window whose earlier entries are zeros: check
        // that evaluating window [0..0, x] equals the net on L=1 columns of the same weights.
        let (l, j) = (12, 2);
        let net = toy_net(l, j, false);
        let zero_hist = vec![0.0; (l - 1) * j];
        let mut ev = IncrementalNet::new(Arc::new(net.clone()));
        ev.set_history(&zero_hist);
        let mut a = vec![0.0; j];
        ev.eval(&[3.0, -4.0], &mut a);
        let mut window = zero_hist.clone();
        window.extend([3.0, -4.0]);
        let b = reference(&net, &window);
        assert!(a.iter().zip(&b).all(|(x, y)| (x - y).abs() < 1e-4), "{a:?} vs {b:?}");
    }

    #[test]
    fn simplify_fuses_and_prunes() {
        let net = toy_net(10, 2, true);
        let before = net.nodes.len();
        let s = net.clone().simplify();
        assert!(s.nodes.len() < before);
        let mut w = vec![0.5; 10 * 2];
        w[19] = -2.0;
        assert_eq!(incremental(&net, &w), incremental(&s, &w));
        let (a, b) = (incremental(&s, &w), reference(&net, &w));
        assert!(a.iter().zip(&b).all(|(x, y)| (x - y).abs() < 1e-4), "{a:?} vs {b:?}");
        let sum = s.summary();
        assert_eq!(sum.convs, 6);
        assert_eq!(sum.residual_blocks, 3);
        assert_eq!(sum.blocks_relu_after_second_conv, 2);
        assert!(sum.lstm);
    }
}
