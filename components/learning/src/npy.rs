//! A small reader for NumPy `.npy` files (format versions 1.0, 2.0 and 3.0): real robots'
//! logs often come as `np.save` arrays, and pulling in a NumPy crate for one header is not
//! worth it. Only what datasets need: 1-D or 2-D arrays of `float32` / `float64` (either
//! byte order, C or Fortran order), returned as row-major `f64`.

use std::path::{Path, PathBuf};

/// What can be wrong with an `.npy` file. Every variant names the file.
#[derive(Debug, thiserror::Error)]
pub enum NpyError {
    #[error("{path}: cannot read: {source}")]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("{path}: not a .npy file (the magic string \\x93NUMPY is missing)")]
    BadMagic { path: PathBuf },
    #[error("{path}: unsupported .npy format version {major}.{minor} (1.0, 2.0 and 3.0 are read)")]
    Version { path: PathBuf, major: u8, minor: u8 },
    #[error("{path}: the file ends inside its header ({len} bytes, header needs {needed})")]
    Truncated { path: PathBuf, len: usize, needed: usize },
    #[error("{path}: malformed header {header:?}: {what}")]
    Header {
        path: PathBuf,
        header: String,
        what: String,
    },
    #[error("{path}: dtype {descr:?} is not supported (only float32 '<f4'/'>f4' and float64 '<f8'/'>f8')")]
    Dtype { path: PathBuf, descr: String },
    #[error("{path}: shape {shape:?} has {ndim} dimensions; expected a 1-D or 2-D array")]
    Rank {
        path: PathBuf,
        shape: Vec<usize>,
        ndim: usize,
    },
    #[error("{path}: shape {shape:?} needs {expected} data bytes but the file holds {actual}")]
    DataLength {
        path: PathBuf,
        shape: Vec<usize>,
        expected: usize,
        actual: usize,
    },
}

/// A 2-D array (a 1-D file reads as `n × 1`), row-major.
#[derive(Debug, Clone, PartialEq)]
pub struct NpyMatrix {
    pub rows: usize,
    pub cols: usize,
    /// `rows * cols` values, row-major.
    pub data: Vec<f64>,
    /// The dtype string of the file, e.g. `<f4`.
    pub descr: String,
}

impl NpyMatrix {
    pub fn get(&self, row: usize, col: usize) -> f64 {
        self.data[row * self.cols + col]
    }
}

/// Reads an `.npy` file.
pub fn read_npy(path: &Path) -> Result<NpyMatrix, NpyError> {
    let bytes = std::fs::read(path).map_err(|source| NpyError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    parse_npy(&bytes, path)
}

/// Parses the bytes of an `.npy` file; `path` only names the source in errors.
pub fn parse_npy(bytes: &[u8], path: &Path) -> Result<NpyMatrix, NpyError> {
    let p = || path.to_path_buf();
    if bytes.len() < 10 || &bytes[..6] != b"\x93NUMPY" {
        return Err(NpyError::BadMagic { path: p() });
    }
    let (major, minor) = (bytes[6], bytes[7]);
    let (header_len, header_start) = match major {
        1 => (u16::from_le_bytes([bytes[8], bytes[9]]) as usize, 10),
        2 | 3 => {
            if bytes.len() < 12 {
                return Err(NpyError::Truncated {
                    path: p(),
                    len: bytes.len(),
                    needed: 12,
                });
            }
            (
                u32::from_le_bytes([bytes[8], bytes[9], bytes[10], bytes[11]]) as usize,
                12,
            )
        }
        _ => {
            return Err(NpyError::Version {
                path: p(),
                major,
                minor,
            })
        }
    };
    let data_start = header_start + header_len;
    if bytes.len() < data_start {
        return Err(NpyError::Truncated {
            path: p(),
            len: bytes.len(),
            needed: data_start,
        });
    }
    // Version 3 allows UTF-8 in the header; versions 1 and 2 are latin-1 but what matters
    // (keys, dtype, shape) is ASCII either way.
    let header = String::from_utf8_lossy(&bytes[header_start..data_start]).into_owned();
    let bad = |what: &str| NpyError::Header {
        path: p(),
        header: header.trim_end().to_string(),
        what: what.to_string(),
    };
    let descr = dict_value(&header, "descr").ok_or_else(|| bad("no 'descr' key"))?;
    let descr = unquote(descr).ok_or_else(|| bad("'descr' is not a quoted string"))?;
    let fortran = match dict_value(&header, "fortran_order").map(str::trim) {
        Some(v) if v.starts_with("True") => true,
        Some(v) if v.starts_with("False") => false,
        _ => return Err(bad("no boolean 'fortran_order' key")),
    };
    let shape_text = dict_value(&header, "shape").ok_or_else(|| bad("no 'shape' key"))?;
    let shape = parse_shape(shape_text).ok_or_else(|| bad("'shape' is not a tuple of integers"))?;

    let (width, big_endian) = match descr.as_str() {
        "<f4" | "=f4" | "f4" => (4, false),
        ">f4" => (4, true),
        "<f8" | "=f8" | "f8" => (8, false),
        ">f8" => (8, true),
        _ => return Err(NpyError::Dtype { path: p(), descr }),
    };
    let (rows, cols) = match shape.as_slice() {
        [n] => (*n, 1),
        [r, c] => (*r, *c),
        _ => {
            return Err(NpyError::Rank {
                path: p(),
                ndim: shape.len(),
                shape,
            })
        }
    };
    let count = rows.checked_mul(cols).ok_or_else(|| bad("shape overflows"))?;
    let expected = count.checked_mul(width).ok_or_else(|| bad("shape overflows"))?;
    let payload = &bytes[data_start..];
    if payload.len() != expected {
        return Err(NpyError::DataLength {
            path: p(),
            shape,
            expected,
            actual: payload.len(),
        });
    }
    let mut flat = Vec::with_capacity(count);
    for chunk in payload.chunks_exact(width) {
        let v = match (width, big_endian) {
            (4, false) => f32::from_le_bytes([chunk[0], chunk[1], chunk[2], chunk[3]]) as f64,
            (4, true) => f32::from_be_bytes([chunk[0], chunk[1], chunk[2], chunk[3]]) as f64,
            (_, false) => f64::from_le_bytes(chunk.try_into().unwrap_or([0; 8])),
            (_, true) => f64::from_be_bytes(chunk.try_into().unwrap_or([0; 8])),
        };
        flat.push(v);
    }
    let data = if fortran && cols > 1 {
        let mut d = vec![0.0; count];
        for c in 0..cols {
            for r in 0..rows {
                d[r * cols + c] = flat[c * rows + r];
            }
        }
        d
    } else {
        flat
    };
    Ok(NpyMatrix {
        rows,
        cols,
        data,
        descr,
    })
}

/// Writes a row-major 2-D `float64` array as an `.npy` (version 1.0), as `np.save` would.
pub fn write_npy_f64(path: &Path, rows: usize, cols: usize, data: &[f64]) -> std::io::Result<()> {
    let mut out = npy_header("<f8", rows, cols);
    for v in data {
        out.extend_from_slice(&v.to_le_bytes());
    }
    std::fs::write(path, out)
}

/// Writes a row-major 2-D `float32` array as an `.npy` (version 1.0).
pub fn write_npy_f32(path: &Path, rows: usize, cols: usize, data: &[f32]) -> std::io::Result<()> {
    let mut out = npy_header("<f4", rows, cols);
    for v in data {
        out.extend_from_slice(&v.to_le_bytes());
    }
    std::fs::write(path, out)
}

fn npy_header(descr: &str, rows: usize, cols: usize) -> Vec<u8> {
    let mut dict = format!("{{'descr': '{descr}', 'fortran_order': False, 'shape': ({rows}, {cols}), }}");
    // Data starts on a 64-byte boundary; the header ends with '\n'.
    let unpadded = 10 + dict.len() + 1;
    dict.push_str(&" ".repeat((64 - unpadded % 64) % 64));
    dict.push('\n');
    let mut out = b"\x93NUMPY\x01\x00".to_vec();
    out.extend_from_slice(&(dict.len() as u16).to_le_bytes());
    out.extend_from_slice(dict.as_bytes());
    out
}

/// The text after `'key':` in a Python dict literal, up to the end of the dict.
fn dict_value<'a>(header: &'a str, key: &str) -> Option<&'a str> {
    let needle_single = format!("'{key}'");
    let needle_double = format!("\"{key}\"");
    let at = header.find(&needle_single).or_else(|| header.find(&needle_double))?;
    let rest = &header[at + key.len() + 2..];
    let colon = rest.find(':')?;
    Some(rest[colon + 1..].trim_start())
}

fn unquote(text: &str) -> Option<String> {
    let q = text.chars().next()?;
    if q != '\'' && q != '"' {
        return None;
    }
    let end = text[1..].find(q)?;
    Some(text[1..1 + end].to_string())
}

fn parse_shape(text: &str) -> Option<Vec<usize>> {
    let text = text.strip_prefix('(')?;
    let end = text.find(')')?;
    text[..end]
        .split(',')
        .map(str::trim)
        .filter(|s| !s.is_empty())
        .map(|s| s.trim_end_matches('L').parse::<usize>().ok())
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trip_f64_and_f32() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("a.npy");
        let data: Vec<f64> = (0..12).map(|i| i as f64 * 0.5 - 2.0).collect();
        write_npy_f64(&p, 4, 3, &data).unwrap();
        let m = read_npy(&p).unwrap();
        assert_eq!((m.rows, m.cols), (4, 3));
        assert_eq!(m.data, data);
        let p32 = dir.path().join("b.npy");
        let d32: Vec<f32> = data.iter().map(|&v| v as f32).collect();
        write_npy_f32(&p32, 3, 4, &d32).unwrap();
        let m = read_npy(&p32).unwrap();
        assert_eq!((m.rows, m.cols, m.descr.as_str()), (3, 4, "<f4"));
        assert_eq!(m.data, data);
    }

    #[test]
    fn fortran_order_and_big_endian() {
        let dict = "{'descr': '>f8', 'fortran_order': True, 'shape': (2, 3), }";
        let mut bytes = b"\x93NUMPY\x01\x00".to_vec();
        bytes.extend_from_slice(&(dict.len() as u16 + 1).to_le_bytes());
        bytes.extend_from_slice(dict.as_bytes());
        bytes.push(b'\n');
        // Column-major [[1,2,3],[4,5,6]] = 1,4,2,5,3,6.
        for v in [1.0f64, 4.0, 2.0, 5.0, 3.0, 6.0] {
            bytes.extend_from_slice(&v.to_be_bytes());
        }
        let m = parse_npy(&bytes, Path::new("x.npy")).unwrap();
        assert_eq!(m.data, vec![1.0, 2.0, 3.0, 4.0, 5.0, 6.0]);
    }

    #[test]
    fn bad_files_give_named_errors() {
        let p = Path::new("bad.npy");
        let e = parse_npy(b"PK\x03\x04 not numpy", p).unwrap_err();
        assert!(matches!(e, NpyError::BadMagic { .. }), "{e}");
        assert!(e.to_string().contains("bad.npy"));

        let mut bytes = npy_header("<i8", 2, 2);
        bytes.extend_from_slice(&[0u8; 32]);
        let e = parse_npy(&bytes, p).unwrap_err();
        assert!(matches!(e, NpyError::Dtype { ref descr, .. } if descr == "<i8"), "{e}");

        let mut bytes = npy_header("<f8", 3, 2);
        bytes.extend_from_slice(&[0u8; 40]); // 5 values for a 3×2 array
        let e = parse_npy(&bytes, p).unwrap_err();
        assert!(
            matches!(
                e,
                NpyError::DataLength {
                    expected: 48,
                    actual: 40,
                    ..
                }
            ),
            "{e}"
        );

        let dict = "{'descr': '<f8', 'fortran_order': False, 'shape': (2, 2, 2), }\n";
        let mut bytes = b"\x93NUMPY\x01\x00".to_vec();
        bytes.extend_from_slice(&(dict.len() as u16).to_le_bytes());
        bytes.extend_from_slice(dict.as_bytes());
        bytes.extend_from_slice(&[0u8; 64]);
        let e = parse_npy(&bytes, p).unwrap_err();
        assert!(matches!(e, NpyError::Rank { ndim: 3, .. }), "{e}");
    }
}
