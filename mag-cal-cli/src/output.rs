//! The two report formats: text for people, JSON for programs.

use std::fmt::Write as _;

use crate::fit::Outcome;

/// Significant digits of the numbers in the text report.
const DIGITS: usize = 7;

/// The JSON report: one object on one line, numbers at full `f64`
/// precision (shortest round-trip form; non-finite values as `null`).
pub fn json(outcome: &Outcome) -> String {
    match serde_json::to_string(outcome) {
        Ok(mut line) => {
            line.push('\n');
            line
        }
        // Unreachable for a struct of numbers and strings; still no panic.
        Err(err) => format!("{{\"error\":{:?}}}\n", err.to_string()),
    }
}

/// The text report for `source_name`, whose samples came from `columns`
/// (one line, e.g. `magx,magy,magz (from the header)`).
pub fn text(o: &Outcome, source_name: &str, columns: &str) -> String {
    let mut s = String::new();
    // Writing into a String cannot fail; the results are ignored.
    let _ = writeln!(s, "magcal fit: {source_name}");
    let _ = writeln!(s, "  columns       {columns}");
    let _ = writeln!(
        s,
        "  method        {} (LS step {}), precision {}",
        o.method, o.ls, o.precision
    );
    let _ = writeln!(
        s,
        "  samples       {} used, {} dropped (non-finite)",
        o.samples_used, o.samples_dropped
    );
    let _ = writeln!(s, "  iterations    {}", o.iterations);
    let _ = writeln!(
        s,
        "  passes        {}  (over the samples, after the LS fit)",
        o.passes
    );
    let _ = writeln!(s, "  fit time      {:.0} us", o.timing_us);
    let _ = writeln!(s);
    let (b, scale) = block(&[o.hard_iron]);
    let _ = writeln!(s, "hard iron b (sensor units){scale}");
    let _ = writeln!(s, "{b}");
    let (w, scale) = block(&o.soft_iron);
    let _ = writeln!(s, "soft iron W (symmetric, 1 / sensor unit){scale}");
    let _ = writeln!(s, "{w}");
    let _ = writeln!(
        s,
        "field strength  {} (sensor units)",
        sig(o.field_strength, DIGITS)
    );
    let _ = writeln!(s);
    let _ = writeln!(s, "quality");
    let _ = writeln!(
        s,
        "  radial RMS    {}  (RMS of |W (raw - b)| - 1)",
        sig(o.quality.radial_rms, 4)
    );
    let _ = writeln!(
        s,
        "  norm spread   {}  (std / mean of |W (raw - b)|)",
        sig(o.quality.norm_spread, 4)
    );
    let warnings = if o.quality.warnings.is_empty() {
        "none".to_owned()
    } else {
        o.quality.warnings.join(", ")
    };
    let q = &o.quality;
    let _ = writeln!(
        s,
        "  geometry      flatness {:.3}, quadric gap {:.3e}, distortion {:.2}, coverage {:.3}, Gram condition {:.1}",
        q.flatness, q.quadric_gap, q.distortion, q.coverage, q.gram_condition
    );
    let _ = writeln!(s, "  warnings      {warnings}");
    let _ = writeln!(s);
    let _ = writeln!(
        s,
        "apply: calibrated = W (raw - b)  (unit sphere; times the field strength for sensor units)"
    );
    s
}

/// Rows of numbers in brackets, right-aligned, with one number of decimals
/// so the columns line up; one line each, no final newline.
///
/// Magnitudes up to about 1e6 and down to 1e-2 print as they are, to
/// [`DIGITS`] significant digits of the largest entry. Others are printed
/// with a common power of ten, returned as ` = 1e-3 x` for the heading.
fn block(rows: &[[f64; 3]]) -> (String, String) {
    let largest = rows
        .iter()
        .flatten()
        .map(|v| v.abs())
        .filter(|v| v.is_finite())
        .fold(0.0, f64::max);
    let exponent = exponent_of(largest);
    let digits = i64::try_from(DIGITS).unwrap_or(7);
    let (factor, heading, decimals) = if (-2..digits).contains(&exponent) {
        (1.0, String::new(), digits - 1 - exponent)
    } else {
        let exponent = i32::try_from(exponent).unwrap_or(0);
        (
            10f64.powi(-exponent),
            format!(" = 1e{exponent} x"),
            digits - 1,
        )
    };
    let decimals = usize::try_from(decimals).unwrap_or(0);
    let lines: Vec<String> = rows
        .iter()
        .map(|row| {
            let cells: String = row
                .iter()
                .map(|v| format!(" {:>width$.decimals$}", v * factor, width = DIGITS + 6))
                .collect();
            format!("  [{cells} ]")
        })
        .collect();
    (lines.join("\n"), heading)
}

/// The decimal exponent of `value` as printed in scientific notation
/// (0 for zero and non-finite values).
fn exponent_of(value: f64) -> i64 {
    if !value.is_finite() || value == 0.0 {
        return 0;
    }
    // Rounding to DIGITS first fixes the exponent (9.99999999 -> 1.0e1).
    format!("{:.*e}", DIGITS - 1, value)
        .rsplit_once('e')
        .and_then(|(_, e)| e.parse().ok())
        .unwrap_or(0)
}

/// `value` to `digits` significant digits, like C's `%g` but keeping
/// trailing zeros: fixed notation for moderate magnitudes, scientific
/// otherwise.
pub fn sig(value: f64, digits: usize) -> String {
    let digits = digits.max(1);
    if !value.is_finite() || value == 0.0 {
        return format!("{value}");
    }
    // Rounding to `digits` first fixes the exponent (9.99999999 -> 1.0e1).
    let scientific = format!("{:.*e}", digits - 1, value);
    let exponent = scientific
        .rsplit_once('e')
        .and_then(|(_, e)| e.parse::<i64>().ok())
        .unwrap_or(0);
    let max_exponent = i64::try_from(digits).unwrap_or(i64::MAX);
    if (-5..max_exponent).contains(&exponent) {
        let decimals = usize::try_from(max_exponent - 1 - exponent).unwrap_or(0);
        format!("{value:.decimals$}")
    } else {
        scientific
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::fit::Quality;

    fn outcome() -> Outcome {
        Outcome {
            method: "adc2",
            ls: "ls9",
            precision: "f64",
            samples_used: 300,
            samples_dropped: 2,
            hard_iron: [-156.7, -52.79, 0.1 + 0.2],
            soft_iron: [[0.0041, 1e-5, 0.0], [1e-5, 0.0041, 0.0], [0.0, 0.0, 0.0039]],
            field_strength: 250.0,
            iterations: 5,
            passes: 1,
            timing_us: 12.5,
            quality: Quality {
                radial_rms: 0.0123,
                norm_spread: f64::NAN,
                flatness: 0.4,
                quadric_gap: 95.0,
                distortion: 1.1,
                coverage: 0.2,
                gram_condition: 5.4,
                warnings: vec!["pass_cap"],
            },
        }
    }

    #[test]
    fn significant_digits() {
        assert_eq!(sig(-156.7, 7), "-156.7000");
        assert_eq!(sig(0.0041, 4), "0.004100");
        assert_eq!(sig(9.99999999, 3), "10.0");
        assert_eq!(sig(1.5e-9, 3), "1.50e-9");
        assert_eq!(sig(12345678.0, 3), "1.23e7");
        assert_eq!(sig(0.0, 7), "0");
        assert_eq!(sig(f64::NAN, 7), "NaN");
    }

    #[test]
    fn json_is_one_line_at_full_precision() {
        let line = json(&outcome());
        assert_eq!(line.lines().count(), 1);
        let v: serde_json::Value = serde_json::from_str(&line).expect("valid JSON");
        assert_eq!(v["hard_iron"][2].as_f64(), Some(0.1 + 0.2));
        assert_eq!(v["soft_iron"][0][1].as_f64(), Some(1e-5));
        assert!(v["quality"]["norm_spread"].is_null());
        assert_eq!(v["samples_dropped"].as_u64(), Some(2));
        assert_eq!(v["passes"].as_u64(), Some(1));
        assert_eq!(v["quality"]["warnings"], serde_json::json!(["pass_cap"]));
    }

    #[test]
    fn text_names_the_parameters() {
        let t = text(&outcome(), "f.csv", "magx,magy,magz (from the header)");
        assert!(
            t.starts_with("magcal fit: f.csv\n  columns       magx,magy,magz (from the header)\n"),
            "{t}"
        );
        assert!(
            t.contains(
                "hard iron b (sensor units)\n  [     -156.7000      -52.7900        0.3000 ]\n"
            ),
            "{t}"
        );
        assert!(
            t.contains("W (symmetric, 1 / sensor unit) = 1e-3 x\n  [      4.100000"),
            "{t}"
        );
        assert!(t.contains("field strength  250.0000"));
        assert!(t.contains("calibrated = W (raw - b)"));
        assert!(t.contains("  passes        1  "), "{t}");
        assert!(t.contains("  warnings      pass_cap\n"), "{t}");
        let mut quiet = outcome();
        quiet.quality.warnings.clear();
        assert!(text(&quiet, "f", "c").contains("  warnings      none\n"));
        assert!(json(&quiet).contains(r#""warnings":[]"#));
    }
}
