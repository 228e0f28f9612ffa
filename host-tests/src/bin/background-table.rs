//! Writes the background-calibration section of `docs/results.md`: the
//! background calibrator on simulated ordinary use, a hard-iron jump, a
//! slow drift and a magnet passing (`host_tests::background`).
//!
//! `cargo run --release -p host-tests --bin background-table [-- --write docs/results.md]`

use std::process::ExitCode;

use host_tests::background::{render, study, CHANGE_AT, MAGNET_READINGS, READINGS};

/// The section's name in `docs/results.md`.
const SECTION: &str = "background";

fn main() -> ExitCode {
    let write = match host_tests::sections::write_target("background-table") {
        Ok(write) => write,
        Err(usage) => return usage,
    };
    let seeds = 20;
    let table = render(&study(seeds));
    let doc = format!(
        "## Background calibration\n\n\
         Written by `cargo run --release -p host-tests --bin background-table -- --write docs/results.md` \
         (source: `host-tests/src/background.rs`; design document section 15; asserted by \
         `host-tests/tests/background.rs`). `Background<f32, [i16; 3], 288, 6>` with the default \
         configuration takes {READINGS} readings of ordinary use, one `push` and one `step` a \
         reading: the heading walks and turns, roll and pitch wander about level (12 deg), and \
         about every 600 readings the device is tilted by 30-80 deg for a few hundred readings; \
         never a full tumble. Sensor: soft iron with a mounting rotation, field 450 counts, noise \
         1 % of the field per axis, integer counts. At reading {CHANGE_AT} the hard iron jumps by \
         0.16 of the field, or starts drifting by as much over the second half, or a magnet passes \
         ({MAGNET_READINGS} readings displaced by up to half the field, rising and falling). \
         {seeds} runs each; errors are gauge-free (`e_M` of `W^T W`, `e_b` over the field), \
         medians unless marked.\n\n{table}\n\
         - *first calibration*: the reading at which the first refit passed every check;\n\
         - *batch ADC2 on the buffer*: `calibrate` (robust ADC2, `f32`) on the calibrator's 288 \
         buffered samples at the end, against the same truth (`inf` where a purge left too few);\n\
         - *detected after*: readings from the jump to the adopted offsets-only fit; *e_b back to \
         its level before after*: until `e_b` is within 1.5 times its value before the jump \
         (or 0.02);\n\
         - *false adoptions*: offsets-only fits adopted without a moved hard iron, and adoptions \
         during a magnet's pass (and 500 readings after it) that worsened either error by 0.01;\n\
         - *refit adoptions past 0.05*: refits that took an error from within 0.05 to above it: \
         the estimation noise of a buffer that ordinary use covers weakly (coverage 0.07-0.12, \
         Gram condition about 20, where batch ADC2 errs as much).\n\n\
         The slow drift is followed only in part: refits of a buffer that spans the drift (samples \
         stay up to `max_age` = 10 000 readings) settle on a compromise, and the residuals under \
         it rarely rise long enough for the offsets-only fit to take over.\n"
    );
    host_tests::sections::publish(&doc, SECTION, write.as_deref())
}
