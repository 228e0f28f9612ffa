//! Properties of the page's entry points on any input: no panic (a panic
//! in the page is a trap that leaves the core unusable), one well-formed
//! JSON document per call, counts that add up, and a packet that checks.

use mag_cal_web::{fit_json, packet, Live};
use proptest::prelude::*;
use serde_json::Value;

/// Lines a logger or a serial port may give: numbers (some huge, zero or
/// non-finite), `Raw:` lines whole or cut short, headers, noise.
fn line() -> impl Strategy<Value = String> {
    let number = prop_oneof![
        (-2000i32..2000).prop_map(|v| v.to_string()),
        any::<f64>().prop_map(|v| v.to_string()),
        Just("nan".to_owned()),
        Just("0".to_owned()),
        Just("32767".to_owned()),
        Just("1e308".to_owned()),
    ];
    prop_oneof![
        prop::collection::vec(number.clone(), 0..12).prop_map(|f| f.join(",")),
        prop::collection::vec(number, 0..11).prop_map(|f| format!("Raw:{}", f.join(","))),
        Just("magx,magy,magz".to_owned()),
        Just("Uni:0.1,0.2".to_owned()),
        "[ -~]{0,40}",
    ]
}

/// A sphere's worth of `Raw:` lines about an offset, with the cases'
/// corruption mixed in: enough to reach a fit. In the order of a board
/// turned steadily from pole to pole (the collector learns the sensor's
/// noise from consecutive readings).
fn sphere_lines(n: usize, offset: [f64; 3]) -> Vec<String> {
    let mut phi = 0.0f64;
    (0..n)
        .map(|i| {
            let z = 1.0 - 2.0 * (i as f64 + 0.5) / n as f64;
            let r = (1.0 - z * z).sqrt();
            phi += 3.6 / (n as f64).sqrt() / r;
            let m = [r * phi.cos(), r * phi.sin(), z];
            format!(
                "Raw:0,0,0,0,0,0,{:.0},{:.0},{:.0}",
                offset[0] + 450.0 * m[0],
                offset[1] + 420.0 * m[1],
                offset[2] + 470.0 * m[2]
            )
        })
        .collect()
}

fn check_fit_doc(code: u32, text: &str) -> Value {
    let doc: Value = serde_json::from_str(text).expect("one JSON document");
    let status = doc["status"].as_str().expect("a status");
    assert_eq!(doc["code"].as_u64(), Some(u64::from(code)), "{text}");
    match status {
        "ok" => {
            assert_eq!(code, 0);
            let rows = doc["rows"].as_u64().unwrap() as usize;
            for key in ["raw", "calibrated", "norms", "classes"] {
                assert_eq!(doc[key].as_array().map(Vec::len), Some(rows), "{key}");
            }
            let bytes: Vec<u8> = doc["packet"]
                .as_array()
                .unwrap()
                .iter()
                .map(|b| b.as_u64().unwrap() as u8)
                .collect();
            assert_eq!(bytes.len(), packet::LEN);
            assert_eq!(packet::crc16(&bytes), 0);
            let fit: Value = serde_json::from_str(doc["json"].as_str().unwrap()).unwrap();
            assert_eq!(fit, doc["fit"]);
        }
        "refused" => assert_eq!(code, 3),
        "error" => assert_eq!(code, 2),
        other => panic!("status {other}"),
    }
    if status != "ok" {
        assert!(!doc["message"].as_str().unwrap().is_empty());
    }
    doc
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(200))]

    #[test]
    fn any_bytes_give_one_document(bytes in prop::collection::vec(any::<u8>(), 0..400),
                                   precision in prop_oneof![Just("f32"), Just("f64"), Just("f16")],
                                   plain in any::<bool>()) {
        let options = format!(r#"{{"precision":"{precision}","plain":{plain}}}"#);
        let (code, text) = fit_json(&bytes, options.as_bytes(), &|| 0.0);
        check_fit_doc(code, &text);
    }

    #[test]
    fn any_lines_give_one_document(lines in prop::collection::vec(line(), 0..60)) {
        let text = lines.join("\n");
        let (code, doc) = fit_json(text.as_bytes(), b"", &|| 0.0);
        check_fit_doc(code, &doc);
    }

    #[test]
    // The bad lines anywhere, also among the collector's first samples
    // (where a wild one makes the core's collector start over).
    fn a_corrupted_stream_adds_up_and_fits(noise in prop::collection::vec((0usize..600, line()), 0..40),
                                           offset in prop::array::uniform3(-3000.0f64..3000.0)) {
        let mut lines = sphere_lines(600, offset);
        for (at, line) in noise {
            lines.insert(at.min(lines.len()), line);
        }
        let mut live = Live::default();
        let mut raw_lines = 0u64;
        for line in &lines {
            let doc: Value = serde_json::from_str(&live.line(line.as_bytes())).unwrap();
            if line.trim().starts_with("Raw:") {
                raw_lines += 1;
                prop_assert_eq!(doc["kind"].as_str(), Some("raw"));
            } else {
                prop_assert_eq!(doc["kind"].as_str(), Some("skipped"));
            }
        }
        let p = live.progress_json();
        prop_assert_eq!(p["lines"].as_u64(), Some(raw_lines));
        let refused: u64 = p["refused"].as_object().unwrap().values().filter_map(Value::as_u64).sum();
        let held = p["samples"].as_u64().unwrap() + p["discarded"].as_u64().unwrap();
        prop_assert_eq!(refused + held, raw_lines);
        let (code, text) = live.fit(b"", &|| 0.0);
        let doc = check_fit_doc(code, &text);
        // A sphere of 600 readings with at most 40 bad lines among them is
        // a calibration, however bad the lines.
        prop_assert_eq!(doc["status"].as_str(), Some("ok"), "{}", doc["message"]);
    }
}

/// The page's live collector is the core's: a board lying still (a fixed
/// reading plus 2 counts of noise, 30 000 `Raw:` lines) keeps one sample,
/// never gets ready, and its progress stays at 1 %; once it turns, the
/// collection completes and fits.
#[test]
fn a_board_lying_still_never_gets_ready() {
    let mut live = Live::default();
    let turn = sphere_lines(600, [150.0, -60.0, 300.0]);
    let first: Vec<f64> = turn[0]
        .trim_start_matches("Raw:")
        .split(',')
        .skip(6)
        .map(|v| v.parse().unwrap())
        .collect();
    let mut seed = 0x5eed_u64;
    let mut noise = || {
        // Sum of four uniforms in [-1.5, 1.5): about 1.7 counts.
        (0..4)
            .map(|_| {
                seed = seed.wrapping_mul(6_364_136_223_846_793_005).wrapping_add(1);
                (seed >> 11) as f64 / (1u64 << 53) as f64 * 3.0 - 1.5
            })
            .sum::<f64>()
    };
    for _ in 0..30_000 {
        let line = format!(
            "Raw:0,0,0,0,0,0,{:.0},{:.0},{:.0}",
            first[0] + noise(),
            first[1] + noise(),
            first[2] + noise()
        );
        let doc: Value = serde_json::from_str(&live.line(line.as_bytes())).unwrap();
        assert_eq!(doc["progress"]["ready"], false);
    }
    let p = live.progress_json();
    assert_eq!(p["samples"], 1, "{p}");
    assert!(p["percent"].as_u64() <= Some(1), "{p}");
    for line in &turn {
        let _ = live.line(line.as_bytes());
    }
    let p = live.progress_json();
    assert_eq!(p["ready"], true, "{p}");
    assert_eq!(p["refused"]["restarted"], 0, "{p}");
    let (code, text) = live.fit(b"", &|| 0.0);
    assert_eq!(code, 0, "{text}");
}
