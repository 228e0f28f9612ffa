//! `magcal`: the command line over the [`mag_cal_cli`] library.

use std::io::Write;
use std::process::ExitCode;

use clap::Parser;

use mag_cal_cli::cli::{Cli, Command};
use mag_cal_cli::error::{self, CliError};
use mag_cal_cli::{apply, background, fit, offsets, planar};

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
        Command::Background(args) => background::run(&args, &mut std::io::stdout().lock()),
    }
}

/// Maps an `i32` process status onto [`ExitCode`] (anything outside
/// `0..=255` becomes the usage-error code 2).
fn exit_code(code: i32) -> ExitCode {
    ExitCode::from(u8::try_from(code).unwrap_or(error::EXIT_USAGE))
}
