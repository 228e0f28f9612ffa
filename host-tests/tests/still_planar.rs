//! Still periods (issue 36) in the planar (heading-only) fit: a log that
//! lies still before, after or between its turns calibrates like the
//! turns alone, and the still rows are no outliers.
//!
//! The issue's case, a real ground-robot log ("still, one slow turn,
//! still": 440 rows, more than half at the two still positions, radial RMS
//! 1.9 %, no row beyond 5 %, refused as "too many outliers: 112 of 440"),
//! is not available: it is simulated
//! ([`host_tests::planar::robot_log`]); the shared planar
//! recording `planar_243.txt` gets still periods added.
//!
//! `cargo test --release -p host-tests --test still_planar -- --nocapture`
//! prints the figures behind the assertions.

use host_tests::planar::{cause, level_turns, robot_log, robot_plane_field, Shift};
use host_tests::real::read_xyz;
use host_tests::sim::Rng;
use mag_cal_core::planar::{calibrate_planar, Error, PlanarConfig, PlanarFit};
use mag_cal_core::{Error as FitError, Real};

/// Where still rows are added to a recording.
#[derive(Clone, Copy, Debug)]
enum Place {
    /// Before its first row (that row, with noise).
    Before,
    /// After its last row.
    After,
    /// Before and after, `k` rows each.
    Ends,
    /// In the middle (the middle row).
    Between,
}

/// The recording `rows` with `k` still rows at `place` (each end's for
/// [`Place::Ends`]): the row there repeated with normal noise of `noise`
/// times `field` per axis. The rows, and where the recording's rows are
/// (in order).
fn with_still(
    rows: &[[f64; 3]],
    place: Place,
    k: usize,
    noise: f64,
    field: f64,
    seed: u64,
) -> (Vec<[f64; 3]>, Vec<usize>) {
    let mut rng = Rng::for_case(seed, 3600);
    let mut still = |p: [f64; 3], k: usize| -> Vec<[f64; 3]> {
        (0..k)
            .map(|_| p.map(|v| v + noise * field * rng.normal()))
            .collect()
    };
    let n = rows.len();
    let (mut out, mut motion) = (Vec::new(), Vec::new());
    let mut push_motion = |out: &mut Vec<[f64; 3]>, part: &[[f64; 3]]| {
        for r in part {
            motion.push(out.len());
            out.push(*r);
        }
    };
    match place {
        Place::Before => {
            out = still(rows[0], k);
            push_motion(&mut out, rows);
        }
        Place::After => {
            push_motion(&mut out, rows);
            out.extend(still(rows[n - 1], k));
        }
        Place::Ends => {
            out = still(rows[0], k);
            push_motion(&mut out, rows);
            out.extend(still(rows[n - 1], k));
        }
        Place::Between => {
            push_motion(&mut out, &rows[..n / 2]);
            out.extend(still(rows[n / 2], k));
            push_motion(&mut out, &rows[n / 2..]);
        }
    }
    (out, motion)
}

/// One recording with still rows against the recording alone (`base`):
/// the shift and the rows set aside when both are accepted, `None` when
/// both are refused alike. Panics when an acceptance turns into a refusal,
/// a refusal into an acceptance, or a refusal changes cause, and when a
/// row is not counted once (`motion`: the recording's rows, in order).
fn check<T: Real>(
    label: &str,
    base: &Result<PlanarFit<T>, Error>,
    rows: &[[f64; 3]],
    motion: &[usize],
    config: &PlanarConfig,
) -> Option<(Shift, usize)> {
    let input: Vec<[T; 3]> = rows.iter().map(|r| r.map(|v| T::lit(v))).collect();
    let got = calibrate_planar::<T, _>(&input, config);
    match (base, &got) {
        (Ok(b), Ok(f)) => {
            let moving: Vec<[f64; 3]> = motion.iter().map(|&i| rows[i]).collect();
            let s = Shift::of(b, f, &moving);
            let r = &f.report;
            // The rows set aside are the still ones, and those of the
            // motion that pass through a still period's ball.
            let motion_aside = motion
                .iter()
                .filter(|&&i| r.still_periods.holds(rows[i].map(|v| T::lit(v))))
                .count();
            println!(
                "| {label} | {} | {s} | {} ({motion_aside} moving) | {} | {} |",
                rows.len(),
                r.dwell,
                r.samples_used,
                r.screened + r.rejected
            );
            assert_eq!(
                r.samples_used + r.drops.total() + r.dwell + r.screened + r.rejected,
                rows.len(),
                "{label}: {r:?}"
            );
            Some((s, r.dwell))
        }
        (Err(a), Err(e)) => {
            println!("| {label} | {} | refused: {e} | | | |", rows.len());
            assert_eq!(cause(a), cause(e), "{label}: the cause changed: {a} -> {e}");
            None
        }
        (Ok(_), Err(e)) => panic!("{label}: accepted alone, refused with still rows: {e}"),
        (Err(a), Ok(_)) => panic!("{label}: refused alone ({a}), accepted with still rows"),
    }
}

/// `config` without the still rule.
fn without_rule(config: &PlanarConfig) -> PlanarConfig {
    let mut c = *config;
    c.still = false;
    c
}

/// The case: the robot log is accepted, and calibrates like its
/// turn alone (in `f64` and `f32`). With still rows of 0.15 % noise the
/// simulation without the rule shows the report's symptom (100-153 of 440
/// rows outliers, half the seeds refused as too many, the real log 112);
/// the still noise of the range, 0.2 % to 3 %, is accepted too.
#[test]
fn the_robot_log_is_accepted_like_its_turn() {
    println!(
        "| robot log | rows | shift from the turn alone | set aside | used | screened + rejected |"
    );
    println!("|---|---|---|---|---|---|");
    let mut refused_without = 0;
    let mut worst = Shift::default();
    for still_noise in [0.0015, 0.002, 0.01, 0.03] {
        for seed in 1..=8u64 {
            let (rows, turn) = robot_log(120, 200, (still_noise, 0.019), 1.1, seed);
            assert_eq!(rows.len(), 440);
            let motion: Vec<usize> = turn.clone().collect();
            let alone = calibrate_planar::<f64, _>(&rows[turn.clone()], &PlanarConfig::default())
                .unwrap_or_else(|e| panic!("seed {seed}: the turn alone refused: {e}"));
            // The turn as the issue describes it: radial RMS about 1.9 %,
            // no row beyond 5 %.
            let radial: Vec<f64> = rows[turn.clone()]
                .iter()
                .map(|&r| {
                    let [u, v] = alone.calibration.apply(r);
                    (u * u + v * v).sqrt() - 1.0
                })
                .collect();
            let rms = (radial.iter().map(|e| e * e).sum::<f64>() / radial.len() as f64).sqrt();
            let largest = radial.iter().fold(0.0f64, |m, e| m.max(e.abs()));
            assert!(
                (0.015..0.025).contains(&rms) && largest < 0.05,
                "seed {seed}: {rms} {largest}"
            );
            let label = format!(
                "still noise {:.2} %, seed {seed}, radial RMS {:.2} %",
                100.0 * still_noise,
                100.0 * rms
            );
            if still_noise == 0.0015 {
                let outliers = match calibrate_planar::<f64, _>(
                    &rows,
                    &without_rule(&PlanarConfig::default()),
                ) {
                    Err(Error::Fit(FitError::TooManyOutliers {
                        rejected, valid, ..
                    })) => {
                        assert_eq!(valid, 440);
                        refused_without += 1;
                        rejected
                    }
                    Ok(f) => f.report.screened + f.report.rejected,
                    Err(e) => panic!("{label} without the rule: {e}"),
                };
                println!("{label} without the rule: {outliers} of 440 outliers");
                assert!(
                    outliers >= 88,
                    "{label}: {outliers} outliers without the rule"
                );
            }
            let (s, dwell) = check(&label, &Ok(alone), &rows, &motion, &PlanarConfig::default())
                .expect("accepted");
            assert!(s.within_one_percent(), "{label}: {s}");
            // The still rows (less those the repetition rule drops).
            assert!(dwell >= 220, "{label}: {dwell} set aside");
            worst = worst.max(s);
            let rows32: Vec<[f32; 3]> = rows[turn.clone()]
                .iter()
                .map(|r| r.map(|v| v as f32))
                .collect();
            let alone32 = calibrate_planar::<f32, _>(&rows32, &PlanarConfig::default());
            let config = PlanarConfig::default();
            let (s, _) = check(&format!("{label}, f32"), &alone32, &rows, &motion, &config)
                .expect("accepted");
            assert!(s.within_one_percent(), "{label} f32: {s}");
        }
    }
    println!("worst: {worst}");
    // The simulation reproduces the report: the rule is what accepts it.
    assert!(
        refused_without >= 2,
        "{refused_without} of 8 refused without the rule"
    );
}

/// One full turn, both still periods on one heading (more than half the
/// rows on one point): accepted as the turn alone.
#[test]
fn one_full_turn_between_still_periods_on_one_heading() {
    for seed in 1..=8u64 {
        let (rows, turn) = robot_log(120, 200, (0.002, 0.019), 1.0, seed);
        let motion: Vec<usize> = turn.clone().collect();
        let alone = calibrate_planar::<f64, _>(&rows[turn], &PlanarConfig::default());
        let without = calibrate_planar::<f64, _>(&rows, &without_rule(&PlanarConfig::default()));
        println!(
            "seed {seed} without the rule: {:?}",
            without.as_ref().map(|f| f.report.rejected)
        );
        let (s, _) = check(
            &format!("one turn, seed {seed}"),
            &alone,
            &rows,
            &motion,
            &PlanarConfig::default(),
        )
        .expect("accepted");
        assert!(s.within_one_percent(), "seed {seed}: {s}");
    }
}

/// Still periods before, after, at both ends or in the middle of the
/// robot's turn and of the shared planar recording, each 1x to 10x the
/// motion's rows, noise 0.2 %, 1 % and 3 % of the field in the plane:
/// within 1 % of the field of the fit without them, no acceptance turned
/// into a refusal.
#[test]
fn still_periods_of_every_size_place_and_noise_leave_the_fit() {
    let (robot, turn) = robot_log(0, 200, (0.0, 0.019), 1.1, 1);
    assert_eq!(turn, 0..200);
    let recordings: Vec<(&str, Vec<[f64; 3]>, PlanarConfig)> = vec![
        ("robot turn", robot, PlanarConfig::default()),
        (
            "planar_243.txt",
            read_xyz("planar_243.txt"),
            PlanarConfig::with_up([0.0, 0.0, 1.0]),
        ),
    ];
    println!("| case | rows | shift | set aside | used | screened + rejected |");
    println!("|---|---|---|---|---|---|");
    let mut worst = Shift::default();
    for (name, rows, config) in &recordings {
        let base = calibrate_planar::<f64, _>(rows, config);
        let field = base
            .as_ref()
            .unwrap_or_else(|e| panic!("{name} alone: {e}"))
            .calibration
            .plane_strength();
        for noise in [0.002, 0.01, 0.03] {
            for mult in [1, 2, 5, 10] {
                for place in [Place::Before, Place::After, Place::Ends, Place::Between] {
                    let k = mult * rows.len();
                    let (all, motion) = with_still(rows, place, k, noise, field, mult as u64);
                    let label = format!("{name}, {place:?} {mult}x, noise {:.1} %", 100.0 * noise);
                    let (s, dwell) = check(&label, &base, &all, &motion, config).expect("accepted");
                    assert!(s.within_one_percent(), "{label}: {s}");
                    // The still rows, less those the repetition rule drops
                    // and those of the first noise estimates.
                    let periods = if matches!(place, Place::Ends) { 2 } else { 1 };
                    assert!(
                        dwell + periods * 30 >= periods * k,
                        "{label}: {dwell} set aside"
                    );
                    worst = worst.max(s);
                }
            }
        }
    }
    println!("worst: {worst}");
}

/// Planar captures without still periods: the rule sets at most 5 % of
/// their rows aside and moves the result by at most 0.3 % of the field.
#[test]
fn captures_without_still_periods_are_left_as_they_are() {
    let mut captures: Vec<(String, Vec<[f64; 3]>, PlanarConfig)> = vec![(
        "planar_243.txt".into(),
        read_xyz("planar_243.txt"),
        PlanarConfig::with_up([0.0, 0.0, 1.0]),
    )];
    for seed in 1..=4 {
        let (rows, _) = robot_log(0, 200, (0.0, 0.019), 1.1, seed);
        captures.push((format!("robot turn {seed}"), rows, PlanarConfig::default()));
    }
    // The planar tests' level turns (two turns at a varying rate, noise 2 %
    // of the field in the plane), with roll and pitch wandering by up to
    // 8 deg (the fit error 0.15-0.2 at 8 deg, some refused).
    for tilt in [0.0, 3.0, 5.0, 8.0] {
        for seed in 1..=5 {
            let (rows, _) = level_turns(tilt, 300, seed);
            captures.push((
                format!("level turns, tilt {tilt}, seed {seed}"),
                rows,
                PlanarConfig::default(),
            ));
        }
    }
    for (name, rows, config) in &captures {
        let with = calibrate_planar::<f64, _>(rows, config);
        let without = calibrate_planar::<f64, _>(rows, &without_rule(config));
        let (a, b) = match (&with, &without) {
            (Ok(a), Ok(b)) => (a, b),
            (Err(a), Err(b)) => {
                println!("{name}: refused, {a}");
                assert_eq!(cause(a), cause(b), "{name}");
                continue;
            }
            _ => panic!("{name}: {with:?} vs {without:?}"),
        };
        let s = Shift::of(b, a, rows);
        println!(
            "{name}: {} of {} rows set aside, {s}",
            a.report.dwell,
            rows.len()
        );
        assert!(
            a.report.dwell * 20 <= rows.len(),
            "{name}: {}",
            a.report.dwell
        );
        assert!(
            s.centre <= 0.003 && s.field <= 0.003 && s.m <= 0.003,
            "{name}: {s}"
        );
    }
}

/// A refusal keeps its cause with still periods added, and a device that
/// hardly moved between two still periods is refused as such.
#[test]
fn refusals_keep_their_cause() {
    // Half a turn: too short an arc, alone and with still ends.
    let (half, turn) = robot_log(0, 150, (0.0, 0.01), 0.5, 5);
    let field = robot_plane_field();
    let base = calibrate_planar::<f64, _>(&half[turn], &PlanarConfig::default());
    assert!(matches!(base, Err(Error::ShortArc { .. })), "{base:?}");
    // A three-dimensional recording: not planar.
    let sphere = read_xyz("icm20948_mag_300.csv");
    let base3 = calibrate_planar::<f64, _>(&sphere, &PlanarConfig::default());
    assert!(matches!(base3, Err(Error::NotPlanar { .. })), "{base3:?}");
    for noise in [0.002, 0.01, 0.03] {
        for mult in [1, 10] {
            for place in [Place::Ends, Place::Between] {
                let (all, motion) = with_still(&half, place, mult * half.len(), noise, field, 7);
                let label = format!("half turn, {place:?} {mult}x, noise {noise}");
                assert!(check(&label, &base, &all, &motion, &PlanarConfig::default()).is_none());
                let (all, motion) =
                    with_still(&sphere, place, mult * sphere.len(), noise, 300.0, 7);
                let label = format!("icm20948, {place:?} {mult}x, noise {noise}");
                assert!(check(&label, &base3, &all, &motion, &PlanarConfig::default()).is_none());
            }
        }
    }
    // Two still periods with one row of motion between: hardly moved.
    let (log, _) = robot_log(300, 1, (0.005, 0.005), 0.5, 6);
    let got = calibrate_planar::<f64, _>(&log, &PlanarConfig::default());
    println!("two still periods, one row between: {got:?}");
    assert!(
        matches!(
            got,
            Err(Error::Fit(FitError::HardlyMoved { required: 10, .. }))
        ),
        "{got:?}"
    );
    let text = got.map(|_| ()).unwrap_err().to_string();
    assert!(text.starts_with("the device hardly moved"), "{text}");
}

/// The core rule, in the batch fit: one still period of 10x the motion at
/// 3 % noise before, after or in the middle of a 3-D recording leaves the
/// fit (its guard's spread is that of the rows outside the still period:
/// the spread of all rows shrank below the period's own radius, and the
/// batch fit refused `NoSphere` 0.43 after the recording).
#[test]
fn one_long_noisy_still_period_leaves_the_batch_fit() {
    use mag_cal_core::{calibrate, Config};
    let rows = read_xyz("icm20948_mag_300.csv");
    let base = calibrate::<f64, _>(&rows, &Config::default()).expect("accepted");
    let rho = base.calibration.field_strength();
    let b0 = base.calibration.hard_iron();
    for place in [Place::Before, Place::After, Place::Between, Place::Ends] {
        let (all, _) = with_still(&rows, place, 10 * rows.len(), 0.03, rho, 3);
        let fit = calibrate::<f64, _>(&all, &Config::default())
            .unwrap_or_else(|e| panic!("{place:?}: {e}"));
        let b = fit.calibration.hard_iron();
        let db = (0..3).map(|i| (b[i] - b0[i]).powi(2)).sum::<f64>().sqrt() / rho;
        let drho = (fit.calibration.field_strength() - rho).abs() / rho;
        println!(
            "icm20948 {place:?} 10x at 3 %: {} set aside, b {:.3} %, field {:.3} %",
            fit.report.dwell,
            100.0 * db,
            100.0 * drho
        );
        assert!(db < 0.01 && drho < 0.01, "{place:?}: {db} {drho}");
        let periods = if matches!(place, Place::Ends) { 2 } else { 1 };
        assert!(
            fit.report.dwell + 30 * periods >= 3000 * periods,
            "{place:?}: {}",
            fit.report.dwell
        );
    }
}

/// A spike among the first rows sets nothing aside: it started the still
/// rule's noise average thousands of times too large, and the first run of
/// motion took a ball a quarter of the field wide (`icm20948_mag_300.csv`
/// with a spike at row 1 was refused as poor coverage; the planar tests'
/// glitches set 66 rows of two turns aside).
#[test]
fn a_spike_among_the_first_rows_sets_nothing_aside() {
    use mag_cal_core::{calibrate, Config};
    for name in ["icm20948_mag_300.csv", "mag3_raw_541.csv"] {
        let rows = read_xyz(name);
        let base = calibrate::<f64, _>(&rows, &Config::default()).expect("accepted");
        let rho = base.calibration.field_strength();
        let b0 = base.calibration.hard_iron();
        for at in [1, 2, 3, 4, 10] {
            let mut dirty = rows.clone();
            dirty[at] = [5000.0, -3000.0, 30000.0];
            let fit = calibrate::<f64, _>(&dirty, &Config::default())
                .unwrap_or_else(|e| panic!("{name}, spike at {at}: {e}"));
            let b = fit.calibration.hard_iron();
            let db = (0..3).map(|i| (b[i] - b0[i]).powi(2)).sum::<f64>().sqrt() / rho;
            println!(
                "{name}, spike at {at}: {} set aside, b {:.3} %",
                fit.report.dwell,
                100.0 * db
            );
            assert_eq!(fit.report.dwell, 0, "{name}, spike at {at}");
            assert!(db < 0.001, "{name}, spike at {at}: {db}");
        }
    }
    let (turns, _) = level_turns(2.0, 400, 11);
    for at in [1, 2, 3, 4] {
        let mut dirty = turns.clone();
        dirty[at] = [-4878.0, 1037.0, 30000.0];
        let with = calibrate_planar::<f64, _>(&dirty, &PlanarConfig::default()).expect("accepted");
        let without = calibrate_planar::<f64, _>(&dirty, &without_rule(&PlanarConfig::default()))
            .expect("accepted");
        let s = Shift::of(&without, &with, &turns);
        println!(
            "level turns, spike at {at}: {} set aside, {s}",
            with.report.dwell
        );
        assert_eq!(with.report.dwell, 0, "level turns, spike at {at}");
    }
}
