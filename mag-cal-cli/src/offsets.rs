//! `magcal offsets`: re-estimates the hard iron of a calibration with its
//! soft iron kept (`mag_cal_core::offsets`), from a log that need not cover
//! the sphere.

use std::io::Write;

use mag_cal_core::offsets::{refit_offsets, Strength};
use serde_json::json;

use crate::apply::{calibration_from_value, read_json, sources};
use crate::cli::{Format, OffsetsArgs, StrengthArg};
use crate::error::CliError;
use crate::input;

/// Runs `magcal offsets`.
pub fn run(args: &OffsetsArgs, out: &mut dyn Write) -> Result<Vec<String>, CliError> {
    let (cal_source, source) = sources(&args.calibration, &args.file)?;
    let cal_name = cal_source.name();
    let previous = calibration_from_value(&read_json(&cal_source.read()?, &cal_name)?, &cal_name)?;
    let table = input::parse(&source.read()?, args.columns.as_ref(), &source.name())?;
    let strength = match args.strength {
        StrengthArg::Known => Strength::Unchanged,
        StrengthArg::Unknown => Strength::Unknown,
    };
    let fit =
        refit_offsets::<f64, _>(&table.samples, &previous, strength).map_err(CliError::Refused)?;
    let cal = fit.calibration;
    let text = match args.format {
        Format::Json => {
            // The fields `magcal apply` reads, and the fit's figures.
            let v = json!({
                "method": "offsets",
                "strength": args.strength.name(),
                "hard_iron": cal.hard_iron(),
                "soft_iron": cal.soft_iron(),
                "field_strength": cal.field_strength(),
                "strength_ratio": fit.strength_ratio,
                "determinacy": fit.determinacy,
                "passes": fit.passes,
                "samples_used": fit.samples_used,
                "samples_dropped": fit.samples_dropped,
                "rejected": fit.rejected,
                "fit_error": fit.fit_error,
                "columns": table.columns.to_string(),
            });
            format!("{v}\n")
        }
        Format::Text => {
            let [bx, by, bz] = cal.hard_iron();
            let [ox, oy, oz] = previous.hard_iron();
            format!(
                "offsets-only fit of {} (columns {}; soft iron of {}, field strength {})\n  \
                 hard iron     [{bx:.4}, {by:.4}, {bz:.4}] (was [{ox:.4}, {oy:.4}, {oz:.4}])\n  \
                 field         {:.4} (ratio {:.5})\n  \
                 determinacy   {:.4}\n  \
                 rows          {} used, {} dropped, {} rejected; {} passes\n  \
                 fit error     {:.5} of the field\n",
                source.name(),
                table.columns,
                cal_name,
                args.strength.name(),
                cal.field_strength(),
                fit.strength_ratio,
                fit.determinacy,
                fit.samples_used,
                fit.samples_dropped,
                fit.rejected,
                fit.passes,
                fit.fit_error,
            )
        }
    };
    out.write_all(text.as_bytes()).map_err(CliError::Write)?;
    Ok(table
        .skipped
        .note()
        .map(|s| format!("input: {s}"))
        .into_iter()
        .collect())
}
