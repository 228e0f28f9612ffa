//! The command line: subcommands, options and the names they accept.
//!
//! Each option value is a small [`ValueEnum`] whose names clap checks
//! (a bad value is a usage error, exit 2) and which maps onto the core's
//! type. A new core method is one more variant of [`MethodArg`] and one
//! more arm in [`MethodArg::to_core`]; a new subcommand is one more variant
//! of [`Command`].

use std::path::PathBuf;

use clap::{Args, Parser, Subcommand, ValueEnum};
use mag_cal_core::{LsVariant, Method};

/// Text after the top-level help.
const AFTER_HELP: &str = "\
Input: CSV or whitespace/tab/semicolon separated text, one sample per line,
'-' for stdin. Lines starting with '#' and blank lines are skipped. The first
other line is a header when any of its fields is not a number. Without
--columns the first three columns are x, y, z; with --columns X,Y,Z they are
picked by header name (case-insensitive). 'nan' and 'inf' are accepted and
skipped by the fit (counted as dropped).

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
}

/// Options of `magcal fit`.
#[derive(Debug, Args)]
#[command(after_help = AFTER_HELP)]
pub struct FitArgs {
    /// Input file (CSV or whitespace separated), '-' for stdin
    #[arg(value_name = "FILE")]
    pub file: PathBuf,

    /// Calibration method
    #[arg(long, value_enum, default_value_t = MethodArg::Adc2)]
    pub method: MethodArg,

    /// Least-squares ellipsoid fit used by 'ls' and as the start of 'adc2'
    #[arg(long, value_enum, default_value_t = LsArg::Ls9)]
    pub ls: LsArg,

    /// Floating-point precision of the fit
    #[arg(long, value_enum, default_value_t = Precision::F64)]
    pub precision: Precision,

    /// Output format
    #[arg(long, value_enum, default_value_t = Format::Text)]
    pub format: Format,

    /// Header names of the x, y, z columns, e.g. magx,magy,magz
    #[arg(long, value_name = "X,Y,Z", value_parser = parse_columns)]
    pub columns: Option<Columns>,
}

/// `--method`: the calibration method, by its core name.
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum MethodArg {
    /// Algebraic least-squares ellipsoid fit alone
    Ls,
    /// LS fit, then artificial-data re-estimation by quasi-Newton
    Adc2,
}

impl MethodArg {
    /// The core's method.
    pub fn to_core(self) -> Method {
        match self {
            MethodArg::Ls => Method::Ls,
            MethodArg::Adc2 => Method::Adc2,
        }
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

/// `--columns`: three header names, x, y, z in that order.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Columns(pub [String; 3]);

/// Parses `X,Y,Z` into three non-empty, trimmed names.
fn parse_columns(text: &str) -> Result<Columns, String> {
    let names: Vec<String> = text.split(',').map(|s| s.trim().to_owned()).collect();
    match <[String; 3]>::try_from(names) {
        Ok(names) if names.iter().all(|n| !n.is_empty()) => Ok(Columns(names)),
        _ => Err("expected three comma-separated column names, e.g. magx,magy,magz".into()),
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
    fn columns_need_three_names() {
        assert_eq!(
            parse_columns(" magx, magy ,magz"),
            Ok(Columns(["magx".into(), "magy".into(), "magz".into()]))
        );
        assert!(parse_columns("a,b").is_err());
        assert!(parse_columns("a,,c").is_err());
        assert!(parse_columns("a,b,c,d").is_err());
    }

    #[test]
    fn defaults() {
        let cli = Cli::try_parse_from(["magcal", "fit", "x.csv"]).expect("parses");
        let Command::Fit(args) = cli.command;
        assert_eq!(args.method, MethodArg::Adc2);
        assert_eq!(args.ls, LsArg::Ls9);
        assert_eq!(args.precision, Precision::F64);
        assert_eq!(args.format, Format::Text);
        assert_eq!(args.columns, None);
    }
}
