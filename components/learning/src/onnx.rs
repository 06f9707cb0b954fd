//! ONNX export (and import) of trained models, following the contract of docs/architecture.md §5 and
//! of the PyTorch fixtures: input `q_seq_deg` f32 `[1, L, J]` (degrees, oldest first),
//! output `q_deg` f32 `[1, J]` (degrees), normalisation inside the graph (`Sub mu_in`,
//! `Div sd_in` first, `Mul sd_out`, `Add mu_out` last), metadata props `direction`,
//! `seq_len`, `joints`, `architecture`, `units` (and `tcn_block` for TCN models).
//!
//! The graph mirrors what `torch.onnx.export` (opset 17) writes for the same modules:
//! TCN = Transpose → per conv an explicit constant `Pad` (2d zeros on the left) and a
//! `Conv` with `dilations = [d]`, `pads = [0, 0]` → Relu / Add → `Gather(axis 2, −1)`;
//! LSTM = Transpose to `[L, 1, J]` → `LSTM` (gates reordered from PyTorch's i, f, g, o to
//! ONNX's i, o, f, c) → last step → `Gemm`s; FNN = `Flatten` → `Gemm`s.

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use prost::Message;
use tract_onnx::pb;
use tract_onnx::pb::{tensor_shape_proto, type_proto};

use bowden_interfaces::model::{keys, parse_prop, ContractError, ModelMetadata, UNITS_DEG};

use crate::arch::{tcn_dilation, Architecture, Direction, ModelSpec, TcnBlock, FNN_HIDDEN, HEAD_HIDDEN, LSTM_HIDDEN};
use crate::support::DataSupport;
use crate::windows::Normaliser;

pub use bowden_interfaces::model::{INPUT_NAME, OUTPUT_NAME};
pub const OPSET: i64 = 17;
pub const IR_VERSION: i64 = 8;

const FLOAT: i32 = 1;
const INT64: i32 = 7;

/// What can go wrong writing, reading or running an ONNX model. Each names the file.
#[derive(Debug, thiserror::Error)]
pub enum OnnxError {
    #[error("{path}: cannot read or write: {source}")]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("{path}: not a valid ONNX protobuf: {source}")]
    Decode {
        path: PathBuf,
        #[source]
        source: prost::DecodeError,
    },
    #[error("{path}: {what}")]
    Contract { path: PathBuf, what: String },
    #[error("{path}: tract: {what}")]
    Tract { path: PathBuf, what: String },
}

/// A trained model: structure, parameters and the normalisations around it.
#[derive(Debug, Clone, PartialEq)]
pub struct ModelFile {
    pub spec: ModelSpec,
    pub direction: Direction,
    pub params: Vec<f32>,
    pub norm_in: Normaliser,
    pub norm_out: Normaliser,
    /// Where the training data lay (`train` records it; a file from elsewhere may lack it).
    pub support: Option<DataSupport>,
}

struct GraphBuilder {
    nodes: Vec<pb::NodeProto>,
    inits: Vec<pb::TensorProto>,
    counter: usize,
}

fn attr_int(name: &str, v: i64) -> pb::AttributeProto {
    pb::AttributeProto {
        name: name.into(),
        r#type: pb::attribute_proto::AttributeType::Int as i32,
        i: v,
        ..Default::default()
    }
}

fn attr_ints(name: &str, v: &[i64]) -> pb::AttributeProto {
    pb::AttributeProto {
        name: name.into(),
        r#type: pb::attribute_proto::AttributeType::Ints as i32,
        ints: v.to_vec(),
        ..Default::default()
    }
}

fn attr_string(name: &str, v: &str) -> pb::AttributeProto {
    pb::AttributeProto {
        name: name.into(),
        r#type: pb::attribute_proto::AttributeType::String as i32,
        s: v.as_bytes().to_vec(),
        ..Default::default()
    }
}

fn value_info(name: &str, dims: &[i64]) -> pb::ValueInfoProto {
    pb::ValueInfoProto {
        name: name.into(),
        r#type: Some(pb::TypeProto {
            value: Some(type_proto::Value::TensorType(type_proto::Tensor {
                elem_type: FLOAT,
                shape: Some(pb::TensorShapeProto {
                    dim: dims
                        .iter()
                        .map(|&d| tensor_shape_proto::Dimension {
                            value: Some(tensor_shape_proto::dimension::Value::DimValue(d)),
                            ..Default::default()
                        })
                        .collect(),
                }),
            })),
            ..Default::default()
        }),
        ..Default::default()
    }
}

impl GraphBuilder {
    fn init_f32(&mut self, name: &str, dims: &[usize], data: &[f32]) -> String {
        let mut raw = Vec::with_capacity(data.len() * 4);
        for v in data {
            raw.extend_from_slice(&v.to_le_bytes());
        }
        self.inits.push(pb::TensorProto {
            name: name.into(),
            dims: dims.iter().map(|&d| d as i64).collect(),
            data_type: FLOAT,
            raw_data: raw,
            ..Default::default()
        });
        name.into()
    }

    fn init_i64(&mut self, name: &str, dims: &[usize], data: &[i64]) -> String {
        let mut raw = Vec::with_capacity(data.len() * 8);
        for v in data {
            raw.extend_from_slice(&v.to_le_bytes());
        }
        self.inits.push(pb::TensorProto {
            name: name.into(),
            dims: dims.iter().map(|&d| d as i64).collect(),
            data_type: INT64,
            raw_data: raw,
            ..Default::default()
        });
        name.into()
    }

    /// Adds a node with one output named after its op; returns the output name.
    fn node(&mut self, op: &str, scope: &str, inputs: &[&str], attrs: Vec<pb::AttributeProto>) -> String {
        self.counter += 1;
        let out = format!("/{scope}/{op}_{}", self.counter);
        self.node_named(op, scope, inputs, attrs, vec![out.clone()]);
        out
    }

    fn node_named(
        &mut self,
        op: &str,
        scope: &str,
        inputs: &[&str],
        attrs: Vec<pb::AttributeProto>,
        outputs: Vec<String>,
    ) {
        self.nodes.push(pb::NodeProto {
            input: inputs.iter().map(|s| s.to_string()).collect(),
            output: outputs,
            name: format!("/{scope}/{op}_{}", self.counter),
            op_type: op.into(),
            attribute: attrs,
            ..Default::default()
        });
    }
}

fn f32s(norm: &[f64]) -> Vec<f32> {
    norm.iter().map(|&v| v as f32).collect()
}

/// PyTorch LSTM gate blocks (i, f, g, o) → ONNX (i, o, f, c).
fn ifgo_to_iofc(src: &[f32], h: usize, cols: usize) -> Vec<f32> {
    let block = h * cols;
    let mut out = Vec::with_capacity(src.len());
    for g in [0, 3, 1, 2] {
        out.extend_from_slice(&src[g * block..(g + 1) * block]);
    }
    out
}

/// ONNX (i, o, f, c) → PyTorch (i, f, g, o).
fn iofc_to_ifgo(src: &[f32], h: usize, cols: usize) -> Vec<f32> {
    let block = h * cols;
    let mut out = Vec::with_capacity(src.len());
    for g in [0, 2, 3, 1] {
        out.extend_from_slice(&src[g * block..(g + 1) * block]);
    }
    out
}

impl ModelFile {
    fn tensor(&self, name: &str) -> &[f32] {
        &self.params[self.spec.layout().range(name)]
    }

    /// The ONNX model.
    // Long: the ONNX graph written node by node in the order PyTorch exports it, so the two files can be compared side by side.
    pub fn to_proto(&self) -> pb::ModelProto {
        let spec = self.spec;
        let (l, j) = (spec.seq_len, spec.joints);
        let h = LSTM_HIDDEN;
        let mut g = GraphBuilder {
            nodes: Vec::new(),
            inits: Vec::new(),
            counter: 0,
        };
        let mu_in = g.init_f32("mu_in", &[j], &f32s(&self.norm_in.mean));
        let sd_in = g.init_f32("sd_in", &[j], &f32s(&self.norm_in.sd));
        let mu_out = g.init_f32("mu_out", &[j], &f32s(&self.norm_out.mean));
        let sd_out = g.init_f32("sd_out", &[j], &f32s(&self.norm_out.sd));
        let centred = g.node("Sub", "norm", &[INPUT_NAME, &mu_in], vec![]);
        let xn = g.node("Div", "norm", &[&centred, &sd_in], vec![]);

        let mut feat = xn.clone(); // [1, L, J] for the LSTM / FNN
        let mut tcn_out = None; // [1, J, L]
        if spec.arch.has_tcn() {
            let mut z = g.node("Transpose", "tcn", &[&xn], vec![attr_ints("perm", &[0, 2, 1])]);
            for k in 0..spec.tcn_blocks() {
                let d = tcn_dilation(k);
                let scope = format!("tcn/blocks.{k}");
                let pads = g.init_i64(&format!("tcn.blocks.{k}.pads"), &[6], &[0, 0, 2 * d as i64, 0, 0, 0]);
                let conv = |g: &mut GraphBuilder, input: &str, c: &str| -> String {
                    let wname = format!("tcn.blocks.{k}.{c}.weight");
                    let bname = format!("tcn.blocks.{k}.{c}.bias");
                    let w = g.init_f32(&wname, &[j, j, 3], self.tensor(&wname));
                    let b = g.init_f32(&bname, &[j], self.tensor(&bname));
                    let padded = g.node("Pad", &scope, &[input, &pads], vec![attr_string("mode", "constant")]);
                    g.node(
                        "Conv",
                        &format!("{scope}/{c}"),
                        &[&padded, &w, &b],
                        vec![
                            attr_ints("dilations", &[d as i64]),
                            attr_int("group", 1),
                            attr_ints("kernel_shape", &[3]),
                            attr_ints("pads", &[0, 0]),
                            attr_ints("strides", &[1]),
                        ],
                    )
                };
                let a1 = conv(&mut g, &z, "c1");
                let h1 = g.node("Relu", &scope, &[&a1], vec![]);
                let mut h2 = conv(&mut g, &h1, "c2");
                if spec.tcn_block == TcnBlock::ReluRelu {
                    h2 = g.node("Relu", &scope, &[&h2], vec![]);
                }
                z = g.node("Add", &scope, &[&z, &h2], vec![]);
            }
            tcn_out = Some(z);
        }
        let core_out = match spec.arch {
            Architecture::Tcn => {
                let last = g.init_i64("tcn.last_step", &[], &[-1]);
                let Some(z) = tcn_out else { unreachable!() };
                g.node("Gather", "tcn", &[&z, &last], vec![attr_int("axis", 2)])
            }
            Architecture::Lstm | Architecture::TcnLstm => {
                let seq = match &tcn_out {
                    // [1, J, L] → [L, 1, J]
                    Some(z) => g.node("Transpose", "lstm", &[z], vec![attr_ints("perm", &[2, 0, 1])]),
                    // [1, L, J] → [L, 1, J]
                    None => g.node("Transpose", "lstm", &[&feat], vec![attr_ints("perm", &[1, 0, 2])]),
                };
                let w = ifgo_to_iofc(self.tensor("lstm.weight_ih_l0"), h, j);
                let r = ifgo_to_iofc(self.tensor("lstm.weight_hh_l0"), h, h);
                let mut bias = ifgo_to_iofc(self.tensor("lstm.bias_ih_l0"), h, 1);
                bias.extend(ifgo_to_iofc(self.tensor("lstm.bias_hh_l0"), h, 1));
                let w = g.init_f32("lstm.W", &[1, 4 * h, j], &w);
                let r = g.init_f32("lstm.R", &[1, 4 * h, h], &r);
                let b = g.init_f32("lstm.B", &[1, 8 * h], &bias);
                g.counter += 1;
                let outs = vec![
                    format!("/lstm/LSTM_Y_{}", g.counter),
                    format!("/lstm/LSTM_Y_h_{}", g.counter),
                    format!("/lstm/LSTM_Y_c_{}", g.counter),
                ];
                g.node_named(
                    "LSTM",
                    "lstm",
                    &[&seq, &w, &r, &b],
                    vec![attr_int("hidden_size", h as i64)],
                    outs.clone(),
                );
                // Y_h [1 (direction), 1 (batch), H] → [1, H]
                let axes = g.init_i64("lstm.squeeze_axes", &[1], &[0]);
                let h_last = g.node("Squeeze", "lstm", &[&outs[1], &axes], vec![]);
                let mut x = h_last;
                for (i, (name, n_out)) in [("fc.0", HEAD_HIDDEN), ("fc.2", j)].iter().enumerate() {
                    x = gemm(&mut g, self, &x, name, *n_out);
                    if i == 0 {
                        x = g.node("Relu", "fc", &[&x], vec![]);
                    }
                }
                x
            }
            Architecture::Fnn => {
                feat = g.node("Flatten", "fnn", &[&feat], vec![attr_int("axis", 1)]);
                let mut x = feat.clone();
                let layers = [("net.1", FNN_HIDDEN), ("net.3", FNN_HIDDEN), ("net.5", j)];
                for (i, (name, n_out)) in layers.iter().enumerate() {
                    x = gemm(&mut g, self, &x, name, *n_out);
                    if i + 1 < layers.len() {
                        x = g.node("Relu", "fnn", &[&x], vec![]);
                    }
                }
                x
            }
        };
        let scaled = g.node("Mul", "denorm", &[&core_out, &sd_out], vec![]);
        g.node_named(
            "Add",
            "denorm",
            &[&scaled, &mu_out],
            vec![],
            vec![OUTPUT_NAME.to_string()],
        );

        let contract = ModelMetadata {
            direction: self.direction,
            seq_len: l,
            joints: j,
            architecture: spec.arch,
            tcn_block: spec.arch.has_tcn().then_some(spec.tcn_block),
        };
        let mut meta: Vec<(String, String)> = contract.to_props();
        if let Some(sup) = &self.support {
            for (k, v) in sup.to_props() {
                meta.push((k.to_string(), v));
            }
        }
        meta.push((
            "producer_note".to_string(),
            format!(
                "bowden-learning {} (fused-kernel training, Rust)",
                env!("CARGO_PKG_VERSION")
            ),
        ));
        pb::ModelProto {
            ir_version: IR_VERSION,
            opset_import: vec![pb::OperatorSetIdProto {
                domain: String::new(),
                version: OPSET,
            }],
            producer_name: "bowden-learning".into(),
            producer_version: env!("CARGO_PKG_VERSION").into(),
            graph: Some(pb::GraphProto {
                node: g.nodes,
                name: format!("{}_{}_L{}_J{}", spec.arch, self.direction, l, j),
                initializer: g.inits,
                input: vec![value_info(INPUT_NAME, &[1, l as i64, j as i64])],
                output: vec![value_info(OUTPUT_NAME, &[1, j as i64])],
                ..Default::default()
            }),
            metadata_props: meta
                .into_iter()
                .map(|(k, v)| pb::StringStringEntryProto { key: k, value: v })
                .collect(),
            ..Default::default()
        }
    }

    /// Writes the `.onnx` file.
    pub fn save(&self, path: &Path) -> Result<(), OnnxError> {
        let bytes = self.to_proto().encode_to_vec();
        if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
            std::fs::create_dir_all(dir).map_err(|source| OnnxError::Io {
                path: dir.to_path_buf(),
                source,
            })?;
        }
        std::fs::write(path, bytes).map_err(|source| OnnxError::Io {
            path: path.to_path_buf(),
            source,
        })
    }

    /// Reads a model written by [`ModelFile::save`] or exported by PyTorch with the same
    /// contract (the fixtures): structure from the metadata, weights from the graph (conv
    /// and gemm weights in graph order, the LSTM node's W, R, B).
    pub fn load(path: &Path) -> Result<Self, OnnxError> {
        let bytes = std::fs::read(path).map_err(|source| OnnxError::Io {
            path: path.to_path_buf(),
            source,
        })?;
        let proto = pb::ModelProto::decode(bytes.as_slice()).map_err(|source| OnnxError::Decode {
            path: path.to_path_buf(),
            source,
        })?;
        Self::from_proto(&proto, path)
    }

    // Long: the ONNX graph read node by node, mirroring `to_proto`.
    pub fn from_proto(proto: &pb::ModelProto, path: &Path) -> Result<Self, OnnxError> {
        let bad = |what: String| OnnxError::Contract {
            path: path.to_path_buf(),
            what,
        };
        let meta: HashMap<&str, &str> = proto
            .metadata_props
            .iter()
            .map(|p| (p.key.as_str(), p.value.as_str()))
            .collect();
        let get = |k: &str| {
            meta.get(k)
                .copied()
                .ok_or_else(|| bad(format!("metadata prop {k:?} is missing")))
        };
        let enumerated = |e: ContractError| bad(e.to_string());
        let arch: Architecture = parse_prop(keys::ARCHITECTURE, get(keys::ARCHITECTURE)?).map_err(enumerated)?;
        let direction: Direction = parse_prop(keys::DIRECTION, get(keys::DIRECTION)?).map_err(enumerated)?;
        let seq_len: usize = get(keys::SEQ_LEN)?
            .parse()
            .map_err(|_| bad(format!("seq_len {:?} is not an integer", meta.get(keys::SEQ_LEN))))?;
        let joints: usize = get(keys::JOINTS)?
            .parse()
            .map_err(|_| bad(format!("joints {:?} is not an integer", meta.get(keys::JOINTS))))?;
        if get(keys::UNITS)? != UNITS_DEG {
            return Err(bad(format!("units {:?} is not deg", meta.get(keys::UNITS))));
        }
        let tcn_block = match meta.get(keys::TCN_BLOCK) {
            Some(v) => parse_prop(keys::TCN_BLOCK, v).map_err(enumerated)?,
            None if arch.has_tcn() => TcnBlock::ReluRelu, // the paper's reading
            None => TcnBlock::default(),
        };
        let spec = ModelSpec::new(arch, seq_len, joints, tcn_block);
        let support = DataSupport::from_props(|k| meta.get(k).copied(), joints).map_err(|e| bad(e.to_string()))?;
        let graph = proto.graph.as_ref().ok_or_else(|| bad("no graph".into()))?;
        let inits: HashMap<&str, &pb::TensorProto> = graph.initializer.iter().map(|t| (t.name.as_str(), t)).collect();
        let tensor = |name: &str, want: usize| -> Result<Vec<f32>, OnnxError> {
            let t = inits
                .get(name)
                .ok_or_else(|| bad(format!("initializer {name:?} is missing")))?;
            let v = float_data(t).ok_or_else(|| bad(format!("initializer {name:?} is not float32")))?;
            if v.len() != want {
                return Err(bad(format!(
                    "initializer {name:?} has {} values, expected {want}",
                    v.len()
                )));
            }
            Ok(v)
        };
        let norm = |m: &str, s: &str| -> Result<Normaliser, OnnxError> {
            Ok(Normaliser {
                mean: tensor(m, joints)?.iter().map(|&v| v as f64).collect(),
                sd: tensor(s, joints)?.iter().map(|&v| v as f64).collect(),
            })
        };
        let norm_in = norm("mu_in", "sd_in")?;
        let norm_out = norm("mu_out", "sd_out")?;

        let layout = spec.layout();
        let mut params = vec![0.0f32; layout.total];
        let mut put = |name: &str, data: &[f32]| -> Result<(), OnnxError> {
            let r = layout.range(name);
            if r.len() != data.len() {
                return Err(bad(format!("{name}: {} values, expected {}", data.len(), r.len())));
            }
            params[r].copy_from_slice(data);
            Ok(())
        };
        let convs: Vec<&pb::NodeProto> = graph.node.iter().filter(|n| n.op_type == "Conv").collect();
        let gemms: Vec<&pb::NodeProto> = graph.node.iter().filter(|n| n.op_type == "Gemm").collect();
        let lstms: Vec<&pb::NodeProto> = graph.node.iter().filter(|n| n.op_type == "LSTM").collect();
        let input = |n: &pb::NodeProto, i: usize| -> Result<String, OnnxError> {
            n.input
                .get(i)
                .cloned()
                .ok_or_else(|| bad(format!("node {} has no input {i}", n.name)))
        };
        let blocks = spec.tcn_blocks();
        if convs.len() != 2 * blocks {
            return Err(bad(format!(
                "{} Conv nodes; a {} at L = {seq_len} has {} blocks of 2",
                convs.len(),
                arch,
                blocks
            )));
        }
        for (i, n) in convs.iter().enumerate() {
            let (k, c) = (i / 2, if i % 2 == 0 { "c1" } else { "c2" });
            put(
                &format!("tcn.blocks.{k}.{c}.weight"),
                &tensor(&input(n, 1)?, joints * joints * 3)?,
            )?;
            put(&format!("tcn.blocks.{k}.{c}.bias"), &tensor(&input(n, 2)?, joints)?)?;
        }
        let dense: Vec<(&str, usize, usize)> = match arch {
            Architecture::Lstm | Architecture::TcnLstm => {
                vec![("fc.0", LSTM_HIDDEN, HEAD_HIDDEN), ("fc.2", HEAD_HIDDEN, joints)]
            }
            Architecture::Fnn => vec![
                ("net.1", joints * seq_len, FNN_HIDDEN),
                ("net.3", FNN_HIDDEN, FNN_HIDDEN),
                ("net.5", FNN_HIDDEN, joints),
            ],
            Architecture::Tcn => vec![],
        };
        if gemms.len() != dense.len() {
            return Err(bad(format!("{} Gemm nodes, a {arch} has {}", gemms.len(), dense.len())));
        }
        for (n, (name, n_in, n_out)) in gemms.iter().zip(&dense) {
            let trans_b = n.attribute.iter().any(|a| a.name == "transB" && a.i == 1);
            if !trans_b {
                return Err(bad(format!("Gemm {} without transB = 1 is not a Linear layer", n.name)));
            }
            put(&format!("{name}.weight"), &tensor(&input(n, 1)?, n_in * n_out)?)?;
            put(&format!("{name}.bias"), &tensor(&input(n, 2)?, *n_out)?)?;
        }
        if arch.has_lstm() {
            let [n] = lstms.as_slice() else {
                return Err(bad(format!("{} LSTM nodes, expected 1", lstms.len())));
            };
            let h = LSTM_HIDDEN;
            let w = tensor(&input(n, 1)?, 4 * h * joints)?;
            let r = tensor(&input(n, 2)?, 4 * h * h)?;
            let b = tensor(&input(n, 3)?, 8 * h)?;
            put("lstm.weight_ih_l0", &iofc_to_ifgo(&w, h, joints))?;
            put("lstm.weight_hh_l0", &iofc_to_ifgo(&r, h, h))?;
            put("lstm.bias_ih_l0", &iofc_to_ifgo(&b[..4 * h], h, 1))?;
            put("lstm.bias_hh_l0", &iofc_to_ifgo(&b[4 * h..], h, 1))?;
        }
        Ok(Self {
            spec,
            direction,
            params,
            norm_in,
            norm_out,
            support,
        })
    }
}

fn gemm(g: &mut GraphBuilder, m: &ModelFile, x: &str, name: &str, n_out: usize) -> String {
    let wname = format!("{name}.weight");
    let bname = format!("{name}.bias");
    let wdata = m.tensor(&wname);
    let n_in = wdata.len() / n_out;
    let w = g.init_f32(&wname, &[n_out, n_in], wdata);
    let b = g.init_f32(&bname, &[n_out], m.tensor(&bname));
    g.node(
        "Gemm",
        name,
        &[x, &w, &b],
        vec![
            pb::AttributeProto {
                name: "alpha".into(),
                r#type: pb::attribute_proto::AttributeType::Float as i32,
                f: 1.0,
                ..Default::default()
            },
            pb::AttributeProto {
                name: "beta".into(),
                r#type: pb::attribute_proto::AttributeType::Float as i32,
                f: 1.0,
                ..Default::default()
            },
            attr_int("transB", 1),
        ],
    )
}

fn float_data(t: &pb::TensorProto) -> Option<Vec<f32>> {
    if t.data_type != FLOAT {
        return None;
    }
    if !t.raw_data.is_empty() {
        if !t.raw_data.len().is_multiple_of(4) {
            return None;
        }
        return Some(
            t.raw_data
                .chunks_exact(4)
                .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
                .collect(),
        );
    }
    Some(t.float_data.clone())
}

/// The metadata props of an ONNX file (tests and tools inspecting the contract).
pub fn read_metadata(path: &Path) -> Result<Vec<(String, String)>, OnnxError> {
    let bytes = std::fs::read(path).map_err(|source| OnnxError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    let proto = pb::ModelProto::decode(bytes.as_slice()).map_err(|source| OnnxError::Decode {
        path: path.to_path_buf(),
        source,
    })?;
    Ok(proto
        .metadata_props
        .iter()
        .map(|p| (p.key.clone(), p.value.clone()))
        .collect())
}

/// A model loaded and optimised by tract, as a consumer of the file would.
pub struct TractModel {
    plan: std::sync::Arc<tract_onnx::prelude::TypedRunnableModel>,
    pub seq_len: usize,
    pub joints: usize,
    path: PathBuf,
}

impl TractModel {
    pub fn load(path: &Path, seq_len: usize, joints: usize) -> Result<Self, OnnxError> {
        use tract_onnx::prelude::*;
        let err = |e: TractError| OnnxError::Tract {
            path: path.to_path_buf(),
            what: format!("{e:#}"),
        };
        let plan = tract_onnx::onnx()
            .model_for_path(path)
            .map_err(err)?
            .into_optimized()
            .map_err(err)?
            .into_runnable()
            .map_err(err)?;
        Ok(Self {
            plan,
            seq_len,
            joints,
            path: path.to_path_buf(),
        })
    }

    /// Runs one window (`L × J` degrees, oldest first) and returns the `J` outputs.
    pub fn run(&self, window_deg: &[f32]) -> Result<Vec<f32>, OnnxError> {
        use tract_onnx::prelude::*;
        let err = |e: TractError| OnnxError::Tract {
            path: self.path.clone(),
            what: format!("{e:#}"),
        };
        let input = tract_ndarray::Array3::from_shape_vec((1, self.seq_len, self.joints), window_deg.to_vec())
            .map_err(|e| OnnxError::Tract {
                path: self.path.clone(),
                what: format!("input shape: {e}"),
            })?;
        let out = self.plan.run(tvec!(Tensor::from(input).into())).map_err(err)?;
        let view = out[0].to_plain_array_view::<f32>().map_err(err)?;
        Ok(view.iter().copied().collect())
    }
}

impl ModelFile {
    /// Runs the model with the fused kernels on `b` windows in degrees (`[b][L][J]`) and
    /// returns `[b][J]` degrees: what the exported graph computes.
    pub fn predict_deg(&self, windows_deg: &[f32], b: usize) -> Vec<f32> {
        let (l, j) = (self.spec.seq_len, self.spec.joints);
        let net = crate::kernels::Net::new(self.spec);
        let prep = net.prepared(&self.params);
        let mut ws = net.workspace(b.max(1));
        let mut x = vec![0.0f32; b * l * j];
        for (i, v) in windows_deg[..b * l * j].iter().enumerate() {
            x[i] = self.norm_in.apply(i % j, *v as f64);
        }
        let mut out = vec![0.0f32; b * j];
        net.forward(&self.params, &prep, &x, b, &mut ws, &mut out);
        out.iter()
            .enumerate()
            .map(|(i, &v)| self.norm_out.invert(i % j, v) as f32)
            .collect()
    }
}
