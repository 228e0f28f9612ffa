//! `magcal planar`: a heading-only calibration from turns about one axis
//! (`mag_cal_core::planar`), and its use by `magcal apply`.

use std::io::Write;

use mag_cal_core::heading::HeadingSmoother;
use mag_cal_core::planar::{calibrate_planar, PlanarCalibration, PlanarConfig, PlanarFit};
use mag_cal_core::Real;
use serde_json::{json, Value};

use crate::apply::number;
use crate::cli::{ApplyArgs, Format, PlanarArgs, Precision, MAX_WINDOW};
use crate::error::{one_line, CliError};
use crate::input::{self, Source};
use crate::selection::DropCounts;

/// Runs `magcal planar`.
pub fn run(args: &PlanarArgs, out: &mut dyn Write) -> Result<Vec<String>, CliError> {
    let source = Source::from_arg(&args.file);
    let table = input::parse(&source.read()?, args.columns.as_ref(), &source.name())?;
    let text = outputs(&table, &source.name(), args, &[args.format])?.concat();
    out.write_all(text.as_bytes()).map_err(CliError::Write)?;
    // As `magcal fit`: where the text does not say which columns were read;
    // and the lines that were no samples.
    Ok((args.format == Format::Json && table.columns.detected())
        .then(|| format!("columns {}", table.columns))
        .into_iter()
        .chain(table.skipped.note().map(|s| format!("input: {s}")))
        .collect())
}

/// What `magcal planar` prints for samples already read, in each of
/// `formats`, from one fit (`args.format` and `args.file` are not read;
/// `name` names the input in the text). The page (`mag-cal-web`) shows the
/// text and saves the JSON.
pub fn outputs(
    table: &input::Table,
    name: &str,
    args: &PlanarArgs,
    formats: &[Format],
) -> Result<Vec<String>, CliError> {
    let config = PlanarConfig::with_up(args.up.vector());
    match args.precision {
        Precision::F64 => {
            let fit = calibrate_planar::<f64, _>(&table.samples, &config);
            let fit = fit.map_err(CliError::PlanarRefused)?;
            formats
                .iter()
                .map(|&format| render(fit, args, format, table, name))
                .collect()
        }
        Precision::F32 => {
            let rows: Vec<[f32; 3]> = table.samples.iter().map(|s| s.map(|v| v as f32)).collect();
            let fit = calibrate_planar::<f32, _>(&rows, &config);
            let fit = fit.map_err(CliError::PlanarRefused)?;
            formats
                .iter()
                .map(|&format| render(fit, args, format, table, name))
                .collect()
        }
    }
}

/// The output of a fit in precision `T`, aligned as `--align` asks.
fn render<T: Real>(
    fit: PlanarFit<T>,
    args: &PlanarArgs,
    format: Format,
    table: &input::Table,
    name: &str,
) -> Result<String, CliError> {
    let mut cal = fit.calibration;
    if let Some((row, deg)) = args.align {
        let sample = table.samples.get(row).ok_or_else(|| {
            CliError::Input(format!(
                "--align {row}:{deg}: the file has {} samples (rows 0..{})",
                table.samples.len(),
                table.samples.len().saturating_sub(1)
            ))
        })?;
        cal = cal
            .aligned(*sample, T::lit(deg))
            .map_err(CliError::Refused)?;
    }
    let r = fit.report;
    let f = |v: T| v.to_f64();
    let v3 = |v: [T; 3]| v.map(f);
    let text = match format {
        Format::Json => {
            let v = json!({
                "method": "planar",
                "precision": args.precision.name(),
                "up": args.up.name(),
                "axis": v3(cal.axis()),
                "centre": v3(cal.centre()),
                "matrix": cal.matrix().map(v3),
                "zero_deg": f(cal.zero_deg()),
                "plane_strength": f(cal.plane_strength()),
                "out_of_plane_offset": Value::Null,
                "samples_used": r.samples_used,
                "samples_dropped": r.drops.total(),
                "drops": DropCounts(r.drops),
                "dwell": r.dwell,
                "screened": r.screened,
                "rejected": r.rejected,
                "flatness": f(r.flatness),
                "fit_error": f(r.fit_error),
                "sectors": r.sectors,
                "thickness": f(r.thickness),
                "axis_tilt_deg": f(r.axis_tilt_deg),
                "passes": r.passes,
                "columns": table.columns.to_string(),
            });
            format!("{v}\n")
        }
        Format::Text => {
            let [ax, ay, az] = v3(cal.axis());
            let [cx, cy, cz] = v3(cal.centre());
            let [k0, k1] = cal.matrix().map(v3);
            let drops: Vec<String> = DropCounts(r.drops)
                .by_rule()
                .filter(|&(_, n)| n > 0)
                .map(|(rule, n)| format!("{n} {}", rule.name()))
                .collect();
            let dropped = if drops.is_empty() {
                String::new()
            } else {
                format!(" ({})", drops.join(", "))
            };
            let zero = match args.align {
                Some((row, deg)) => format!("row {row} at {deg} deg"),
                None => "arbitrary (set it with --align ROW:DEG)".into(),
            };
            format!(
                "planar (heading-only) calibration of {} (columns {}): u = K (raw - centre), heading = angle(u) - zero\n  \
                 turn axis     [{ax:.4}, {ay:.4}, {az:.4}] ({:.1} deg from {})\n  \
                 centre        [{cx:.4}, {cy:.4}, {cz:.4}] (in-plane hard iron; the offset along the axis is not observable)\n  \
                 K             [{:.6}, {:.6}, {:.6}]\n                \
                 [{:.6}, {:.6}, {:.6}]\n  \
                 zero          {:.3} deg: {zero}\n  \
                 field         {:.4} in the plane\n  \
                 samples       {} used of {}: {} dropped{dropped}, {} still, {} screened, {} rejected\n  \
                 fit error     {:.4} of the field in the plane\n  \
                 flatness      {:.4} (thickness {:.4} of the field in the plane)\n  \
                 coverage      {} of 12 sectors of 30 deg\n",
                name,
                table.columns,
                f(r.axis_tilt_deg),
                args.up.name(),
                k0[0],
                k0[1],
                k0[2],
                k1[0],
                k1[1],
                k1[2],
                f(cal.zero_deg()),
                f(cal.plane_strength()),
                r.samples_used,
                table.samples.len(),
                r.drops.total(),
                r.dwell,
                r.screened,
                r.rejected,
                f(r.fit_error),
                f(r.flatness),
                f(r.thickness),
                r.sectors,
            )
        }
    };
    Ok(text)
}

/// `magcal apply` with a calibration of `magcal planar`: per row `u` (times
/// the field in the plane with `--scaled`), the heading and its smoothed
/// value.
pub fn apply(
    args: &ApplyArgs,
    cal_json: &Value,
    cal_name: &str,
    source: &Source,
    out: &mut dyn Write,
) -> Result<Vec<String>, CliError> {
    let bad = |what: &str| CliError::Input(format!("{}: {what}", one_line(cal_name)));
    if args.flags || args.accel_columns.is_some() {
        return Err(bad(
            "a planar calibration has no per-row selection and no tilt compensation: \
             --flags and --accel-columns do not apply",
        ));
    }
    let cal = planar_from_value(cal_json).map_err(|what| bad(&what))?;
    let table = input::parse(&source.read()?, args.columns.as_ref(), &source.name())?;
    let mut smoother = HeadingSmoother::<f64, MAX_WINDOW>::with_window(usize::from(args.window))
        .map_err(|err| CliError::Input(format!("--window {}: {err}", args.window)))?;
    let scale = if args.scaled {
        cal.plane_strength()
    } else {
        1.0
    };
    let mut text = String::from("u,v,heading_deg,heading_smoothed_deg\n");
    for raw in &table.samples {
        let [u, v] = cal.apply(*raw);
        let heading = (u.is_finite() && v.is_finite()).then(|| cal.heading_deg(*raw));
        let smoothed = match heading {
            Some(h) => smoother.push(h),
            None => smoother.mean(),
        };
        let opt = |h: Option<f64>| h.map(number).unwrap_or_default();
        text.push_str(&format!(
            "{},{},{},{}\n",
            number(u * scale),
            number(v * scale),
            opt(heading),
            opt(smoothed)
        ));
    }
    out.write_all(text.as_bytes()).map_err(CliError::Write)?;
    Ok((table.columns.detected())
        .then(|| format!("columns {}", table.columns))
        .into_iter()
        .chain(table.skipped.note().map(|s| format!("input: {s}")))
        .collect())
}

/// The calibration of a `magcal planar --format json` object, or what is
/// wrong with it.
pub fn planar_from_value(value: &Value) -> Result<PlanarCalibration<f64>, String> {
    let field = |key: &str| value.get(key).ok_or(format!("missing field '{key}'"));
    let row = |v: &Value| -> Option<[f64; 3]> {
        let a = v.as_array().filter(|a| a.len() == 3)?;
        Some([a[0].as_f64()?, a[1].as_f64()?, a[2].as_f64()?])
    };
    let axis = row(field("axis")?).ok_or("'axis' must be an array of 3 numbers")?;
    let centre = row(field("centre")?).ok_or("'centre' must be an array of 3 numbers")?;
    let matrix = field("matrix")?
        .as_array()
        .filter(|rows| rows.len() == 2)
        .and_then(|rows| Some([row(&rows[0])?, row(&rows[1])?]))
        .ok_or("'matrix' must be 2 rows of 3 numbers")?;
    let zero = field("zero_deg")?
        .as_f64()
        .ok_or("'zero_deg' must be a number")?;
    PlanarCalibration::new(axis, centre, matrix, zero)
        .map_err(|err| format!("not a usable planar calibration: {err}"))
}
