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

/// Issue 36 for the background calibrator: still periods before, between
/// and after the motion, each up to ten times as long as it, at noise of
/// 0.2 % to 3 % of the field, never take the calibration away, and leave
/// the one in use at the end as accurate as without them (within 1 % of
/// the field against the truth). Before a calibration a reading is
/// buffered only once the device moved beyond the sensor's noise (the
/// collector's rule); after, its calibrated direction must differ from the
/// last buffered one by `min_angle_deg`, and a direction cell holds at
/// most `K` samples.
///
/// Against the truth, not against the run without still periods: the
/// calibrator adopts a refit only when it fits the buffer 10 % better
/// than the calibration in use, so its result depends on the path (at
/// 1 % noise two runs that differ only by a still start end 2.3 % of the
/// field apart, each within 1.5-1.9 % of the truth).
#[test]
fn still_periods_change_nothing_in_the_background() {
    use host_tests::background::{calibrator, ordinary_use, truth};
    use host_tests::sim::Rng;
    use nalgebra::{Matrix3, Vector3};
    let truth = truth();
    let rho = truth.t.determinant().abs().cbrt();
    let t_inv = truth.t.try_inverse().expect("invertible");
    let m_true = t_inv.transpose() * t_inv;
    // The errors (e_b, e_M) of the calibration in use at the end of a run.
    let end = |samples: &[[i16; 3]]| {
        let mut bg = calibrator();
        for s in samples {
            bg.push(*s);
            bg.step();
        }
        bg.calibration().map(|c| {
            let w = Matrix3::from_fn(|r, k| f64::from(c.soft_iron()[r][k]));
            let b = Vector3::from(c.hard_iron().map(f64::from));
            let m = w.transpose() * w;
            (
                (b - truth.b).norm() / rho,
                (m - m_true).norm() / m_true.norm(),
            )
        })
    };
    // A slow tumble through every orientation (at 3 % noise, ordinary
    // use, which tilts by 80 deg at most, is refused with and without
    // still periods).
    let tumble = |n: usize| -> Vec<Vector3<f64>> {
        (0..n)
            .map(|k| {
                let z = (k as f64 * 0.0021).sin();
                let (r, phi) = ((1.0 - z * z).sqrt(), k as f64 * 0.05);
                Vector3::new(r * phi.cos(), r * phi.sin(), z)
            })
            .collect()
    };
    for (seed, noise, dirs) in [
        (1u64, 0.002, ordinary_use(30_000, 1)),
        (2, 0.01, ordinary_use(30_000, 2)),
        (3, 0.03, tumble(12_000)),
    ] {
        let mut rng = Rng::for_case(seed, 36);
        let mut read = |h: &Vector3<f64>| {
            let n = Vector3::new(rng.normal(), rng.normal(), rng.normal()) * noise * rho;
            let y = truth.t * h + truth.b + n;
            [y.x, y.y, y.z].map(|v| v.round() as i16)
        };
        let motion: Vec<[i16; 3]> = dirs.iter().map(&mut read).collect();
        let (b0, m0) = end(&motion).expect("the motion alone calibrates");
        let (first, last, mid) = (dirs[0], dirs[dirs.len() - 1], dirs[dirs.len() / 2]);
        for factor in [1usize, 10] {
            let mut still = |h: Vector3<f64>| {
                (0..factor * motion.len())
                    .map(|_| read(&h))
                    .collect::<Vec<_>>()
            };
            let (before, between, after) = (still(first), still(mid), still(last));
            let half = motion.len() / 2;
            let logs: [(&str, Vec<[i16; 3]>); 3] = [
                ("before and after", [&before[..], &motion, &after].concat()),
                (
                    "between",
                    [&motion[..half], &between, &motion[half..]].concat(),
                ),
                ("after", [&motion[..], &after].concat()),
            ];
            for (name, log) in logs {
                let what = format!("noise {noise}, {factor}x still {name}");
                let (e_b, e_m) = end(&log).unwrap_or_else(|| panic!("{what}: no calibration"));
                println!("{what}: e_b {e_b:.4}, e_M {e_m:.4} (motion alone {b0:.4}, {m0:.4})");
                assert!(
                    e_b <= b0 + 0.01 && e_m <= m0 + 0.01,
                    "{what}: e_b {e_b:.4}, e_M {e_m:.4}"
                );
            }
        }
    }
}
