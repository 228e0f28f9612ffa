//! Reading the input and parsing it into samples.
//!
//! The format is deliberately loose, to take what loggers write. One
//! detection step on the first content lines picks one of three readers:
//! a MotionCal log, labelled values, or a table; then every line is read
//! by that reader.
//!
//! - one sample per line; `\n`, `\r\n` or `\r` line ends; a UTF-8 byte-order mark
//!   is ignored, invalid UTF-8 is decoded lossily (and then fails to parse
//!   as a number, naming its line);
//! - blank lines and lines starting with `#` are skipped;
//! - a MotionCal log (one of the first ten content lines starts with
//!   `Raw:`, after a sketch's banner, say: the
//!   serial output of PJRC's and Adafruit's calibration sketches,
//!   `Raw:ax,ay,az,gx,gy,gz,mx,my,mz` in integers, the magnetometer at 10
//!   per uT) gives x, y, z from fields 7-9 of its `Raw:` lines and the
//!   accelerometer from fields 1-3; its other lines (`Uni:`, `Cal1:`, ...)
//!   are skipped, and a `Raw:` line that is cut short or garbled (a serial
//!   line caught mid-way) becomes a non-finite row, which the fit drops and
//!   counts;
//! - labelled values (one of the first [`SNIFF_LINES`] content lines holds
//!   an x, y, z named by labels: `Mx 19 My -129 Mz 174`, `Mag X: 12.3 Y:
//!   -4.5 Z: 6.7 uT`, `ax=.. mx=.. my=.. mz=..`, `Acc: 1 2 3 Mag: 4 5 6`,
//!   SparkFun's `Mag (uT) [ 4, 5, 6 ]`): the magnetometer's values are
//!   found by label or unit ([`labelled`] says how, and how `--columns`
//!   names labels); lines without them (a banner, other sensors' lines)
//!   are skipped and counted, a line with some of them (cut short) is a
//!   non-finite row; no magnetometer reading among several, or several, is
//!   an error (exit 2) that lists the readings found and how to pick one;
//! - otherwise a table. Its first data line is found among the first
//!   [`SNIFF_LINES`] lines with at least three numeric fields, each split
//!   at its own separator: `;` if it holds one, else `,`, else runs of
//!   spaces and tabs. Fields are trimmed and may be wrapped in double
//!   quotes. It is the first such line that begins a run of [`DATA_RUN`]
//!   lines of its shape (as many fields, as many of them numbers), or of
//!   as many as the file has (else the first that begins the longest
//!   run), or an earlier line of that shape; so a metadata line of three
//!   numbers (`Start,2024,05,12`) is not data. The header is the last line
//!   before it with at least three fields, one of them not a number, and
//!   fewer than three numbers; lines before the header (or before the
//!   data, without one) are metadata (`Fs,50.00`), skipped and counted.
//!   Without such a data line, the first line is the header when any of
//!   its fields is not a number;
//! - `--columns` gives x, y, z by header name (case-insensitive) or by
//!   1-based field number (`--columns 7,8,9`, with or without a header), and
//!   only those fields have to be numbers;
//! - without `--columns`, the number of numeric fields in the first data
//!   row decides:
//!   - at most three: the first three fields of each row are x, y, z and
//!     later fields are ignored;
//!   - more than three: the header must name exactly one triple of raw
//!     magnetometer columns ([`mag_axis`]: `magx`, `mag_x`, `MagX`, `mx`,
//!     `m_x`, `mag.x`, `mag_x_raw`, `raw_mag_x`, `magnetometer_x`,
//!     `compass_x`, `HX(uT)`, bare `x`, ...; never a name containing `cal`),
//!     and those are x, y, z. None, several, or no header at all is an
//!     error (exit 2) that lists the header's columns and asks for
//!     `--columns` (names, or field numbers): taking the first three of
//!     many columns silently calibrated the wrong ones (the accelerometer,
//!     in `imu_gnss_1252.csv`);
//! - [`Table::columns`] says which of these rules picked the columns;
//! - for `apply`, accelerometer columns are named (or numbered) by
//!   `--accel-columns` or found in the header by their exact names
//!   ([`ACCEL_NAMES`]; in labelled lines, values so named on the
//!   magnetometer's line);
//! - `nan`, `inf`, `-inf` and overflowing literals such as `1e400` are read
//!   as non-finite numbers, which the core skips and counts as dropped;
//!   finite but absurd values such as `1e308` are passed to the core as
//!   they are (what to do with them is the core's decision, not the
//!   parser's);
//! - a data line that cannot be read (a field that is not a number, too
//!   few fields: a serial line caught mid-way, a logger's message) is kept
//!   as a non-finite row, which the fit drops and counts, and a later copy
//!   of the header line (logs appended to one another) is skipped; both
//!   are counted and the first few named ([`Skipped`]). Only an input with
//!   no readable data line is an error, naming the first line that failed.

use std::fmt;
use std::io::Read;
use std::path::{Path, PathBuf};

use crate::cli::Columns;
use crate::error::CliError;

pub mod labelled;

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
/// blank lines. Lines end at `\n`, `\r\n` or a lone `\r` (a serial
/// terminal's log).
fn content_lines(text: &str) -> impl Iterator<Item = (usize, &str)> {
    text.split('\n')
        .flat_map(|line| line.strip_suffix('\r').unwrap_or(line).split('\r'))
        .enumerate()
        .map(|(i, line)| (i + 1, line))
        .filter(|(_, line)| {
            let t = line.trim();
            !t.is_empty() && !t.starts_with('#')
        })
}

/// Parses input bytes into `[x, y, z]` samples (see the module docs), and
/// says which columns they came from.
///
/// `source_name` is only used in messages.
pub fn parse(
    bytes: &[u8],
    columns: Option<&Columns>,
    source_name: &str,
) -> Result<Table, CliError> {
    parse_with_accel(bytes, columns, Accel::None, source_name)
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
    /// Where the samples came from.
    pub columns: ColumnsUsed,
    /// Lines that were neither samples nor comments.
    pub skipped: Skipped,
}

/// Lines of an input that were neither samples nor comments nor blank:
/// data lines that could not be read, each kept as a non-finite row (the
/// fit drops and counts it; `apply` keeps the row order), copies of the
/// header line after the first, skipped, and lines without a magnetometer
/// reading, skipped.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct Skipped {
    /// Data lines that could not be read.
    pub unreadable: usize,
    /// Copies of the header line after the first.
    pub header_copies: usize,
    /// Lines without a magnetometer reading: metadata before the header
    /// (`Fs,50.00`), a sketch's banner and other sensors' lines in a
    /// labelled log (`Accel X: 0.1 Y: 0.2 Z: 9.8 m/s^2`).
    pub no_reading: usize,
    /// The first [`Skipped::EXAMPLES`] of them, e.g. `line 104: 'abc' is
    /// not a number`.
    pub examples: Vec<String>,
}

impl Skipped {
    /// How many lines [`Skipped::examples`] names at most.
    pub const EXAMPLES: usize = 3;

    /// Whether every line was a sample, a comment or blank.
    pub fn is_empty(&self) -> bool {
        self.unreadable == 0 && self.header_copies == 0 && self.no_reading == 0
    }

    /// One line for a report, e.g. `2 unreadable lines kept as non-finite
    /// rows (dropped), 1 copy of the header skipped, 2 lines without a
    /// magnetometer reading skipped: line 1: 'Fs,50.00'; line 2:
    /// 'Initialization time,60'; line 74: a copy of the header; ...`; `None`
    /// when [`Skipped::is_empty`].
    pub fn note(&self) -> Option<String> {
        if self.is_empty() {
            return None;
        }
        let plural =
            |n: usize, one: &str, many: &str| format!("{n} {}", if n == 1 { one } else { many });
        let mut parts = Vec::new();
        if self.unreadable > 0 {
            parts.push(plural(
                self.unreadable,
                "unreadable line kept as a non-finite row (dropped)",
                "unreadable lines kept as non-finite rows (dropped)",
            ));
        }
        if self.header_copies > 0 {
            parts.push(format!(
                "{} skipped",
                plural(
                    self.header_copies,
                    "copy of the header",
                    "copies of the header"
                )
            ));
        }
        if self.no_reading > 0 {
            parts.push(format!(
                "{} skipped",
                plural(
                    self.no_reading,
                    "line without a magnetometer reading",
                    "lines without a magnetometer reading"
                )
            ));
        }
        let total = self.unreadable + self.header_copies + self.no_reading;
        let more = if total > self.examples.len() {
            "; ..."
        } else {
            ""
        };
        Some(format!(
            "{}: {}{more}",
            parts.join(", "),
            self.examples.join("; ")
        ))
    }

    /// Names one more line while fewer than [`Skipped::EXAMPLES`] are
    /// named (the caller counts it).
    fn add(&mut self, example: impl FnOnce() -> String) {
        if self.examples.len() < Self::EXAMPLES {
            self.examples.push(example());
        }
    }
}

/// The columns the samples were read from, and the rule that chose them.
///
/// [`Display`](fmt::Display) gives one line for a report, e.g.
/// `magx,magy,magz (from the header)`.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct ColumnsUsed {
    /// The header's names of the x, y, z columns, when there is a header;
    /// in labelled lines, the values' labels and unit (`Mag X (uT)`).
    pub names: Option<[String; 3]>,
    /// The rule.
    pub picked: Picked,
}

/// How the sample columns were chosen.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Picked {
    /// The first three fields: the first data row has at most three numeric
    /// fields.
    FirstThree,
    /// Named by `--columns`.
    Named,
    /// Found by name in the header ([`mag_axis`]), without `--columns`.
    Header,
    /// The magnetometer fields of MotionCal `Raw:` lines.
    MotionCal,
    /// By 1-based field number, `--columns 7,8,9` (in labelled lines: the
    /// line's 7th, 8th and 9th numbers).
    Fields([usize; 3]),
    /// The magnetometer's labelled values ([`labelled`]), without
    /// `--columns`.
    Labels,
}

/// The prefix of a MotionCal raw line.
pub const MOTIONCAL_PREFIX: &str = "Raw:";

/// A log is read as MotionCal's when one of its first this many content
/// lines starts with [`MOTIONCAL_PREFIX`]: a sketch prints a banner or two
/// first, and a saved serial log keeps them.
pub const MOTIONCAL_SNIFF_LINES: usize = 10;

/// Whether `text` is a MotionCal log ([`MOTIONCAL_SNIFF_LINES`]).
fn is_motioncal(text: &str) -> bool {
    content_lines(text)
        .take(MOTIONCAL_SNIFF_LINES)
        .any(|(_, line)| line.trim_start().starts_with(MOTIONCAL_PREFIX))
}

impl ColumnsUsed {
    /// Whether the columns were found by a rule that may guess wrong (in
    /// the header, or among labelled values), so that a report must name
    /// them.
    pub fn detected(&self) -> bool {
        matches!(self.picked, Picked::Header | Picked::Labels)
    }
}

impl fmt::Display for ColumnsUsed {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let how = match self.picked {
            Picked::FirstThree => "the first three fields".to_owned(),
            Picked::Named => "--columns".to_owned(),
            Picked::Header => "from the header".to_owned(),
            Picked::MotionCal => "MotionCal Raw: lines, fields 7-9 (10 per uT)".to_owned(),
            Picked::Fields([a, b, c]) if self.names.is_some() => {
                format!("fields {a},{b},{c}, --columns")
            }
            Picked::Fields([a, b, c]) => format!("fields {a},{b},{c} (--columns)"),
            Picked::Labels => "labelled values".to_owned(),
        };
        if let (Picked::Fields(_), None) = (self.picked, &self.names) {
            return f.write_str(&how);
        }
        match &self.names {
            Some(names) => {
                let names: Vec<String> = names.iter().map(|n| excerpt(n)).collect();
                write!(f, "{} ({how})", names.join(","))
            }
            None => f.write_str(&how),
        }
    }
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
    let lines: Vec<(usize, &str)> = content_lines(text).collect();
    if lines.is_empty() {
        return Err(CliError::Input(format!("{source_name}: no data rows")));
    }
    if is_motioncal(text) {
        if columns.is_some() {
            return Err(CliError::Input(format!(
                "{source_name}: MotionCal Raw: lines have no header: --columns does not apply"
            )));
        }
        if matches!(accel, Accel::Named(_)) {
            return Err(CliError::Input(format!(
                "{source_name}: MotionCal Raw: lines have no header: --accel-columns does not apply"
            )));
        }
        return Ok(motioncal(text, accel != Accel::None));
    }
    if lines
        .iter()
        .take(SNIFF_LINES)
        .any(|(_, line)| labelled::holds_reading(line))
    {
        return labelled::read(&lines, SNIFF_LINES, columns, accel, source_name);
    }
    delimited(&lines, columns, accel, source_name)
}

/// How many of the first content lines decide the format: whether the
/// lines are labelled ([`labelled`]), which labelled values are the
/// magnetometer's, and where a table's data begin after metadata and its
/// header. Sketches print a banner first (Adafruit's ICM-20948 example:
/// 9 lines of settings, then 4 lines per reading, the magnetometer's on
/// the 13th), and loggers a few lines of metadata (`Fs,50.00`).
pub const SNIFF_LINES: usize = 40;

/// The 1-based numbers of the fields that are numbers.
fn numeric_fields(fields: &[&str]) -> Vec<usize> {
    fields
        .iter()
        .enumerate()
        .filter(|(_, f)| number(f).is_some())
        .map(|(i, _)| i + 1)
        .collect()
}

/// How many content lines of one shape (as many fields, as many of them
/// numbers) begin a table's data, or as many as the file has: a
/// metadata line of three numbers (`Start,2024,05,12`) is followed by
/// lines of other shapes (`Fs,50`, the header), so it is not taken for
/// the first data row (which made the first three fields, a tumbling
/// accelerometer, the samples, with exit 0:
/// `cargo test -p mag-cal-cli --test formats a_date_line`). Three, not
/// two, so that two metadata lines of one shape (`Start,2024,05,12`,
/// `End,2024,05,13`) are not a run either (with two, the unit test
/// `a_metadata_line_of_three_numbers_is_not_data` fails).
const DATA_RUN: usize = 3;

/// A line's shape under `separator`: its number of fields and of numeric
/// fields.
fn shape(separator: Separator, line: &str) -> (usize, usize) {
    let fields = separator.fields(line);
    (fields.len(), numeric_fields(&fields).len())
}

/// Where a table's data begin, and their separator (see the module docs):
/// of the first [`SNIFF_LINES`] lines with at least three numeric fields,
/// the first that begins a run of [`DATA_RUN`] lines of its shape, or of
/// as many as the file has, else the first that begins the longest run;
/// then the first line of that shape before it (data rows garbled near the
/// start do not push the data past rows of the right shape). `None`
/// without a line of three numbers.
fn data_start(lines: &[(usize, &str)]) -> Option<(usize, Separator)> {
    // (whole run, run length) and the line that begins it.
    let mut best: Option<((bool, usize), usize)> = None;
    for (at, &(_, line)) in lines.iter().enumerate().take(SNIFF_LINES) {
        let separator = Separator::detect(line);
        let want = shape(separator, line);
        if want.1 < 3 {
            continue;
        }
        let run = lines[at..]
            .iter()
            .take(DATA_RUN)
            .take_while(|&&(_, line)| shape(separator, line) == want)
            .count();
        let rank = (run == DATA_RUN || at + run == lines.len(), run);
        if best.is_none_or(|(best, ..)| rank > best) {
            best = Some((rank, at));
        }
        if run == DATA_RUN {
            break;
        }
    }
    let (_, at) = best?;
    let separator = Separator::detect(lines[at].1);
    let want = shape(separator, lines[at].1);
    let first = lines[..at]
        .iter()
        .position(|&(_, line)| shape(separator, line) == want)
        .unwrap_or(at);
    Some((first, separator))
}

/// Reads a table: delimited fields, an optional header (after optional
/// metadata lines), one sample per line (see the module docs).
fn delimited(
    lines: &[(usize, &str)],
    columns: Option<&Columns>,
    accel: Accel<'_>,
    source_name: &str,
) -> Result<Table, CliError> {
    // The first data line ([`data_start`]); the header is the last line
    // before it with at least three fields, one of them not a number, and
    // fewer than three numbers; lines before the header (or before the
    // data, without one) are metadata. Without such a data line among the
    // first, the first line is the header when one of its fields is not a
    // number.
    let data_at = data_start(lines);
    let (separator, header_at, start) = match data_at {
        Some((data_at, separator)) => {
            let header_at = lines[..data_at].iter().rposition(|(_, line)| {
                let fields = separator.fields(line);
                let numeric = numeric_fields(&fields).len();
                fields.len() >= 3 && numeric < fields.len() && numeric < 3
            });
            (separator, header_at, header_at.map_or(data_at, |h| h + 1))
        }
        None => {
            let separator = Separator::detect(lines[0].1);
            let is_header = separator
                .fields(lines[0].1)
                .iter()
                .any(|f| number(f).is_none());
            (separator, is_header.then_some(0), usize::from(is_header))
        }
    };
    let header_fields = header_at.map(|h| separator.fields(lines[h].1));
    let header = header_fields.as_deref();
    let first_row = lines.get(data_at.map_or(start, |(at, _)| at));
    let first_no = first_row.map_or(lines[0].0, |&(no, _)| no);

    let (indices, picked) = match columns {
        None => {
            let fields = first_row.map_or_else(Vec::new, |&(_, line)| separator.fields(line));
            default_indices(header, &fields, source_name)?
        }
        Some(columns) => column_indices(header, columns, "--columns", first_no, source_name)?,
    };
    let accel_indices = match (accel, header) {
        (Accel::None, _) | (Accel::Detect, None) => None,
        (Accel::Named(columns), _) => {
            Some(column_indices(header, columns, "--accel-columns", first_no, source_name)?.0)
        }
        (Accel::Detect, Some(header)) => ACCEL_NAMES
            .iter()
            .find_map(|names| named_indices(header, names, source_name).ok())
            .filter(|found| *found != indices),
    };
    let columns = ColumnsUsed {
        names: header
            .filter(|header| indices.iter().all(|&i| i < header.len()))
            .map(|header| indices.map(|i| header[i].to_owned())),
        picked,
    };

    let mut samples = Vec::new();
    let mut accel_rows = accel_indices.map(|_| Vec::new());
    let mut skipped = Skipped::default();
    for &(line_no, line) in &lines[..header_at.unwrap_or(start)] {
        skipped.no_reading += 1;
        skipped.add(|| format!("line {line_no}: '{}'", excerpt(line.trim())));
    }
    // The first line that could not be read: the error when none could.
    let mut first_error = None;
    for &(line_no, line) in &lines[start..] {
        let fields = separator.fields(line);
        if header.is_some_and(|h| same_fields(h, &fields)) {
            skipped.header_copies += 1;
            skipped.add(|| format!("line {line_no}: a copy of the header"));
            continue;
        }
        let row = parse_row(line_no, &fields, &indices).and_then(|sample| {
            let accel = match accel_indices.as_ref() {
                Some(accel_indices) => Some(parse_row(line_no, &fields, accel_indices)?),
                None => None,
            };
            Ok((sample, accel))
        });
        let (sample, accel) = match row {
            Ok(row) => row,
            Err(err) => {
                skipped.unreadable += 1;
                skipped.add(|| err.to_string());
                first_error.get_or_insert(err);
                ([f64::NAN; 3], accel_indices.map(|_| [f64::NAN; 3]))
            }
        };
        samples.push(sample);
        if let (Some(rows), Some(accel)) = (accel_rows.as_mut(), accel) {
            rows.push(accel);
        }
    }
    if skipped.unreadable == samples.len() {
        return Err(first_error.unwrap_or_else(|| {
            CliError::Input(format!("{source_name}: no data rows after the header"))
        }));
    }
    Ok(Table {
        samples,
        accel: accel_rows,
        columns,
        skipped,
    })
}

/// A `--columns` name that is a field number: 1-based, as written
/// (`7`); `None` for a name (and for `0`, which `--columns` refuses).
pub(crate) fn field_number(name: &str) -> Option<usize> {
    let name = name.trim();
    if name.is_empty() || !name.bytes().all(|b| b.is_ascii_digit()) {
        return None;
    }
    name.parse::<usize>().ok().filter(|&n| n >= 1)
}

/// The indices of `--columns` (or `--accel-columns`, `option`): field
/// numbers, or names in the header (which must then exist; `first_no` is
/// the first data line, for the message); with the rule: [`Picked::Fields`]
/// when all three are numbers, else [`Picked::Named`].
fn column_indices(
    header: Option<&[&str]>,
    Columns(names): &Columns,
    option: &str,
    first_no: usize,
    source_name: &str,
) -> Result<([usize; 3], Picked), CliError> {
    if let [Some(a), Some(b), Some(c)] = names.each_ref().map(|n| field_number(n)) {
        return Ok(([a - 1, b - 1, c - 1], Picked::Fields([a, b, c])));
    }
    let Some(header) = header else {
        return Err(CliError::Input(format!(
            "{source_name}: {option} needs a header line naming the columns, \
             but line {first_no} is data; or give their field numbers, e.g. \
             {option} 1,2,3"
        )));
    };
    let mut indices = [0; 3];
    for (index, name) in indices.iter_mut().zip(names) {
        *index = match field_number(name) {
            Some(n) => n - 1,
            None => named_index(header, name, source_name)?,
        };
    }
    Ok((indices, Picked::Named))
}

/// Whether a line's fields are the header's (a copy of the header line,
/// compared without case).
fn same_fields(header: &[&str], fields: &[&str]) -> bool {
    header.len() == fields.len()
        && header
            .iter()
            .zip(fields)
            .all(|(h, f)| h.eq_ignore_ascii_case(f))
}

/// The rows of a MotionCal log: every `Raw:` line, the magnetometer from
/// fields 7-9 and (with `with_accel`) the accelerometer from fields 1-3; a
/// line without nine numbers is a non-finite row.
fn motioncal(text: &str, with_accel: bool) -> Table {
    let mut samples = Vec::new();
    let mut accel = Vec::new();
    let mut skipped = Skipped::default();
    for (line_no, line) in content_lines(text) {
        let Some(rest) = line.trim_start().strip_prefix(MOTIONCAL_PREFIX) else {
            continue;
        };
        let parsed: Vec<Option<f64>> = rest.split(',').map(|f| number(f.trim())).collect();
        let values: Vec<f64> = parsed
            .iter()
            .map(|v| v.filter(|v| v.is_finite()).unwrap_or(f64::NAN))
            .collect();
        let whole = values.len() == 9;
        // A garbled magnetometer field makes the row non-finite.
        if !whole || parsed.iter().skip(6).any(Option::is_none) {
            skipped.unreadable += 1;
            skipped.add(|| {
                if whole {
                    format!("line {line_no}: a magnetometer field is not a number")
                } else {
                    format!(
                        "line {line_no}: {} fields after {MOTIONCAL_PREFIX}, expected 9",
                        values.len()
                    )
                }
            });
        }
        let triple = |at: usize| {
            if whole {
                [values[at], values[at + 1], values[at + 2]]
            } else {
                [f64::NAN; 3]
            }
        };
        samples.push(triple(6));
        accel.push(triple(0));
    }
    Table {
        samples,
        accel: with_accel.then_some(accel),
        columns: ColumnsUsed {
            names: None,
            picked: Picked::MotionCal,
        },
        skipped,
    }
}

/// The sample columns without `--columns`, from the header and the first
/// data row's fields: the first three fields when at most three are
/// numbers, else the one raw magnetometer triple the header names (see the
/// module docs); none, several, or no header is an error (without a
/// header, it suggests the last three numeric fields).
fn default_indices(
    header: Option<&[&str]>,
    first_row: &[&str],
    source_name: &str,
) -> Result<([usize; 3], Picked), CliError> {
    let numeric_at = numeric_fields(first_row);
    let numeric = numeric_at.len();
    if numeric <= 3 {
        return Ok(([0, 1, 2], Picked::FirstThree));
    }
    let Some(header) = header else {
        return Err(CliError::Input(format!(
            "{source_name}: {numeric} numeric columns and no header line to choose \
             the magnetometer's x, y, z from; add a header naming the columns and \
             pass --columns X,Y,Z, or pass their field numbers (from 1), e.g. \
             --columns {},{},{}",
            numeric_at[numeric - 3],
            numeric_at[numeric - 2],
            numeric_at[numeric - 1],
        )));
    };
    let triples = mag_triples(header);
    match triples.as_slice() {
        [triple] => match triple.as_slice() {
            &[x, y, z] => Ok(([x, y, z], Picked::Header)),
            // One name triple with a repeated axis (`magx` and `mag_x`).
            _ => Err(CliError::Input(format!(
                "{source_name}: {numeric} numeric columns and the header repeats a \
                 magnetometer axis ({}); pass --columns X,Y,Z (columns: {})",
                column_list(header, triple),
                column_list(header, &all(header)),
            ))),
        },
        [] => Err(CliError::Input(format!(
            "{source_name}: {numeric} numeric columns and no raw magnetometer \
             x, y, z columns recognised in the header; pass --columns X,Y,Z \
             (columns: {})",
            column_list(header, &all(header)),
        ))),
        several => {
            let listed: Vec<String> = several
                .iter()
                .map(|triple| format!("({})", column_list(header, triple)))
                .collect();
            Err(CliError::Input(format!(
                "{source_name}: {numeric} numeric columns and {} sets of magnetometer \
                 columns in the header: {}; pass --columns X,Y,Z (columns: {})",
                several.len(),
                listed.join(", "),
                column_list(header, &all(header)),
            )))
        }
    }
}

/// Every index of `header`.
fn all(header: &[&str]) -> Vec<usize> {
    (0..header.len()).collect()
}

/// Stems of raw magnetometer column names, after lower-casing and dropping
/// `_`, `-`, `.` and spaces; an optional `raw` may stand before or after
/// stem and axis (`raw_mag_x`, `mag_x_raw`). The empty stem (bare `x`,
/// `y`, `z`) is accepted without `raw` only.
///
/// `h` is the magnetic field's symbol; WitMotion's IMU software exports its
/// magnetometer as `HX(uT)`, `HY(uT)`, `HZ(uT)` (beside `AccX(g)`,
/// `AsX(°/s)`, `AngleX(°)`, none of which match), and Arduino loggers for
/// it and the BMX160 write `hx(uT)`. Stems such as `b` (also a bias) or
/// `acc`, `gyro`, `pos` are left out on purpose: a name this list does not
/// know is never guessed.
const MAG_STEMS: [&str; 8] = [
    "mag",
    "m",
    "magnetometer",
    "magnetic",
    "magneticfield",
    "compass",
    "h",
    "",
];

/// `name` as a raw magnetometer column: its group (the compact name with
/// the axis letter replaced by `?`: `mag?`, `rawmag?`, `mag?raw`) and its
/// axis (0, 1, 2 for x, y, z); `None` for any other name.
///
/// Case and the separators `_`, `-`, `.` and spaces are ignored, and so is
/// a trailing unit in brackets (`HX(uT)`, `mag_x [uT]`). A name containing
/// `cal` (`mag_x_cal`, `cal_mag_x`, `magx_calibrated`) is a calibrated
/// column, never a raw one.
pub fn mag_axis(name: &str) -> Option<(String, usize)> {
    let lower = name.to_lowercase();
    if lower.contains("cal") {
        return None;
    }
    let compact: String = without_unit(&lower)
        .chars()
        .filter(|c| !matches!(c, '_' | '-' | '.' | ' '))
        .collect();
    let (prefix, rest, suffix) = if let Some(rest) = compact.strip_prefix("raw") {
        ("raw", rest, "")
    } else if let Some(rest) = compact.strip_suffix("raw") {
        ("", rest, "raw")
    } else {
        ("", compact.as_str(), "")
    };
    let axis = match rest.chars().last()? {
        'x' => 0,
        'y' => 1,
        'z' => 2,
        _ => return None,
    };
    let stem = &rest[..rest.len() - 1];
    let raw = !prefix.is_empty() || !suffix.is_empty();
    (MAG_STEMS.contains(&stem) && !(raw && stem.is_empty()))
        .then(|| (format!("{prefix}{stem}?{suffix}"), axis))
}

/// `name` without one trailing bracketed unit: `hx (ut)` is `hx`.
fn without_unit(name: &str) -> &str {
    let trimmed = name.trim_end();
    let open = match trimmed.chars().last() {
        Some(')') => '(',
        Some(']') => '[',
        _ => return trimmed,
    };
    trimmed
        .rfind(open)
        .map_or(trimmed, |i| trimmed[..i].trim_end())
}

/// The header's raw magnetometer name triples, in header order: per group
/// of [`mag_axis`] that has all three axes, the indices of its columns, x
/// first, then y, then z (more than three when an axis is repeated).
fn mag_triples(header: &[&str]) -> Vec<Vec<usize>> {
    let mut groups: Vec<(String, [Vec<usize>; 3])> = Vec::new();
    for (index, name) in header.iter().enumerate() {
        let Some((group, axis)) = mag_axis(name) else {
            continue;
        };
        let slot = match groups.iter().position(|(g, _)| *g == group) {
            Some(slot) => slot,
            None => {
                groups.push((group, Default::default()));
                groups.len() - 1
            }
        };
        groups[slot].1[axis].push(index);
    }
    groups
        .into_iter()
        .filter(|(_, axes)| axes.iter().all(|a| !a.is_empty()))
        .map(|(_, axes)| axes.concat())
        .collect()
}

/// The header's names at `indices`, for a one-line message: each one
/// escaped and shortened, at most 40 names.
fn column_list(header: &[&str], indices: &[usize]) -> String {
    const MAX: usize = 40;
    let mut names: Vec<String> = indices
        .iter()
        .take(MAX)
        .map(|&i| excerpt(header.get(i).copied().unwrap_or("")))
        .collect();
    if indices.len() > MAX {
        names.push(format!("... {} more", indices.len() - MAX));
    }
    names.join(", ")
}

/// The position of `name` in `header` (case-insensitive).
fn named_index(header: &[&str], name: &str, source_name: &str) -> Result<usize, CliError> {
    header
        .iter()
        .position(|f| f.eq_ignore_ascii_case(name))
        .ok_or_else(|| {
            CliError::Input(format!(
                "{source_name}: no column named '{}' in the header (columns: {})",
                excerpt(name),
                column_list(header, &all(header))
            ))
        })
}

/// The positions of `names` in `header` (case-insensitive).
fn named_indices(
    header: &[&str],
    [x, y, z]: &[&str; 3],
    source_name: &str,
) -> Result<[usize; 3], CliError> {
    Ok([
        named_index(header, x, source_name)?,
        named_index(header, y, source_name)?,
        named_index(header, z, source_name)?,
    ])
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
        parse(text.as_bytes(), None, "t").expect("parses").samples
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
    fn three_numeric_columns_are_the_first_three_fields() {
        // A line of three numbers and text is data: its text is ignored.
        let t = parse(b"1 2 3 text\n4 5 6 more\n7 8 9 x", None, "t").expect("parses");
        assert_eq!(
            t.samples,
            vec![[1.0, 2.0, 3.0], [4.0, 5.0, 6.0], [7.0, 8.0, 9.0]]
        );
        assert_eq!(t.columns.picked, Picked::FirstThree);
        assert_eq!(t.columns.to_string(), "the first three fields");
        // A header of any names, with or without a fourth text column.
        for text in ["a,b,c\n1,2,3\n", "a,b,c,note\n1,2,3,fine\n"] {
            let t = parse(text.as_bytes(), None, "t").expect("parses");
            assert_eq!(t.samples, vec![[1.0, 2.0, 3.0]], "{text}");
            assert_eq!(t.columns.picked, Picked::FirstThree);
            assert_eq!(t.columns.to_string(), "a,b,c (the first three fields)");
        }
        let t = parse(b"1,2,3\n", None, "t").expect("parses");
        assert_eq!(t.columns.to_string(), "the first three fields");
        assert_eq!(t.columns.names, None);
    }

    #[test]
    fn metadata_before_the_header_is_skipped() {
        // As a phone logger writes it: sampling rate and start-up time, then
        // the header, then the data.
        let text = b"Fs,50.00\nInitialization time,60\nmx,my,mz\n1,2,3\n4,5,6\n";
        let t = parse(text, None, "t").expect("parses");
        assert_eq!(t.samples, vec![[1.0, 2.0, 3.0], [4.0, 5.0, 6.0]]);
        assert_eq!(t.columns.to_string(), "mx,my,mz (the first three fields)");
        assert_eq!(
            t.skipped.note().as_deref(),
            Some(
                "2 lines without a magnetometer reading skipped: line 1: 'Fs,50.00'; \
                 line 2: 'Initialization time,60'"
            )
        );
        // Wide rows: the header after the metadata names the magnetometer.
        let text = "Device: phone\nrate 50 Hz\n\nt;ax;ay;az;mx;my;mz\n0;0;0;9.8;1;2;3\n";
        let t = parse(text.as_bytes(), None, "t").expect("parses");
        assert_eq!(t.samples, vec![[1.0, 2.0, 3.0]]);
        assert_eq!(t.columns.picked, Picked::Header);
        assert_eq!(t.skipped.no_reading, 2);
        // Metadata without a header; a line cut short after the header is
        // still an unreadable row, not the header.
        let t = parse(b"Fs,50.00\n1,2,3\n", None, "t").expect("parses");
        assert_eq!((t.samples.len(), t.skipped.no_reading), (1, 1));
        let t = parse(b"x,y,z\n4,5\n1,2,3\n", None, "t").expect("parses");
        assert_eq!(t.columns.names, Some(["x", "y", "z"].map(String::from)));
        assert_eq!((t.skipped.unreadable, t.skipped.no_reading), (1, 0));
        // Copies of the header later are still copies.
        let t = parse(b"Fs,50\nmx,my,mz\n1,2,3\nmx,my,mz\n4,5,6\n", None, "t").expect("parses");
        assert_eq!((t.samples.len(), t.skipped.header_copies), (2, 1));
    }

    #[test]
    fn a_metadata_line_of_three_numbers_is_not_data() {
        // A start date before the header of wide rows: the data begin with
        // the first run of lines of one shape.
        let text = b"Start,2024,05,12\nFs,50\nax,ay,az,gx,gy,gz,mx,my,mz\n\
                     1,2,3,0,0,0,7,8,9\n4,5,6,0,0,0,10,11,12\n4,5,6,0,0,0,13,14,15\n";
        let t = parse(text, None, "t").expect("parses");
        assert_eq!(t.samples[0], [7.0, 8.0, 9.0]);
        assert_eq!(t.columns.to_string(), "mx,my,mz (from the header)");
        assert_eq!(t.skipped.no_reading, 2);
        // Two such lines of one shape.
        let text = b"Start,2024,05,12\nEnd,2024,05,13\nmx,my,mz,t\n\
                     7,8,9,0\n10,11,12,1\n13,14,15,2\n";
        let t = parse(text, None, "t").expect("parses");
        assert_eq!(t.samples[0], [7.0, 8.0, 9.0]);
        assert_eq!(t.skipped.no_reading, 2);
        // Fewer rows than a run, or a line cut short among them: the
        // longest run.
        let head = "Start,2024,05,12\nFs,50\nax,ay,az,gx,gy,gz,mx,my,mz\n";
        for rows in [
            "1,2,3,0,0,0,7,8,9\n",
            "1,2,3,0,0,0,7,8,9\n4,5,6,0,0,0,10,11,12\n4,5",
        ] {
            let t = parse(format!("{head}{rows}").as_bytes(), None, "t").expect(rows);
            assert_eq!(t.samples[0], [7.0, 8.0, 9.0], "{rows}");
            assert_eq!(t.skipped.no_reading, 2, "{rows}");
        }
        // Without a header: metadata, and wide rows refused as such.
        let err = parse(b"Start,2024,05,12\n1,2,3,4\n5,6,7,8\n9,1,2,3\n", None, "f").unwrap_err();
        assert!(err.to_string().contains("no header line"), "{err}");
        let t = parse(b"Start,2024,05,12\n1,2,3\n5,6,7\n9,1,2\n", None, "t").expect("parses");
        assert_eq!((t.samples.len(), t.skipped.no_reading), (3, 1));
        // Rows garbled near the start: the data still begin with the first
        // row, not after a garbled line taken for a header.
        let t = parse(b"1,2,3\n1,abc,3\n4,5,6\n7,8,9\n1,2,3\n", None, "t").expect("parses");
        assert_eq!((t.samples.len(), t.skipped.unreadable), (5, 1));
        assert_eq!(t.columns.names, None);
        let t = parse(b"x,y,z\n4,5\n1,2,3\n4,5,6\n7,8,9\n", None, "t").expect("parses");
        assert_eq!(t.columns.names, Some(["x", "y", "z"].map(String::from)));
        assert_eq!((t.samples.len(), t.skipped.unreadable), (4, 1));
    }

    #[test]
    fn the_advice_names_the_last_three_numeric_fields() {
        // A text time stamp first, a status last: fields 5, 6, 7 of 8.
        let err = parse(
            b"12:00:01,0.1,0.2,9.8,19,-129,174,OK\n12:00:02,0.1,0.2,9.8,20,-130,175,OK\n",
            None,
            "f",
        )
        .unwrap_err();
        assert!(
            err.to_string()
                .starts_with("f: 6 numeric columns and no header line")
                && err.to_string().ends_with("e.g. --columns 5,6,7"),
            "{err}"
        );
    }

    #[test]
    fn columns_by_field_number() {
        // Without a header: wide rows, as a 9-axis sketch prints them.
        let text = b"0.1,0.2,9.8,0,0,0,19,-129,174\n0.1,0.2,9.8,0,0,0,20,-130,175\n";
        let t = parse(text, Some(&cols("7", "8", "9")), "t").expect("parses");
        assert_eq!(
            t.samples,
            vec![[19.0, -129.0, 174.0], [20.0, -130.0, 175.0]]
        );
        assert_eq!(t.columns.picked, Picked::Fields([7, 8, 9]));
        assert_eq!(t.columns.to_string(), "fields 7,8,9 (--columns)");
        // With a header: its names are reported; any order; mixed with names.
        let text = b"t,mx,my,mz\n0,1,2,3\n";
        let t = parse(text, Some(&cols("4", "2", "3")), "t").expect("parses");
        assert_eq!(t.samples, vec![[3.0, 1.0, 2.0]]);
        assert_eq!(t.columns.to_string(), "mz,mx,my (fields 4,2,3, --columns)");
        let t = parse(text, Some(&cols("mx", "3", "4")), "t").expect("parses");
        assert_eq!(t.samples, vec![[1.0, 2.0, 3.0]]);
        assert_eq!(t.columns.picked, Picked::Named);
        // Beyond the rows: each row is unreadable, the first is the error.
        let err = parse(b"1,2,3\n", Some(&cols("7", "8", "9")), "t").unwrap_err();
        assert_eq!(
            err.to_string(),
            "line 1: expected at least 9 fields, found 3"
        );
        // For the accelerometer too.
        let text = b"0.1,0.2,9.8,19,-129,174\n";
        let t = parse_with_accel(
            text,
            Some(&cols("4", "5", "6")),
            Accel::Named(&cols("1", "2", "3")),
            "t",
        )
        .expect("parses");
        assert_eq!(t.accel, Some(vec![[0.1, 0.2, 9.8]]));
    }

    #[test]
    fn the_usual_magnetometer_names_are_recognised() {
        for (name, group, axis) in [
            ("mag_x", "mag?", 0),
            ("magx", "mag?", 0),
            ("MagY", "mag?", 1),
            ("mag.z", "mag?", 2),
            ("Mag-X", "mag?", 0),
            ("mag x", "mag?", 0),
            ("mx", "m?", 0),
            ("m_y", "m?", 1),
            ("MZ", "m?", 2),
            ("mag_x_raw", "mag?raw", 0),
            ("raw_mag_y", "rawmag?", 1),
            ("RawMagZ", "rawmag?", 2),
            ("magnetometer_x", "magnetometer?", 0),
            ("Magnetic field y (µT)", "magneticfield?", 1),
            ("compass_z", "compass?", 2),
            ("HX(uT)", "h?", 0),
            ("hy", "h?", 1),
            ("mag_z [uT]", "mag?", 2),
            ("x", "?", 0),
            ("Z", "?", 2),
        ] {
            assert_eq!(mag_axis(name), Some((group.to_owned(), axis)), "{name}");
        }
        for name in [
            // Calibrated, not raw.
            "mag_x_cal",
            "cal_mag_x",
            "magx_calibrated",
            "MagXCal",
            "mag_x (cal)",
            // Other sensors and other quantities.
            "accx",
            "acc_x",
            "ax",
            "gyro_x",
            "gx",
            "AsX(°/s)",
            "AngleX(°)",
            "pos_x",
            "bx",
            "roll",
            "magnitude",
            // `raw` needs a magnetometer stem; no axis; empty.
            "raw_x",
            "x_raw",
            "mag",
            "mag_w",
            "",
            "(uT)",
        ] {
            assert_eq!(mag_axis(name), None, "{name}");
        }
    }

    #[test]
    fn wide_rows_use_the_magnetometer_columns_of_the_header() {
        for header in [
            "t,magx,magy,magz",
            "t,mag_x,mag_y,mag_z",
            "t,MagX,MagY,MagZ",
            "t,mag.x,mag.y,mag.z",
            "t,mx,my,mz",
            "t,m_x,m_y,m_z",
            "t,mag_x_raw,mag_y_raw,mag_z_raw",
            "t,raw_mag_x,raw_mag_y,raw_mag_z",
            "t,magnetometer_x,magnetometer_y,magnetometer_z",
            "t,compass_x,compass_y,compass_z",
            "t,HX(uT),HY(uT),HZ(uT)",
            "t,x,y,z",
        ] {
            let text = format!("{header},accx,accy,accz\n0,1,2,3,4,5,6\n1,7,8,9,0,0,1\n");
            let t = parse(text.as_bytes(), None, "t").expect(header);
            assert_eq!(
                t.samples,
                vec![[1.0, 2.0, 3.0], [7.0, 8.0, 9.0]],
                "{header}"
            );
            assert_eq!(t.columns.picked, Picked::Header, "{header}");
            let names: Vec<&str> = header.split(',').skip(1).collect();
            assert_eq!(
                t.columns.to_string(),
                format!("{} (from the header)", names.join(",")),
            );
        }
        // Any column order; the semicolon and whitespace separators too.
        let t = parse(b"magz;t;magx;q;magy\n3;0;1;9;2\n", None, "t").expect("parses");
        assert_eq!(t.samples, vec![[1.0, 2.0, 3.0]]);
        let t = parse(b"t ax ay az mx my mz\n0 0 0 9.8 1 2 3\n", None, "t").expect("parses");
        assert_eq!(t.samples, vec![[1.0, 2.0, 3.0]]);
        // Text fields do not count as numeric columns, and may be anywhere.
        let t = parse(b"fix,t,mx,my,mz\nNoFix,0,1,2,3\n", None, "t").expect("parses");
        assert_eq!(t.samples, vec![[1.0, 2.0, 3.0]]);
    }

    #[test]
    fn calibrated_columns_are_never_picked() {
        for header in [
            "mag_x_cal,mag_y_cal,mag_z_cal,magx,magy,magz",
            "cal_mag_x,cal_mag_y,cal_mag_z,magx,magy,magz",
            "magx_calibrated,magy_calibrated,magz_calibrated,magx,magy,magz",
        ] {
            let text = format!("{header}\n9,9,9,1,2,3\n");
            let t = parse(text.as_bytes(), None, "t").expect(header);
            assert_eq!(t.samples, vec![[1.0, 2.0, 3.0]], "{header}");
        }
        // Only calibrated magnetometer columns: nothing to pick.
        let err = parse(
            b"accx,accy,accz,mag_x_cal,mag_y_cal,mag_z_cal\n0,0,9.8,1,2,3\n",
            None,
            "f.csv",
        )
        .unwrap_err();
        assert_eq!(
            err.to_string(),
            "f.csv: 6 numeric columns and no raw magnetometer x, y, z columns recognised \
             in the header; pass --columns X,Y,Z (columns: accx, accy, accz, mag_x_cal, \
             mag_y_cal, mag_z_cal)"
        );
        assert_eq!(err.exit_code(), 2);
    }

    #[test]
    fn wide_rows_without_one_header_triple_are_refused() {
        // No triple: none known, or one axis missing.
        for (text, columns) in [
            ("a,b,c,d\n1,2,3,4\n", "a, b, c, d"),
            ("t,magx,magy,q\n0,1,2,3\n", "t, magx, magy, q"),
        ] {
            let err = parse(text.as_bytes(), None, "f.csv").unwrap_err();
            let msg = err.to_string();
            assert!(
                msg.contains("no raw magnetometer x, y, z columns")
                    && msg.contains("pass --columns X,Y,Z")
                    && msg.ends_with(&format!("(columns: {columns})")),
                "{msg}"
            );
            assert_eq!(err.exit_code(), 2);
        }
        // Two triples.
        let err = parse(
            b"mag_x,mag_y,mag_z,raw_mag_x,raw_mag_y,raw_mag_z\n1,2,3,4,5,6\n",
            None,
            "f.csv",
        )
        .unwrap_err();
        assert_eq!(
            err.to_string(),
            "f.csv: 6 numeric columns and 2 sets of magnetometer columns in the header: \
             (mag_x, mag_y, mag_z), (raw_mag_x, raw_mag_y, raw_mag_z); pass --columns \
             X,Y,Z (columns: mag_x, mag_y, mag_z, raw_mag_x, raw_mag_y, raw_mag_z)"
        );
        let err = parse(b"x,y,z,mx,my,mz\n1,2,3,4,5,6\n", None, "f").unwrap_err();
        assert!(err.to_string().contains("2 sets"), "{err}");
        // One axis twice (the separators are ignored: the same name).
        let err = parse(b"magx,mag_x,magy,magz\n1,2,3,4\n", None, "f.csv").unwrap_err();
        assert_eq!(
            err.to_string(),
            "f.csv: 4 numeric columns and the header repeats a magnetometer axis \
             (magx, mag_x, magy, magz); pass --columns X,Y,Z (columns: magx, mag_x, \
             magy, magz)"
        );
        assert_eq!(err.exit_code(), 2);
    }

    #[test]
    fn wide_rows_without_a_header_are_refused() {
        for text in [
            "1,2,3,4\n5,6,7,8\n",
            "1 2 3 4 5 6\n",
            "# x y z t\n1;2;3;4\n",
        ] {
            let err = parse(text.as_bytes(), None, "f.csv").unwrap_err();
            let msg = err.to_string();
            assert!(
                msg.starts_with("f.csv: ")
                    && msg.contains("numeric columns and no header line")
                    && msg.contains("--columns X,Y,Z"),
                "{text}: {msg}"
            );
            assert_eq!(err.exit_code(), 2);
        }
    }

    #[test]
    fn columns_option_wins_over_the_header() {
        let c = cols("mag_x_cal", "mag_y_cal", "mag_z_cal");
        let text = b"magx,magy,magz,mag_x_cal,mag_y_cal,mag_z_cal\n1,2,3,4,5,6\n";
        let t = parse(text, Some(&c), "t").expect("parses");
        assert_eq!(t.samples, vec![[4.0, 5.0, 6.0]]);
        assert_eq!(t.columns.picked, Picked::Named);
        assert_eq!(
            t.columns.to_string(),
            "mag_x_cal,mag_y_cal,mag_z_cal (--columns)"
        );
        // An ambiguous or unknown header is no obstacle to --columns.
        let c = cols("raw_mag_x", "raw_mag_y", "raw_mag_z");
        let text = b"mag_x,mag_y,mag_z,raw_mag_x,raw_mag_y,raw_mag_z\n1,2,3,4,5,6\n";
        let t = parse(text, Some(&c), "t").expect("parses");
        assert_eq!(t.samples, vec![[4.0, 5.0, 6.0]]);
        let t = parse(b"a,b,c,d\n1,2,3,4\n", Some(&cols("b", "c", "d")), "t").expect("parses");
        assert_eq!(t.samples, vec![[2.0, 3.0, 4.0]]);
    }

    #[test]
    fn long_headers_are_listed_in_one_bounded_line() {
        let names: Vec<String> = (0..50).map(|i| format!("c{i}")).collect();
        let text = format!("{}\n{}\n", names.join(","), vec!["1"; 50].join(","));
        let msg = parse(text.as_bytes(), None, "t").unwrap_err().to_string();
        assert!(
            msg.contains("c0, c1, ") && msg.contains("c39, ... 10 more)"),
            "{msg}"
        );
        assert!(!msg.contains("c40"), "{msg}");
        // Control characters in a name stay escaped.
        let msg = parse(b"a\x1b,b,c,d\n1,2,3,4\n", None, "t")
            .unwrap_err()
            .to_string();
        assert!(msg.contains("(columns: a\\u{1b}, b, c, d)"), "{msg}");
    }

    /// The samples, column line and note of a labelled log.
    fn labelled(text: &str) -> (Vec<[f64; 3]>, String, Option<String>) {
        let t = parse(text.as_bytes(), None, "t").expect(text);
        (t.samples, t.columns.to_string(), t.skipped.note())
    }

    #[test]
    fn labelled_lines_of_one_sensor() {
        let want = vec![[19.0, -129.0, 174.0], [20.0, -130.0, 175.0]];
        for (text, columns) in [
            (
                "Mx 19 My -129 Mz 174\nMx 20 My -130 Mz 175\n",
                "Mx,My,Mz (labelled values)",
            ),
            (
                "X: 19  Y: -129  Z: 174  uT\nX: 20  Y: -130  Z: 175  uT\n",
                "X (uT),Y (uT),Z (uT) (labelled values)",
            ),
            (
                "Mag X: 19 Y: -129 Z: 174 uTesla\nMag X: 20 Y: -130 Z: 175 uTesla\n",
                "Mag X (uTesla),Mag Y (uTesla),Mag Z (uTesla) (labelled values)",
            ),
            (
                "mag_x=19, mag_y=-129, mag_z=174\nmag_x=20, mag_y=-130, mag_z=175\n",
                "mag_x,mag_y,mag_z (labelled values)",
            ),
            // A bare X, Y, Z without a unit, when the lines hold nothing else.
            (
                "X: 19 Y: -129 Z: 174\nX: 20 Y: -130 Z: 175\n",
                "X,Y,Z (labelled values)",
            ),
        ] {
            let (samples, shown, note) = labelled(text);
            assert_eq!(samples, want, "{text}");
            assert_eq!(shown, columns, "{text}");
            assert_eq!(note, None, "{text}");
        }
    }

    #[test]
    fn labelled_lines_of_several_sensors_give_the_magnetometer() {
        let want = vec![[19.0, -129.0, 174.0], [20.0, -130.0, 175.0]];
        for (text, columns, skipped) in [
            // Adafruit's ICM-20948 example: a banner, then one line per sensor.
            (
                "Adafruit ICM20948 test!\nICM20948 Found!\nAccelerometer range set to: +-4G\n\
                 Magnetometer data rate set to: 100 Hz\n\
                 \t\tTemperature 25.50 deg C\n\
                 \t\tAccel X: 0.10 \tY: 0.20 \tZ: 9.80 m/s^2 \n\
                 \t\tGyro X: 0.01 \tY: 0.02 \tZ: 0.03 radians/s \n\n\
                 \t\tMag X: 19 \tY: -129 \tZ: 174 uT\n\
                 \t\tAccel X: 0.10 \tY: 0.20 \tZ: 9.80 m/s^2 \n\
                 \t\tMag X: 20 \tY: -130 \tZ: 175 uT\n",
                "Mag X (uT),Mag Y (uT),Mag Z (uT) (labelled values)",
                8,
            ),
            // One line: the m of mx names the magnetometer.
            (
                "ax=0.1 ay=0.2 az=9.8 gx=0 gy=0 gz=0 mx=19 my=-129 mz=174\n\
                 ax=0.1 ay=0.2 az=9.8 gx=0 gy=0 gz=0 mx=20 my=-130 mz=175\n",
                "mx,my,mz (labelled values)",
                0,
            ),
            (
                "Acc: 0.1 0.2 9.8 Gyro: 0 0 0 Mag: 19 -129 174\n\
                 Acc: 0.1 0.2 9.8 Gyro: 0 0 0 Mag: 20 -130 175\n",
                "Mag x,Mag y,Mag z (labelled values)",
                0,
            ),
            // SparkFun's ICM-20948 example.
            (
                "Scaled. Acc (mg) [ -00012.21,  00004.39,  01008.79 ], Gyr (DPS) [ -00000.11, \
                 00000.53, -00000.08 ], Mag (uT) [  00019.00, -00129.00,  00174.00 ], Tmp (C) [ \
                 00029.03 ]\n\
                 Scaled. Acc (mg) [ -00012.21,  00004.39,  01008.79 ], Gyr (DPS) [ -00000.11, \
                 00000.53, -00000.08 ], Mag (uT) [  00020.00, -00130.00,  00175.00 ], Tmp (C) [ \
                 00029.03 ]\n",
                "Mag x (uT),Mag y (uT),Mag z (uT) (labelled values)",
                0,
            ),
            // Kris Winer's MPU-9250 sketch: mg is the accelerometer's milli-g,
            // mG the magnetometer's milligauss.
            (
                "ax = 12 ay = 4 az = 1000 mg\ngx = 0.1 gy = 0.2 gz = 0.3 deg/s\n\
                 mx = 19 my = -129 mz = 174 mG\nq0 = 1 qx = 0 qy = 0 qz = 0\n\
                 ax = 12 ay = 4 az = 1000 mg\nmx = 20 my = -130 mz = 175 mG\n",
                "mx (mG),my (mG),mz (mG) (labelled values)",
                4,
            ),
            // Adafruit's LIS3MDL example: raw counts, then uTesla; the unit
            // decides.
            (
                "X:  1900 \tY:  -12900 \tZ:  17400\n\tX: 19 \tY: -129 \tZ: 174 uTesla \n\
                 X:  2000 \tY:  -13000 \tZ:  17500\n\tX: 20 \tY: -130 \tZ: 175 uTesla \n",
                "X (uTesla),Y (uTesla),Z (uTesla) (labelled values)",
                2,
            ),
        ] {
            let t = parse(text.as_bytes(), None, "t").expect(text);
            assert_eq!(t.samples, want, "{text}");
            assert_eq!(t.columns.to_string(), columns, "{text}");
            assert_eq!(t.columns.picked, Picked::Labels);
            assert!(t.columns.detected());
            assert_eq!(
                (t.skipped.no_reading, t.skipped.unreadable),
                (skipped, 0),
                "{text}"
            );
        }
        // The note names the lines skipped.
        let (_, _, note) = labelled("Accel X: 1 Y: 2 Z: 3 m/s^2\nMag X: 19 Y: -129 Z: 174 uT\n");
        assert_eq!(
            note.as_deref(),
            Some(
                "1 line without a magnetometer reading skipped: line 1: 'Accel X: 1 Y: 2 Z: 3 \
                 m/s^2'"
            )
        );
    }

    #[test]
    fn a_labelled_line_cut_short_is_an_unreadable_row() {
        let t = parse(
            b"Mag X: 19 Y: -129 Z: 174 uT\nMag X: 20 Y: -1\nMag X: 21 Y: -131 Z: 176 uT\n",
            None,
            "t",
        )
        .expect("parses");
        assert_eq!(t.samples.len(), 3);
        assert!(t.samples[1].iter().all(|v| v.is_nan()));
        assert_eq!(
            t.skipped.note().as_deref(),
            Some(
                "1 unreadable line kept as a non-finite row (dropped): line 2: no value \
                 named 'magz'"
            )
        );
    }

    #[test]
    fn ambiguous_labelled_lines_are_refused_with_what_was_found() {
        // No magnetometer by label or unit.
        let err = parse(
            b"Accel X: 1 Y: 2 Z: 3 m/s^2\nGyro X: 1 Y: 2 Z: 3 dps\n",
            None,
            "f.txt",
        )
        .unwrap_err();
        assert_eq!(
            err.to_string(),
            "f.txt: labelled values, but none is the magnetometer's by its label (Mag, M, \
             mx, ...) or unit (uT, gauss, mG): found Accel X, Accel Y, Accel Z (m/s^2); Gyro \
             X, Gyro Y, Gyro Z (dps); pass --columns with the three labels to use (e.g. \
             --columns accelx,accely,accelz) or their numbers in the line (e.g. --columns \
             1,2,3)"
        );
        assert_eq!(err.exit_code(), 2);
        // Two bare triples: which is which is not said.
        let err = parse(b"X: 1 Y: 2 Z: 3\nX: 1 Y: 2 Z: 3 m/s^2\n", None, "f").unwrap_err();
        assert!(
            err.to_string().contains("found X, Y, Z; X, Y, Z (m/s^2)"),
            "{err}"
        );
        // Two magnetometers.
        let err = parse(
            b"Mag X: 1 Y: 2 Z: 3 uT\nmx = 1 my = 2 mz = 3 mG\n",
            None,
            "f.txt",
        )
        .unwrap_err();
        assert_eq!(
            err.to_string(),
            "f.txt: labelled values with 2 magnetometer readings: Mag X, Mag Y, Mag Z (uT); \
             mx, my, mz (mG); pass --columns with the labels of the one to use (e.g. \
             --columns magx,magy,magz)"
        );
        assert_eq!(err.exit_code(), 2);
        // The same labels in two field units: the unit picks.
        let err = parse(b"X: 1 Y: 2 Z: 3 uT\nX: 1 Y: 2 Z: 3 gauss\n", None, "f").unwrap_err();
        assert!(
            err.to_string()
                .ends_with("(e.g. --columns x[uT],y[uT],z[uT])"),
            "{err}"
        );
        let t = parse(
            b"X: 1 Y: 2 Z: 3 uT\nX: 1 Y: 2 Z: 3 gauss\n",
            Some(&cols("x[gauss]", "y[gauss]", "z[gauss]")),
            "f",
        )
        .expect("parses");
        assert_eq!((t.samples.len(), t.skipped.no_reading), (1, 1));
    }

    #[test]
    fn columns_pick_labelled_values() {
        let text =
            b"Accel X: 1 Y: 2 Z: 3 m/s^2\nGyro X: 4 Y: 5 Z: 6 dps\nAccel X: 7 Y: 8 Z: 9 m/s^2\n";
        // By label: the line's sensor word and axis, compacted.
        let t = parse(text, Some(&cols("accelx", "Accel Y", "accel_z")), "t").expect("parses");
        assert_eq!(t.samples, vec![[1.0, 2.0, 3.0], [7.0, 8.0, 9.0]]);
        assert_eq!(t.columns.picked, Picked::Named);
        assert_eq!(
            t.columns.to_string(),
            "Accel X (m/s^2),Accel Y (m/s^2),Accel Z (m/s^2) (--columns)"
        );
        assert_eq!(t.skipped.no_reading, 1);
        // By the numbers' places in each line.
        let text = b"ax=1 ay=2 az=3 gx=4 gy=5 gz=6 mx=7 my=8 mz=9\nax=1 ay=2\n";
        let t = parse(text, Some(&cols("7", "8", "9")), "t").expect("parses");
        assert_eq!(t.samples[0], [7.0, 8.0, 9.0]);
        assert!(t.samples[1][0].is_nan());
        assert_eq!(t.columns.to_string(), "mx,my,mz (fields 7,8,9, --columns)");
        assert_eq!(
            t.skipped.examples,
            ["line 2: 2 numbers, expected at least 9"]
        );
        // A unit in brackets picks one of two readings of the same labels
        // (the report's names are what --columns takes).
        let text = b"X: 1900 Y: -12900 Z: 17400\nX: 19 Y: -129 Z: 174 uTesla\n";
        let t = parse(
            text,
            Some(&cols("X (uTesla)", "Y (uTesla)", "Z (uTesla)")),
            "t",
        )
        .expect("parses");
        assert_eq!(t.samples, vec![[19.0, -129.0, 174.0]]);
        let t = parse(
            text,
            Some(&cols("x[uTesla]", "y[uTesla]", "z[uTesla]")),
            "t",
        )
        .expect("parses");
        assert_eq!(t.samples, vec![[19.0, -129.0, 174.0]]);
        // Without the unit they would mix: refused.
        let err = parse(text, Some(&cols("x", "y", "z")), "f").unwrap_err();
        assert_eq!(
            err.to_string(),
            "f: the values named 'x', 'y', 'z' come in 2 units (no unit, uTesla); add the \
             unit to each name (e.g. --columns x[uTesla],y[uTesla],z[uTesla])"
        );
        // Absent names: the labels of a line.
        let err = parse(text, Some(&cols("mx", "my", "mz")), "f").unwrap_err();
        assert_eq!(
            err.to_string(),
            "f: no line holds values named 'mx', 'my', 'mz' (line 1 has: X, Y, Z)"
        );
    }

    #[test]
    fn labelled_accelerometer_values() {
        let text = b"t=1 ax=0.1 ay=0.2 az=9.8 mx=19 my=-129 mz=174\n";
        let t = parse_with_accel(text, None, Accel::Detect, "t").expect("parses");
        assert_eq!(t.samples, vec![[19.0, -129.0, 174.0]]);
        assert_eq!(t.accel, Some(vec![[0.1, 0.2, 9.8]]));
        let t =
            parse_with_accel(text, None, Accel::Named(&cols("2", "3", "4")), "t").expect("parses");
        assert_eq!(t.accel, Some(vec![[0.1, 0.2, 9.8]]));
        // On other lines than the magnetometer's: none detected; named, an error.
        let text = b"Accel X: 0.1 Y: 0.2 Z: 9.8 m/s^2\nMag X: 19 Y: -129 Z: 174 uT\n";
        let t = parse_with_accel(text, None, Accel::Detect, "t").expect("parses");
        assert_eq!(t.accel, None);
        let err = parse_with_accel(
            text,
            None,
            Accel::Named(&cols("accelx", "accely", "accelz")),
            "f",
        )
        .unwrap_err();
        assert!(err.to_string().contains("--accel-columns"), "{err}");
    }

    #[test]
    fn non_finite_values_are_numbers() {
        let s = parse_ok("nan,inf,-inf\n1e400,NaN,Infinity\n1,2,3");
        assert!(s[0][0].is_nan() && s[0][1] == f64::INFINITY && s[0][2] == f64::NEG_INFINITY);
        assert!(s[1][0].is_infinite() && s[1][1].is_nan() && s[1][2].is_infinite());
        assert_eq!(s[2], [1.0, 2.0, 3.0]);
    }

    #[test]
    fn absurd_finite_values_pass_through() {
        // Finite in f64, absurd for a magnetometer: the core's to judge.
        let s = parse_ok("1,2,3\n1e308,0,0\n-1.7976931348623157e308,5e-324,-0\n4,5,6\n");
        assert_eq!(s.len(), 4);
        assert_eq!(s[1], [1e308, 0.0, 0.0]);
        assert_eq!(s[2], [f64::MIN, 5e-324, 0.0]);
        assert!(s.iter().flatten().all(|v| v.is_finite()));
    }

    #[test]
    fn named_columns() {
        let text = "t,MagX,magy,magz,fix\n0,1,2,3,NoFix\n1,4,5,6,3D\n";
        let c = cols("magx", "magy", "MAGZ");
        let s = parse(text.as_bytes(), Some(&c), "t").expect("parses");
        assert_eq!(s.samples, vec![[1.0, 2.0, 3.0], [4.0, 5.0, 6.0]]);
        // The header's spelling, not the option's.
        assert_eq!(s.columns.to_string(), "MagX,magy,magz (--columns)");
        let c = cols("magz", "magx", "magy");
        let s = parse(text.as_bytes(), Some(&c), "t").expect("parses");
        assert_eq!(s.samples[0], [3.0, 1.0, 2.0]);
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

    /// Whether every component of every row is NaN.
    fn all_nan(rows: &[[f64; 3]]) -> bool {
        rows.iter().flatten().all(|v| v.is_nan())
    }

    #[test]
    fn unreadable_lines_are_named_and_kept_as_non_finite_rows() {
        let t = parse(b"x,y,z\n1,2,3\n\n1,abc,3\n4,5\n4,,6\n7,8,9\n", None, "t").expect("parses");
        assert_eq!(t.samples.len(), 5);
        assert_eq!(
            (t.samples[0], t.samples[4]),
            ([1.0, 2.0, 3.0], [7.0, 8.0, 9.0])
        );
        assert!(all_nan(&t.samples[1..4]), "{:?}", t.samples);
        assert_eq!((t.skipped.unreadable, t.skipped.header_copies), (3, 0));
        assert_eq!(
            t.skipped.examples,
            [
                "line 4: 'abc' is not a number",
                "line 5: expected at least 3 fields, found 2",
                "line 6: field 2 is empty",
            ]
        );
        assert_eq!(
            t.skipped.note().as_deref(),
            Some(
                "3 unreadable lines kept as non-finite rows (dropped): line 4: 'abc' is not a \
                 number; line 5: expected at least 3 fields, found 2; line 6: field 2 is empty"
            )
        );
        // A clean input names nothing.
        let t = parse(b"x,y,z\n1,2,3\n", None, "t").expect("parses");
        assert!(t.skipped.is_empty() && t.skipped.note().is_none());
    }

    #[test]
    fn copies_of_the_header_are_skipped() {
        // Two logs appended to one another, the second with the header in
        // another case; then a line that is not the header.
        let text = b"MagX,MagY,MagZ\n1,2,3\nmagx,magy,magz\n4,5,6\n7,8,9\nMagX,MagY\n";
        let t = parse(text, None, "t").expect("parses");
        assert_eq!(t.samples.len(), 4);
        assert_eq!(
            t.samples[..3],
            [[1.0, 2.0, 3.0], [4.0, 5.0, 6.0], [7.0, 8.0, 9.0]]
        );
        assert!(all_nan(&t.samples[3..]));
        assert_eq!((t.skipped.unreadable, t.skipped.header_copies), (1, 1));
        assert_eq!(
            t.skipped.note().as_deref(),
            Some(
                "1 unreadable line kept as a non-finite row (dropped), 1 copy of the header \
                 skipped: line 3: a copy of the header; line 6: expected at least 3 fields, \
                 found 2"
            )
        );
    }

    #[test]
    fn every_line_end_ends_a_line() {
        for text in [
            "x,y,z\n1,2,3\n4,5,6\n",
            "x,y,z\r\n1,2,3\r\n4,5,6\r\n",
            "x,y,z\r1,2,3\r4,5,6\r",
        ] {
            let t = parse(text.as_bytes(), None, "t").expect("parses");
            assert_eq!(t.samples, [[1.0, 2.0, 3.0], [4.0, 5.0, 6.0]], "{text:?}");
        }
        // Line numbers count lone `\r` too.
        let t = parse(b"x,y,z\r1,2,3\r4,q,6\r", None, "t").expect("parses");
        assert_eq!(t.skipped.examples, ["line 3: 'q' is not a number"]);
    }

    #[test]
    fn the_examples_stop_at_three() {
        let mut text = String::from("1,2,3\n");
        for _ in 0..5 {
            text.push_str("1,x,3\n");
        }
        let t = parse(text.as_bytes(), None, "t").expect("parses");
        assert_eq!(t.skipped.unreadable, 5);
        assert_eq!(t.skipped.examples.len(), Skipped::EXAMPLES);
        let note = t.skipped.note().expect("a note");
        assert!(
            note.starts_with("5 unreadable lines") && note.ends_with("; ..."),
            "{note}"
        );
    }

    #[test]
    fn without_a_readable_line_the_first_failure_is_the_error() {
        let err = parse(b"x,y,z\n1,abc,3\n1,2\n", None, "t").unwrap_err();
        assert_eq!(err.to_string(), "line 2: 'abc' is not a number");
        assert_eq!(err.exit_code(), 2);
        let err = parse(b"x,y,z\nx,y,z\n", None, "t").unwrap_err();
        assert_eq!(err.to_string(), "t: no data rows after the header");
    }

    #[test]
    fn garbled_motioncal_lines_are_counted() {
        let text = b"Raw:1,2,3,4,5,6,70,80,90\nRaw:1,2,3,4,5,6,7\nRaw:1,2,3,4,5,6,7,x,9\nRaw:a,2,3,4,5,6,7,8,9\n";
        let t = parse(text, None, "t").expect("parses");
        assert_eq!(t.samples.len(), 4);
        assert_eq!(t.samples[0], [70.0, 80.0, 90.0]);
        assert!(all_nan(&t.samples[1..2]) && t.samples[2][1].is_nan());
        // A garbled accelerometer field leaves the magnetometer's.
        assert_eq!(t.samples[3], [7.0, 8.0, 9.0]);
        assert_eq!(
            t.skipped.examples,
            [
                "line 2: 7 fields after Raw:, expected 9",
                "line 3: a magnetometer field is not a number",
            ]
        );
    }

    #[test]
    fn hostile_fields_stay_on_one_line() {
        let mut bytes = b"1,2,3\n1,2,".to_vec();
        bytes.extend_from_slice(&[0xff, 0x07, 0x1b, b'x']);
        bytes.extend(std::iter::repeat_n(b'a', 100));
        let t = parse(&bytes, None, "t").expect("parses");
        let note = t.skipped.note().expect("a note");
        assert!(
            !note.contains('\u{7}') && !note.contains('\u{1b}'),
            "{note}"
        );
        assert!(
            note.contains(": line 2: '\u{fffd}\\u{7}\\u{1b}x")
                && note.ends_with("...' is not a number"),
            "{note}"
        );
        // The same as the error of an input without a readable line.
        let alone = [b"x,y,z\n".as_slice(), &bytes[6..]].concat();
        let err = parse(&alone, None, "t").unwrap_err().to_string();
        assert!(!err.contains('\u{7}') && !err.contains('\u{1b}'), "{err}");
        assert!(err.starts_with("line 2: '\u{fffd}\\u{7}\\u{1b}x"), "{err}");
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
