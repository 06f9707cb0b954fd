//! Recording: every sample of chosen services to a log of fixed-layout records, with an index
//! file beside it, and the reader `bowden replay` uses.
//!
//! Data file (`run.blog`), little-endian:
//! ```text
//! file header   16 B   magic "BOWDNLOG", version u32 = 1, service count u32
//! service table 136 B each: name [u8; 64] (NUL-padded), type name [u8; 64], kind u32
//!               (0 = fixed-size sample, 1 = RGBD frame), sample size u32 (frames: header size)
//! records       16 B header: magic u32 "BREC", service u16, kind u16, payload length u32,
//!               FNV-1a-32 of the payload u32; then the payload (the sample's exact shared-memory
//!               bytes; frames: RgbdFrameHeader then the frame bytes), zero-padded to 8 bytes
//! ```
//! Index file (`run.blog.idx`): header 24 B (magic "BOWDNIDX", version u32, service count u32,
//! record count u64, written when the log is closed) then 40 B per record: data offset u64,
//! service u16, kind u16, payload length u32, seq u64, tick u64, t_origin_ns u64.
//!
//! In lockstep the recorder handles tick k after every producer of its services is done with k
//! and writes that tick's samples service by service in its configured order (one producer per
//! service, so FIFO order is the producer's order): the bytes depend only on the run's inputs.
//! A log without a valid index (the recorder was killed) is still readable: the reader scans it.

use crate::node::{service_list, NodeKind, ParamPorts, ParamPortsError, Read as ReadPolicy, Schedule};
use crate::ports::{visit_payload, FrameInput, Input, Message, PayloadVisitor};
use crate::stage::{Stage, StageBuildError, StageCounters, StageEnv, StageError, StepCx, StepReport};
use bowden_interfaces::{services, RgbdFrameHeader};
use std::fs::File;
use std::io::{BufWriter, Read, Seek, SeekFrom, Write};
use std::path::{Path, PathBuf};

pub const LOG_MAGIC: &[u8; 8] = b"BOWDNLOG";
pub const INDEX_MAGIC: &[u8; 8] = b"BOWDNIDX";
pub const LOG_VERSION: u32 = 1;
pub const RECORD_MAGIC: u32 = u32::from_le_bytes(*b"BREC");
pub const FILE_HEADER_LEN: u64 = 16;
pub const SERVICE_ENTRY_LEN: u64 = 136;
pub const RECORD_HEADER_LEN: u64 = 16;
pub const INDEX_HEADER_LEN: u64 = 24;
pub const INDEX_ENTRY_LEN: u64 = 40;
/// Kind of a service's records.
pub const KIND_SAMPLE: u16 = 0;
pub const KIND_FRAME: u16 = 1;

/// A log that cannot be written or read; names the file and the offset.
#[derive(Debug, thiserror::Error)]
pub enum LogError {
    #[error("{path}: {op}: {source}")]
    Io {
        path: PathBuf,
        op: &'static str,
        source: std::io::Error,
    },
    #[error("{path}: not a bowden log ({what})")]
    NotALog { path: PathBuf, what: String },
    #[error("{path}: corrupt at byte {offset}: {what}")]
    Corrupt { path: PathBuf, offset: u64, what: String },
    #[error("{path}: service `{service}` cannot be recorded: {what}")]
    Service {
        path: PathBuf,
        service: String,
        what: String,
    },
}

/// FNV-1a, 32 bit: cheap corruption check of a record's payload.
pub fn fnv1a32(bytes: &[u8]) -> u32 {
    let mut h: u32 = 0x811c_9dc5;
    for &b in bytes {
        h ^= b as u32;
        h = h.wrapping_mul(0x0100_0193);
    }
    h
}

/// The payload type and size of a bowden service.
pub fn service_type(service: &str) -> Option<(&'static str, u16, u32)> {
    struct TypeOf;
    impl PayloadVisitor for TypeOf {
        type Output = (&'static str, u16, u32);
        fn sample<T: Message>(self) -> Self::Output {
            (T::TYPE_NAME, KIND_SAMPLE, core::mem::size_of::<T>() as u32)
        }
        fn frame(self) -> Self::Output {
            (
                RgbdFrameHeader::TYPE_NAME,
                KIND_FRAME,
                core::mem::size_of::<RgbdFrameHeader>() as u32,
            )
        }
    }
    visit_payload(service, TypeOf)
}

/// One service of a log.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct LogService {
    pub name: String,
    pub type_name: String,
    pub kind: u16,
    pub sample_size: u32,
}

/// One index entry.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct IndexEntry {
    pub offset: u64,
    pub service: u16,
    pub kind: u16,
    pub len: u32,
    pub seq: u64,
    pub tick: u64,
    pub t_origin_ns: u64,
}

impl IndexEntry {
    fn to_bytes(self) -> [u8; INDEX_ENTRY_LEN as usize] {
        let mut b = [0u8; INDEX_ENTRY_LEN as usize];
        b[0..8].copy_from_slice(&self.offset.to_le_bytes());
        b[8..10].copy_from_slice(&self.service.to_le_bytes());
        b[10..12].copy_from_slice(&self.kind.to_le_bytes());
        b[12..16].copy_from_slice(&self.len.to_le_bytes());
        b[16..24].copy_from_slice(&self.seq.to_le_bytes());
        b[24..32].copy_from_slice(&self.tick.to_le_bytes());
        b[32..40].copy_from_slice(&self.t_origin_ns.to_le_bytes());
        b
    }

    fn from_bytes(b: &[u8]) -> Self {
        let u64_at = |i: usize| u64::from_le_bytes(b[i..i + 8].try_into().expect("8 bytes"));
        Self {
            offset: u64_at(0),
            service: u16::from_le_bytes([b[8], b[9]]),
            kind: u16::from_le_bytes([b[10], b[11]]),
            len: u32::from_le_bytes(b[12..16].try_into().expect("4 bytes")),
            seq: u64_at(16),
            tick: u64_at(24),
            t_origin_ns: u64_at(32),
        }
    }
}

/// Appends records to a log and its index.
pub struct LogWriter {
    path: PathBuf,
    index_path: PathBuf,
    data: BufWriter<File>,
    index: BufWriter<File>,
    offset: u64,
    records: u64,
    n_services: u32,
}

/// The index file of `log`.
pub fn index_path(log: &Path) -> PathBuf {
    let mut p = log.as_os_str().to_owned();
    p.push(".idx");
    PathBuf::from(p)
}

fn name_field(s: &str) -> [u8; 64] {
    let mut b = [0u8; 64];
    let n = s.len().min(64);
    b[..n].copy_from_slice(&s.as_bytes()[..n]);
    b
}

impl LogWriter {
    /// Creates (truncates) `path` and its index for `services` (full service names).
    pub fn create(path: &Path, services: &[String]) -> Result<Self, LogError> {
        let io = |op, source| LogError::Io {
            path: path.to_path_buf(),
            op,
            source,
        };
        if let Some(dir) = path.parent() {
            if !dir.as_os_str().is_empty() {
                std::fs::create_dir_all(dir).map_err(|e| io("create directory", e))?;
            }
        }
        let index_path = index_path(path);
        let data = File::create(path).map_err(|e| io("create", e))?;
        let index = File::create(&index_path).map_err(|e| LogError::Io {
            path: index_path.clone(),
            op: "create",
            source: e,
        })?;
        let mut w = Self {
            path: path.to_path_buf(),
            index_path,
            data: BufWriter::with_capacity(1 << 20, data),
            index: BufWriter::with_capacity(1 << 16, index),
            offset: 0,
            records: 0,
            n_services: services.len() as u32,
        };
        let mut head = Vec::new();
        head.extend_from_slice(LOG_MAGIC);
        head.extend_from_slice(&LOG_VERSION.to_le_bytes());
        head.extend_from_slice(&(services.len() as u32).to_le_bytes());
        for s in services {
            let (type_name, kind, size) = service_type(s).ok_or_else(|| LogError::Service {
                path: path.to_path_buf(),
                service: s.clone(),
                what: "unknown service".into(),
            })?;
            head.extend_from_slice(&name_field(s));
            head.extend_from_slice(&name_field(type_name));
            head.extend_from_slice(&(kind as u32).to_le_bytes());
            head.extend_from_slice(&size.to_le_bytes());
        }
        w.data.write_all(&head).map_err(|e| io("write header", e))?;
        w.offset = head.len() as u64;
        w.write_index_header(0)?;
        Ok(w)
    }

    fn write_index_header(&mut self, records: u64) -> Result<(), LogError> {
        let mut h = [0u8; INDEX_HEADER_LEN as usize];
        h[0..8].copy_from_slice(INDEX_MAGIC);
        h[8..12].copy_from_slice(&LOG_VERSION.to_le_bytes());
        h[12..16].copy_from_slice(&self.n_services.to_le_bytes());
        h[16..24].copy_from_slice(&records.to_le_bytes());
        self.index.write_all(&h).map_err(|e| LogError::Io {
            path: self.index_path.clone(),
            op: "write index header",
            source: e,
        })
    }

    /// Appends one record. `parts` are concatenated into the payload (frame header + frame).
    pub fn append(
        &mut self,
        service: u16,
        kind: u16,
        parts: &[&[u8]],
        header: &bowden_interfaces::SampleHeader,
    ) -> Result<(), LogError> {
        let len: usize = parts.iter().map(|p| p.len()).sum();
        let mut h: u32 = 0x811c_9dc5;
        for p in parts {
            for &b in *p {
                h ^= b as u32;
                h = h.wrapping_mul(0x0100_0193);
            }
        }
        let mut rh = [0u8; RECORD_HEADER_LEN as usize];
        rh[0..4].copy_from_slice(&RECORD_MAGIC.to_le_bytes());
        rh[4..6].copy_from_slice(&service.to_le_bytes());
        rh[6..8].copy_from_slice(&kind.to_le_bytes());
        rh[8..12].copy_from_slice(&(len as u32).to_le_bytes());
        rh[12..16].copy_from_slice(&h.to_le_bytes());
        let io = |e| LogError::Io {
            path: self.path.clone(),
            op: "write record",
            source: e,
        };
        self.data.write_all(&rh).map_err(io)?;
        for p in parts {
            self.data.write_all(p).map_err(io)?;
        }
        let pad = (8 - len % 8) % 8;
        self.data.write_all(&[0u8; 8][..pad]).map_err(io)?;
        let entry = IndexEntry {
            offset: self.offset,
            service,
            kind,
            len: len as u32,
            seq: header.seq,
            tick: header.tick,
            t_origin_ns: header.t_origin_ns,
        };
        self.index.write_all(&entry.to_bytes()).map_err(|e| LogError::Io {
            path: self.index_path.clone(),
            op: "write index",
            source: e,
        })?;
        self.offset += RECORD_HEADER_LEN + len as u64 + pad as u64;
        self.records += 1;
        Ok(())
    }

    pub fn records(&self) -> u64 {
        self.records
    }

    /// Flushes both files and writes the record count into the index header.
    pub fn finish(&mut self) -> Result<(), LogError> {
        self.data.flush().map_err(|e| LogError::Io {
            path: self.path.clone(),
            op: "flush",
            source: e,
        })?;
        let ierr = |op, e| LogError::Io {
            path: self.index_path.clone(),
            op,
            source: e,
        };
        self.index.flush().map_err(|e| ierr("flush", e))?;
        let f = self.index.get_mut();
        f.seek(SeekFrom::Start(16)).map_err(|e| ierr("seek", e))?;
        f.write_all(&self.records.to_le_bytes())
            .map_err(|e| ierr("write count", e))?;
        f.seek(SeekFrom::End(0)).map_err(|e| ierr("seek", e))?;
        f.sync_all().map_err(|e| ierr("sync", e))?;
        self.data.get_mut().sync_all().map_err(|e| LogError::Io {
            path: self.path.clone(),
            op: "sync",
            source: e,
        })?;
        Ok(())
    }
}

/// A log opened for reading.
pub struct LogReader {
    path: PathBuf,
    file: File,
    len: u64,
    pub services: Vec<LogService>,
    pub entries: Vec<IndexEntry>,
    /// The index was missing or incomplete and the data file was scanned instead.
    pub rebuilt_index: bool,
}

impl LogReader {
    /// Opens `path`, validating the header, and the index (or scanning the records when the index
    /// is missing, truncated or inconsistent).
    pub fn open(path: &Path) -> Result<Self, LogError> {
        let io = |op, source| LogError::Io {
            path: path.to_path_buf(),
            op,
            source,
        };
        let mut file = File::open(path).map_err(|e| io("open", e))?;
        let len = file.metadata().map_err(|e| io("stat", e))?.len();
        let not_log = |what: &str| LogError::NotALog {
            path: path.to_path_buf(),
            what: what.to_string(),
        };
        if len < FILE_HEADER_LEN {
            return Err(not_log("shorter than the file header"));
        }
        let mut head = [0u8; 16];
        file.read_exact(&mut head).map_err(|e| io("read header", e))?;
        if &head[0..8] != LOG_MAGIC {
            return Err(not_log("bad magic"));
        }
        let version = u32::from_le_bytes(head[8..12].try_into().expect("4 bytes"));
        if version != LOG_VERSION {
            return Err(not_log(&format!("version {version}, this build reads {LOG_VERSION}")));
        }
        let n = u32::from_le_bytes(head[12..16].try_into().expect("4 bytes")) as u64;
        if n == 0 || n > 64 || FILE_HEADER_LEN + n * SERVICE_ENTRY_LEN > len {
            return Err(LogError::Corrupt {
                path: path.to_path_buf(),
                offset: 12,
                what: format!("service count {n} impossible for a file of {len} bytes"),
            });
        }
        let mut services = Vec::new();
        for i in 0..n {
            let mut e = [0u8; SERVICE_ENTRY_LEN as usize];
            file.read_exact(&mut e).map_err(|e| io("read service table", e))?;
            let text = |b: &[u8]| {
                let end = b.iter().position(|&c| c == 0).unwrap_or(b.len());
                String::from_utf8_lossy(&b[..end]).into_owned()
            };
            let name = text(&e[0..64]);
            let type_name = text(&e[64..128]);
            let kind = u32::from_le_bytes(e[128..132].try_into().expect("4 bytes"));
            let sample_size = u32::from_le_bytes(e[132..136].try_into().expect("4 bytes"));
            let known = service_type(&name);
            if known.map(|(t, k, s)| (t, k as u32, s)) != Some((type_name.as_str(), kind, sample_size)) {
                return Err(LogError::Corrupt {
                    path: path.to_path_buf(),
                    offset: FILE_HEADER_LEN + i * SERVICE_ENTRY_LEN,
                    what: format!(
                        "service `{name}` type `{type_name}` kind {kind} size {sample_size} does not match this build's layout"
                    ),
                });
            }
            services.push(LogService {
                name,
                type_name,
                kind: kind as u16,
                sample_size,
            });
        }
        let data_start = FILE_HEADER_LEN + n * SERVICE_ENTRY_LEN;
        let mut r = Self {
            path: path.to_path_buf(),
            file,
            len,
            services,
            entries: Vec::new(),
            rebuilt_index: false,
        };
        match r.read_index(data_start) {
            Some(entries) => r.entries = entries,
            None => {
                r.entries = r.scan(data_start)?;
                r.rebuilt_index = true;
            }
        }
        Ok(r)
    }

    /// The index if it is complete and consistent with the data file.
    fn read_index(&self, data_start: u64) -> Option<Vec<IndexEntry>> {
        let bytes = std::fs::read(index_path(&self.path)).ok()?;
        if bytes.len() < INDEX_HEADER_LEN as usize || &bytes[0..8] != INDEX_MAGIC {
            return None;
        }
        let count = u64::from_le_bytes(bytes[16..24].try_into().ok()?);
        let body = &bytes[INDEX_HEADER_LEN as usize..];
        if count == 0 && !body.is_empty() || body.len() as u64 != count * INDEX_ENTRY_LEN {
            return None;
        }
        let mut expect = data_start;
        let mut out = Vec::with_capacity(count as usize);
        for chunk in body.chunks_exact(INDEX_ENTRY_LEN as usize) {
            let e = IndexEntry::from_bytes(chunk);
            let pad = (8 - e.len as u64 % 8) % 8;
            if e.offset != expect || e.service as usize >= self.services.len() {
                return None;
            }
            expect = e.offset + RECORD_HEADER_LEN + e.len as u64 + pad;
            out.push(e);
        }
        (expect == self.len).then_some(out)
    }

    /// Walks the records from `data_start`, checking each header and checksum. A truncated last
    /// record (the writer was killed mid-write) ends the scan; anything else inconsistent is an error.
    fn scan(&mut self, data_start: u64) -> Result<Vec<IndexEntry>, LogError> {
        let mut out = Vec::new();
        let mut off = data_start;
        let mut buf = Vec::new();
        while off + RECORD_HEADER_LEN <= self.len {
            let rh = self.read_at(off, RECORD_HEADER_LEN as usize)?;
            let magic = u32::from_le_bytes(rh[0..4].try_into().expect("4 bytes"));
            if magic != RECORD_MAGIC {
                return Err(self.corrupt(off, "bad record magic"));
            }
            let service = u16::from_le_bytes([rh[4], rh[5]]);
            let kind = u16::from_le_bytes([rh[6], rh[7]]);
            let len = u32::from_le_bytes(rh[8..12].try_into().expect("4 bytes"));
            if off + RECORD_HEADER_LEN + len as u64 > self.len {
                break; // truncated tail
            }
            let entry = self.check_record(off, service, kind, len, &mut buf)?;
            out.push(entry);
            let pad = (8 - len as u64 % 8) % 8;
            off += RECORD_HEADER_LEN + len as u64 + pad;
        }
        Ok(out)
    }

    fn corrupt(&self, offset: u64, what: impl Into<String>) -> LogError {
        LogError::Corrupt {
            path: self.path.clone(),
            offset,
            what: what.into(),
        }
    }

    fn read_at(&mut self, off: u64, len: usize) -> Result<Vec<u8>, LogError> {
        let mut v = vec![0u8; len];
        self.read_into(off, &mut v)?;
        Ok(v)
    }

    fn read_into(&mut self, off: u64, out: &mut [u8]) -> Result<(), LogError> {
        self.file.seek(SeekFrom::Start(off)).map_err(|e| LogError::Io {
            path: self.path.clone(),
            op: "seek",
            source: e,
        })?;
        self.file.read_exact(out).map_err(|e| LogError::Io {
            path: self.path.clone(),
            op: "read",
            source: e,
        })
    }

    fn check_record(
        &mut self,
        off: u64,
        service: u16,
        kind: u16,
        len: u32,
        buf: &mut Vec<u8>,
    ) -> Result<IndexEntry, LogError> {
        let Some(svc) = self.services.get(service as usize) else {
            return Err(self.corrupt(off, format!("service index {service} out of range")));
        };
        if svc.kind != kind {
            return Err(self.corrupt(
                off,
                format!("record kind {kind} differs from service kind {}", svc.kind),
            ));
        }
        let size_ok = if kind == KIND_FRAME {
            len >= svc.sample_size
        } else {
            len == svc.sample_size
        };
        if !size_ok {
            return Err(self.corrupt(
                off,
                format!("record of {len} bytes for `{}` ({} bytes)", svc.name, svc.sample_size),
            ));
        }
        buf.resize(len as usize, 0);
        self.read_into(off + RECORD_HEADER_LEN, buf)?;
        let sum_bytes = self.read_at(off + 12, 4)?;
        let sum = u32::from_le_bytes(sum_bytes[..4].try_into().expect("4 bytes"));
        if fnv1a32(buf) != sum {
            return Err(self.corrupt(off, "payload checksum mismatch"));
        }
        let h = bowden_interfaces::SampleHeader {
            seq: u64::from_le_bytes(buf[0..8].try_into().expect("8 bytes")),
            tick: u64::from_le_bytes(buf[8..16].try_into().expect("8 bytes")),
            t_origin_ns: u64::from_le_bytes(buf[16..24].try_into().expect("8 bytes")),
        };
        Ok(IndexEntry {
            offset: off,
            service,
            kind,
            len,
            seq: h.seq,
            tick: h.tick,
            t_origin_ns: h.t_origin_ns,
        })
    }

    /// Reads and verifies record `i`'s payload into `buf`.
    pub fn payload(&mut self, i: usize, buf: &mut Vec<u8>) -> Result<IndexEntry, LogError> {
        let e = self.entries[i];
        let rh = self.read_at(e.offset, RECORD_HEADER_LEN as usize)?;
        let magic = u32::from_le_bytes(rh[0..4].try_into().expect("4 bytes"));
        let service = u16::from_le_bytes([rh[4], rh[5]]);
        let kind = u16::from_le_bytes([rh[6], rh[7]]);
        let len = u32::from_le_bytes(rh[8..12].try_into().expect("4 bytes"));
        if magic != RECORD_MAGIC || service != e.service || kind != e.kind || len != e.len {
            return Err(self.corrupt(e.offset, "record header disagrees with the index"));
        }
        self.check_record(e.offset, service, kind, len, buf)
    }

    /// Decodes record `i` as `T` (a fixed-size sample); `None` if it is another type.
    pub fn sample<T: Message>(&mut self, i: usize, buf: &mut Vec<u8>) -> Result<Option<T>, LogError> {
        let e = self.entries[i];
        if self.services[e.service as usize].type_name != T::TYPE_NAME {
            return Ok(None);
        }
        self.payload(i, buf)?;
        Ok(T::from_bytes(buf))
    }

    pub fn path(&self) -> &Path {
        &self.path
    }
}

/// Type-erased drain of one recorded service.
trait Source {
    /// Appends every queued sample (lockstep: of ticks ≤ `upto`) to `w`. Returns how many.
    fn drain(&mut self, upto: Option<u64>, idx: u16, w: &mut LogWriter, gaps: &mut u64) -> Result<u64, LogError>;
}

struct SampleSource<T: Message> {
    input: Input<T>,
    last_seq: Option<u64>,
    track_gaps: bool,
}

impl<T: Message> Source for SampleSource<T> {
    fn drain(&mut self, upto: Option<u64>, idx: u16, w: &mut LogWriter, gaps: &mut u64) -> Result<u64, LogError> {
        let mut n = 0;
        loop {
            let s = match upto {
                Some(k) => self.input.next_upto(k),
                None => self.input.recv(),
            };
            let Some(s) = s else { break };
            let h = *s.header();
            if self.track_gaps {
                if let Some(l) = self.last_seq {
                    if h.seq > l + 1 {
                        *gaps += h.seq - l - 1;
                    }
                }
                self.last_seq = Some(h.seq);
            }
            w.append(idx, KIND_SAMPLE, &[s.as_bytes()], &h)?;
            n += 1;
        }
        Ok(n)
    }
}

struct FrameTap {
    input: FrameInput,
    last_seq: Option<u64>,
}

impl Source for FrameTap {
    fn drain(&mut self, upto: Option<u64>, idx: u16, w: &mut LogWriter, gaps: &mut u64) -> Result<u64, LogError> {
        let mut n = 0;
        loop {
            let f = match upto {
                Some(k) => self.input.next_upto(k),
                None => self.input.recv(),
            };
            let Some(f) = f else { break };
            let h = *f.user_header();
            if let Some(l) = self.last_seq {
                if h.header.seq > l + 1 {
                    *gaps += h.header.seq - l - 1;
                }
            }
            self.last_seq = Some(h.header.seq);
            w.append(idx, KIND_FRAME, &[h.as_bytes(), f.payload()], &h.header)?;
            n += 1;
        }
        Ok(n)
    }
}

/// Recorder parameters (`[node.params]` of a `recorder` stage).
#[derive(Debug, Clone, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RecorderParams {
    /// Log file (relative to the pipeline config's directory).
    pub path: PathBuf,
    /// Full service names, recorded in this order within a tick.
    pub services: Vec<String>,
}

/// The recorder's node kind: the one kind the runtime provides itself. Its inputs are the
/// services its parameters name; in lockstep it handles tick k once their producers are done
/// with k. Periodic (every 10 ms in real time): it is not part of the control cycle and drains
/// its 64-deep queues at its own pace.
pub const KIND: NodeKind = NodeKind {
    kind: "recorder",
    summary: "writes chosen services to a fixed-layout log (`bowden replay` reads it)",
    inputs: &[],
    outputs: &[],
    schedule: Schedule {
        period_us: Some(10_000),
        ..Schedule::PERIODIC
    },
    ports_from_params: Some(recorder_ports),
    lockstep_refusal: None,
    build: |env| Ok(Box::new(RecorderStage::from_env(env)?)),
};

/// The services a recorder's `params.services` names (validated), as its inputs.
fn recorder_ports(params: &toml::Table) -> Result<ParamPorts, ParamPortsError> {
    Ok(ParamPorts {
        inputs: recorder_services(params)?
            .into_iter()
            .map(|s| (s, ReadPolicy::Tick))
            .collect(),
        outputs: Vec::new(),
    })
}

fn recorder_services(params: &toml::Table) -> Result<Vec<String>, ParamPortsError> {
    if !params.contains_key("services") {
        return Err(ParamPortsError::Missing {
            what: "a recorder needs `services = [...]`",
        });
    }
    let out = service_list(params, "services", |_| None)?;
    if out.is_empty() {
        return Err(ParamPortsError::Missing {
            what: "no services to record",
        });
    }
    Ok(out)
}

/// The recorder as a pipeline stage.
pub struct RecorderStage {
    lockstep: bool,
    writer: LogWriter,
    sources: Vec<(String, Box<dyn Source>)>,
    counts: Vec<u64>,
    gaps: u64,
    write_errors: u64,
    first_error: Option<String>,
}

impl RecorderStage {
    pub fn from_env(env: &StageEnv<'_>) -> Result<Self, StageBuildError> {
        let p: RecorderParams = env.params()?;
        let services = recorder_services(&env.spec.params).map_err(|e| env.error(e))?;
        // A relative path is relative to the working directory of the run (where the user asked
        // for the recording), not to the config file.
        let path = p.path.clone();
        let writer = LogWriter::create(&path, &services).map_err(|e| env.error(e))?;
        let mut sources: Vec<(String, Box<dyn Source>)> = Vec::new();
        // A generous queue: in real time the recorder drains every 10 ms.
        const BUF: usize = 64;
        struct MakeSource<'a, 'e> {
            env: &'a StageEnv<'e>,
            service: &'a str,
        }
        impl PayloadVisitor for MakeSource<'_, '_> {
            type Output = Result<Box<dyn Source>, StageBuildError>;
            fn sample<T: Message>(self) -> Self::Output {
                // Several publishers (statuses, e-stop tools) or sparse streams: no gap count.
                let track_gaps =
                    ![services::COMPONENT_STATUS, services::SAFETY, services::MODEL_UPDATE].contains(&self.service);
                Ok(Box::new(SampleSource::<T> {
                    input: self.env.ports.input::<T>(self.service, BUF)?,
                    last_seq: None,
                    track_gaps,
                }))
            }
            fn frame(self) -> Self::Output {
                Ok(Box::new(FrameTap {
                    input: self.env.ports.frame_input(self.service, 4)?,
                    last_seq: None,
                }))
            }
        }
        for s in &services {
            let b = visit_payload(s, MakeSource { env, service: s })
                .unwrap_or_else(|| Err(env.error(format!("cannot record service `{s}`"))))?;
            sources.push((s.clone(), b));
        }
        let n = sources.len();
        Ok(Self {
            lockstep: env.reproducible(),
            writer,
            sources,
            counts: vec![0; n],
            gaps: 0,
            write_errors: 0,
            first_error: None,
        })
    }
}

impl Stage for RecorderStage {
    fn step(&mut self, cx: &StepCx) -> Result<StepReport, StageError> {
        let upto = cx.reproducible().then_some(cx.tick());
        let mut any = false;
        for (i, (_, src)) in self.sources.iter_mut().enumerate() {
            match src.drain(upto, i as u16, &mut self.writer, &mut self.gaps) {
                Ok(n) => {
                    self.counts[i] += n;
                    any |= n > 0;
                }
                Err(e) => {
                    // A full disk must not take the pipeline down: count, report, go on.
                    self.write_errors += 1;
                    self.first_error.get_or_insert_with(|| e.to_string());
                }
            }
        }
        Ok(StepReport {
            active: any,
            t_origin_ns: None,
        })
    }

    fn counters(&self) -> StageCounters {
        StageCounters {
            rejected: 0,
            faults: self.gaps + self.write_errors,
            degraded: self.write_errors > 0,
            ..Default::default()
        }
    }

    fn finish(&mut self) -> Result<(), StageError> {
        // Real time: whatever is still queued belongs in the log too. Lockstep: every tick was
        // recorded when it completed; samples arriving during shutdown are not part of the run.
        if !self.lockstep {
            let _ = self.step(&StepCx::realtime(0, 0, 0, 0));
        }
        self.writer.finish().map_err(|e| StageError::Fatal {
            stage: "recorder".into(),
            message: e.to_string(),
        })
    }

    fn summary(&self) -> Vec<String> {
        let mut v = vec![format!(
            "recorder: {} records to {} (lost by sequence gaps: {}, write errors: {})",
            self.writer.records(),
            self.writer.path.display(),
            self.gaps,
            self.write_errors
        )];
        if let Some(e) = &self.first_error {
            v.push(format!("recorder: first write error: {e}"));
        }
        for ((s, _), n) in self.sources.iter().zip(&self.counts) {
            v.push(format!("  {s}: {n}"));
        }
        v
    }
}
