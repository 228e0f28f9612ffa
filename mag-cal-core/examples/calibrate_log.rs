//! Calibrates a recorded log: one reading per line, three numbers (`x,y,z`,
//! separated by commas, tabs or spaces). Other lines (a header, comments,
//! a truncated row) are skipped and counted.
//!
//! ```sh
//! cargo run -p mag-cal-core --example calibrate_log -- my_log.csv
//! ```

use std::process::ExitCode;

use mag_cal_core::{calibrate, Config};

fn main() -> ExitCode {
    let Some(path) = std::env::args().nth(1) else {
        eprintln!("usage: calibrate_log FILE");
        return ExitCode::from(2);
    };
    let text = match std::fs::read_to_string(&path) {
        Ok(text) => text,
        Err(e) => {
            eprintln!("{path}: {e}");
            return ExitCode::from(2);
        }
    };

    // Three numbers a line, or the line is skipped.
    let mut samples: Vec<[f64; 3]> = Vec::new();
    let mut skipped = 0;
    for line in text.lines() {
        let fields: Vec<f64> = line
            .split(|c: char| c == ',' || c.is_whitespace())
            .filter(|f| !f.is_empty())
            .filter_map(|f| f.parse().ok())
            .collect();
        match fields[..] {
            [x, y, z] => samples.push([x, y, z]),
            _ => skipped += 1,
        }
    }
    println!(
        "{path}: {} readings, {skipped} other lines skipped",
        samples.len()
    );

    // Outlier handling is on by default: glitch rows are dropped, outliers
    // left out, and the report counts both.
    let fit = match calibrate::<f64, _>(&samples, &Config::default()) {
        Ok(fit) => fit,
        Err(e) => {
            // A refusal names the cause, e.g. "samples lie near a plane".
            eprintln!("not calibrated: {e}");
            return ExitCode::from(3);
        }
    };
    let (cal, report) = (fit.calibration, fit.report);
    println!("hard iron b = {:?}", cal.hard_iron());
    for (i, row) in cal.soft_iron().iter().enumerate() {
        println!("soft iron W[{i}] = {row:?}");
    }
    println!("field strength = {:.4}", cal.field_strength());
    println!(
        "rows used {}, dropped {}, screened {}, rejected {}",
        report.samples_used, report.samples_dropped, report.screened, report.rejected
    );
    println!(
        "radial RMS {:.5}, fit error {:.5} (of the field)",
        report.radial_rms, report.quality.fit_error
    );
    for warning in report.warnings.iter() {
        println!("warning: {warning}");
    }
    ExitCode::SUCCESS
}
