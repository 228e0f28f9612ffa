//! Writes the still-period section of `docs/results.md` (issue 36): each
//! shared recording of `shared/data/real/` (read in place) and simulated
//! recordings, with still rows added at each end (the first and last row
//! repeated with noise), calibrated with the default configuration: how far
//! the fit moves from the fit without the still rows, how many rows the
//! still rule sets aside, and the verdict; beside it the same rows without
//! the rule (`Config { still: false, .. }`). The recording as it is (no
//! row added) is compared with the fit without the rule.
//!
//! `cargo run --release -p host-tests --bin still-table [-- --write docs/results.md]`

use std::fmt::Write as _;
use std::process::ExitCode;
use std::time::Instant;

use host_tests::contamination::refusal_name;
use host_tests::planar::{cause, robot_log, robot_plane_field, Shift};
use host_tests::real::{read_csv_fields, read_xyz};
use host_tests::sim::{self, Rng};
use mag_cal_core::planar::{self as planar, calibrate_planar, PlanarConfig, PlanarFit};
use mag_cal_core::{calibrate, Config, Error, Fit};
use nalgebra::{Matrix3, Vector3};

/// The section's name in `docs/results.md`.
const SECTION: &str = "still";
/// Still rows added at each end, in multiples of the recording's rows.
const MULTIPLES: [usize; 4] = [0, 1, 3, 10];
/// Noise of the still rows in % of the field (besides one count).
const STILL_SHARE: f64 = 0.01;
/// Noise of the simulated recordings, share of the field per axis.
const SIM_NOISE: [f64; 3] = [0.002, 0.01, 0.03];
/// Rows of a simulated recording.
const SIM_ROWS: usize = 600;
/// Turns of its spiral from pole to pole.
const SIM_TURNS: f64 = 6.0;
/// Field of a simulated recording, counts (the scale of its soft iron).
const SIM_FIELD: f64 = 400.0;
/// Largest hard-iron component of a simulated recording, counts.
const SIM_OFFSET: f64 = 300.0;
/// The robot log's still rows at each end, turn rows, turns, radial
/// noise of the turn (share of the field in the plane), and seed.
const ROBOT: (usize, usize, f64, f64, u64) = (120, 200, 1.1, 0.019, 1);
/// Noise of the robot log's still rows, share of the field in the plane.
const ROBOT_STILL_NOISE: [f64; 3] = [0.0015, 0.01, 0.03];
/// Still rows in the middle of `planar_243.txt`, in multiples of its rows.
const BETWEEN_MULTIPLES: [usize; 2] = [1, 10];

/// A recording: its label, its rows, and one count (the smallest step
/// between two values of an axis: the sensor's resolution).
struct Recording {
    label: String,
    rows: Vec<[f64; 3]>,
    count: f64,
}

/// The smallest positive step between two values of an axis.
fn resolution(rows: &[[f64; 3]]) -> f64 {
    (0..3)
        .filter_map(|a| {
            let mut v: Vec<f64> = rows.iter().map(|r| r[a]).collect();
            v.sort_by(f64::total_cmp);
            v.windows(2)
                .map(|w| w[1] - w[0])
                .filter(|d| *d > 0.0)
                .min_by(f64::total_cmp)
        })
        .min_by(f64::total_cmp)
        .unwrap_or(1.0)
}

fn recording(name: &str, rows: Vec<[f64; 3]>) -> Recording {
    Recording {
        label: format!("`{name}`"),
        count: resolution(&rows),
        rows,
    }
}

/// The shared recordings, read as `host-tests/tests/still_periods.rs`
/// reads them.
fn shared() -> Vec<Recording> {
    vec![
        recording("icm20948_mag_300.csv", read_xyz("icm20948_mag_300.csv")),
        recording("mag3_raw_541.csv", read_xyz("mag3_raw_541.csv")),
        recording(
            "imu_gnss_1252.csv",
            read_csv_fields("imu_gnss_1252.csv", [6, 7, 8]),
        ),
        recording("magcal_25598.txt", read_xyz("magcal_25598.txt")),
        recording("planar_243.txt", read_xyz("planar_243.txt")),
    ]
}

/// A simulated recording in integer counts: `y = T h + b + e` along a
/// spiral from pole to pole ([`SIM_TURNS`] turns, [`SIM_ROWS`] rows: about
/// 5 % of the field a row), `T` [`SIM_FIELD`] times a random distortion,
/// `b` up to [`SIM_OFFSET`] an axis, noise `noise` of the field per axis.
fn simulated(noise: f64, seed: u64) -> Recording {
    let mut rng = Rng(seed);
    let t = sim::random_t(&mut rng) * SIM_FIELD;
    let b = Vector3::from_fn(|_, _| (2.0 * rng.unit() - 1.0) * SIM_OFFSET);
    let dirs: Vec<Vector3<f64>> = (0..SIM_ROWS)
        .map(|i| {
            let s = (i as f64 + 0.5) / SIM_ROWS as f64;
            let z = 1.0 - 2.0 * s;
            let r = (1.0 - z * z).sqrt();
            let phi = std::f64::consts::TAU * SIM_TURNS * s;
            Vector3::new(r * phi.cos(), r * phi.sin(), z)
        })
        .collect();
    let field = t.determinant().abs().cbrt();
    let rows = sim::make_samples(&t, &b, &dirs, noise * field, &mut rng)
        .into_iter()
        .map(|y| y.map(f64::round))
        .collect();
    Recording {
        label: format!("simulated, noise {} %", 100.0 * noise),
        rows,
        count: 1.0,
    }
}

/// The noise of the still rows.
#[derive(Clone, Copy)]
enum StillNoise {
    /// One count (Gaussian, standard deviation one count).
    Count,
    /// [`STILL_SHARE`] of the field.
    Share,
}

/// `k` rows of the first row with Gaussian noise `sigma` per axis, the
/// rows, `k` rows of the last row: each value rounded to a whole number
/// of counts away from the row it repeats (a sensor's resolution).
impl StillNoise {
    /// The noise's sigma for `rec` (whose field is `field`) and its label.
    fn of(self, rec: &Recording, field: f64) -> (f64, String) {
        match self {
            StillNoise::Count => (rec.count, format!("1 count ({})", sig3(rec.count))),
            StillNoise::Share => (
                STILL_SHARE * field,
                format!("{} % ({})", 100.0 * STILL_SHARE, sig3(STILL_SHARE * field)),
            ),
        }
    }
}

fn with_still_ends(rec: &Recording, k: usize, sigma: f64, rng: &mut Rng) -> Vec<[f64; 3]> {
    let (Some(&first), Some(&last)) = (rec.rows.first(), rec.rows.last()) else {
        return rec.rows.clone();
    };
    let mut out: Vec<[f64; 3]> = (0..k).map(|_| jitter(rec, first, sigma, rng)).collect();
    out.extend_from_slice(&rec.rows);
    out.extend((0..k).map(|_| jitter(rec, last, sigma, rng)));
    out
}

/// The first half of the rows, `k` rows of the middle row (the first of
/// the second half) with noise as in [`with_still_ends`], the second half.
fn with_still_between(rec: &Recording, k: usize, sigma: f64, rng: &mut Rng) -> Vec<[f64; 3]> {
    let half = rec.rows.len() / 2;
    let Some(&middle) = rec.rows.get(half) else {
        return rec.rows.clone();
    };
    let mut out = rec.rows[..half].to_vec();
    out.extend((0..k).map(|_| jitter(rec, middle, sigma, rng)));
    out.extend_from_slice(&rec.rows[half..]);
    out
}

/// Row `p` with Gaussian noise `sigma` per axis, each value rounded to a
/// whole number of counts away from `p`.
fn jitter(rec: &Recording, p: [f64; 3], sigma: f64, rng: &mut Rng) -> [f64; 3] {
    p.map(|v| v + rec.count * (sigma * rng.normal() / rec.count).round())
}

/// The shift of `fit` from `base`: hard iron `|db| / rho`, field strength
/// `|drho| / rho` (`rho` the base's field), and `M = W^T W`
/// (`|M - M_base|_F / |M_base|_F`), as `host-tests/tests/still_periods.rs`
/// measures it.
fn shift(base: &Fit<f64>, fit: &Fit<f64>) -> [f64; 3] {
    let parts = |f: &Fit<f64>| {
        let c = &f.calibration;
        let w = Matrix3::from_fn(|i, j| c.soft_iron()[i][j]);
        (
            w.transpose() * w,
            Vector3::from(c.hard_iron()),
            c.field_strength(),
        )
    };
    let (m0, b0, rho0) = parts(base);
    let (m, b, rho) = parts(fit);
    [
        (b - b0).norm() / rho0,
        (rho - rho0).abs() / rho0,
        (m - m0).norm() / m0.norm(),
    ]
}

/// `x` to three significant digits.
fn sig3(x: f64) -> String {
    if x.is_nan() || x <= 0.0 {
        return format!("{x}");
    }
    let scale = 10f64.powi(2 - x.log10().floor() as i32);
    format!("{}", (x * scale).round() / scale)
}

/// The rows set aside by an accepted fit, `-` for a refusal.
fn set_aside(r: &Result<Fit<f64>, Error>) -> String {
    r.as_ref()
        .map_or("-".into(), |f| f.report.dwell.to_string())
}

fn verdict(r: &Result<Fit<f64>, Error>) -> String {
    match r {
        Ok(_) => "accepted".into(),
        Err(e) => refusal_name(e),
    }
}

/// The three shifts in %, or `-` without both fits.
fn shifts(base: &Result<Fit<f64>, Error>, fit: &Result<Fit<f64>, Error>) -> [String; 3] {
    match (base, fit) {
        (Ok(b), Ok(f)) => shift(b, f).map(|s| format!("{:.3}", 100.0 * s)),
        _ => std::array::from_fn(|_| "-".into()),
    }
}

/// The field of a recording: its fit's field strength, or (refused) the
/// RMS distance of its rows from their mean.
fn field_of(rec: &Recording, fit: &Result<Fit<f64>, Error>) -> f64 {
    if let Ok(f) = fit {
        return f.calibration.field_strength();
    }
    let n = rec.rows.len().max(1) as f64;
    let mean: Vector3<f64> = rec
        .rows
        .iter()
        .map(|r| Vector3::from(*r))
        .sum::<Vector3<f64>>()
        / n;
    (rec.rows
        .iter()
        .map(|r| (Vector3::from(*r) - mean).norm_squared())
        .sum::<f64>()
        / n)
        .sqrt()
}

/// The table rows of one recording.
fn rows_of(rec: &Recording, seed: u64, out: &mut String) {
    let plain = Config {
        still: false,
        ..Config::default()
    };
    let base = calibrate::<f64, _>(&rec.rows, &Config::default());
    let field = field_of(rec, &base);
    let n = rec.rows.len();
    // As it is: the rule against no rule.
    let without = calibrate::<f64, _>(&rec.rows, &plain);
    let [b, rho, m] = shifts(&without, &base);
    let aside = set_aside(&base);
    let _ = writeln!(
        out,
        "| {} | 0 | - | {n} | {} | {aside} | {b} | {rho} | {m} | {} (the reference) |",
        rec.label,
        verdict(&base),
        verdict(&without),
    );
    for noise in [StillNoise::Count, StillNoise::Share] {
        let (sigma, label) = noise.of(rec, field);
        for mult in MULTIPLES.into_iter().filter(|&m| m > 0) {
            let k = mult * n;
            let mut rng =
                Rng(seed ^ ((mult as u64) << 8) ^ u64::from(matches!(noise, StillNoise::Share)));
            let rows = with_still_ends(rec, k, sigma, &mut rng);
            let fit = calibrate::<f64, _>(&rows, &Config::default());
            let no_rule = calibrate::<f64, _>(&rows, &plain);
            let [b, rho, m] = shifts(&base, &fit);
            let aside = set_aside(&fit);
            let without = match (&base, &no_rule) {
                (Ok(_), Ok(_)) => {
                    let [b, rho, m] = shifts(&base, &no_rule);
                    format!("{b} / {rho} / {m}")
                }
                _ => verdict(&no_rule),
            };
            let _ = writeln!(
                out,
                "| {} | {mult}x ({k}) | {label} | {} | {} | {aside} | {b} | {rho} | {m} | {without} |",
                rec.label,
                rows.len(),
                verdict(&fit),
            );
        }
    }
}

/// The planar fit's result.
type PlanarResult = Result<PlanarFit<f64>, planar::Error>;

/// `config` without the still rule.
fn without_rule(config: &PlanarConfig) -> PlanarConfig {
    let mut c = *config;
    c.still = false;
    c
}

fn planar_verdict(r: &PlanarResult) -> String {
    match r {
        Ok(_) => "accepted".into(),
        Err(e) => cause(e),
    }
}

/// The rows set aside by an accepted planar fit, `-` for a refusal.
fn planar_set_aside(r: &PlanarResult) -> String {
    r.as_ref()
        .map_or("-".into(), |f| f.report.dwell.to_string())
}

/// The planar shift of `fit` from `base` (heading over `motion`, the
/// recording's rows): centre, plane field and `K^T K` in %, heading in
/// degrees; `-` without both fits.
fn planar_shifts(base: &PlanarResult, fit: &PlanarResult, motion: &[[f64; 3]]) -> [String; 4] {
    match (base, fit) {
        (Ok(b), Ok(f)) => {
            let s = Shift::of(b, f, motion);
            [
                format!("{:.3}", 100.0 * s.centre),
                format!("{:.3}", 100.0 * s.field),
                format!("{:.3}", 100.0 * s.m),
                format!("{:.3}", s.heading),
            ]
        }
        _ => std::array::from_fn(|_| "-".into()),
    }
}

/// A planar recording without still rows: its label, its rows, its
/// configuration and its fit.
struct PlanarCase<'a> {
    label: &'a str,
    motion: &'a [[f64; 3]],
    config: &'a PlanarConfig,
    base: &'a PlanarResult,
}

/// One row of the planar table: `rows` (the recording's rows with still
/// rows) against the fit of the recording alone, with the rule and without
/// it. The worst shift of an accepted row goes into `worst`.
fn planar_row(
    case: &PlanarCase,
    (still, noise): (&str, &str),
    rows: &[[f64; 3]],
    worst: &mut Shift,
    out: &mut String,
) {
    let PlanarCase {
        label,
        motion,
        config,
        base,
    } = *case;
    let fit = calibrate_planar::<f64, _>(rows, config);
    let no_rule = calibrate_planar::<f64, _>(rows, &without_rule(config));
    if let (Ok(b), Ok(f)) = (base, &fit) {
        *worst = worst.max(Shift::of(b, f, motion));
    }
    let [c, rho, m, h] = planar_shifts(base, &fit, motion);
    let without = match (base, &no_rule) {
        (Ok(_), Ok(_)) => planar_shifts(base, &no_rule, motion).join(" / "),
        _ => planar_verdict(&no_rule),
    };
    let _ = writeln!(
        out,
        "| {label} | {still} | {noise} | {} | {} | {} | {c} | {rho} | {m} | {h} | {without} |",
        rows.len(),
        planar_verdict(&fit),
        planar_set_aside(&fit),
    );
}

/// The reference row of a planar recording: as it is, the rule against no
/// rule.
fn planar_reference(
    label: &str,
    still: &str,
    rows: &[[f64; 3]],
    config: &PlanarConfig,
    out: &mut String,
) {
    let base = calibrate_planar::<f64, _>(rows, config);
    let without = calibrate_planar::<f64, _>(rows, &without_rule(config));
    let [c, rho, m, h] = planar_shifts(&without, &base, rows);
    let _ = writeln!(
        out,
        "| {label} | {still} | - | {} | {} | {} | {c} | {rho} | {m} | {h} | {} (the reference) |",
        rows.len(),
        planar_verdict(&base),
        planar_set_aside(&base),
        planar_verdict(&without),
    );
}

/// The planar table's rows: the robot log, then `planar_243.txt`; and the
/// worst shift over the accepted rows with still rows.
fn planar_rows(out: &mut String) -> Shift {
    let mut worst = Shift::default();
    let (still, turn, turns, turn_noise, seed) = ROBOT;
    let config = PlanarConfig::default();
    let field = robot_plane_field();
    let label = format!("robot log (simulated, seed {seed})");
    for (i, &still_noise) in ROBOT_STILL_NOISE.iter().enumerate() {
        let (rows, range) = robot_log(still, turn, (still_noise, turn_noise), turns, seed);
        let motion = &rows[range];
        if i == 0 {
            planar_reference(&label, "0 (the turn alone)", motion, &config, out);
        }
        let base = calibrate_planar::<f64, _>(motion, &config);
        let case = PlanarCase {
            label: &label,
            motion,
            config: &config,
            base: &base,
        };
        let noise = format!("{} % ({})", 100.0 * still_noise, sig3(still_noise * field));
        let still = format!("{still} at each end");
        planar_row(&case, (&still, &noise), &rows, &mut worst, out);
    }
    let rec = recording("planar_243.txt", read_xyz("planar_243.txt"));
    let config = PlanarConfig::with_up([0.0, 0.0, 1.0]);
    let n = rec.rows.len();
    planar_reference(&rec.label, "0", &rec.rows, &config, out);
    let base = calibrate_planar::<f64, _>(&rec.rows, &config);
    let field = base
        .as_ref()
        .unwrap_or_else(|e| panic!("planar_243.txt alone: {e}"))
        .calibration
        .plane_strength();
    let case = PlanarCase {
        label: &rec.label,
        motion: &rec.rows,
        config: &config,
        base: &base,
    };
    let seed = 0x5712_0000;
    for noise in [StillNoise::Count, StillNoise::Share] {
        let (sigma, label) = noise.of(&rec, field);
        let share = u64::from(matches!(noise, StillNoise::Share));
        for mult in MULTIPLES.into_iter().filter(|&m| m > 0) {
            let k = mult * n;
            let mut rng = Rng(seed ^ ((mult as u64) << 8) ^ share);
            let rows = with_still_ends(&rec, k, sigma, &mut rng);
            let still = format!("{mult}x ({k}) at each end");
            planar_row(&case, (&still, &label), &rows, &mut worst, out);
        }
    }
    let sigma = STILL_SHARE * field;
    let label = format!("{} % ({})", 100.0 * STILL_SHARE, sig3(sigma));
    for mult in BETWEEN_MULTIPLES {
        let k = mult * n;
        let mut rng = Rng(seed ^ ((mult as u64) << 8) ^ 0x10);
        let rows = with_still_between(&rec, k, sigma, &mut rng);
        let still = format!("{mult}x ({k}) between");
        planar_row(&case, (&still, &label), &rows, &mut worst, out);
    }
    worst
}

fn main() -> ExitCode {
    let write = match host_tests::sections::write_target("still-table") {
        Ok(write) => write,
        Err(usage) => return usage,
    };
    let start = Instant::now();
    let mut table = String::new();
    for (i, rec) in shared().iter().enumerate() {
        rows_of(rec, 0x5711_0000 + i as u64, &mut table);
        eprintln!("[{:5.1} s] {}", start.elapsed().as_secs_f64(), rec.label);
    }
    for (i, &noise) in SIM_NOISE.iter().enumerate() {
        let rec = simulated(noise, 0x5117_0000 + i as u64);
        rows_of(&rec, 0x5711_1000 + i as u64, &mut table);
        eprintln!("[{:5.1} s] {}", start.elapsed().as_secs_f64(), rec.label);
    }
    let mut planar_table = String::new();
    let worst = planar_rows(&mut planar_table);
    eprintln!(
        "[{:5.1} s] planar; worst accepted: {worst}",
        start.elapsed().as_secs_f64()
    );
    let elapsed = start.elapsed().as_secs_f64();
    let (still, turn, robot_turns, turn_noise, seed) = ROBOT;
    let doc = format!(
        "## Still periods\n\n\
         Written by `cargo run --release -p host-tests --bin still-table -- --write docs/results.md` \
         (source: `host-tests/src/bin/still-table.rs`; the rule: `mag-cal-core/src/steps/dwell.rs`; \
         asserted by `host-tests/tests/still_periods.rs`; issue 36); it took {elapsed:.0} s. \
         A log usually starts and ends with the device lying still. Each shared recording of \
         `shared/data/real/` (read in place), and simulated ones, with still rows added at each \
         end: the first row repeated before it and the last after it, {multiples} times the \
         recording's rows at each end (in brackets: the rows), with Gaussian noise of one count (the recording's \
         smallest step between two values of an axis: 1 for integer counts) or {share} % of the \
         field (its fit's field strength; for a refused recording the RMS distance of its rows \
         from their mean), in brackets in the recording's units, each value rounded to whole \
         counts. Calibrated with `Config::default()` \
         (`f64`): the shift of `b` and of the field strength (in % of the field) and of \
         `M = W^T W` (in % of its norm) from the fit of the recording alone, the rows the still \
         rule set aside, and the verdict (or the refusal). The recording as it is (0 added) is \
         compared with the fit without the rule (`Config {{ still: false, .. }}`); the last \
         column gives the same rows without the rule (b / field / M shifts in %, or its \
         refusal). Simulated: {sim_rows} rows in integer counts along a spiral from pole to \
         pole ({turns} turns, about 5 % of the field a row), soft iron {field} times a random \
         distortion, hard iron up to {offset} counts an axis, noise {noises} of the field per \
         axis.\n\n\
         | recording | still rows at each end | still noise | rows | verdict | set aside | b % | field % | M % | without the rule |\n\
         |---|---|---|---:|---|---:|---:|---:|---:|---|\n{table}\n\
         ### Planar (`calibrate_planar`)\n\n\
         The same for the planar (heading-only) fit, `mag_cal_core::planar::calibrate_planar` \
         (`f64`; asserted by `host-tests/tests/still_planar.rs`). The robot log of the issue \
         (\"still, one slow turn, still\", refused without the rule as too many outliers), \
         simulated (`host_tests::planar::robot_log`): {still} still rows, {turn} rows of {robot_turns} \
         slow turns at radial noise {turn_pct} % of the field in the plane, {still} still rows, \
         seed {seed}, the still rows with noise {robot_noises} of the field in the plane per axis \
         (in brackets: counts), with `PlanarConfig::default()`; its reference is the turn alone \
         (0 still). `planar_243.txt` (`shared/data/real/`, read in place, \
         `PlanarConfig::with_up([0.0, 0.0, 1.0])`) with its first row repeated before it and its \
         last after it, {multiples_planar} times its rows at each end, noise of one count (its \
         smallest step) or {share} % of its field in the plane, rounded to whole counts as \
         above; and the same {share} % still rows in its middle (one still period of {between} \
         times its rows, the middle row repeated). Shifts from the fit without the still rows \
         (the turn alone; `planar_243.txt` as it is): the centre within the plane and the field \
         in the plane (in % of that fit's field in the plane), `K'K` (`K` the 2x3 matrix, in % \
         of its norm), and the largest heading change over the recording's rows (deg, their \
         mean change removed: one alignment), as `Shift` in `host_tests::planar`. The rows \
         set aside are `PlanarReport::dwell`. The reference rows compare the fit with the rule \
         against the fit without it (`still: false`); the last column gives the same rows \
         without the rule (centre / field / K'K in %, heading in deg, or its refusal).\n\n\
         | recording | still rows | still noise | rows | verdict | set aside | centre % | plane field % | K'K % | heading deg | without the rule |\n\
         |---|---|---|---:|---|---:|---:|---:|---:|---:|---|\n{planar_table}",
        multiples = MULTIPLES
            .iter()
            .map(|m| m.to_string())
            .collect::<Vec<_>>()
            .join(", "),
        share = 100.0 * STILL_SHARE,
        sim_rows = SIM_ROWS,
        turns = SIM_TURNS,
        field = SIM_FIELD,
        offset = SIM_OFFSET,
        noises = SIM_NOISE
            .iter()
            .map(|s| format!("{} %", 100.0 * s))
            .collect::<Vec<_>>()
            .join(", "),
        turn_pct = 100.0 * turn_noise,
        robot_noises = ROBOT_STILL_NOISE
            .iter()
            .map(|s| format!("{} %", 100.0 * s))
            .collect::<Vec<_>>()
            .join(", "),
        multiples_planar = MULTIPLES[1..]
            .iter()
            .map(|m| m.to_string())
            .collect::<Vec<_>>()
            .join(", "),
        between = BETWEEN_MULTIPLES
            .iter()
            .map(|m| m.to_string())
            .collect::<Vec<_>>()
            .join(" and "),
    );
    host_tests::sections::publish(&doc, SECTION, write.as_deref())
}
