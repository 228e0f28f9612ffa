//! The serialised calibration (feature `serde`).
#![cfg(feature = "serde")]

use mag_cal_core::{Calibration, Error};

#[test]
fn a_calibration_round_trips_through_json() {
    let w = [
        [0.02, 0.001, 0.0],
        [0.001, 0.025, -0.002],
        [0.0, -0.002, 0.018],
    ];
    let cal = Calibration::<f64>::new([120.0, -40.0, 15.0], w).unwrap();
    let text = serde_json::to_string(&cal).unwrap();
    let back: Calibration<f64> = serde_json::from_str(&text).unwrap();
    assert_eq!(back.hard_iron(), cal.hard_iron());
    for (a, b) in back
        .soft_iron()
        .iter()
        .flatten()
        .zip(cal.soft_iron().iter().flatten())
    {
        // W is canonicalised again on reading: equal to rounding.
        assert!((a - b).abs() <= 1e-15 * 0.025, "{a} vs {b}");
    }
    assert!((back.field_strength() / cal.field_strength() - 1.0).abs() < 1e-14);
}

#[test]
fn reading_validates_and_ignores_other_fields() {
    // A magcal-like object: other fields are ignored, the field strength
    // may be missing (it is recomputed).
    let text = r#"{"method":"adc2","hard_iron":[1.0,2.0,3.0],
        "soft_iron":[[0.5,0.0,0.0],[0.0,0.5,0.0],[0.0,0.0,0.5]],"samples_used":300}"#;
    let cal: Calibration<f32> = serde_json::from_str(text).unwrap();
    assert!((cal.field_strength() - 2.0).abs() < 1e-6);
    // A singular W is not a calibration.
    let singular = r#"{"hard_iron":[0,0,0],"soft_iron":[[1,0,0],[0,1,0],[0,0,0]]}"#;
    let err = serde_json::from_str::<Calibration<f64>>(singular).unwrap_err();
    assert!(
        err.to_string().contains(&Error::SingularSystem.to_string()),
        "{err}"
    );
    // Nor is a row missing.
    assert!(serde_json::from_str::<Calibration<f64>>(r#"{"hard_iron":[0,0,0]}"#).is_err());
}
