//! The `apply` subcommand: a calibration from `fit --format json`, applied
//! to every row of a file, with tilt-compensated headings when the file
//! has accelerometer columns, and with `--flags` what the fit did with
//! each row.

use std::io::{BufWriter, Write};
use std::path::Path;

use mag_cal_core::heading::{tilt_compensated_heading_deg, HeadingSmoother};
use mag_cal_core::{Calibration, Real, SampleClass};
use nalgebra::{Matrix3, Vector3};
use serde_json::Value;

use crate::cli::{ApplyArgs, Precision, MAX_WINDOW};
use crate::error::{one_line, CliError};
use crate::input::{self, Accel, Source};
use crate::selection::{class_name, SelectionJson};

/// Runs `magcal apply`, writing the CSV to `out`.
///
/// Returns notes for stderr: when the sample columns were found in the
/// header, and when `--flags` found no `selection` in the calibration.
pub fn run(args: &ApplyArgs, out: &mut dyn Write) -> Result<Vec<String>, CliError> {
    let (cal_source, source) = sources(&args.calibration, &args.file)?;
    let cal_name = cal_source.name();
    let cal_json = read_json(&cal_source.read()?, &cal_name)?;
    if cal_json.get("method").and_then(Value::as_str) == Some("planar") {
        return crate::planar::apply(args, &cal_json, &cal_name, &source, out);
    }
    let cal = calibration_from_value(&cal_json, &cal_name)?;
    let mut notes = Vec::new();
    let flags = if args.flags {
        let flags = RowFlags::from_value(&cal_json, &cal_name)?;
        if flags.legacy {
            notes.push(format!(
                "{} has no 'selection' (written before outlier handling): \
                 --flags marks every finite row used",
                one_line(&cal_name)
            ));
        }
        Some(flags)
    } else {
        None
    };
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
    let classes = match &flags {
        Some(flags) => Some(flags.classify(&table.samples, &cal_name)?),
        None => None,
    };
    let mut header = String::from("x,y,z");
    if table.accel.is_some() {
        header.push_str(",heading_deg,heading_smoothed_deg");
    }
    if classes.is_some() {
        header.push_str(",used,class");
    }
    header.push('\n');
    write(&mut out, &header)?;
    let mut line = String::new();
    for (row, raw) in table.samples.iter().enumerate() {
        let u = cal.apply_vector(*raw);
        let v = if args.scaled {
            u * cal.field_strength()
        } else {
            u
        };
        line.clear();
        line.push_str(&format!("{},{},{}", number(v.x), number(v.y), number(v.z)));
        if let Some(accel) = &table.accel {
            let f = accel.get(row).copied().unwrap_or([f64::NAN; 3]);
            let heading = tilt_compensated_heading_deg(u.into(), f).filter(|h| h.is_finite());
            // An undefined heading is not pushed: the smoothed column keeps
            // the mean of the last defined ones.
            let smoothed = match heading {
                Some(h) => smoother.push(h),
                None => smoother.mean(),
            }
            .filter(|h| h.is_finite());
            line.push_str(&format!(",{},{}", optional(heading), optional(smoothed)));
        }
        if let Some(class) = classes.as_ref().and_then(|c| c.get(row)) {
            let used = u8::from(*class == SampleClass::Used);
            line.push_str(&format!(",{used},{}", class_name(*class)));
        }
        line.push('\n');
        write(&mut out, &line)?;
    }
    out.flush().map_err(CliError::Write)?;
    if let Some(skipped) = table.skipped.note() {
        notes.insert(0, format!("input: {skipped}"));
    }
    if table.columns.detected() {
        notes.insert(0, format!("columns {}", table.columns));
    }
    Ok(notes)
}

/// What `--flags` needs from the calibration file: the fit's selection,
/// precision and parameters.
#[derive(Clone, Debug, PartialEq)]
struct RowFlags {
    selection: SelectionJson,
    precision: Precision,
    hard_iron: [f64; 3],
    soft_iron: [[f64; 3]; 3],
    /// The file has no `selection` (an older file): [`SelectionJson::ALL`].
    legacy: bool,
}

impl RowFlags {
    /// Reads the `selection` and `precision` of a fit JSON whose
    /// calibration [`calibration_from_value`] accepted.
    fn from_value(value: &Value, name: &str) -> Result<Self, CliError> {
        let bad = |what: String| CliError::Input(format!("{}: {what}", one_line(name)));
        let (selection, legacy) = match value.get("selection") {
            None => (SelectionJson::ALL, true),
            Some(v) => (SelectionJson::from_json(v).map_err(bad)?, false),
        };
        let precision = match value.get("precision") {
            None => Precision::F64,
            Some(v) => match v.as_str() {
                Some("f64") => Precision::F64,
                Some("f32") => Precision::F32,
                _ => return Err(bad("'precision' must be \"f32\" or \"f64\"".into())),
            },
        };
        let (hard_iron, soft_iron) = parameters(value).map_err(bad)?;
        Ok(Self {
            selection,
            precision,
            hard_iron,
            soft_iron,
            legacy,
        })
    }

    /// The class of every row, computed as the fit did: the core's
    /// [`mag_cal_core::Selection::classify`] in the fit's precision, with
    /// the still periods ([`SelectionJson::classify`]).
    fn classify(&self, samples: &[[f64; 3]], name: &str) -> Result<Vec<SampleClass>, CliError> {
        match self.precision {
            Precision::F32 => self.classify_in::<f32>(samples, name),
            Precision::F64 => self.classify_in::<f64>(samples, name),
        }
    }

    fn classify_in<T: Real>(
        &self,
        samples: &[[f64; 3]],
        name: &str,
    ) -> Result<Vec<SampleClass>, CliError> {
        let b = Vector3::from(self.hard_iron.map(T::lit));
        let w = Matrix3::from_fn(|r, c| T::lit(self.soft_iron[r][c]));
        let cal = Calibration::from_nalgebra(b, w).map_err(|err| {
            CliError::Input(format!(
                "{}: hard_iron and soft_iron are not a calibration in {}: {err}",
                one_line(name),
                self.precision.name()
            ))
        })?;
        // The rows as the fit would read them (integer counts as i16).
        Ok(match crate::fit::counts(samples) {
            Some(ints) => self.selection.classify(&cal, &ints),
            None => self.selection.classify(&cal, samples),
        })
    }
}

/// A CSV field: the shortest round-trip form, `nan` for non-finite values.
pub(crate) fn number(v: f64) -> String {
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

/// Parses a calibration file: the JSON object of `fit --format json`.
/// The sources of a calibration file and a sample file, which cannot both
/// be stdin.
pub(crate) fn sources(calibration: &Path, file: &Path) -> Result<(Source, Source), CliError> {
    let cal_source = Source::from_arg(calibration);
    let source = Source::from_arg(file);
    if cal_source == Source::Stdin && source == Source::Stdin {
        return Err(CliError::Input(
            "CAL.json and FILE cannot both be '-' (stdin)".into(),
        ));
    }
    Ok((cal_source, source))
}

pub(crate) fn read_json(bytes: &[u8], name: &str) -> Result<Value, CliError> {
    let bad = |what: String| CliError::Input(format!("{}: {what}", one_line(name)));
    let value: Value = serde_json::from_slice(bytes)
        .map_err(|err| bad(format!("not a calibration (invalid JSON: {err})")))?;
    if !value.is_object() {
        return Err(bad(
            "not a calibration (expected the JSON object of 'magcal fit --format json')".into(),
        ));
    }
    Ok(value)
}

/// The `hard_iron` (3 numbers) and `soft_iron` (3 rows of 3 numbers) of a
/// fit JSON object, or what is wrong with them.
fn parameters(value: &Value) -> Result<([f64; 3], [[f64; 3]; 3]), String> {
    let field = |key: &str| value.get(key).ok_or(format!("missing field '{key}'"));
    let row = |v: &Value| -> Option<[f64; 3]> {
        let a = v.as_array().filter(|a| a.len() == 3)?;
        Some([a[0].as_f64()?, a[1].as_f64()?, a[2].as_f64()?])
    };
    let b = row(field("hard_iron")?).ok_or("'hard_iron' must be an array of 3 numbers")?;
    let w = field("soft_iron")?
        .as_array()
        .filter(|rows| rows.len() == 3)
        .and_then(|rows| Some([row(&rows[0])?, row(&rows[1])?, row(&rows[2])?]))
        .ok_or("'soft_iron' must be 3 rows of 3 numbers")?;
    Ok((b, w))
}

/// Rebuilds the calibration from the JSON object of `fit --format json`:
/// its `hard_iron` and `soft_iron`; other fields are ignored.
pub(crate) fn calibration_from_value(
    value: &Value,
    name: &str,
) -> Result<Calibration<f64>, CliError> {
    let bad = |what: String| CliError::Input(format!("{}: {what}", one_line(name)));
    let (b, w) = parameters(value).map_err(bad)?;
    Calibration::from_nalgebra(Vector3::from(b), Matrix3::from_fn(|r, c| w[r][c])).map_err(|err| {
        bad(format!(
            "hard_iron and soft_iron are not a calibration: {err}"
        ))
    })
}

/// [`calibration_from_value`] on the bytes of a calibration file.
#[cfg(test)]
fn calibration_from_json(bytes: &[u8], name: &str) -> Result<Calibration<f64>, CliError> {
    calibration_from_value(&read_json(bytes, name)?, name)
}

#[cfg(test)]
mod tests {
    use super::*;

    const CAL: &str = r#"{"method":"adc2","hard_iron":[10,0,0],"soft_iron":[[0.5,0,0],[0,0.5,0],[0,0,0.5]],"x":null}"#;

    #[test]
    fn reads_the_fit_json() {
        let cal = calibration_from_json(CAL.as_bytes(), "c.json").expect("valid");
        assert_eq!(
            cal.apply_vector([12.0, 0.0, 0.0]),
            Vector3::new(1.0, 0.0, 0.0)
        );
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
    fn flags_read_the_selection_in_the_fit_precision() {
        let v: Value = serde_json::from_str(CAL).expect("json");
        // No selection: every finite row used, and the file is marked old.
        let flags = RowFlags::from_value(&v, "c.json").expect("reads");
        assert!(flags.legacy && flags.selection == SelectionJson::ALL);
        assert_eq!(flags.precision, Precision::F64);
        let rows = [[12.0, 0.0, 0.0], [f64::NAN, 0.0, 0.0], [14.0, 0.0, 0.0]];
        let classes = flags.classify(&rows, "c.json").expect("classifies");
        assert_eq!(
            classes,
            [
                SampleClass::Used,
                SampleClass::Dropped(mag_cal_core::Rule::NonFinite),
                SampleClass::Used
            ]
        );
        // A residual limit: |u| = 2 for the last row, residual 1.
        let mut v = v;
        v["precision"] = "f32".into();
        v["selection"] = serde_json::json!({
            "glitch_rules": true,
            "clip_levels": [[null, null], [null, null], [null, null]],
            "screen": null,
            "residual_limit": 0.5
        });
        let flags = RowFlags::from_value(&v, "c.json").expect("reads");
        assert!(!flags.legacy);
        assert_eq!(flags.precision, Precision::F32);
        let classes = flags.classify(&rows, "c.json").expect("classifies");
        assert_eq!(classes[2], SampleClass::Rejected);
        // 1e39 is finite in f64, not in f32: the f32 rules drop it.
        let big = flags
            .classify(&[[1e39, 0.0, 0.0]], "c.json")
            .expect("classifies");
        assert_eq!(big, [SampleClass::Dropped(mag_cal_core::Rule::NonFinite)]);
        v["precision"] = 32.into();
        let err = RowFlags::from_value(&v, "c.json").unwrap_err().to_string();
        assert!(err.starts_with("c.json: 'precision' must be"), "{err}");
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
