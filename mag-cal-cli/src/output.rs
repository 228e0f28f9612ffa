//! The two report formats: text for people, JSON for programs.

use std::fmt::Write as _;

use mag_cal_core::Warning;

use crate::fit::{Outcome, Parameters, Quality};

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
/// (one line, e.g. `magx,magy,magz (from the header)`), with the lines of
/// the input that were no samples (`skipped`, [`crate::input::Skipped::note`]).
pub fn text(o: &Outcome, source_name: &str, columns: &str, skipped: Option<&str>) -> String {
    let mut s = String::new();
    // Writing into a String cannot fail; the results are ignored.
    let _ = writeln!(s, "magcal fit: {source_name}");
    let _ = writeln!(s, "  columns       {columns}");
    if let Some(skipped) = skipped {
        let _ = writeln!(s, "  input         {skipped}");
    }
    let _ = writeln!(
        s,
        "  method        {} (LS step {}), precision {}",
        o.method, o.ls, o.precision
    );
    let _ = writeln!(s, "  outliers      {}", outlier_handling(o));
    let _ = writeln!(s, "  samples       {}", sample_counts(o));
    let _ = writeln!(s, "  iterations    {}", o.iterations);
    let _ = writeln!(
        s,
        "  passes        {}  (over the samples, after the LS fit)",
        o.passes
    );
    let _ = writeln!(s, "  fit time      {:.0} us", o.timing_us);
    let _ = writeln!(s);
    s.push_str(&calibration(
        &Parameters {
            hard_iron: o.hard_iron,
            soft_iron: o.soft_iron,
            field_strength: o.field_strength,
        },
        &o.quality,
    ));
    let _ = writeln!(s);
    let _ = writeln!(
        s,
        "apply: calibrated = W (raw - b)  (unit sphere; times the field strength for sensor units)"
    );
    s
}

/// The calibration block of `fit`'s text report (also `magcal
/// background`'s): `b`, `W`, the field strength and the quality figures,
/// one line each, ending with the warnings line.
pub fn calibration(p: &Parameters, q: &Quality) -> String {
    let mut s = String::new();
    let (b, scale) = block(&[p.hard_iron]);
    let _ = writeln!(s, "hard iron b (sensor units){scale}");
    let _ = writeln!(s, "{b}");
    let (w, scale) = block(&p.soft_iron);
    let _ = writeln!(s, "soft iron W (symmetric, 1 / sensor unit){scale}");
    let _ = writeln!(s, "{w}");
    let _ = writeln!(
        s,
        "field strength  {} (sensor units)",
        sig(p.field_strength, DIGITS)
    );
    let _ = writeln!(s);
    let _ = writeln!(s, "quality");
    let _ = writeln!(
        s,
        "  radial RMS    {}  (RMS of |W (raw - b)| - 1)",
        sig(q.radial_rms, 4)
    );
    let _ = writeln!(
        s,
        "  norm spread   {}  (std / mean of |W (raw - b)|)",
        sig(q.norm_spread, 4)
    );
    let _ = writeln!(
        s,
        "  fit error     {} of the field, lack of fit {}, outlier share {} %, skewness {}",
        sig(q.fit_error, 3),
        sig(q.lack_of_fit, 2),
        sig(100.0 * q.outlier_share, 2),
        sig(q.skewness, 2)
    );
    // One line a warning: its name and the core's sentence for people,
    // with its figure when the fit gave one.
    let warnings = if q.warnings.is_empty() {
        "none".to_owned()
    } else {
        q.warnings
            .iter()
            .enumerate()
            .map(|(i, name)| {
                match (
                    q.warning_texts.get(i),
                    Warning::ALL.into_iter().find(|w| w.name() == *name),
                ) {
                    (Some(text), _) => format!("{name}: {text}"),
                    (None, Some(w)) => format!("{name}: {w}"),
                    (None, None) => (*name).to_owned(),
                }
            })
            .collect::<Vec<_>>()
            .join("\n                ")
    };
    let _ = writeln!(
        s,
        "  geometry      flatness {:.3}, quadric gap {:.3e}, distortion {:.2}, coverage {:.3}, Gram condition {:.1}",
        q.flatness, q.quadric_gap, q.distortion, q.coverage, q.gram_condition
    );
    let _ = writeln!(s, "  warnings      {warnings}");
    s
}

/// The `outliers` line: whether outlier handling ran, and its passes.
fn outlier_handling(o: &Outcome) -> String {
    match (o.robust, o.robust_passes) {
        (false, _) => "off (--plain: every finite row trusted)".to_owned(),
        (true, 0) => "on; the plain fit was clean (0 robust passes)".to_owned(),
        (true, 1) => "on, 1 robust pass (screening, robust LS refits)".to_owned(),
        (true, n) if o.start_window.is_empty() => {
            format!("on, {n} robust passes (screening, robust LS refits)")
        }
        (true, n) => {
            let rows: Vec<String> = o
                .start_window
                .spans()
                .iter()
                .map(|&(start, end)| format!("{start}-{}", end - 1))
                .collect();
            format!(
                "on, {n} robust passes (screening, robust LS refits; the first fit was in doubt, \
                 and the fit that started without rows {} scored best)",
                rows.join(", ")
            )
        }
    }
}

/// The `samples` line: every row counted once, e.g. `298 used of 300: 0
/// dropped, 0 still, 0 screened, 2 rejected (residual beyond 0.0946 of the
/// field)`; still rows with where the device lay, `1795 still (set aside:
/// the device lay still within 1.2 of (40.19, -25.00, 342.1), within 1.4
/// of (39.00, -24.50, -318.0))`.
fn sample_counts(o: &Outcome) -> String {
    let rows = o.samples_used + o.samples_dropped + o.dwell + o.screened + o.rejected;
    let mut s = format!(
        "{} used of {rows}: {} dropped",
        o.samples_used, o.samples_dropped
    );
    if o.samples_dropped > 0 {
        let rules: Vec<String> = o
            .drops
            .by_rule()
            .filter(|&(_, n)| n > 0)
            .map(|(rule, n)| format!("{n} {}", rule.name().replace('_', "-")))
            .collect();
        let _ = write!(s, " ({})", rules.join(", "));
    }
    let _ = write!(s, ", {} still", o.dwell);
    if o.dwell > 0 && !o.selection.dwell.is_empty() {
        let balls: Vec<String> = o
            .selection
            .dwell
            .iter()
            .map(|b| {
                let c = b.centre.map(|v| sig(v, 4));
                format!(
                    "within {} of ({}, {}, {})",
                    sig(b.radius, 2),
                    c[0],
                    c[1],
                    c[2]
                )
            })
            .collect();
        let _ = write!(s, " (set aside: the device lay still {})", balls.join(", "));
    }
    let _ = write!(s, ", {} screened", o.screened);
    if let Some(screen) = o.selection.screen.filter(|_| o.screened > 0) {
        let _ = write!(
            s,
            " (farther than {} from the median centre)",
            sig(screen.radius, 4)
        );
    }
    let _ = write!(s, ", {} rejected", o.rejected);
    if let Some(limit) = o.selection.residual_limit.filter(|_| o.rejected > 0) {
        let _ = write!(s, " (residual beyond {} of the field", sig(limit, 3));
        let spans = o.selection.runs.spans();
        if !spans.is_empty() {
            let _ = write!(
                s,
                ", or beside a run of such rows: {}; {} of them within the cut",
                rows_of(spans),
                o.beside_runs
            );
        }
        s.push(')');
    }
    s
}

/// Half-open spans of rows as `first-last` ranges: `5-599, 1305-2099`.
fn rows_of(spans: &[(usize, usize)]) -> String {
    spans
        .iter()
        .map(|&(start, end)| format!("{start}-{}", end.saturating_sub(1)))
        .collect::<Vec<_>>()
        .join(", ")
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
    use crate::selection::{DropCounts, Screen, SelectionJson};
    use mag_cal_core::Drops;

    fn outcome() -> Outcome {
        Outcome {
            method: "adc2",
            ls: "ls9",
            precision: "f64",
            robust: true,
            samples_used: 300,
            samples_dropped: 2,
            drops: DropCounts({
                let mut drops = Drops::default();
                drops.non_finite = 1;
                drops.repeated = 1;
                drops
            }),
            dwell: 0,
            screened: 0,
            rejected: 3,
            beside_runs: 0,
            hard_iron: [-156.7, -52.79, 0.1 + 0.2],
            soft_iron: [[0.0041, 1e-5, 0.0], [1e-5, 0.0041, 0.0], [0.0, 0.0, 0.0039]],
            field_strength: 250.0,
            iterations: 5,
            passes: 1,
            robust_passes: 2,
            start_window: mag_cal_core::Runs::NONE,
            timing_us: 12.5,
            quality: Quality {
                radial_rms: 0.0123,
                norm_spread: f64::NAN,
                flatness: 0.4,
                quadric_gap: 95.0,
                distortion: 1.1,
                coverage: 0.2,
                gram_condition: 5.4,
                fit_error: 0.023_78,
                lack_of_fit: 0.003_04,
                outlier_share: 0.01,
                skewness: -0.12,
                warnings: vec!["pass_cap"],
                warning_texts: Vec::new(),
            },
            selection: SelectionJson {
                glitch_rules: true,
                screen: Some(Screen {
                    centre: [1.0, 2.0, 3.0],
                    radius: 812.345,
                }),
                residual_limit: Some(0.094_61),
                ..SelectionJson::ALL
            },
            classes: Vec::new(),
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
        assert_eq!(v["drops"]["repeated"].as_u64(), Some(1));
        assert_eq!(v["drops"].as_object().map(|d| d.len()), Some(6));
        assert_eq!(
            (
                v["dwell"].as_u64(),
                v["screened"].as_u64(),
                v["rejected"].as_u64()
            ),
            (Some(0), Some(0), Some(3))
        );
        assert_eq!(v["selection"]["dwell"], serde_json::json!([]));
        assert_eq!(v["robust_passes"].as_u64(), Some(2));
        assert_eq!(v["robust"], true);
        assert_eq!(v["quality"]["fit_error"].as_f64(), Some(0.023_78));
        assert_eq!(v["selection"]["screen"]["radius"].as_f64(), Some(812.345));
        assert_eq!(v["selection"]["residual_limit"].as_f64(), Some(0.094_61));
        assert!(v["selection"]["clip_levels"][2][1].is_null());
        assert!(v.get("classes").is_none(), "{v}");
    }

    #[test]
    fn text_names_the_parameters() {
        let t = text(
            &outcome(),
            "f.csv",
            "magx,magy,magz (from the header)",
            None,
        );
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
        assert!(
            t.contains("  warnings      pass_cap: iterated ADC2 stopped at its pass cap: "),
            "{t}"
        );
        assert!(
            t.contains(
                "  samples       300 used of 305: 2 dropped (1 non-finite, 1 repeated), \
                 0 still, 0 screened, 3 rejected (residual beyond 0.0946 of the field)\n"
            ),
            "{t}"
        );
        assert!(
            t.contains("  outliers      on, 2 robust passes (screening, robust LS refits)\n"),
            "{t}"
        );
        assert!(
            t.contains(
                "  fit error     0.0238 of the field, lack of fit 0.0030, outlier share 1.0 %, \
                 skewness -0.12\n"
            ),
            "{t}"
        );
        let mut plain = outcome();
        (plain.robust, plain.samples_dropped, plain.rejected) = (false, 0, 0);
        plain.drops = DropCounts::default();
        plain.screened = 4;
        let t = text(&plain, "f", "c", None);
        assert!(t.contains("  outliers      off (--plain"), "{t}");
        assert!(
            t.contains(
                "  samples       300 used of 304: 0 dropped, 0 still, 4 screened (farther \
                 than 812.3 from the median centre), 0 rejected\n"
            ),
            "{t}"
        );
        // Still periods: counted, with their rows in order.
        let mut still = outcome();
        still.dwell = 1795;
        still.selection.dwell = vec![
            Screen {
                centre: [40.1875, -25.0, 342.0625],
                radius: 1.1875,
            },
            Screen {
                centre: [39.0, -24.5, -318.0],
                radius: 1.4375,
            },
        ];
        let t = text(&still, "f", "c", None);
        assert!(
            t.contains(
                "  samples       300 used of 2100: 2 dropped (1 non-finite, 1 repeated), \
                 1795 still (set aside: the device lay still within 1.2 of (40.19, -25.00, \
                 342.1), within 1.4 of (39.00, -24.50, -318.0)), 0 screened, 3 rejected"
            ),
            "{t}"
        );
        let v: serde_json::Value = serde_json::from_str(&json(&still)).expect("valid JSON");
        assert_eq!(v["dwell"], 1795);
        assert_eq!(
            v["selection"]["dwell"],
            serde_json::json!([
                {"centre": [40.1875, -25.0, 342.0625], "radius": 1.1875},
                {"centre": [39.0, -24.5, -318.0], "radius": 1.4375}
            ])
        );
        let mut quiet = outcome();
        quiet.quality.warnings.clear();
        assert!(text(&quiet, "f", "c", None).contains("  warnings      none\n"));
        assert!(json(&quiet).contains(r#""warnings":[]"#));
    }
}
