//! Still periods (issue 36): the shared real recordings with still ends
//! added (the first reading repeated with noise before the recording, the
//! last after it) calibrate like the recording alone, and every recording
//! as it is loses no data to the rule.
//!
//! `cargo test --release -p host-tests --test still_periods -- --nocapture`
//! prints the table behind the assertions.

use host_tests::real::{read_csv_fields, read_xyz};
use mag_cal_core::{calibrate, Config, Error, Fit, SampleClass};
use nalgebra::Matrix3;

/// A small generator: uniform and normal draws.
struct Lcg(u64);

impl Lcg {
    fn uniform(&mut self) -> f64 {
        self.0 = self
            .0
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        ((self.0 >> 11) as f64 + 0.5) / (1u64 << 53) as f64
    }

    fn normal(&mut self) -> f64 {
        let (u, v) = (self.uniform(), self.uniform());
        (-2.0 * u.ln()).sqrt() * (std::f64::consts::TAU * v).cos()
    }
}

/// The shared 3-D recordings: name, rows, whether the rows are integer
/// counts.
fn recordings() -> Vec<(&'static str, Vec<[f64; 3]>, bool)> {
    vec![
        (
            "icm20948_mag_300.csv",
            read_xyz("icm20948_mag_300.csv"),
            true,
        ),
        ("mag3_raw_541.csv", read_xyz("mag3_raw_541.csv"), true),
        ("imu_gnss_1252.csv", raw_mag("imu_gnss_1252.csv"), true),
        ("magcal_25598.txt", read_xyz("magcal_25598.txt"), false),
        ("planar_243.txt", read_xyz("planar_243.txt"), false),
    ]
}

/// Columns 6-8 (the raw `magx, magy, magz`) of a CSV with a header and
/// text columns.
fn raw_mag(name: &str) -> Vec<[f64; 3]> {
    read_csv_fields(name, [6, 7, 8])
}

/// Noise of the still rows: one count (integer rows), or a share of the
/// field.
#[derive(Clone, Copy, Debug)]
enum Noise {
    Count,
    Share(f64),
}

/// `k` rows of the first reading with noise, the recording, `k` rows of
/// the last reading with noise.
fn with_still_ends(
    rows: &[[f64; 3]],
    k: usize,
    noise: Noise,
    field: f64,
    seed: u64,
) -> Vec<[f64; 3]> {
    let mut rng = Lcg(seed);
    let mut jitter = |p: [f64; 3]| match noise {
        Noise::Count => p.map(|v| v + (rng.uniform() * 3.0).floor() - 1.0),
        Noise::Share(s) => p.map(|v| v + s * field * rng.normal()),
    };
    let (first, last) = (rows[0], rows[rows.len() - 1]);
    let mut out: Vec<[f64; 3]> = (0..k).map(|_| jitter(first)).collect();
    out.extend_from_slice(rows);
    out.extend((0..k).map(|_| jitter(last)));
    out
}

/// The shift of `fit` from `base` in units of the base's field: hard iron
/// `|db| / rho`, field strength `|drho| / rho`, and `M = W^T W` (Frobenius,
/// relative to its norm).
fn shift(base: &Fit<f64>, fit: &Fit<f64>) -> (f64, f64, f64) {
    let parts = |f: &Fit<f64>| {
        let c = &f.calibration;
        let w = Matrix3::from_fn(|i, j| c.soft_iron()[i][j]);
        (w.transpose() * w, c.hard_iron(), c.field_strength())
    };
    let (m0, b0, rho0) = parts(base);
    let (m, b, rho) = parts(fit);
    let db = ((b[0] - b0[0]).powi(2) + (b[1] - b0[1]).powi(2) + (b[2] - b0[2]).powi(2)).sqrt();
    (
        db / rho0,
        (rho - rho0).abs() / rho0,
        (m - m0).norm() / m0.norm(),
    )
}

fn cause(e: &Error) -> String {
    format!("{e:?}")
        .split([' ', '{'])
        .next()
        .unwrap_or("")
        .to_owned()
}

/// One recording with still ends against the recording alone: `None` when
/// both are refused alike; the shift and the rows set aside otherwise.
/// Panics when an acceptance turns into a refusal or a refusal changes
/// cause.
fn check(
    name: &str,
    base: &Result<Fit<f64>, Error>,
    rows: &[[f64; 3]],
    label: &str,
) -> Option<((f64, f64, f64), usize)> {
    let got = calibrate::<f64, _>(rows, &Config::default());
    match (base, &got) {
        (Ok(b), Ok(f)) => {
            let s = shift(b, f);
            println!(
                "| {name} | {label} | {} | {:.3} % | {:.3} % | {:.3} % | {} | {} |",
                rows.len(),
                100.0 * s.0,
                100.0 * s.1,
                100.0 * s.2,
                f.report.dwell,
                f.report.samples_used
            );
            // Every row counted once.
            let r = &f.report;
            assert_eq!(
                r.samples_used + r.samples_dropped + r.dwell + r.screened + r.rejected,
                rows.len(),
                "{name} {label}: {r:?}"
            );
            Some((s, f.report.dwell))
        }
        (Err(a), Err(e)) => {
            println!(
                "| {name} | {label} | {} | refused: {e} | | | | |",
                rows.len()
            );
            assert_eq!(cause(a), cause(e), "{name} {label}: the cause changed: {e}");
            None
        }
        (Ok(_), Err(e)) => panic!("{name} {label}: accepted alone, refused with still ends: {e}"),
        (Err(a), Ok(_)) => panic!("{name} {label}: refused alone ({a}), accepted with still ends"),
    }
}

/// The issue's cases: icm20948 with 600 and 1 200 still rows at each end
/// (one count of noise), mag3 with 600.
#[test]
fn the_issues_still_ends_leave_the_fit() {
    for (name, k) in [
        ("icm20948_mag_300.csv", 600),
        ("icm20948_mag_300.csv", 1200),
        ("mag3_raw_541.csv", 600),
    ] {
        let rows = read_xyz(name);
        let base = calibrate::<f64, _>(&rows, &Config::default());
        let field = base
            .as_ref()
            .expect("accepted alone")
            .calibration
            .field_strength();
        let all = with_still_ends(&rows, k, Noise::Count, field, 7);
        let (s, dwell) = check(name, &base, &all, &format!("+{k} x 2, 1 count")).expect("accepted");
        assert!(s.0 < 0.01 && s.1 < 0.01 && s.2 < 0.01, "{name} +{k}: {s:?}");
        // All but a few of each end's rows, beside those the repetition
        // rule drops.
        assert!(dwell > 2 * k - 120, "{name} +{k}: {dwell} set aside");
    }
}

/// Every shared recording with still ends of 0.5x to 10x its rows (half
/// at each end), noise from one count to 3 % of the field: within 1 % of
/// the field of the fit without them, and no acceptance refused.
#[test]
fn still_ends_of_every_size_and_noise_leave_the_fit() {
    println!("| recording | still rows | rows | b | field | M | set aside | used |");
    println!("|---|---|---|---|---|---|---|---|");
    let mut worst = (0.0f64, 0.0f64, 0.0f64);
    for (name, rows, integer) in recordings() {
        let base = calibrate::<f64, _>(&rows, &Config::default());
        let field = match &base {
            Ok(f) => f.calibration.field_strength(),
            // The field from the rows' spread (the noise's scale alone).
            Err(_) => 50.0,
        };
        let mut noises = vec![Noise::Share(0.002), Noise::Share(0.01), Noise::Share(0.03)];
        if integer {
            noises.insert(0, Noise::Count);
        }
        for noise in noises {
            for mult in [0.5, 1.0, 2.0, 5.0, 10.0] {
                // The long recording: up to 2x (the rule does not depend
                // on the length; the test's time does).
                if rows.len() > 10_000 && mult > 2.0 {
                    continue;
                }
                let k = (rows.len() as f64 * mult / 2.0) as usize;
                let all = with_still_ends(&rows, k, noise, field, 11);
                let label = format!("{mult}x, {noise:?}");
                if let Some((s, _)) = check(name, &base, &all, &label) {
                    assert!(
                        s.0 < 0.01 && s.1 < 0.01 && s.2 < 0.01,
                        "{name} {label}: {s:?}"
                    );
                    worst = (worst.0.max(s.0), worst.1.max(s.1), worst.2.max(s.2));
                }
            }
        }
    }
    println!(
        "worst: b {:.3} %, field {:.3} %, M {:.3} %",
        100.0 * worst.0,
        100.0 * worst.1,
        100.0 * worst.2
    );
}

/// Every shared recording as it is: at most 5 % of its rows set aside,
/// and the result within 0.3 % of the field of the fit without the rule.
#[test]
fn the_recordings_as_they_are_lose_nothing() {
    for (name, rows, _) in recordings() {
        let with = calibrate::<f64, _>(&rows, &Config::default());
        let without = calibrate::<f64, _>(
            &rows,
            &Config {
                still: false,
                ..Config::default()
            },
        );
        match (&with, &without) {
            (Ok(a), Ok(b)) => {
                let s = shift(b, a);
                let aside = a.report.dwell;
                println!(
                    "{name}: {aside} of {} rows set aside, b {:.4} %, field {:.4} %, M {:.4} %",
                    rows.len(),
                    100.0 * s.0,
                    100.0 * s.1,
                    100.0 * s.2
                );
                assert!(aside * 20 <= rows.len(), "{name}: {aside} set aside");
                assert!(
                    s.0 <= 0.003 && s.1 <= 0.003 && s.2 <= 0.003,
                    "{name}: {s:?}"
                );
                let classes = a
                    .report
                    .selection
                    .classify(&a.calibration, &rows)
                    .filter(|c| *c == SampleClass::Dwell)
                    .count();
                assert_eq!(classes, aside, "{name}");
            }
            (Err(a), Err(b)) => {
                println!("{name}: refused, {a}");
                assert_eq!(cause(a), cause(b), "{name}");
            }
            _ => panic!("{name}: {with:?} vs {without:?}"),
        }
    }
}
