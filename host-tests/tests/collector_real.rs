//! The on-device collector on real recordings, after a start lying still:
//! the still start stores (almost) nothing, and the recording then
//! collects as it does alone (`cargo test -p host-tests --test
//! collector_real -- --nocapture` prints the readings to ready).

use host_tests::real::read_xyz;
use host_tests::sim::Rng;
use mag_cal_core::collector::{Collector, Offer};
use mag_cal_core::{calibrate, Config};

/// Offers every reading; the reading (0-based) at which the collector
/// first said ready, and the restarts.
fn collect<const N: usize>(
    c: &mut Collector<[f64; 3], N>,
    rows: &[[f64; 3]],
) -> (Option<usize>, usize) {
    let mut ready = None;
    let mut restarts = 0;
    for (k, r) in rows.iter().enumerate() {
        restarts += usize::from(c.offer(*r) == Offer::Restarted);
        if ready.is_none() && c.is_ready() {
            ready = Some(k);
        }
    }
    (ready, restarts)
}

/// Hard-iron distance between a calibration of the collected samples and
/// one of the whole recording, over the field strength.
fn hard_iron_gap(samples: &[[f64; 3]], all: &[[f64; 3]]) -> f64 {
    let kept = calibrate::<f64, _>(samples, &Config::default())
        .unwrap()
        .calibration;
    let whole = calibrate::<f64, _>(all, &Config::default())
        .unwrap()
        .calibration;
    (kept.hard_iron_vector() - whole.hard_iron_vector()).norm() / whole.field_strength()
}

/// A device lying still (the recording's first reading plus 2 counts of
/// independent noise per axis, rounded to counts) for 300 to 30 000
/// readings, then the recording: the still part leaves one sample and
/// no progress, and the recording becomes ready within 10 readings of
/// when it does alone, on samples that calibrate like the whole recording.
#[test]
fn a_still_start_then_a_recording_calibrates() {
    for name in ["icm20948_mag_300.csv", "mag3_raw_541.csv"] {
        let rows = read_xyz(name);
        let mut alone: Collector<[f64; 3], 600> = Collector::default();
        let (ready_alone, _) = collect(&mut alone, &rows);
        let ready_alone = ready_alone.expect("ready alone");
        for n in [300, 3_000, 30_000] {
            let mut rng = Rng(n as u64);
            let still: Vec<[f64; 3]> = (0..n)
                .map(|_| rows[0].map(|v| (v + 2.0 * rng.normal()).round()))
                .collect();
            let mut c: Collector<[f64; 3], 600> = Collector::default();
            let (ready, restarts) = collect(&mut c, &still);
            let p = c.progress();
            assert!(ready.is_none() && restarts == 0, "{name}: {p:?}");
            assert!(p.samples <= 2 && p.percent <= 2, "{name}: {p:?}");
            let (ready, restarts) = collect(&mut c, &rows);
            let gap = hard_iron_gap(c.samples(), &rows);
            println!(
                "{name}: still {n}: ready {ready:?} readings into the recording (alone {ready_alone}), {restarts} restarts, {} samples, |db|/rho {gap:.4}",
                c.len()
            );
            assert_eq!(restarts, 0);
            let at = ready.expect("never ready");
            assert!(at <= ready_alone + 10, "{name}: {at} against {ready_alone}");
            assert!(gap < 0.01, "{name}: {gap}");
        }
    }
}

/// Real still noise: `magcal_25598.txt` lies still for its rows 50..200
/// (per-axis spread 0.003 of a 0.6 field, 0.5 %). Those rows played 200
/// times over (30 000 readings) keep one sample; the whole recording
/// after them collects as it does alone (ready after 4 952 readings with
/// capacity 4 000).
#[test]
fn real_still_noise_keeps_nothing() {
    let rows = read_xyz("magcal_25598.txt");
    let still: Vec<[f64; 3]> = rows[50..200].iter().cycle().take(30_000).copied().collect();
    let mut c: Collector<[f64; 3], 4000> = Collector::default();
    let (ready, restarts) = collect(&mut c, &still);
    let p = c.progress();
    assert!(ready.is_none() && restarts == 0 && p.samples <= 2, "{p:?}");
    let (ready, restarts) = collect(&mut c, &rows);
    let mut alone: Collector<[f64; 3], 4000> = Collector::default();
    let (ready_alone, _) = collect(&mut alone, &rows);
    let gap = hard_iron_gap(c.samples(), &rows);
    println!(
        "magcal_25598 after 30 000 still readings: ready {ready:?} (alone {ready_alone:?}), {restarts} restarts, |db|/rho {gap:.4}"
    );
    assert_eq!(restarts, 0);
    assert!(
        ready.is_some() && ready <= ready_alone.map(|r| r + 10),
        "{ready:?}"
    );
    assert!(gap < 0.01, "{gap}");
}
