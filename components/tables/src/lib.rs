//! bowden's tabular files, read and written with well-kept crates: CSV tables with named
//! columns through the `csv` crate ([`Table`], [`TableWriter`]).
//!
//! Every CSV that bowden reads goes through [`Table`]: a log imported as a dataset, a dataset
//! written by `collect`, target and command files, the adaptation state. It is RFC 4180 as the
//! `csv` crate reads it — quoted fields may hold commas, quotes and line breaks — plus what
//! logs from real rigs carry: a UTF-8 byte-order mark, CRLF line ends, blank lines and (where
//! the caller allows them) `#` comment lines, spaces around fields. A row with another number of
//! fields than the header, a missing column or a field that is not a number is refused with
//! `file:line:column` (1-based; the column also by name).

use std::fmt;
use std::path::{Path, PathBuf};

/// Where in a file something is wrong: `path:line[:column]`, the column 1-based and named when
/// the header names it.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Location {
    pub path: PathBuf,
    /// 1-based line of the file (of the record's first line for a quoted multi-line field).
    pub line: u64,
    /// 1-based field index and the header's name of it.
    pub column: Option<(usize, String)>,
}

impl fmt::Display for Location {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}:{}", self.path.display(), self.line)?;
        if let Some((k, name)) = &self.column {
            if name.is_empty() {
                write!(f, ":{k}")?;
            } else {
                write!(f, ":{k} ({name})")?;
            }
        }
        Ok(())
    }
}

/// What can be wrong with a CSV table. Every variant says where.
#[derive(Debug, thiserror::Error)]
pub enum TableError {
    #[error("{path}: cannot read: {source}")]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("{at}: {what}")]
    Malformed { at: Location, what: String },
    #[error("{path}: no column {column:?} (the header has: {available})")]
    MissingColumn {
        path: PathBuf,
        column: String,
        available: String,
    },
    #[error("{at}: not a number: {value:?}")]
    NotANumber { at: Location, value: String },
    #[error("{at}: not a finite number: {value:?}")]
    NotFinite { at: Location, value: String },
    #[error("{path}: {what}")]
    Empty { path: PathBuf, what: String },
}

impl TableError {
    /// The file the error is about.
    pub fn path(&self) -> &Path {
        match self {
            TableError::Io { path, .. } | TableError::MissingColumn { path, .. } | TableError::Empty { path, .. } => {
                path
            }
            TableError::Malformed { at, .. } | TableError::NotANumber { at, .. } | TableError::NotFinite { at, .. } => {
                &at.path
            }
        }
    }
}

/// How a file is read.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ReadOptions {
    /// The first record names the columns (else columns are only known by index).
    pub header: bool,
    /// Lines starting with `#` are comments.
    pub comments: bool,
    /// Column names compare ignoring ASCII case (`Q1` is `q1`).
    pub ignore_case: bool,
}

impl Default for ReadOptions {
    fn default() -> Self {
        Self {
            header: true,
            comments: false,
            ignore_case: false,
        }
    }
}

/// One row: its 1-based line in the file and its fields (trimmed).
#[derive(Debug, Clone, PartialEq)]
pub struct Row {
    pub line: u64,
    pub fields: Vec<String>,
}

/// A whole CSV file: its header (empty without one) and rows, each row as many fields as the
/// header (or as the first row without a header).
#[derive(Debug, Clone, PartialEq)]
pub struct Table {
    pub path: PathBuf,
    pub header: Vec<String>,
    pub rows: Vec<Row>,
    ignore_case: bool,
}

impl Table {
    /// Reads and parses `path`.
    pub fn read(path: &Path, opts: ReadOptions) -> Result<Table, TableError> {
        let bytes = std::fs::read(path).map_err(|source| TableError::Io {
            path: path.to_path_buf(),
            source,
        })?;
        Table::parse(&bytes, path, opts)
    }

    /// Parses CSV bytes; `path` names them in errors.
    pub fn parse(bytes: &[u8], path: &Path, opts: ReadOptions) -> Result<Table, TableError> {
        let bytes = bytes.strip_prefix("\u{feff}".as_bytes()).unwrap_or(bytes);
        let mut reader = csv::ReaderBuilder::new()
            .has_headers(false)
            // Field counts are checked here, to say which line and what the header has.
            .flexible(true)
            .trim(csv::Trim::All)
            .comment(opts.comments.then_some(b'#'))
            .from_reader(bytes);
        // csv's own line count lags by one after a CRLF (a record then starts at the line
        // feed), so lines are counted here from each record's byte offset.
        let mut lines = LineCounter::new(bytes, opts.comments);
        let mut header: Option<Vec<String>> = None;
        let mut width = None;
        let mut rows = Vec::new();
        let mut record = csv::StringRecord::new();
        loop {
            let more = reader
                .read_record(&mut record)
                .map_err(|e| csv_error(path, &e, &mut lines))?;
            if !more {
                break;
            }
            let line = record.position().map_or(0, |p| lines.line_at(p.byte()));
            // A line of spaces is a blank line, as in every spreadsheet's export.
            if record.iter().all(str::is_empty) {
                continue;
            }
            let fields: Vec<String> = record.iter().map(unquote).collect();
            if opts.header && header.is_none() {
                for (i, h) in fields.iter().enumerate() {
                    if fields[..i].iter().any(|e| same_name(e, h, opts.ignore_case)) {
                        return Err(TableError::Malformed {
                            at: Location {
                                path: path.to_path_buf(),
                                line,
                                column: Some((i + 1, h.clone())),
                            },
                            what: format!("column {h:?} appears twice in the header"),
                        });
                    }
                }
                width = Some(fields.len());
                header = Some(fields);
                continue;
            }
            let expected = *width.get_or_insert(fields.len());
            if fields.len() != expected {
                return Err(TableError::Malformed {
                    at: Location {
                        path: path.to_path_buf(),
                        line,
                        column: None,
                    },
                    what: format!(
                        "{} fields, {} {expected}",
                        fields.len(),
                        if opts.header {
                            "the header has"
                        } else {
                            "the first row has"
                        }
                    ),
                });
            }
            rows.push(Row { line, fields });
        }
        if opts.header && header.is_none() {
            return Err(TableError::Empty {
                path: path.to_path_buf(),
                what: "empty file (no header)".into(),
            });
        }
        Ok(Table {
            path: path.to_path_buf(),
            header: header.unwrap_or_default(),
            rows,
            ignore_case: opts.ignore_case,
        })
    }

    /// The index of column `name`, if the header has it.
    pub fn find(&self, name: &str) -> Option<usize> {
        self.header.iter().position(|h| same_name(h, name, self.ignore_case))
    }

    /// The index of column `name`; an error listing the header when it has none.
    pub fn column(&self, name: &str) -> Result<usize, TableError> {
        self.find(name).ok_or_else(|| TableError::MissingColumn {
            path: self.path.clone(),
            column: name.to_string(),
            available: self.header.join(","),
        })
    }

    /// The indices of `names`, in their order.
    pub fn columns<S: AsRef<str>>(&self, names: &[S]) -> Result<Vec<usize>, TableError> {
        names.iter().map(|n| self.column(n.as_ref())).collect()
    }

    /// Columns `<prefix><k>` for k = 1, 2, … while the header has them (contiguous from 1).
    pub fn numbered(&self, prefix: &str) -> Vec<String> {
        (1..)
            .map(|k| format!("{prefix}{k}"))
            .take_while(|n| self.find(n).is_some())
            .collect()
    }

    /// Where field `col` of row `row` is.
    pub fn at(&self, row: usize, col: usize) -> Location {
        Location {
            path: self.path.clone(),
            line: self.rows[row].line,
            column: Some((col + 1, self.header.get(col).cloned().unwrap_or_default())),
        }
    }

    /// The field text.
    pub fn text(&self, row: usize, col: usize) -> &str {
        &self.rows[row].fields[col]
    }

    /// The field as an `f64`; an empty field and `nan` (any case) read as NaN, so a log's
    /// missing measurement stays a (marked) hole rather than an error.
    pub fn f64_or_nan(&self, row: usize, col: usize) -> Result<f64, TableError> {
        let s = self.text(row, col);
        if s.is_empty() || s.eq_ignore_ascii_case("nan") {
            return Ok(f64::NAN);
        }
        s.parse::<f64>().map_err(|_| TableError::NotANumber {
            at: self.at(row, col),
            value: s.to_string(),
        })
    }

    /// The field as a finite `f64`.
    pub fn finite(&self, row: usize, col: usize) -> Result<f64, TableError> {
        let s = self.text(row, col);
        match s.parse::<f64>() {
            Ok(v) if v.is_finite() => Ok(v),
            Ok(_) => Err(TableError::NotFinite {
                at: self.at(row, col),
                value: s.to_string(),
            }),
            Err(_) => Err(TableError::NotANumber {
                at: self.at(row, col),
                value: s.to_string(),
            }),
        }
    }

    /// The field as an integer.
    pub fn i64(&self, row: usize, col: usize) -> Result<i64, TableError> {
        let s = self.text(row, col);
        s.parse::<i64>().map_err(|_| TableError::NotANumber {
            at: self.at(row, col),
            value: s.to_string(),
        })
    }

    /// Every row's `cols` as finite numbers: the typed joint table (one `Vec` per row, in the
    /// order of `cols`).
    pub fn finite_rows(&self, cols: &[usize]) -> Result<Vec<Vec<f64>>, TableError> {
        (0..self.rows.len())
            .map(|r| cols.iter().map(|&c| self.finite(r, c)).collect())
            .collect()
    }

    /// An error when the table has no rows.
    pub fn require_rows(&self, what: &str) -> Result<(), TableError> {
        if self.rows.is_empty() {
            return Err(TableError::Empty {
                path: self.path.clone(),
                what: format!("no {what}"),
            });
        }
        Ok(())
    }
}

/// A field as trimmed; one that still reads `"..."` was quoted after a space (`1, "b"`, which
/// RFC 4180 does not allow but exporters write): its quotes are taken off as a reader of the
/// strict form would have.
fn unquote(field: &str) -> String {
    match field.strip_prefix('"').and_then(|f| f.strip_suffix('"')) {
        Some(inner) => inner.replace("\"\"", "\""),
        None => field.to_string(),
    }
}

fn same_name(a: &str, b: &str, ignore_case: bool) -> bool {
    if ignore_case {
        a.eq_ignore_ascii_case(b)
    } else {
        a == b
    }
}

/// 1-based line numbers of byte offsets, asked in increasing order.
struct LineCounter<'a> {
    bytes: &'a [u8],
    /// `#` starts a comment line (which csv skips, but counts into the next record's start).
    comments: bool,
    scanned: usize,
    newlines: u64,
}

impl<'a> LineCounter<'a> {
    fn new(bytes: &'a [u8], comments: bool) -> Self {
        Self {
            bytes,
            comments,
            scanned: 0,
            newlines: 0,
        }
    }

    /// The line of the first byte at or after `offset` that is neither a line end nor in a
    /// comment line.
    fn line_at(&mut self, offset: u64) -> u64 {
        let b = self.bytes;
        let mut start = (offset as usize).min(b.len());
        loop {
            while start < b.len() && matches!(b[start], b'\n' | b'\r') {
                start += 1;
            }
            if self.comments && start < b.len() && b[start] == b'#' {
                start += b[start..].iter().position(|&c| c == b'\n').unwrap_or(b.len() - start);
                continue;
            }
            break;
        }
        if start < self.scanned {
            // Not in order (an error's position): count from the beginning.
            return 1 + self.bytes[..start].iter().filter(|&&b| b == b'\n').count() as u64;
        }
        self.newlines += self.bytes[self.scanned..start].iter().filter(|&&b| b == b'\n').count() as u64;
        self.scanned = start;
        1 + self.newlines
    }
}

fn csv_error(path: &Path, e: &csv::Error, lines: &mut LineCounter<'_>) -> TableError {
    let line = e.position().map_or(0, |p| lines.line_at(p.byte()));
    let what = match e.kind() {
        csv::ErrorKind::Utf8 { err, .. } => format!("field {} is not UTF-8", err.field() + 1),
        csv::ErrorKind::Io(io) => format!("cannot read: {io}"),
        _ => e.to_string(),
    };
    TableError::Malformed {
        at: Location {
            path: path.to_path_buf(),
            line,
            column: None,
        },
        what,
    }
}

/// Writes a CSV table: a header, then rows of fields, `\n` line ends, a field quoted only when
/// it must be (a comma, quote or line break in it) — what pandas and spreadsheets read back.
pub struct TableWriter {
    inner: csv::Writer<Vec<u8>>,
}

impl TableWriter {
    /// A table with these column names.
    pub fn new<S: AsRef<str>>(header: &[S]) -> Self {
        let mut inner = csv::WriterBuilder::new()
            .terminator(csv::Terminator::Any(b'\n'))
            .from_writer(Vec::new());
        // Writing into a Vec cannot fail.
        inner
            .write_record(header.iter().map(|h| h.as_ref()))
            .expect("in-memory CSV");
        Self { inner }
    }

    /// One row of already formatted fields.
    ///
    /// # Panics
    /// When the row has another number of fields than the header: the caller builds both, so
    /// that is a bug in the caller, never bad input.
    pub fn row<I, S>(&mut self, fields: I)
    where
        I: IntoIterator<Item = S>,
        S: AsRef<[u8]>,
    {
        self.inner.write_record(fields).expect("in-memory CSV");
    }

    /// The CSV bytes.
    pub fn into_bytes(self) -> Vec<u8> {
        self.inner.into_inner().expect("in-memory CSV")
    }

    /// The CSV text.
    pub fn into_string(self) -> String {
        String::from_utf8(self.into_bytes()).expect("fields are UTF-8")
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn parse(text: &str, opts: ReadOptions) -> Result<Table, TableError> {
        Table::parse(text.as_bytes(), Path::new("log.csv"), opts)
    }

    #[test]
    fn quoted_commas_bom_crlf_blank_lines_and_spaces() {
        let text = "\u{feff}\"t, ns\",q1 , \"q2\"\r\n\r\n  \r\n1, 2.5 ,\"3\"\r\n\"4,5\",6,7\r\n";
        let t = parse(text, ReadOptions::default()).unwrap();
        assert_eq!(t.header, ["t, ns", "q1", "q2"]);
        assert_eq!(t.rows.len(), 2);
        assert_eq!(t.rows[0].fields, ["1", "2.5", "3"]);
        assert_eq!(t.rows[0].line, 4);
        assert_eq!(t.text(1, 0), "4,5");
        assert_eq!(t.column("q2").unwrap(), 2);
        assert_eq!(t.finite(0, 1).unwrap(), 2.5);
    }

    #[test]
    fn comments_and_case_only_when_asked() {
        let text = "# exported by the rig\nQ1,Q2\n# a note\n1,2\n";
        let t = parse(
            text,
            ReadOptions {
                comments: true,
                ignore_case: true,
                ..Default::default()
            },
        )
        .unwrap();
        assert_eq!(t.columns(&["q1", "q2"]).unwrap(), [0, 1]);
        assert_eq!(t.rows[0].line, 4, "the line of the row, past the comment before it");
        let crlf = parse(
            &text.replace('\n', "\r\n"),
            ReadOptions {
                comments: true,
                ..Default::default()
            },
        )
        .unwrap();
        assert_eq!(crlf.rows[0].line, 4);
        assert_eq!(t.finite_rows(&[1, 0]).unwrap(), vec![vec![2.0, 1.0]]);
        let strict = parse(text, ReadOptions::default());
        assert!(strict.is_err(), "a `#` line is data without `comments`");
    }

    #[test]
    fn errors_say_file_line_and_column() {
        let e = parse("q1,q2\n1,2\n3\n", ReadOptions::default()).unwrap_err();
        assert_eq!(e.to_string(), "log.csv:3: 1 fields, the header has 2");
        let t = parse("q1,q2\n1,2\n3,x\n", ReadOptions::default()).unwrap();
        let e = t.finite_rows(&[0, 1]).unwrap_err();
        assert_eq!(e.to_string(), "log.csv:3:2 (q2): not a number: \"x\"");
        let t = parse("q1,q2\n1,inf\n", ReadOptions::default()).unwrap();
        assert_eq!(
            t.finite(0, 1).unwrap_err().to_string(),
            "log.csv:2:2 (q2): not a finite number: \"inf\""
        );
        let e = t.column("q3").unwrap_err();
        assert_eq!(e.to_string(), "log.csv: no column \"q3\" (the header has: q1,q2)");
        let e = parse("a,b,a\n", ReadOptions::default()).unwrap_err();
        assert_eq!(
            e.to_string(),
            "log.csv:1:3 (a): column \"a\" appears twice in the header"
        );
        let e = parse("", ReadOptions::default()).unwrap_err();
        assert_eq!(e.to_string(), "log.csv: empty file (no header)");
        let e = parse("q1\n\"unterminated\n", ReadOptions::default());
        // An unterminated quote runs to the end of the file: one field, read as such.
        assert!(e.is_ok());
        let e = Table::parse(b"q1\n\xff\n", Path::new("log.csv"), ReadOptions::default()).unwrap_err();
        assert!(e.to_string().starts_with("log.csv:2: "), "{e}");
    }

    #[test]
    fn nan_and_empty_read_as_holes_where_asked() {
        let t = parse("q1,q2,q3\nNaN,,nan\n", ReadOptions::default()).unwrap();
        for c in 0..3 {
            assert!(t.f64_or_nan(0, c).unwrap().is_nan());
            assert!(t.finite(0, c).is_err());
        }
    }

    #[test]
    fn without_a_header_rows_agree_with_the_first() {
        let opts = ReadOptions {
            header: false,
            ..Default::default()
        };
        let t = parse("1,2\n3,4\n", opts).unwrap();
        assert!(t.header.is_empty());
        assert_eq!(t.rows.len(), 2);
        let e = parse("1,2\n3\n", opts).unwrap_err();
        assert_eq!(e.to_string(), "log.csv:2: 1 fields, the first row has 2");
    }

    #[test]
    fn written_tables_read_back() {
        let mut w = TableWriter::new(&["t_ns", "note", "q1"]);
        w.row(["1", "plain", "0.5"]);
        w.row(["2", "a, \"quoted\" one", "-1e-9"]);
        let text = w.into_string();
        assert_eq!(text, "t_ns,note,q1\n1,plain,0.5\n2,\"a, \"\"quoted\"\" one\",-1e-9\n");
        let t = parse(&text, ReadOptions::default()).unwrap();
        assert_eq!(t.text(1, 1), "a, \"quoted\" one");
        assert_eq!(t.finite(1, 2).unwrap(), -1e-9);
    }
}
