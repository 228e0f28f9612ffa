//! Step 0 of the robust pipeline: the rows that are dropped before any
//! fit, by rule (design document, section 14), and the per-sample gate
//! every later pass applies.
//!
//! A row is dropped when it
//!
//! - is not finite (always);
//! - has a component whose magnitude would overflow the working precision
//!   in the fit's sums (always; e.g. a `1e308` row, which would otherwise
//!   make the whole batch [`crate::Error::OutOfRange`]);
//! - is exactly `(0, 0, 0)`, the value a failed bus read leaves;
//! - has a component on the integer type's rails ([`Sample::on_rails`]);
//! - repeats the previous row exactly (a stuck sensor, or a driver that
//!   returned a stale register);
//! - has a component at a clip level: the largest or smallest value of an
//!   axis when at least `CLIP_SHARE` of the rows share it exactly (an
//!   axis that saturated below the type's rails; noise makes an axis's
//!   extreme a value few rows share), or a value inside the axis's range
//!   that as many rows share exactly, on a side whose extreme is no clip
//!   level (an axis clipped on some reads only; the robust path's
//!   screening looks for it where its histogram shows a spike).
//!
//! The last four only when outlier handling is on
//! ([`crate::Config::robust`]). No per-sample mask is stored: every pass
//! re-applies the rules to the read-only samples (a few instructions a
//! sample), and the repetition rule reads the row before.

use crate::robust::runs::Runs;
use crate::sample::Sample;
use crate::steps::dwell::Dwell;
use crate::Real;

/// Rows dropped before the fit, by rule.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[non_exhaustive]
pub struct Drops {
    /// Rows with a NaN or infinite component.
    pub non_finite: usize,
    /// Rows with a component too large for the working precision's sums.
    pub overflow: usize,
    /// Rows that are exactly `(0, 0, 0)`.
    pub zero: usize,
    /// Rows with a component on the integer type's rails.
    pub rails: usize,
    /// Rows equal to the row before.
    pub repeated: usize,
    /// Rows with a component at a clip level: an axis's extreme value that
    /// many rows share (at least 1/64 of them, and 5), where a saturated
    /// axis stops.
    pub clipped: usize,
}

impl Drops {
    /// Rows dropped by every rule together.
    pub const fn total(&self) -> usize {
        self.non_finite + self.overflow + self.zero + self.rails + self.repeated + self.clipped
    }

    /// Rows dropped by the rules that signal glitches (zero, rails,
    /// repeated, clipped), as opposed to values that cannot be computed
    /// with.
    pub const fn glitches(&self) -> usize {
        self.zero + self.rails + self.repeated + self.clipped
    }

    /// Rows dropped by `rule`.
    pub const fn by(&self, rule: Rule) -> usize {
        match rule {
            Rule::NonFinite => self.non_finite,
            Rule::Overflow => self.overflow,
            Rule::Zero => self.zero,
            Rule::Rails => self.rails,
            Rule::Repeated => self.repeated,
            Rule::Clipped => self.clipped,
        }
    }

    fn count(&mut self, rule: Rule) {
        let c = match rule {
            Rule::NonFinite => &mut self.non_finite,
            Rule::Overflow => &mut self.overflow,
            Rule::Zero => &mut self.zero,
            Rule::Rails => &mut self.rails,
            Rule::Repeated => &mut self.repeated,
            Rule::Clipped => &mut self.clipped,
        };
        *c += 1;
    }
}

/// The rule that dropped a row.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[non_exhaustive]
pub enum Rule {
    /// A NaN or infinite component.
    NonFinite,
    /// A component too large for the working precision.
    Overflow,
    /// Exactly `(0, 0, 0)`.
    Zero,
    /// A component on the integer type's rails.
    Rails,
    /// Equal to the row before.
    Repeated,
    /// A component at a clip level.
    Clipped,
}

impl Rule {
    /// Every rule, in the order of [`Drops`]' fields.
    pub const ALL: [Rule; 6] = [
        Rule::NonFinite,
        Rule::Overflow,
        Rule::Zero,
        Rule::Rails,
        Rule::Repeated,
        Rule::Clipped,
    ];

    /// Short snake-case name, as used in the CLI's JSON.
    pub const fn name(self) -> &'static str {
        match self {
            Rule::NonFinite => "non_finite",
            Rule::Overflow => "overflow",
            Rule::Zero => "zero",
            Rule::Rails => "rails",
            Rule::Repeated => "repeated",
            Rule::Clipped => "clipped",
        }
    }
}

/// The largest component magnitude a row may have: `sqrt(MAX) / 2^20`
/// (`f32`: 1.8e13, `f64`: 1.3e148). Squares of differences of such values,
/// summed over `2^20` rows, stay finite.
fn overflow_limit<T: Real>() -> T {
    T::MAX.sqrt() * T::lit(1.0 / 1_048_576.0)
}

/// The glitch rules, as one pass applies them.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct Rules<T: Real> {
    /// The zero, rails, repetition and clip rules.
    pub glitches: bool,
    /// Per axis the low and high clip level; `MAX` in magnitude (which no
    /// kept value reaches) when the axis has none.
    pub clip: [[T; 2]; 3],
    /// Whether any clip level is set.
    pub clipping: bool,
}

impl<T: Real> Rules<T> {
    /// Only the non-finite and overflow rules.
    pub(crate) const PLAIN: Self = Self {
        glitches: false,
        clip: [[T::MAX; 2]; 3],
        clipping: false,
    };

    /// The glitch rules, without clip levels.
    pub(crate) const GLITCHES: Self = Self {
        glitches: true,
        clip: [[T::MAX; 2]; 3],
        clipping: false,
    };

    /// The glitch rules with the clip levels `clip`.
    pub(crate) fn with_clip(clip: [[T; 2]; 3]) -> Self {
        Self {
            glitches: true,
            clip,
            clipping: clip.as_flattened().iter().any(|l| l.abs() < T::MAX),
        }
    }

    /// Whether `v` lies on a clip level. Applied after [`check`] and the
    /// still periods ([`Gate::admit`], [`Selection::classify`]): a still
    /// row on a clip level is a still row (the scan counts still rows
    /// before screening finds the clip levels).
    #[inline(always)]
    pub(crate) fn clipped(&self, v: &[T; 3]) -> bool {
        // Written out per axis: the iterator form keeps the row in memory
        // at opt-level "s", in every gated pass.
        let [[l0, h0], [l1, h1], [l2, h2]] = self.clip;
        self.clipping
            && ((v[0] == l0)
                | (v[0] == h0)
                | (v[1] == l1)
                | (v[1] == h1)
                | (v[2] == l2)
                | (v[2] == h2))
    }
}

/// The components of `sample` in precision `T`, or the rule that drops it.
/// `prev` is the row before it in the slice (`None` for the first). The
/// glitch rules compare the raw row (integer compares for integer
/// samples) before it is converted. The clip levels are not applied here
/// ([`Rules::clipped`]: after the still balls).
#[inline(always)]
pub(crate) fn check<T: Real, S: Sample>(
    sample: &S,
    prev: Option<&S>,
    rules: &Rules<T>,
) -> Result<[T; 3], Rule> {
    if rules.glitches {
        if let Some(rule) = glitch(sample, prev) {
            return Err(rule);
        }
    }
    let v = sample.xyz::<T>();
    // The integer types are finite and far below the limit.
    if !S::ALWAYS_FINITE {
        if !(v[0].is_finite() && v[1].is_finite() && v[2].is_finite()) {
            return Err(Rule::NonFinite);
        }
        let limit = overflow_limit::<T>();
        if !(v[0].abs() <= limit && v[1].abs() <= limit && v[2].abs() <= limit) {
            return Err(Rule::Overflow);
        }
    }
    Ok(v)
}

/// A ball in sensor units: the screening region (samples outside it are
/// not used by any fit).
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct Ball<T: Real> {
    pub centre: [T; 3],
    pub radius_sq: T,
}

impl<T: Real> Ball<T> {
    #[inline(always)]
    pub(crate) fn contains(&self, y: [T; 3]) -> bool {
        let d = [
            y[0] - self.centre[0],
            y[1] - self.centre[1],
            y[2] - self.centre[2],
        ];
        d[0] * d[0] + d[1] * d[1] + d[2] * d[2] <= self.radius_sq
    }
}

/// Which rows a pass uses: the rules, the screening ball when the
/// robust path set one, and the still periods set aside
/// ([`crate::Dwell`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct Gate<'d, T: Real> {
    /// The drop rules.
    pub rules: Rules<T>,
    /// Samples outside are screened out.
    pub screen: Option<Ball<T>>,
    /// Samples in a still period's ball are set aside. By reference:
    /// gates are copied into the methods' frames.
    pub dwell: &'d Dwell<T>,
}

impl<T: Real> Gate<'static, T> {
    /// Every finite, representable row: the plain pipeline's.
    pub(crate) const PLAIN: Self = Self {
        rules: Rules::PLAIN,
        screen: None,
        dwell: T::NO_DWELL,
    };
}

impl<'d, T: Real> Gate<'d, T> {
    /// The gate of `rules`, no ball, the still periods `dwell`.
    pub(crate) const fn of(rules: Rules<T>, dwell: &'d Dwell<T>) -> Self {
        Self {
            rules,
            screen: None,
            dwell,
        }
    }

    /// Whether the gate passes every finite, representable row.
    pub(crate) fn is_plain(&self) -> bool {
        !self.rules.glitches
            && !self.rules.clipping
            && self.screen.is_none()
            && self.dwell.is_empty()
    }

    /// The components of a row the gate passes ([`Gate::admit`]).
    ///
    /// Out of line (in `admit`): one copy for every gated loop. Inlined, the rules and
    /// the ball took about 300 bytes in each of 16 loops (LS9 + ADC2 on a
    /// Cortex-M4F: 47 312 -> 42 616 bytes of flash, `bench.sh footprint`),
    /// for about 10 instructions a gated row more (LS9 + ADC2, n = 1000,
    /// a tenth of the rows displaced: 1.56 M -> 1.70 M instructions).
    /// Clean data pay it in the final pass, which has no plain copy of its
    /// loop (84 bytes of flash for about 41 000 instructions on 1 000
    /// clean rows, `bash bench.sh flash` and `bench`); the moments have
    /// one ([`Moments::accumulate_every`](crate::steps::moments::Moments::accumulate_every)).
    #[inline(always)]
    pub(crate) fn pass<S: Sample>(&self, sample: &S, prev: Option<&S>) -> Option<[T; 3]> {
        self.admit(sample, prev).ok()
    }

    /// The components of a row the gate passes, or the rule that drops
    /// it (`None`: outside the screening ball or in a still period's). Out of line, the one copy of the
    /// rules ([`Gate::pass`], and [`count_drops`] with clip levels or on
    /// floating-point rows: LS9 + ADC2 on a Cortex-M4F 36 592 -> 36 528
    /// bytes of flash, the plain build's 22 504 -> 22 420, `bash bench.sh
    /// flash`; clean `adc2` 472 160 -> 470 240 instructions).
    #[inline(never)]
    pub(crate) fn admit<S: Sample>(
        &self,
        sample: &S,
        prev: Option<&S>,
    ) -> Result<[T; 3], Option<Rule>> {
        // Without the `robust` feature no gate clips or screens: only the
        // robust path finds clip levels and sets a ball (a `Selection`'s
        // own levels and ball are applied by `classify`, not through a
        // gate). The glitch rules alone then, and no ball: LS9 + ADC2
        // without `robust` 21 776 -> 21 548 bytes of flash (`bash bench.sh
        // flash`).
        #[cfg(not(feature = "robust"))]
        {
            let rules = Rules {
                glitches: self.rules.glitches,
                ..Rules::PLAIN
            };
            let y = check::<T, S>(sample, prev, &rules).map_err(Some)?;
            if self.dwell.holds(y) {
                return Err(None);
            }
            Ok(y)
        }
        #[cfg(feature = "robust")]
        let y = check::<T, S>(sample, prev, &self.rules).map_err(Some)?;
        #[cfg(feature = "robust")]
        if self.dwell.holds(y) {
            return Err(None);
        }
        #[cfg(feature = "robust")]
        if self.rules.clipped(&y) {
            return Err(Some(Rule::Clipped));
        }
        #[cfg(feature = "robust")]
        match &self.screen {
            Some(ball) if !ball.contains(y) => Err(None),
            _ => Ok(y),
        }
    }

    /// The rows of `block` the gate passes; `prev` is the row before the
    /// block in the whole slice.
    #[inline(always)]
    pub(crate) fn rows<'a, S: Sample>(
        &'a self,
        block: &'a [S],
        prev: Option<&'a S>,
    ) -> impl Iterator<Item = [T; 3]> + 'a {
        let mut last = prev;
        block.iter().filter_map(move |s| {
            let y = self.pass(s, last);
            last = Some(s);
            y
        })
    }
}

/// What a fit did with one row ([`Selection::classify`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum SampleClass {
    /// The final fit used the row.
    Used,
    /// A drop rule removed the row before any fit.
    Dropped(Rule),
    /// The row lies too far from the others (screening).
    Screened,
    /// The row lies in a still period's ball: set aside before any fit
    /// ([`crate::Dwell`]).
    Dwell,
    /// The row's radial residual under the calibration exceeds the cut,
    /// or the row lies beside a run of such rows ([`crate::robust::runs`]).
    Rejected,
}

/// Which rows a fit used: enough to classify every row afterwards, e.g.
/// to mark outliers on a plot or to flag them when applying the
/// calibration ([`crate::Report::selection`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Selection<T: Real> {
    /// The zero, rails, repetition and clip rules applied.
    pub glitch_rules: bool,
    /// Per axis, the low and high clip levels found (rows with a component
    /// at one were dropped, [`Rule::Clipped`]).
    pub clip_levels: [[Option<T>; 2]; 3],
    /// Rows farther than `radius` from `centre` (sensor units) were
    /// screened out.
    pub screen: Option<([T; 3], T)>,
    /// Rows whose radial residual `||u| - 1|` under the calibration exceeds
    /// this were rejected.
    pub residual_limit: Option<T>,
    /// Rows in these spans, beside runs of rejected rows, were rejected
    /// too ([`crate::robust::runs`]).
    pub runs: Runs,
    /// Rows in these balls, still periods, were set aside before any fit
    /// ([`SampleClass::Dwell`]).
    pub dwell: Dwell<T>,
}

impl<T: Real> Selection<T> {
    /// Every finite, representable row used: the plain pipeline's.
    pub const ALL: Self = Self {
        glitch_rules: false,
        clip_levels: [[None; 2]; 3],
        screen: None,
        residual_limit: None,
        runs: Runs::NONE,
        dwell: Dwell::NONE,
    };

    pub(crate) fn rules(&self) -> Rules<T> {
        let level = |l: Option<T>| l.unwrap_or(T::MAX);
        let [[a, b], [c, d], [e, f]] = self.clip_levels;
        let clip = [
            [level(a), level(b)],
            [level(c), level(d)],
            [level(e), level(f)],
        ];
        Rules {
            glitches: self.glitch_rules,
            ..Rules::with_clip(clip)
        }
    }

    pub(crate) fn gate(&self) -> Gate<'_, T> {
        Gate {
            rules: self.rules(),
            screen: self.screen.map(|(centre, r)| Ball {
                centre,
                radius_sq: r * r,
            }),
            dwell: &self.dwell,
        }
    }

    /// What the fit did with each row of `samples` under `calibration`
    /// (the fit's own rows and calibration give the fit's own choice, up to
    /// rounding for a row exactly at the limit).
    ///
    /// ```
    /// use mag_cal_core::{calibrate, Config, Rule, SampleClass};
    /// let mut samples: Vec<[f32; 3]> = (0..300)
    ///     .map(|i| {
    ///         let z = 1.0 - 2.0 * (i as f32 + 0.5) / 300.0;
    ///         let (r, phi) = ((1.0 - z * z).sqrt(), i as f32 * 2.399_963);
    ///         [40.0 * r * phi.cos() + 5.0, 40.0 * r * phi.sin(), 40.0 * z - 3.0]
    ///     })
    ///     .collect();
    /// samples[100] = [400.0, -250.0, 90.0]; // an I2C glitch
    /// samples[200] = [0.0, 0.0, 0.0]; // a failed read
    /// let result = calibrate::<f32, _>(&samples, &Config::default());
    /// # // Without the `robust` feature the glitch is trusted: it bends
    /// # // the fit, which is then refused.
    /// # #[cfg(not(feature = "robust"))]
    /// # {
    /// #     assert!(matches!(result, Err(mag_cal_core::Error::NoSphere { .. })));
    /// #     return Ok(());
    /// # }
    /// let fit = result?;
    /// let classes: Vec<_> = fit.report.selection.classify(&fit.calibration, &samples).collect();
    /// assert_eq!(classes.iter().filter(|c| **c == SampleClass::Used).count(), 298);
    /// assert_ne!(classes[100], SampleClass::Used);
    /// assert_eq!(classes[200], SampleClass::Dropped(Rule::Zero));
    /// # Ok::<(), mag_cal_core::Error>(())
    /// ```
    pub fn classify<'a, S: Sample>(
        &'a self,
        calibration: &'a crate::Calibration<T>,
        samples: &'a [S],
    ) -> impl Iterator<Item = SampleClass> + 'a {
        let Gate {
            rules,
            screen: ball,
            ..
        } = self.gate();
        let runs = self.runs;
        let dwell = self.dwell;
        let mut prev = None;
        samples.iter().enumerate().map(move |(i, s)| {
            let row = check::<T, S>(s, prev, &rules);
            prev = Some(s);
            let y = match row {
                Ok(y) => y,
                Err(rule) => return SampleClass::Dropped(rule),
            };
            if dwell.holds(y) {
                return SampleClass::Dwell;
            }
            if rules.clipped(&y) {
                return SampleClass::Dropped(Rule::Clipped);
            }
            if ball.is_some_and(|b| !b.contains(y)) {
                return SampleClass::Screened;
            }
            if runs.contains(i) {
                return SampleClass::Rejected;
            }
            match self.residual_limit {
                Some(limit) => {
                    let r = calibration.map(y).norm() - T::one();
                    if r.abs() <= limit {
                        SampleClass::Used
                    } else {
                        SampleClass::Rejected
                    }
                }
                None => SampleClass::Used,
            }
        })
    }
}

/// Every `stride`-th row of `block` from the first, with its index and the
/// row before it (`prev` for the first row of the block), which the
/// repetition rule reads.
#[inline(always)]
pub(crate) fn every<'a, S>(
    block: &'a [S],
    prev: Option<&'a S>,
    stride: usize,
) -> impl Iterator<Item = (usize, &'a S, Option<&'a S>)> + 'a {
    // An index stepped by hand: `step_by` divides the length by the
    // stride, and its loop is longer at opt-level "s".
    let step = stride.max(1);
    let mut i = 0;
    core::iter::from_fn(move || {
        let s = block.get(i)?;
        let last = match i.checked_sub(1) {
            Some(j) => block.get(j),
            None => prev,
        };
        let at = i;
        i = i.saturating_add(step);
        Some((at, s, last))
    })
}

/// The slice in pieces of `size`, each with the row before it.
#[inline(always)]
pub(crate) fn pieces<S>(samples: &[S], size: usize) -> impl Iterator<Item = (Option<&S>, &[S])> {
    let mut prev = None;
    samples.chunks(size.max(1)).map(move |piece| {
        let p = prev;
        prev = piece.last();
        (p, piece)
    })
}

/// The glitch rule (zero, rails, repeated) that drops a row, on the raw
/// row: integer compares for integer samples, before any conversion.
#[inline(always)]
fn glitch<S: Sample>(sample: &S, prev: Option<&S>) -> Option<Rule> {
    if sample.is_zero() {
        Some(Rule::Zero)
    } else if sample.on_rails() {
        Some(Rule::Rails)
    } else if prev.is_some_and(|p| p == sample) {
        Some(Rule::Repeated)
    } else {
        None
    }
}

/// Counts the drops of every rule over the slice; rows in a ball of
/// `dwell` are still rows, not drops.
pub(crate) fn count_drops<T: Real, S: Sample>(
    samples: &[S],
    rules: &Rules<T>,
    dwell: &Dwell<T>,
) -> Drops {
    let mut drops = Drops::default();
    let mut prev = None;
    // Without the `robust` feature, the gated loop below alone (flash over
    // speed: LS9 + ADC2 plain 22 348 -> 22 056 bytes, `bash bench.sh
    // flash`).
    if cfg!(feature = "robust") && S::ALWAYS_FINITE && rules.glitches && !rules.clipping {
        // Integer rows: the loop of the scan on clean data, no conversion.
        // The three tests are combined without branches (`|`, not `||`);
        // only a flagged row takes the branch that names its rule.
        let Some((first, rest)) = samples.split_first() else {
            return drops;
        };
        if let Some(rule) = glitch(first, None) {
            drops.count(rule);
        }
        let mut last = first;
        for s in rest {
            if s.is_zero() | s.on_rails() | (s == last) {
                if let Some(rule) = glitch(s, Some(last)) {
                    drops.count(rule);
                }
            }
            last = s;
        }
        return drops;
    }
    // Through the gate's out-of-line check, no screening ball (the still
    // balls' rows are no drops): no second copy of the rules for this loop
    // (it runs with clip levels or on floating-point rows).
    let gate = Gate::of(*rules, dwell);
    for s in samples {
        if let Err(Some(rule)) = gate.admit(s, prev) {
            drops.count(rule);
        }
        prev = Some(s);
    }
    drops
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn each_rule_drops_its_rows() {
        let rows: [[f64; 3]; 8] = [
            [1.0, 2.0, 3.0],
            [1.0, 2.0, 3.0],      // repeated
            [0.0, 0.0, 0.0],      // zero
            [f64::NAN, 0.0, 1.0], // non-finite
            [1e308, 0.0, 1.0],    // overflow
            [0.0, 0.0, 0.0],      // zero (also a repeat: zero is checked first)
            [4.0, 5.0, 6.0],
            [4.0, 5.0, 6.5],
        ];
        let d = count_drops::<f64, _>(&rows, &Rules::GLITCHES, &Dwell::NONE);
        assert_eq!(
            d,
            Drops {
                non_finite: 1,
                overflow: 1,
                zero: 2,
                rails: 0,
                repeated: 1,
                clipped: 0,
            }
        );
        assert_eq!(d.total(), 5);
        let plain = count_drops::<f64, _>(&rows, &Rules::PLAIN, &Dwell::NONE);
        assert_eq!((plain.total(), plain.non_finite, plain.overflow), (2, 1, 1));
        let ints: [[i16; 3]; 4] = [[1, 2, 3], [32767, 0, 1], [5, -32768, 1], [-32767, 4, 4]];
        assert_eq!(
            count_drops::<f32, _>(&ints, &Rules::GLITCHES, &Dwell::NONE).rails,
            3
        );
        // (Clip levels are the robust path's: without it no gate applies
        // them, `Gate::admit`.)
        #[cfg(feature = "robust")]
        let clip = Rules::with_clip([[f32::MAX, 5.0], [f32::MAX; 2], [-1.0, f32::MAX]]);
        #[cfg(feature = "robust")]
        assert_eq!(
            count_drops::<f32, _>(&[[5i16, 0, 3], [4, 4, -1], [1, 2, 3]], &clip, &Dwell::NONE)
                .clipped,
            2
        );
    }

    #[test]
    fn the_gate_reads_the_row_before_across_pieces() {
        let rows = [
            [1.0f32, 1.0, 1.0],
            [2.0, 2.0, 2.0],
            [2.0, 2.0, 2.0],
            [3.0, 3.0, 1.0],
        ];
        let gate = Gate::<f32> {
            rules: Rules::GLITCHES,
            screen: Some(Ball {
                centre: [0.0; 3],
                radius_sq: 12.5,
            }),
            dwell: &Dwell::NONE,
        };
        // Piece boundary between the two equal rows: still a repeat; the
        // last row lies outside the ball (a ball is the robust path's:
        // without it no gate screens, `Gate::admit`).
        let kept: usize = pieces(&rows, 2)
            .map(|(prev, piece)| gate.rows(piece, prev).count())
            .sum();
        assert_eq!(kept, if cfg!(feature = "robust") { 2 } else { 3 });
    }
}
