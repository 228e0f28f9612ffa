//! Step 2-3 of Algorithm 1: artificial field vectors and the sufficient
//! statistics of ADC2 (design document, section 4), in one pass.
//!
//! With the current estimate (`b0`, `T0`, `W0 = T0^-1`, normalised units):
//!
//! ```text
//! d_i = x_i - b0,   u_i = W0 d_i,   h_i = u_i / |u_i|
//! r_i = d_i - T0 h_i = d_i (1 - 1/|u_i|)      (the residual at the start)
//! ```
//!
//! ADC2 regresses `d_i` on `[h_i, 1]`. Writing the unknowns as a correction
//! `(T, beta) = (T0 + dT, beta)` makes that a regression of the small
//! residuals `r_i` on `[h_i, 1]`, so every statistic is a sum of small
//! terms and nothing cancels, even in `f32`:
//!
//! ```text
//! n,  s_h = sum h_i,  S_hh = sum h_i h_i^T,  s_r = sum r_i,  S_rh = sum r_i h_i^T,  S_rr = sum r_i r_i^T
//! ```
//!
//! The ADC2 cost at the start is `J0 = tr S_rr`; ADC1 weights the same
//! quantities. (The design document's `s_d`, `S_dh` are `s_r + T0 s_h` and
//! `S_rh + T0 S_hh`.)
//!
//! The pass itself needs neither `d` nor `T0`: with the radial error
//! `e_i = |u_i| - 1`, `r_i = T0 (u_i - h_i) = T0 g_i` with
//! `g_i = u_i - h_i = e_i h_i`, so
//!
//! ```text
//! s_r = T0 sum g_i,   S_rh = T0 sum g_i h_i^T,   S_rr = T0 (sum g_i g_i^T) T0^T
//! ```
//!
//! and the samples feed 24 sums (`h`, `g` and three symmetric matrices:
//! `g h^T = e h h^T` is one) instead of 27, each still a sum of small terms.
//! Per sample the pass keeps `u` and `1/|u|`, then forms `h = u/|u|` and
//! `g = u - h` (no cancellation: `u` and `h` are parallel and of nearly
//! the same length, so the difference is exact up to the rounding of `h`).

use nalgebra::{Matrix3, Matrix3x4, Matrix4, Vector3};

use crate::numerics::histogram::LogHistogram;
use crate::numerics::linalg::{columns_of, from_columns, inverse3, larger};
use crate::robust::runs::Runs;
use crate::sample::Sample;
use crate::steps::methods::robust_sigma;
use crate::steps::moments::BLOCK;
use crate::steps::normalize::{Normalization, Projector};
#[cfg(any(feature = "robust", test, feature = "bench-internals"))]
use crate::steps::rules::{check, Rules};
use crate::steps::rules::{pieces, Gate};
use crate::{Error, Real};

/// The shape of the algebraic residuals `e = |u|^2 - 1` of a plain pass
/// (raw moments: the LS start leaves their mean near 0).
// (Without `robust` only the tests and the benchmarks measure them.)
#[cfg(any(feature = "robust", test, feature = "bench-internals"))]
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct Tails<T> {
    /// `n sum e^4 / (sum e^2)^2`: about 3 for Gaussian noise, more when a
    /// share of the rows lies off the ellipsoid (0 when every residual is
    /// 0).
    pub kurtosis: T,
    /// `sqrt(n) sum e^3 / (sum e^2)^(3/2)`: near 0 for small noise,
    /// positive for large noise (`e = 2 n + n^2` for a radial noise `n`)
    /// and for rows displaced outwards, negative when a share of the rows
    /// is pulled inwards, as a clipped axis pulls them.
    pub skewness: T,
}

/// Sufficient statistics of the artificial data (normalised units).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Stats<T: Real> {
    /// Samples that contributed (finite, and not at the fitted centre).
    pub count: usize,
    /// `sum h_i`.
    pub s_h: Vector3<T>,
    /// `sum h_i h_i^T`.
    pub s_hh: Matrix3<T>,
    /// `sum r_i`.
    pub s_r: Vector3<T>,
    /// `sum r_i h_i^T`.
    pub s_rh: Matrix3<T>,
    /// `sum r_i r_i^T` (symmetric); its trace is the ADC2 cost at the start.
    pub s_rr: Matrix3<T>,
}

impl<T: Real> Stats<T> {
    /// `Q = [S_rh | s_r]` (3x4): residuals against the regressors `[h, 1]`.
    pub fn q(&self) -> Matrix3x4<T> {
        let mut q = Matrix3x4::zeros();
        q.fixed_view_mut::<3, 3>(0, 0).copy_from(&self.s_rh);
        q.fixed_view_mut::<3, 1>(0, 3).copy_from(&self.s_r);
        q
    }

    /// `G = [[S_hh, s_h], [s_h^T, n]]` (4x4): the Gram matrix of `[h, 1]`.
    pub fn gram(&self) -> Matrix4<T> {
        let mut g = Matrix4::zeros();
        g.fixed_view_mut::<3, 3>(0, 0).copy_from(&self.s_hh);
        g.fixed_view_mut::<3, 1>(0, 3).copy_from(&self.s_h);
        g.fixed_view_mut::<1, 3>(3, 0)
            .copy_from(&self.s_h.transpose());
        g[(3, 3)] = T::from_count(self.count);
        g
    }

    /// Covariance of the start residuals, `S_rr/n - (s_r/n)(s_r/n)^T`: the
    /// paper's noise estimate for ADC1 (normalised units).
    #[cfg(feature = "adc1")]
    pub fn residual_covariance(&self) -> Matrix3<T> {
        let n = T::from_count(self.count);
        let mean = self.s_r / n;
        self.s_rr / n - mean * mean.transpose()
    }

    /// One pass over the samples with the start `(centre, w)` = (`b0`, `W0`)
    /// in the coordinates of `norm`; `T0 = W0^-1`.
    ///
    /// [`Error::NotAnEllipsoid`] when `W0` is singular to working precision,
    /// [`Error::TooFewSamples`] when fewer than [`crate::MIN_SAMPLES`]
    /// samples have a direction.
    #[cfg(any(test, feature = "bench-internals"))]
    pub fn accumulate<S: Sample>(
        samples: &[S],
        norm: &Normalization<T>,
        centre: &Vector3<T>,
        w: &Matrix3<T>,
    ) -> Result<Self, Error> {
        Self::accumulate_plain(samples, norm, centre, w).map(|(stats, _)| stats)
    }

    /// `Stats::accumulate`, and the shape of the algebraic residuals
    /// `e_i = |u_i|^2 - 1` at the start ([`Tails`]).
    #[cfg(any(feature = "robust", test, feature = "bench-internals"))]
    pub(crate) fn accumulate_plain<S: Sample>(
        samples: &[S],
        norm: &Normalization<T>,
        centre: &Vector3<T>,
        w: &Matrix3<T>,
    ) -> Result<(Self, Tails<T>), Error> {
        let mut sums = [T::zero(); 3];
        let stats = Self::from_pass(samples, norm, centre, w, Measure::Tails(&mut sums))?;
        let [s2, s3, s4] = sums;
        let n = T::from_count(stats.count);
        let tails = if s2 > T::zero() {
            Tails {
                kurtosis: n * s4 / (s2 * s2),
                skewness: n.square_root() * s3 / (s2 * s2.square_root()),
            }
        } else {
            Tails {
                kurtosis: T::zero(),
                skewness: T::zero(),
            }
        };
        Ok((stats, tails))
    }

    /// [`Stats::accumulate`] over the rows `gate` passes, weight 1, measuring
    /// nothing: the one artificial-data pass of the plain build (no tails
    /// limit, no residual limit). The rows and sums are those of the plain
    /// pass ([`Stats::accumulate_plain`]) for a plain gate, and those of
    /// the gated pass without a limit ([`Stats::accumulate_with`])
    /// otherwise, to the bit.
    #[cfg(not(feature = "robust"))]
    pub(crate) fn accumulate_rows<S: Sample>(
        samples: &[S],
        norm: &Normalization<T>,
        centre: &Vector3<T>,
        w: &Matrix3<T>,
        gate: &Gate<T>,
    ) -> Result<Self, Error> {
        let mut total = [T::zero(); SUMS];
        let map = Projector::new(norm, centre, w);
        let count = row_sums(samples, &map, gate, &mut total);
        Self::from_counted(count, &total, w)
    }

    /// The pass: plain, or gated, weighted and measured.
    #[cfg(any(feature = "robust", test, feature = "bench-internals"))]
    fn from_pass<S: Sample>(
        samples: &[S],
        norm: &Normalization<T>,
        centre: &Vector3<T>,
        w: &Matrix3<T>,
        weighted: Measure<'_, '_, T>,
    ) -> Result<Self, Error> {
        let mut total = [T::zero(); SUMS];
        let map = Projector::new(norm, centre, w);
        let count = sums(samples, &map, weighted, &mut total);
        Self::from_counted(count, &total, w)
    }

    /// The statistics of a pass's `count` rows with a direction and their
    /// sums `total`, under the start `w`.
    #[inline(always)]
    fn from_counted(count: usize, total: &[T; SUMS], w: &Matrix3<T>) -> Result<Self, Error> {
        if count < crate::steps::normalize::MIN_SAMPLES {
            return Err(Error::TooFewSamples {
                found: count,
                required: crate::steps::normalize::MIN_SAMPLES,
            });
        }
        Self::from_sums(count, total, w)
    }

    /// The statistics from the sums of the pass, or
    /// [`Error::NotAnEllipsoid`] when `W0` is singular. Not inlined: its
    /// temporaries then stay out of the stack frame that is live during
    /// the pass. The caller's result is its own (an `Option` converted
    /// there took a slot of 140 bytes in the frame live during the pass).
    #[inline(never)]
    fn from_sums(count: usize, t: &[T; SUMS], w: &Matrix3<T>) -> Result<Self, Error> {
        let t0 = inverse(w).ok_or(Error::NotAnEllipsoid)?;
        let sym = |a: T, b: T, c: T, d: T, e: T, f: T| Matrix3::new(a, b, c, b, d, e, c, e, f);
        let s_eh = Vector3::new(t[3], t[4], t[5]);
        let s_ehh = sym(t[12], t[13], t[14], t[15], t[16], t[17]);
        let s_eehh = sym(t[18], t[19], t[20], t[21], t[22], t[23]);
        // `T0 S T0^T` through the one product (a second, `a b^T` written
        // out, took 132 bytes of flash more, LS9 + ADC2 without `robust`).
        let s_rr = product(&product(&t0, &s_eehh), &t0.transpose());
        Ok(Self {
            count,
            s_h: Vector3::new(t[0], t[1], t[2]),
            s_hh: sym(t[6], t[7], t[8], t[9], t[10], t[11]),
            s_r: Vector3::from(times(&t0, s_eh.into())),
            s_rh: product(&t0, &s_ehh),
            // Symmetric to the last bit, as a sum of `r r^T` is (entry by
            // entry: `(S + S^T) / 2` through nalgebra's temporaries took 28
            // bytes of flash more, LS9 + ADC2 with or without `robust`).
            s_rr: Matrix3::from_fn(|i, j| (s_rr[(i, j)] + s_rr[(j, i)]) * T::lit(0.5)),
        })
    }
}

/// `a b` for 3x3 matrices. Written out: nalgebra's generic product is a
/// loop nest that costs several times the 27 multiply-adds on a
/// Cortex-M4F.
fn product<T: Real>(a: &Matrix3<T>, b: &Matrix3<T>) -> Matrix3<T> {
    let [b0, b1, b2] = b.data.0;
    Matrix3::from_columns(&[
        times(a, b0).into(),
        times(a, b1).into(),
        times(a, b2).into(),
    ])
}

/// `a v` for a 3x3 matrix, written out (as [`product`]).
fn times<T: Real>(a: &Matrix3<T>, [x, y, z]: [T; 3]) -> [T; 3] {
    // Columns of the storage: `a[column][row]`.
    let [a0, a1, a2] = a.data.0;
    [
        a0[0] * x + a1[0] * y + a2[0] * z,
        a0[1] * x + a1[1] * y + a2[1] * z,
        a0[2] * x + a1[2] * y + a2[2] * z,
    ]
}

/// Number of per-sample sums: `h` (3), `g = e h` (3), then the upper
/// triangles of `h h^T`, `g h^T = e h h^T` and `g g^T = e^2 h h^T` (6 each).
const SUMS: usize = 24;

/// One gated artificial-data pass under one start, as a value that is fed
/// the rows in slices ([`AdcPass::feed`], the background calibrator,
/// [`crate::device::background`]) or run over all of them at once
/// ([`AdcPass::run`], the batch fit): the same sums either way, then the
/// same statistics and robust sigma.
#[derive(Clone)]
pub(crate) struct AdcPass<T: Real> {
    /// The start `(b0, W0)`, folded with the normalisation.
    map: Projector<T>,
    /// Rows with `||u| - 1|` above this are left out (none when `None`).
    limit: Option<T>,
    /// Rows with a direction so far.
    count: usize,
    total: [T; SUMS],
    /// The residuals of every row the gate passed.
    residuals: Residuals<T>,
}

impl<T: Real> AdcPass<T> {
    /// The whole pass over `samples` under the start `(centre, w)` in the
    /// coordinates of `norm`, with the gate, spans and limit of `pass`: the
    /// statistics, and the residuals of the rows the gate passed measured
    /// into `residuals`. No value is kept: the sums stay in the frame of
    /// the pass, as those of the plain pass.
    ///
    /// [`Error::NotAnEllipsoid`] when `W0` is singular to working precision,
    /// [`Error::TooFewSamples`] when fewer than [`crate::MIN_SAMPLES`]
    /// rows have a direction within the limit.
    #[cfg(any(feature = "robust", test))]
    pub(crate) fn run<S: Sample>(
        samples: &[S],
        norm: &Normalization<T>,
        centre: &Vector3<T>,
        w: &Matrix3<T>,
        pass: &Pass<'_, T>,
        residuals: &mut Residuals<T>,
    ) -> Result<Stats<T>, Error> {
        Stats::from_pass(samples, norm, centre, w, Measure::Gated(pass, residuals))
    }

    /// No rows yet: the pass under the start `(centre, w)` in the
    /// coordinates of `norm`, leaving out rows beyond `limit`.
    pub(crate) fn new(
        norm: &Normalization<T>,
        centre: &Vector3<T>,
        w: &Matrix3<T>,
        limit: Option<T>,
    ) -> Self {
        Self {
            map: Projector::new(norm, centre, w),
            limit,
            count: 0,
            total: [T::zero(); SUMS],
            residuals: Residuals::new(),
        }
    }

    /// Adds the rows of `rows` the gate passes outside the spans of `runs`
    /// (a slice of the samples; the rows after it come with the next call).
    pub(crate) fn feed<S: Sample>(&mut self, rows: &[S], gate: &Gate<T>, runs: &Runs) {
        let pass = Pass {
            gate,
            runs,
            limit: self.limit,
        };
        let measure = Measure::Gated(&pass, &mut self.residuals);
        self.count += sums(rows, &self.map, measure, &mut self.total);
    }

    /// The statistics of every row fed, under the start `w` (the pass's).
    ///
    /// # Errors
    /// As [`AdcPass::run`].
    pub(crate) fn stats(&self, w: &Matrix3<T>) -> Result<Stats<T>, Error> {
        if self.count < crate::steps::normalize::MIN_SAMPLES {
            return Err(Error::TooFewSamples {
                found: self.count,
                required: crate::steps::normalize::MIN_SAMPLES,
            });
        }
        Stats::from_sums(self.count, &self.total, w)
    }

    /// The robust standard deviation of the residuals of the rows the gate
    /// passed (see [`robust_sigma`]); `None` before any.
    pub(crate) fn sigma(&self) -> Option<T> {
        robust_sigma(&self.residuals.hist)
    }
}

/// Which rows an artificial-data pass uses.
#[derive(Clone, Copy)]
pub(crate) struct Pass<'a, T: Real> {
    /// The drop rules and the screening ball.
    pub gate: &'a Gate<'a, T>,
    /// The spans of rows skipped ([`crate::robust::runs`]).
    pub runs: &'a Runs,
    /// Rows with `||u| - 1|` above this are left out (none when `None`).
    pub limit: Option<T>,
}

/// What a weighted pass measures of the radial residuals `||u| - 1|` of
/// the rows its gate passes (before its limit).
#[derive(Clone, Debug)]
pub(crate) struct Residuals<T: Real> {
    /// Their histogram.
    pub hist: LogHistogram,
    /// The largest.
    pub max: T,
}

impl<T: Real> Residuals<T> {
    /// Nothing measured yet.
    pub(crate) fn new() -> Self {
        Self {
            hist: LogHistogram::new(),
            max: T::zero(),
        }
    }
}

/// What a pass measures beside its sums.
enum Measure<'a, 'p, T: Real> {
    /// The plain pass (every finite row, weight 1): the sums of `e^2`,
    /// `e^3` and `e^4` of the algebraic residuals.
    #[cfg(any(feature = "robust", test, feature = "bench-internals"))]
    Tails(&'a mut [T; 3]),
    /// A gated pass: its gate and cut, and the residuals it measures.
    Gated(&'a Pass<'p, T>, &'a mut Residuals<T>),
}

/// Adds the [`SUMS`] sums of the samples to `total` (zeros on entry), in
/// blocks of [`BLOCK`] samples, and returns the count of the samples with a
/// direction. Not inlined: the buffer of directions is then the only large
/// item of its stack frame (and `total` lives in the caller's).
#[inline(never)]
fn sums<T: Real, S: Sample>(
    samples: &[S],
    map: &Projector<T>,
    mut weighted: Measure<'_, '_, T>,
    total: &mut [T; SUMS],
) -> usize {
    let mut count = 0usize;
    let mut buf = [[T::zero(); 4]; CHUNK];
    // The plain pass (every finite row, weight 1) needs neither the rules
    // nor the residuals: its loop is the cheaper one.
    // By reference: a copy took stack in the method's deepest frame.
    let runs: &Runs = match &weighted {
        #[cfg(any(feature = "robust", test, feature = "bench-internals"))]
        Measure::Tails(_) => &Runs::NONE,
        Measure::Gated(pass, _) => pass.runs,
    };
    for (_, block_prev, block) in runs.pieces(samples, BLOCK) {
        let mut a = [T::zero(); SUMS];
        for (chunk_prev, chunk) in pieces(block, CHUNK) {
            let prev = chunk_prev.or(block_prev);
            count += match &mut weighted {
                #[cfg(any(feature = "robust", test, feature = "bench-internals"))]
                Measure::Tails(tails) => plain_directions(chunk, map, tails, &mut buf),
                Measure::Gated(pass, res) => directions(chunk, prev, map, pass, res, &mut buf),
            };
            add_directions(&mut a, buf.get(..chunk.len()).unwrap_or(&[]));
        }
        add_sums(total, &a);
    }
    count
}

/// Adds a block's sums `a` to the pass's `total`, four sums a step (one a
/// step takes twice the instructions).
#[inline(always)]
fn add_sums<T: Real>(total: &mut [T; SUMS], a: &[T; SUMS]) {
    const { assert!(SUMS.is_multiple_of(4)) };
    let quads = total
        .as_chunks_mut::<4>()
        .0
        .iter_mut()
        .zip(a.as_chunks::<4>().0);
    for (t, v) in quads {
        *t = [t[0] + v[0], t[1] + v[1], t[2] + v[2], t[3] + v[3]];
    }
}

/// [`sums`] of the plain build's pass ([`Stats::accumulate_rows`]): the
/// same blocks and chunks, the rows of [`row_directions`]. A function of
/// its own: `sums` links the directions of every kind of pass.
#[cfg(not(feature = "robust"))]
#[inline(never)]
fn row_sums<T: Real, S: Sample>(
    samples: &[S],
    map: &Projector<T>,
    gate: &Gate<T>,
    total: &mut [T; SUMS],
) -> usize {
    let mut count = 0usize;
    let mut buf = [[T::zero(); 4]; CHUNK];
    for (_, block_prev, block) in Runs::NONE.pieces(samples, BLOCK) {
        let mut a = [T::zero(); SUMS];
        for (chunk_prev, chunk) in pieces(block, CHUNK) {
            let prev = chunk_prev.or(block_prev);
            count += row_directions(chunk, prev, map, gate, &mut buf);
            add_directions(&mut a, buf.get(..chunk.len()).unwrap_or(&[]));
        }
        add_sums(total, &a);
    }
    count
}

/// Samples whose directions are buffered between the two loops of the
/// pass.
///
/// The pass is two loops over each chunk, each a function of its own (not
/// inlined): [`directions`] maps the samples to `[u, 1/|u|]` and
/// [`add_directions`] adds the 24 sums. In one loop, the 24 sums, the map's
/// 12 constants and the temporaries do not fit the Cortex-M4F's 32
/// floating-point registers, and spills and register shuffles made the pass
/// 153 instructions a sample (`f32`, `[i16; 3]`, opt-level "s"); split, each
/// loop fits: about 51 instructions a sample and 37, and the pass takes 94
/// with the chunk and block overhead and the final 3x3 products. The
/// buffer is 16 bytes a sample in `f32` (512 bytes of stack); 32 samples
/// make four chunks of a [`BLOCK`] (44, three chunks, took 1 instruction a
/// sample less for 192 bytes more stack, which the 4 KiB stack budget of
/// the robust path does not leave).
const CHUNK: usize = 32;

/// `[u, 1/|u|]` of each finite sample of `chunk` into `out` (zeros for a
/// sample without a direction: non-finite, or at the fitted centre), and
/// the count of the samples with a direction: the plain pass.
#[cfg(any(feature = "robust", test, feature = "bench-internals"))]
#[inline(never)]
fn plain_directions<T: Real, S: Sample>(
    chunk: &[S],
    map: &Projector<T>,
    tails: &mut [T; 3],
    out: &mut [[T; 4]; CHUNK],
) -> usize {
    let mut count = chunk.len();
    let [mut s2, mut s3, mut s4] = *tails;
    for (sample, slot) in chunk.iter().zip(out.iter_mut()) {
        *slot = match plain_direction(sample, map) {
            Some((v, q)) => {
                let e = q - T::one();
                let e2 = e * e;
                s2 += e2;
                s3 += e2 * e;
                s4 += e2 * e2;
                v
            }
            None => {
                count -= 1;
                [T::zero(); 4]
            }
        };
    }
    *tails = [s2, s3, s4];
    count
}

/// `[u, 1/|u|]` of each sample of `chunk` the gate passes into `out` (zeros
/// for the others and for a sample without a direction), and the count of
/// the samples with a direction: the plain build's pass. With a plain gate
/// the rows and directions of [`plain_directions`], otherwise those of
/// [`directions`] without a limit (which leaves out a row whose `|u|`
/// overflows, its residual not being finite), without measuring.
#[cfg(not(feature = "robust"))]
#[inline(never)]
fn row_directions<T: Real, S: Sample>(
    chunk: &[S],
    prev: Option<&S>,
    map: &Projector<T>,
    gate: &Gate<T>,
    out: &mut [[T; 4]; CHUNK],
) -> usize {
    let plain = gate.is_plain();
    let mut count = 0;
    let mut last = prev;
    for (sample, slot) in chunk.iter().zip(out.iter_mut()) {
        let row = gate.pass(sample, last);
        last = Some(sample);
        *slot = [T::zero(); 4];
        let Some(y) = row else {
            continue;
        };
        let [ux, uy, uz] = map.project(y);
        let q = ux * ux + uy * uy + uz * uz;
        if !(q >= T::MIN_POSITIVE) {
            continue;
        }
        let inv = q.rsqrt();
        if plain || (q * inv - T::one()).abs() <= T::MAX {
            *slot = [ux, uy, uz, inv];
            count += 1;
        }
    }
    count
}

/// `[u, 1/|u|]` of one sample and `|u|^2`; `None` when the sample is not
/// finite or lies at the fitted centre (no direction).
#[cfg(any(feature = "robust", test, feature = "bench-internals"))]
#[inline(always)]
fn plain_direction<T: Real, S: Sample>(sample: &S, map: &Projector<T>) -> Option<([T; 4], T)> {
    let [ux, uy, uz] = map.project(check::<T, S>(sample, None, &Rules::PLAIN).ok()?);
    let q = ux * ux + uy * uy + uz * uz;
    if !(q >= T::MIN_POSITIVE) {
        return None;
    }
    Some(([ux, uy, uz, q.rsqrt()], q))
}

/// `[u, 1/|u|]` of each sample of `chunk` into `out` (zeros for a sample
/// without a direction: dropped by the gate, at the fitted centre, or
/// beyond the pass's limit), the residuals of the rows the gate passes
/// measured into `res`, and the count of the samples with a direction.
/// `prev` is the row before the chunk.
#[inline(never)]
fn directions<T: Real, S: Sample>(
    chunk: &[S],
    prev: Option<&S>,
    map: &Projector<T>,
    pass: &Pass<'_, T>,
    res: &mut Residuals<T>,
    out: &mut [[T; 4]; CHUNK],
) -> usize {
    let mut count = 0;
    let mut last = prev;
    let limit = pass.limit.unwrap_or(T::MAX);
    let mut max = res.max;
    let hist = &mut res.hist;
    for (sample, slot) in chunk.iter().zip(out.iter_mut()) {
        // The gate out of line, as in every gated loop: inlined here (this
        // loop runs at the deepest stack of the robust path) it took 308
        // bytes of flash more (LS9 + ADC2) for 52 bytes of stack less.
        let row = pass.gate.pass(sample, last);
        last = Some(sample);
        *slot = [T::zero(); 4];
        let Some(y) = row else {
            continue;
        };
        let [ux, uy, uz] = map.project(y);
        let q = ux * ux + uy * uy + uz * uz;
        if !(q >= T::MIN_POSITIVE) {
            // At the fitted centre: no direction, residual -1.
            hist.add(T::one());
            max = larger(max, T::one());
            continue;
        }
        let inv = q.rsqrt();
        let r = (q * inv - T::one()).abs();
        hist.add(r);
        max = larger(max, r);
        if r <= limit {
            *slot = [ux, uy, uz, inv];
            count += 1;
        }
    }
    res.max = max;
    count
}

/// Adds the sums of `h = u/|u|` and `g = u - h = e h` over `dirs` (each
/// `[u, 1/|u|]`; zeros add nothing) to `a`. One sample a step: two would
/// not fit the registers.
#[inline(never)]
fn add_directions<T: Real>(a: &mut [T; SUMS], dirs: &[[T; 4]]) {
    let mut s = *a;
    for &[ux, uy, uz, inv] in dirs {
        let (hx, hy, hz) = (ux * inv, uy * inv, uz * inv);
        let (gx, gy, gz) = (ux - hx, uy - hy, uz - hz);
        s[0] += hx;
        s[1] += hy;
        s[2] += hz;
        s[3] += gx;
        s[4] += gy;
        s[5] += gz;
        s[6] += hx * hx;
        s[7] += hx * hy;
        s[8] += hx * hz;
        s[9] += hy * hy;
        s[10] += hy * hz;
        s[11] += hz * hz;
        s[12] += gx * hx;
        s[13] += gx * hy;
        s[14] += gx * hz;
        s[15] += gy * hy;
        s[16] += gy * hz;
        s[17] += gz * hz;
        s[18] += gx * gx;
        s[19] += gx * gy;
        s[20] += gx * gz;
        s[21] += gy * gy;
        s[22] += gy * gz;
        s[23] += gz * gz;
    }
    *a = s;
}

/// The inverse of a 3x3 matrix, or `None` when it is singular to working
/// precision (see [`inverse3`]).
fn inverse<T: Real>(m: &Matrix3<T>) -> Option<Matrix3<T>> {
    // Storage columns read as rows: the inverse of the transpose, read back
    // the same way, is the inverse.
    inverse3(&columns_of(m)).map(from_columns)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::test_support::{stats_by_definition, Rng};

    /// The statistics by their definition, sample by sample:
    /// `d = x - b0`, `u = W0 d`, `h = u/|u|`, `r = d - T0 h`.
    fn by_definition(
        samples: &[[f64; 3]],
        norm: &Normalization<f64>,
        b0: &Vector3<f64>,
        w0: &Matrix3<f64>,
    ) -> Stats<f64> {
        let t0 = w0.try_inverse().unwrap();
        stats_by_definition(samples.iter().filter_map(|y| {
            if !y.iter().all(|v| v.is_finite()) {
                return None;
            }
            let d = norm.forward(*y) - b0;
            let u = w0 * d;
            if u.norm() == 0.0 {
                return None;
            }
            let h = u / u.norm();
            Some((h, d - t0 * h))
        }))
    }

    /// The pass's sums of `h`, `e h` and `e^k h h^T`, mapped through `T0`,
    /// are the statistics of the definition; a non-finite sample and those
    /// at the fitted centre are skipped, at any length of the last chunk.
    #[test]
    fn the_pass_matches_the_definition() {
        let mut rng = Rng(7);
        let norm = Normalization {
            centre: Vector3::new(120.0, -40.0, 15.0),
            scale: 50.0,
            inv_scale: 1.0 / 50.0,
        };
        let b0 = Vector3::new(0.05, -0.02, 0.1);
        let w0 = Matrix3::new(1.1, 0.05, -0.02, 0.05, 0.9, 0.03, -0.02, 0.03, 1.2);
        let t0 = w0.try_inverse().unwrap();
        let mut samples = [[0.0f64; 3]; 300];
        for s in samples.iter_mut() {
            let x = b0 + t0 * (rng.direction() * rng.range(0.9, 1.1));
            let y = norm.point_back(&x);
            *s = [y.x, y.y, y.z];
        }
        samples[5] = [f64::NAN, 1.0, 2.0];
        let centre = norm.point_back(&b0);
        samples[9] = [centre.x, centre.y, centre.z];
        samples[296] = [centre.x, centre.y, centre.z];
        let close = |a: &[f64], b: &[f64]| {
            a.iter()
                .zip(b)
                .all(|(x, y)| (x - y).abs() <= 1e-9 * (1.0 + y.abs()))
        };
        for n in [300, 299, 298, 297] {
            let samples = &samples[..n];
            let got = Stats::accumulate(samples, &norm, &b0, &w0).unwrap();
            let want = by_definition(samples, &norm, &b0, &w0);
            assert_eq!(got.count, n - 3);
            assert_eq!(want.count, n - 3);
            assert!(close(got.s_h.as_slice(), want.s_h.as_slice()));
            assert!(close(got.s_hh.as_slice(), want.s_hh.as_slice()));
            assert!(close(got.s_r.as_slice(), want.s_r.as_slice()));
            assert!(close(got.s_rh.as_slice(), want.s_rh.as_slice()));
            assert!(close(got.s_rr.as_slice(), want.s_rr.as_slice()));
            assert_eq!(got.s_rr, got.s_rr.transpose());
        }
    }

    /// The plain build's one pass gives the statistics of the plain pass
    /// for a plain gate and of the gated pass without a limit otherwise,
    /// to the bit: in `f32`, on clean rows and on rows with glitches (a
    /// zero row, a repeat).
    #[cfg(not(feature = "robust"))]
    #[test]
    fn the_plain_builds_pass_is_the_plain_and_the_gated_one() {
        let mut rng = Rng(11);
        let norm = Normalization {
            centre: Vector3::new(120.0f32, -40.0, 300.0),
            scale: 50.0,
            inv_scale: 1.0 / 50.0,
        };
        let b0 = Vector3::new(0.05f32, -0.02, 0.1);
        let w0 = Matrix3::new(1.1f32, 0.05, -0.02, 0.05, 0.9, 0.03, -0.02, 0.03, 1.2);
        let t0: Matrix3<f32> = w0.try_inverse().unwrap();
        let mut samples = [[0i16; 3]; 700];
        for s in samples.iter_mut() {
            let d = rng.direction() * rng.range(0.9, 1.1);
            let x: Vector3<f32> = b0 + t0 * Vector3::new(d.x as f32, d.y as f32, d.z as f32);
            let y = norm.point_back(&x);
            *s = [y.x, y.y, y.z].map(|v| v.round() as i16);
        }
        let plain = Stats::accumulate(&samples, &norm, &b0, &w0).unwrap();
        let rows = Stats::accumulate_rows(&samples, &norm, &b0, &w0, &Gate::PLAIN).unwrap();
        assert_eq!(rows, plain);
        samples[17] = [0; 3];
        samples[400] = samples[399];
        let gate = Gate::of(Rules::GLITCHES, &crate::Dwell::NONE);
        let pass = Pass {
            gate: &gate,
            runs: &Runs::NONE,
            limit: None,
        };
        let mut res = Residuals::new();
        let gated = AdcPass::run(&samples, &norm, &b0, &w0, &pass, &mut res).unwrap();
        let rows = Stats::accumulate_rows(&samples, &norm, &b0, &w0, &gate).unwrap();
        assert_eq!(rows, gated);
        // The zero row and the repeat dropped.
        assert_eq!(gated.count, 698);
    }

    /// The kurtosis of the plain pass is that of `|u|^2 - 1` computed row
    /// by row, about 3 for Gaussian radial noise and far above it when a
    /// tenth of the rows sits 0.3 off the ellipsoid.
    #[test]
    fn the_plain_pass_measures_the_tails() {
        let mut rng = Rng(11);
        let norm = Normalization {
            centre: Vector3::new(-30.0, 12.0, 5.0),
            scale: 40.0,
            inv_scale: 1.0 / 40.0,
        };
        let b0 = Vector3::new(0.02, 0.01, -0.03);
        let w0 = Matrix3::new(1.05, 0.02, 0.0, 0.02, 0.95, 0.01, 0.0, 0.01, 1.0);
        let t0 = w0.try_inverse().unwrap();
        let mut samples = [[0.0f64; 3]; 2000];
        let mut kurtosis = |displaced: usize, samples: &mut [[f64; 3]]| {
            for (i, s) in samples.iter_mut().enumerate() {
                // Radial noise from a sum of 12 uniforms (nearly Gaussian).
                let g: f64 = (0..12).map(|_| rng.range(-0.5, 0.5)).sum();
                let off = if i % 10 == 0 && i / 10 < displaced {
                    0.3
                } else {
                    0.0
                };
                let x = b0 + t0 * (rng.direction() * (1.0 + 0.01 * g + off));
                let y = norm.point_back(&x);
                *s = [y.x, y.y, y.z];
            }
            let (mut s2, mut s3, mut s4) = (0.0, 0.0, 0.0);
            for s in samples.iter() {
                let x = norm.forward(*s) - b0;
                let e = (w0 * x).norm_squared() - 1.0;
                s2 += e * e;
                s3 += e * e * e;
                s4 += e * e * e * e;
            }
            let n = samples.len() as f64;
            let want = n * s4 / (s2 * s2);
            let want_skew = n.sqrt() * s3 / s2.powf(1.5);
            let (_, got) = Stats::accumulate_plain(samples, &norm, &b0, &w0).unwrap();
            assert!((got.kurtosis - want).abs() < 1e-9 * want, "{got:?} {want}");
            assert!(
                (got.skewness - want_skew).abs() < 1e-9,
                "{got:?} {want_skew}"
            );
            got
        };
        let clean = kurtosis(0, &mut samples);
        assert!((2.6..3.4).contains(&clean.kurtosis), "{clean:?}");
        assert!(clean.skewness.abs() < 0.3, "{clean:?}");
        // Every tenth row 0.3 outside: heavy tails, and all on one side.
        let dirty = kurtosis(200, &mut samples);
        // Beyond the limits of the plain fit's cleanness (only with
        // outlier handling).
        #[cfg(feature = "robust")]
        {
            assert!(
                dirty.kurtosis > crate::tuning::CLEAN_KURTOSIS + 3.0,
                "{dirty:?}"
            );
            assert!(dirty.skewness > crate::tuning::CLEAN_SKEWNESS, "{dirty:?}");
        }
        #[cfg(not(feature = "robust"))]
        assert!(dirty.kurtosis > 3.0 * clean.kurtosis, "{dirty:?}");
    }

    /// The pass fed in slices is the pass run whole: bit for bit when the
    /// slices are whole blocks (each block's sums are added to the total
    /// in the same order), to rounding otherwise; the same rows cut, the
    /// same residuals.
    #[test]
    fn the_pass_in_slices_is_the_pass_run_whole() {
        let mut rng = Rng(3);
        let norm = Normalization {
            centre: Vector3::new(20.0, -10.0, 5.0),
            scale: 30.0,
            inv_scale: 1.0 / 30.0,
        };
        let b0 = Vector3::new(0.01, 0.02, -0.01);
        let w0 = Matrix3::new(1.02, 0.01, 0.0, 0.01, 0.98, 0.02, 0.0, 0.02, 1.0);
        let t0 = w0.try_inverse().unwrap();
        let mut samples = [[0.0f64; 3]; 1000];
        for (i, s) in samples.iter_mut().enumerate() {
            // Every 25th row 0.2 off the ellipsoid: beyond the cut.
            let off = if i % 25 == 0 { 0.2 } else { 0.0 };
            let x = b0 + t0 * (rng.direction() * rng.range(0.99 + off, 1.01 + off));
            let y = norm.point_back(&x);
            *s = [y.x, y.y, y.z];
        }
        let (gate, limit) = (Gate::PLAIN, Some(0.05));
        let pass = Pass {
            gate: &gate,
            runs: &Runs::NONE,
            limit,
        };
        let mut res = Residuals::new();
        let whole = AdcPass::run(&samples, &norm, &b0, &w0, &pass, &mut res).unwrap();
        assert_eq!(whole.count, 1000 - 40);
        let whole_sigma = robust_sigma::<f64>(&res.hist);
        for slice in [128, 256, 37, 1] {
            let mut fed = AdcPass::new(&norm, &b0, &w0, limit);
            for rows in samples.chunks(slice) {
                fed.feed(rows, &gate, &Runs::NONE);
            }
            let got = fed.stats(&w0).unwrap();
            assert_eq!(got.count, whole.count);
            assert_eq!(fed.sigma(), whole_sigma);
            if slice % BLOCK == 0 {
                assert_eq!(got, whole, "slices of {slice}");
            } else {
                let close = |a: &[f64], b: &[f64]| {
                    a.iter()
                        .zip(b)
                        .all(|(x, y)| (x - y).abs() <= 1e-9 * (1.0 + y.abs()))
                };
                assert!(close(got.s_hh.as_slice(), whole.s_hh.as_slice()), "{slice}");
                assert!(close(got.s_rr.as_slice(), whole.s_rr.as_slice()), "{slice}");
                assert!(close(got.s_rh.as_slice(), whole.s_rh.as_slice()), "{slice}");
            }
        }
    }

    #[test]
    fn a_singular_start_is_refused() {
        let norm = Normalization {
            centre: Vector3::zeros(),
            scale: 1.0,
            inv_scale: 1.0,
        };
        let mut samples = [[1.0f64, 1.0, -2.0]; 20];
        for (i, s) in samples.iter_mut().enumerate() {
            s[0] = i as f64;
        }
        let w0 = Matrix3::new(1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0);
        let r = Stats::accumulate(&samples, &norm, &Vector3::zeros(), &w0);
        assert_eq!(r.unwrap_err(), Error::NotAnEllipsoid);
    }
}
