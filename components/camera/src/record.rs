//! Recorded RGBD sequences: a directory of `color/NNNNNN.png` (RGB8), `depth/NNNNNN.png`
//! (16-bit counts of `depth_unit_mm`, 0 = no depth) and `index.json` (intrinsics, depth unit,
//! and per frame seq, tick, t_origin_ns and the two file names, relative to the directory).
//! [`Recorder`] writes one; [`ReplaySource`] reads one back, bit-exact, so that recorded
//! real-camera data (converted to this layout) can drive the pipeline.

use serde::{Deserialize, Serialize};
use std::path::{Component, Path, PathBuf};

use bowden_interfaces::{RgbdFrameHeader, SampleHeader};

use crate::pngio::{read_depth_png, read_rgb_png, write_depth_png, write_rgb_png};
use crate::CameraError;

/// Format tag of `index.json`.
pub const INDEX_FORMAT: &str = "bowden-rgbd/1";
/// File name of the index inside a recording directory.
pub const INDEX_FILE: &str = "index.json";

/// What every frame of a stream shares: size, pinhole intrinsics (pixel centres at integer
/// coordinates) and depth unit.
#[derive(Debug, Clone, Copy, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct StreamInfo {
    pub width: u32,
    pub height: u32,
    pub fx: f64,
    pub fy: f64,
    pub cx: f64,
    pub cy: f64,
    pub depth_unit_mm: f64,
}

impl StreamInfo {
    /// The stream a frame header describes.
    pub fn from_header(h: &RgbdFrameHeader) -> Self {
        Self {
            width: h.width,
            height: h.height,
            fx: h.fx,
            fy: h.fy,
            cx: h.cx,
            cy: h.cy,
            depth_unit_mm: h.depth_unit_mm,
        }
    }

    pub fn pixels(&self) -> usize {
        self.width as usize * self.height as usize
    }

    /// A frame header of this stream.
    pub fn header(&self, sample: SampleHeader) -> RgbdFrameHeader {
        let px = self.pixels() as u64;
        RgbdFrameHeader {
            header: sample,
            width: self.width,
            height: self.height,
            fx: self.fx,
            fy: self.fy,
            cx: self.cx,
            cy: self.cy,
            depth_unit_mm: self.depth_unit_mm,
            depth_offset: px * 3,
            payload_len: px * 5,
        }
    }

    fn validate(&self, path: &Path) -> Result<(), CameraError> {
        let bad = |problem: String| CameraError::Index {
            path: path.to_path_buf(),
            problem,
        };
        if !(1..=16384).contains(&self.width) || !(1..=16384).contains(&self.height) {
            return Err(bad(format!(
                "frame size {}x{} is not 1..=16384 each",
                self.width, self.height
            )));
        }
        for (name, v) in [("fx", self.fx), ("fy", self.fy), ("depth_unit_mm", self.depth_unit_mm)] {
            if !(v.is_finite() && v > 0.0) {
                return Err(bad(format!("`{name}` must be a positive number, got {v}")));
            }
        }
        for (name, v) in [("cx", self.cx), ("cy", self.cy)] {
            if !v.is_finite() {
                return Err(bad(format!("`{name}` must be finite, got {v}")));
            }
        }
        Ok(())
    }
}

/// One frame of `index.json`.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct FrameEntry {
    pub seq: u64,
    pub tick: u64,
    pub t_origin_ns: u64,
    /// Colour PNG, relative to the recording directory.
    pub color: String,
    /// Depth PNG, relative to the recording directory.
    pub depth: String,
}

/// `index.json`.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct RecordingIndex {
    pub format: String,
    #[serde(flatten)]
    pub stream: StreamInfo,
    pub frames: Vec<FrameEntry>,
}

/// Writes frames into a recording directory. The index is written by [`finish`](Self::finish)
/// (and, best effort, when the recorder is dropped unfinished, so frames already on disk are
/// not orphaned).
#[derive(Debug)]
pub struct Recorder {
    dir: PathBuf,
    index: RecordingIndex,
    finished: bool,
    scratch: Vec<u8>,
}

impl Recorder {
    /// Creates (or reuses an empty) directory `dir`. Refuses to overwrite a recording.
    pub fn create(dir: impl AsRef<Path>, stream: StreamInfo) -> Result<Self, CameraError> {
        let dir = dir.as_ref().to_path_buf();
        let index_path = dir.join(INDEX_FILE);
        stream.validate(&index_path)?;
        if index_path.exists() {
            return Err(CameraError::Index {
                path: index_path,
                problem: "a recording already exists here; choose another directory".into(),
            });
        }
        for sub in ["color", "depth"] {
            let p = dir.join(sub);
            std::fs::create_dir_all(&p).map_err(|cause| CameraError::Write { path: p, cause })?;
        }
        Ok(Self {
            dir,
            index: RecordingIndex {
                format: INDEX_FORMAT.into(),
                stream,
                frames: Vec::new(),
            },
            finished: false,
            scratch: Vec::new(),
        })
    }

    pub fn dir(&self) -> &Path {
        &self.dir
    }
    pub fn len(&self) -> usize {
        self.index.frames.len()
    }
    pub fn is_empty(&self) -> bool {
        self.index.frames.is_empty()
    }

    /// Appends one frame (colour RGB8 and depth counts of the stream's size).
    pub fn record(&mut self, sample: &SampleHeader, rgb: &[u8], depth: &[u16]) -> Result<(), CameraError> {
        let n = self.index.frames.len();
        let entry = FrameEntry {
            seq: sample.seq,
            tick: sample.tick,
            t_origin_ns: sample.t_origin_ns,
            color: format!("color/{n:06}.png"),
            depth: format!("depth/{n:06}.png"),
        };
        let (w, h) = (self.index.stream.width, self.index.stream.height);
        write_rgb_png(&self.dir.join(&entry.color), w, h, rgb)?;
        write_depth_png(&self.dir.join(&entry.depth), w, h, depth, &mut self.scratch)?;
        self.index.frames.push(entry);
        Ok(())
    }

    /// Appends a frame in the interfaces layout (header + RGB8 plane + LE u16 depth plane).
    /// The header must describe this recording's stream.
    pub fn record_payload(&mut self, frame: &RgbdFrameHeader, payload: &[u8]) -> Result<(), CameraError> {
        let s = self.index.stream;
        let path = self.dir.join(INDEX_FILE);
        if StreamInfo::from_header(frame) != s {
            return Err(CameraError::Index {
                path,
                problem: format!(
                    "frame seq {} has stream {:?}, the recording is {:?}",
                    frame.header.seq,
                    StreamInfo::from_header(frame),
                    s
                ),
            });
        }
        let px = s.pixels();
        if payload.len() != px * 5 {
            return Err(CameraError::BufferSize {
                buffer: "payload",
                expected: px * 5,
                got: payload.len(),
                width: s.width,
                height: s.height,
            });
        }
        let (rgb, depth_bytes) = payload.split_at(px * 3);
        let depth: Vec<u16> = depth_bytes
            .chunks_exact(2)
            .map(|b| u16::from_le_bytes([b[0], b[1]]))
            .collect();
        self.record(&frame.header, rgb, &depth)
    }

    /// Writes `index.json` now (atomically: temporary file, then rename).
    pub fn write_index(&self) -> Result<PathBuf, CameraError> {
        let path = self.dir.join(INDEX_FILE);
        let tmp = self.dir.join("index.json.tmp");
        let text = serde_json::to_string_pretty(&self.index).map_err(|e| CameraError::Index {
            path: path.clone(),
            problem: format!("cannot serialise: {e}"),
        })?;
        std::fs::write(&tmp, text).map_err(|cause| CameraError::Write {
            path: tmp.clone(),
            cause,
        })?;
        std::fs::rename(&tmp, &path).map_err(|cause| CameraError::Write {
            path: path.clone(),
            cause,
        })?;
        Ok(path)
    }

    /// Writes the index and closes the recording; returns the index path.
    pub fn finish(mut self) -> Result<PathBuf, CameraError> {
        self.finished = true;
        self.write_index()
    }
}

impl Drop for Recorder {
    fn drop(&mut self) {
        if !self.finished {
            // Best effort: an error here has nowhere to go, and the frames stay on disk.
            let _ = self.write_index();
        }
    }
}

/// Reads a recording back, frame by frame, into caller buffers.
#[derive(Debug)]
pub struct ReplaySource {
    dir: PathBuf,
    index_path: PathBuf,
    index: RecordingIndex,
    scratch: Vec<u8>,
    depth_scratch: Vec<u16>,
}

/// A frame file name must stay inside the recording directory.
fn check_rel(index_path: &Path, frame: usize, field: &str, rel: &str) -> Result<(), CameraError> {
    let p = Path::new(rel);
    let inside = !rel.is_empty()
        && p.components()
            .all(|c| matches!(c, Component::Normal(_) | Component::CurDir));
    if inside {
        Ok(())
    } else {
        Err(CameraError::Index {
            path: index_path.to_path_buf(),
            problem: format!("frames[{frame}].{field} = {rel:?} must be a relative path inside the recording"),
        })
    }
}

impl ReplaySource {
    /// Opens `dir/index.json`, validates it and checks that every listed file exists.
    pub fn open(dir: impl AsRef<Path>) -> Result<Self, CameraError> {
        let dir = dir.as_ref().to_path_buf();
        let index_path = dir.join(INDEX_FILE);
        let text = std::fs::read_to_string(&index_path).map_err(|cause| CameraError::Read {
            path: index_path.clone(),
            cause,
        })?;
        let index: RecordingIndex = serde_json::from_str(&text).map_err(|e| CameraError::Index {
            path: index_path.clone(),
            problem: format!("malformed: {e}"),
        })?;
        if index.format != INDEX_FORMAT {
            return Err(CameraError::Index {
                path: index_path,
                problem: format!("format {:?} is not {INDEX_FORMAT:?}", index.format),
            });
        }
        index.stream.validate(&index_path)?;
        for (i, f) in index.frames.iter().enumerate() {
            for (field, rel) in [("color", &f.color), ("depth", &f.depth)] {
                check_rel(&index_path, i, field, rel)?;
                let p = dir.join(rel);
                if !p.is_file() {
                    return Err(CameraError::Index {
                        path: index_path,
                        problem: format!("frames[{i}].{field}: {} is missing", p.display()),
                    });
                }
            }
        }
        Ok(Self {
            dir,
            index_path,
            index,
            scratch: Vec::new(),
            depth_scratch: Vec::new(),
        })
    }

    pub fn stream(&self) -> &StreamInfo {
        &self.index.stream
    }
    pub fn len(&self) -> usize {
        self.index.frames.len()
    }
    pub fn is_empty(&self) -> bool {
        self.index.frames.is_empty()
    }
    pub fn frames(&self) -> &[FrameEntry] {
        &self.index.frames
    }

    fn entry(&self, i: usize) -> Result<&FrameEntry, CameraError> {
        self.index.frames.get(i).ok_or(CameraError::FrameOutOfRange {
            path: self.index_path.clone(),
            index: i,
            len: self.index.frames.len(),
        })
    }

    /// The header frame `i` was recorded with.
    pub fn header(&self, i: usize) -> Result<RgbdFrameHeader, CameraError> {
        let e = self.entry(i)?;
        Ok(self.index.stream.header(SampleHeader {
            seq: e.seq,
            tick: e.tick,
            t_origin_ns: e.t_origin_ns,
        }))
    }

    fn check_len(&self, buffer: &'static str, got: usize, per_px: usize) -> Result<(), CameraError> {
        let s = &self.index.stream;
        if got != s.pixels() * per_px {
            return Err(CameraError::BufferSize {
                buffer,
                expected: s.pixels() * per_px,
                got,
                width: s.width,
                height: s.height,
            });
        }
        Ok(())
    }

    /// Reads frame `i` into `rgb` (RGB8) and `depth` (counts of `depth_unit_mm`).
    pub fn read(&mut self, i: usize, rgb: &mut [u8], depth: &mut [u16]) -> Result<RgbdFrameHeader, CameraError> {
        self.check_len("rgb", rgb.len(), 3)?;
        self.check_len("depth", depth.len(), 1)?;
        let header = self.header(i)?;
        let e = &self.index.frames[i];
        let (w, h) = (self.index.stream.width, self.index.stream.height);
        read_rgb_png(&self.dir.join(&e.color), w, h, rgb, &mut self.scratch)?;
        read_depth_png(&self.dir.join(&e.depth), w, h, depth, &mut self.scratch)?;
        Ok(header)
    }

    /// Reads frame `i` into an interfaces payload (RGB8 plane then LE u16 depth plane).
    pub fn read_into_payload(&mut self, i: usize, payload: &mut [u8]) -> Result<RgbdFrameHeader, CameraError> {
        self.check_len("payload", payload.len(), 5)?;
        let s = self.index.stream;
        let px = s.pixels();
        let header = self.header(i)?;
        let e = &self.index.frames[i];
        let (rgb, depth_bytes) = payload.split_at_mut(px * 3);
        read_rgb_png(&self.dir.join(&e.color), s.width, s.height, rgb, &mut self.scratch)?;
        self.depth_scratch.resize(px, 0);
        read_depth_png(
            &self.dir.join(&e.depth),
            s.width,
            s.height,
            &mut self.depth_scratch,
            &mut self.scratch,
        )?;
        for (o, d) in depth_bytes.chunks_exact_mut(2).zip(&self.depth_scratch) {
            o.copy_from_slice(&d.to_le_bytes());
        }
        Ok(header)
    }
}
