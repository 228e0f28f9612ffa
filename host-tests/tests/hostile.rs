//! No input panics the core: arbitrary samples full of special values give
//! a calibration with finite parameters or an error, never a panic.

use mag_cal_core::{calibrate, Config, LsVariant, Method, Real};
use proptest::prelude::*;

fn special_f64() -> impl Strategy<Value = f64> {
    prop_oneof![
        4 => -1e3f64..1e3,
        1 => Just(f64::NAN),
        1 => Just(f64::INFINITY),
        1 => Just(f64::NEG_INFINITY),
        1 => Just(0.0),
        1 => Just(1e30),
        1 => Just(-1e38),
        1 => Just(1e300),
        1 => Just(5e-324),
        1 => Just(1e-40),
        1 => any::<f64>(),
    ]
}

/// Samples: mostly special values, or a real ellipsoid with a few special
/// values mixed in, optionally scaled and offset to extreme magnitudes.
fn samples() -> impl Strategy<Value = Vec<[f64; 3]>> {
    let garbage = prop::collection::vec([special_f64(), special_f64(), special_f64()], 0..60);
    let sphere = (
        20usize..120,
        -40.0f64..40.0,
        -30.0f64..300.0,
        prop::collection::vec(
            (0usize..120, [special_f64(), special_f64(), special_f64()]),
            0..4,
        ),
    )
        .prop_map(|(n, log_scale, offset, spikes)| {
            let k = 10f64.powf(log_scale);
            let mut y: Vec<[f64; 3]> = (0..n)
                .map(|i| {
                    let z = 1.0 - 2.0 * (i as f64 + 0.5) / n as f64;
                    let (r, phi) = ((1.0 - z * z).sqrt(), i as f64 * 2.4);
                    [
                        k * (offset + 1.2 * r * phi.cos()),
                        k * (offset + 0.8 * r * phi.sin()),
                        k * (offset + z),
                    ]
                })
                .collect();
            for (i, v) in spikes {
                let len = y.len();
                y[i % len] = v;
            }
            y
        });
    let duplicates =
        ([special_f64(), special_f64(), special_f64()], 0usize..40).prop_map(|(v, n)| vec![v; n]);
    prop_oneof![garbage, sphere, duplicates]
}

fn check<T: Real>(y: &[[f64; 3]]) -> Result<(), TestCaseError> {
    for method in Method::ALL {
        for ls in [LsVariant::Ls9, LsVariant::Svd10, LsVariant::LiGriffiths] {
            let cfg = Config {
                method,
                ls,
                ..Config::default()
            };
            if let Ok(fit) = calibrate::<T, _>(y, &cfg) {
                let c = fit.calibration;
                prop_assert!(c.hard_iron_vector().iter().all(|v| v.is_finite()));
                prop_assert!(c.soft_iron_matrix().iter().all(|v| v.is_finite()));
                prop_assert!(c.field_strength() > T::zero() && c.field_strength().is_finite());
                prop_assert_eq!(
                    fit.report.samples_used
                        + fit.report.samples_dropped
                        + fit.report.screened
                        + fit.report.rejected,
                    y.len()
                );
            }
        }
    }
    Ok(())
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(300))]

    #[test]
    fn never_panics_f64(y in samples()) {
        check::<f64>(&y)?;
    }

    #[test]
    fn never_panics_f32(y in samples()) {
        check::<f32>(&y)?;
    }
}
