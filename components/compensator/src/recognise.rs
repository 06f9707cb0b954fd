//! Recognises FNN / LSTM / TCN / TCN-LSTM graphs in tract's decluttered typed model and turns
//! them into a [`Net`] for the incremental evaluator.
//!
//! Decluttering folds what PyTorch's exporter writes around the arithmetic (the
//! ConstantOfShape/Concat/Slice/Cast chains computing causal pad amounts, the Transposes around
//! the convolutions, Flatten + Gemm) into convolutions with explicit padding, axis moves and
//! einsums, so one walk over the typed graph handles PyTorch's files and bowden's own. The
//! walk tracks, for every value, which axis is time and which is channels; anything it does
//! not understand makes the whole graph "unrecognised" (it then runs through tract). The LSTM
//! weights come from the ONNX `LSTM` node itself (tract rewrites it into a Scan loop).
//!
//! Whatever is recognised is checked against tract's full evaluation at load, so a
//! misreading cannot reach the control loop.

use crate::net::{build, AffineOp, Net, Node, NodeId, Op};
use std::collections::HashMap;
use std::sync::Arc;
use tract_onnx::prelude::*;
use tract_onnx::tract_core::ops::array::{Gather, Pad, PadMode, Slice};
use tract_onnx::tract_core::ops::binary::TypedBinOp;
use tract_onnx::tract_core::ops::change_axes::AxisOp;
use tract_onnx::tract_core::ops::cnn::{Conv, KernelFormat, PaddingSpec};
use tract_onnx::tract_core::ops::einsum::EinSum;
use tract_onnx::tract_core::ops::konst::Const;
use tract_onnx::tract_core::ops::nn::DataFormat;
use tract_onnx::tract_core::ops::scan::{InputMapping, Scan};
use tract_onnx::tract_core::ops::source::TypedSource;

/// Weights of an ONNX `LSTM` node, read from the protobuf.
#[derive(Debug, Clone)]
pub(crate) struct ProtoLstm {
    pub name: String,
    pub input: usize,
    pub hidden: usize,
    /// `W[4H][I]`, `R[4H][H]`, `B[8H]` (zeros when absent), gates i, o, f, c.
    pub w: Vec<f32>,
    pub r: Vec<f32>,
    pub b: Vec<f32>,
    /// Why this node cannot be run by the evaluator (peepholes, other activations, …).
    pub unsupported: Option<String>,
    /// The final cell state `Y_c` feeds something. The final hidden state `Y_h` is the hidden
    /// sequence's last column and is supported; `Y_c` is not.
    pub final_cell_used: bool,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Pending {
    None,
    /// Zero padding on the time axis not yet consumed by a convolution.
    Padded {
        left: usize,
        right: usize,
    },
    /// A convolution over right-padded input: only the first L columns are causal.
    Chomp,
}

#[derive(Clone, Debug)]
struct Val {
    node: NodeId,
    dims: Vec<usize>,
    time: Option<usize>,
    chan: usize,
    pending: Pending,
}

#[derive(Clone)]
enum Slot {
    Const(Arc<Tensor>),
    Val(Val),
}

struct Walker<'a> {
    l: usize,
    j: usize,
    nodes: Vec<Node>,
    slots: HashMap<OutletId, Slot>,
    model: &'a TypedModel,
    lstms: &'a [ProtoLstm],
}

type R<T> = Result<T, String>;

/// Walks `model` (decluttered, input fixed to `[1, l, j]`) into a [`Net`], or says why not.
pub(crate) fn recognise(model: &TypedModel, l: usize, j: usize, lstms: &[ProtoLstm]) -> R<Net> {
    let mut w = Walker {
        l,
        j,
        nodes: Vec::new(),
        slots: HashMap::new(),
        model,
        lstms,
    };
    let inputs = model.input_outlets().map_err(|e| e.to_string())?;
    let outputs = model.output_outlets().map_err(|e| e.to_string())?;
    if inputs.len() != 1 || outputs.len() != 1 {
        return Err(format!(
            "{} inputs and {} outputs (expected 1 and 1)",
            inputs.len(),
            outputs.len()
        ));
    }
    for id in model.eval_order().map_err(|e| e.to_string())? {
        w.node(id)?;
    }
    let out = w.val(outputs[0])?;
    if out.time.is_some() || out.pending != Pending::None || w.nodes[out.node].c != j {
        return Err(format!("the output is not a vector of {j} joints"));
    }
    let net = Net {
        nodes: w.nodes,
        output: out.node,
        seq_len: l,
        joints: j,
    };
    Ok(net.simplify())
}

fn tensor_f32(t: &Tensor) -> R<Vec<f32>> {
    if t.datum_type() != f32::datum_type() {
        return Err(format!("constant of type {:?} where f32 was expected", t.datum_type()));
    }
    let v = t.to_plain_array_view::<f32>().map_err(|e| e.to_string())?;
    Ok(v.iter().copied().collect())
}

fn tensor_i64_scalar(t: &Tensor) -> Option<i64> {
    if t.len() != 1 {
        return None;
    }
    let c = t.cast_to::<i64>().ok()?;
    let v = c.to_plain_array_view::<i64>().ok()?;
    v.iter().next().copied()
}

impl Walker<'_> {
    fn fact_dims(&self, o: OutletId) -> R<Vec<usize>> {
        let f = self.model.outlet_fact(o).map_err(|e| e.to_string())?;
        if f.datum_type != f32::datum_type() && f.konst.is_none() {
            return Err(format!("value of type {:?} (only f32 is supported)", f.datum_type));
        }
        f.shape
            .as_concrete()
            .map(|s| s.to_vec())
            .ok_or_else(|| "symbolic shape".to_string())
    }

    fn val(&self, o: OutletId) -> R<Val> {
        match self.slots.get(&o) {
            Some(Slot::Val(v)) => Ok(v.clone()),
            Some(Slot::Const(_)) => Err("constant where a value was expected".into()),
            None => Err(format!("outlet {o:?} was not produced by a recognised node")),
        }
    }

    fn push(&mut self, op: Op, seq: bool, c: usize) -> NodeId {
        self.nodes.push(Node { op, seq, c });
        self.nodes.len() - 1
    }

    /// Checks that `dims` has the size of the time/channel axes where claimed and 1 elsewhere.
    fn check_layout(&self, v: &Val, time_len: usize) -> R<()> {
        let c = self.nodes[v.node].c;
        for (a, &d) in v.dims.iter().enumerate() {
            let want = if Some(a) == v.time {
                time_len
            } else if a == v.chan {
                c
            } else {
                1
            };
            if d != want {
                return Err(format!(
                    "unexpected shape {:?} (time axis {:?}, channel axis {})",
                    v.dims, v.time, v.chan
                ));
            }
        }
        Ok(())
    }

    fn node(&mut self, id: usize) -> R<()> {
        let node = self.model.node(id);
        let out0 = OutletId::new(id, 0);
        let ctx = |e: String| format!("node `{}` ({}): {e}", node.name, node.op.name());

        if let Some(src) = node.op_as::<TypedSource>() {
            let dims = src
                .fact
                .shape
                .as_concrete()
                .ok_or_else(|| ctx("symbolic input shape".into()))?
                .to_vec();
            if dims != [1, self.l, self.j] {
                return Err(ctx(format!("input shape {dims:?}")));
            }
            let n = self.push(Op::Input, true, self.j);
            debug_assert_eq!(n, 0);
            self.slots.insert(
                out0,
                Slot::Val(Val {
                    node: n,
                    dims,
                    time: Some(1),
                    chan: 2,
                    pending: Pending::None,
                }),
            );
            return Ok(());
        }
        if let Some(k) = node.op_as::<Const>() {
            self.slots.insert(out0, Slot::Const(k.val().clone()));
            return Ok(());
        }
        let res = if let Some(b) = node.op_as::<TypedBinOp>() {
            self.binop(id, b.0.name())
        } else if let Some(c) = node.op_as::<Conv>() {
            self.conv(id, c)
        } else if let Some(p) = node.op_as::<Pad>() {
            self.pad(id, p)
        } else if let Some(s) = node.op_as::<Slice>() {
            self.slice(id, s)
        } else if let Some(g) = node.op_as::<Gather>() {
            self.gather(id, g)
        } else if let Some(a) = node.op_as::<AxisOp>() {
            self.axis_op(id, a)
        } else if let Some(e) = node.op_as::<EinSum>() {
            self.einsum(id, e)
        } else if let Some(s) = node.op_as::<Scan>() {
            self.scan(id, s)
        } else if node.op.name() == "Identity" {
            let v = self.val(node.inputs[0])?;
            self.slots.insert(out0, Slot::Val(v));
            Ok(())
        } else {
            Err("operator not part of a recognised FNN/LSTM/TCN graph".into())
        };
        res.map_err(ctx)
    }

    fn binop(&mut self, id: usize, name: &str) -> R<()> {
        let node = self.model.node(id);
        let out0 = OutletId::new(id, 0);
        let out_dims = self.fact_dims(out0)?;
        let a = self.slots.get(&node.inputs[0]).cloned();
        let b = self.slots.get(&node.inputs[1]).cloned();
        match (a, b) {
            // tract folds constant arithmetic while decluttering; one it left is not ours.
            (Some(Slot::Const(_)), Some(Slot::Const(_))) => Err("constant-only arithmetic".into()),
            (Some(Slot::Val(x)), Some(Slot::Const(c))) | (Some(Slot::Const(c)), Some(Slot::Val(x))) => {
                let const_first = matches!(self.slots.get(&node.inputs[0]), Some(Slot::Const(_)));
                if x.pending != Pending::None {
                    return Err("elementwise op on a padded value".into());
                }
                if out_dims != x.dims {
                    return Err(format!("broadcast changes the shape {:?} → {out_dims:?}", x.dims));
                }
                let cvals = tensor_f32(&c)?;
                let ch = self.nodes[x.node].c;
                let per_chan = self.channel_const(&x, c.shape(), &cvals)?;
                let (seq, node_c) = (self.nodes[x.node].seq, ch);
                let new = if name == "Max" {
                    if cvals.iter().any(|&v| v != 0.0) {
                        return Err("max with a non-zero constant".into());
                    }
                    self.push(Op::Relu { src: x.node }, seq, node_c)
                } else {
                    let aop = match (name, const_first) {
                        ("Add", _) => AffineOp::Add,
                        ("Mul", _) => AffineOp::Mul,
                        ("Sub", false) => AffineOp::Sub,
                        ("Sub", true) => AffineOp::SubFrom,
                        ("Div", false) => AffineOp::Div,
                        _ => return Err(format!("{name} with a constant")),
                    };
                    let fill = if matches!(aop, AffineOp::Mul | AffineOp::Div) {
                        1.0
                    } else {
                        0.0
                    };
                    let steps = vec![(aop, build::channel_vec(&per_chan, fill))];
                    self.push(Op::Affine { src: x.node, steps }, seq, node_c)
                };
                self.slots.insert(out0, Slot::Val(Val { node: new, ..x }));
                Ok(())
            }
            (Some(Slot::Val(x)), Some(Slot::Val(y))) => {
                if name != "Add" {
                    return Err(format!("{name} of two values"));
                }
                if x.dims != y.dims
                    || x.time != y.time
                    || x.chan != y.chan
                    || x.pending != Pending::None
                    || y.pending != Pending::None
                {
                    return Err(format!(
                        "adding values of different layouts {:?} and {:?}",
                        x.dims, y.dims
                    ));
                }
                let (seq, c) = (self.nodes[x.node].seq, self.nodes[x.node].c);
                let new = self.push(Op::Add { a: x.node, b: y.node }, seq, c);
                self.slots.insert(out0, Slot::Val(Val { node: new, ..x }));
                Ok(())
            }
            _ => Err("input not produced by a recognised node".into()),
        }
    }

    /// The per-channel values of a constant that broadcasts along everything but channels.
    fn channel_const(&self, x: &Val, cshape: &[usize], cvals: &[f32]) -> R<Vec<f32>> {
        let c = self.nodes[x.node].c;
        let rank = x.dims.len();
        if cshape.len() > rank {
            return Err("constant of higher rank than the value".into());
        }
        let offset = rank - cshape.len();
        for (i, &d) in cshape.iter().enumerate() {
            if d != 1 && (i + offset != x.chan || d != c) {
                return Err(format!("constant of shape {cshape:?} varies along a non-channel axis"));
            }
        }
        if cvals.len() == 1 {
            Ok(vec![cvals[0]; c])
        } else if cvals.len() == c {
            Ok(cvals.to_vec())
        } else {
            Err(format!("constant of shape {cshape:?}"))
        }
    }

    fn conv(&mut self, id: usize, conv: &Conv) -> R<()> {
        let node = self.model.node(id);
        let out0 = OutletId::new(id, 0);
        if conv.q_params.is_some() || conv.group != 1 {
            return Err("quantised or grouped convolution".into());
        }
        if conv.kernel_fmt != KernelFormat::OIHW {
            return Err(format!("kernel format {:?}", conv.kernel_fmt));
        }
        let ps = &conv.pool_spec;
        if ps.kernel_shape.len() != 1 {
            return Err("not a 1-D convolution".into());
        }
        if ps.strides.as_ref().is_some_and(|s| s.iter().any(|&v| v != 1)) {
            return Err("strided convolution".into());
        }
        let k = ps.kernel_shape[0];
        let dil = ps.dilations.as_ref().map(|d| d[0]).unwrap_or(1);
        let (before, after) = match &ps.padding {
            PaddingSpec::Valid => (0, 0),
            PaddingSpec::Explicit(b, a) | PaddingSpec::ExplicitOnnxPool(b, a, _) => (b[0], a[0]),
            other => return Err(format!("padding {other:?} is not causal")),
        };
        let x = self.val(node.inputs[0])?;
        let (want_chan, want_time) = match ps.data_format {
            DataFormat::NCHW => (1, 2),
            DataFormat::NHWC => (2, 1),
            DataFormat::CHW => (0, 1),
            DataFormat::HWC => (1, 0),
        };
        let rank = if matches!(ps.data_format, DataFormat::NCHW | DataFormat::NHWC) {
            3
        } else {
            2
        };
        if x.chan != want_chan || x.time != Some(want_time) || x.dims.len() != rank {
            return Err(format!(
                "data format {:?} does not match the value's layout {:?}",
                ps.data_format, x.dims
            ));
        }
        let (pad_l, pad_r) = match x.pending {
            Pending::None => (0, 0),
            Pending::Padded { left, right } => (left, right),
            Pending::Chomp => return Err("convolution of an unsliced convolution".into()),
        };
        let left = pad_l + before;
        let right = pad_r + after;
        if left != (k - 1) * dil {
            return Err(format!(
                "left padding {left} ≠ (k−1)·dilation = {} (not a causal convolution)",
                (k - 1) * dil
            ));
        }
        let kernel = match self.slots.get(&node.inputs[1]) {
            Some(Slot::Const(t)) => t.clone(),
            _ => return Err("kernel is not a constant".into()),
        };
        let c_in = self.nodes[x.node].c;
        let kshape = kernel.shape().to_vec();
        let c_out = ps.output_channels;
        if kshape != [c_out, c_in, k] {
            return Err(format!("kernel shape {kshape:?}, expected [{c_out}, {c_in}, {k}]"));
        }
        let wv = tensor_f32(&kernel)?;
        let bias = match node.inputs.get(2).and_then(|i| self.slots.get(i)) {
            None => vec![0.0; c_out],
            Some(Slot::Const(t)) => {
                let b = tensor_f32(t)?;
                match b.len() {
                    1 => vec![b[0]; c_out],
                    n if n == c_out => b,
                    _ => return Err(format!("bias of shape {:?}", t.shape())),
                }
            }
            Some(Slot::Val(_)) => return Err("bias is not a constant".into()),
        };
        let n = build::conv(x.node, c_out, c_in, k, dil, &wv, &bias);
        let new = self.push(n.op, true, c_out);
        let mut dims = x.dims.clone();
        dims[x.chan] = c_out;
        let out_dims = self.fact_dims(out0)?;
        dims[want_time] = self.l + right;
        if dims != out_dims {
            return Err(format!("output shape {out_dims:?}, expected {dims:?}"));
        }
        let pending = if right == 0 { Pending::None } else { Pending::Chomp };
        self.slots.insert(
            out0,
            Slot::Val(Val {
                node: new,
                dims,
                time: x.time,
                chan: x.chan,
                pending,
            }),
        );
        Ok(())
    }

    fn pad(&mut self, id: usize, pad: &Pad) -> R<()> {
        let node = self.model.node(id);
        let x = self.val(node.inputs[0])?;
        match &pad.mode {
            PadMode::Constant(t) if tensor_f32(t).map(|v| v.iter().all(|&z| z == 0.0)).unwrap_or(false) => {}
            _ => return Err("non-zero padding".into()),
        }
        let time = x.time.ok_or("padding a vector")?;
        let (mut left, mut right) = match x.pending {
            Pending::None => (0, 0),
            Pending::Padded { left, right } => (left, right),
            Pending::Chomp => return Err("padding an unsliced convolution".into()),
        };
        for (a, &(b, e)) in pad.pads.iter().enumerate() {
            if a == time {
                left += b;
                right += e;
            } else if b != 0 || e != 0 {
                return Err("padding along a non-time axis".into());
            }
        }
        let mut dims = x.dims.clone();
        dims[time] = self.l + left + right;
        self.slots.insert(
            OutletId::new(id, 0),
            Slot::Val(Val {
                dims,
                pending: Pending::Padded { left, right },
                ..x
            }),
        );
        Ok(())
    }

    fn slice(&mut self, id: usize, s: &Slice) -> R<()> {
        let node = self.model.node(id);
        let x = self.val(node.inputs[0])?;
        let start = s.start.to_i64().map_err(|_| "symbolic slice")?;
        let end = s.end.to_i64().map_err(|_| "symbolic slice")?;
        let l = self.l as i64;
        let out0 = OutletId::new(id, 0);
        if Some(s.axis) == x.time {
            if start == 0 && end == l && matches!(x.pending, Pending::None | Pending::Chomp) {
                let mut dims = x.dims.clone();
                dims[s.axis] = self.l;
                self.slots.insert(
                    out0,
                    Slot::Val(Val {
                        dims,
                        pending: Pending::None,
                        ..x
                    }),
                );
                return Ok(());
            }
            if start == l - 1 && end == l && x.pending == Pending::None {
                let c = self.nodes[x.node].c;
                let new = self.push(Op::TakeLast { src: x.node }, false, c);
                let mut dims = x.dims.clone();
                dims[s.axis] = 1;
                self.slots.insert(
                    out0,
                    Slot::Val(Val {
                        node: new,
                        dims,
                        time: None,
                        chan: x.chan,
                        pending: Pending::None,
                    }),
                );
                return Ok(());
            }
            return Err(format!("slice {start}..{end} of the time axis"));
        }
        if x.dims[s.axis] == 1 && start == 0 && end == 1 {
            self.slots.insert(out0, Slot::Val(x));
            return Ok(());
        }
        Err(format!("slice along axis {}", s.axis))
    }

    fn gather(&mut self, id: usize, g: &Gather) -> R<()> {
        let node = self.model.node(id);
        let x = self.val(node.inputs[0])?;
        let idx = match self.slots.get(&node.inputs[1]) {
            Some(Slot::Const(t)) => t.clone(),
            _ => return Err("gather with non-constant indices".into()),
        };
        let i = tensor_i64_scalar(&idx).ok_or("gather of more than one index")?;
        if Some(g.axis) != x.time || x.pending != Pending::None || !(i == -1 || i == self.l as i64 - 1) {
            return Err(format!("gather of index {i} along axis {}", g.axis));
        }
        let c = self.nodes[x.node].c;
        let new = self.push(Op::TakeLast { src: x.node }, false, c);
        let mut dims = x.dims.clone();
        let mut chan = x.chan;
        if idx.rank() == 0 {
            dims.remove(g.axis);
            if chan > g.axis {
                chan -= 1;
            }
        } else {
            dims[g.axis] = 1;
        }
        let v = Val {
            node: new,
            dims,
            time: None,
            chan,
            pending: Pending::None,
        };
        self.check_layout(&v, 1)?;
        self.slots.insert(OutletId::new(id, 0), Slot::Val(v));
        Ok(())
    }

    fn axis_op(&mut self, id: usize, op: &AxisOp) -> R<()> {
        let node = self.model.node(id);
        let x = self.val(node.inputs[0])?;
        if x.pending != Pending::None {
            return Err("axis change on a padded value".into());
        }
        let out_dims = self.fact_dims(OutletId::new(id, 0))?;
        let (time, chan) = if let AxisOp::Move(..) = op {
            let t = match x.time {
                Some(t) => Some(op.transform_axis(t).ok_or("time axis lost")?),
                None => None,
            };
            (t, op.transform_axis(x.chan).ok_or("channel axis lost")?)
        } else {
            // Add / Rm / Reshape: the non-unit axes keep their order; find them again.
            let roles: Vec<(usize, bool)> = x
                .dims
                .iter()
                .enumerate()
                .filter(|(_, &d)| d != 1)
                .map(|(a, &d)| (d, Some(a) == x.time))
                .collect();
            let out_non1: Vec<(usize, usize)> = out_dims
                .iter()
                .enumerate()
                .filter(|(_, &d)| d != 1)
                .map(|(a, &d)| (a, d))
                .collect();
            // Unit-size channel or time axes cannot be told apart from batch axes.
            let ambiguous = self.nodes[x.node].c == 1 || (x.time.is_some() && self.l == 1);
            if ambiguous || roles.len() != out_non1.len() || roles.iter().zip(&out_non1).any(|(r, o)| r.0 != o.1) {
                return Err(format!("reshape {:?} → {out_dims:?}", x.dims));
            }
            let mut t = None;
            let mut ch = None;
            for (r, o) in roles.iter().zip(&out_non1) {
                if r.1 {
                    t = Some(o.0);
                } else {
                    ch = Some(o.0);
                }
            }
            (t, ch.ok_or("channel axis lost")?)
        };
        let v = Val {
            node: x.node,
            dims: out_dims,
            time,
            chan,
            pending: Pending::None,
        };
        self.check_layout(&v, self.l)?;
        self.slots.insert(OutletId::new(id, 0), Slot::Val(v));
        Ok(())
    }

    // Long: one pattern match over the ONNX einsum equations PyTorch emits for the LSTM, each case a few lines.
    fn einsum(&mut self, id: usize, e: &EinSum) -> R<()> {
        let node = self.model.node(id);
        if e.q_params.is_some() || node.inputs.len() != 2 || e.operating_dt != f32::datum_type() {
            return Err("not a plain f32 two-operand einsum".into());
        }
        let (di, wi) = match (self.slots.get(&node.inputs[0]), self.slots.get(&node.inputs[1])) {
            (Some(Slot::Val(_)), Some(Slot::Const(_))) => (0, 1),
            (Some(Slot::Const(_)), Some(Slot::Val(_))) => (1, 0),
            _ => return Err("einsum needs one value and one constant operand".into()),
        };
        let x = self.val(node.inputs[di])?;
        if x.pending != Pending::None {
            return Err("einsum of a padded value".into());
        }
        let wt = match self.slots.get(&node.inputs[wi]) {
            Some(Slot::Const(t)) => t.clone(),
            _ => unreachable!(),
        };
        let wshape = wt.shape().to_vec();
        let out0 = OutletId::new(id, 0);
        let out_dims = self.fact_dims(out0)?;
        let c_in = self.nodes[x.node].c;

        // Classify every axis of the mapping.
        let mut k_axis = None; // data channel axis: (pos in weight)
        let mut t_axis = None; // data time axis: (pos in weight or None, pos in output or None)
        let mut n_candidates = Vec::new(); // output features: (pos in weight, pos in output)
        for ax in e.axes.iter_all_axes() {
            let dpos = ax.inputs[di].first().copied();
            let wpos = ax.inputs[wi].first().copied();
            let opos = ax.outputs[0].first().copied();
            if ax.inputs[di].len() > 1 || ax.inputs[wi].len() > 1 || ax.outputs[0].len() > 1 {
                return Err("repeated axis in einsum".into());
            }
            if dpos.is_some() && dpos == Some(x.chan) {
                match (wpos, opos) {
                    (Some(wp), None) => k_axis = Some(wp),
                    _ => return Err("channel axis not contracted with the weights".into()),
                }
            } else if dpos.is_some() && dpos == x.time {
                t_axis = Some((wpos, opos));
            } else if let (None, Some(wp), Some(op)) = (dpos, wpos, opos) {
                n_candidates.push((wp, op));
            } else {
                // Any other axis must be of size 1 wherever it appears.
                let ones = dpos.is_none_or(|p| x.dims[p] == 1)
                    && wpos.is_none_or(|p| wshape[p] == 1)
                    && opos.is_none_or(|p| out_dims[p] == 1);
                if !ones {
                    return Err(format!(
                        "einsum axis `{}` is neither batch, time, channel nor features",
                        ax.repr
                    ));
                }
            }
        }
        let kw = k_axis.ok_or("no contracted channel axis")?;
        let big: Vec<_> = n_candidates.iter().filter(|(w, _)| wshape[*w] != 1).copied().collect();
        let (nw, no) = match big.len() {
            0 => *n_candidates.first().ok_or("no output feature axis")?,
            1 => big[0],
            _ => return Err("weights with two output axes".into()),
        };
        let n_out = wshape[nw];
        let wv = wt.to_plain_array_view::<f32>().map_err(|e| e.to_string())?;
        let mut idx = vec![0usize; wshape.len()];
        match (x.time, t_axis) {
            (None, None) => {
                // Dense on a vector.
                let mut w_ni = vec![0.0f32; n_out * c_in];
                for o in 0..n_out {
                    for i in 0..c_in {
                        idx[nw] = o;
                        idx[kw] = i;
                        w_ni[o * c_in + i] = wv[idx.as_slice()];
                    }
                }
                let n = build::dense(x.node, n_out, c_in, &w_ni, &vec![0.0; n_out]);
                let new = self.push(n.op, false, n_out);
                let v = Val {
                    node: new,
                    dims: out_dims,
                    time: None,
                    chan: no,
                    pending: Pending::None,
                };
                self.check_layout(&v, 1)?;
                self.slots.insert(out0, Slot::Val(v));
                Ok(())
            }
            (Some(_), Some((Some(tw), None))) => {
                // Dense over the flattened window.
                let l = self.l;
                let mut w_ntc = vec![0.0f32; n_out * l * c_in];
                for o in 0..n_out {
                    for t in 0..l {
                        for i in 0..c_in {
                            idx[nw] = o;
                            idx[tw] = t;
                            idx[kw] = i;
                            w_ntc[(o * l + t) * c_in + i] = wv[idx.as_slice()];
                        }
                    }
                }
                let n = build::flatten_dense(x.node, n_out, l, c_in, &w_ntc, &vec![0.0; n_out]);
                let new = self.push(n.op, false, n_out);
                let v = Val {
                    node: new,
                    dims: out_dims,
                    time: None,
                    chan: no,
                    pending: Pending::None,
                };
                self.check_layout(&v, 1)?;
                self.slots.insert(out0, Slot::Val(v));
                Ok(())
            }
            (Some(_), Some((None, Some(to)))) => {
                // Time-distributed dense = a 1×1 convolution.
                let mut w_oik = vec![0.0f32; n_out * c_in];
                for o in 0..n_out {
                    for i in 0..c_in {
                        idx[nw] = o;
                        idx[kw] = i;
                        w_oik[o * c_in + i] = wv[idx.as_slice()];
                    }
                }
                let n = build::conv(x.node, n_out, c_in, 1, 1, &w_oik, &vec![0.0; n_out]);
                let new = self.push(n.op, true, n_out);
                let v = Val {
                    node: new,
                    dims: out_dims,
                    time: Some(to),
                    chan: no,
                    pending: Pending::None,
                };
                self.check_layout(&v, self.l)?;
                self.slots.insert(out0, Slot::Val(v));
                Ok(())
            }
            _ => Err("einsum over time that is neither a flatten nor time-distributed".into()),
        }
    }

    fn scan(&mut self, id: usize, scan: &Scan) -> R<()> {
        let node = self.model.node(id);
        let lstm = self
            .lstms
            .iter()
            .find(|p| p.name == node.name)
            .or_else(|| (self.lstms.len() == 1).then(|| &self.lstms[0]))
            .ok_or("a loop that is not an ONNX LSTM node")?;
        if let Some(why) = &lstm.unsupported {
            return Err(why.clone());
        }
        let mut src = None;
        for (slot, m) in scan.input_mapping.iter().enumerate() {
            let outlet = node.inputs[slot];
            match m {
                InputMapping::State => match self.slots.get(&outlet) {
                    Some(Slot::Const(t)) if tensor_f32(t)?.iter().all(|&v| v == 0.0) => {}
                    _ => return Err("LSTM with a non-zero initial state".into()),
                },
                InputMapping::Scan(_) => {
                    let v = self.val(outlet)?;
                    let c = self.nodes[v.node].c;
                    // tract hoists the input projection X·Wᵀ out of the loop; the LSTM input
                    // is what that projection reads.
                    let x = if c == lstm.input {
                        v
                    } else if c == 4 * lstm.hidden {
                        let proj = self.model.node(outlet.node);
                        let data = proj
                            .inputs
                            .iter()
                            .find_map(|i| match self.slots.get(i) {
                                Some(Slot::Val(v)) => Some(v.clone()),
                                _ => None,
                            })
                            .ok_or("LSTM input projection without a data input")?;
                        if self.nodes[data.node].c != lstm.input {
                            return Err("LSTM input width mismatch".into());
                        }
                        data
                    } else {
                        return Err(format!("LSTM scanned input of width {c}"));
                    };
                    if x.time.is_none() {
                        return Err("LSTM over a vector".into());
                    }
                    src = Some(x);
                }
                InputMapping::Full => return Err("LSTM with a full (non-scanned) input".into()),
            }
        }
        let x = src.ok_or("LSTM without a scanned input")?;
        let n = build::lstm(x.node, lstm.input, lstm.hidden, &lstm.w, &lstm.r, &lstm.b);
        let new = self.push(n.op, true, lstm.hidden);
        let outputs = self.model.output_outlets().map_err(|e| e.to_string())?.to_vec();
        let used = |slot: usize| {
            node.outputs.get(slot).is_some_and(|o| !o.successors.is_empty())
                || outputs.contains(&OutletId::new(id, slot))
        };
        for m in &scan.output_mapping {
            if let Some(slot) = m.last_value_slot {
                if used(slot) {
                    if lstm.final_cell_used {
                        return Err(
                            "the LSTM's final cell state Y_c is used (only the hidden state is supported)".into(),
                        );
                    }
                    // With Y_c unused, the only final state anything reads is Y_h: for a single
                    // forward LSTM from a zero state that is the hidden sequence's last column
                    // (what `bowden train` exports, and PyTorch's `h_n`).
                    let take = self.push(Op::TakeLast { src: new }, false, lstm.hidden);
                    let dims = self.fact_dims(OutletId::new(id, slot))?;
                    let chan = (0..dims.len())
                        .rev()
                        .find(|&a| dims[a] == lstm.hidden)
                        .ok_or("cannot find the hidden axis of Y_h")?;
                    let v = Val {
                        node: take,
                        dims,
                        time: None,
                        chan,
                        pending: Pending::None,
                    };
                    self.check_layout(&v, 1)?;
                    self.slots.insert(OutletId::new(id, slot), Slot::Val(v));
                }
            }
            if let Some((slot, info)) = m.scan {
                let dims = self.fact_dims(OutletId::new(id, slot))?;
                let chan = (0..dims.len())
                    .find(|&a| a != info.axis && dims[a] == lstm.hidden)
                    .ok_or("cannot find the hidden axis")?;
                let v = Val {
                    node: new,
                    dims,
                    time: Some(info.axis),
                    chan,
                    pending: Pending::None,
                };
                self.check_layout(&v, self.l)?;
                self.slots.insert(OutletId::new(id, slot), Slot::Val(v));
            }
        }
        Ok(())
    }
}
