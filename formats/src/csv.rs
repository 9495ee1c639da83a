//! The recording CSV schema shared by every offline tool (and written by hand by users):
//! a header row; `t_s` (seconds); `n0 .. n{N-1}` (raw readings exactly as the board recorded
//! them: ADC counts, or ohms, up to 32-bit values or decimals, never assumed 0-1023); optional
//! `force_n` (reference force, N), `curvature_m1` (1/m), `temp_c` (degC), `trial` (integer).
//! Other columns are ignored. `.csv` or `.csv.gz` (gzip is detected from its magic bytes).
//! rows x cols comes from the caller or is inferred for a square N.

use std::fmt::Write as _;
use std::fs::File;
use std::io::{BufRead, BufReader, BufWriter, Read, Write};
use std::path::{Path, PathBuf};

/// Why a recording could not be read or written. Every variant names the file; row errors name
/// the line (1 = the header).
#[derive(Debug, thiserror::Error)]
pub enum CsvError {
    #[error("{path}: {error}")]
    Io {
        path: PathBuf,
        error: std::io::Error,
    },
    #[error("{path}:{line}: {error}")]
    IoAt {
        path: PathBuf,
        line: usize,
        error: std::io::Error,
    },
    #[error("{path}: empty file (expected a header row)")]
    Empty { path: PathBuf },
    #[error("{path}:1: {reason}")]
    Header { path: PathBuf, reason: String },
    #[error("{path}:{line}: {reason}")]
    Row {
        path: PathBuf,
        line: usize,
        reason: String,
    },
    #[error("{path}: no data rows after the header")]
    NoRows { path: PathBuf },
    #[error("{path}: {reason}")]
    Geometry { path: PathBuf, reason: String },
}

/// Array geometry of a recording.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Geometry {
    pub rows: usize,
    pub cols: usize,
}

impl Geometry {
    /// Resolves rows x cols for `n` nodes from optional flags: both given must multiply to `n`;
    /// one given derives the other; none given works for a square `n`.
    pub fn resolve(n: usize, rows: Option<usize>, cols: Option<usize>) -> Result<Geometry, String> {
        let g = match (rows, cols) {
            (Some(r), Some(c)) => Geometry { rows: r, cols: c },
            (Some(r), None) if r > 0 && n.is_multiple_of(r) => Geometry {
                rows: r,
                cols: n / r,
            },
            (None, Some(c)) if c > 0 && n.is_multiple_of(c) => Geometry {
                rows: n / c,
                cols: c,
            },
            (None, None) => {
                let s = (n as f64).sqrt().round() as usize;
                if s * s != n {
                    return Err(format!(
                        "cannot infer rows x cols for {n} node columns (not a square): give --rows and --cols"
                    ));
                }
                Geometry { rows: s, cols: s }
            }
            (r, c) => {
                return Err(format!(
                    "--rows {r:?} / --cols {c:?} do not divide the {n} node columns"
                ))
            }
        };
        if g.rows * g.cols != n || g.rows == 0 || g.cols == 0 {
            return Err(format!(
                "{} rows x {} cols does not match the {n} node columns",
                g.rows, g.cols
            ));
        }
        if g.rows > 32 || g.cols > 32 {
            return Err(format!(
                "{} x {} exceeds the largest supported array (32 x 32)",
                g.rows, g.cols
            ));
        }
        Ok(g)
    }
}

/// A recording in memory, column by column.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Recording {
    /// Where it was read from (for messages).
    pub path: PathBuf,
    /// Number of node columns.
    pub n_nodes: usize,
    pub t_s: Vec<f64>,
    /// Readings, sample-major: sample `i`, node `k` at `i * n_nodes + k`.
    pub nodes: Vec<f64>,
    pub force_n: Option<Vec<f64>>,
    pub curvature_m1: Option<Vec<f64>>,
    pub temp_c: Option<Vec<f64>>,
    pub trial: Option<Vec<i64>>,
}

#[derive(Clone, Copy)]
enum Col {
    T,
    Node(usize),
    Force,
    Curv,
    Temp,
    Trial,
    Ignore,
}

impl Recording {
    /// Number of samples (rows).
    pub fn len(&self) -> usize {
        self.t_s.len()
    }
    pub fn is_empty(&self) -> bool {
        self.t_s.is_empty()
    }
    /// The readings of sample `i`.
    pub fn sample(&self, i: usize) -> &[f64] {
        &self.nodes[i * self.n_nodes..(i + 1) * self.n_nodes]
    }

    /// Reads a `.csv` or `.csv.gz` file.
    pub fn read(path: &Path) -> Result<Recording, CsvError> {
        let file = File::open(path).map_err(|source| CsvError::Io {
            path: path.to_path_buf(),
            error: source,
        })?;
        let mut reader = BufReader::with_capacity(1 << 16, file);
        let is_gz = reader
            .fill_buf()
            .map(|b| b.starts_with(&[0x1f, 0x8b]))
            .map_err(|source| CsvError::Io {
                path: path.to_path_buf(),
                error: source,
            })?;
        if is_gz {
            let dec = flate2::bufread::MultiGzDecoder::new(reader);
            Self::parse(path, BufReader::with_capacity(1 << 16, dec))
        } else {
            Self::parse(path, reader)
        }
    }

    /// Parses CSV text from any reader; `path` is only used in messages.
    pub fn parse<R: BufRead>(path: &Path, mut input: R) -> Result<Recording, CsvError> {
        let p = || path.to_path_buf();
        let mut line = String::new();
        let mut line_no = 0usize;
        // Header: the first non-empty line.
        loop {
            line.clear();
            let n = read_line(&mut input, &mut line).map_err(|source| CsvError::IoAt {
                path: p(),
                line: line_no + 1,
                error: source,
            })?;
            if n == 0 {
                return Err(CsvError::Empty { path: p() });
            }
            line_no += 1;
            if !line.trim().is_empty() {
                break;
            }
        }
        let header: Vec<String> = line
            .trim()
            .trim_start_matches('\u{feff}')
            .split(',')
            .map(|s| s.trim().to_string())
            .collect();
        let (cols, have, n_nodes) = header_columns(path, &header)?;
        let mut rec = Recording {
            path: p(),
            n_nodes,
            force_n: have[1].then(Vec::new),
            curvature_m1: have[2].then(Vec::new),
            temp_c: have[3].then(Vec::new),
            trial: have[4].then(Vec::new),
            ..Recording::default()
        };
        let mut row_nodes = vec![0.0; n_nodes];
        loop {
            line.clear();
            let n = read_line(&mut input, &mut line).map_err(|source| CsvError::IoAt {
                path: p(),
                line: line_no + 1,
                error: source,
            })?;
            if n == 0 {
                break;
            }
            line_no += 1;
            let text = line.trim();
            if text.is_empty() {
                continue;
            }
            let (t, f, c, temp, trial) =
                parse_row(text, &cols, &header, &mut row_nodes).map_err(|reason| {
                    CsvError::Row {
                        path: p(),
                        line: line_no,
                        reason,
                    }
                })?;
            rec.t_s.push(t);
            rec.nodes.extend_from_slice(&row_nodes);
            if let Some(v) = rec.force_n.as_mut() {
                v.push(f);
            }
            if let Some(v) = rec.curvature_m1.as_mut() {
                v.push(c);
            }
            if let Some(v) = rec.temp_c.as_mut() {
                v.push(temp);
            }
            if let Some(v) = rec.trial.as_mut() {
                v.push(trial);
            }
        }
        if rec.t_s.is_empty() {
            return Err(CsvError::NoRows { path: p() });
        }
        Ok(rec)
    }

    /// The largest reference force at which a frame counts as unloaded (N): 0.02 N, or 1 % of
    /// the recording's largest force when that is more (a load cell's noise and offset scale
    /// with its range). None without a force column.
    pub fn unloaded_limit_n(&self) -> Option<f64> {
        let f = self.force_n.as_ref()?;
        let max = f.iter().copied().fold(0.0, f64::max);
        Some(0.02f64.max(0.01 * max))
    }

    /// Rows `range` (clamped to the recording) as a recording of their own, with the same
    /// path (for messages) and columns.
    pub fn slice(&self, range: std::ops::Range<usize>) -> Recording {
        let end = range.end.min(self.len());
        let r = range.start.min(end)..end;
        let cut = |v: &Option<Vec<f64>>| v.as_ref().map(|v| v[r.clone()].to_vec());
        Recording {
            path: self.path.clone(),
            n_nodes: self.n_nodes,
            t_s: self.t_s[r.clone()].to_vec(),
            nodes: self.nodes[r.start * self.n_nodes..r.end * self.n_nodes].to_vec(),
            force_n: cut(&self.force_n),
            curvature_m1: cut(&self.curvature_m1),
            temp_c: cut(&self.temp_c),
            trial: self.trial.as_ref().map(|v| v[r.clone()].to_vec()),
        }
    }

    /// rows x cols for this recording (see [`Geometry::resolve`]).
    pub fn geometry(&self, rows: Option<usize>, cols: Option<usize>) -> Result<Geometry, CsvError> {
        Geometry::resolve(self.n_nodes, rows, cols).map_err(|reason| CsvError::Geometry {
            path: self.path.clone(),
            reason,
        })
    }
}

/// Reads one line, refusing absurdly long ones (a binary file fed as CSV) and invalid UTF-8.
fn read_line<R: BufRead>(input: &mut R, line: &mut String) -> std::io::Result<usize> {
    const MAX: u64 = 1 << 20;
    let n = input.by_ref().take(MAX).read_line(line)?;
    if n as u64 == MAX && !line.ends_with('\n') {
        return Err(std::io::Error::new(
            std::io::ErrorKind::InvalidData,
            "line longer than 1 MiB (not a CSV file?)",
        ));
    }
    Ok(n)
}

/// The header's columns: each column's meaning, which of t_s, force_n, curvature_m1, temp_c
/// and trial are present, and the node count (n0..n{N-1} without holes).
fn header_columns(
    path: &Path,
    header: &[String],
) -> Result<(Vec<Col>, [bool; 5], usize), CsvError> {
    let p = || path.to_path_buf();
    let mut cols = Vec::with_capacity(header.len());
    let mut seen_nodes: Vec<Option<usize>> = Vec::new();
    let mut have = [false; 5];
    for (ci, name) in header.iter().enumerate() {
        let col = match name.as_str() {
            "t_s" => Col::T,
            "force_n" => Col::Force,
            "curvature_m1" => Col::Curv,
            "temp_c" => Col::Temp,
            "trial" => Col::Trial,
            s if s.len() > 1
                && s.starts_with('n')
                && s[1..].bytes().all(|b| b.is_ascii_digit()) =>
            {
                let k: usize = s[1..].parse().map_err(|_| CsvError::Header {
                    path: p(),
                    reason: format!("column {}: node index {s:?} is too large", ci + 1),
                })?;
                if k >= 1024 {
                    return Err(CsvError::Header {
                        path: p(),
                        reason: format!("column {}: {s} exceeds the 1024-node limit", ci + 1),
                    });
                }
                if seen_nodes.len() <= k {
                    seen_nodes.resize(k + 1, None);
                }
                if seen_nodes[k].is_some() {
                    return Err(CsvError::Header {
                        path: p(),
                        reason: format!("column {}: {s} appears twice", ci + 1),
                    });
                }
                seen_nodes[k] = Some(ci);
                Col::Node(k)
            }
            _ => Col::Ignore,
        };
        let slot = match col {
            Col::T => Some(0),
            Col::Force => Some(1),
            Col::Curv => Some(2),
            Col::Temp => Some(3),
            Col::Trial => Some(4),
            _ => None,
        };
        if let Some(s) = slot {
            if have[s] {
                return Err(CsvError::Header {
                    path: p(),
                    reason: format!("column {}: {name} appears twice", ci + 1),
                });
            }
            have[s] = true;
        }
        cols.push(col);
    }
    if !have[0] {
        return Err(CsvError::Header {
            path: p(),
            reason: format!("no t_s column (header is {:?})", header.join(",")),
        });
    }
    if seen_nodes.is_empty() {
        return Err(CsvError::Header {
            path: p(),
            reason: "no node columns (expected n0, n1, ...)".into(),
        });
    }
    if let Some(k) = seen_nodes.iter().position(|s| s.is_none()) {
        return Err(CsvError::Header {
            path: p(),
            reason: format!(
                "node columns must be n0..n{} without holes: n{k} is missing",
                seen_nodes.len() - 1
            ),
        });
    }
    Ok((cols, have, seen_nodes.len()))
}

/// One data row: the node readings into `nodes`, and (t_s, force_n, curvature_m1, temp_c,
/// trial), 0 where the column is absent; the error is the reason, without file and line.
fn parse_row(
    text: &str,
    cols: &[Col],
    header: &[String],
    nodes: &mut [f64],
) -> Result<(f64, f64, f64, f64, i64), String> {
    let mut fields = 0usize;
    let (mut t, mut f, mut c, mut temp, mut trial) = (0.0, 0.0, 0.0, 0.0, 0i64);
    for (ci, field) in text.split(',').enumerate() {
        fields += 1;
        let Some(&col) = cols.get(ci) else {
            continue;
        };
        let field = field.trim();
        if matches!(col, Col::Ignore) {
            continue;
        }
        if let Col::Trial = col {
            trial = parse_int(field)
                .ok_or_else(|| format!("column {} (trial): {field:?} is not an integer", ci + 1))?;
            continue;
        }
        let v: f64 = field.parse().map_err(|_| {
            format!(
                "column {} ({}): {field:?} is not a number",
                ci + 1,
                header[ci]
            )
        })?;
        if !v.is_finite() {
            return Err(format!(
                "column {} ({}): {field:?} is not finite",
                ci + 1,
                header[ci]
            ));
        }
        match col {
            Col::T => t = v,
            Col::Node(k) => nodes[k] = v,
            Col::Force => f = v,
            Col::Curv => c = v,
            Col::Temp => temp = v,
            Col::Trial | Col::Ignore => {}
        }
    }
    if fields != cols.len() {
        return Err(format!(
            "{fields} fields, but the header has {}",
            cols.len()
        ));
    }
    Ok((t, f, c, temp, trial))
}

fn parse_int(s: &str) -> Option<i64> {
    if let Ok(v) = s.parse::<i64>() {
        return Some(v);
    }
    // Accept "3.0" as written by tools that store everything as floats.
    let f: f64 = s.parse().ok()?;
    (f.fract() == 0.0 && f.abs() < 9e15).then_some(f as i64)
}

/// Which optional columns a [`RecordingWriter`] writes, plus extra named columns after them.
#[derive(Debug, Clone, Default)]
pub struct Columns {
    pub force_n: bool,
    pub curvature_m1: bool,
    pub temp_c: bool,
    pub trial: bool,
    /// Extra columns (e.g. `est_force_n`), written after the schema columns.
    pub extra: Vec<String>,
}

/// One row for [`RecordingWriter::write_row`].
#[derive(Debug, Clone, Default)]
pub struct Row<'a> {
    pub t_s: f64,
    pub nodes: &'a [f64],
    pub force_n: f64,
    pub curvature_m1: f64,
    pub temp_c: f64,
    pub trial: i64,
    /// Values of the extra columns, in order (NaN writes an empty field).
    pub extra: &'a [f64],
}

/// Writes a recording CSV (gzip-compressed when the path ends in `.gz`).
pub struct RecordingWriter {
    out: Box<dyn Write>,
    path: PathBuf,
    n_nodes: usize,
    columns: Columns,
    line: String,
}

impl RecordingWriter {
    pub fn create(
        path: &Path,
        n_nodes: usize,
        columns: Columns,
    ) -> Result<RecordingWriter, CsvError> {
        let file = File::create(path).map_err(|source| CsvError::Io {
            path: path.to_path_buf(),
            error: source,
        })?;
        let buf = BufWriter::with_capacity(1 << 16, file);
        let out: Box<dyn Write> = if path.extension().is_some_and(|e| e == "gz") {
            Box::new(flate2::write::GzEncoder::new(
                buf,
                flate2::Compression::default(),
            ))
        } else {
            Box::new(buf)
        };
        let mut w = RecordingWriter {
            out,
            path: path.to_path_buf(),
            n_nodes,
            columns,
            line: String::with_capacity(256),
        };
        let mut header = String::from("t_s");
        for k in 0..n_nodes {
            let _ = write!(header, ",n{k}");
        }
        for (on, name) in [
            (w.columns.force_n, "force_n"),
            (w.columns.curvature_m1, "curvature_m1"),
            (w.columns.temp_c, "temp_c"),
            (w.columns.trial, "trial"),
        ] {
            if on {
                header.push(',');
                header.push_str(name);
            }
        }
        for e in &w.columns.extra {
            header.push(',');
            header.push_str(e);
        }
        header.push('\n');
        w.write_str(&header)?;
        Ok(w)
    }

    fn write_str(&mut self, s: &str) -> Result<(), CsvError> {
        self.out
            .write_all(s.as_bytes())
            .map_err(|source| CsvError::Io {
                path: self.path.clone(),
                error: source,
            })
    }

    pub fn write_row(&mut self, row: &Row<'_>) -> Result<(), CsvError> {
        debug_assert_eq!(row.nodes.len(), self.n_nodes);
        let mut l = std::mem::take(&mut self.line);
        l.clear();
        let _ = write!(l, "{}", row.t_s);
        for v in row.nodes {
            let _ = write!(l, ",{v}");
        }
        if self.columns.force_n {
            let _ = write!(l, ",{}", row.force_n);
        }
        if self.columns.curvature_m1 {
            let _ = write!(l, ",{}", row.curvature_m1);
        }
        if self.columns.temp_c {
            let _ = write!(l, ",{}", row.temp_c);
        }
        if self.columns.trial {
            let _ = write!(l, ",{}", row.trial);
        }
        for v in row.extra {
            if v.is_finite() {
                let _ = write!(l, ",{v}");
            } else {
                l.push(',');
            }
        }
        l.push('\n');
        let r = self.write_str(&l);
        self.line = l;
        r
    }

    /// Flushes and closes the file (finishing the gzip stream).
    pub fn finish(mut self) -> Result<(), CsvError> {
        self.out.flush().map_err(|source| CsvError::Io {
            path: self.path.clone(),
            error: source,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn parse(text: &str) -> Result<Recording, CsvError> {
        Recording::parse(Path::new("x.csv"), text.as_bytes())
    }

    #[test]
    fn reads_schema_with_optional_and_extra_columns() {
        let r = parse(
            "t_s,n0,n1,n2,n3,force_n,reading_ohm,trial\n0,100,101,102,103,0.5,1e3,1\n\n0.01,4000000000,1.25,3,4,0,2,2.0\n",
        )
        .expect("parses");
        assert_eq!(r.len(), 2);
        assert_eq!(r.n_nodes, 4);
        assert_eq!(r.sample(1), &[4_000_000_000.0, 1.25, 3.0, 4.0]);
        assert_eq!(r.force_n, Some(vec![0.5, 0.0]));
        assert_eq!(r.trial, Some(vec![1, 2]));
        assert_eq!(r.curvature_m1, None);
        assert_eq!(
            r.geometry(None, None).expect("square"),
            Geometry { rows: 2, cols: 2 }
        );
    }

    #[test]
    fn slice_keeps_rows_and_columns_together() {
        let r = parse("t_s,n0,n1,force_n,trial\n0,1,2,0.5,1\n1,3,4,1.5,1\n2,5,6,2.5,2\n")
            .expect("parses");
        let s = r.slice(1..9);
        assert_eq!(s.len(), 2);
        assert_eq!(s.t_s, vec![1.0, 2.0]);
        assert_eq!(s.sample(0), &[3.0, 4.0]);
        assert_eq!(s.sample(1), &[5.0, 6.0]);
        assert_eq!(s.force_n, Some(vec![1.5, 2.5]));
        assert_eq!(s.trial, Some(vec![1, 2]));
        assert_eq!(s.temp_c, None);
        assert!(r.slice(3..3).is_empty());
    }

    #[test]
    fn single_node_and_geometry_rules() {
        let r = parse("t_s,n0,force_n\n0,19000,0\n1,3,40\n").expect("parses");
        assert_eq!(
            r.geometry(None, None).expect("1x1"),
            Geometry { rows: 1, cols: 1 }
        );
        assert!(Geometry::resolve(6, None, None).is_err());
        assert_eq!(
            Geometry::resolve(6, Some(2), None),
            Ok(Geometry { rows: 2, cols: 3 })
        );
        assert!(Geometry::resolve(6, Some(4), Some(2)).is_err());
        assert!(Geometry::resolve(33 * 33, None, None).is_err());
    }

    #[test]
    fn bad_rows_name_file_and_line() {
        let e = parse("t_s,n0\n0,1\n1,abc\n").expect_err("bad number");
        assert_eq!(
            e.to_string(),
            "x.csv:3: column 2 (n0): \"abc\" is not a number"
        );
        let e = parse("t_s,n0\n0,1\n1,2,3\n").expect_err("extra field");
        assert!(e.to_string().starts_with("x.csv:3: 3 fields"), "{e}");
        let e = parse("t_s,n0\n0,NaN\n").expect_err("nan");
        assert!(e.to_string().contains("x.csv:2"), "{e}");
        let e = parse("t_s,n0,trial\n0,1,1.5\n").expect_err("trial");
        assert!(e.to_string().contains("not an integer"), "{e}");
        assert!(parse("").is_err());
        assert!(parse("t_s,n0\n").is_err());
        assert!(parse("n0,n1\n1,2\n")
            .expect_err("no t")
            .to_string()
            .contains("t_s"));
        assert!(parse("t_s,n0,n2\n0,1,2\n")
            .expect_err("hole")
            .to_string()
            .contains("n1"));
        assert!(parse("t_s,n0,n0\n0,1,2\n").is_err());
    }

    #[test]
    fn binary_garbage_is_an_error_not_a_panic() {
        let garbage: Vec<u8> = (0..5000u32).map(|i| (i * 7919 % 251) as u8).collect();
        assert!(Recording::parse(Path::new("g"), &garbage[..]).is_err());
    }

    #[test]
    fn writer_round_trip_plain_and_gz() {
        let dir = tempfile::tempdir().expect("tempdir");
        for name in ["a.csv", "a.csv.gz"] {
            let path = dir.path().join(name);
            let cols = Columns {
                force_n: true,
                curvature_m1: true,
                trial: true,
                extra: vec!["est_force_n".into()],
                ..Columns::default()
            };
            let mut w = RecordingWriter::create(&path, 2, cols).expect("create");
            for i in 0..100 {
                w.write_row(&Row {
                    t_s: i as f64 * 0.002,
                    nodes: &[100.0 + i as f64, 0.5],
                    force_n: i as f64 / 10.0,
                    curvature_m1: 40.0,
                    trial: i / 50,
                    extra: &[f64::NAN],
                    ..Row::default()
                })
                .expect("row");
            }
            w.finish().expect("finish");
            let r = Recording::read(&path).expect("reads back");
            assert_eq!(r.len(), 100);
            assert_eq!(r.sample(99), &[199.0, 0.5]);
            assert_eq!(r.force_n.as_ref().map(|f| f[99]), Some(9.9));
            assert_eq!(r.trial.as_ref().map(|t| t[99]), Some(1));
        }
    }

    #[test]
    fn truncated_gzip_is_reported_with_the_file() {
        let dir = tempfile::tempdir().expect("tempdir");
        let path = dir.path().join("t.csv.gz");
        let mut w = RecordingWriter::create(&path, 1, Columns::default()).expect("create");
        for i in 0..20000 {
            w.write_row(&Row {
                t_s: i as f64,
                nodes: &[i as f64],
                ..Row::default()
            })
            .expect("row");
        }
        w.finish().expect("finish");
        let bytes = std::fs::read(&path).expect("read");
        std::fs::write(&path, &bytes[..bytes.len() / 2]).expect("cut");
        let e = Recording::read(&path).expect_err("truncated");
        assert!(e.to_string().contains("t.csv.gz"), "{e}");
    }

    #[test]
    fn reads_the_shared_real_recordings_when_present() {
        let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../shared/data/real");
        let Ok(entries) = std::fs::read_dir(&dir) else {
            eprintln!("skipping: {} is absent", dir.display());
            return;
        };
        let mut n = 0;
        for e in entries.flatten() {
            let p = e.path();
            if p.to_string_lossy().ends_with(".csv.gz") {
                let r = Recording::read(&p).expect("real recording parses");
                assert_eq!(r.n_nodes, 1);
                assert!(r.force_n.is_some());
                assert!(r.nodes.iter().all(|v| *v >= 0.0 && v.fract() == 0.0));
                n += 1;
            }
        }
        assert!(n >= 14, "expected the 14 fixtures, read {n}");
    }
}
