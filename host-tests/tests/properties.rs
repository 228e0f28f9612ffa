//! proptest properties of the core: exact recovery on noise-free data, and
//! the invariances every calibration must have, for every method (LS with
//! each variant; ADC1, ADC2, iterated ADC2 and subMLE from LS9).

use host_tests::sim::{make_samples_axes, sphere, Rng};
use mag_cal_core::{calibrate, Calibration, Config, Error, Fit, LsVariant, Method, Thresholds};
use nalgebra::{Matrix3, Rotation3, Vector3};
use proptest::prelude::*;

/// A random distortion `T = U diag(s) V^T`, singular values in 0.5..2.
fn distortion() -> impl Strategy<Value = Matrix3<f64>> {
    (
        rotation(),
        rotation(),
        [0.5f64..2.0, 0.5f64..2.0, 0.5f64..2.0],
    )
        .prop_map(|(u, v, s)| u * Matrix3::from_diagonal(&Vector3::from(s)) * v.transpose())
}

fn rotation() -> impl Strategy<Value = Matrix3<f64>> {
    [-1.0f64..1.0, -1.0f64..1.0, -1.0f64..1.0].prop_map(|a| {
        Rotation3::from_scaled_axis(Vector3::from(a) * std::f64::consts::PI).into_inner()
    })
}

fn unit_vector() -> impl Strategy<Value = Vector3<f64>> {
    [-1.0f64..1.0, -1.0f64..1.0, -1.0f64..1.0]
        .prop_filter("not too short", |v| Vector3::from(*v).norm() > 0.1)
        .prop_map(|v| Vector3::from(v).normalize())
}

/// Units 1e-3..1e4 (log-uniform).
fn unit_scale() -> impl Strategy<Value = f64> {
    (-3.0f64..4.0).prop_map(|e| 10f64.powf(e))
}

fn config(method: Method, ls: LsVariant) -> Config {
    Config {
        method,
        ls,
        ..Config::default()
    }
}

/// `lambda_min / lambda_max` of the samples' covariance (the planar rule's
/// figure), computed independently of the core.
fn sample_flatness(y: &[[f64; 3]]) -> f64 {
    let n = y.len() as f64;
    let mean = y
        .iter()
        .fold(Vector3::zeros(), |a, r| a + Vector3::from(*r))
        / n;
    let cov = y.iter().fold(Matrix3::zeros(), |a, r| {
        let d = Vector3::from(*r) - mean;
        a + d * d.transpose()
    }) / n;
    let e = cov.symmetric_eigenvalues();
    e.min() / e.max()
}

/// Every method: LS alone with each variant, the re-estimating methods from
/// the default LS9 start.
const ALL: [(Method, LsVariant); 7] = [
    (Method::Adc2, LsVariant::Ls9),
    (Method::Ls, LsVariant::Ls9),
    (Method::Ls, LsVariant::Svd10),
    (Method::Ls, LsVariant::LiGriffiths),
    (Method::Adc1, LsVariant::Ls9),
    (Method::SubMle, LsVariant::Ls9),
    (Method::Adc2Iterated, LsVariant::Ls9),
];

/// The plain estimators are invariant to rounding. With outlier handling
/// the 0/1 weights are a hard cut: a row at the cut may change sides when
/// rounding moves the robust sigma by an ulp, and the fit then moves by
/// that row's influence, a few `sigma / n` (seen: 1.7e-3 in M for one row
/// of 300 at noise 0.03 with a 4:1 distortion, in 1 of 3000 cases; 1e-6 to
/// 3e-5 in 10 more).
const MODES: [(bool, f64); 2] = [(false, 1e-10), (true, 1e-2)];

/// Li and Griffiths' constraint `4J - I^2 > 0` holds for `M`: only then can
/// that variant represent the ellipsoid at all.
fn li_griffiths_representable(m: &Matrix3<f64>) -> bool {
    let i = m.trace();
    let j = m[(0, 0)] * m[(1, 1)] + m[(1, 1)] * m[(2, 2)] + m[(0, 0)] * m[(2, 2)]
        - m[(0, 1)].powi(2)
        - m[(0, 2)].powi(2)
        - m[(1, 2)].powi(2);
    4.0 * j - i * i > 0.0
}

/// The calibrations of a pair of inputs.
type Pair = (Calibration<f64>, Calibration<f64>);

/// The two fits of a transformed pair: both refused for the same reason
/// (`None`), or both calibrated. Li and Griffiths' fit of an ellipsoid it
/// cannot represent is wrong, and the fit error refuses it: in both frames.
fn pair(
    label: &str,
    t: &Matrix3<f64>,
    a: Result<Fit<f64>, Error>,
    c: Result<Fit<f64>, Error>,
) -> Result<Option<Pair>, TestCaseError> {
    match (a, c) {
        (Ok(a), Ok(c)) => Ok(Some((a.calibration, c.calibration))),
        (Err(a), Err(c)) if core::mem::discriminant(&a) == core::mem::discriminant(&c) => {
            // `distortion()` draws axis ratios up to 4, a condition of `M`
            // up to 16: the refusal limit (`Thresholds::refuse_distortion`). With noise
            // an estimate of a true condition near it may pass it, and then
            // it does in both frames: the same answer, which is what these
            // tests ask. (`noise_free_recovery` asserts that no draw is
            // refused but by the planar rule on samples that are that flat.)
            let sv = t.singular_values();
            let condition = (sv.max() / sv.min()).powi(2);
            let near_limit = condition > 0.75 * f64::from(Thresholds::DEFAULT.refuse_distortion);
            prop_assert!(
                label.contains("LiGriffiths")
                    || (matches!(a, Error::ExtremeDistortion { .. }) && near_limit),
                "{label}: both refused: {a:?} (true condition of M {condition})"
            );
            Ok(None)
        }
        (a, c) => Err(TestCaseError::fail(format!(
            "{label}: {:?} vs {:?}",
            a.map(|f| f.report.quality),
            c.map(|f| f.report.quality)
        ))),
    }
}

fn m_err(fit: &Fit<f64>, m: &Matrix3<f64>) -> f64 {
    (fit.calibration.shape_matrix() - m).amax() / m.amax()
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(256))]

    /// Noise-free samples: M = (T T^T)^-1 and b are recovered within 1e-6.
    #[test]
    fn noise_free_recovery(
        t in distortion(),
        dir in unit_vector(),
        offset in 0.0f64..3.0,
        unit in unit_scale(),
        n in 30usize..400,
        seed in any::<u64>(),
    ) {
        let t = t * unit;
        let rho = t.determinant().abs().cbrt();
        let b = dir * offset * rho;
        let mut rng = Rng(seed);
        let y = make_samples_axes(&t, &b, &sphere(n, &mut rng), [0.0; 3], &mut rng);
        let m = (t * t.transpose()).try_inverse().unwrap();
        for (method, ls) in ALL {
            let fit = calibrate::<f64, _>(&y, &config(method, ls));
            if ls == LsVariant::LiGriffiths && !li_griffiths_representable(&m) {
                // Out of that estimator's reach: any answer, but no panic.
                continue;
            }
            let fit = match fit {
                // Few samples of an elongated ellipsoid can be flatter than
                // the planar rule allows (measured here on the samples,
                // with nalgebra's eigen decomposition): the refusal is then
                // the rule's.
                Err(Error::Planar { .. }) if sample_flatness(&y) < f64::from(Thresholds::DEFAULT.refuse_flatness) => continue,
                f => f.unwrap(),
            };
            let eb = (fit.calibration.hard_iron_vector() - b).norm() / rho;
            prop_assert!(m_err(&fit, &m) < 1e-6, "{method:?} {ls:?}: eM {}", m_err(&fit, &m));
            prop_assert!(eb < 1e-6, "{method:?} {ls:?}: eb {eb}");
            prop_assert!((fit.calibration.field_strength() - rho).abs() < 1e-6 * rho);
        }
    }

    /// Permuting the samples changes nothing (beyond summation rounding),
    /// but where the robust path started from a window of the recording
    /// (`Report::start`, a result in doubt): the windows are stretches of
    /// the samples' order by design (a disturbance lasts a stretch of the
    /// recording), so another order may score another window best. Seen:
    /// LS alone on 300 rows of a 4:1 ellipsoid at 3 % noise, in doubt in
    /// both orders (lack of fit 0.0045 and 0.0041), one of which took a
    /// window that scored 5 % better than the crude start: 1.7e-2 in M.
    /// (Requiring a window to score 5 % better than the crude start left
    /// 13 of 18 688 runs of the contamination study silently wrong
    /// against 12.)
    #[test]
    fn permutation_invariance(t in distortion(), seed in any::<u64>(), shift in 0usize..1000) {
        let mut rng = Rng(seed);
        let y = make_samples_axes(&t, &Vector3::new(0.4, -0.1, 0.2), &sphere(300, &mut rng), [0.03; 3], &mut rng);
        let mut p = y.clone();
        p.rotate_left(shift % y.len());
        p.reverse();
        for ((method, ls), (robust, tol)) in ALL.into_iter().flat_map(|m| MODES.map(|r| (m, r))) {
            let label = format!("{method:?} {ls:?} robust {robust}");
            let cfg = Config { robust, ..config(method, ls) };
            let (fy, fp) = (calibrate(&y, &cfg), calibrate(&p, &cfg));
            let window = |f: &Result<Fit<f64>, Error>| f.as_ref().is_ok_and(|f| f.report.start != 0);
            if window(&fy) || window(&fp) {
                continue;
            }
            let Some((a, c)) = pair(&label, &t, fy, fp)? else { continue };
            let dm = (a.shape_matrix() - c.shape_matrix()).amax() / a.shape_matrix().amax();
            prop_assert!(dm < tol, "{label}: {dm:e}");
            prop_assert!((a.hard_iron_vector() - c.hard_iron_vector()).norm() < tol * a.field_strength());
        }
    }

    /// Rotating the data, y -> Q y, maps b -> Q b and M -> Q M Q^T.
    /// Not for `Svd10`: its constraint `|v| = 1` counts the off-diagonal
    /// coefficients of the quadric once, so it is not `|A|_F` and not
    /// rotation invariant; on noisy data it moves with the frame (by about
    /// 1e-3 relative here, and ADC2 from it by as much).
    ///
    /// The estimators are equivariant, but two solvers' paths are not:
    /// subMLE's BFGS works on an upper-triangular `A` and iterated ADC2's
    /// Anderson mixing on the packed upper entries of `W`, and neither
    /// packing is rotation invariant. So the two fits of a rotated pair stop
    /// at different points within their stop tests. Iterated ADC2 is run to
    /// a tight pass tolerance (1e-11), where its fixed point is seen to be
    /// equivariant to 1e-9. subMLE's stop (a step below 1e-6) is fixed; its
    /// fits differ by up to about 1e-5 (8e-6 in 300 random cases), so it is
    /// held to 1e-4: a real frame dependence, like Svd10's, is ten times
    /// larger at this noise and would still fail.
    #[test]
    fn rotation_equivariance(t in distortion(), q in rotation(), seed in any::<u64>()) {
        let mut rng = Rng(seed);
        let y = make_samples_axes(&t, &Vector3::new(0.4, -0.1, 0.2), &sphere(300, &mut rng), [0.03; 3], &mut rng);
        let qy: Vec<[f64; 3]> = y.iter().map(|v| (q * Vector3::from(*v)).into()).collect();
        for (method, ls) in ALL.into_iter().filter(|(_, ls)| *ls != LsVariant::Svd10) {
            // Plain estimators: the robust path's coordinate-wise median
            // centre (screening, crude start) depends on the frame.
            let cfg = Config {
                pass_tolerance: Some(1e-11),
                max_passes: 200,
                robust: false,
                ..config(method, ls)
            };
            let tol = if method == Method::SubMle { 1e-4 } else { 1e-9 };
            let label = format!("{method:?} {ls:?}");
            let Some((a, c)) = pair(&label, &t, calibrate(&y, &cfg), calibrate(&qy, &cfg))? else { continue };
            let want_m = q * a.shape_matrix() * q.transpose();
            prop_assert!((c.shape_matrix() - want_m).amax() < tol * want_m.amax(), "{method:?} {ls:?}");
            prop_assert!((c.hard_iron_vector() - q * a.hard_iron_vector()).norm() < tol * a.field_strength());
            prop_assert!((c.field_strength() - a.field_strength()).abs() < tol * a.field_strength());
        }
    }

    /// Changing the unit, y -> k y, scales b and rho by k (and M by 1/k^2).
    #[test]
    fn unit_scaling(t in distortion(), k in unit_scale(), seed in any::<u64>()) {
        let mut rng = Rng(seed);
        let y = make_samples_axes(&t, &Vector3::new(0.4, -0.1, 0.2), &sphere(300, &mut rng), [0.03; 3], &mut rng);
        let ky: Vec<[f64; 3]> = y.iter().map(|v| v.map(|c| c * k)).collect();
        for ((method, ls), (robust, tol)) in ALL.into_iter().flat_map(|m| MODES.map(|r| (m, r))) {
            let label = format!("{method:?} {ls:?} robust {robust}");
            let cfg = Config { robust, ..config(method, ls) };
            let Some((a, c)) = pair(&label, &t, calibrate(&y, &cfg), calibrate(&ky, &cfg))? else { continue };
            let tol = tol * 10.0;
            let db = (c.hard_iron_vector() - a.hard_iron_vector() * k).norm() / (k * a.field_strength());
            prop_assert!(db < tol, "{label}: {db:e}");
            prop_assert!((c.field_strength() - a.field_strength() * k).abs() < tol * k * a.field_strength());
            prop_assert!((c.shape_matrix() * (k * k) - a.shape_matrix()).amax() < tol * a.shape_matrix().amax());
        }
    }
}
