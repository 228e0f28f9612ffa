//! Parity of the methods beyond one-step ADC2 against independent
//! computations in the float64 reference:
//! - ADC1 (weighted BFGS) against the closed-form ADC2 (the SUR identity);
//! - iterated ADC2 (Anderson-accelerated) against plain fixed-point
//!   iteration of the closed-form ADC2, at tight tolerances;
//! - subMLE (BFGS, analytic gradient) against Levenberg-Marquardt with a
//!   numeric Jacobian on the same cost.

use host_tests::reference::{self, RefFit, RefLs};
use mag_cal_core::{calibrate, Config, Fit, Method};

/// The plain estimators, which the reference implements: outlier handling
/// off (the robust pipeline has its own tests, `tests/robust.rs`).
const PLAIN: Config = Config {
    robust: false,
    ..Config::DEFAULT
};

use host_tests::sim::scenario_samples as scenario;

/// max|dM| / max|M| and |db| / rho.
fn deviation(core: &Fit<f64>, want: &RefFit) -> (f64, f64) {
    let m = core.calibration.shape_matrix();
    (
        (m - want.m).amax() / want.m.amax(),
        (core.calibration.hard_iron_vector() - want.b).norm() / want.rho,
    )
}

const CASES: [([f64; 3], bool, u64); 4] = [
    ([0.01, 0.02, 0.03], false, 1),
    ([0.05, 0.075, 0.10], false, 2),
    ([0.05, 0.075, 0.10], true, 3),
    ([0.10, 0.15, 0.20], false, 4),
];

#[test]
fn adc1_equals_closed_form_adc2_for_any_noise_weight() {
    for (noise, banded, seed) in CASES {
        let y = scenario(noise, banded, seed);
        let want = reference::adc2(&y, RefLs::Ls9).unwrap();
        let estimated = Config {
            method: Method::Adc1,
            ..PLAIN
        };
        // A deliberately wrong, strongly anisotropic, correlated covariance:
        // the minimiser must not move.
        let given = Config {
            method: Method::Adc1,
            noise_covariance: Some([[4e-4, 1e-4, 0.0], [1e-4, 1e-2, -2e-3], [0.0, -2e-3, 2.5e-3]]),
            ..PLAIN
        };
        for cfg in [estimated, given] {
            let fit = calibrate::<f64, _>(&y, &cfg).unwrap();
            let (dm, db) = deviation(&fit, &want);
            println!(
                "ADC1 {noise:?} band {banded}: dM {dm:.1e} db {db:.1e}, {} iterations",
                fit.report.iterations
            );
            assert!(dm < 1e-9 && db < 1e-9, "{dm:e} {db:e}");
        }
    }
}

#[test]
fn adc1_rejects_an_invalid_noise_covariance() {
    let y = scenario([0.05; 3], false, 9);
    for bad in [
        [[1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, 1.0]],
        [[1.0, 0.5, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
        [[f64::NAN, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
    ] {
        let cfg = Config {
            method: Method::Adc1,
            noise_covariance: Some(bad),
            ..PLAIN
        };
        assert_eq!(
            calibrate::<f64, _>(&y, &cfg).unwrap_err(),
            mag_cal_core::Error::InvalidConfig {
                field: "noise_covariance"
            }
        );
    }
}

#[test]
fn iterated_adc2_reaches_the_plain_fixed_point() {
    for (noise, banded, seed) in CASES {
        let y = scenario(noise, banded, seed);
        let start = reference::ls_fit(&y, RefLs::Ls9).unwrap();
        let (plain, plain_passes) =
            reference::adc2_plain_iteration(&y, &start, 1e-14, 2000).unwrap();
        let cfg = Config {
            method: Method::Adc2Iterated,
            pass_tolerance: Some(1e-12),
            max_passes: 200,
            ..PLAIN
        };
        let fit = calibrate::<f64, _>(&y, &cfg).unwrap();
        assert!(!fit.report.warnings.contains(mag_cal_core::Warning::PassCap));
        let (dm, db) = deviation(&fit, &plain);
        println!(
            "iterated {noise:?} band {banded}: dM {dm:.1e} db {db:.1e}; {} accelerated passes vs {plain_passes} plain (to 1e-12 / 1e-14)",
            fit.report.passes
        );
        assert!(dm < 1e-9 && db < 1e-9, "{dm:e} {db:e}");
        assert!(fit.report.passes * 3 < plain_passes as u32);
    }
}

#[test]
fn iterated_adc2_hitting_the_cap_is_reported() {
    let y = scenario([0.05, 0.075, 0.10], true, 5);
    let cfg = Config {
        method: Method::Adc2Iterated,
        max_passes: 2,
        ..PLAIN
    };
    let fit = calibrate::<f64, _>(&y, &cfg).unwrap();
    assert_eq!(fit.report.passes, 2);
    assert!(fit.report.warnings.contains(mag_cal_core::Warning::PassCap));
}

#[test]
fn submle_matches_an_independent_minimiser() {
    for (noise, banded, seed) in CASES {
        let y = scenario(noise, banded, seed);
        let start = reference::ls_fit(&y, RefLs::Ls9).unwrap();
        let want = reference::submle(&y, &start).unwrap();
        let fit = calibrate::<f64, _>(
            &y,
            &Config {
                method: Method::SubMle,
                ..PLAIN
            },
        )
        .unwrap();
        let (dm, db) = deviation(&fit, &want);
        println!(
            "subMLE {noise:?} band {banded}: dM {dm:.1e} db {db:.1e}; {} iterations, {} passes",
            fit.report.iterations, fit.report.passes
        );
        // The core stops at the paper's 1e-6 step; the reference runs to 1e-12.
        assert!(dm < 1e-5 && db < 1e-5, "{dm:e} {db:e}");
    }
}

#[test]
fn f32_methods_agree_with_f64() {
    let y = scenario([0.05, 0.075, 0.10], false, 6);
    let y32: Vec<[f32; 3]> = y.iter().map(|v| v.map(|c| c as f32)).collect();
    let y64: Vec<[f64; 3]> = y32.iter().map(|v| v.map(f64::from)).collect();
    for method in Method::ALL {
        let cfg = Config { method, ..PLAIN };
        let a = calibrate::<f64, _>(&y64, &cfg).unwrap().calibration;
        let b = calibrate::<f32, _>(&y32, &cfg).unwrap().calibration;
        let dm =
            (b.shape_matrix().map(f64::from) - a.shape_matrix()).amax() / a.shape_matrix().amax();
        let db = (b.hard_iron_vector().map(f64::from) - a.hard_iron_vector()).norm()
            / a.field_strength();
        println!("{method:?} f32 vs f64: dM {dm:.1e} db {db:.1e}");
        assert!(dm < 1e-4 && db < 1e-4, "{method:?}: {dm:e} {db:e}");
    }
}
