//! Step 4 of Algorithm 1: the re-estimation methods, each a small objective
//! over the shared [`crate::quasi_newton`] solver.

pub mod adc2;

/// Which method produced a calibration.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[non_exhaustive]
pub enum Method {
    /// The algebraic least-squares ellipsoid fit alone (step 1).
    Ls,
    /// One-step artificial data creation with quasi-Newton re-estimation
    /// (the paper's ADC2, steps 1-5).
    #[default]
    Adc2,
}

impl Method {
    /// Short lower-case name (`ls`, `adc2`), as used by the CLI.
    pub const fn name(self) -> &'static str {
        match self {
            Method::Ls => "ls",
            Method::Adc2 => "adc2",
        }
    }
}
