//! The CLI's error type: what went wrong, the one-line message, the exit code.

use std::fmt;
use std::io;

/// Exit code for usage, I/O and parse errors.
pub const EXIT_USAGE: u8 = 2;
/// Exit code when the core refused to calibrate.
pub const EXIT_REFUSED: u8 = 3;

/// Everything that ends a run without a result.
///
/// [`Display`](fmt::Display) gives one line without the `magcal: ` prefix,
/// which `main` adds.
#[derive(Debug)]
pub enum CliError {
    /// The input could not be read.
    Read {
        /// File name as given, or `<stdin>`.
        source_name: String,
        /// The underlying error.
        err: io::Error,
    },
    /// A data line could not be parsed.
    Parse {
        /// 1-based line number in the input.
        line: usize,
        /// What is wrong with it.
        message: String,
    },
    /// The input as a whole does not fit the request (no data rows,
    /// `--columns` without a header, unknown column name, rows of more than
    /// three numeric fields without `--columns` and without one
    /// magnetometer triple in the header).
    Input(String),
    /// The report could not be written to stdout.
    Write(io::Error),
    /// An output file (the plot) could not be written.
    WriteFile {
        /// File name as given.
        path: String,
        /// The underlying error.
        err: io::Error,
    },
    /// The core refused to calibrate.
    Refused(mag_cal_core::Error),
    /// The core refused a planar calibration (`magcal planar`).
    PlanarRefused(mag_cal_core::planar::Error),
    /// A replay through the background calibrator ended without a
    /// calibration (`magcal background`): why, with the core's reason.
    NotCalibrated(String),
}

impl CliError {
    /// The process exit code for this error.
    pub fn exit_code(&self) -> i32 {
        match self {
            CliError::Refused(_) | CliError::PlanarRefused(_) | CliError::NotCalibrated(_) => {
                i32::from(EXIT_REFUSED)
            }
            _ => i32::from(EXIT_USAGE),
        }
    }
}

impl fmt::Display for CliError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            CliError::Read { source_name, err } => {
                write!(
                    f,
                    "cannot read {}: {}",
                    one_line(source_name),
                    io_reason(err)
                )
            }
            CliError::Parse { line, message } => write!(f, "line {line}: {message}"),
            CliError::Input(message) => f.write_str(message),
            CliError::Write(err) => write!(f, "cannot write output: {}", io_reason(err)),
            CliError::WriteFile { path, err } => {
                write!(f, "cannot write {}: {}", one_line(path), io_reason(err))
            }
            CliError::Refused(err @ mag_cal_core::Error::Planar { .. }) => write!(
                f,
                "calibration refused: {err} (a device that turns about one axis only: 'magcal planar')"
            ),
            CliError::Refused(err) => write!(f, "calibration refused: {err}"),
            CliError::PlanarRefused(err) => write!(f, "calibration refused: {err}"),
            CliError::NotCalibrated(reason) => write!(f, "no calibration: {reason}"),
        }
    }
}

impl std::error::Error for CliError {
    fn source(&self) -> Option<&(dyn std::error::Error + 'static)> {
        match self {
            CliError::Read { err, .. } | CliError::Write(err) | CliError::WriteFile { err, .. } => {
                Some(err)
            }
            CliError::Refused(err) => Some(err),
            CliError::PlanarRefused(err) => Some(err),
            CliError::Parse { .. } | CliError::Input(_) | CliError::NotCalibrated(_) => None,
        }
    }
}

impl From<mag_cal_core::Error> for CliError {
    fn from(err: mag_cal_core::Error) -> Self {
        CliError::Refused(err)
    }
}

impl From<mag_cal_core::planar::Error> for CliError {
    fn from(err: mag_cal_core::planar::Error) -> Self {
        CliError::PlanarRefused(err)
    }
}

/// `text` with control characters (line breaks, escapes) written as Rust
/// escapes, so that a message stays on one line.
pub fn one_line(text: &str) -> String {
    text.chars()
        .flat_map(|c| {
            let escaped: Vec<char> = if c.is_control() {
                c.escape_debug().collect()
            } else {
                vec![c]
            };
            escaped
        })
        .collect()
}

/// The operating system's reason without Rust's ` (os error N)` suffix:
/// `No such file or directory`.
fn io_reason(err: &io::Error) -> String {
    let text = err.to_string();
    match text.rsplit_once(" (os error ") {
        Some((reason, _)) if err.raw_os_error().is_some() => reason.to_owned(),
        _ => text,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn io_messages_drop_the_os_error_number() {
        let err = CliError::Read {
            source_name: "foo.csv".into(),
            err: io::Error::from_raw_os_error(2),
        };
        assert_eq!(
            err.to_string(),
            "cannot read foo.csv: No such file or directory"
        );
        assert_eq!(err.exit_code(), 2);
    }

    #[test]
    fn paths_stay_on_one_line() {
        let err = CliError::WriteFile {
            path: "a\nb\u{1b}.svg".into(),
            err: io::Error::from_raw_os_error(13),
        };
        assert_eq!(
            err.to_string(),
            "cannot write a\\nb\\u{1b}.svg: Permission denied"
        );
    }

    #[test]
    fn refusals_exit_3() {
        let err = CliError::from(mag_cal_core::Error::AllSamplesEqual);
        assert_eq!(err.exit_code(), 3);
        assert!(err.to_string().starts_with("calibration refused: "));
        // A planar refusal, its own or one it shares with the fit: the
        // same code, the same words.
        let shared = mag_cal_core::planar::Error::Fit(mag_cal_core::Error::AllSamplesEqual);
        let err = CliError::from(shared);
        assert_eq!(err.exit_code(), 3);
        assert_eq!(
            err.to_string(),
            CliError::from(mag_cal_core::Error::AllSamplesEqual).to_string()
        );
        let short = mag_cal_core::planar::Error::ShortArc {
            sectors: 7,
            required: 8,
        };
        assert_eq!(CliError::from(short).exit_code(), 3);
    }
}
