//! `magcal`: calibrate recorded magnetometer logs with [`mag_cal_core`].
//!
//! The library behind the `magcal` binary and the web page
//! (`mag-cal-web`), which runs the same parser, fit summary and JSON in the
//! browser. It has no numerics of its own: it parses the command line and
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
//! | [`offsets`], [`planar`] | the `offsets` and `planar` subcommands |
//! | [`background`] | the `background` subcommand: a log replayed through the core's background calibrator |
//!
//! Exit codes: 0 success, 2 usage, I/O or parse error, 3 calibration refused
//! by the core. Every failure prints one line on stderr naming the reason
//! (clap's usage errors start with such a line and add a usage hint). A
//! success prints nothing on stderr, except `magcal: note: ...` lines: one
//! `columns ...` when the sample columns were found in the header or among
//! labelled values and the output does not say so (`fit --format json`,
//! `apply`, `planar --format json`), one `input: ...` naming lines that were
//! no samples, and one for `apply --flags` with a calibration file that has
//! no `selection`.

#![warn(missing_docs)]

pub mod apply;
pub mod background;
pub mod cli;
pub mod error;
pub mod fit;
pub mod input;
pub mod offsets;
pub mod output;
pub mod planar;
pub mod selection;
pub mod svg;
