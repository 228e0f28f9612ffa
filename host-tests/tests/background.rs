//! The background calibrator (`mag_cal_core::background`) on simulated
//! ordinary use (`host_tests::background`; the `background-table` binary
//! writes the table of `docs/results.md`).

use host_tests::background::{render, study, Kind, Outcome, CHANGE_AT};

fn runs(study: &[(Kind, Vec<Outcome>)], kind: Kind) -> &[Outcome] {
    &study.iter().find(|(k, _)| *k == kind).expect("studied").1
}

#[test]
fn ordinary_use_jumps_drift_and_a_magnet() {
    let s = study(20);
    print!("{}", render(&s));
    let within =
        |e: Option<(f64, f64)>, limit: f64| e.is_some_and(|(m, b)| m <= limit && b <= limit);
    for kind in Kind::ALL {
        for (seed, o) in runs(&s, kind).iter().enumerate() {
            // Every run calibrates in the first half, from ordinary use.
            assert!(
                o.first.is_some_and(|f| f < CHANGE_AT),
                "{kind:?} {seed}: {o:?}"
            );
            // Nothing but a moved hard iron is adopted as one, and a magnet
            // passing changes nothing.
            assert_eq!(o.false_adoptions, 0, "{kind:?} {seed}: {o:?}");
            // Never silently wrong.
            if kind != Kind::Drift {
                assert!(within(o.end, 0.05), "{kind:?} {seed}: {o:?}");
            }
        }
        // As accurate as the batch fit of the same buffers, in the median
        // (a run may keep an earlier calibration that fits its buffer
        // within 10 % of a new fit: docs/results.md).
        if kind != Kind::Drift {
            let med = |f: &dyn Fn(&Outcome) -> Option<f64>| {
                host_tests::background::median(runs(&s, kind).iter().filter_map(f).collect())
                    .expect("runs")
            };
            for (name, end, batch) in [
                (
                    "e_M",
                    med(&|o| o.end.map(|e| e.0)),
                    med(&|o| o.batch.map(|e| e.0)),
                ),
                (
                    "e_b",
                    med(&|o| o.end.map(|e| e.1)),
                    med(&|o| o.batch.map(|e| e.1)),
                ),
            ] {
                assert!(
                    end <= 1.5 * batch + 0.005,
                    "{kind:?} {name}: {end} against batch {batch}"
                );
            }
        }
    }
    for o in runs(&s, Kind::Steady).iter().chain(runs(&s, Kind::Magnet)) {
        assert_eq!(
            o.adoptions.1, 0,
            "no offsets-only fit without a change: {o:?}"
        );
    }
    let jumps = runs(&s, Kind::Jump);
    for (seed, o) in jumps.iter().enumerate() {
        // The jump (0.16 of the field) is detected, and the offsets
        // re-estimated, within 2000 readings (40 s at 50 Hz) in every run.
        assert!(o.detected.is_some_and(|d| d < 2000), "{seed}: {o:?}");
    }
    // e_b is back to its level before the jump in at least 90 % of the
    // runs, within 1000 readings in the median (in the others the
    // offsets-only fit leaves it a little above: still within 0.05, above).
    let recovered: Vec<f64> = jumps
        .iter()
        .map(|o| o.recovered.map_or(f64::INFINITY, |r| r as f64))
        .collect();
    let back = recovered.iter().filter(|r| r.is_finite()).count();
    assert!(
        back * 10 >= jumps.len() * 9,
        "{back} of {} recovered",
        jumps.len()
    );
    assert!(host_tests::background::median(recovered).is_some_and(|m| m < 1000.0));
    // The drift (0.16 of the field over the second half) is followed only
    // in part (docs/results.md): at the end the hard iron is off by less
    // than the drift in every run, and by less than half of it in most.
    let drift = runs(&s, Kind::Drift);
    for (seed, o) in drift.iter().enumerate() {
        assert!(o.end.is_some_and(|e| e.1 < 0.9 * 0.16), "{seed}: {o:?}");
    }
    let ends: Vec<f64> = drift.iter().map(|o| o.end.map_or(1.0, |e| e.1)).collect();
    assert!(host_tests::background::median(ends).is_some_and(|m| m < 0.08));
}
