//! End-to-end behaviour of `calibrate` against generated truth.

use mag_cal_core::{calibrate, Config, Error, LsVariant, Method};
use nalgebra::{Matrix3, Rotation3, Vector3};

/// Unit directions on a Fibonacci sphere.
fn directions(n: usize) -> Vec<Vector3<f64>> {
    (0..n)
        .map(|i| {
            let z = 1.0 - 2.0 * (i as f64 + 0.5) / n as f64;
            let r = (1.0 - z * z).sqrt();
            let phi = i as f64 * 2.399_963_229_728_653;
            Vector3::new(r * phi.cos(), r * phi.sin(), z)
        })
        .collect()
}

/// A distortion with distinct singular values and a rotation.
fn truth(scale: f64) -> (Matrix3<f64>, Vector3<f64>) {
    let r = Rotation3::from_euler_angles(0.3, -0.2, 0.5);
    let t = r.matrix() * Matrix3::from_diagonal(&Vector3::new(1.25, 0.85, 1.05)) * scale;
    (t, Vector3::new(0.3, -0.2, 0.1) * scale * 3.0)
}

fn samples(t: &Matrix3<f64>, b: &Vector3<f64>, n: usize) -> Vec<[f64; 3]> {
    directions(n).iter().map(|h| (t * h + b).into()).collect()
}

fn rel_err_m(fit_m: &Matrix3<f64>, t: &Matrix3<f64>) -> f64 {
    let m = (t * t.transpose()).try_inverse().unwrap();
    (fit_m - m).amax() / m.amax()
}

#[test]
fn noise_free_recovery_every_variant_and_method_f64() {
    let (t, b) = truth(1.0);
    let y = samples(&t, &b, 500);
    for ls in [LsVariant::Ls9, LsVariant::Svd10, LsVariant::LiGriffiths] {
        for method in [Method::Ls, Method::Adc2] {
            let cfg = Config {
                method,
                ls,
                ..Config::default()
            };
            let fit = calibrate::<f64, _>(&y, &cfg).unwrap();
            let c = fit.calibration;
            let em = rel_err_m(&Matrix3::from(c.shape()), &t);
            let eb = (Vector3::from(c.hard_iron()) - b).amax();
            println!(
                "{ls:?} {method:?}: eM {em:.2e} eb {eb:.2e} it {} rms {:.2e}",
                fit.report.iterations, fit.report.radial_rms
            );
            assert!(em < 1e-9 && eb < 1e-9, "{ls:?} {method:?}: {em} {eb}");
            let rho = t.determinant().abs().cbrt();
            assert!((c.field_strength() - rho).abs() < 1e-9 * rho);
        }
    }
}

#[test]
fn f32_with_large_offset() {
    let t = Matrix3::from_diagonal(&Vector3::new(2000.0, 1800.0, 2100.0));
    let b = Vector3::new(25000.0, -25000.0, 25000.0);
    let y: Vec<[f32; 3]> = directions(1000)
        .iter()
        .map(|h| {
            let v = t * h + b;
            [v.x as f32, v.y as f32, v.z as f32]
        })
        .collect();
    for ls in [LsVariant::Ls9, LsVariant::Svd10, LsVariant::LiGriffiths] {
        let fit = calibrate::<f32, _>(
            &y,
            &Config {
                ls,
                ..Config::default()
            },
        )
        .unwrap();
        let c = fit.calibration;
        let m = Matrix3::from(c.shape()).map(f64::from);
        let em = rel_err_m(&m, &t);
        let eb = (Vector3::from(c.hard_iron()).map(f64::from) - b).amax() / 2000.0;
        println!(
            "f32 {ls:?}: eM {em:.2e} eb {eb:.2e} it {}",
            fit.report.iterations
        );
        assert!(em < 1e-4 && eb < 1e-4, "{ls:?}: {em} {eb}");
    }
}

#[test]
fn errors() {
    let cfg = Config::default();
    let few = vec![[1.0f64, 2.0, 3.0]; 5];
    assert_eq!(
        calibrate::<f64, _>(&few, &cfg).unwrap_err(),
        Error::TooFewSamples {
            found: 5,
            required: 10
        }
    );
    let same = vec![[1.0f64, 2.0, 3.0]; 50];
    assert_eq!(
        calibrate::<f64, _>(&same, &cfg).unwrap_err(),
        Error::AllSamplesEqual
    );
    let nan = vec![[f64::NAN, 2.0, 3.0]; 50];
    assert_eq!(
        calibrate::<f64, _>(&nan, &cfg).unwrap_err(),
        Error::TooFewSamples {
            found: 0,
            required: 10
        }
    );
    let (t, b) = truth(1e30);
    let huge: Vec<[f32; 3]> = samples(&t, &b, 100)
        .iter()
        .map(|v| v.map(|x| x as f32))
        .collect();
    assert_eq!(
        calibrate::<f32, _>(&huge, &cfg).unwrap_err(),
        Error::OutOfRange
    );
    let (t, b) = truth(1e-40);
    let tiny: Vec<[f32; 3]> = samples(&t, &b, 100)
        .iter()
        .map(|v| v.map(|x| x as f32))
        .collect();
    assert_eq!(
        calibrate::<f32, _>(&tiny, &cfg).unwrap_err(),
        Error::OutOfRange
    );
    // a planar circle
    let planar: Vec<[f64; 3]> = (0..100)
        .map(|i| {
            let a = i as f64 * 0.0628;
            [a.cos(), a.sin(), 0.0]
        })
        .collect();
    let e = calibrate::<f64, _>(&planar, &cfg).unwrap_err();
    assert!(
        matches!(e, Error::Planar { flatness, limit } if flatness.get() < limit.get()),
        "{e}"
    );
}

#[test]
fn huge_values_work_in_f64() {
    let (t, b) = truth(1e30);
    let y = samples(&t, &b, 300);
    let fit = calibrate::<f64, _>(&y, &Config::default()).unwrap();
    assert!(rel_err_m(&Matrix3::from(fit.calibration.shape()), &t) < 1e-9);
}

#[test]
fn soft_iron_is_exactly_symmetric() {
    let (t, b) = truth(3.0);
    let mut y = samples(&t, &b, 300);
    // a little deterministic "noise" so that nothing is exact by accident
    for (i, v) in y.iter_mut().enumerate() {
        v[i % 3] += 1e-3 * ((i * 7919 % 13) as f64 - 6.0);
    }
    let w = calibrate::<f64, _>(&y, &Config::default())
        .unwrap()
        .calibration
        .soft_iron();
    for (i, row) in w.iter().enumerate() {
        for (j, x) in row.iter().enumerate() {
            assert_eq!(*x, w[j][i], "symmetric");
        }
    }
}

/// A method or LS variant whose cargo feature is off is refused by the
/// feature's name, and one that is on runs (`cargo xtask test` also runs
/// this with `--no-default-features --features adc1`).
#[test]
fn a_method_left_out_is_refused_by_its_feature() {
    let (t, b) = truth(300.0);
    let y = samples(&t, &b, 300);
    for method in Method::ALL {
        let config = Config {
            method,
            ..Config::default()
        };
        let r = calibrate::<f64, _>(&y, &config);
        if method.is_enabled() {
            assert!(r.is_ok(), "{method:?}: {r:?}");
        } else {
            let feature = method.feature();
            assert_eq!(r.unwrap_err(), Error::NotEnabled { feature });
            assert!(Error::NotEnabled { feature }.to_string().contains(feature));
        }
    }
    for ls in [LsVariant::Svd10, LsVariant::LiGriffiths] {
        let config = Config {
            ls,
            ..Config::default()
        };
        let r = calibrate::<f64, _>(&y, &config);
        let enabled = match ls {
            LsVariant::Svd10 => cfg!(feature = "svd10"),
            _ => cfg!(feature = "lg10"),
        };
        if enabled {
            assert!(r.is_ok(), "{ls:?}: {r:?}");
        } else {
            assert_eq!(
                r.unwrap_err(),
                Error::NotEnabled {
                    feature: ls.feature()
                }
            );
        }
    }
}

/// A device lying still (most rows on one point): refused by the
/// screening, naming the caller's fit-error limit, not the default one;
/// its infinite fit error is refused whatever the limit. (Without the
/// `robust` feature no screening: the LS fit fails, `NotAnEllipsoid`.)
#[cfg(feature = "robust")]
#[test]
fn a_still_device_names_the_configured_limit() {
    let still: Vec<[i16; 3]> = (0..200)
        .map(|i| [120 + i % 3, -40 + i % 5, 300 + i % 2])
        .collect();
    for limit in [0.2f32, 0.3, 0.123, f32::INFINITY] {
        let cfg = Config {
            thresholds: mag_cal_core::Thresholds {
                refuse_fit_error: limit,
                ..mag_cal_core::Thresholds::DEFAULT
            },
            ..Config::default()
        };
        let e = calibrate::<f32, _>(&still, &cfg).unwrap_err();
        assert!(
            matches!(e, Error::NoSphere { limit: l, .. } if l.get() == limit),
            "{e:?}"
        );
        let shown = format!("fit error limit {limit})");
        assert!(e.to_string().contains(&shown), "{e}");
    }
}

/// A noise ball (a Gaussian blob, no shell) and a flat circle, judged with
/// limits the caller set: each refusal names that limit, on the plain path
/// and through the screening of the robust one.
#[test]
fn refusals_name_the_configured_limits() {
    // A Gaussian blob of 600 rows (Box-Muller on a fixed LCG).
    let mut seed = 0x2545_f491_4f6c_dd1d_u64;
    let mut uniform = || {
        seed = seed.wrapping_mul(6_364_136_223_846_793_005).wrapping_add(1);
        ((seed >> 11) as f64 + 0.5) / (1u64 << 53) as f64
    };
    let mut normal = || {
        let (u, v) = (uniform(), uniform());
        (-2.0 * u.ln()).sqrt() * (std::f64::consts::TAU * v).cos()
    };
    let ball: Vec<[f64; 3]> = (0..600)
        .map(|_| {
            [
                200.0 + 80.0 * normal(),
                -50.0 + 80.0 * normal(),
                30.0 + 80.0 * normal(),
            ]
        })
        .collect();
    // A circle in a tilted plane: flatness 0.
    let circle: Vec<[f64; 3]> = directions(400)
        .iter()
        .map(|h| {
            let a = h.z * std::f64::consts::PI;
            [
                100.0 + 300.0 * a.cos(),
                20.0 + 300.0 * a.sin(),
                5.0 + 30.0 * a.sin(),
            ]
        })
        .collect();
    for robust in [true, false] {
        for limit in [0.15f32, 0.2, 0.3] {
            let config = Config {
                robust,
                thresholds: mag_cal_core::Thresholds {
                    refuse_fit_error: limit,
                    ..mag_cal_core::Thresholds::DEFAULT
                },
                ..Config::default()
            };
            let e = calibrate::<f32, _>(&ball, &config).unwrap_err();
            assert!(
                matches!(e, Error::NoSphere { fit_error, limit: l } if l.get() == limit && fit_error.get() > limit),
                "robust {robust}, limit {limit}: {e:?}"
            );
            assert!(e.to_string().contains(&format!(", limit {limit}")), "{e}");
        }
        for limit in [0.01f32, 0.05] {
            let config = Config {
                robust,
                thresholds: mag_cal_core::Thresholds {
                    refuse_flatness: limit,
                    ..mag_cal_core::Thresholds::DEFAULT
                },
                ..Config::default()
            };
            let e = calibrate::<f64, _>(&circle, &config).unwrap_err();
            assert!(
                matches!(e, Error::Planar { limit: l, .. } if l.get() == limit),
                "robust {robust}, limit {limit}: {e:?}"
            );
            assert!(e.to_string().contains(&format!(", limit {limit})")), "{e}");
        }
    }
}

/// Without the `robust` feature the plain pipeline answers alone: the
/// glitch rules (with `Config::robust`, the default) drop the zero rows
/// and the repeated ones, and every row they keep is used, displaced
/// or not: no screening, no residual cut, no robust pass. With
/// `Config::robust` off, the zero rows and repeats are used too.
#[cfg(not(feature = "robust"))]
#[test]
fn the_plain_build_keeps_the_glitch_rules_and_trusts_every_row_they_keep() {
    let (t, b) = truth(300.0);
    let n = 600;
    let mut rows: Vec<[i16; 3]> = samples(&t, &b, n)
        .iter()
        .map(|y| y.map(|v| v.round() as i16))
        .collect();
    // Every 50th row a failed read (zero), every 50th (another) a
    // repeat of the row before, every 10th (others) displaced by 55
    // counts on each axis.
    let (mut zeros, mut repeats, mut displaced) = (0, 0, 0);
    for i in 1..n {
        match i % 50 {
            7 => {
                rows[i] = [0; 3];
                zeros += 1;
            }
            21 => {
                rows[i] = rows[i - 1];
                repeats += 1;
            }
            k if k % 10 == 3 => {
                rows[i] = rows[i].map(|v| v + 55);
                displaced += 1;
            }
            _ => {}
        }
    }
    assert!(zeros > 0 && repeats > 0 && displaced > 0);
    let fit = calibrate::<f32, _>(&rows, &Config::default()).unwrap();
    let r = &fit.report;
    assert_eq!((r.drops.zero, r.drops.repeated), (zeros, repeats));
    assert_eq!(r.samples_used, n - zeros - repeats);
    assert_eq!((r.screened, r.rejected, r.robust_passes), (0, 0, 0));
    assert!(r.selection.glitch_rules && r.selection.screen.is_none());
    assert!(r.selection.residual_limit.is_none() && r.quality.outlier_share == 0.0);
    // Without the glitch rules the zero rows and repeats are used too.
    let plain = Config {
        robust: false,
        ..Config::default()
    };
    let fit = calibrate::<f32, _>(&rows, &plain).unwrap();
    assert_eq!(fit.report.samples_used, n);
    assert_eq!(fit.report.drops.total(), 0);
    assert!(!fit.report.selection.glitch_rules);
}
