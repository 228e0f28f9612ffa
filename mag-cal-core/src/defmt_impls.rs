//! `defmt::Format` for the result types (feature `defmt`): the values by
//! name, warnings by their names (not bits). Written out for `f32` and
//! `f64`, the two [`crate::Real`] types, whose values `defmt` formats.

use defmt::{write, Format, Formatter};

use crate::{Calibration, Fit, Quality, Report, Selection, Warnings};

impl Format for Warnings {
    fn format(&self, f: Formatter<'_>) {
        write!(f, "[");
        for (i, w) in self.iter().enumerate() {
            if i > 0 {
                write!(f, ", ");
            }
            write!(f, "{=str}", w.name());
        }
        write!(f, "]");
    }
}

macro_rules! formats {
    ($($t:ty),*) => {$(
        impl Format for Calibration<$t> {
            fn format(&self, f: Formatter<'_>) {
                write!(
                    f,
                    "Calibration {{ b: {}, W: {}, field_strength: {} }}",
                    self.hard_iron(),
                    self.soft_iron(),
                    self.field_strength()
                );
            }
        }

        impl Format for Quality<$t> {
            fn format(&self, f: Formatter<'_>) {
                write!(
                    f,
                    "Quality {{ flatness: {}, quadric_gap: {}, distortion: {}, coverage: {}, gram_condition: {}, fit_error: {}, lack_of_fit: {}, outlier_share: {}, skewness: {} }}",
                    self.flatness,
                    self.quadric_gap,
                    self.distortion,
                    self.coverage,
                    self.gram_condition,
                    self.fit_error,
                    self.lack_of_fit,
                    self.outlier_share,
                    self.skewness
                );
            }
        }

        impl Format for Selection<$t> {
            fn format(&self, f: Formatter<'_>) {
                write!(
                    f,
                    "Selection {{ glitch_rules: {}, clip_levels: {}, screen: {}, residual_limit: {}, runs: {} }}",
                    self.glitch_rules,
                    self.clip_levels,
                    self.screen,
                    self.residual_limit,
                    self.runs.spans()
                );
            }
        }

        impl Format for Report<$t> {
            fn format(&self, f: Formatter<'_>) {
                write!(
                    f,
                    "Report {{ method: {}, ls: {}, iterations: {}, passes: {}, robust_passes: {}, samples_used: {}, samples_dropped: {}, drops: {}, screened: {}, rejected: {}, beside_runs: {}, radial_rms: {}, quality: {}, warnings: {}, selection: {}, start: {} }}",
                    self.method,
                    self.ls,
                    self.iterations,
                    self.passes,
                    self.robust_passes,
                    self.samples_used,
                    self.samples_dropped,
                    self.drops,
                    self.screened,
                    self.rejected,
                    self.beside_runs,
                    self.radial_rms,
                    self.quality,
                    self.warnings,
                    self.selection,
                    self.start
                );
            }
        }

        impl Format for Fit<$t> {
            fn format(&self, f: Formatter<'_>) {
                write!(
                    f,
                    "Fit {{ calibration: {}, report: {} }}",
                    self.calibration,
                    self.report
                );
            }
        }
    )*};
}

formats!(f32, f64);
