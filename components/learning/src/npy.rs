//! NumPy `.npy` files through the `npyz` crate: real robots' logs often come as `np.save`
//! arrays. What datasets need: 1-D or 2-D arrays of `float32` / `float64` (either byte order,
//! C or Fortran order), returned as row-major `f64`, with errors that name the file and what
//! is wrong; and `float32` / `float64` files written as `np.save` writes them.

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
    #[error("{path}: malformed header: {what}")]
    Header { path: PathBuf, what: String },
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
    if !bytes.starts_with(b"\x93NUMPY") {
        return Err(NpyError::BadMagic { path: p() });
    }
    // The header first, so that what follows it is the payload whose length can be checked
    // (npyz reads as many values as the shape says and would ignore trailing bytes).
    let mut payload: &[u8] = bytes;
    let header = npyz::NpyHeader::from_reader(&mut payload).map_err(|e| NpyError::Header {
        path: p(),
        what: e.to_string(),
    })?;
    let descr = match header.dtype() {
        npyz::DType::Plain(ts) => ts.to_string(),
        other => format!("{other:?}"),
    };
    let width = match descr.trim_start_matches(['<', '>', '=', '|']) {
        "f4" => 4,
        "f8" => 8,
        _ => return Err(NpyError::Dtype { path: p(), descr }),
    };
    let shape: Vec<usize> = header.shape().iter().map(|&d| d as usize).collect();
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
    let overflow = || NpyError::Header {
        path: p(),
        what: format!("shape {shape:?} overflows"),
    };
    let count = rows.checked_mul(cols).ok_or_else(overflow)?;
    let expected = count.checked_mul(width).ok_or_else(overflow)?;
    if payload.len() != expected {
        return Err(NpyError::DataLength {
            path: p(),
            shape,
            expected,
            actual: payload.len(),
        });
    }
    let fortran = header.order() == npyz::Order::Fortran;
    let npy = npyz::NpyFile::with_header(header, payload);
    let read_err = |e: std::io::Error| NpyError::Header {
        path: p(),
        what: e.to_string(),
    };
    // npyz reads either byte order as the dtype says.
    let flat: Vec<f64> = if width == 4 {
        npy.into_vec::<f32>()
            .map_err(read_err)?
            .into_iter()
            .map(f64::from)
            .collect()
    } else {
        npy.into_vec::<f64>().map_err(read_err)?
    };
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

/// Writes a row-major 2-D array as an `.npy` (little-endian, C order), as `np.save` would.
fn write_npy<T: npyz::Serialize + npyz::AutoSerialize + Copy>(
    path: &Path,
    rows: usize,
    cols: usize,
    data: &[T],
) -> std::io::Result<()> {
    if data.len() != rows * cols {
        return Err(std::io::Error::new(
            std::io::ErrorKind::InvalidInput,
            format!("{}: {} values for a {rows}×{cols} array", path.display(), data.len()),
        ));
    }
    use npyz::WriterBuilder;
    let mut out = std::io::BufWriter::new(std::fs::File::create(path)?);
    let mut w = npyz::WriteOptions::new()
        .default_dtype()
        .shape(&[rows as u64, cols as u64])
        .writer(&mut out)
        .begin_nd()?;
    w.extend(data.iter().copied())?;
    w.finish()?;
    std::io::Write::flush(&mut out)
}

/// Writes a row-major 2-D `float64` array as an `.npy`.
pub fn write_npy_f64(path: &Path, rows: usize, cols: usize, data: &[f64]) -> std::io::Result<()> {
    write_npy(path, rows, cols, data)
}

/// Writes a row-major 2-D `float32` array as an `.npy`.
pub fn write_npy_f32(path: &Path, rows: usize, cols: usize, data: &[f32]) -> std::io::Result<()> {
    write_npy(path, rows, cols, data)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A version 1.0 header by hand, for files npyz would not write (other dtypes, bad lengths).
    fn npy_header(descr: &str, rows: usize, cols: usize) -> Vec<u8> {
        let mut dict = format!("{{'descr': '{descr}', 'fortran_order': False, 'shape': ({rows}, {cols}), }}");
        let unpadded = 10 + dict.len() + 1;
        dict.push_str(&" ".repeat((64 - unpadded % 64) % 64));
        dict.push('\n');
        let mut out = b"\x93NUMPY\x01\x00".to_vec();
        out.extend_from_slice(&(dict.len() as u16).to_le_bytes());
        out.extend_from_slice(dict.as_bytes());
        out
    }

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
