//! `magcal background`: replays a log through the core's background
//! calibrator ([`mag_cal_core::background::Background`]) to show what it
//! would do with the data, short of writing firmware.
//!
//! Each row is [`Background::push`]ed in file order, then
//! [`Background::step`] is called `--steps` times (once by default, as the
//! firmware example `src/bin/background.rs` and the host study do: at most
//! one slice of 32 buffered samples of work a reading). After the last row
//! the work under way is finished (steps until the calibrator is idle), as
//! the steps of the readings that would follow would finish it.

use std::fmt::Write as _;
use std::io::Write;

use mag_cal_core::background::{Background, BackgroundConfig, Pushed, Stepped, CELLS};
use mag_cal_core::{Error, Real, Sample};
use serde::Serialize;

use crate::cli::{BackgroundArgs, Format, Precision};
use crate::error::CliError;
use crate::fit::{counts, spread, Parameters, Quality};
use crate::input::{self, Source};
use crate::output::{self, sig};

/// Samples a direction cell holds: 48 cells of 6 (288 samples), as the
/// firmware example and the host study (`host-tests/src/background.rs`).
pub const CELL_SAMPLES: usize = 6;

/// Buffered samples: [`CELLS`] cells of [`CELL_SAMPLES`].
pub const CAPACITY: usize = CELLS * CELL_SAMPLES;

/// The calibrator replayed, in precision `T`, on samples `S`.
type Calibrator<T, S> = Background<T, S, CAPACITY, CELL_SAMPLES>;

/// Steps after the last row before the replay gives up finishing the work
/// under way. A refit of a full buffer takes about 50 steps (five passes
/// of nine slices and the solves), and one can start another: a cap far
/// above any finish, which only an endless loop would reach.
const FINISH_STEPS: usize = 10_000;

/// Rows named in a list of rows the calibrator set aside (the count is
/// always complete).
const ROWS_NAMED: usize = 5;

/// What the replay saw and did: the JSON report (`--format json`), in field
/// order, and the text report's content.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Replay {
    /// `f32` or `f64`: the calibrator's precision.
    pub precision: &'static str,
    /// Buffered samples the calibrator holds at most.
    pub capacity: usize,
    /// Calls of `step` after each push.
    pub steps_per_reading: u32,
    /// Rows replayed.
    pub rows: usize,
    /// What `push` did with the rows.
    pub readings: Readings,
    /// The row after whose push (and steps) the first calibration was
    /// adopted.
    pub first_calibration: Option<usize>,
    /// Every adoption, in order.
    pub adoptions: Vec<Adoption>,
    /// Full refits.
    pub refits: Refits,
    /// Offsets-only re-estimates (tried when the calibration in use was
    /// stale).
    pub offsets_only: OffsetsOnly,
    /// Rows at which the calibration in use became stale (the residuals
    /// had risen for `stale_readings` readings).
    pub stale_from: Vec<usize>,
    /// Buffered samples dropped after a new hard iron.
    pub purged: u32,
    /// Steps taken after the last row to finish the work under way.
    pub steps_after_end: usize,
    /// The buffer at the end.
    pub buffer: Buffer,
    /// The calibration in use at the end, with `fit`'s fields; `null` when
    /// none was adopted.
    #[serde(rename = "final")]
    pub final_calibration: Option<Final>,
    /// Why there is no calibration (`null` when there is one).
    pub reason: Option<String>,
    /// The calibrator's configuration (not in the JSON report).
    #[serde(skip)]
    pub config: BackgroundConfig,
}

/// What [`Background::push`] did with the rows.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct Readings {
    /// Buffered.
    pub stored: usize,
    /// Not buffered: too close in direction to the last buffered reading
    /// (still used to watch the calibration).
    pub too_close: usize,
    /// Not buffered, before the first calibration: the device lay within
    /// the sensor's noise of the running centre (lying still).
    pub still: usize,
    /// Not buffered: a glitch (a zero row, a component on the rails),
    /// not finite, or beyond the working precision.
    pub invalid: usize,
    /// The first of the invalid rows.
    pub invalid_rows: Vec<usize>,
    /// Not buffered: far off the calibrated sphere (before the first
    /// calibration, off the running sphere fit).
    pub wild: usize,
    /// The first of the wild rows.
    pub wild_rows: Vec<usize>,
}

/// One adoption: a calibration the calibrator put in use.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Adoption {
    /// The row after whose push (and steps) it was adopted; the last row
    /// when it was adopted after the end (`after_end`).
    pub row: usize,
    /// Adopted by the steps that finished the work under way after the
    /// last row.
    pub after_end: bool,
    /// `refit` (a full refit of the buffer) or `offsets` (the hard iron
    /// alone re-estimated from the recent readings, the calibration being
    /// stale).
    pub kind: &'static str,
    /// The hard iron adopted, sensor units.
    pub hard_iron: [f64; 3],
    /// Its field strength, sensor units.
    pub field_strength: f64,
    /// `b` minus that of the calibration before (`null` for the first).
    pub hard_iron_change: Option<[f64; 3]>,
    /// `|b - b_before|` over the new field strength (`null` for the first).
    pub hard_iron_change_of_field: Option<f64>,
    /// Relative change of the field strength (`null` for the first).
    pub field_strength_change: Option<f64>,
    /// Robust fit error on the buffer, units of the field (after an
    /// offsets-only fit: the larger of its fit error on the recent readings
    /// and that of the refit before).
    pub fit_error: f64,
    /// RMS radial residual of the refit on its buffer (after an
    /// offsets-only fit: that of the refit before).
    pub radial_rms: f64,
    /// Coverage of the refit's directions (`lambda_min`; after an
    /// offsets-only fit, that of the refit before).
    pub coverage: f64,
    /// Lack of fit of the refit.
    pub lack_of_fit: f64,
    /// The refit's warnings (names).
    pub warnings: Vec<&'static str>,
    /// The same warnings for people, each with the figure and the limit
    /// that raised it ([`warning_texts`]).
    #[serde(skip)]
    pub warning_texts: Vec<String>,
    /// Buffered samples then.
    pub buffered: usize,
    /// Direction cells holding samples then.
    pub cells: usize,
}

/// Refits and their outcomes.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct Refits {
    /// Refits that ended: adopted, kept or refused.
    pub run: u32,
    /// Adopted.
    pub adopted: u32,
    /// Passed every check but did not fit the buffer better than the
    /// calibration in use, which stayed.
    pub kept: u32,
    /// Refused, by reason.
    pub refused: Vec<Refusal>,
}

/// Offsets-only fits and their outcomes.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct OffsetsOnly {
    /// Adopted.
    pub adopted: u32,
    /// Refused, by reason.
    pub refused: Vec<Refusal>,
}

/// Refusals of one kind.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Refusal {
    /// The core's reason, with the figures of the last such refusal.
    pub reason: String,
    /// How many.
    pub count: usize,
    /// The row of the first.
    pub first_row: usize,
    /// The row of the last.
    pub last_row: usize,
    /// The core's error (for grouping; not printed).
    #[serde(skip)]
    error: Error,
}

/// The buffer at the end.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct Buffer {
    /// Buffered samples.
    pub samples: usize,
    /// Direction cells holding samples (of 48).
    pub cells: usize,
}

/// The final calibration: `fit`'s JSON fields of a calibration.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Final {
    /// `f32` or `f64`.
    pub precision: &'static str,
    /// `hard_iron`, `soft_iron`, `field_strength`.
    #[serde(flatten)]
    pub parameters: Parameters,
    /// The figures of the refit that produced it (`fit_error`: that of the
    /// calibration in use, see [`Adoption::fit_error`]; `norm_spread`: over
    /// the samples buffered at the end).
    pub quality: Quality,
    /// The row it was adopted at.
    pub row: usize,
    /// `refit` or `offsets`.
    pub kind: &'static str,
}

/// Runs `magcal background`, writing the report to `out`.
///
/// Without a calibration at the end, the report is written and the error
/// returned is [`CliError::NotCalibrated`] (exit 3).
pub fn run(args: &BackgroundArgs, out: &mut dyn Write) -> Result<Vec<String>, CliError> {
    let source = Source::from_arg(&args.file);
    let table = input::parse(&source.read()?, args.columns.as_ref(), &source.name())?;
    let skipped = table.skipped.note();
    let replay = replay(&table.samples, args.precision, args.steps);
    let report = match args.format {
        Format::Text => text(
            &replay,
            &source.name(),
            &table.columns.to_string(),
            skipped.as_deref(),
        ),
        Format::Json => json(&replay),
    };
    out.write_all(report.as_bytes())
        .and_then(|()| out.flush())
        .map_err(CliError::Write)?;
    if let Some(reason) = &replay.reason {
        return Err(CliError::NotCalibrated(reason.clone()));
    }
    let json = args.format == Format::Json;
    Ok((json && table.columns.detected())
        .then(|| format!("columns {}", table.columns))
        .into_iter()
        .chain(skipped.filter(|_| json).map(|s| format!("input: {s}")))
        .collect())
}

/// Replays `samples` in `precision`, `steps` steps a reading. Integer
/// counts of an i16 sensor are pushed as such (so that the rails rule
/// sees them), as `magcal fit` calibrates them.
pub fn replay(samples: &[[f64; 3]], precision: Precision, steps: u32) -> Replay {
    let ints = counts(samples);
    match (precision, &ints) {
        (Precision::F32, Some(ints)) => replay_in::<f32, _>(ints, precision, steps),
        (Precision::F32, None) => replay_in::<f32, _>(samples, precision, steps),
        (Precision::F64, Some(ints)) => replay_in::<f64, _>(ints, precision, steps),
        (Precision::F64, None) => replay_in::<f64, _>(samples, precision, steps),
    }
}

/// The replay in precision `T` on samples `S`.
fn replay_in<T: Real, S: Sample>(samples: &[S], precision: Precision, steps: u32) -> Replay {
    let config = BackgroundConfig::DEFAULT;
    // About 10 KB for f64 samples: on the heap.
    let mut bg: Box<Calibrator<T, S>> =
        Box::new(Background::new(config).expect("the default configuration is valid"));
    let mut log = Log::default();
    for (row, sample) in samples.iter().enumerate() {
        let pushed = bg.push(*sample);
        log.pushed(row, pushed);
        // The watch moves with the push; the step after may end it (an
        // offsets-only fit adopted).
        if bg.is_stale() && !log.stale {
            log.stale_from.push(row);
        }
        for _ in 0..steps {
            let stepped = bg.step();
            log.stepped(&bg, row, stepped, false);
        }
        log.stale = bg.is_stale();
    }
    let last = samples.len().saturating_sub(1);
    let mut after_end = 0;
    while after_end < FINISH_STEPS {
        let stepped = bg.step();
        if stepped == Stepped::Idle && !bg.is_working() {
            break;
        }
        after_end += 1;
        log.stepped(&bg, last, stepped, true);
    }
    let counters = bg.counters();
    let final_calibration = bg.current().map(|current| {
        let cal = &current.calibration;
        let norms = bg.samples().iter().map(|s| {
            let u = cal.apply(*s);
            (u[0] * u[0] + u[1] * u[1] + u[2] * u[2]).sqrt().to_f64()
        });
        let mut quality = Quality::from_core(
            &current.quality,
            current.radial_rms,
            spread(norms),
            current.warnings,
        );
        quality.fit_error = current.fit_error.to_f64();
        quality.warning_texts = warning_texts(current);
        let (row, kind) = log
            .adoptions
            .last()
            .map_or((last, "refit"), |a| (a.row, a.kind));
        Final {
            precision: precision.name(),
            parameters: Parameters::of(cal),
            quality,
            row,
            kind,
        }
    });
    let reason = final_calibration.is_none().then(|| {
        not_calibrated(
            &config,
            &log.refits.refused,
            &log.readings,
            bg.samples().len(),
            bg.cells_filled(),
        )
    });
    Replay {
        precision: precision.name(),
        capacity: CAPACITY,
        steps_per_reading: steps,
        rows: samples.len(),
        readings: log.readings,
        first_calibration: log.first,
        adoptions: log.adoptions,
        refits: Refits {
            run: log.refits.adopted
                + log.refits.kept
                + log
                    .refits
                    .refused
                    .iter()
                    .map(|r| r.count as u32)
                    .sum::<u32>(),
            ..log.refits
        },
        offsets_only: log.offsets,
        stale_from: log.stale_from,
        purged: counters.purged,
        steps_after_end: after_end,
        buffer: Buffer {
            samples: bg.samples().len(),
            cells: bg.cells_filled(),
        },
        final_calibration,
        reason,
        config,
    }
}

/// Why a replay ended without a calibration: the refusals, or what a
/// first refit still lacked; and the wild readings, which were not
/// buffered.
fn not_calibrated(
    config: &BackgroundConfig,
    refused: &[Refusal],
    readings: &Readings,
    buffered: usize,
    cells: usize,
) -> String {
    let rows =
        readings.stored + readings.too_close + readings.still + readings.invalid + readings.wild;
    let mut reason = match refused.iter().max_by_key(|r| r.last_row) {
        Some(last) => {
            let count: usize = refused.iter().map(|r| r.count).sum();
            let refits = if count == 1 { "refit" } else { "refits" };
            format!(
                "{count} {refits} refused, the last at row {}: {}",
                last.last_row, last.error
            )
        }
        None => format!(
            "no refit ran in {rows} rows: a refit needs {} buffered samples in {} of the \
             {CELLS} direction cells, and the readings gave {buffered} in {cells} (turn the \
             device through more orientations, or record longer)",
            config.refit_after.max(mag_cal_core::MIN_SAMPLES),
            config.min_cells,
        ),
    };
    if readings.wild > 0 {
        let _ = write!(
            reason,
            "; {} readings {} were not buffered as wild: farther than {} radii from the \
             sphere fitted to the readings buffered before",
            readings.wild,
            row_list(&readings.wild_rows, readings.wild),
            mag_cal_core::collector::OUTLIER_RADII
        );
    }
    reason
}

/// What the replay collects as it goes.
#[derive(Default)]
struct Log {
    readings: Readings,
    first: Option<usize>,
    adoptions: Vec<Adoption>,
    refits: Refits,
    offsets: OffsetsOnly,
    stale_from: Vec<usize>,
    stale: bool,
}

impl Log {
    fn pushed(&mut self, row: usize, pushed: Pushed) {
        let r = &mut self.readings;
        match pushed {
            Pushed::Stored => r.stored += 1,
            Pushed::TooClose => r.too_close += 1,
            Pushed::Still => r.still += 1,
            Pushed::Invalid => {
                r.invalid += 1;
                if r.invalid_rows.len() < ROWS_NAMED {
                    r.invalid_rows.push(row);
                }
            }
            // `Wild`, and any outcome a later core adds: not buffered.
            _ => {
                r.wild += 1;
                if r.wild_rows.len() < ROWS_NAMED {
                    r.wild_rows.push(row);
                }
            }
        }
    }

    fn stepped<T: Real, S: Sample>(
        &mut self,
        bg: &Calibrator<T, S>,
        row: usize,
        stepped: Stepped,
        after_end: bool,
    ) {
        match stepped {
            Stepped::Adopted => {
                self.refits.adopted += 1;
                self.first.get_or_insert(row);
                self.adopted(bg, row, "refit", after_end);
            }
            Stepped::OffsetsAdopted => {
                self.offsets.adopted += 1;
                self.adopted(bg, row, "offsets", after_end);
            }
            Stepped::Kept => self.refits.kept += 1,
            Stepped::Refused(e) => count(&mut self.refits.refused, e, row),
            Stepped::OffsetsRefused(e) => count(&mut self.offsets.refused, e, row),
            _ => {}
        }
    }

    fn adopted<T: Real, S: Sample>(
        &mut self,
        bg: &Calibrator<T, S>,
        row: usize,
        kind: &'static str,
        after_end: bool,
    ) {
        let Some(current) = bg.current() else {
            return;
        };
        let now = Parameters::of(&current.calibration);
        let before = self.adoptions.last();
        let change = before.map(|b| [0, 1, 2].map(|i| now.hard_iron[i] - b.hard_iron[i]));
        let q = &current.quality;
        self.adoptions.push(Adoption {
            row,
            after_end,
            kind,
            hard_iron: now.hard_iron,
            field_strength: now.field_strength,
            hard_iron_change: change,
            hard_iron_change_of_field: change
                .map(|d| (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt() / now.field_strength),
            field_strength_change: before.map(|b| now.field_strength / b.field_strength - 1.0),
            fit_error: current.fit_error.to_f64(),
            radial_rms: current.radial_rms.to_f64(),
            coverage: q.coverage.to_f64(),
            lack_of_fit: q.lack_of_fit.to_f64(),
            warnings: current.warnings.iter().map(|w| w.name()).collect(),
            warning_texts: warning_texts(current),
            buffered: bg.samples().len(),
            cells: bg.cells_filled(),
        });
    }
}

/// Counts refusal `e` at `row` with the others of its kind; the kind's
/// reason is its last refusal's (figures differ from one refit to the next).
fn count(refusals: &mut Vec<Refusal>, e: Error, row: usize) {
    let kind = std::mem::discriminant(&e);
    match refusals
        .iter_mut()
        .find(|r| std::mem::discriminant(&r.error) == kind)
    {
        Some(r) => {
            r.count += 1;
            r.last_row = row;
            r.reason = e.to_string();
            r.error = e;
        }
        None => refusals.push(Refusal {
            reason: e.to_string(),
            count: 1,
            first_row: row,
            last_row: row,
            error: e,
        }),
    }
}

/// The JSON report: one object on one line.
pub fn json(replay: &Replay) -> String {
    match serde_json::to_string(replay) {
        Ok(mut line) => {
            line.push('\n');
            line
        }
        // Unreachable for a struct of numbers and strings; still no panic.
        Err(err) => format!("{{\"error\":{:?}}}\n", err.to_string()),
    }
}

/// The text report.
pub fn text(r: &Replay, source_name: &str, columns: &str, skipped: Option<&str>) -> String {
    let mut s = String::new();
    // Writing into a String cannot fail; the results are ignored.
    let _ = writeln!(s, "magcal background: {source_name}");
    let _ = writeln!(s, "  columns       {columns}");
    if let Some(skipped) = skipped {
        let _ = writeln!(s, "  input         {skipped}");
    }
    let steps = match r.steps_per_reading {
        1 => "one step".to_owned(),
        n => format!("{n} steps"),
    };
    let _ = writeln!(
        s,
        "  calibrator    {CELLS} direction cells of {CELL_SAMPLES} samples ({}), precision {}; \
         push, then {steps} a reading",
        r.capacity, r.precision
    );
    let rd = &r.readings;
    let mut readings = format!(
        "{} rows: {} buffered, {} too close in direction to the last buffered, \
         {} lying still (before the first calibration, within the sensor's noise of the running centre)",
        r.rows, rd.stored, rd.too_close, rd.still
    );
    for (n, rows, what) in [
        (rd.invalid, &rd.invalid_rows, "invalid (glitch, not finite)"),
        (rd.wild, &rd.wild_rows, "wild (far off the sphere)"),
    ] {
        let _ = write!(readings, ", {n} {what}");
        if n > 0 {
            let _ = write!(readings, " {}", row_list(rows, n));
        }
    }
    let _ = writeln!(s, "  readings      {readings}");
    match (r.first_calibration, r.adoptions.first()) {
        (Some(row), Some(a)) => {
            let _ = writeln!(
                s,
                "  first         calibrated at row {row}{} ({} buffered in {} cells)",
                if a.after_end { " (after the end)" } else { "" },
                a.buffered,
                a.cells
            );
        }
        _ => {
            let _ = writeln!(s, "  first         never calibrated");
        }
    }
    let f = &r.refits;
    let _ = writeln!(
        s,
        "  refits        {} run: {} adopted, {} kept (not better than the calibration in use), {} refused{}",
        f.run,
        f.adopted,
        f.kept,
        f.refused.iter().map(|x| x.count).sum::<usize>(),
        refusals(&f.refused)
    );
    let o = &r.offsets_only;
    let _ = writeln!(
        s,
        "  offsets-only  {} adopted, {} refused{}",
        o.adopted,
        o.refused.iter().map(|x| x.count).sum::<usize>(),
        refusals(&o.refused)
    );
    if !r.stale_from.is_empty() {
        let rows: Vec<String> = r.stale_from.iter().map(usize::to_string).collect();
        let _ = writeln!(
            s,
            "  stale         from rows {} (residuals risen for {} readings); {} buffered samples purged after a new hard iron",
            rows.join(", "),
            r.config.stale_readings,
            r.purged
        );
    }
    let _ = writeln!(
        s,
        "  at the end    {} buffered in {} cells; {} steps after the last row finished the work under way",
        r.buffer.samples, r.buffer.cells, r.steps_after_end
    );
    let _ = writeln!(s);
    if !r.adoptions.is_empty() {
        let _ = writeln!(
            s,
            "adoptions (row: what; change of b and of the field strength; figures, units of the field)"
        );
        for a in &r.adoptions {
            let _ = writeln!(s, "  {}", adoption(a));
        }
        let _ = writeln!(s);
    }
    match &r.final_calibration {
        Some(fin) => {
            let what = match fin.kind {
                "offsets" => "offsets-only re-estimate",
                _ => "refit",
            };
            let _ = writeln!(
                s,
                "final calibration (adopted at row {}, {what}; precision {})",
                fin.row, fin.precision
            );
            s.push_str(&output::calibration(&fin.parameters, &fin.quality));
            let _ = writeln!(s);
            let _ = writeln!(
                s,
                "apply: calibrated = W (raw - b)  (unit sphere; times the field strength for sensor units)"
            );
        }
        None => {
            let reason = r.reason.as_deref().unwrap_or("none adopted");
            let _ = writeln!(s, "no calibration: {reason}");
        }
    }
    s
}

/// One line of an adoption.
fn adoption(a: &Adoption) -> String {
    let mut s = format!(
        "row {:>7}{}  {:<7}",
        a.row,
        if a.after_end { " (after the end)" } else { "" },
        a.kind
    );
    match (
        a.hard_iron_change,
        a.hard_iron_change_of_field,
        a.field_strength_change,
    ) {
        (Some(d), Some(rel), Some(field)) => {
            let _ = write!(
                s,
                "  b moved {} of the field ({}, {}, {}), field strength {}{} %",
                sig(rel, 3),
                sig(d[0], 4),
                sig(d[1], 4),
                sig(d[2], 4),
                if field >= 0.0 { "+" } else { "" },
                sig(100.0 * field, 3)
            );
        }
        _ => {
            let _ = write!(
                s,
                "  first: b ({}, {}, {}), field strength {}",
                sig(a.hard_iron[0], 6),
                sig(a.hard_iron[1], 6),
                sig(a.hard_iron[2], 6),
                sig(a.field_strength, 6)
            );
        }
    }
    let _ = write!(
        s,
        "; fit error {}, radial RMS {}, coverage {}, lack of fit {}; {} buffered in {} cells",
        sig(a.fit_error, 3),
        sig(a.radial_rms, 3),
        sig(a.coverage, 3),
        sig(a.lack_of_fit, 2),
        a.buffered,
        a.cells
    );
    // A line a warning, as the final calibration's: its name and sentence
    // with the figure and limit.
    for (name, text) in a.warnings.iter().zip(&a.warning_texts) {
        let _ = write!(s, "\n      {name}: {text}");
    }
    s
}

/// The warnings of `current` for people, each with the figure of its
/// refit and the limit of the replay's thresholds (the core's
/// [`Warning::explain_with`](mag_cal_core::Warning::explain_with): the
/// calibrator keeps no row counts, so `outliers_rejected` names the
/// outlier share).
fn warning_texts<T: Real>(current: &mag_cal_core::background::Current<T>) -> Vec<String> {
    let thresholds = &BackgroundConfig::DEFAULT.thresholds;
    current
        .warnings
        .iter()
        .map(|w| {
            w.explain_with(&current.quality, None, thresholds)
                .to_string()
        })
        .collect()
}

/// ` (3 at rows 10-250: reason; ...)`, or nothing.
fn refusals(refused: &[Refusal]) -> String {
    if refused.is_empty() {
        return String::new();
    }
    let parts: Vec<String> = refused
        .iter()
        .map(|r| {
            let rows = if r.first_row == r.last_row {
                format!("row {}", r.first_row)
            } else {
                format!("rows {}-{}", r.first_row, r.last_row)
            };
            format!("{} at {rows}: {}", r.count, r.reason)
        })
        .collect();
    format!(" ({})", parts.join("; "))
}

/// `(rows 1, 5, 9, ...)` for the first rows of `n`.
fn row_list(rows: &[usize], n: usize) -> String {
    let named: Vec<String> = rows.iter().map(usize::to_string).collect();
    let more = if n > rows.len() { ", ..." } else { "" };
    let word = if n == 1 { "row" } else { "rows" };
    format!("({word} {}{more})", named.join(", "))
}

#[cfg(test)]
mod tests {
    use super::*;
    use mag_cal_core::Figure;

    /// A device turned slowly through most orientations (the core's
    /// example): hard iron (250, -80, 40), axes 300, 330, 280.
    fn turning(n: usize) -> Vec<[f64; 3]> {
        (0..n)
            .map(|k| {
                let z = (k as f64 * 0.0021).sin();
                let r = (1.0 - z * z).sqrt();
                let phi = k as f64 * 0.05;
                [
                    250.0 + 300.0 * r * phi.cos(),
                    -80.0 + 330.0 * r * phi.sin(),
                    40.0 + 280.0 * z,
                ]
            })
            .collect()
    }

    #[test]
    fn replays_a_simulated_device_to_its_calibration() {
        let rho = (300.0f64 * 330.0 * 280.0).cbrt();
        for precision in [Precision::F32, Precision::F64] {
            for steps in [1, 4] {
                let r = replay(&turning(6000), precision, steps);
                let fin = r.final_calibration.as_ref().expect("calibrated");
                let b = fin.parameters.hard_iron;
                let db =
                    ((b[0] - 250.0).powi(2) + (b[1] + 80.0).powi(2) + (b[2] - 40.0).powi(2)).sqrt();
                assert!(db < 1e-3 * rho, "{precision:?} {steps}: b {b:?}");
                assert!((fin.parameters.field_strength / rho - 1.0).abs() < 1e-3);
                assert_eq!(r.first_calibration, r.adoptions.first().map(|a| a.row));
                assert_eq!(r.refits.adopted as usize, r.adoptions.len());
                assert!(r.reason.is_none() && r.stale_from.is_empty());
                let rd = &r.readings;
                assert_eq!(rd.stored + rd.too_close + rd.still, 6000);
            }
        }
    }

    #[test]
    fn integer_counts_are_pushed_as_such_and_glitches_named() {
        // i16 counts: a component on the rails is a glitch, as in `fit`.
        let mut rows: Vec<[f64; 3]> = turning(3000).iter().map(|r| r.map(f64::round)).collect();
        rows[7] = [32767.0, 1.0, 2.0];
        rows[9] = [0.0, 0.0, 0.0];
        let r = replay(&rows, Precision::F32, 1);
        assert_eq!(
            (r.readings.invalid, &r.readings.invalid_rows[..]),
            (2, &[7, 9][..])
        );
        // In a file of floats, 32767 is no glitch (the rails rule is for
        // integer counts).
        rows[100] = [0.5, 0.0, 0.0];
        let r = replay(&rows, Precision::F32, 1);
        assert_eq!(r.readings.invalid_rows, vec![9]);
    }

    #[test]
    fn refusals_are_grouped_by_kind() {
        let mut refused = Vec::new();
        let planar = |flatness| Error::Planar {
            flatness: Figure::new(flatness),
            limit: Figure::new(0.03),
        };
        count(&mut refused, planar(0.02), 10);
        count(
            &mut refused,
            Error::PoorCoverage {
                coverage: Figure::new(0.04),
                limit: Figure::new(0.05),
            },
            20,
        );
        count(&mut refused, planar(0.01), 30);
        assert_eq!(refused.len(), 2);
        assert_eq!(
            (refused[0].count, refused[0].first_row, refused[0].last_row),
            (2, 10, 30)
        );
        let readings = Readings::default();
        let reason = not_calibrated(&BackgroundConfig::DEFAULT, &refused, &readings, 0, 0);
        assert!(
            reason.starts_with("3 refits refused, the last at row 30: samples lie near a plane")
                && reason.contains("flatness 0.01,"),
            "{reason}"
        );
    }
}
