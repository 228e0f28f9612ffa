//! `magcal`: calibrate recorded magnetometer logs with [`mag_cal_core`].
//!
//! The binary has no numerics of its own: it parses the command line and
//! the input file, calls [`mag_cal_core::calibrate`] (or rebuilds a
//! calibration and applies it), and formats the result.
//!
//! | module | what |
//! |---|---|
//! | [`cli`] | the command line: subcommands, options, name-to-method mapping |
//! | [`input`] | reading a file or stdin and parsing it into samples |
//! | [`fit`] | the `fit` subcommand: one call to the core, timed |
//! | [`output`] | the text (for people) and JSON (for programs) reports |
//! | [`svg`] | `fit --plot`: the samples before and after, as SVG |
//! | [`selection`] | which rows a fit used: drop counts, the JSON `selection`, row classes |
//! | [`apply`] | the `apply` subcommand: calibrated samples, headings and row flags as CSV |
//! | [`error`] | the error type and its exit codes |
//!
//! Exit codes: 0 success, 2 usage, I/O or parse error, 3 calibration refused
//! by the core. Every failure prints one line on stderr naming the reason
//! (clap's usage errors start with such a line and add a usage hint). A
//! success prints nothing on stderr, except `magcal: note: ...` lines: one
//! `columns ...` when the sample columns were found in the header and the
//! output does not say so (`fit --format json`, `apply`), and one for
//! `apply --flags` with a calibration file that has no `selection`.

mod apply;
mod cli;
mod error;
mod fit;
mod input;
mod offsets;
mod output;
mod planar;
mod selection;
mod svg;

use std::io::Write;
use std::process::ExitCode;

use clap::Parser;

use crate::cli::{Cli, Command};
use crate::error::CliError;

fn main() -> ExitCode {
    let cli = match Cli::try_parse() {
        Ok(cli) => cli,
        Err(err) => {
            // Help and version go to stdout with code 0; usage errors to
            // stderr with code 2. A failed write is nothing left to report.
            let _ = err.print();
            return exit_code(err.exit_code());
        }
    };
    match run(cli) {
        Ok(notes) => {
            // After the output, so that a failure stays one line on stderr.
            for note in notes {
                let _ = writeln!(std::io::stderr(), "magcal: note: {note}");
            }
            ExitCode::SUCCESS
        }
        Err(err) => {
            let _ = writeln!(std::io::stderr(), "magcal: {err}");
            exit_code(err.exit_code())
        }
    }
}

/// Dispatches a parsed command line to its subcommand; returns its notes
/// for stderr, if any.
fn run(cli: Cli) -> Result<Vec<String>, CliError> {
    match cli.command {
        Command::Fit(args) => fit::run(&args, &mut std::io::stdout().lock()),
        Command::Apply(args) => apply::run(&args, &mut std::io::stdout().lock()),
        Command::Offsets(args) => offsets::run(&args, &mut std::io::stdout().lock()),
        Command::Planar(args) => planar::run(&args, &mut std::io::stdout().lock()),
    }
}

/// Maps an `i32` process status onto [`ExitCode`] (anything outside
/// `0..=255` becomes the usage-error code 2).
fn exit_code(code: i32) -> ExitCode {
    ExitCode::from(u8::try_from(code).unwrap_or(error::EXIT_USAGE))
}
