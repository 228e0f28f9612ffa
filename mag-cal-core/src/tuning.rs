//! Every tuning constant of the pipeline, in one place: its value, what it
//! guards, and the measurement that set it (the command that shows it, and
//! the commit where the value was set; `git show COMMIT` has the figures of
//! that day). A constant whose evidence says "an open question" was set by
//! reasoning alone: a measurement that moves it is welcome.
//!
//! What a caller may reasonably set is in [`Thresholds`](crate::Thresholds)
//! (the judging's limits, whose defaults are here) and validated once by
//! [`Thresholds::validate`](crate::Thresholds::validate); the rest is fixed. The
//! robust path's mechanisms and what each buys are in `docs/robustness.md`,
//! section 5 (`cargo xtask ablation`). The background calibrator's own
//! constants are still in `device/background.rs` (`background::RECENT`,
//! `MIN_SIGMA`, ...) and, for its decisions, `judge/background.rs`
//! (`ADOPT_RATIO`, `ADOPT_COVERAGE`, `OFFSETS_ERROR_RATIO`,
//! `OFFSETS_MAX_FIT_ERROR`).

// Without outlier handling (feature `robust` off) the robust path's
// constants are not read.
#![cfg_attr(not(feature = "robust"), allow(dead_code))]

// ---- The plain fit is taken as the robust one (routing) ----

/// A plain fit is taken as the robust one when no row's residual exceeds
/// this many robust standard deviations, in the method's pass and in the
/// final pass. Beyond it a row cannot be Gaussian noise of that sigma
/// (probability 6e-7 a row); below it, the 0/1 weights at
/// [`OUTLIER_CUT`] would leave out rows that move the fit by less than the
/// noise. Clean data then pay no robust pass.
///
/// Set at `6e576de`. Evidence: the clean scenarios and the contamination study, `cargo run --release -p host-tests --bin contamination-table -- 64`; the reasoning above (a Gaussian tail) is the whole case: no other value was measured.
pub const CLEAN_LIMIT: f64 = 5.0;
/// A plain fit is taken as the robust one only when the RMS of its radial
/// residuals is at most this many times their robust sigma: about 1 for
/// Gaussian noise (0.8 for quantisation), more when a share of the rows
/// lies off the ellipsoid. (Residuals at the level of rounding, an RMS
/// below the square root of the type's epsilon, are not judged by it.)
///
/// Set at `12e397e`. Evidence: `cargo run --release -p host-tests --bin contamination-table -- 64` (`heavy-tails` gate in `docs/robustness.md` section 5: without it 2 cells change, 1 target lost).
pub const CLEAN_TAIL: f64 = 1.25;
/// A plain fit is not taken when the kurtosis `n sum e^4 / (sum e^2)^2`
/// of the algebraic residuals `e = |u|^2 - 1` under its LS start (in the
/// method's artificial-data pass) exceeds this: about 3 for Gaussian
/// noise, below 2 for quantisation; 10 % of the rows displaced by 0.3 of
/// the field give about 10. The robust path then starts without the plain
/// method's solve and final pass.
///
/// Set at `04dfd51`. Evidence: `cargo run --release -p host-tests --bin contamination-table -- 64` (`kurtosis-gate`: 2 targets lost without it, and +68 217 instructions on the 10 % kinds).
pub(crate) const CLEAN_KURTOSIS: f64 = 6.0;
/// Nor when the skewness `sqrt(n) sum e^3 / (sum e^2)^(3/2)` of the same
/// residuals is below minus this: a share of the rows pulled inwards, as
/// an axis clipped on some reads pulls them (-1.5 when 30 % of the rows
/// are; the robust path's screening then finds the clip levels). Noise
/// skews the other way (`e = 2 n + n^2` for a radial noise `n`), and so do
/// rows displaced outwards, which the kurtosis sees.
///
/// Set at `d957ec1`. Evidence: `cargo test --release -p host-tests --test robust an_axis_clipped` and `cargo run --release -p host-tests --bin contamination-table -- 64` (`skewness-gate`: 2 targets lost without it).
pub(crate) const CLEAN_SKEWNESS: f64 = 1.0;
/// Nor, for the LS fit alone, when its lack of fit about the mean radial
/// residual ([`Quality::lack_of_fit`](crate::Quality::lack_of_fit) without the common offset, which is
/// the algebraic fit's shrinkage under noise) is significant and exceeds
/// this many fit errors. LS's lack of fit is not judged, as its criterion
/// leaves a pattern under noise; but that pattern grows with the noise, a
/// displaced stretch of rows does not. Measured (f64, LS9): clean
/// scenarios A-G at most 0.17 (200 runs each, E 0.13-0.17, A and C below
/// 0.15); plain LS fits bent by a displaced patch or a moving disturbance
/// (10-30 % of the rows) that passed every other test 0.36 or more, most
/// above 0.44.
///
/// Set at `8c24d1a`. Evidence: `cargo run --release -p host-tests --bin paper-tables` (scenarios A-G) and `cargo run --release -p host-tests --bin contamination-table -- 64`.
pub(crate) const CLEAN_SHAPE: f64 = 0.3;
/// The plain path is not tried when an extreme of an axis is shared by at
/// least this many rows of the subsample (every `k`-th row,
/// [`SUBSAMPLE_ROWS`]) that the scan's rules keep, and by at most half of
/// them: a clip level may lie there (the clip rule drops an extreme that
/// a sixty-fourth of all the rows share), and only screening looks for
/// one. Rows clipped a little inside the sphere (a range that ends just
/// below the field) bend the plain fit without standing out of its
/// residuals: with 2 % of the rows clipped so, the plain fit passed as
/// clean in 4 of 5 runs of the contamination study, with median error
/// ratios of 1.35 / 1.52 to the fit of the clean rows (1.02 / 1.04 with
/// this hint). Of 1000 rows the subsample holds a third. Measured on the
/// study's clean runs (1000 and 600 rows, 415 counts or 52 uT, 1 % noise):
/// 3 rows sent 4 of 128 integer runs past the plain fit, 4 none of 256;
/// every run with 2 % of the rows clipped at one level went to screening,
/// about half of those with 1 %. Cost on a Cortex-M4F: about 47
/// instructions a subsampled row (LS9 + ADC2 at n = 1000: about +15 600).
///
/// Set at `a30678b`. Evidence: `cargo run --release -p host-tests --bin contamination-table -- 64` (`clip-hint`: 3 targets lost without it).
pub(crate) const CLIP_HINT_ROWS: u32 = 4;

// ---- Drop rules ----

/// Rows sharing an axis's extreme value are a clip level when they are at
/// least this share of the rows (and at least [`CLIP_MIN_ROWS`]). One
/// sixty-fourth: on a clean integer recording the extreme of an axis is
/// shared by a few rows at most (a 50-count field, 1000 rows: about 5).
///
/// Set at `8e2075d`. Evidence: `cargo run --release -p host-tests --bin contamination-table -- 64` (`clip-extremes`: 10 targets lost without the clip rule); the value itself was not varied.
pub(crate) const CLIP_SHARE: f64 = 1.0 / 64.0;
/// See [`CLIP_SHARE`].
///
/// Set at `8e2075d`. Evidence: none recorded: the floor keeps a short log's extreme (a few rows by chance) from being a level; an open question.
pub(crate) const CLIP_MIN_ROWS: usize = 5;

// ---- Screening and the crude sphere (`robust::screen`) ----

/// The median centre's histograms (with the candidate clip levels), the
/// median distance, the shell band and the crude start, and the robust LS
/// refits before the last one (which also find the runs of rejected rows,
/// [`crate::robust::runs`]), run on a fixed subsample of about this many rows
/// (every `k`-th row, `k` at least 1). A quantile or the set of outliers
/// is settled as well on a few hundred rows as on all of them, at a
/// fraction of the passes' cost. The bounds of the first median-centre
/// window come from it too; the count that confirms a clip level and the
/// last refit see every row. The median centre's first histogram on every
/// row instead cost about 125 instructions a row on a Cortex-M4F (LS9 +
/// ADC2, n = 1000, a tenth of the rows displaced: 1.74 M -> 1.67 M
/// instructions) and the contamination study's f32 runs silently wrong
/// moved from 15 to 14 of 18 688.
///
/// Set at `ab26f18`. Evidence: `bash firmware-example/bench.sh bench` and `cargo run --release -p host-tests --bin contamination-table -- 64`.
pub(crate) const SUBSAMPLE_ROWS: usize = 256;
/// The median is resolved when the middle half of an axis spans this many
/// bins: its bins are then at most a sixteenth of that axis's
/// inter-quartile range, and the interpolated median is closer still.
///
/// Set at `6e576de`. Evidence: none recorded beyond the resolution argument above; an open question.
pub(crate) const RESOLVED_BINS: usize = 16;
/// Cap on the nested histogram passes.
///
/// Set at `6e576de`. Evidence: a cap, not a tuning: 1-2 passes on data without wild values, 3-4 with values 100 times the field away (the screening's pass counts in `Report::passes`).
pub(crate) const MAX_LEVELS: u32 = 12;
/// Samples farther from the median centre than this many median distances
/// are screened out. A sphere's samples lie at most 1 median distance (plus
/// noise) from its centre, an ellipsoid of axis ratio 4 (the largest
/// distortion accepted) at most 2.
///
/// Set at `6e576de`. Evidence: the geometry argument above (design document section 14); no other value was measured.
pub const SCREEN_RADIUS: f64 = 2.5;
/// The share of the screened samples, closest to the crude sphere, that
/// the crude LS start fits.
///
/// Set at `6e576de`. Evidence: none recorded: the design document's choice (section 14, step 4); an open question.
pub(crate) const CRUDE_SHARE: f64 = 0.7;
/// The algebraic sphere fit that may replace the median centre sees the
/// rows within this many median distances of it: the far side of a sphere
/// whose samples crowd on one side (median distance down to a third of the
/// radius, the median centre near the crowded side) is within 6.
///
/// Set at `8d6a5d3`. Evidence: `cargo test --release -p host-tests --test robust samples_crowded_on_one_side` (fails without re-centring, `docs/robustness.md` 5.4).
pub(crate) const RECENTRE_RADIUS: f32 = 6.0;
/// The algebraic sphere replaces the median centre's only where the
/// median centre is clearly off: its robust shell error is below this
/// fraction of the median centre's, and its ball holds more rows (see
/// [`RECENTRE_MORE_ROWS`]). Elsewhere the median centre's robustness to
/// wild rows is kept.
///
/// Set at `8d6a5d3`. Evidence: as [`RECENTRE_RADIUS`]; with it, no cell of `cargo run --release -p host-tests --bin contamination-table -- 64` changes (`recentre` leave-one-out).
pub(crate) const RECENTRE_GAIN: f64 = 0.5;
/// ... at least `1 / RECENTRE_MORE_ROWS` (a sixteenth) more rows than the
/// median centre's ball: the far side of a sphere that the median
/// centre's ball left out. The algebraic sphere is only fitted when the
/// median centre's ball leaves out that many of the rows within
/// [`RECENTRE_RADIUS`] median distances, which wild rows (beyond that
/// radius) do not: contaminated data with even coverage pay nothing. On a
/// cap, whose rows the median centre's ball holds all of, the median
/// centre stays (the coverage refusal then names the cause).
///
/// Set at `8d6a5d3`. Evidence: as [`RECENTRE_RADIUS`].
pub(crate) const RECENTRE_MORE_ROWS: u32 = 16;

// ---- Robust refits, runs and window starts (`robust::refit`, `robust::runs`, `pipeline::robust`) ----

/// Rows whose residual exceeds this many robust standard deviations get
/// weight 0. Hard 0/1 weights: Tukey's smooth weights took 4 more passes
/// for the same result; a 3-sigma cut cost 2-8 % of the clean accuracy,
/// 3.5 sigma at most 2.2 % (measured in simulation).
///
/// Set at `6e576de`. Evidence: the simulation named above (design document section 14).
pub const OUTLIER_CUT: f64 = 3.5;
/// Cap on the weighted LS refits after the crude start.
///
/// Set at `8e2075d`. Evidence: a cap: `cargo run --release -p host-tests --bin contamination-table -- 64` reports the passes each run takes (`robust passes` of the real recordings: 11-75 in all, refits included).
pub(crate) const REFITS: u32 = 8;
/// A trimmed refit on the subsample keeps at most this share of the rows
/// the gate passes: those with the smallest residuals under the fit
/// before. Measured on the contamination study (f32, 64 runs a cell, every
/// subsample refit trimmed): 0.5 and 0.6 left 68 and 61 of 18 688 runs
/// silently wrong, 0.7 51, 0.8 59 (62 without trimming); trimming the
/// refits on every row as well raised the error ratio at 10 %
/// contamination to 1.3-1.5.
///
/// Set at `8c3e4e4`. Evidence: `cargo run --release -p host-tests --bin contamination-table -- 64` (`trim`: 4 targets lost without the trimmed refits).
pub(crate) const TRIM_SHARE: f64 = 0.7;
/// The trimmed refits on the subsample: the second and the third. Later
/// refits cut at [`OUTLIER_CUT`]` sigma` only, so that the sigma the refits
/// on every row start from is that of an untrimmed fit: a trimmed fit
/// follows its best rows, and on a real recording (`mag3_raw_541.csv`,
/// model error beside the noise) with every subsample refit trimmed its
/// sigma was 0.0115 against 0.0146, and the refits on every row then cut
/// 16 rows instead of 4. One trimmed refit left a patch of 10 % at 94.1 %
/// accepted, two at 98.0 %, three at 98.4 % (one subsample pass more,
/// about 85 k instructions on a Cortex-M4F at n = 1000).
///
/// Set at `eb531f0`. Evidence: `cargo run --release -p host-tests --bin contamination-table -- 64` and `bash firmware-example/bench.sh bench`.
pub(crate) const TRIM_REFITS: u32 = 2;
/// This many consecutive rows with a residual beyond [`STRONG`] times the
/// cut are a run.
///
/// Set at `081c9aa`. Evidence: `cargo run --release -p host-tests --bin contamination-table -- 64` (`runs`: 8 targets lost without the runs); the length itself was not varied.
pub(crate) const RUN_LENGTH: usize = 6;
/// A row counts towards a run when its residual exceeds the cut by this
/// factor (the core of a disturbance, not the edge of a bent fit).
///
/// Set at `081c9aa`. Evidence: as [`RUN_LENGTH`]; the factor itself was not varied.
pub(crate) const STRONG: f64 = 3.0;
/// Rows left out on each side of a run (20 gave the moving disturbance of
/// 10 % ratios of 1.18 / 1.25 and 54 runs silently wrong, 30 1.16 / 1.23
/// and 53).
///
/// Set at `081c9aa`. Evidence: `cargo run --release -p host-tests --bin contamination-table -- 64`.
pub(crate) const MARGIN: usize = 30;
/// The most spans kept. Each span costs 8 bytes in every copy of the
/// spans (the report's [`crate::Selection`], the robust path's weights):
/// with 4, LS9 + ADC2 on contaminated data took 4 108 bytes of stack on a
/// Cortex-M4F, over its 4 KiB budget; with 2, 4 076.
///
/// Set at `205e9b5`. Evidence: `bash firmware-example/bench.sh footprint` (the stack figure).
pub const RUNS: usize = 2;
/// The window starts ([`window`](crate::robust::refit::window)): start `k = 1..=STARTS` leaves out half
/// of the rows, from `(k - 1) n / STARTS` on (wrapping at the end). A
/// disturbance that lasts less than a quarter of the recording lies wholly
/// in one window, one of up to 30 % mostly. Measured on the contamination
/// study (f64, 256 runs a cell, every robust run with window starts, in
/// an earlier form): four windows left a 30 % patch 5 of 256 runs silently
/// wrong, eight windows 6, six 6, and four windows leaving out a quarter
/// each 11.
///
/// Set at `174f1b3`. Evidence: `cargo run --release -p host-tests --bin contamination-table -- 64` (`windows`: 14 targets lost without the window starts).
pub(crate) const STARTS: usize = 4;
/// The result of the robust path is in doubt when its lack of fit exceeds
/// this (0.4 of the default refusal limit,
/// [`REFUSE_LACK_OF_FIT`]), or when it is refused for too many
/// outliers or as a systematic misfit: the robust LS may have settled on a
/// compromise that a long disturbance bent. The path then tries the window
/// starts ([`Report::start`](crate::Report::start)). Measured on the contamination study
/// (f32, 256 runs a cell): 0.003 and 0.004 left 22 of 18 688 runs silently
/// wrong, 0.005 24 (53 without the window starts); of the accepted fits
/// with a tenth of the rows displaced as a patch or by a moving
/// disturbance 1-2 % exceed 0.003, the other kinds none. Real recordings
/// with some model error lie near it (lack of fit 0.003-0.006): at 0.003
/// `mag3_raw_541.csv` (0.0032) and `imu_gnss_1252.csv` (0.0031) were in
/// doubt too, and with a magnet passing the first (a CLI test) a window
/// start that scored a few percent better left the hard iron 0.8 % of the
/// field (28 counts) from the fit of the clean rows, against 0.02 %.
///
/// Set at `174f1b3`. Evidence: `cargo run --release -p host-tests --bin contamination-table -- 64`.
pub(crate) const DOUBT_LACK_OF_FIT: f64 = 0.004;
/// Among the window starts of a result in doubt, a start whose fit leaves
/// out more than [`Thresholds::refuse_outlier_share`](crate::Thresholds::refuse_outlier_share) of the rows is
/// preferred to the best-scoring one when its score (the median residual)
/// is within this factor of the best: a displaced third of the recording
/// lets the robust LS either leave it out (and then the result is refused
/// for too many outliers) or bend into a compromise whose residuals spread
/// over every row, with a median as low. Measured on the contamination
/// study (f32, 256 runs a cell): with a third of the rows displaced as a
/// patch the compromise left 12 runs accepted and silently wrong, 2 with
/// this preference (the others refused, too many outliers); in all, 22 of
/// 18 688 runs were silently wrong before it and 12 after, and no cell up
/// to a fifth of the rows changed. 1.1 left 17 of them, 1.5 as 1.25, and 2
/// refused 2 % of the runs with a fifth of the rows displaced as a patch.
///
/// Set at `0a96b39`. Evidence: `cargo run --release -p host-tests --bin contamination-table -- 64` (`ambiguous-score`: 3 targets lost without it).
pub(crate) const AMBIGUOUS_SCORE: f64 = 1.25;

// ---- Lack of fit (`steps::final_pass`) ----

/// Direction cells of the lack-of-fit figure: the 6 faces of the cube
/// around the unit sphere, each cut in 4 by the signs of the two other
/// components.
///
/// Set at `6e576de`. Evidence: none recorded: the cube's 24 face quarters are the design's choice; an open question.
pub(crate) const LOF_CELLS: usize = 24;
/// Cells with fewer rows than this do not enter the lack-of-fit figure.
///
/// Set at `6e576de`. Evidence: none recorded; an open question.
pub(crate) const LOF_MIN_ROWS: u32 = 5;
/// The cell means are significantly off zero when `sum_c n_c m_c^2 /
/// sigma^2 / cells` (about 1 for noise) exceeds this.
///
/// Set at `8e2075d`. Evidence: none recorded beyond the noise argument above (about 1 for noise); an open question.
pub(crate) const LOF_SIGNIFICANCE: f64 = 3.0;

// ---- Defaults of the judging (`Thresholds::DEFAULT`; a caller sets its own in `Config::thresholds`) ----

/// Fewer samples than this: [`Warning::FewSamples`](crate::Warning::FewSamples).
///
/// Set at `bf4f7d4`. Evidence: none recorded: a warning only; an open question.
pub(crate) const WARN_SAMPLES: usize = 50;
/// Flatness below this: [`Error::Planar`](crate::Error::Planar). A single planar circle gives
/// 0.004 and the real nearly planar recording `planar_243.txt` 0.010; a
/// +-10 deg band 0.02 (also refused by coverage); a +-30 deg band 0.18
/// (0.10-0.15 after the simulated test scenarios' distortions).
///
/// Set at `bf4f7d4`. Evidence: `cargo test --release -p host-tests --test degenerate` and the real recording `planar_243.txt`.
pub(crate) const REFUSE_FLATNESS: f64 = 0.03;
/// Flatness below this: [`Warning::NearlyPlanar`](crate::Warning::NearlyPlanar).
///
/// Set at `bf4f7d4`. Evidence: none recorded: a warning only, between the refusal and a +-30 deg band's 0.10-0.18.
pub(crate) const WARN_FLATNESS: f64 = 0.1;
/// Quadric gap below this, on data that fit their ellipsoid to within
/// [`GAP_NOISE_LIMIT`]: [`Error::AmbiguousQuadric`](crate::Error::AmbiguousQuadric).
///
/// Measured (a simulated sensor with a tilted soft iron, 1000 samples, 20
/// runs each): two orthogonal great circles give gaps of 1.8-2.5 at every
/// noise level (0.3 %, noise A, noise B) and errors in `M` of 18-22 %:
/// a second quadric fits as well as the first, whatever the noise, so the
/// fit is nonsense. A +-30 deg band gives 860 at 0.3 % noise, 22 at noise A
/// (errors 0.7 % and 3.7 %) but 2.5 at noise B (16 %): a well-posed
/// geometry's gap falls as 1/noise^2, an ambiguous one's does not. A gap
/// below 3 is conclusive only when the noise is small; see
/// [`GAP_NOISE_LIMIT`].
///
/// Set at `bf4f7d4`. Evidence: `cargo test --release -p host-tests --test degenerate`.
pub(crate) const REFUSE_QUADRIC_GAP: f64 = 3.0;
/// Radial RMS below which a small quadric gap refuses the fit. Above it,
/// noise alone compresses the gap of good geometry below 3 (the design
/// document's scenario D, a band with 5-10 % noise and radial RMS 0.068,
/// must calibrate), and the gap only warns. Real sensors here fit with
/// radial RMS 0.003-0.027.
///
/// Set at `bf4f7d4`. Evidence: `cargo run --release -p host-tests --bin paper-tables` (scenario D) and the real recordings.
pub(crate) const GAP_NOISE_LIMIT: f64 = 0.05;
/// Quadric gap below this: [`Warning::WeakQuadric`](crate::Warning::WeakQuadric).
///
/// Set at `bf4f7d4`. Evidence: none recorded: a warning only; an open question.
pub(crate) const WARN_QUADRIC_GAP: f64 = 10.0;
/// Condition of `M` above this: [`Error::ExtremeDistortion`](crate::Error::ExtremeDistortion). It is an
/// axis ratio of 4; magnetometer soft iron and scale errors stay within a
/// few tens of percent (the simulated test scenarios: 2.7).
///
/// Set at `bf4f7d4`. Evidence: `cargo test --release -p host-tests --test degenerate`.
pub(crate) const REFUSE_DISTORTION: f64 = 16.0;
/// Coverage below this: [`Error::PoorCoverage`](crate::Error::PoorCoverage). Full sphere 0.31-0.33,
/// +-30 deg band 0.085, +-10 deg band 0.02, a 45 deg cap 0.03 (which passes
/// every algebraic check yet fits a sphere 0.67x too small).
///
/// Set at `bf4f7d4`. Evidence: `cargo test --release -p host-tests --test degenerate`.
pub(crate) const REFUSE_COVERAGE: f64 = 0.05;
/// Gram condition above this: [`Warning::WeakCoverage`](crate::Warning::WeakCoverage) (full sphere about
/// 3, +-30 deg band about 12; the accuracy of every method degrades on
/// partial coverage).
///
/// Set at `bf4f7d4`. Evidence: `cargo test --release -p host-tests --test degenerate` (a warning only).
pub(crate) const WARN_GRAM_CONDITION: f64 = 20.0;
/// Relative deviation of the field strength from an expected value above
/// which the fit is refused ([`Error::FieldStrengthMismatch`](crate::Error::FieldStrengthMismatch)).
///
/// Set at `bf4f7d4`. Evidence: none recorded: only judged when the caller gives an expected field; an open question.
pub(crate) const REFUSE_FIELD_DEVIATION: f64 = 0.25;
/// Spread below this many noise standard deviations:
/// [`Warning::LowSpread`](crate::Warning::LowSpread).
///
/// Set at `bf4f7d4`. Evidence: none recorded: a warning only; an open question.
pub(crate) const WARN_SPREAD_OVER_NOISE: f64 = 10.0;
/// Fit error above this: [`Warning::HighFitError`](crate::Warning::HighFitError).
///
/// Set at `6e576de`. Evidence: none recorded for the warning itself; it also gates [`REFUSE_SKEWNESS`].
pub(crate) const WARN_FIT_ERROR: f64 = 0.05;
/// Fit error above this: [`Error::NoSphere`](crate::Error::NoSphere). Measured in simulation
/// (5th-95th percentiles): noise of 10-20 % per axis 0.13-0.16, isotropic 20 %
/// noise on a real sphere 0.18-0.19; a filled ball 0.24-0.27, a cube
/// 0.28-0.30, a stationary device or a blob 0.37-0.44.
///
/// Set at `6e576de`. Evidence: `cargo test --release -p host-tests --test robust what_is_not_a_sphere` and `cargo run --release -p host-tests --bin contamination-table -- 64` (the degenerate cells).
pub(crate) const REFUSE_FIT_ERROR: f64 = 0.20;
/// Share of rows not used above this (not counting the rows beside a run
/// within the cut, [`crate::robust::runs`]): [`Error::TooManyOutliers`](crate::Error::TooManyOutliers).
///
/// Set at `6e576de`. Evidence: `cargo run --release -p host-tests --bin contamination-table -- 64`: the 20-30 % cells refuse with this cause.
pub(crate) const REFUSE_OUTLIER_SHARE: f64 = 0.25;
/// Lack of fit above this (1 % of the field), significant against the
/// noise: [`Error::SystematicMisfit`](crate::Error::SystematicMisfit). Measured on a simulated
/// contamination study: fits that a displaced patch or a moving
/// disturbance bent to `e_M` above 0.05 have 0.006-0.04; accepted good fits
/// of the same data 0.002-0.012; real recordings 0.003-0.011 with the plain
/// fit, 0.003-0.005 with outlier handling.
///
/// Set at `8e2075d`. Evidence: `cargo run --release -p host-tests --bin contamination-table -- 64` (`misfit-gate`: 11 targets lost without it).
pub(crate) const REFUSE_LACK_OF_FIT: f64 = 0.01;
/// Skewness of the radial residuals below this, with a fit error above
/// [`WARN_FIT_ERROR`]: [`Error::FilledCloud`](crate::Error::FilledCloud) (outlier handling only). The
/// rows of a filled ball lie inside the shell that fits its outer rows, and
/// an ellipsoid fit of it can keep its fit error just under
/// [`REFUSE_FIT_ERROR`]: the LS fit alone did so in 4 of 256 runs of the
/// contamination study (fit error 0.189-0.200, skewness -0.72 to -0.85 in
/// 24 such runs of 1024). Noise on a shell leaves the residuals nearly
/// symmetric: the clean scenarios A-G (100 runs each, LS and ADC2) -0.38 at
/// the lowest, with fit errors up to 0.166; of 4 267 contaminated runs
/// accepted with a fit error below the warning, a few reached -0.70 (a
/// fifth of the rows clipped at a lower level), none with a fit error
/// above it.
///
/// Set at `6dce5c1`. Evidence: `cargo run --release -p host-tests --bin contamination-table -- 64` (`filled-cloud`: 1 target lost without it).
pub(crate) const REFUSE_SKEWNESS: f64 = -0.6;

// ---- Iterated ADC2 (`steps::methods::adc2_iter`) ----

/// Anderson mixing `beta`: the step without history is `x + beta (g(x) - x)`.
///
/// The map's Jacobian at the fixed point, measured by finite differences,
/// has eigenvalues 0.58-0.70 on a full sphere (scenarios A, B, E), 0.49-0.93
/// on a +-30 deg band (D), and one 0. Plain steps (`beta = 1`) contract the
/// cluster by only 0.6-0.7, and Anderson's first steps are plain steps (its
/// first difference, from the LS fit to one-step ADC2, carries no useful
/// secant). With `beta = 1.8` the mixing step contracts the cluster to
/// 0.46 or less and the zero-eigenvalue direction by `|1 - beta| = 0.8`;
/// any `beta < 2` keeps every eigenvalue in `[0, 1)` contracting.
/// Median passes over scenarios A-G (50 runs each, f64), `beta` = 1 / 1.8:
/// 6/7/7/11/9/7/11 and 5/7/7/10/8/7/9 (plain iteration: 15/21/68/83/24/20/77).
///
/// Set at `c6c0074`. Evidence: `cargo run --release -p host-tests --bin paper-tables` (passes per scenario).
#[cfg(feature = "adc2-iter")]
pub(crate) const MIXING: f64 = 1.8;
/// Anderson memory.
///
/// Set at `21e77b4`. Evidence: none recorded: Anderson(5) as first written; an open question.
#[cfg(feature = "adc2-iter")]
pub(crate) const MEMORY: usize = 5;

// ---- The collector's sphere fit (`numerics::sphere`) ----

/// Weight `delta` of the midrange prior in the centre solve: `mu = delta
/// trace(C) / 3`.
///
/// Set at `2930d02`. Evidence: none recorded: it only keeps the collector's centre solve regular on few directions; an open question.
pub(crate) const PRIOR_WEIGHT: f32 = 0.001;

// ---- Still periods (`steps::dwell`, issue 36) ----

/// Weight of the newest row in the moving average of the local noise (the
/// mean absolute second difference over the axes): about the last 16
/// rows. Guards: the noise of the still period itself, not of the motion
/// before it, sets the radius of its run.
///
/// Set at `1e1b99f` (branch `still`, a host prototype, not on main).
/// Today's rule checked by `cargo test --release -p host-tests --test
/// still_periods -- --nocapture` (worst b 0.199 %, field 0.057 %, M
/// 0.415 %). The prototype's evidence:
/// `LOCAL=1 L0=16 K0=4 SHARE=48 cargo run --release -p host-tests --bin
/// still-probe -- 6 runs` on the shared recordings with still ends of
/// 0.5x-10x the motion, noise 1 count to 3 % of the field: no refusal, b
/// within 0.31 %, field strength 0.26 %, M 1.06 % of the fit without them;
/// a global noise (the median second difference) was not varied further.
pub(crate) const DWELL_EMA: f64 = 1.0 / 16.0;
/// A row's mean absolute second difference enters the noise's average
/// only below this many times the average (above, a spike's rows or the
/// start of motion: the average is left as it is). Guards: spikes do not
/// inflate the radius of the rows after them, which then formed one long
/// run of motion set aside as still (the contamination table's spike
/// cells: median error ratios 1.00 -> 1.19-1.32 without any clip; with the
/// second difference clipped to 4 averages instead of skipped, spikes at
/// 5-10 % still raised the noise without bound: NoSphere in 1.6-2.0 % of
/// the runs).
///
/// Set with issue 36's core rule. Evidence: `cargo run --release -p
/// host-tests --bin contamination-table -- 64`; 4 alone tried.
pub(crate) const DWELL_CLIP: f64 = 4.0;
/// The mean absolute second difference `x[i] - 2 x[i-1] + x[i-2]` of white
/// noise of standard deviation 1: `sqrt(6) sqrt(2 / pi)`. Guards: the
/// local noise in units of the noise's standard deviation.
///
/// Set at `1e1b99f`: by derivation, not by measurement.
pub(crate) const DWELL_NOISE: f64 = 1.955;
/// A row farther than this many local sigmas (Euclidean) from the mean of
/// the run so far starts a new run. Guards: noise does not break a still
/// period (a 3-D Gaussian row beyond 6 sigma: 1e-7), and a device that
/// moves by more than the noise between rows is not still.
///
/// Set at `1e1b99f` with the prototype of [`DWELL_EMA`] (its `still-probe`
/// command: radius 6 its first argument; 4 split the noisier still ends);
/// today's rule checked as [`DWELL_EMA`].
pub(crate) const DWELL_RADIUS: f64 = 6.0;
/// A run of at least this many rows is a still period. Guards: a slow
/// turn's runs of a few rows are not set aside (every shared recording as
/// it is: none set aside).
///
/// Set at `1e1b99f` with the prototype of [`DWELL_EMA`] (`L0=16`; its
/// `still-stats` command gave the runs of the shared recordings); today's
/// rule checked as [`DWELL_EMA`] (none of a recording as it is set aside).
pub(crate) const DWELL_MIN_RUN: usize = 16;
/// A run is a still period only when it holds at least a `DWELL_SHARE`-th
/// of the recording's rows. Guards: a short pause in a long recording,
/// which weighs little, keeps its rows (`imu_gnss_1252.csv` as it is: a
/// still start of 80 rows, 6.4 %, beyond the 5 % a recording as it is may
/// lose); still periods that outweigh a tenth of the rows are set aside.
///
/// Set with issue 36's ball rule (branch `core-dwell`). Evidence: `cargo
/// test --release -p host-tests --test still_periods -- --nocapture`: no
/// row of a shared recording as it is set aside; still ends of 0.5x-10x
/// at one count to 3 % noise: worst b 0.199 %, field 0.057 %, M 0.415 %
/// of the field. (With `3 max(4, n / 64)`, the old span rule's threshold,
/// the 80 rows of `imu_gnss_1252.csv` were set aside.)
pub(crate) const DWELL_SHARE: usize = 10;
/// A run is a still period only when its radius is at most this many
/// times the spread of the rows (their RMS distance from their mean).
/// Guards: rows out of time order (shuffled or interleaved), whose second
/// differences are as large as their spread (radius about 3.5 spreads):
/// every row would lie in one run; and contaminated rows whose noise is
/// inflated (displaced rows). Still ends of 10x the motion at 3 % noise:
/// about 0.6 spreads at worst, 0.2-0.4 mostly.
///
/// Set with issue 36's first (span) rule at `89d7ee4`, by `cargo run
/// --release -p host-tests --bin contamination-table -- 64`: robust ADC2
/// f32 runs silently wrong 15 (main) -> 55 at 1.0 (displace-1 20-30 %),
/// 28 at 0.5, 19 at 0.35, 16 at 0.25; and `cargo test --release -p
/// host-tests --test still_periods`: passes at 0.35 and above, at 0.25
/// `icm20948_mag_300.csv` with still ends of 5x at 3 % noise is refused
/// (NoSphere 0.43). With today's ball rule at 0.35 every robust count of
/// the contamination table equals main's (silently wrong 15/16, 11/9,
/// 15/16; `core-dwell` `c800cd3`).
pub(crate) const DWELL_SCALE: f64 = 0.35;
