//! Offsets-only calibration (`mag_cal_core::offsets`): the soft iron known,
//! the hard iron moved, readings over a cap of directions of half-angle
//! alpha. Run with `--nocapture` for the table of `docs/results.md`.

use host_tests::sim::Rng;
use mag_cal_core::offsets::{refit_offsets, Strength};
use mag_cal_core::{calibrate, Calibration, Config, Error};
use nalgebra::{Matrix3, Rotation3, Vector3};

/// The sensor: a tilted, anisotropic soft iron `T` (field 320 counts),
/// the old and the new hard iron.
fn sensor() -> (Matrix3<f64>, Vector3<f64>, Vector3<f64>) {
    let r = Rotation3::from_euler_angles(0.3, -0.2, 0.5);
    let t = r.matrix() * Matrix3::from_diagonal(&Vector3::new(1.2, 0.9, 1.05)) * 320.0;
    (
        t,
        Vector3::new(150.0, -80.0, 60.0),
        Vector3::new(190.0, -50.0, 35.0),
    )
}

/// `n` readings with directions uniform on the cap of half-angle `alpha`
/// (degrees) about a fixed axis, noise 1 % of the field per axis.
fn cap(alpha: f64, n: usize, seed: u64) -> Vec<[f64; 3]> {
    let (t, _, b) = sensor();
    let mut rng = Rng::for_case(seed, 0);
    let axis = Rotation3::from_euler_angles(0.7, 0.4, 0.0);
    let cos_max = alpha.to_radians().cos();
    (0..n)
        .map(|_| {
            let z = 1.0 - rng.uniform() * (1.0 - cos_max);
            let phi = rng.uniform() * std::f64::consts::TAU;
            let s = (1.0 - z * z).max(0.0).sqrt();
            let h = axis * Vector3::new(s * phi.cos(), s * phi.sin(), z);
            let noise = Vector3::new(rng.normal(), rng.normal(), rng.normal()) * 3.2;
            let y = t * h + b + noise;
            [y.x, y.y, y.z]
        })
        .collect()
}

/// The old calibration: the true soft iron, the old hard iron.
fn previous() -> Calibration<f64> {
    let (t, b_old, _) = sensor();
    let w = t.try_inverse().unwrap();
    Calibration::from_nalgebra(b_old, w).unwrap()
}

fn e_b(b: [f64; 3]) -> f64 {
    let (_, _, b_new) = sensor();
    (Vector3::from(b) - b_new).norm() / 320.0
}

/// Median of the accepted runs' `e_b`, and how many of `runs` were refused.
fn study(alpha: f64, strength: Option<Strength>, runs: u64) -> (f64, u64, f64) {
    let mut errors = Vec::new();
    let mut refused = 0;
    let mut determinacy = Vec::new();
    for seed in 0..runs {
        let y = cap(alpha, 200, seed);
        let r = match strength {
            Some(s) => refit_offsets::<f64, _>(&y, &previous(), s).map(|f| {
                determinacy.push(f.determinacy);
                f.calibration.hard_iron()
            }),
            None => calibrate::<f64, _>(&y, &Config::default()).map(|f| f.calibration.hard_iron()),
        };
        match r {
            Ok(b) => errors.push(e_b(b)),
            Err(Error::OffsetsUndetermined { determinacy: d, .. }) => {
                determinacy.push(f64::from(d.get()));
                refused += 1;
            }
            Err(e) => {
                if std::env::var("OFFSETS_DEBUG").is_ok() {
                    println!("alpha {alpha} seed {seed}: {e}");
                }
                refused += 1
            }
        }
    }
    errors.sort_by(f64::total_cmp);
    determinacy.sort_by(f64::total_cmp);
    let median = |v: &[f64]| {
        if v.is_empty() {
            f64::NAN
        } else {
            v[v.len() / 2]
        }
    };
    (median(&errors), refused, median(&determinacy))
}

#[test]
fn offsets_against_cap_size() {
    println!("| cap half-angle | strength known: e_b (refused of 20) | determinacy | strength unknown: e_b (refused) | determinacy | full refit (calibrate): e_b (refused) |");
    println!("|---:|---|---:|---|---:|---|");
    for alpha in [180.0, 90.0, 60.0, 45.0, 30.0, 20.0, 15.0, 10.0] {
        let (known, known_refused, known_det) = study(alpha, Some(Strength::Unchanged), 20);
        let (unknown, unknown_refused, unknown_det) = study(alpha, Some(Strength::Unknown), 20);
        let (full, full_refused, _) = study(alpha, None, 20);
        let show = |e: f64| {
            if e.is_nan() {
                "-".to_string()
            } else {
                format!("{e:.4}")
            }
        };
        println!(
            "| {alpha} deg | {} ({known_refused}) | {known_det:.3} | {} ({unknown_refused}) | {unknown_det:.3} | {} ({full_refused}) |",
            show(known),
            show(unknown),
            show(full)
        );
        // Accepted fits are good: a refusal, never a wrong offset.
        assert!(
            known.is_nan() || known < 0.02,
            "alpha {alpha}: known {known}"
        );
        assert!(
            unknown.is_nan() || unknown < 0.03,
            "alpha {alpha}: unknown {unknown}"
        );
        if alpha >= 45.0 {
            assert_eq!(known_refused, 0, "alpha {alpha}");
            assert!(known < 0.005, "alpha {alpha}: {known}");
        }
        if alpha <= 10.0 {
            assert_eq!(
                known_refused, 20,
                "alpha {alpha}: a 10 deg cap determines nothing"
            );
        }
    }
}

/// A magnet passing by: a tenth of the rows displaced by half the field are
/// left out, and the offsets stay right.
#[test]
fn a_passing_magnet_is_left_out() {
    let mut y = cap(60.0, 300, 3);
    for (i, row) in y.iter_mut().enumerate() {
        if i % 10 == 0 {
            row[0] += 160.0;
            row[1] -= 60.0;
        }
    }
    let fit = refit_offsets::<f32, _>(
        &y,
        &Calibration::from_nalgebra(
            previous().hard_iron_vector().cast(),
            previous().soft_iron_matrix().cast(),
        )
        .unwrap(),
        Strength::Unchanged,
    )
    .unwrap();
    assert!(fit.rejected >= 25, "{fit:?}");
    let b = fit.calibration.hard_iron().map(f64::from);
    assert!(e_b(b) < 0.005, "{}", e_b(b));
    // Non-finite rows are dropped and counted.
    y[7] = [f64::NAN, 0.0, 0.0];
    let fit = refit_offsets::<f64, _>(&y, &previous(), Strength::Unchanged).unwrap();
    assert_eq!(fit.samples_dropped, 1);
}

/// With the strength unknown, a changed field strength (another place) is
/// found and folded into `W`.
#[test]
fn an_unknown_strength_is_estimated() {
    let y: Vec<[f64; 3]> = cap(90.0, 300, 5);
    // The previous calibration believed the field 10 % stronger.
    let (t, b_old, _) = sensor();
    let w = (t * 1.1).try_inverse().unwrap();
    let old = Calibration::from_nalgebra(b_old, w).unwrap();
    let fit = refit_offsets::<f64, _>(&y, &old, Strength::Unknown).unwrap();
    assert!(
        (fit.strength_ratio - 1.0 / 1.1).abs() < 0.005,
        "{}",
        fit.strength_ratio
    );
    let err = e_b(fit.calibration.hard_iron());
    assert!(err < 0.01, "{err}");
    // The sensor's field strength, |det T|^(1/3).
    let want = t.determinant().abs().cbrt();
    let rho = fit.calibration.field_strength();
    assert!((rho / want - 1.0).abs() < 0.005, "{rho} vs {want}");
    assert!(fit.fit_error < 0.02, "{}", fit.fit_error);
}
