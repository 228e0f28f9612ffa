//! The command line: subcommands, options and the names they accept.
//!
//! Each option value is a small [`ValueEnum`] whose names clap checks
//! (a bad value is a usage error, exit 2) and which maps onto the core's
//! type. The method names come from the core ([`Method::ALL`],
//! [`Method::name`]), so a new core method needs no change here beyond,
//! optionally, its help line in [`method_help`]; a new subcommand is one
//! more variant of [`Command`].

use std::path::PathBuf;

use clap::builder::PossibleValue;
use clap::{Args, Parser, Subcommand, ValueEnum};
use mag_cal_core::{LsVariant, Method};

/// Text after the top-level help.
const AFTER_HELP: &str = "\
Input: CSV or whitespace/tab/semicolon separated text, one sample per line,
'-' for stdin. Lines starting with '#' and blank lines are skipped. The first
line with three numeric fields is data; the last line before it with three
fields, one not a number, is the header, and lines before that (metadata such
as 'Fs,50.00') are skipped.
Columns: --columns X,Y,Z picks x, y, z by header name (case-insensitive) or
by field number from 1 (--columns 7,8,9, with or without a header).
Without it, rows of at most three numeric fields give x, y, z from the first
three fields; wider rows need a header naming exactly one raw magnetometer
triple, which is then used (and named in the report, or on stderr): magx,
mag_x, MagX, mag.x, mx, m_x, mag_x_raw, raw_mag_x, magnetometer_x, compass_x,
HX(uT), x, ... (case, '_', '-', '.', spaces and a trailing unit in brackets
are ignored; names containing 'cal' are calibrated columns, never picked).
No such triple, several, or no header: exit 2, listing the header's columns.
Labelled values, as sketches print them ('Mx 19 My -129 Mz 174',
'Mag X: 12.3 Y: -4.5 Z: 6.7 uT', 'ax=.. ay=.. mx=.. my=.. mz=..',
'Acc: 1 2 3 Mag: 4 5 6', 'Mag (uT) [ 4, 5, 6 ]'): the magnetometer's x, y, z
are the values labelled so (Mag, M, mx, mag_x, ...) or in a field's unit
(uT, gauss, mG); a bare 'X: Y: Z:' when the lines hold nothing else. Lines
without them (other sensors, a banner) are skipped and counted. Several or
none: exit 2, listing what was found. --columns names labels ('Mag X:' is
magx, 'Mx' is mx, 'Mag (uT) [a, b, c]' is magx,magy,magz; a unit may follow
in brackets: x[uT]) or the numbers' places in the line (--columns 7,8,9).
MotionCal logs (lines 'Raw:ax,ay,az,gx,gy,gz,mx,my,mz', as PJRC's and
Adafruit's calibration sketches print them; magnetometer at 10 per uT) are
recognised by a Raw: line among the first ten (after a banner, say): x, y, z
are fields 7-9 and the accelerometer fields 1-3; other lines are skipped, a
cut-short Raw: line is dropped.
'nan' and 'inf' are accepted and skipped by the fit (counted as dropped).
A data line that cannot be read (a field that is not a number, too few
fields) is kept as a non-finite row, dropped by the fit, and a later copy of
the header (logs appended to one another) is skipped; the report names the
first of them ('input', or on stderr). Only when no data line can be read is
it an error (exit 2, naming the first that failed).

Outliers (unless --plain): rows that are not finite or too large are dropped,
and so are glitches: exact (0, 0, 0) rows, rows equal to the row before,
rows at an axis's clip level (an extreme value many rows share), and in a
file of integer counts (every value an integer in i16's range, read as i16)
rows with a component on the rails (+-32767, -32768). A plain fit of the
rest is kept when it is clean (no residual beyond 5 robust standard
deviations, their RMS at most 1.25 of them, no systematic misfit);
otherwise rows farther than 2.5 median distances from the median centre are
screened out, and rows whose calibrated
norm is off the unit sphere by more than 3.5 robust standard deviations are
rejected.

Still periods (with or without --plain): where the device lay still (a log
that starts or ends on the desk), every row within a ball about the still
position (a few noise sigmas) is set aside before any fit, so that the log
calibrates like its motion alone; they are no outliers. Too few rows left in motion is
refused: the device hardly moved.

The report counts every row once (used + dropped + still + screened +
rejected = rows); the JSON's 'selection' lets 'magcal apply --flags' mark them.

Exit status: 0 success, 2 usage, I/O or parse error, 3 calibration refused.";

/// Calibrate a three-axis magnetometer from a recorded log.
///
/// Fits a hard-iron offset b and a symmetric soft-iron matrix W such that
/// W (raw - b) lies on the unit sphere.
#[derive(Debug, Parser)]
#[command(
    name = "magcal",
    version,
    propagate_version = true,
    subcommand_required = true,
    arg_required_else_help = true,
    flatten_help = true,
    disable_help_subcommand = true,
    after_help = AFTER_HELP
)]
pub struct Cli {
    /// What to do.
    #[command(subcommand)]
    pub command: Command,
}

/// The subcommands.
#[derive(Debug, Subcommand)]
pub enum Command {
    /// Fit a calibration to a file of raw samples and print it
    Fit(FitArgs),
    /// Apply a calibration (from 'magcal fit --format json') to a file of raw samples
    Apply(ApplyArgs),
    /// Re-estimate only the hard iron of a calibration from a file of raw samples
    Offsets(OffsetsArgs),
    /// Fit a heading-only calibration to turns about one axis (a car, a boat)
    Planar(PlanarArgs),
    /// Replay a log through the core's background calibrator, as firmware runs it
    Background(BackgroundArgs),
}

/// Options of `magcal fit`.
#[derive(Debug, Args)]
#[command(after_help = AFTER_HELP)]
pub struct FitArgs {
    /// Input file (CSV or whitespace separated), '-' for stdin
    #[arg(value_name = "FILE")]
    pub file: PathBuf,

    /// Calibration method
    #[arg(long, value_enum, default_value_t = MethodArg(Method::Adc2))]
    pub method: MethodArg,

    /// Least-squares ellipsoid fit: the 'ls' result, and the start of the other methods
    #[arg(long, value_enum, default_value_t = LsArg::Ls9)]
    pub ls: LsArg,

    /// Floating-point precision of the fit
    #[arg(long, value_enum, default_value_t = Precision::F64)]
    pub precision: Precision,

    /// Output format
    #[arg(long, value_enum, default_value_t = Format::Text)]
    pub format: Format,

    /// The x, y, z columns: header names or labels (magx,magy,magz), or field
    /// numbers from 1 (7,8,9) (default: the first three fields, or in wider
    /// rows the magnetometer columns the header names; see below)
    #[arg(long, value_name = "X,Y,Z", value_parser = parse_columns)]
    pub columns: Option<Columns>,

    /// Per-axis noise standard deviation, sensor units, for adc1 (a
    /// diagonal covariance); without it adc1 estimates the covariance from
    /// the LS residuals
    #[arg(long, value_name = "SX,SY,SZ", value_parser = parse_noise_std)]
    pub noise_std: Option<NoiseStd>,

    /// Also draw the samples before and after calibration into an SVG file
    /// (rows the fit did not use marked as red crosses)
    #[arg(long, value_name = "OUT.svg")]
    pub plot: Option<PathBuf>,

    /// Outlier handling off: trust every finite row, the paper's plain
    /// methods (no glitch rules, screening or residual rejection; rows too
    /// large for the precision are still dropped, and data that lie on no
    /// sphere are still refused)
    #[arg(long)]
    pub plain: bool,
}

/// Text after the help of `magcal apply`.
const APPLY_AFTER_HELP: &str = "\
CAL.json is what 'magcal fit --format json' prints; its hard_iron and
soft_iron are read (with --flags also its selection and precision). FILE is
read as by 'magcal fit', by the same rule for its x, y, z columns (see
'magcal fit --help').

Output: CSV on stdout, header 'x,y,z', then one calibrated sample per input
row: W (raw - b) on the unit sphere, or with --scaled times the field strength
(sensor units). When FILE has accelerometer columns (--accel-columns, or a
header holding accx,accy,accz / ax,ay,az / acc_x,acc_y,acc_z) two columns
follow: heading_deg, the tilt-compensated heading of the sensor's x axis from
magnetic north towards east, in degrees in (-180, 180] (empty where undefined:
non-finite or zero readings, field along gravity), and heading_smoothed_deg,
the circular mean of the last --window defined headings. The accelerometer
reading is the specific force at rest (pointing up; its unit does not matter).
The calibrated frame is the canonical one (symmetric W), not aligned to the
accelerometer's axes: for headings the two sensors must share right-handed
axes. Rows with non-finite values give 'nan' coordinates and an empty heading.

--flags adds two last columns: used (1 or 0) and class (used, dropped:RULE with
RULE one of non_finite, overflow, zero, rails, repeated, clipped; dwell, a
still period's row set aside; screened; rejected), what the fit did with each
row by the rules, still periods and limits of CAL.json's
'selection' applied to FILE, in the fit's precision. For the file that was
fitted, exactly samples_used rows are marked used (up to rounding at the
limit). A CAL.json without 'selection' (written before outlier handling)
marks every finite row used, and a note on stderr says so.

Exit status: 0 success, 2 usage, I/O, parse or calibration-file error.";

/// Largest `--window`: the capacity of the heading smoother.
const OFFSETS_AFTER_HELP: &str = "\
Keeps the soft iron of CAL.json (what 'magcal fit --format json' prints) and
re-estimates the hard iron from FILE (read as by 'magcal fit'), e.g. after a
part was magnetised. The readings need not cover the sphere: with the field
strength known (--strength known, the default) a cap of directions of about
20 deg half-angle determines the offsets; with it unknown, about a
hemisphere. Too small a cap is refused (exit 3) with its determinacy.

Output: the calibration (hard_iron, soft_iron, field_strength: what 'magcal
apply' reads) and the fit's figures.

Exit status: 0 success, 2 usage, I/O, parse or calibration-file error,
3 refused.";

/// `magcal offsets` arguments.
#[derive(Debug, Args)]
#[command(after_help = OFFSETS_AFTER_HELP)]
pub struct OffsetsArgs {
    /// Calibration JSON whose soft iron is kept
    #[arg(value_name = "CAL.json")]
    pub calibration: PathBuf,

    /// Raw samples ('-' for stdin)
    #[arg(value_name = "FILE")]
    pub file: PathBuf,

    /// Whether the field strength is that of CAL.json
    #[arg(long, value_enum, default_value_t = StrengthArg::Known)]
    pub strength: StrengthArg,

    /// Output format
    #[arg(long, value_enum, default_value_t = Format::Text)]
    pub format: Format,

    /// Magnetometer columns: header names or labels, or field numbers from 1
    /// (default: as for 'magcal fit')
    #[arg(long, value_name = "X,Y,Z", value_parser = parse_columns)]
    pub columns: Option<Columns>,
}

/// Options of `magcal planar`.
#[derive(Debug, Args)]
pub struct PlanarArgs {
    /// Raw samples taken while the device turned about one axis ('-' for stdin)
    #[arg(value_name = "FILE")]
    pub file: PathBuf,

    /// The sensor axis that points up while turning: it sets the sense of the
    /// heading (clockwise seen from above is positive)
    #[arg(long, value_enum, default_value_t = AxisArg::MinusZ, allow_hyphen_values = true)]
    pub up: AxisArg,

    /// Heading 0 at... : ROW:DEG gives sample ROW (0-based, in file order) the
    /// heading DEG; without it, heading 0 is an arbitrary turn angle
    #[arg(long, value_name = "ROW:DEG", value_parser = parse_align)]
    pub align: Option<(usize, f64)>,

    /// Floating-point precision of the fit
    #[arg(long, value_enum, default_value_t = Precision::F64)]
    pub precision: Precision,

    /// Output format
    #[arg(long, value_enum, default_value_t = Format::Text)]
    pub format: Format,

    /// Magnetometer columns: header names or labels, or field numbers from 1
    /// (default: as for 'magcal fit')
    #[arg(long, value_name = "X,Y,Z", value_parser = parse_columns)]
    pub columns: Option<Columns>,
}

/// Text after the help of `magcal background`.
const BACKGROUND_AFTER_HELP: &str = "\
Replays FILE (read as by 'magcal fit') row by row through the core's
background calibrator (mag_cal_core::background::Background, 48 direction
cells of 6 samples, default configuration), as firmware drives it: push each
reading, then one step (at most 32 buffered samples of work), as the
firmware example does. The refit under way after the last row is finished
(the steps of the readings that would follow). Rows are numbered from 0 in
file order, as 'magcal apply --flags' counts them.

Output: the row at which it first calibrated, each adoption (row, refit or
offsets-only re-estimate after a hard-iron change, the change of b and of the
field strength, its figures), the refits refused and why, the readings not
buffered (glitches, wild readings), and the final calibration as 'magcal fit'
prints it. --format json: one object with 'adoptions' (each with its 'row')
and 'final' (the fields of 'magcal fit --format json' that 'magcal apply'
reads: hard_iron, soft_iron, field_strength, quality, precision).

Exit status: 0 success, 2 usage, I/O or parse error, 3 no calibration adopted
(the report is printed, 'final' is null and 'reason' says why).";

/// Options of `magcal background`.
#[derive(Debug, Args)]
#[command(after_help = BACKGROUND_AFTER_HELP)]
pub struct BackgroundArgs {
    /// Raw samples in the order they were read ('-' for stdin)
    #[arg(value_name = "FILE")]
    pub file: PathBuf,

    /// Floating-point precision of the calibrator (f32 as on a
    /// microcontroller's FPU)
    #[arg(long, value_enum, default_value_t = Precision::F32)]
    pub precision: Precision,

    /// Calls of step after each push (1 as the firmware example: at most 32
    /// buffered samples of work a reading)
    #[arg(
        long,
        value_name = "N",
        default_value_t = 1,
        value_parser = clap::value_parser!(u32).range(1..=1000)
    )]
    pub steps: u32,

    /// Output format
    #[arg(long, value_enum, default_value_t = Format::Text)]
    pub format: Format,

    /// Magnetometer columns: header names or labels, or field numbers from 1
    #[arg(long, value_name = "X,Y,Z", value_parser = parse_columns)]
    pub columns: Option<Columns>,
}

/// `--up`: a sensor axis with its sign.
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum AxisArg {
    /// +x
    #[value(name = "x", alias = "+x")]
    X,
    /// -x
    #[value(name = "-x")]
    MinusX,
    /// +y
    #[value(name = "y", alias = "+y")]
    Y,
    /// -y
    #[value(name = "-y")]
    MinusY,
    /// +z
    #[value(name = "z", alias = "+z")]
    Z,
    /// -z (a sensor whose z axis points down, as NED)
    #[value(name = "-z")]
    MinusZ,
}

impl AxisArg {
    /// The unit vector.
    pub fn vector(self) -> [f64; 3] {
        match self {
            AxisArg::X => [1.0, 0.0, 0.0],
            AxisArg::MinusX => [-1.0, 0.0, 0.0],
            AxisArg::Y => [0.0, 1.0, 0.0],
            AxisArg::MinusY => [0.0, -1.0, 0.0],
            AxisArg::Z => [0.0, 0.0, 1.0],
            AxisArg::MinusZ => [0.0, 0.0, -1.0],
        }
    }

    /// The name `--up` takes.
    pub fn name(self) -> &'static str {
        match self {
            AxisArg::X => "x",
            AxisArg::MinusX => "-x",
            AxisArg::Y => "y",
            AxisArg::MinusY => "-y",
            AxisArg::Z => "z",
            AxisArg::MinusZ => "-z",
        }
    }
}

/// `--align ROW:DEG`.
pub fn parse_align(s: &str) -> Result<(usize, f64), String> {
    let (row, deg) = s
        .split_once(':')
        .ok_or_else(|| format!("expected ROW:DEG, e.g. 0:90, got '{s}'"))?;
    let row = row
        .trim()
        .parse::<usize>()
        .map_err(|_| format!("ROW must be a row index (0, 1, ...), got '{row}'"))?;
    let deg = deg
        .trim()
        .parse::<f64>()
        .ok()
        .filter(|d| d.is_finite())
        .ok_or_else(|| format!("DEG must be a finite number of degrees, got '{deg}'"))?;
    Ok((row, deg))
}

/// `--strength`: what is known of the field strength.
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum StrengthArg {
    /// That of the calibration (three unknowns)
    Known,
    /// Unknown (four unknowns; needs about a hemisphere)
    Unknown,
}

impl StrengthArg {
    /// The flag's value.
    pub fn name(self) -> &'static str {
        match self {
            StrengthArg::Known => "known",
            StrengthArg::Unknown => "unknown",
        }
    }
}

/// The largest `--window` of `apply` (headings smoothed over at most this
/// many readings).
pub const MAX_WINDOW: usize = 128;

/// Options of `magcal apply`.
#[derive(Debug, Args)]
#[command(after_help = APPLY_AFTER_HELP)]
pub struct ApplyArgs {
    /// Calibration: the JSON object printed by 'magcal fit --format json'
    #[arg(value_name = "CAL.json")]
    pub calibration: PathBuf,

    /// Input file of raw samples (CSV or whitespace separated), '-' for stdin
    #[arg(value_name = "FILE")]
    pub file: PathBuf,

    /// The x, y, z columns: header names or labels, or field numbers from 1
    /// (default: as for 'magcal fit')
    #[arg(long, value_name = "X,Y,Z", value_parser = parse_columns)]
    pub columns: Option<Columns>,

    /// The accelerometer columns: header names or labels, or field numbers
    /// from 1 (default: detected from the header); adds heading columns
    #[arg(long, value_name = "AX,AY,AZ", value_parser = parse_columns)]
    pub accel_columns: Option<Columns>,

    /// Samples in the heading's circular moving average, 1..=128
    #[arg(
        long,
        value_name = "W",
        default_value_t = default_window(),
        value_parser = clap::value_parser!(u16).range(1..=MAX_WINDOW as i64)
    )]
    pub window: u16,

    /// Print in sensor units (times the field strength), not on the unit sphere
    #[arg(long)]
    pub scaled: bool,

    /// Add the columns used (1/0) and class (used, dropped:RULE, dwell,
    /// screened, rejected): what the fit did with each row
    #[arg(long)]
    pub flags: bool,
}

/// The core's default smoothing window, as a `--window` value.
fn default_window() -> u16 {
    u16::try_from(mag_cal_core::heading::DEFAULT_WINDOW.min(MAX_WINDOW)).unwrap_or(15)
}

/// `--method`: a core [`Method`], by its core name.
///
/// The accepted names are [`Method::ALL`] through [`Method::name`], so a new
/// core method appears here (and in the help) without a change to the CLI;
/// [`method_help`] adds its one-line description.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct MethodArg(pub Method);

/// Every method the core offers, in [`Method::ALL`] order.
static METHODS: [MethodArg; Method::ALL.len()] = {
    let mut out = [MethodArg(Method::ALL[0]); Method::ALL.len()];
    let mut i = 1;
    while i < out.len() {
        out[i] = MethodArg(Method::ALL[i]);
        i += 1;
    }
    out
};

impl MethodArg {
    /// The core's method.
    pub fn to_core(self) -> Method {
        self.0
    }
}

impl ValueEnum for MethodArg {
    fn value_variants<'a>() -> &'a [Self] {
        &METHODS
    }

    fn to_possible_value(&self) -> Option<PossibleValue> {
        Some(PossibleValue::new(self.0.name()).help(method_help(self.0)))
    }
}

/// One line of help for `method` (empty for a method this CLI does not
/// know yet; its name is still accepted).
pub fn method_help(method: Method) -> &'static str {
    match method {
        Method::Ls => "Algebraic least-squares ellipsoid fit alone",
        Method::Adc1 => {
            "LS fit, artificial data, noise-weighted re-estimate (the paper's ADC1; \
             same minimiser as adc2)"
        }
        Method::Adc2 => "LS fit, then artificial-data re-estimation by quasi-Newton",
        Method::Adc2Iterated => {
            "ADC2 repeated to its fixed point: as accurate as submle, one pass per step"
        }
        Method::SubMle => {
            "Approximate maximum likelihood (Vasconcelos et al.), the paper's baseline; slowest"
        }
        _ => "",
    }
}

/// `--ls`: the least-squares variant of the core's first step.
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum LsArg {
    /// Constant term fixed, 9x9 solve (cheapest, best on partial coverage)
    Ls9,
    /// Smallest eigenvector of the 10x10 scatter
    Svd10,
    /// Li-Griffiths ellipsoid-specific fit, as in Magneto
    Lg10,
}

impl LsArg {
    /// The core's LS variant.
    pub fn to_core(self) -> LsVariant {
        match self {
            LsArg::Ls9 => LsVariant::Ls9,
            LsArg::Svd10 => LsVariant::Svd10,
            LsArg::Lg10 => LsVariant::LiGriffiths,
        }
    }
}

/// `--precision`: the scalar type the core computes in.
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum Precision {
    /// Single precision, as on a microcontroller's FPU
    F32,
    /// Double precision
    F64,
}

impl Precision {
    /// `f32` or `f64`.
    pub fn name(self) -> &'static str {
        match self {
            Precision::F32 => "f32",
            Precision::F64 => "f64",
        }
    }
}

/// `--format`: how the result is printed.
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum Format {
    /// A readable summary
    Text,
    /// One JSON object on one line
    Json,
}

/// `--columns`: three header names, labels or 1-based field numbers
/// (digits only), x, y, z in that order.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Columns(pub [String; 3]);

/// Parses `X,Y,Z` into three non-empty, trimmed names (the message says
/// what is expected); field numbers count from 1.
pub fn parse_columns(text: &str) -> Result<Columns, String> {
    let names: Vec<String> = text.split(',').map(|s| s.trim().to_owned()).collect();
    match <[String; 3]>::try_from(names) {
        Ok(names)
            if names
                .iter()
                .any(|n| n.bytes().all(|b| b == b'0') && !n.is_empty()) =>
        {
            Err("field numbers count from 1, e.g. 7,8,9".into())
        }
        Ok(names) if names.iter().all(|n| !n.is_empty()) => Ok(Columns(names)),
        _ => Err(
            "expected three comma-separated column names or field numbers, e.g. \
             magx,magy,magz or 7,8,9"
                .into(),
        ),
    }
}

/// `--noise-std`: three positive per-axis standard deviations.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct NoiseStd(pub [f64; 3]);

impl NoiseStd {
    /// The diagonal covariance `diag(s^2)`, sensor units squared.
    pub fn covariance(self) -> [[f64; 3]; 3] {
        let [x, y, z] = self.0.map(|s| s * s);
        [[x, 0.0, 0.0], [0.0, y, 0.0], [0.0, 0.0, z]]
    }
}

/// Parses `SX,SY,SZ` into three finite positive numbers whose squares are
/// finite and positive.
fn parse_noise_std(text: &str) -> Result<NoiseStd, String> {
    let values: Vec<Option<f64>> = text.split(',').map(|s| s.trim().parse().ok()).collect();
    match <[Option<f64>; 3]>::try_from(values) {
        Ok([Some(x), Some(y), Some(z)]) => {
            let std = [x, y, z];
            if std.iter().all(|&s| {
                let v = s * s;
                s > 0.0 && v.is_finite() && v > 0.0
            }) {
                Ok(NoiseStd(std))
            } else {
                Err(
                    "each standard deviation must be a positive number (squares \
                     within the range of f64)"
                        .into(),
                )
            }
        }
        _ => Err("expected three comma-separated numbers, e.g. 0.6,0.6,0.9".into()),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::CommandFactory;

    #[test]
    fn command_line_is_consistent() {
        Cli::command().debug_assert();
    }

    #[test]
    fn value_names_match_the_core_names() {
        for m in MethodArg::value_variants() {
            let name = m.to_possible_value().map(|v| v.get_name().to_owned());
            assert_eq!(name.as_deref(), Some(m.to_core().name()));
        }
        for v in LsArg::value_variants() {
            let name = v.to_possible_value().map(|p| p.get_name().to_owned());
            assert_eq!(name.as_deref(), Some(v.to_core().name()));
        }
        for p in Precision::value_variants() {
            let name = p.to_possible_value().map(|v| v.get_name().to_owned());
            assert_eq!(name.as_deref(), Some(p.name()));
        }
    }

    #[test]
    fn the_outlier_help_quotes_the_core_constants() {
        for (value, words) in [
            (mag_cal_core::CLEAN_LIMIT, "beyond {} robust standard"),
            (mag_cal_core::CLEAN_TAIL, "RMS at most {} of them"),
            (mag_cal_core::SCREEN_RADIUS, "farther than {} median"),
            (mag_cal_core::OUTLIER_CUT, "by more than {} robust standard"),
        ] {
            let phrase = words.replace("{}", &value.to_string());
            let help = AFTER_HELP.split_whitespace().collect::<Vec<_>>().join(" ");
            assert!(help.contains(&phrase), "{phrase}");
        }
    }

    #[test]
    fn columns_need_three_names() {
        assert_eq!(
            parse_columns(" magx, magy ,magz"),
            Ok(Columns(["magx".into(), "magy".into(), "magz".into()]))
        );
        assert!(parse_columns("a,b").is_err());
        assert!(parse_columns("a,,c").is_err());
        assert!(parse_columns("a,b,c,d").is_err());
        assert_eq!(
            parse_columns("7, 8,9"),
            Ok(Columns(["7".into(), "8".into(), "9".into()]))
        );
        assert!(parse_columns("0,1,2").is_err());
        assert!(parse_columns("1,00,2").is_err());
    }

    #[test]
    fn defaults() {
        let cli = Cli::try_parse_from(["magcal", "fit", "x.csv"]).expect("parses");
        let Command::Fit(args) = cli.command else {
            panic!("fit parses as fit");
        };
        assert_eq!(args.method, MethodArg(Method::Adc2));
        assert_eq!(args.ls, LsArg::Ls9);
        assert_eq!(args.precision, Precision::F64);
        assert_eq!(args.format, Format::Text);
        assert_eq!(args.columns, None);
        assert_eq!(args.noise_std, None);
        assert_eq!(args.plot, None);
        assert!(!args.plain);

        let cli = Cli::try_parse_from(["magcal", "apply", "c.json", "x.csv"]).expect("parses");
        let Command::Apply(args) = cli.command else {
            panic!("apply parses as apply");
        };
        assert_eq!(
            usize::from(args.window),
            mag_cal_core::heading::DEFAULT_WINDOW
        );
        assert!(!args.scaled && !args.flags && args.accel_columns.is_none());
    }

    #[test]
    fn every_core_method_is_accepted() {
        for method in Method::ALL {
            let cli = Cli::try_parse_from(["magcal", "fit", "x.csv", "--method", method.name()])
                .expect("parses");
            let Command::Fit(args) = cli.command else {
                panic!("fit parses as fit");
            };
            assert_eq!(args.method.to_core(), method);
            assert!(!method_help(method).is_empty(), "{method:?} has no help");
        }
    }

    #[test]
    fn window_is_bounded() {
        for (w, ok) in [
            ("1", true),
            ("128", true),
            ("0", false),
            ("129", false),
            ("x", false),
        ] {
            let r = Cli::try_parse_from(["magcal", "apply", "c", "f", "--window", w]);
            assert_eq!(r.is_ok(), ok, "{w}");
        }
    }

    #[test]
    fn noise_std_needs_three_positive_numbers() {
        assert_eq!(parse_noise_std("0.5, 1,2"), Ok(NoiseStd([0.5, 1.0, 2.0])));
        assert_eq!(
            NoiseStd([0.5, 1.0, 2.0]).covariance(),
            [[0.25, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 4.0]]
        );
        for bad in [
            "1,2",
            "1,2,3,4",
            "1,x,3",
            "0,1,1",
            "-1,1,1",
            "nan,1,1",
            "inf,1,1",
            "1e200,1,1",
            "1e-200,1,1",
        ] {
            assert!(parse_noise_std(bad).is_err(), "{bad}");
        }
    }
}
