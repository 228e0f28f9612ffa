//! Writes the planar-calibration section of `docs/results.md`: heading
//! errors of the planar fit of level turns with tilts, against the truth
//! and the three-dimensional fit of the same sensor, and the real nearly
//! planar recording.
//!
//! `cargo run --release -p host-tests --bin planar-table [-- --write docs/results.md]`

use std::process::ExitCode;

use host_tests::planar::{render, tilt_study};
use host_tests::real::read_xyz;
use mag_cal_core::planar::{calibrate_planar, PlanarConfig};

/// The section's name in `docs/results.md`.
const SECTION: &str = "planar";

fn main() -> ExitCode {
    let write = match host_tests::sections::write_target("planar-table") {
        Ok(write) => write,
        Err(usage) => return usage,
    };
    let seeds = 20;
    let rows = tilt_study(&[0.0, 2.0, 5.0, 10.0], seeds);
    let samples = read_xyz("planar_243.txt");
    let real = match calibrate_planar::<f64, _>(&samples, &PlanarConfig::with_up([0.0, 0.0, 1.0])) {
        Ok(fit) => {
            let r = fit.report;
            format!(
                "`planar_243.txt` (243 rows, `magcal planar FILE --up z`): {} used, {} dropped \
                 ({} repeated), {} screened, {} rejected by their radial residual; fit error {:.4} of \
                 the field in the plane, flatness {:.4}, thickness {:.4}, {} of 12 sectors; turn \
                 axis {:.1} deg from z; field in the plane {:.1} (the file's units, uT); {} passes. \
                 The three-dimensional fit refuses it as planar.",
                r.samples_used,
                r.drops.total(),
                r.drops.repeated,
                r.screened,
                r.rejected,
                r.fit_error,
                r.flatness,
                r.thickness,
                r.sectors,
                r.axis_tilt_deg,
                fit.calibration.plane_strength(),
                r.passes
            )
        }
        Err(e) => format!("`planar_243.txt`: refused: {e}"),
    };
    let doc = format!(
        "## Planar (heading-only) calibration\n\n\
         Written by `cargo run --release -p host-tests --bin planar-table -- --write docs/results.md` \
         (source: `host-tests/src/planar.rs`; design document section 17; asserted by \
         `host-tests/tests/planar.rs`). A level vehicle makes two turns at a varying rate (300 \
         readings, noise 1 % of the field per axis, inclination 60 deg, symmetric soft iron, field \
         400 counts) while roll and pitch wander within the tilt. The planar fit of those turns, \
         and the three-dimensional ADC2 fit of the same sensor on 400 full-sphere readings, are \
         applied to other, level turns (the error of the calibration) and to the tilted turns \
         themselves (the error in use, heading without tilt compensation). Heading errors are RMS \
         (largest) after removing one constant offset (heading 0 set once), medians over {seeds} \
         runs. The fits are measured past the default fit-error limit of 0.2; the last column \
         counts the runs that limit refuses.\n\n{}\n\
         Level, the planar fit is as accurate as a full calibration. Tilts while turning move the \
         vertical field into the plane: an uncompensated heading then errs by about \
         tilt x tan(inclination) for either fit, and the planar fit's own calibration is bent by \
         them too (its fit error rises with the tilt, and at 10 deg most runs are refused).\n\n{real}\n",
        render(&rows)
    );
    host_tests::sections::publish(&doc, SECTION, write.as_deref())
}
