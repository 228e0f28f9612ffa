//! Reading the input and parsing it into samples.
//!
//! The format is deliberately loose, to take what loggers write:
//!
//! - one sample per line; `\n` or `\r\n` line ends; a UTF-8 byte-order mark
//!   is ignored, invalid UTF-8 is decoded lossily (and then fails to parse
//!   as a number, naming its line);
//! - blank lines and lines starting with `#` are skipped;
//! - the separator is chosen from the first remaining line: `;` if it holds
//!   one, else `,`, else runs of spaces and tabs. Fields are trimmed and may
//!   be wrapped in double quotes;
//! - that first line is a header when any of its fields is not a number;
//! - without `--columns` the first three fields of each row are x, y, z and
//!   later fields are ignored; with `--columns` the named header fields are
//!   used (case-insensitive), and only they have to be numbers;
//! - for `apply`, accelerometer columns are read the same way, named by
//!   `--accel-columns` or found in the header ([`ACCEL_NAMES`]);
//! - `nan`, `inf`, `-inf` and overflowing literals such as `1e400` are read
//!   as non-finite numbers, which the core skips and counts as dropped.

use std::io::Read;
use std::path::{Path, PathBuf};

use crate::cli::Columns;
use crate::error::CliError;

/// Where the samples come from.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Source {
    /// Standard input (`-` on the command line).
    Stdin,
    /// A file.
    File(PathBuf),
}

impl Source {
    /// `-` means stdin; anything else is a file path.
    pub fn from_arg(path: &Path) -> Self {
        if path.as_os_str() == "-" {
            Source::Stdin
        } else {
            Source::File(path.to_owned())
        }
    }

    /// The name used in messages: the path as given, or `<stdin>`.
    pub fn name(&self) -> String {
        match self {
            Source::Stdin => "<stdin>".to_owned(),
            Source::File(path) => path.display().to_string(),
        }
    }

    /// The name for a title: the file name without its folders, or
    /// `<stdin>`.
    pub fn file_name(&self) -> String {
        match self {
            Source::Stdin => "<stdin>".to_owned(),
            Source::File(path) => path.file_name().map_or_else(
                || path.display().to_string(),
                |n| n.to_string_lossy().into_owned(),
            ),
        }
    }

    /// Reads the whole input as bytes.
    pub fn read(&self) -> Result<Vec<u8>, CliError> {
        let result = match self {
            Source::Stdin => {
                let mut bytes = Vec::new();
                std::io::stdin()
                    .lock()
                    .read_to_end(&mut bytes)
                    .map(|_| bytes)
            }
            Source::File(path) => std::fs::read(path),
        };
        result.map_err(|err| CliError::Read {
            source_name: self.name(),
            err,
        })
    }
}

/// How fields are separated, decided once per input.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Separator {
    /// One character; empty fields count.
    Char(char),
    /// Runs of spaces and tabs.
    Whitespace,
}

impl Separator {
    /// Chooses the separator from the first content line.
    fn detect(line: &str) -> Self {
        if line.contains(';') {
            Separator::Char(';')
        } else if line.contains(',') {
            Separator::Char(',')
        } else {
            Separator::Whitespace
        }
    }

    /// The line's fields, trimmed and unquoted.
    fn fields(self, line: &str) -> Vec<&str> {
        match self {
            Separator::Char(c) => line.split(c).map(unquote).collect(),
            Separator::Whitespace => line.split_whitespace().map(unquote).collect(),
        }
    }
}

/// Trims a field and strips one pair of surrounding double quotes.
fn unquote(field: &str) -> &str {
    let field = field.trim();
    field
        .strip_prefix('"')
        .and_then(|f| f.strip_suffix('"'))
        .map_or(field, str::trim)
}

/// A number, or `None` when the field is not one. `nan`, `inf`, `infinity`
/// (any case, optionally signed) and out-of-range literals are numbers.
fn number(field: &str) -> Option<f64> {
    field.parse::<f64>().ok()
}

/// The content lines: 1-based line number and text, without comments and
/// blank lines.
fn content_lines(text: &str) -> impl Iterator<Item = (usize, &str)> {
    text.split('\n')
        .enumerate()
        .map(|(i, line)| (i + 1, line.strip_suffix('\r').unwrap_or(line)))
        .filter(|(_, line)| {
            let t = line.trim();
            !t.is_empty() && !t.starts_with('#')
        })
}

/// Parses input bytes into `[x, y, z]` samples (see the module docs).
///
/// `source_name` is only used in messages.
pub fn parse(
    bytes: &[u8],
    columns: Option<&Columns>,
    source_name: &str,
) -> Result<Vec<[f64; 3]>, CliError> {
    parse_with_accel(bytes, columns, Accel::None, source_name).map(|table| table.samples)
}

/// Which accelerometer columns to read beside the samples.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Accel<'a> {
    /// None.
    None,
    /// The named header fields (an error when absent).
    Named(&'a Columns),
    /// The first of [`ACCEL_NAMES`] whose three names are all in the header,
    /// if any (and if they are not the sample columns themselves).
    Detect,
}

/// Accelerometer column names recognised by [`Accel::Detect`], compared
/// case-insensitively.
pub const ACCEL_NAMES: [[&str; 3]; 5] = [
    ["accx", "accy", "accz"],
    ["acc_x", "acc_y", "acc_z"],
    ["ax", "ay", "az"],
    ["accelx", "accely", "accelz"],
    ["accel_x", "accel_y", "accel_z"],
];

/// The rows of an input: samples and, when requested and present,
/// accelerometer readings of the same rows.
#[derive(Clone, Debug, PartialEq)]
pub struct Table {
    /// `[x, y, z]` per row.
    pub samples: Vec<[f64; 3]>,
    /// `[ax, ay, az]` per row, when accelerometer columns were found.
    pub accel: Option<Vec<[f64; 3]>>,
}

/// Parses input bytes into samples and, as `accel` asks, accelerometer
/// readings (see the module docs).
pub fn parse_with_accel(
    bytes: &[u8],
    columns: Option<&Columns>,
    accel: Accel<'_>,
    source_name: &str,
) -> Result<Table, CliError> {
    let text = String::from_utf8_lossy(bytes);
    let text = text.strip_prefix('\u{feff}').unwrap_or(&text);
    let mut lines = content_lines(text);
    let Some((first_no, first)) = lines.next() else {
        return Err(CliError::Input(format!("{source_name}: no data rows")));
    };
    let separator = Separator::detect(first);
    let first_fields = separator.fields(first);
    let has_header = first_fields.iter().any(|f| number(f).is_none());
    let header = has_header.then_some(first_fields.as_slice());
    let needs_header = |option: &str| {
        CliError::Input(format!(
            "{source_name}: {option} needs a header line naming the columns, \
             but line {first_no} is data"
        ))
    };

    let indices = match (columns, header) {
        (None, _) => [0, 1, 2],
        (Some(Columns(names)), Some(header)) => named_indices(header, names, source_name)?,
        (Some(_), None) => return Err(needs_header("--columns")),
    };
    let accel_indices = match (accel, header) {
        (Accel::None, _) | (Accel::Detect, None) => None,
        (Accel::Named(Columns(names)), Some(header)) => {
            Some(named_indices(header, names, source_name)?)
        }
        (Accel::Named(_), None) => return Err(needs_header("--accel-columns")),
        (Accel::Detect, Some(header)) => ACCEL_NAMES
            .iter()
            .find_map(|names| named_indices(header, names, source_name).ok())
            .filter(|found| *found != indices),
    };

    let data_first = (!has_header).then_some((first_no, first));
    let mut samples = Vec::new();
    let mut accel_rows = accel_indices.map(|_| Vec::new());
    for (line_no, line) in data_first.into_iter().chain(lines) {
        let fields = separator.fields(line);
        samples.push(parse_row(line_no, &fields, &indices)?);
        if let (Some(rows), Some(accel_indices)) = (accel_rows.as_mut(), accel_indices.as_ref()) {
            rows.push(parse_row(line_no, &fields, accel_indices)?);
        }
    }
    if samples.is_empty() {
        return Err(CliError::Input(format!(
            "{source_name}: no data rows after the header"
        )));
    }
    Ok(Table {
        samples,
        accel: accel_rows,
    })
}

/// The positions of `names` in `header` (case-insensitive).
fn named_indices<S: AsRef<str>>(
    header: &[&str],
    names: &[S; 3],
    source_name: &str,
) -> Result<[usize; 3], CliError> {
    let mut indices = [0; 3];
    for (index, name) in indices.iter_mut().zip(names) {
        let name = name.as_ref();
        *index = header
            .iter()
            .position(|f| f.eq_ignore_ascii_case(name))
            .ok_or_else(|| {
                CliError::Input(format!(
                    "{source_name}: no column named '{}' in the header (columns: {})",
                    excerpt(name),
                    excerpt(&header.join(", "))
                ))
            })?;
    }
    Ok(indices)
}

/// One data row: the fields at `indices`, as numbers.
fn parse_row(line_no: usize, fields: &[&str], indices: &[usize; 3]) -> Result<[f64; 3], CliError> {
    let needed = indices.iter().max().map_or(0, |m| m + 1);
    if fields.len() < needed {
        return Err(CliError::Parse {
            line: line_no,
            message: format!("expected at least {needed} fields, found {}", fields.len()),
        });
    }
    let mut sample = [0.0; 3];
    for (value, &index) in sample.iter_mut().zip(indices) {
        let field = fields[index];
        *value = number(field).ok_or_else(|| CliError::Parse {
            line: line_no,
            message: if field.is_empty() {
                format!("field {} is empty", index + 1)
            } else {
                format!("'{}' is not a number", excerpt(field))
            },
        })?;
    }
    Ok(sample)
}

/// A field for a one-line message: control characters escaped, at most 40
/// characters.
fn excerpt(field: &str) -> String {
    const MAX: usize = 40;
    let mut out: String = field
        .chars()
        .take(MAX)
        .flat_map(char::escape_debug)
        .collect();
    if field.chars().nth(MAX).is_some() {
        out.push_str("...");
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn parse_ok(text: &str) -> Vec<[f64; 3]> {
        parse(text.as_bytes(), None, "t").expect("parses")
    }

    fn cols(x: &str, y: &str, z: &str) -> Columns {
        Columns([x.into(), y.into(), z.into()])
    }

    #[test]
    fn separators() {
        let want = vec![[1.0, 2.0, 3.0], [4.0, -5.0, 6.5]];
        assert_eq!(parse_ok("1,2,3\n4,-5,6.5\n"), want);
        assert_eq!(parse_ok("1, 2, 3\r\n4 ,-5, 6.5"), want);
        assert_eq!(parse_ok("1;2;3\n4;-5;6.5"), want);
        assert_eq!(parse_ok("1\t2\t3\n4\t-5\t6.5"), want);
        assert_eq!(parse_ok("  1   2 3\n4  -5\t\t6.5  "), want);
        assert_eq!(parse_ok("\"1\",\"2\",\"3\"\n4,-5,6.5"), want);
    }

    #[test]
    fn comments_blank_lines_header_and_bom() {
        let text = "\u{feff}# a comment\n\nX,Y,Z\n\n1,2,3\n# another\n4,5,6\n";
        assert_eq!(parse_ok(text), vec![[1.0, 2.0, 3.0], [4.0, 5.0, 6.0]]);
    }

    #[test]
    fn extra_columns_are_ignored_without_columns() {
        assert_eq!(
            parse_ok("1 2 3 4\n4 5 6 7"),
            vec![[1.0, 2.0, 3.0], [4.0, 5.0, 6.0]]
        );
        // Any non-number makes the first line a header, even beyond the
        // first three fields; later rows may hold text there.
        assert_eq!(
            parse_ok("1 2 3 text\n4 5 6 more\n7 8 9 x"),
            vec![[4.0, 5.0, 6.0], [7.0, 8.0, 9.0]]
        );
    }

    #[test]
    fn non_finite_values_are_numbers() {
        let s = parse_ok("nan,inf,-inf\n1e400,NaN,Infinity\n1,2,3");
        assert!(s[0][0].is_nan() && s[0][1] == f64::INFINITY && s[0][2] == f64::NEG_INFINITY);
        assert!(s[1][0].is_infinite() && s[1][1].is_nan() && s[1][2].is_infinite());
        assert_eq!(s[2], [1.0, 2.0, 3.0]);
    }

    #[test]
    fn named_columns() {
        let text = "t,MagX,magy,magz,fix\n0,1,2,3,NoFix\n1,4,5,6,3D\n";
        let c = cols("magx", "magy", "MAGZ");
        let s = parse(text.as_bytes(), Some(&c), "t").expect("parses");
        assert_eq!(s, vec![[1.0, 2.0, 3.0], [4.0, 5.0, 6.0]]);
        let c = cols("magz", "magx", "magy");
        let s = parse(text.as_bytes(), Some(&c), "t").expect("parses");
        assert_eq!(s[0], [3.0, 1.0, 2.0]);
    }

    #[test]
    fn named_columns_errors() {
        let c = cols("a", "b", "q");
        let err = parse(b"a,b,c\n1,2,3\n", Some(&c), "f.csv").unwrap_err();
        assert_eq!(
            err.to_string(),
            "f.csv: no column named 'q' in the header (columns: a, b, c)"
        );
        let err = parse(b"1,2,3\n", Some(&c), "f.csv").unwrap_err();
        assert!(err.to_string().contains("needs a header"), "{err}");
    }

    #[test]
    fn parse_errors_name_the_line() {
        let err = parse(b"x,y,z\n1,2,3\n\n1,abc,3\n", None, "t").unwrap_err();
        assert_eq!(err.to_string(), "line 4: 'abc' is not a number");
        assert_eq!(err.exit_code(), 2);
        let err = parse(b"1,2,3\n1,2\n", None, "t").unwrap_err();
        assert_eq!(
            err.to_string(),
            "line 2: expected at least 3 fields, found 2"
        );
        let err = parse(b"1,2,3\n1,,3\n", None, "t").unwrap_err();
        assert_eq!(err.to_string(), "line 2: field 2 is empty");
    }

    #[test]
    fn hostile_fields_stay_on_one_line() {
        let mut bytes = b"1,2,3\n1,2,".to_vec();
        bytes.extend_from_slice(&[0xff, b'\r', 0x1b, b'x']);
        bytes.extend(std::iter::repeat_n(b'a', 100));
        let err = parse(&bytes, None, "t").unwrap_err().to_string();
        assert!(!err.contains('\r') && !err.contains('\u{1b}'), "{err}");
        assert!(
            err.starts_with("line 2: '\u{fffd}\\r\\u{1b}x")
                && err.ends_with("...' is not a number")
        );
    }

    #[test]
    fn accelerometer_columns() {
        let text = "t,AccX,accy,accz,magx,magy,magz\n0,0.1,0.2,9.8,1,2,3\n1,0,0,9.7,4,5,6\n";
        let c = cols("magx", "magy", "magz");
        let t = parse_with_accel(text.as_bytes(), Some(&c), Accel::Detect, "t").expect("parses");
        assert_eq!(t.samples, vec![[1.0, 2.0, 3.0], [4.0, 5.0, 6.0]]);
        assert_eq!(t.accel, Some(vec![[0.1, 0.2, 9.8], [0.0, 0.0, 9.7]]));
        let a = cols("accz", "accy", "accx");
        let t = parse_with_accel(text.as_bytes(), Some(&c), Accel::Named(&a), "t").expect("parses");
        assert_eq!(t.accel.as_ref().map(|a| a[0]), Some([9.8, 0.2, 0.1]));
        let t = parse_with_accel(text.as_bytes(), Some(&c), Accel::None, "t").expect("parses");
        assert_eq!(t.accel, None);

        // Other spellings; none at all; the sample columns themselves.
        let t = parse_with_accel(b"x,y,z,ax,ay,az\n1,2,3,4,5,6\n", None, Accel::Detect, "t")
            .expect("parses");
        assert_eq!(t.accel, Some(vec![[4.0, 5.0, 6.0]]));
        let t = parse_with_accel(b"x,y,z,ax,ay\n1,2,3,4,5\n", None, Accel::Detect, "t")
            .expect("parses");
        assert_eq!(t.accel, None);
        let t = parse_with_accel(b"acc_x,acc_y,acc_z\n1,2,3\n", None, Accel::Detect, "t")
            .expect("parses");
        assert_eq!(t.accel, None);
        let t = parse_with_accel(b"1,2,3\n", None, Accel::Detect, "t").expect("parses");
        assert_eq!(t.accel, None);

        // Named but absent, or no header: errors.
        let err = parse_with_accel(
            text.as_bytes(),
            Some(&c),
            Accel::Named(&cols("a", "b", "c")),
            "f",
        )
        .unwrap_err();
        assert!(err.to_string().contains("no column named 'a'"), "{err}");
        let err = parse_with_accel(b"1,2,3\n", None, Accel::Named(&a), "f").unwrap_err();
        assert!(
            err.to_string().contains("--accel-columns needs a header"),
            "{err}"
        );
        // Accelerometer fields must be numbers too.
        let err = parse_with_accel(b"x,y,z,ax,ay,az\n1,2,3,4,,6\n", None, Accel::Detect, "f")
            .unwrap_err();
        assert_eq!(err.to_string(), "line 2: field 5 is empty");
    }

    #[test]
    fn empty_inputs() {
        for text in ["", "\n\n", "# only a comment\n", "x,y,z\n"] {
            let err = parse(text.as_bytes(), None, "e.csv").unwrap_err();
            assert!(err.to_string().starts_with("e.csv: no data rows"), "{err}");
        }
    }

    #[test]
    fn stdin_is_a_dash() {
        assert_eq!(Source::from_arg(Path::new("-")), Source::Stdin);
        assert_eq!(Source::Stdin.name(), "<stdin>");
        assert_eq!(Source::from_arg(Path::new("a.csv")).name(), "a.csv");
    }
}
