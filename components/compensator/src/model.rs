//! Loading contract-following ONNX models (tract-onnx), checking them, and building their
//! evaluators: the exact incremental one when the graph is recognised, tract otherwise.

use crate::net::{IncrementalNet, Net, NetSummary};
use crate::recognise::{recognise, ProtoLstm};
use crate::refine::WindowModel;
use bowden_interfaces::model::{self as contract, Architecture, ContractError, ModelMetadata, Support, TcnBlock};
use prost::Message;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use std::path::Path;
use std::sync::Arc;
use tract_onnx::pb;
use tract_onnx::prelude::*;

/// Why a model file was refused. Every variant names the file.
#[derive(Debug, thiserror::Error)]
pub enum ModelError {
    #[error("{path}: cannot read the model file: {source}")]
    Io {
        path: String,
        #[source]
        source: std::io::Error,
    },
    #[error("{path}: not a valid ONNX model, the file is corrupt or truncated (protobuf: {detail})")]
    Corrupt { path: String, detail: String },
    #[error("{path}: the ONNX model has no graph")]
    NoGraph { path: String },
    #[error("{path}: {source}")]
    Metadata {
        path: String,
        #[source]
        source: ContractError,
    },
    #[error("{path}: {what}: expected {expected}, found {found}")]
    Interface {
        path: String,
        what: String,
        expected: String,
        found: String,
    },
    #[error("{path}: weight tensor `{tensor}` has a non-finite value ({value}) at element {index}")]
    NonFiniteWeight {
        path: String,
        tensor: String,
        index: usize,
        value: f32,
    },
    #[error("{path}: tract cannot load the graph: {detail}")]
    Tract { path: String, detail: String },
    #[error("{path}: metadata says {key} = {declared} but the graph is {found}")]
    MetadataMismatch {
        path: String,
        key: &'static str,
        declared: String,
        found: String,
    },
    #[error(
        "{path}: the incremental evaluator differs from tract's full evaluation by {max_abs_diff_deg:.3e} deg \
         (tolerance {tolerance_deg:.1e} deg: the larger of the absolute floor and {relative:.1e} × the \
         outputs' scale {scale_deg:.3} deg) on check window {window}; refusing to run this model"
    )]
    IncrementalMismatch {
        path: String,
        max_abs_diff_deg: f64,
        tolerance_deg: f64,
        relative: f64,
        scale_deg: f64,
        window: usize,
    },
}

impl ModelError {
    /// Short stable name of the error kind (for counters and tests).
    pub fn kind(&self) -> &'static str {
        match self {
            ModelError::Io { .. } => "io",
            ModelError::Corrupt { .. } => "corrupt",
            ModelError::NoGraph { .. } => "no-graph",
            ModelError::Metadata { .. } => "metadata",
            ModelError::Interface { .. } => "interface",
            ModelError::NonFiniteWeight { .. } => "non-finite-weight",
            ModelError::Tract { .. } => "tract",
            ModelError::MetadataMismatch { .. } => "metadata-mismatch",
            ModelError::IncrementalMismatch { .. } => "incremental-mismatch",
        }
    }
}

/// How a model is loaded and checked.
#[derive(Debug, Clone)]
pub struct LoadOptions {
    /// Random windows on which the incremental evaluator is checked against tract.
    pub check_windows: usize,
    /// Absolute floor of the accepted |incremental − tract|, degrees.
    pub tolerance_deg: f64,
    /// Accepted |incremental − tract| relative to the outputs' scale (the largest |output| on
    /// the check windows). tract computes in f32, the incremental evaluator in f64: their
    /// difference grows with the size of the numbers, so an absolute bound refused models whose
    /// outputs are merely large (1.2e-4° against 1e-4°). The default, 1e-5, is about 80 f32
    /// ulps of the output — far below any real error of the evaluator (a wrong dilation or
    /// padding is off by degrees).
    pub relative: f64,
    /// Seed of the check windows (deterministic load).
    pub seed: u64,
}

impl LoadOptions {
    /// The accepted difference for outputs of scale `scale_deg`.
    pub fn tolerance_at(&self, scale_deg: f64) -> f64 {
        self.tolerance_deg.max(self.relative * scale_deg)
    }
}

impl Default for LoadOptions {
    fn default() -> Self {
        Self {
            check_windows: 8,
            tolerance_deg: 1e-4,
            relative: 1e-5,
            seed: 0x5eed,
        }
    }
}

/// A loaded, checked model.
#[derive(Clone)]
pub struct Model {
    path: String,
    meta: ModelMetadata,
    support: Option<Support>,
    producer: String,
    plan: Arc<TypedSimplePlan>,
    net: Option<Arc<Net>>,
    unrecognised: Option<String>,
    check_max_abs_diff_deg: Option<f64>,
}

impl std::fmt::Debug for Model {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Model")
            .field("path", &self.path)
            .field("meta", &self.meta)
            .field("incremental", &self.net.is_some())
            .field("check_max_abs_diff_deg", &self.check_max_abs_diff_deg)
            .finish()
    }
}

const FLOAT: i32 = 1;

impl Model {
    /// Loads `path` with the default checks.
    pub fn load(path: impl AsRef<Path>) -> Result<Model, ModelError> {
        Self::load_with(path, &LoadOptions::default())
    }

    pub fn load_with(path: impl AsRef<Path>, opts: &LoadOptions) -> Result<Model, ModelError> {
        let p = path.as_ref();
        let name = p.display().to_string();
        let bytes = std::fs::read(p).map_err(|source| ModelError::Io {
            path: name.clone(),
            source,
        })?;
        Self::from_bytes(&bytes, &name, p.parent(), opts)
    }

    /// Loads a model from memory; `name` is used in errors, `dir` resolves external data.
    pub fn from_bytes(bytes: &[u8], name: &str, dir: Option<&Path>, opts: &LoadOptions) -> Result<Model, ModelError> {
        let path = name.to_string();
        let proto = pb::ModelProto::decode(bytes).map_err(|e| ModelError::Corrupt {
            path: path.clone(),
            detail: e.to_string(),
        })?;
        let graph = proto
            .graph
            .as_ref()
            .ok_or_else(|| ModelError::NoGraph { path: path.clone() })?;
        if graph.node.is_empty() {
            return Err(ModelError::NoGraph { path });
        }
        let meta = ModelMetadata::from_props(|k| {
            proto
                .metadata_props
                .iter()
                .find(|p| p.key == k)
                .map(|p| p.value.as_str())
        })
        .map_err(|source| ModelError::Metadata {
            path: path.clone(),
            source,
        })?;
        let support = Support::from_props(
            |k| {
                proto
                    .metadata_props
                    .iter()
                    .find(|p| p.key == k)
                    .map(|p| p.value.as_str())
            },
            meta.joints,
        )
        .map_err(|source| ModelError::Metadata {
            path: path.clone(),
            source,
        })?;
        check_interface(&path, graph, &meta)?;
        check_finite(&path, graph)?;
        let lstms = proto_lstms(graph);

        let (l, j) = (meta.seq_len, meta.joints);
        let tract_err = |e: TractError| ModelError::Tract {
            path: path.clone(),
            detail: format!("{e:#}"),
        };
        let onnx = tract_onnx::onnx();
        let dir_s = dir.and_then(|d| d.to_str());
        let parsed = onnx.parse(&proto, dir_s).map_err(tract_err)?;
        if !parsed.unresolved_inputs.is_empty() {
            return Err(ModelError::Tract {
                path,
                detail: format!("unresolved inputs {:?}", parsed.unresolved_inputs),
            });
        }
        let typed = parsed
            .model
            .with_input_fact(0, f32::fact([1, l, j]).into())
            .and_then(|m| m.into_typed())
            .and_then(|m| m.into_decluttered())
            .map_err(tract_err)?;
        let out_fact = typed.output_fact(0).map_err(tract_err)?.clone();
        let out_shape = out_fact.shape.as_concrete().map(|s| s.to_vec());
        if out_fact.datum_type != f32::datum_type() || out_shape.as_deref() != Some(&[1, j][..]) {
            return Err(ModelError::Interface {
                path,
                what: format!("output `{}`", contract::OUTPUT_NAME),
                expected: format!("f32 [1, {j}]"),
                found: format!("{:?} {:?}", out_fact.datum_type, out_fact.shape),
            });
        }
        let (net, unrecognised) = match recognise(&typed, l, j, &lstms) {
            Ok(net) => (Some(Arc::new(net)), None),
            Err(why) => (None, Some(why)),
        };
        let plan = typed
            .into_optimized()
            .and_then(|m| m.into_runnable())
            .map_err(tract_err)?;
        let mut model = Model {
            path,
            meta,
            support,
            producer: format!("{} {}", proto.producer_name, proto.producer_version)
                .trim()
                .to_string(),
            plan,
            net,
            unrecognised,
            check_max_abs_diff_deg: None,
        };
        if let Some(net) = &model.net {
            model.check_structure(&net.summary())?;
            model.check_max_abs_diff_deg = Some(model.check_incremental(opts)?);
        }
        Ok(model)
    }

    /// Recognised structure must agree with the declared architecture and TCN block.
    fn check_structure(&self, s: &NetSummary) -> Result<(), ModelError> {
        let found = match (s.convs > 0, s.lstm, s.flatten_dense) {
            (true, true, _) => Some(Architecture::TcnLstm),
            (true, false, false) => Some(Architecture::Tcn),
            (false, true, _) => Some(Architecture::Lstm),
            (false, false, true) => Some(Architecture::Fnn),
            _ => None,
        };
        if let Some(found) = found {
            if found != self.meta.architecture {
                return Err(ModelError::MetadataMismatch {
                    path: self.path.clone(),
                    key: contract::keys::ARCHITECTURE,
                    declared: self.meta.architecture.to_string(),
                    found: found.to_string(),
                });
            }
        }
        if let Some(declared) = self.meta.tcn_block {
            let found = if s.residual_blocks == 0 {
                "without residual blocks".to_string()
            } else if s.blocks_relu_after_second_conv == s.residual_blocks {
                TcnBlock::ReluRelu.to_string()
            } else if s.blocks_relu_after_second_conv == 0 {
                TcnBlock::ReluLinear.to_string()
            } else {
                format!(
                    "mixed ({} of {} blocks with a ReLU after the second conv)",
                    s.blocks_relu_after_second_conv, s.residual_blocks
                )
            };
            if found != declared.as_str() {
                return Err(ModelError::MetadataMismatch {
                    path: self.path.clone(),
                    key: contract::keys::TCN_BLOCK,
                    declared: declared.to_string(),
                    found,
                });
            }
        }
        Ok(())
    }

    /// Runs the incremental evaluator and tract on seeded random windows (some with left
    /// zero padding, as at start-up) and returns the largest difference in degrees; refuses a
    /// difference beyond [`LoadOptions::tolerance_at`] the outputs' scale.
    fn check_incremental(&self, opts: &LoadOptions) -> Result<f64, ModelError> {
        let (l, j) = (self.meta.seq_len, self.meta.joints);
        let mut rng = ChaCha8Rng::seed_from_u64(opts.seed);
        let mut inc = self.incremental().expect("recognised");
        let mut out = vec![0.0; j];
        // Per window: the largest difference (NaN stays NaN) and the largest |output|.
        let mut per_window = Vec::with_capacity(opts.check_windows);
        for w in 0..opts.check_windows {
            let zeros = if w % 2 == 1 { rng.random_range(0..l) } else { 0 };
            let window: Vec<f64> = (0..l * j)
                .map(|i| {
                    if i / j < zeros {
                        0.0
                    } else {
                        rng.random_range(-60.0..60.0f32) as f64
                    }
                })
                .collect();
            let win32: Vec<f32> = window.iter().map(|&v| v as f32).collect();
            let full = self.eval_full(&win32)?;
            inc.set_history(&window[..(l - 1) * j]);
            inc.eval(&window[(l - 1) * j..], &mut out);
            let mut diff = 0.0f64;
            let mut scale = 0.0f64;
            for c in 0..j {
                let d = (out[c] - full[c] as f64).abs();
                diff = if d.is_nan() || diff.is_nan() {
                    f64::NAN
                } else {
                    diff.max(d)
                };
                scale = scale.max((full[c] as f64).abs());
            }
            per_window.push((diff, scale));
        }
        let scale_deg = per_window.iter().map(|w| w.1).fold(0.0, f64::max);
        let tolerance_deg = opts.tolerance_at(scale_deg);
        let mut worst = 0.0f64;
        for (w, &(d, _)) in per_window.iter().enumerate() {
            if d.is_nan() || d > tolerance_deg {
                return Err(ModelError::IncrementalMismatch {
                    path: self.path.clone(),
                    max_abs_diff_deg: if d.is_nan() { f64::INFINITY } else { d },
                    tolerance_deg,
                    relative: opts.relative,
                    scale_deg,
                    window: w,
                });
            }
            worst = worst.max(d);
        }
        Ok(worst)
    }

    pub fn path(&self) -> &str {
        &self.path
    }
    pub fn metadata(&self) -> &ModelMetadata {
        &self.meta
    }
    /// The support of the training data, when the file records it (`bowden train` does).
    pub fn support(&self) -> Option<&Support> {
        self.support.as_ref()
    }
    pub fn seq_len(&self) -> usize {
        self.meta.seq_len
    }
    pub fn joints(&self) -> usize {
        self.meta.joints
    }
    /// `producer_name producer_version` from the file (e.g. `pytorch 2.15.0`).
    pub fn producer(&self) -> &str {
        &self.producer
    }
    /// True when the graph was recognised and runs incrementally.
    pub fn is_incremental(&self) -> bool {
        self.net.is_some()
    }
    /// Why the graph was not recognised (it then runs through tract).
    pub fn unrecognised_reason(&self) -> Option<&str> {
        self.unrecognised.as_deref()
    }
    /// Largest |incremental − tract| found by the load check, degrees.
    pub fn load_check_max_abs_diff_deg(&self) -> Option<f64> {
        self.check_max_abs_diff_deg
    }
    /// Structure of the recognised graph.
    pub fn summary(&self) -> Option<NetSummary> {
        self.net.as_ref().map(|n| n.summary())
    }

    /// Full evaluation by tract of one window (`L·J` values, oldest first, degrees).
    /// Allocates: not for the real-time path.
    pub fn eval_full(&self, window_deg: &[f32]) -> Result<Vec<f32>, ModelError> {
        let (l, j) = (self.meta.seq_len, self.meta.joints);
        let err = |e: TractError| ModelError::Tract {
            path: self.path.clone(),
            detail: format!("{e:#}"),
        };
        let input = Tensor::from_shape(&[1, l, j], window_deg).map_err(err)?;
        let out = self.plan.run(tvec!(input.into())).map_err(err)?;
        let v = out[0].to_plain_array_view::<f32>().map_err(err)?;
        Ok(v.iter().copied().collect())
    }

    /// A fresh incremental evaluator, if the graph was recognised.
    pub fn incremental(&self) -> Option<IncrementalNet> {
        self.net.as_ref().map(|n| IncrementalNet::new(n.clone()))
    }

    /// A tract-backed evaluator (full evaluation per call; allocates).
    pub fn tract_evaluator(&self) -> TractEvaluator {
        TractEvaluator::new(self.plan.clone(), self.meta.seq_len, self.meta.joints)
    }

    /// The evaluator the compensator uses: incremental when recognised, else tract (with a
    /// warning on stderr: not real-time).
    pub fn evaluator(&self) -> Evaluator {
        match self.incremental() {
            Some(n) => Evaluator::Incremental(Box::new(n)),
            None => {
                eprintln!(
                    "warning: {}: graph not recognised as FNN/LSTM/TCN/TCN-LSTM ({}); it runs through tract's \
                     full evaluation, which allocates and is outside the real-time guarantees",
                    self.path,
                    self.unrecognised.as_deref().unwrap_or("?")
                );
                Evaluator::Tract(Box::new(self.tract_evaluator()))
            }
        }
    }
}

fn check_interface(path: &str, graph: &pb::GraphProto, meta: &ModelMetadata) -> Result<(), ModelError> {
    let iface = |what: String, expected: String, found: String| ModelError::Interface {
        path: path.to_string(),
        what,
        expected,
        found,
    };
    // Old IR versions also list initializers among the inputs.
    let inits: std::collections::HashSet<&str> = graph.initializer.iter().map(|t| t.name.as_str()).collect();
    let inputs: Vec<&pb::ValueInfoProto> = graph
        .input
        .iter()
        .filter(|i| !inits.contains(i.name.as_str()))
        .collect();
    let names = |v: &[&pb::ValueInfoProto]| v.iter().map(|i| i.name.clone()).collect::<Vec<_>>().join(", ");
    if inputs.len() != 1 || inputs[0].name != contract::INPUT_NAME {
        return Err(iface(
            "graph inputs".into(),
            format!("one input `{}`", contract::INPUT_NAME),
            format!("[{}]", names(&inputs)),
        ));
    }
    let outputs: Vec<&pb::ValueInfoProto> = graph.output.iter().collect();
    if outputs.len() != 1 || outputs[0].name != contract::OUTPUT_NAME {
        return Err(iface(
            "graph outputs".into(),
            format!("one output `{}`", contract::OUTPUT_NAME),
            format!("[{}]", names(&outputs)),
        ));
    }
    let want_in = [1, meta.seq_len as i64, meta.joints as i64];
    let want_out = [1, meta.joints as i64];
    for (vi, want) in [(inputs[0], &want_in[..]), (outputs[0], &want_out[..])] {
        let Some(pb::type_proto::Value::TensorType(tt)) = vi.r#type.as_ref().and_then(|t| t.value.as_ref()) else {
            continue; // untyped: tract infers it, the output check below catches mismatches
        };
        if tt.elem_type != FLOAT {
            return Err(iface(
                format!("element type of `{}`", vi.name),
                "float32 (1)".into(),
                format!("{}", tt.elem_type),
            ));
        }
        if let Some(shape) = &tt.shape {
            let dims: Vec<Option<i64>> = shape
                .dim
                .iter()
                .map(|d| match d.value {
                    Some(pb::tensor_shape_proto::dimension::Value::DimValue(v)) => Some(v),
                    _ => None,
                })
                .collect();
            let ok = dims.len() == want.len() && dims.iter().zip(want).all(|(d, w)| d.is_none_or(|v| v == *w));
            if !ok {
                let shown: Vec<String> = dims
                    .iter()
                    .map(|d| d.map(|v| v.to_string()).unwrap_or_else(|| "?".into()))
                    .collect();
                return Err(iface(
                    format!(
                        "shape of `{}` (metadata: seq_len = {}, joints = {})",
                        vi.name, meta.seq_len, meta.joints
                    ),
                    format!("{want:?}"),
                    format!("[{}]", shown.join(", ")),
                ));
            }
        }
    }
    Ok(())
}

/// Every float of `t`, if it is a float tensor stored in the file.
fn proto_floats(t: &pb::TensorProto) -> Option<Vec<f32>> {
    if t.data_type != FLOAT {
        return None;
    }
    if !t.raw_data.is_empty() {
        Some(
            t.raw_data
                .chunks_exact(4)
                .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
                .collect(),
        )
    } else {
        Some(t.float_data.clone())
    }
}

fn check_finite(path: &str, graph: &pb::GraphProto) -> Result<(), ModelError> {
    let constants = graph.node.iter().filter(|n| n.op_type == "Constant").flat_map(|n| {
        n.attribute
            .iter()
            .filter_map(|a| a.t.as_ref().map(|t| (n.output.first(), t)))
    });
    let inits = graph.initializer.iter().map(|t| (Some(&t.name), t));
    for (name, t) in inits.chain(constants) {
        let check = |index: usize, value: f32| {
            Err(ModelError::NonFiniteWeight {
                path: path.to_string(),
                tensor: name.cloned().unwrap_or_default(),
                index,
                value,
            })
        };
        if let Some(v) = proto_floats(t) {
            if let Some((i, &x)) = v.iter().enumerate().find(|(_, x)| !x.is_finite()) {
                return check(i, x);
            }
        } else if let Some((i, &x)) = t.double_data.iter().enumerate().find(|(_, x)| !x.is_finite()) {
            return check(i, x as f32);
        }
    }
    Ok(())
}

/// The LSTM nodes of the graph with their weights (from initializers or Constant nodes).
fn proto_lstms(graph: &pb::GraphProto) -> Vec<ProtoLstm> {
    let find = |name: &str| -> Option<(Vec<i64>, Vec<f32>)> {
        if name.is_empty() {
            return None;
        }
        if let Some(t) = graph.initializer.iter().find(|t| t.name == name) {
            return proto_floats(t).map(|v| (t.dims.clone(), v));
        }
        graph
            .node
            .iter()
            .filter(|n| n.op_type == "Constant" && n.output.first().map(|s| s.as_str()) == Some(name))
            .find_map(|n| n.attribute.iter().find_map(|a| a.t.as_ref()))
            .and_then(|t| proto_floats(t).map(|v| (t.dims.clone(), v)))
    };
    let mut out = Vec::new();
    for n in graph.node.iter().filter(|n| n.op_type == "LSTM") {
        let attr = |k: &str| n.attribute.iter().find(|a| a.name == k);
        let hidden = attr("hidden_size").map(|a| a.i as usize).unwrap_or(0);
        let input_at = |i: usize| n.input.get(i).map(|s| s.as_str()).unwrap_or("");
        let mut why: Option<String> = None;
        let mut note = |s: String| {
            why.get_or_insert(s);
        };
        if attr("direction").is_some_and(|a| a.s != b"forward") {
            note("bidirectional or reverse LSTM".into());
        }
        if attr("clip").is_some() {
            note("LSTM with clipping".into());
        }
        if attr("input_forget").is_some_and(|a| a.i != 0) {
            note("LSTM with coupled input-forget gate".into());
        }
        if attr("layout").is_some_and(|a| a.i != 0) {
            note("LSTM with batch-first layout".into());
        }
        if let Some(a) = attr("activations") {
            let acts: Vec<String> = a
                .strings
                .iter()
                .map(|s| String::from_utf8_lossy(s).to_lowercase())
                .collect();
            if acts != ["sigmoid", "tanh", "tanh"] {
                note(format!("LSTM activations {acts:?}"));
            }
        }
        if !input_at(4).is_empty() {
            note("LSTM with sequence_lens".into());
        }
        if !input_at(7).is_empty() {
            note("LSTM with peepholes".into());
        }
        let w = find(input_at(1));
        let r = find(input_at(2));
        let b = find(input_at(3));
        let (mut input, mut wv, mut rv, mut bv) = (0, Vec::new(), Vec::new(), vec![0.0; 8 * hidden]);
        match (w, r) {
            (Some((wd, w)), Some((rd, r)))
                if hidden > 0
                    && wd.len() == 3
                    && wd[0] == 1
                    && wd[1] == 4 * hidden as i64
                    && rd == [1, 4 * hidden as i64, hidden as i64] =>
            {
                input = wd[2] as usize;
                wv = w;
                rv = r;
            }
            _ => note("LSTM weights not found as constants".into()),
        }
        if let Some((bd, b)) = b {
            if bd == [1, 8 * hidden as i64] {
                bv = b;
            } else {
                note(format!("LSTM bias of shape {bd:?}"));
            }
        }
        // Y_c (output 2) is read by a node or is a graph output.
        let final_cell_used = n.output.get(2).is_some_and(|y_c| {
            !y_c.is_empty()
                && (graph.node.iter().any(|m| m.input.iter().any(|i| i == y_c))
                    || graph.output.iter().any(|o| &o.name == y_c))
        });
        out.push(ProtoLstm {
            name: n.name.clone(),
            final_cell_used,
            input,
            hidden,
            w: wv,
            r: rv,
            b: bv,
            unsupported: why,
        });
    }
    out
}

/// The two ways a window model is evaluated.
pub enum Evaluator {
    /// Exact incremental evaluation (real-time, allocation-free).
    Incremental(Box<IncrementalNet>),
    /// tract's full evaluation per call (allocates; fallback and the naive baseline).
    Tract(Box<TractEvaluator>),
}

impl Evaluator {
    pub fn is_incremental(&self) -> bool {
        matches!(self, Evaluator::Incremental(_))
    }
}

impl WindowModel for Evaluator {
    fn joints(&self) -> usize {
        match self {
            Evaluator::Incremental(n) => n.joints(),
            Evaluator::Tract(t) => t.joints(),
        }
    }
    fn seq_len(&self) -> usize {
        match self {
            Evaluator::Incremental(n) => n.seq_len(),
            Evaluator::Tract(t) => t.seq_len(),
        }
    }
    fn set_history(&mut self, history_deg: &[f64]) {
        match self {
            Evaluator::Incremental(n) => n.set_history(history_deg),
            Evaluator::Tract(t) => t.set_history(history_deg),
        }
    }
    fn shift_history(&mut self, history_deg: &[f64]) {
        match self {
            Evaluator::Incremental(n) => n.shift_history(history_deg),
            Evaluator::Tract(t) => t.set_history(history_deg),
        }
    }
    fn eval(&mut self, last_deg: &[f64], out_deg: &mut [f64]) {
        match self {
            Evaluator::Incremental(n) => n.eval(last_deg, out_deg),
            Evaluator::Tract(t) => t.eval(last_deg, out_deg),
        }
    }
    fn eval_jacobian(&mut self, last_deg: &[f64], out_deg: &mut [f64], jac: &mut [f64]) {
        match self {
            Evaluator::Incremental(n) => n.eval_jacobian(last_deg, out_deg, jac),
            Evaluator::Tract(t) => t.eval_jacobian(last_deg, out_deg, jac),
        }
    }
}

impl WindowModel for IncrementalNet {
    fn joints(&self) -> usize {
        IncrementalNet::joints(self)
    }
    fn seq_len(&self) -> usize {
        IncrementalNet::seq_len(self)
    }
    fn set_history(&mut self, history_deg: &[f64]) {
        IncrementalNet::set_history(self, history_deg)
    }
    fn shift_history(&mut self, history_deg: &[f64]) {
        IncrementalNet::shift_history(self, history_deg)
    }
    fn eval(&mut self, last_deg: &[f64], out_deg: &mut [f64]) {
        IncrementalNet::eval(self, last_deg, out_deg)
    }
    fn eval_jacobian(&mut self, last_deg: &[f64], out_deg: &mut [f64], jac: &mut [f64]) {
        IncrementalNet::eval_jacobian(self, last_deg, out_deg, jac)
    }
}

/// Full tract evaluation of the window for every call.
pub struct TractEvaluator {
    state: TypedSimpleState,
    l: usize,
    j: usize,
    window: Vec<f32>,
}

impl TractEvaluator {
    fn new(plan: Arc<TypedSimplePlan>, l: usize, j: usize) -> Self {
        Self {
            state: TypedSimpleState::new(&plan).expect("a plan tract built has a state"),
            l,
            j,
            window: vec![0.0; l * j],
        }
    }
    pub fn joints(&self) -> usize {
        self.j
    }
    pub fn seq_len(&self) -> usize {
        self.l
    }
    pub fn set_history(&mut self, history_deg: &[f64]) {
        for (w, h) in self.window.iter_mut().zip(history_deg) {
            *w = *h as f32;
        }
    }
    /// NaN outputs if tract fails (the refinement treats them as a failed trial).
    pub fn eval(&mut self, last_deg: &[f64], out_deg: &mut [f64]) {
        let (l, j) = (self.l, self.j);
        for c in 0..j {
            self.window[(l - 1) * j + c] = last_deg[c] as f32;
        }
        let res = Tensor::from_shape(&[1, l, j], &self.window)
            .and_then(|t| self.state.run(tvec!(t.into())))
            .and_then(|o| Ok(o[0].to_plain_array_view::<f32>()?.iter().copied().collect::<Vec<f32>>()));
        match res {
            Ok(v) => out_deg.iter_mut().zip(v).for_each(|(o, y)| *o = y as f64),
            Err(_) => out_deg.iter_mut().for_each(|o| *o = f64::NAN),
        }
    }
    /// Central finite differences (2·J + 1 evaluations), step 0.01 deg.
    pub fn eval_jacobian(&mut self, last_deg: &[f64], out_deg: &mut [f64], jac: &mut [f64]) {
        let j = self.j;
        let h = 1e-2;
        let mut q = last_deg.to_vec();
        let (mut yp, mut ym) = (vec![0.0; j], vec![0.0; j]);
        for c in 0..j {
            q[c] = last_deg[c] + h;
            self.eval(&q, &mut yp);
            q[c] = last_deg[c] - h;
            self.eval(&q, &mut ym);
            q[c] = last_deg[c];
            for r in 0..j {
                jac[r * j + c] = (yp[r] - ym[r]) / (2.0 * h);
            }
        }
        self.eval(last_deg, out_deg);
    }
}
