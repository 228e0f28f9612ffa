//! The `apply` subcommand: a calibration from `fit --format json`, applied
//! to every row of a file, with tilt-compensated headings when the file
//! has accelerometer columns.

use std::io::{BufWriter, Write};

use mag_cal_core::heading::{tilt_compensated_heading_deg, HeadingSmoother};
use mag_cal_core::nalgebra::{Matrix3, Vector3};
use mag_cal_core::Calibration;
use serde_json::Value;

use crate::cli::{ApplyArgs, MAX_WINDOW};
use crate::error::{one_line, CliError};
use crate::input::{self, Accel, Picked, Source};

/// Runs `magcal apply`, writing the CSV to `out`.
///
/// Returns a note for stderr when the sample columns were found in the
/// header.
pub fn run(args: &ApplyArgs, out: &mut dyn Write) -> Result<Option<String>, CliError> {
    let cal_source = Source::from_arg(&args.calibration);
    let source = Source::from_arg(&args.file);
    if cal_source == Source::Stdin && source == Source::Stdin {
        return Err(CliError::Input(
            "CAL.json and FILE cannot both be '-' (stdin)".into(),
        ));
    }
    let cal = calibration_from_json(&cal_source.read()?, &cal_source.name())?;
    let accel = match &args.accel_columns {
        Some(columns) => Accel::Named(columns),
        None => Accel::Detect,
    };
    let bytes = source.read()?;
    let table = input::parse_with_accel(&bytes, args.columns.as_ref(), accel, &source.name())?;
    let mut smoother = HeadingSmoother::<f64, MAX_WINDOW>::with_window(usize::from(args.window))
        .map_err(|err| CliError::Input(format!("--window {}: {err}", args.window)))?;

    let mut out = BufWriter::new(out);
    let write = |out: &mut BufWriter<&mut dyn Write>, line: &str| {
        out.write_all(line.as_bytes()).map_err(CliError::Write)
    };
    write(
        &mut out,
        if table.accel.is_some() {
            "x,y,z,heading_deg,heading_smoothed_deg\n"
        } else {
            "x,y,z\n"
        },
    )?;
    let mut line = String::new();
    for (row, raw) in table.samples.iter().enumerate() {
        let u = cal.apply(*raw);
        let v = if args.scaled {
            u * cal.field_strength()
        } else {
            u
        };
        line.clear();
        line.push_str(&format!("{},{},{}", number(v.x), number(v.y), number(v.z)));
        if let Some(accel) = &table.accel {
            let f = accel.get(row).copied().unwrap_or([f64::NAN; 3]);
            let heading =
                tilt_compensated_heading_deg(&u, &Vector3::from(f)).filter(|h| h.is_finite());
            // An undefined heading is not pushed: the smoothed column keeps
            // the mean of the last defined ones.
            let smoothed = match heading {
                Some(h) => smoother.push(h),
                None => smoother.mean(),
            }
            .filter(|h| h.is_finite());
            line.push_str(&format!(",{},{}", optional(heading), optional(smoothed)));
        }
        line.push('\n');
        write(&mut out, &line)?;
    }
    out.flush().map_err(CliError::Write)?;
    Ok((table.columns.picked == Picked::Header).then(|| format!("columns {}", table.columns)))
}

/// A CSV field: the shortest round-trip form, `nan` for non-finite values.
fn number(v: f64) -> String {
    if v.is_finite() {
        format!("{v}")
    } else {
        "nan".to_owned()
    }
}

/// A CSV field that is empty when undefined.
fn optional(v: Option<f64>) -> String {
    v.map(number).unwrap_or_default()
}

/// Rebuilds the calibration from the JSON object of `fit --format json`:
/// its `hard_iron` (3 numbers) and `soft_iron` (3 rows of 3 numbers);
/// other fields are ignored.
pub fn calibration_from_json(bytes: &[u8], name: &str) -> Result<Calibration<f64>, CliError> {
    let name = one_line(name);
    let bad = |what: String| CliError::Input(format!("{name}: {what}"));
    let value: Value = serde_json::from_slice(bytes)
        .map_err(|err| bad(format!("not a calibration (invalid JSON: {err})")))?;
    if !value.is_object() {
        return Err(bad(
            "not a calibration (expected the JSON object of 'magcal fit --format json')".into(),
        ));
    }
    let field = |key: &str| {
        value
            .get(key)
            .ok_or_else(|| bad(format!("missing field '{key}'")))
    };
    let row = |v: &Value| -> Option<[f64; 3]> {
        let a = v.as_array().filter(|a| a.len() == 3)?;
        Some([a[0].as_f64()?, a[1].as_f64()?, a[2].as_f64()?])
    };
    let b = row(field("hard_iron")?)
        .ok_or_else(|| bad("'hard_iron' must be an array of 3 numbers".into()))?;
    let w = field("soft_iron")?
        .as_array()
        .filter(|rows| rows.len() == 3)
        .and_then(|rows| Some([row(&rows[0])?, row(&rows[1])?, row(&rows[2])?]))
        .ok_or_else(|| bad("'soft_iron' must be 3 rows of 3 numbers".into()))?;
    Calibration::new(Vector3::from(b), Matrix3::from_fn(|r, c| w[r][c])).map_err(|err| {
        bad(format!(
            "hard_iron and soft_iron are not a calibration: {err}"
        ))
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    const CAL: &str = r#"{"method":"adc2","hard_iron":[10,0,0],"soft_iron":[[0.5,0,0],[0,0.5,0],[0,0,0.5]],"x":null}"#;

    #[test]
    fn reads_the_fit_json() {
        let cal = calibration_from_json(CAL.as_bytes(), "c.json").expect("valid");
        assert_eq!(cal.apply([12.0, 0.0, 0.0]), Vector3::new(1.0, 0.0, 0.0));
        assert_eq!(cal.field_strength(), 2.0);
    }

    #[test]
    fn bad_files_name_the_problem() {
        for (text, reason) in [
            ("", "invalid JSON"),
            ("{", "invalid JSON"),
            ("[1,2,3]", "expected the JSON object"),
            (r#"{"soft_iron":[]}"#, "missing field 'hard_iron'"),
            (r#"{"hard_iron":[1,2,3]}"#, "missing field 'soft_iron'"),
            (
                r#"{"hard_iron":[1,2],"soft_iron":[]}"#,
                "'hard_iron' must be",
            ),
            (
                r#"{"hard_iron":[1,2,"3"],"soft_iron":[]}"#,
                "'hard_iron' must be",
            ),
            (
                r#"{"hard_iron":[1,2,3],"soft_iron":[[1,0,0],[0,1,0]]}"#,
                "'soft_iron' must be",
            ),
            (
                r#"{"hard_iron":[1,2,3],"soft_iron":[[1,0,0],[0,1,0],[0,0,null]]}"#,
                "'soft_iron' must be",
            ),
            (
                r#"{"hard_iron":[1,2,3],"soft_iron":[[1,0,0],[0,1,0],[0,0,0]]}"#,
                "not a calibration",
            ),
            (
                r#"{"hard_iron":[1,2,3],"soft_iron":[[1e300,0,0],[0,1e300,0],[0,0,1e300]]}"#,
                "not a calibration",
            ),
        ] {
            let err = calibration_from_json(text.as_bytes(), "c.json").unwrap_err();
            let msg = err.to_string();
            assert!(
                msg.starts_with("c.json: ") && msg.contains(reason),
                "{text}: {msg}"
            );
            assert_eq!(msg.lines().count(), 1, "{msg}");
            assert_eq!(err.exit_code(), 2);
        }
    }

    #[test]
    fn fields_print_nan_and_empty() {
        assert_eq!(number(0.25), "0.25");
        assert_eq!(number(f64::NAN), "nan");
        assert_eq!(number(f64::NEG_INFINITY), "nan");
        assert_eq!(optional(None), "");
        assert_eq!(optional(Some(-90.0)), "-90");
    }
}
