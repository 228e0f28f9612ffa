//! Real recordings from other people's sensors (`../shared/data/real/`).
//! No truth is known: judge by the calibrated norm spread, by agreement with
//! the reference outputs shipped beside them, and by f32/f64 agreement.

use host_tests::real::read_xyz;
use host_tests::reference::{self, RefLs};
use mag_cal_core::{calibrate, Calibration, Config, LsVariant, Method, SampleClass};
use nalgebra::{Matrix3, Vector3};

/// std/mean of `|W (y - b)|` over the samples.
fn norm_spread(samples: &[[f64; 3]], cal: &Calibration<f64>) -> f64 {
    let norms: Vec<f64> = samples
        .iter()
        .map(|y| cal.apply_vector(*y).norm())
        .collect();
    let n = norms.len() as f64;
    let mean = norms.iter().sum::<f64>() / n;
    let var = norms.iter().map(|r| (r - mean).powi(2)).sum::<f64>() / n;
    var.sqrt() / mean
}

/// Fits with every LS variant, LS alone and ADC2; prints the spreads; checks
/// ADC2 against its own LS start (within 1% relative) and the f64 core
/// against the reference. Returns the default ADC2 calibration.
fn fit_all(name: &str) -> Calibration<f64> {
    let y = read_xyz(name);
    assert!(y.len() > 100, "{name}: {} rows", y.len());
    for (ls, rls) in [
        (LsVariant::Ls9, RefLs::Ls9),
        (LsVariant::Svd10, RefLs::Svd10),
        (LsVariant::LiGriffiths, RefLs::LiGriffiths),
    ] {
        // The plain estimators, which the reference implements.
        let cfg = |method| Config {
            method,
            ls,
            robust: false,
            ..Config::default()
        };
        let start = calibrate::<f64, _>(&y, &cfg(Method::Ls)).unwrap();
        let adc2 = calibrate::<f64, _>(&y, &cfg(Method::Adc2)).unwrap();
        let (s_ls, s_adc2) = (
            norm_spread(&y, &start.calibration),
            norm_spread(&y, &adc2.calibration),
        );
        println!(
            "{name} {}: spread LS {s_ls:.6} ADC2 {s_adc2:.6} (ratio {:.5}), {} iterations, radial RMS {:.5}",
            ls.name(),
            s_adc2 / s_ls,
            adc2.report.iterations,
            adc2.report.radial_rms
        );
        assert!((s_adc2 / s_ls - 1.0).abs() < 0.01, "{name} {ls:?}");
        let want = reference::adc2(&y, rls).unwrap();
        let c = adc2.calibration;
        assert!((c.shape_matrix() - want.m).amax() < 1e-9 * want.m.amax());
        assert!((c.hard_iron_vector() - want.b).norm() < 1e-9 * want.rho);
        // f32 on the same recording agrees with f64 (counts up to 1e4 here).
        let y32: Vec<[f32; 3]> = y.iter().map(|v| v.map(|x| x as f32)).collect();
        let c32 = calibrate::<f32, _>(&y32, &cfg(Method::Adc2))
            .unwrap()
            .calibration;
        let db = (c32.hard_iron_vector().map(f64::from) - c.hard_iron_vector()).norm()
            / c.field_strength();
        let dm =
            (c32.shape_matrix().map(f64::from) - c.shape_matrix()).amax() / c.shape_matrix().amax();
        assert!(db < 1e-4 && dm < 1e-4, "{name} {ls:?} f32: {db:e} {dm:e}");
    }
    robust_as_good(name, &y)
}

/// The default (robust) ADC2 fit against the plain one: it says what it
/// left out, its hard iron stays within 0.5 % of the field of the plain
/// fit's, and the calibrated norm of the rows it used spreads no more than
/// the plain fit's over all rows. Returns the robust calibration.
fn robust_as_good(name: &str, y: &[[f64; 3]]) -> Calibration<f64> {
    let plain = Config {
        robust: false,
        ..Config::default()
    };
    let p = calibrate::<f64, _>(y, &plain).unwrap();
    let r = calibrate::<f64, _>(y, &Config::default()).unwrap();
    let rep = r.report;
    let used: Vec<[f64; 3]> = rep
        .selection
        .classify(&r.calibration, y)
        .zip(y)
        .filter(|(c, _)| *c == SampleClass::Used)
        .map(|(_, v)| *v)
        .collect();
    assert_eq!(
        used.len(),
        rep.samples_used,
        "{name}: classify agrees with the report"
    );
    let (s_plain, s_robust) = (
        norm_spread(y, &p.calibration),
        norm_spread(&used, &r.calibration),
    );
    let db = (r.calibration.hard_iron_vector() - p.calibration.hard_iron_vector()).norm()
        / p.calibration.field_strength();
    println!(
        "{name} robust: used {} dropped {:?} screened {} rejected {} fit error {:.4} lack of fit {:.2} \
         robust passes {}; spread {s_robust:.6} (plain {s_plain:.6}), |db| {db:.2e} of the field",
        rep.samples_used,
        rep.drops,
        rep.screened,
        rep.rejected,
        rep.quality.fit_error,
        rep.quality.lack_of_fit,
        rep.robust_passes,
    );
    assert_eq!(
        rep.samples_used + rep.samples_dropped + rep.screened + rep.rejected,
        y.len()
    );
    assert!(
        s_robust <= s_plain * 1.0001,
        "{name}: {s_robust} > {s_plain}"
    );
    assert!(db < 0.005, "{name}: {db}");
    r.calibration
}

#[test]
fn icm20948_agrees_with_magneto() {
    let cal = fit_all("icm20948_mag_300.csv");
    // Magneto 1.4 on the same file (icm20948_mag_300.magneto14.lis): a
    // Li-Griffiths fit after rejecting 10 samples at 2 sigma.
    let magneto_b = Vector3::new(-156.70, -52.79, -141.07);
    let magneto_ainv: Matrix3<f64> = Matrix3::new(
        1.12823, -0.01142, 0.00980, -0.01142, 1.09539, 0.00927, 0.00980, 0.00927, 1.10625,
    );
    let b = cal.hard_iron_vector();
    let db = (b - magneto_b).norm();
    println!("icm20948: b = {b:.2?}, Magneto b = {magneto_b:.2?}, |db| = {db:.2} counts");
    // Observed 0.17 counts of a 370-count field; Magneto dropped 10 samples,
    // we keep them, so allow about ten times that: 0.5% of the field.
    assert!(db < 0.005 * cal.field_strength(), "|db| = {db}");
    // Magneto scales its Ainv to the mean norm Hm = 369.4; compare shapes
    // up to that scale: W / |W| against Ainv / |Ainv|.
    let w: Matrix3<f64> = cal.soft_iron_matrix();
    let dw = (w / w.norm() - magneto_ainv / magneto_ainv.norm()).amax();
    println!("icm20948: normalised soft-iron difference to Magneto {dw:.4}");
    assert!(dw < 0.005, "{dw}"); // observed 0.001
}

#[test]
fn mag3_large_offset() {
    let cal = fit_all("mag3_raw_541.csv");
    // That repository's own Python fit (mag3_raw_541.out.txt).
    let theirs = Vector3::new(9955.151669, -7948.26463057, 8511.80447932);
    let db = (cal.hard_iron_vector() - theirs).norm() / cal.field_strength();
    println!(
        "mag3: b = {:.1?}, theirs {theirs:.1?}, |db|/rho = {db:.4}",
        cal.hard_iron_vector()
    );
    assert!(db < 0.002, "{db}"); // observed 2e-4
}

/// What the on-device collector keeps of the long recording (capacity
/// 4000, the web page's): the recording starts with the board lying still
/// (the collector keeps one sample until it moves), then a level swing
/// repeated many times before the device tilts, so the kept samples crowd
/// on one side of the sphere. The robust fit agrees with the plain one and
/// with the whole recording's.
#[test]
fn the_collected_part_of_a_long_recording_calibrates() {
    use mag_cal_core::collector::{Collector, Offer};
    let y = read_xyz("magcal_25598.txt");
    let mut c: Collector<[f64; 3], 4000> = Collector::default();
    let restarts = y
        .iter()
        .filter(|s| c.offer(**s) == Offer::Restarted)
        .count();
    let p = c.progress();
    println!("collector on magcal_25598: {restarts} restart(s), {p:?}");
    assert!(restarts == 0 && p.ready && c.len() == 4000, "{p:?}");
    let kept = robust_as_good("magcal_25598 collected", c.samples());
    let all = calibrate::<f64, _>(&y, &Config::default())
        .unwrap()
        .calibration;
    let db = (kept.hard_iron_vector() - all.hard_iron_vector()).norm() / all.field_strength();
    println!("collected against the whole recording: |db| {db:.2e} of the field");
    assert!(db < 0.01, "{db}");
}
