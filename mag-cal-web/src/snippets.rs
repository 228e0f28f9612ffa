//! Copyable code for a fitted calibration: C over `mag_cal.h` (the
//! library's C API) and Rust over `mag-cal-core`. A planar calibration has
//! Rust only: the C API has no planar calibration.

use std::fmt::Write as _;

use mag_cal_cli::fit::Outcome;
use mag_cal_core::planar::PlanarCalibration;

/// A C definition of the calibration for `magcal_apply`, full `double`
/// precision (shortest round-trip form).
pub fn c(o: &Outcome) -> String {
    let [b0, b1, b2] = o.hard_iron;
    let mut s = String::new();
    let _ = writeln!(
        s,
        "/* magcal {} fit: W (raw - b) lies on the unit sphere; field strength {:?} sensor units. */",
        o.method, o.field_strength
    );
    let _ = writeln!(s, "#include \"mag_cal.h\"\n");
    let _ = writeln!(s, "static const MagcalCalibration mag_calibration = {{");
    let _ = writeln!(s, "    .hard_iron = {{ {b0:?}, {b1:?}, {b2:?} }},");
    let _ = writeln!(s, "    .soft_iron = {{");
    for [a, b, c] in o.soft_iron {
        let _ = writeln!(s, "        {{ {a:?}, {b:?}, {c:?} }},");
    }
    let _ = writeln!(s, "    }},");
    let _ = writeln!(s, "    .field_strength = {:?},", o.field_strength);
    let _ = writeln!(s, "}};\n");
    let _ = writeln!(
        s,
        "/* float raw[3] = {{ x, y, z }}, out[3];\n   magcal_apply(&mag_calibration, raw, out);  out: unit vector */"
    );
    s
}

/// A Rust function building the calibration with `mag-cal-core`, in `f32`
/// (the values rounded to the nearest `f32`).
pub fn rust(o: &Outcome) -> String {
    let f = |v: f64| format!("{:?}", v as f32);
    let mut s = String::new();
    let _ = writeln!(
        s,
        "// magcal {} fit: W (raw - b) lies on the unit sphere; field strength {} sensor units.",
        o.method,
        f(o.field_strength)
    );
    let _ = writeln!(s, "use mag_cal_core::{{Calibration, Error}};\n");
    let _ = writeln!(
        s,
        "pub fn calibration() -> Result<Calibration<f32>, Error> {{"
    );
    let _ = writeln!(s, "    Calibration::new(");
    let [b0, b1, b2] = o.hard_iron.map(f);
    let _ = writeln!(s, "        [{b0}, {b1}, {b2}],");
    let _ = writeln!(s, "        [");
    for row in o.soft_iron {
        let [a, b, c] = row.map(f);
        let _ = writeln!(s, "            [{a}, {b}, {c}],");
    }
    let _ = writeln!(s, "        ],");
    let _ = writeln!(s, "    )");
    let _ = writeln!(s, "}}\n");
    let _ = writeln!(
        s,
        "// let unit = calibration()?.apply(raw); // raw: [i16; 3], [f32; 3], ..."
    );
    s
}

/// A Rust function building a planar (heading-only) calibration with
/// `mag-cal-core`, in `f32` (the values rounded to the nearest `f32`).
pub fn rust_planar(cal: &PlanarCalibration<f64>) -> String {
    let f = |v: f64| format!("{:?}", v as f32);
    let v3 = |v: [f64; 3]| v.map(f).join(", ");
    let mut s = String::new();
    let _ = writeln!(
        s,
        "// magcal planar fit: u = K (raw - centre) is a unit 2-vector, heading = angle(u) - zero;\n\
         // field in the plane {} sensor units. Valid for turns about the axis only.",
        f(cal.plane_strength())
    );
    let _ = writeln!(s, "use mag_cal_core::planar::PlanarCalibration;");
    let _ = writeln!(s, "use mag_cal_core::Error;\n");
    let _ = writeln!(
        s,
        "pub fn calibration() -> Result<PlanarCalibration<f32>, Error> {{"
    );
    let _ = writeln!(s, "    PlanarCalibration::new(");
    let _ = writeln!(s, "        [{}], // turn axis", v3(cal.axis()));
    let _ = writeln!(s, "        [{}], // centre", v3(cal.centre()));
    let [k0, k1] = cal.matrix();
    let _ = writeln!(s, "        [[{}], [{}]], // K", v3(k0), v3(k1));
    let _ = writeln!(s, "        {}, // zero, degrees", f(cal.zero_deg()));
    let _ = writeln!(s, "    )");
    let _ = writeln!(s, "}}\n");
    let _ = writeln!(
        s,
        "// let heading = calibration()?.heading_deg(raw); // degrees; raw: [i16; 3], [f32; 3], ..."
    );
    s
}
