//! Step 1 on contaminated data, continued: the rows beside runs of rejected
//! rows are left out too (beyond the design document).
//!
//! A disturbance that passes the sensor (a magnet, a motor, a steel door)
//! displaces a stretch of consecutive rows, and the rows at its edges are
//! displaced by less than the residual cut: they pass it and bend the fit.
//! So where `RUN_LENGTH` consecutive rows have a residual beyond
//! `STRONG` times the cut, the rows from `MARGIN` before the first of
//! them to `MARGIN` after the last are left out of the passes that follow
//! (spans that touch merge). Rejected rows scattered in time (glitches,
//! isolated displacements) leave their neighbours alone.
//!
//! The spans are found by the robust LS fit's refits on a subsample (every
//! `k`-th row; then six consecutive rows of the subsample are a run, and
//! the rows between them count too), or without one by its first pass on
//! every row after two refits; the later refits, the method's passes and
//! the final pass skip them, and [`crate::Selection::classify`] reports
//! their rows as rejected. At most [`RUNS`] spans are kept: later runs are left to the
//! residual cut, and their count is reported ([`Runs::missed`]).
//!
//! Measured on the contamination study (`docs/results.md`, f32, 64 runs a
//! cell): a moving disturbance over 10 % of the rows, median error ratios
//! to the clean fit 1.35 / 1.47 -> 1.16 / 1.23; over 20 %, 3.9 -> 3.1 % of
//! the runs silently wrong; a patch of 20 %, ratios 2.17 / 3.21 -> 1.84 /
//! 2.94; but patch 30 % 6.6 -> 7.0 % and moving 30 % 3.1 -> 3.5 % silently
//! wrong. In all, 53 of 18 688 runs silently wrong before and after
//! (iterated ADC2 47 -> 41). The rows beside a run within the cut do not
//! count as outliers ([`crate::Quality::outlier_share`]): counted, they
//! refused a quarter of the patches of 20 % (66 -> 50 % accepted).
//!
//! Runs of any rejected rows (a factor of 1 instead of `STRONG`, 10 rows
//! each side) also caught the clean rows that a fit bent by a patch of
//! 30 % rejects beside the patch, and leaving out their neighbours bent it
//! further: 72 runs silently wrong (patch 30 %: 6.6 -> 13.3 %); a factor
//! of 2 (10 rows), 57; 4 (20 rows), 52 but the moving ratios 1.23 / 1.27.
//! With three rejected rows within five as a run instead of six
//! consecutive ones (a factor of 1), every run of isolated displacements
//! of 20 % was refused: too many rows left out.

pub use crate::tuning::RUNS;
use crate::tuning::{MARGIN, RUN_LENGTH};

/// The spans of rows left out beside runs of rejected rows: half-open
/// ranges `start..end` of row indices, ascending and disjoint.
///
/// ```
/// use mag_cal_core::Runs;
/// let runs = Runs::from_spans(&[(10, 40), (100, 130)]).unwrap();
/// assert!(runs.contains(39) && !runs.contains(40));
/// assert_eq!(runs.spans(), &[(10, 40), (100, 130)]);
/// assert!(Runs::from_spans(&[(50, 60), (55, 70)]).is_none()); // overlap
/// ```
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Runs {
    spans: [(usize, usize); RUNS],
    len: usize,
    missed: usize,
}

impl Default for Runs {
    fn default() -> Self {
        Self::NONE
    }
}

impl Runs {
    /// No span: every row is judged on its own.
    pub const NONE: Self = Self {
        spans: [(0, 0); RUNS],
        len: 0,
        missed: 0,
    };

    /// The spans `start..end` given, or `None` unless each is non-empty,
    /// they ascend without touching, and there are at most [`RUNS`].
    pub fn from_spans(spans: &[(usize, usize)]) -> Option<Self> {
        let mut runs = Self::NONE;
        let mut end = None;
        for &(s, e) in spans {
            if s >= e || end.is_some_and(|last| s <= last) {
                return None;
            }
            *runs.spans.get_mut(runs.len)? = (s, e);
            runs.len += 1;
            end = Some(e);
        }
        Some(runs)
    }

    /// The spans, ascending.
    pub fn spans(&self) -> &[(usize, usize)] {
        self.spans.get(..self.len).unwrap_or(&[])
    }

    /// Whether row `i` lies in a span.
    pub fn contains(&self, i: usize) -> bool {
        self.spans().iter().any(|&(s, e)| s <= i && i < e)
    }

    /// Whether there is no span.
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// Runs found after [`RUNS`] spans were kept, left to the residual cut.
    pub fn missed(&self) -> usize {
        self.missed
    }

    /// Calls `visit(row, row before)` on every row of the spans.
    #[cfg(feature = "robust")]
    pub(crate) fn visit<S>(&self, samples: &[S], mut visit: impl FnMut(&S, Option<&S>)) {
        for &(s, e) in self.spans() {
            let mut prev = s.checked_sub(1).and_then(|j| samples.get(j));
            for row in samples.get(s..e).unwrap_or(&[]) {
                visit(row, prev);
                prev = Some(row);
            }
        }
    }

    /// The pieces of `samples` outside the spans, each at most `size` rows,
    /// with its first row's index and the row before it in `samples` (the
    /// repetition rule reads it). Without spans, the chunks of `size`.
    #[inline(always)]
    pub(crate) fn pieces<'a, S>(
        &'a self,
        samples: &'a [S],
        size: usize,
    ) -> impl Iterator<Item = (usize, Option<&'a S>, &'a [S])> + 'a {
        let size = size.max(1);
        let spans = self.spans();
        let (mut at, mut k) = (0usize, 0usize);
        core::iter::from_fn(move || {
            // Past the spans that begin at or before `at`: at most one
            // step a span.
            while let Some(&(s, e)) = spans.get(k) {
                if at < s {
                    break;
                }
                at = at.max(e);
                k += 1;
            }
            let stop = spans.get(k).map_or(samples.len(), |&(s, _)| s);
            let end = stop.min(samples.len()).min(at.saturating_add(size));
            let piece = samples.get(at..end).filter(|p| !p.is_empty())?;
            let prev = at.checked_sub(1).and_then(|j| samples.get(j));
            let start = at;
            at = end;
            Some((start, prev, piece))
        })
    }
}

/// Finds the spans from the rows rejected by their residual, given in
/// ascending order, and writes them into the caller's [`Runs`] (not a copy
/// of its own: the finder lives in the deepest frame of its pass).
#[derive(Debug)]
pub(crate) struct RunFinder<'a> {
    /// The first and the last row of the latest stretch of consecutive
    /// rejected rows, and how many rows of it were seen (0: none yet; no
    /// `Option`, whose tag took 4 bytes of the deepest frame).
    stretch: (usize, usize, usize),
    /// The span still growing.
    open: Option<(usize, usize)>,
    /// Rows between consecutive rows seen (a subsample's stride).
    step: usize,
    runs: &'a mut Runs,
}

impl<'a> RunFinder<'a> {
    /// A finder that writes into `runs` (cleared), of every `step`-th row.
    pub(crate) fn new(runs: &'a mut Runs, step: usize) -> Self {
        *runs = Runs::NONE;
        Self {
            stretch: (0, 0, 0),
            open: None,
            step: step.max(1),
            runs,
        }
    }

    /// Row `i` was rejected by its residual (rows in ascending order).
    #[inline(never)]
    pub(crate) fn reject(&mut self, i: usize) {
        let step = self.step;
        let (first, last, seen) = self.stretch;
        // A subsample's rows are `step` apart, or fewer across the blocks
        // of a pass.
        let (first, seen) = if seen > 0 && i > last && i - last <= step {
            (first, seen + 1)
        } else {
            (i, 1)
        };
        self.stretch = (first, i, seen);
        if seen >= RUN_LENGTH {
            // The rows between the rows seen count as rejected too.
            let span = (
                first.saturating_sub(MARGIN + step - 1),
                i.saturating_add(MARGIN).saturating_add(step),
            );
            self.open = match self.open {
                Some((s, e)) if span.0 <= e => Some((s, e.max(span.1))),
                Some(done) => {
                    self.close(done);
                    Some(span)
                }
                None => Some(span),
            };
        }
    }

    fn close(&mut self, span: (usize, usize)) {
        match self.runs.spans.get_mut(self.runs.len) {
            Some(slot) => {
                *slot = span;
                self.runs.len += 1;
            }
            None => self.runs.missed = self.runs.missed.saturating_add(1),
        }
    }

    /// Closes the last span and clips the spans to `rows` rows.
    pub(crate) fn finish(mut self, rows: usize) {
        if let Some(open) = self.open.take() {
            self.close(open);
        }
        let runs = self.runs;
        // The spans ascend: those past the end are the last ones.
        let mut kept = 0;
        for span in runs.spans.iter_mut().take(runs.len) {
            span.1 = span.1.min(rows);
            if span.0 < span.1 {
                kept += 1;
            }
        }
        runs.len = kept;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The runs found from the rejected rows `rejected` of `rows` rows.
    fn found(rows: usize, rejected: impl IntoIterator<Item = usize>) -> Runs {
        let mut runs = Runs::NONE;
        let mut f = RunFinder::new(&mut runs, 1);
        for i in rejected {
            f.reject(i);
        }
        f.finish(rows);
        runs
    }

    /// `RUN_LENGTH` consecutive rows from `first`.
    fn run(first: usize) -> core::ops::Range<usize> {
        first..first + RUN_LENGTH
    }

    #[test]
    fn scattered_rejections_are_no_run() {
        // One row short of a run, and rows apart by one.
        let rejected = (100..100 + RUN_LENGTH - 1).chain((200..240).step_by(2));
        let runs = found(300, rejected);
        assert!(runs.is_empty(), "{runs:?}");
    }

    #[test]
    fn a_subsample_s_rows_in_a_row_are_a_run_with_the_rows_between() {
        // Every third row, half of them each side of a block boundary
        // (at 384, where the rows seen are two apart): RUN_LENGTH of them
        // are a run, the rows between and beside them rejected too.
        let step = 3;
        let first = 384 - step * (RUN_LENGTH / 2 - 1);
        let rejected =
            (0..RUN_LENGTH)
                .map(|k| first + step * k)
                .map(|i| if i > 384 { i - 1 } else { i });
        let last = rejected.clone().next_back().unwrap();
        let mut runs = Runs::NONE;
        let mut f = RunFinder::new(&mut runs, step);
        for i in rejected {
            f.reject(i);
        }
        f.finish(1000);
        let span = (first - MARGIN - (step - 1), last + MARGIN + step);
        assert_eq!(runs.spans(), &[span]);
        // One row short of a run of the subsample.
        let mut runs = Runs::NONE;
        let mut f = RunFinder::new(&mut runs, step);
        for k in 0..RUN_LENGTH - 1 {
            f.reject(600 + step * k);
        }
        f.finish(1000);
        assert!(runs.is_empty());
    }

    #[test]
    fn consecutive_rejections_are_a_run() {
        let runs = found(1000, 100..100 + RUN_LENGTH + 3);
        let span = (100 - MARGIN, 100 + RUN_LENGTH + 3 + MARGIN);
        assert_eq!(runs.spans(), &[span]);
    }

    #[cfg(feature = "robust")]
    #[test]
    fn touching_runs_merge_and_spans_stop_at_the_ends() {
        let rejected = run(1)
            .chain(run(1 + RUN_LENGTH + 2 * MARGIN))
            .chain(run(995));
        let runs = found(1000, rejected);
        let end = 1 + 2 * RUN_LENGTH + 3 * MARGIN;
        assert_eq!(runs.spans(), &[(0, end), (995 - MARGIN, 1000)]);
        // Each row of the spans once, with the row before it.
        let rows: [u16; 1000] = core::array::from_fn(|i| i as u16);
        let (mut seen, mut tenth) = (0, 0);
        runs.visit(&rows, |&row, prev| {
            assert_eq!(prev.copied(), row.checked_sub(1));
            seen += 1;
            tenth += usize::from(row % 10 == 0);
        });
        assert_eq!(seen, end + MARGIN + 5);
        // 11 in the first span; 970, 980 and 990 in the second.
        assert_eq!(tenth, end.div_ceil(10) + 3);
    }

    #[test]
    fn runs_beyond_the_capacity_are_counted() {
        let rejected = (0..RUNS + 2).flat_map(|k| run(k * 1000));
        let runs = found(100_000, rejected);
        assert_eq!(runs.spans().len(), RUNS);
        assert_eq!(runs.missed(), 2);
    }

    #[test]
    fn the_pieces_skip_the_spans() {
        let rows: [usize; 100] = core::array::from_fn(|i| i);
        for (spans, last) in [([(0, 5), (95, 120)], 95), ([(20, 30), (31, 33)], 100)] {
            let runs = Runs::from_spans(&spans).unwrap();
            let mut next = 0;
            for (start, prev, piece) in runs.pieces(&rows, 8) {
                assert_eq!(prev, start.checked_sub(1).map(|j| &rows[j]));
                assert!(piece.len() <= 8);
                for &i in piece {
                    // Every row outside the spans, once, in order.
                    while runs.contains(next) {
                        next += 1;
                    }
                    assert_eq!(i, next);
                    next += 1;
                }
            }
            assert_eq!(next, last, "{spans:?}");
        }
        let too_many: [(usize, usize); RUNS + 1] = core::array::from_fn(|k| (10 * k, 10 * k + 5));
        assert!(Runs::from_spans(&too_many).is_none());
        assert!(Runs::from_spans(&too_many[..RUNS]).is_some());
        let mut ends = Runs::NONE.pieces(&rows, 32).map(|(s, _, p)| s + p.len());
        assert!([32, 64, 96, 100].into_iter().eq(ends.by_ref()));
    }
}
