//! Parity: the core (moments, small solves) against the independent
//! float64 reference (explicit design matrix, SVD/QR, closed-form ADC2).

use host_tests::reference::{self, RefFit, RefLs};
use host_tests::sim::{make_samples_axes, scenario_t, sphere, Rng};
use mag_cal_core::{calibrate, Config, LsVariant, Method, Real, Sample};
use nalgebra::{Matrix3, Vector3};

/// The plain estimators, which the reference implements: outlier handling
/// off (the robust pipeline has its own tests, `tests/robust.rs`).
const PLAIN: Config = Config {
    robust: false,
    ..Config::DEFAULT
};

const VARIANTS: [(LsVariant, RefLs); 3] = [
    (LsVariant::Ls9, RefLs::Ls9),
    (LsVariant::Svd10, RefLs::Svd10),
    (LsVariant::LiGriffiths, RefLs::LiGriffiths),
];

/// Gauge-free differences: max|dM| / max|M| and |db| / rho.
fn deviation<T: Real>(core: &mag_cal_core::Fit<T>, reference: &RefFit) -> (f64, f64) {
    let m = core.calibration.shape_matrix().map(T::to_f64);
    let b = core.calibration.hard_iron_vector().map(T::to_f64);
    (
        (m - reference.m).amax() / reference.m.amax(),
        (b - reference.b).norm() / reference.rho,
    )
}

fn check<T: Real, S: Sample>(label: &str, samples: &[S], reference_input: &[[f64; 3]], tol: f64) {
    for (core_ls, ref_ls) in VARIANTS {
        let ls_ref = reference::ls_fit(reference_input, ref_ls).expect("reference LS");
        let adc2_ref =
            reference::adc2_closed_form(reference_input, &ls_ref).expect("reference ADC2");
        for (method, want) in [(Method::Ls, &ls_ref), (Method::Adc2, &adc2_ref)] {
            let cfg = Config {
                method,
                ls: core_ls,
                ..PLAIN
            };
            let fit = calibrate::<T, S>(samples, &cfg).expect("core fit");
            let (dm, db) = deviation(&fit, want);
            let rho = fit.calibration.field_strength().to_f64();
            let drho = (rho - want.rho).abs() / want.rho;
            println!("{label} {core_ls:?} {method:?}: dM {dm:.1e} db/rho {db:.1e} drho {drho:.1e}");
            assert!(
                dm < tol && db < tol && drho < tol,
                "{label} {core_ls:?} {method:?}: {dm:e} {db:e} {drho:e}"
            );
        }
    }
}

use host_tests::sim::scenario_samples as scenario;

#[test]
fn f64_matches_reference_to_1e_9() {
    for (label, noise, banded) in [
        ("A", [0.01, 0.02, 0.03], false),
        ("B", [0.05, 0.075, 0.10], false),
        ("D", [0.05, 0.075, 0.10], true),
        ("E", [0.10, 0.15, 0.20], false),
    ] {
        let y = scenario(noise, banded, 7);
        check::<f64, _>(label, &y, &y, 1e-9);
    }
}

/// Counts with a 25000-count offset and a 2000-count radius: without
/// centring, f32 fails here; with it, f32 agrees with the f64 reference.
fn offset_counts(seed: u64) -> Vec<[f64; 3]> {
    let mut rng = Rng(seed);
    let t = scenario_t() * 2000.0;
    let b = Vector3::new(25000.0, -24000.0, 26000.0);
    let dirs = sphere(1000, &mut rng);
    make_samples_axes(&t, &b, &dirs, [20.0, 30.0, 40.0], &mut rng)
        .into_iter()
        .map(|v| v.map(f64::round))
        .collect()
}

#[test]
fn f32_matches_reference_to_1e_4() {
    let y = offset_counts(11);
    // The core reads the same integer counts as i16 (firmware storage), f32.
    let y_i32: Vec<[i32; 3]> = y.iter().map(|v| v.map(|c| c as i32)).collect();
    check::<f32, _>("offset 25000 (i32 counts)", &y_i32, &y, 1e-4);
    let y_f32: Vec<[f32; 3]> = y.iter().map(|v| v.map(|c| c as f32)).collect();
    check::<f32, _>("offset 25000 (f32)", &y_f32, &y, 1e-4);
    for (label, noise, banded) in [
        ("B", [0.05, 0.075, 0.10], false),
        ("D", [0.05, 0.075, 0.10], true),
    ] {
        let y = scenario(noise, banded, 3);
        // Round the inputs to f32 first, so both sides see the same data.
        let y32: Vec<[f32; 3]> = y.iter().map(|v| v.map(|c| c as f32)).collect();
        let y64: Vec<[f64; 3]> = y32.iter().map(|v| v.map(f64::from)).collect();
        check::<f32, _>(label, &y32, &y64, 1e-4);
    }
}

#[test]
fn i16_storage_matches_f64_input() {
    // Magnetometer counts stored as i16 give the same fit as the same
    // counts given as f64.
    let mut rng = Rng(5);
    let t = scenario_t() * 900.0;
    let dirs = sphere(600, &mut rng);
    let y = make_samples_axes(
        &t,
        &Vector3::new(-3000.0, 1200.0, 800.0),
        &dirs,
        [5.0; 3],
        &mut rng,
    );
    let y16: Vec<[i16; 3]> = y.iter().map(|v| v.map(|c| c.round() as i16)).collect();
    let y64: Vec<[f64; 3]> = y16.iter().map(|v| v.map(f64::from)).collect();
    let reference = reference::adc2(&y64, RefLs::Ls9).unwrap();
    let fit = calibrate::<f64, _>(&y16, &Config::default()).unwrap();
    let (dm, db) = deviation(&fit, &reference);
    assert!(dm < 1e-9 && db < 1e-9, "{dm} {db}");
}

/// The core's solve on the sufficient statistics (normal equations, 4x4
/// Cholesky) against the minimiser computed by the reference from explicit
/// artificial vectors (SVD least squares), starting from the same LS fit.
/// No solver iterates: the report counts none.
#[test]
fn the_statistics_solve_reaches_the_closed_form() {
    for (seed, banded) in [(1, false), (2, true), (3, false)] {
        let y = scenario([0.05, 0.075, 0.1], banded, seed);
        let ls = reference::ls_fit(&y, RefLs::Ls9).unwrap();
        let closed = reference::adc2_closed_form(&y, &ls).unwrap();
        let fit = calibrate::<f64, _>(&y, &Config::default()).unwrap();
        let (dm, db) = deviation(&fit, &closed);
        println!(
            "seed {seed} band {banded}: dM {dm:.1e} db {db:.1e}, {} iterations",
            fit.report.iterations
        );
        // 1e-15 to 3e-15 here (BFGS stopped at its 1e-6 step test was
        // held to 1e-6).
        assert!(dm < 1e-12 && db < 1e-12);
        assert_eq!(fit.report.iterations, 0);
        // ADC2 moves the estimate away from the LS start (it is not a no-op).
        let m_ls: Matrix3<f64> = ls.m;
        assert!((fit.calibration.shape_matrix() - m_ls).amax() / m_ls.amax() > 1e-4);
    }
}
