//! The calibration page's WebAssembly: [`mag_cal_core`] with `magcal`'s
//! parser, fit summary and reports ([`mag_cal_cli`]) behind a handful of
//! plain exports, so that the page shows exactly what `magcal fit` (or
//! `magcal planar`) prints and does no numerics of its own.
//!
//! # The interface
//!
//! Built for `wasm32-unknown-unknown` as a `cdylib`, without generated
//! glue. Every call that returns data writes one JSON document into an
//! output buffer, read by the page with [`mc_out_ptr`] and [`mc_out_len`].
//! Inputs are bytes the page writes into memory it got from [`mc_alloc`]
//! (and gives back with [`mc_free`]). The one import is
//! `env.now_us() -> f64`, a monotonic clock in microseconds
//! (`performance.now() * 1000`), which times the fit as the CLI does.
//!
//! | export | does | JSON written |
//! |---|---|---|
//! | [`mc_info`] | the core's method names and coverage grid | [`info_json`] |
//! | [`mc_fit`] | parses a file and fits it (3-D or planar) | [`fit_json`] |
//! | [`mc_live_reset`] | empties the live collector | none |
//! | [`mc_live_line`] | one line of a serial stream into the collector | [`Live::line`] |
//! | [`mc_live_fit`] | fits the collector's samples | [`fit_json`] |
//!
//! On the host the same functions are plain Rust ([`fit_json`], [`Live`]),
//! which the unit tests call.

#![warn(missing_docs)]

pub mod packet;
pub mod snippets;

use std::cell::RefCell;
use std::path::PathBuf;

use mag_cal_cli::cli::{
    parse_align, parse_columns, AxisArg, Columns, Format, PlanarArgs, Precision,
};
use mag_cal_cli::error::CliError;
use mag_cal_cli::fit::{fit_timed, Outcome};
use mag_cal_cli::input::{self, ColumnsUsed, Picked, Table};
use mag_cal_cli::selection::class_name;
use mag_cal_cli::{output, planar};
use mag_cal_core::collector::{Collector, Offer, Progress};
use mag_cal_core::{Config, Error, Method, SampleClass};
use serde_json::{json, Value};

/// Capacity of the live collection (24 bytes a sample). MotionCal keeps
/// 650 points and replaces old ones; the core's collector keeps what it
/// accepted and refuses the rest once full, so the page takes room for
/// several minutes of slow turning (at the default 4 deg spacing, the
/// 25 599 readings of a long real recording fill 1 000 in their first
/// fifth).
pub const LIVE_CAPACITY: usize = 4000;

/// The fits the page runs.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Mode {
    /// `magcal fit`: the three-dimensional calibration (`"3d"`).
    Full,
    /// `magcal planar`: a heading calibration from turns about one axis
    /// (`"planar"`).
    Planar,
}

/// The sensor axes `magcal planar --up` takes, by [`AxisArg::name`].
const UP_AXES: [AxisArg; 6] = [
    AxisArg::X,
    AxisArg::MinusX,
    AxisArg::Y,
    AxisArg::MinusY,
    AxisArg::Z,
    AxisArg::MinusZ,
];

/// The options of a fit, as the page sends them (JSON object; every field
/// optional).
#[derive(Clone, Debug, PartialEq)]
pub struct Options {
    /// The name of the file, for messages (`"name"`).
    pub name: String,
    /// Which fit (`"mode"`: `"3d"`, the default, or `"planar"`).
    pub mode: Mode,
    /// `"f32"` or `"f64"` (`"precision"`, default `f64`).
    pub precision: Precision,
    /// Outlier handling off (`"plain": true`), as `magcal fit --plain`.
    pub plain: bool,
    /// Method name (`"method"`, default `adc2`), as `magcal fit --method`.
    pub method: Method,
    /// Column names (`"columns": "x,y,z"`), as `magcal fit --columns`.
    pub columns: Option<Columns>,
    /// The planar fit's up axis (`"up"`, default `-z`), as `magcal planar
    /// --up`.
    pub up: AxisArg,
    /// The planar fit's heading 0 (`"align": "ROW:DEG"`), as `magcal
    /// planar --align`.
    pub align: Option<(usize, f64)>,
}

impl Options {
    /// Reads the options from the page's JSON; a bad value is an input
    /// error naming it.
    pub fn from_json(text: &[u8]) -> Result<Self, CliError> {
        let bad = |what: &str| CliError::Input(format!("page options: {what}"));
        let value: Value = if text.is_empty() {
            json!({})
        } else {
            serde_json::from_slice(text).map_err(|e| bad(&e.to_string()))?
        };
        let name = value["name"].as_str().unwrap_or("<page>").to_owned();
        let precision = match value["precision"].as_str().unwrap_or("f64") {
            "f64" => Precision::F64,
            "f32" => Precision::F32,
            other => return Err(bad(&format!("precision {other:?} is not f32 or f64"))),
        };
        let method_name = value["method"].as_str().unwrap_or("adc2");
        let method = Method::ALL
            .into_iter()
            .find(|m| m.name() == method_name)
            .ok_or_else(|| bad(&format!("no method {method_name:?}")))?;
        let columns = match value["columns"].as_str() {
            None | Some("") => None,
            Some(text) => Some(parse_columns(text).map_err(|e| bad(&format!("columns: {e}")))?),
        };
        let mode = match value["mode"].as_str().unwrap_or("3d") {
            "3d" => Mode::Full,
            "planar" => Mode::Planar,
            other => return Err(bad(&format!("mode {other:?} is not 3d or planar"))),
        };
        let up_name = value["up"].as_str().unwrap_or("-z");
        let up = UP_AXES
            .into_iter()
            .find(|a| a.name() == up_name)
            .ok_or_else(|| {
                bad(&format!(
                    "up axis {up_name:?} is not one of x, -x, y, -y, z, -z"
                ))
            })?;
        let align = match value["align"].as_str().map(str::trim) {
            None | Some("") => None,
            Some(text) => {
                Some(parse_align(text).map_err(|e| bad(&format!("heading 0 at {text}: {e}")))?)
            }
        };
        Ok(Options {
            name,
            mode,
            precision,
            plain: value["plain"].as_bool().unwrap_or(false),
            method,
            columns,
            up,
            align,
        })
    }

    /// The core's configuration for these options.
    fn config(&self) -> Config {
        Config {
            method: self.method,
            robust: !self.plain,
            ..Config::default()
        }
    }

    /// `magcal planar`'s arguments for these options.
    fn planar_args(&self) -> PlanarArgs {
        PlanarArgs {
            file: PathBuf::from(&self.name),
            up: self.up,
            align: self.align,
            precision: self.precision,
            format: Format::Json,
            columns: None,
        }
    }
}

/// Parses `bytes` (any format `magcal fit` reads) and fits them as the
/// options' [`Mode`] asks; the JSON for the page and the exit code `magcal
/// fit` (or `magcal planar`) would give (0, 2 or 3).
///
/// The JSON: `status` (`"ok"`, `"refused"` or `"error"`), `code`, and
/// - when the file parsed: `columns` (which columns, and why), `rows`,
///   `raw` (every row, `null` for a non-finite value) and `skipped` (the
///   lines that were no samples, one sentence, or `null`);
/// - on success: `mode` (`"3d"` or `"planar"`), `json` (the line `magcal
///   fit --format json` or `magcal planar --format json` prints, to save
///   for `magcal apply`), `text` (its text report), `fit` (that JSON as an
///   object), per row `calibrated` and `norms`, and `snippets` (`c`,
///   `rust`); see [`success`] and [`planar_success`] for the rest;
/// - otherwise `message`: the CLI's error line, without `magcal: `, with
///   advice the page can follow ([`message`]), and `offer`: the other
///   mode (`"planar"` or `"3d"`) when the refusal's cause is that the
///   motion fits it, else `null`.
pub fn fit_json(bytes: &[u8], options: &[u8], now_us: &dyn Fn() -> f64) -> (u32, String) {
    let result = Options::from_json(options).and_then(|o| {
        let table = input::parse(bytes, o.columns.as_ref(), &o.name)?;
        Ok((o, table))
    });
    let (options, table) = match result {
        Ok(parsed) => parsed,
        Err(err) => return failure(&err, json!({})),
    };
    let skipped = table.skipped.note();
    let doc = json!({
        "columns": columns_in_page_terms(&table.columns),
        "rows": table.samples.len(),
        "raw": table.samples,
        "skipped": skipped,
    });
    if options.mode == Mode::Planar {
        return planar_success(&table, &options, doc);
    }
    let samples = &table.samples;
    match fit_timed(samples, &options.config(), options.precision, now_us) {
        Ok(o) => {
            let columns = table.columns.to_string();
            success(
                &o,
                samples,
                &options.name,
                &columns,
                skipped.as_deref(),
                doc,
            )
        }
        Err(err) => failure(&err, doc),
    }
}

/// The error line for the page: the CLI's, but in the page's terms. A
/// refusal as planar, whose advice names `magcal planar`, names the page's
/// planar fit instead; the reader's advice to pass `--columns` names the
/// page's columns box ([`in_page_terms`]).
pub fn message(err: &CliError) -> String {
    match err {
        CliError::Refused(cause @ Error::Planar { .. }) => format!(
            "calibration refused: {cause} (a device that turns about one axis only: fit it as planar)"
        ),
        _ => in_page_terms(&err.to_string()),
    }
}

/// The reader's advice that names `--columns`, phrase by phrase, and the
/// page's words for it: every message of `mag-cal-cli/src/input.rs` (and
/// `input/labelled.rs`) that names the option is rewritten whole, so that
/// it names the columns box and only what the page offers (no header to
/// add: the page reads the file as it is). The page has no
/// `--accel-columns`: it never reads accelerometers. The unit tests build
/// each of these messages with the reader and check the page's sentence.
const COLUMNS_ADVICE: [(&str, &str); 10] = [
    // A table of more than three numbers without a header.
    (
        "; add a header naming the columns and pass --columns X,Y,Z, or pass their \
         field numbers (from 1), e.g. --columns ",
        "; fill the columns box with their field numbers (from 1), e.g. ",
    ),
    // Names given, but the file has no header.
    (
        ": --columns needs a header line naming the columns, but line ",
        ": names in the columns box need a header line naming the columns, but line ",
    ),
    (
        "; or give their field numbers, e.g. --columns ",
        "; or fill it with their field numbers, e.g. ",
    ),
    // A header with no, several or a repeated magnetometer triple.
    (
        "; pass --columns X,Y,Z (columns: ",
        "; fill the columns box with the names of the three to use (columns: ",
    ),
    // Labelled lines: several magnetometers, none, or one in two units.
    (
        "; pass --columns with the three labels to use (e.g. --columns ",
        "; fill the columns box with the three labels to use (e.g. ",
    ),
    (
        ") or their numbers in the line (e.g. --columns ",
        ") or their numbers in the line (e.g. ",
    ),
    (
        "; pass --columns with the labels of the one to use (e.g. --columns ",
        "; fill the columns box with the labels of the one to use (e.g. ",
    ),
    (
        "; add the unit to each name (e.g. --columns ",
        "; fill the columns box with the names and their unit (e.g. ",
    ),
    // MotionCal lines with names in the box.
    (
        ": MotionCal Raw: lines have no header: --columns does not apply",
        ": MotionCal Raw: lines have no header: empty the columns box",
    ),
    // The one message that names `--columns` only in its example.
    ("(e.g. --columns ", "(e.g. "),
];

/// `text`, one of the CLI's error lines, with its advice in the page's
/// terms ([`COLUMNS_ADVICE`]).
fn in_page_terms(text: &str) -> String {
    COLUMNS_ADVICE
        .iter()
        .fold(text.to_owned(), |text, (cli, page)| text.replace(cli, page))
}

/// The columns a fit read, in the page's terms: what the CLI reports as
/// picked by `--columns` is picked by the columns box.
fn columns_in_page_terms(used: &ColumnsUsed) -> String {
    let text = used.to_string();
    match used.picked {
        // `names (--columns)`, `fields 7,8,9 (--columns)`, `names
        // (fields 4,2,3, --columns)`: the option ends the text.
        Picked::Named | Picked::Fields(_) => match text.strip_suffix("--columns)") {
            Some(head) => format!("{head}the columns box)"),
            None => text,
        },
        _ => text,
    }
}

/// The JSON of a refused or failed fit, and its exit code.
fn failure(err: &CliError, mut doc: Value) -> (u32, String) {
    let code = u32::try_from(err.exit_code()).unwrap_or(2);
    doc["status"] = json!(
        if matches!(err, CliError::Refused(_) | CliError::PlanarRefused(_)) {
            "refused"
        } else {
            "error"
        }
    );
    doc["code"] = json!(code);
    doc["message"] = json!(message(err));
    doc["offer"] = match err {
        CliError::Refused(Error::Planar { .. }) => json!("planar"),
        CliError::PlanarRefused(mag_cal_core::planar::Error::NotPlanar { .. }) => json!("3d"),
        _ => Value::Null,
    };
    (code, doc.to_string())
}

/// The JSON of a planar fit of `table` (`magcal planar`): besides what
/// [`fit_json`] names, per row `calibrated` (`[u0, u1, 0]`, `u = K (y -
/// centre)`), `norms` (`|u|`, 1 on the ellipse) and `headings` (degrees,
/// `null` for a non-finite row), `classes` `null` (the planar fit does not
/// classify rows), no `warnings`, `snippets.c` `null` (the C API has no
/// planar calibration) and `packet` `null` (MotionCal's packet holds a
/// three-dimensional calibration).
fn planar_success(table: &Table, options: &Options, mut doc: Value) -> (u32, String) {
    let args = options.planar_args();
    let formats = [Format::Json, Format::Text];
    let (line, text) = match planar::outputs(table, &options.name, &args, &formats) {
        Ok(outputs) => match <[String; 2]>::try_from(outputs) {
            Ok([line, text]) => (line, text),
            Err(_) => return failure(&CliError::Input("planar: no output".into()), doc),
        },
        Err(err) => return failure(&err, doc),
    };
    let fit: Value = serde_json::from_str(&line).unwrap_or(Value::Null);
    // The calibration as `magcal apply` reads it back from that JSON.
    let cal = match planar::planar_from_value(&fit) {
        Ok(cal) => cal,
        Err(what) => return failure(&CliError::Input(format!("planar: {what}")), doc),
    };
    let finite = |v: f64| v.is_finite().then_some(v);
    let mut calibrated = Vec::with_capacity(table.samples.len());
    let mut norms = Vec::with_capacity(table.samples.len());
    let mut headings = Vec::with_capacity(table.samples.len());
    for s in &table.samples {
        let [u0, u1] = cal.apply(*s);
        let ok = u0.is_finite() && u1.is_finite();
        calibrated.push(json!([u0, u1, 0.0]));
        norms.push(json!(finite(u0.hypot(u1))));
        headings.push(json!(ok.then(|| cal.heading_deg(*s))));
    }
    doc["status"] = json!("ok");
    doc["code"] = json!(0);
    doc["mode"] = json!("planar");
    doc["fit"] = fit;
    doc["json"] = json!(line);
    doc["text"] = json!(text);
    doc["classes"] = Value::Null;
    doc["calibrated"] = Value::Array(calibrated);
    doc["norms"] = Value::Array(norms);
    doc["headings"] = Value::Array(headings);
    doc["warnings"] = json!([]);
    doc["snippets"] = json!({ "c": Value::Null, "rust": snippets::rust_planar(&cal) });
    doc["packet"] = Value::Null;
    (0, doc.to_string())
}

/// The JSON of a successful three-dimensional fit: besides what
/// [`fit_json`] names, per row `classes`, `calibrated` (`W (y - b)`) and
/// `norms`, `warnings` (`name` and the core's sentence, `text`), and
/// `packet` (MotionCal's 68 bytes).
fn success(
    o: &Outcome,
    samples: &[[f64; 3]],
    name: &str,
    columns: &str,
    skipped: Option<&str>,
    mut doc: Value,
) -> (u32, String) {
    let line = output::json(o);
    let (calibrated, norms): (Vec<Value>, Vec<Value>) = match o.calibration() {
        Ok(cal) => samples
            .iter()
            .map(|s| {
                let v = cal.apply_vector(*s);
                (json!([v.x, v.y, v.z]), json!(v.norm()))
            })
            .unzip(),
        Err(err) => return failure(&err, doc),
    };
    doc["status"] = json!("ok");
    doc["code"] = json!(0);
    doc["mode"] = json!("3d");
    doc["fit"] = serde_json::from_str(&line).unwrap_or(Value::Null);
    doc["json"] = json!(line);
    doc["text"] = json!(output::text(o, name, columns, skipped));
    doc["classes"] = o
        .classes
        .iter()
        .map(|c: &SampleClass| json!(class_name(*c)))
        .collect();
    doc["calibrated"] = Value::Array(calibrated);
    doc["norms"] = Value::Array(norms);
    // The core's sentence for each warning the fit reported, with its
    // figure and limit.
    doc["warnings"] = o
        .quality
        .warnings
        .iter()
        .zip(&o.quality.warning_texts)
        .map(|(name, text)| json!({ "name": name, "text": text }))
        .collect();
    doc["snippets"] = json!({ "c": snippets::c(o), "rust": snippets::rust(o) });
    doc["packet"] = json!(packet::from_outcome(o).to_vec());
    (0, doc.to_string())
}

/// A live collection from a serial stream of MotionCal lines.
#[derive(Default)]
pub struct Live {
    collector: Collector<[f64; 3], LIVE_CAPACITY>,
    /// `Raw:` lines read.
    lines: usize,
    /// Other lines skipped (`Uni:`, `Cal1:`, a sketch's banner, ...).
    skipped: usize,
    /// The collector's refusals, by [`OFFER_NAMES`] (index 0, accepted,
    /// unused).
    refused: [usize; OFFER_NAMES.len()],
    /// Samples discarded when the collection started over
    /// ([`Offer::Restarted`]).
    discarded: usize,
}

/// The names of the collector's answers, as [`Live::line`] gives them.
pub const OFFER_NAMES: [&str; 8] = [
    "accepted",
    "too_close",
    "not_finite",
    "full",
    "glitch",
    "outlier",
    "restarted",
    "refused",
];

impl Live {
    /// Reads one line of the stream: a `Raw:` line's magnetometer (fields
    /// 7-9, by `magcal`'s parser) is offered to the core's collector. The
    /// JSON: `kind` (`"raw"` or `"skipped"`), for a `Raw:` line `sample`
    /// (`null` values when cut short) and `offer` (the collector's answer:
    /// `accepted`, `too_close`, `not_finite`, `full`, `glitch`,
    /// `outlier`, `restarted`), and always `progress`
    /// ([`Live::progress_json`]).
    pub fn line(&mut self, line: &[u8]) -> String {
        let text = String::from_utf8_lossy(line);
        let text = text.trim();
        let mut doc = if text.starts_with("Raw:") {
            self.lines += 1;
            let sample = input::parse(text.as_bytes(), None, "serial")
                .ok()
                .and_then(|t| t.samples.first().copied())
                .unwrap_or([f64::NAN; 3]);
            let held = self.collector.len();
            let answer = self.collector.offer(sample);
            if answer == Offer::Restarted {
                self.discarded += held;
            }
            let offer = offer_index(answer);
            if let Some(n) = self.refused.get_mut(offer).filter(|_| offer > 0) {
                *n += 1;
            }
            json!({ "kind": "raw", "sample": sample, "offer": OFFER_NAMES.get(offer) })
        } else {
            self.skipped += 1;
            json!({ "kind": "skipped" })
        };
        doc["progress"] = self.progress_json();
        doc.to_string()
    }

    /// The collector's progress: `samples`, `cells_visited`, `cells`,
    /// `percent`, `ready`, `visited` (one flag per cell, cell
    /// `band * 8 + sector`: six bands of equal area from the south pole,
    /// eight sectors of longitude from +x counter-clockwise), the stream's
    /// `lines` and `skipped`, `refused`: the collector's refusals by name
    /// (`too_close`, `not_finite`: a cut-short line, `full`, `glitch`,
    /// `outlier`, `restarted`: the lines on which the collection started
    /// over, [`Offer::Restarted`]), and the samples those restarts
    /// `discarded`. Every `Raw:` line is counted once:
    /// `lines = samples + discarded + sum(refused)`.
    pub fn progress_json(&self) -> Value {
        let p: Progress = self.collector.progress();
        let visited: Vec<bool> = (0..p.cells).map(|c| (p.visited >> c) & 1 == 1).collect();
        json!({
            "samples": p.samples,
            "cells_visited": p.cells_visited,
            "cells": p.cells,
            "percent": p.percent,
            "ready": p.ready,
            "visited": visited,
            "lines": self.lines,
            "skipped": self.skipped,
            "discarded": self.discarded,
            "refused": OFFER_NAMES
                .iter()
                .zip(self.refused)
                .skip(1)
                .map(|(name, n)| (name.to_string(), json!(n)))
                .collect::<serde_json::Map<_, _>>(),
        })
    }

    /// Fits the collected samples, as [`fit_json`] fits a file (3-D or
    /// planar).
    pub fn fit(&self, options: &[u8], now_us: &dyn Fn() -> f64) -> (u32, String) {
        let options = match Options::from_json(options) {
            Ok(o) => o,
            Err(err) => return failure(&err, json!({})),
        };
        let samples = self.collector.samples();
        let columns = ColumnsUsed {
            names: None,
            picked: Picked::MotionCal,
        }
        .to_string();
        let mut doc = json!({
            "columns": columns,
            "rows": samples.len(),
            "raw": samples,
        });
        if options.mode == Mode::Planar {
            let table = Table {
                samples: samples.to_vec(),
                accel: None,
                columns: ColumnsUsed {
                    names: None,
                    picked: Picked::MotionCal,
                },
                skipped: input::Skipped::default(),
            };
            return planar_success(&table, &options, doc);
        }
        match fit_timed(samples, &options.config(), options.precision, now_us) {
            Ok(o) => success(&o, samples, &options.name, &columns, None, doc),
            Err(err) => {
                doc["progress"] = self.progress_json();
                failure(&err, doc)
            }
        }
    }
}

/// The index of a collector's answer in [`OFFER_NAMES`].
fn offer_index(offer: Offer) -> usize {
    match offer {
        Offer::Accepted => 0,
        Offer::TooClose => 1,
        Offer::NotFinite => 2,
        Offer::Full => 3,
        Offer::Glitch => 4,
        Offer::Outlier => 5,
        Offer::Restarted => 6,
        _ => 7,
    }
}

/// The core's names and layout for the page's controls: `methods` (names,
/// the default first), the collector's coverage grid (`bands`, `sectors`,
/// `cells`: cell `band * sectors + sector`, bands from the south pole,
/// sectors of longitude from +x counter-clockwise), `live_capacity`, and
/// the limits the core's fits judge by, which the page's figures quote:
/// `limits["3d"]` ([`mag_cal_core::quality::Thresholds::DEFAULT`]) and
/// `limits.planar` ([`mag_cal_core::planar::PlanarThresholds::DEFAULT`],
/// with the number of `sectors` of turn angle counted).
pub fn info_json() -> Value {
    use mag_cal_core::planar;
    let default = Config::default().method;
    let methods: Vec<&str> = std::iter::once(default)
        .chain(Method::ALL.into_iter().filter(|m| *m != default))
        .map(Method::name)
        .collect();
    let th = mag_cal_core::Thresholds::DEFAULT;
    json!({
        "methods": methods,
        "bands": mag_cal_core::collector::BANDS,
        "sectors": mag_cal_core::collector::SECTORS,
        "cells": mag_cal_core::collector::CELLS,
        "live_capacity": LIVE_CAPACITY,
        // The default thresholds as written: an f32 limit prints its
        // shortest form (0.2, not 0.200000003 as an f64 would).
        "limits": {
            "3d": {
                "warn_fit_error": shortest(th.warn_fit_error),
                "refuse_fit_error": shortest(th.refuse_fit_error),
                "refuse_coverage": shortest(th.refuse_coverage),
                "refuse_flatness": shortest(th.refuse_flatness),
                "refuse_distortion": shortest(th.refuse_distortion),
                "refuse_lack_of_fit": shortest(th.refuse_lack_of_fit),
                "refuse_outlier_share": shortest(th.refuse_outlier_share),
            },
            "planar": {
                "refuse_fit_error": shortest(th.refuse_fit_error),
                "refuse_not_planar": planar::REFUSE_NOT_PLANAR,
                "min_sectors": planar::MIN_SECTORS,
                "sectors": planar::SECTORS,
            },
        },
    })
}

// ---- the WebAssembly exports ----------------------------------------------

thread_local! {
    /// The last JSON document written.
    static OUT: RefCell<String> = const { RefCell::new(String::new()) };
    /// The live collection (boxed: 96 KB of samples).
    static LIVE: RefCell<Box<Live>> = RefCell::new(Box::default());
}

/// Stores `text` as the output.
fn set_out(text: String) {
    OUT.with(|o| *o.borrow_mut() = text);
}

#[cfg(target_arch = "wasm32")]
mod clock {
    #[link(wasm_import_module = "env")]
    extern "C" {
        /// `performance.now() * 1000`, from the page.
        fn now_us() -> f64;
    }

    /// The page's monotonic clock, microseconds.
    pub fn now() -> f64 {
        // SAFETY: an import without arguments or memory access.
        unsafe { now_us() }
    }
}

#[cfg(not(target_arch = "wasm32"))]
mod clock {
    use std::sync::OnceLock;
    use std::time::Instant;

    /// A monotonic clock, microseconds since its first reading.
    pub fn now() -> f64 {
        static START: OnceLock<Instant> = OnceLock::new();
        START.get_or_init(Instant::now).elapsed().as_secs_f64() * 1e6
    }
}

/// The bytes at `ptr` (from [`mc_alloc`]), empty for a null pointer.
///
/// # Safety
/// `ptr` must be null or point to `len` initialised bytes.
unsafe fn bytes<'a>(ptr: *const u8, len: usize) -> &'a [u8] {
    if ptr.is_null() || len == 0 {
        &[]
    } else {
        // SAFETY: per the function's contract.
        unsafe { std::slice::from_raw_parts(ptr, len) }
    }
}

/// Allocates `len` bytes (zeroed) for the page to write an input into.
#[no_mangle]
pub extern "C" fn mc_alloc(len: usize) -> *mut u8 {
    // A boxed slice has exactly `len` bytes, which `mc_free` rebuilds.
    Box::into_raw(vec![0u8; len].into_boxed_slice()).cast::<u8>()
}

/// Frees memory from [`mc_alloc`].
///
/// # Safety
/// `ptr` and `len` must be a pointer [`mc_alloc`] returned and the length
/// it was called with, not freed before.
#[no_mangle]
pub unsafe extern "C" fn mc_free(ptr: *mut u8, len: usize) {
    if !ptr.is_null() {
        // SAFETY: per the function's contract, the box `mc_alloc` made.
        drop(unsafe { Box::from_raw(std::ptr::slice_from_raw_parts_mut(ptr, len)) });
    }
}

/// The output JSON's address.
#[no_mangle]
pub extern "C" fn mc_out_ptr() -> *const u8 {
    OUT.with(|o| o.borrow().as_ptr())
}

/// The output JSON's length in bytes.
#[no_mangle]
pub extern "C" fn mc_out_len() -> usize {
    OUT.with(|o| o.borrow().len())
}

/// Fits the file at `data` with the options at `options` ([`fit_json`]);
/// returns the exit code `magcal fit` would give.
///
/// # Safety
/// Both pointers must be null or point to their lengths of bytes.
#[no_mangle]
pub unsafe extern "C" fn mc_fit(
    data: *const u8,
    data_len: usize,
    options: *const u8,
    options_len: usize,
) -> u32 {
    // SAFETY: per the function's contract.
    let (data, options) = unsafe { (bytes(data, data_len), bytes(options, options_len)) };
    let (code, text) = fit_json(data, options, &clock::now);
    set_out(text);
    code
}

/// What the page builds its controls from ([`info_json`]).
#[no_mangle]
pub extern "C" fn mc_info() {
    set_out(info_json().to_string());
}

/// Empties the live collection.
#[no_mangle]
pub extern "C" fn mc_live_reset() {
    LIVE.with(|l| **l.borrow_mut() = Live::default());
}

/// One line of the serial stream ([`Live::line`]).
///
/// # Safety
/// `line` must be null or point to `len` bytes.
#[no_mangle]
pub unsafe extern "C" fn mc_live_line(line: *const u8, len: usize) {
    // SAFETY: per the function's contract.
    let line = unsafe { bytes(line, len) };
    let text = LIVE.with(|l| l.borrow_mut().line(line));
    set_out(text);
}

/// Fits the collected samples ([`Live::fit`]); returns the exit code.
///
/// # Safety
/// `options` must be null or point to `len` bytes.
#[no_mangle]
pub unsafe extern "C" fn mc_live_fit(options: *const u8, len: usize) -> u32 {
    // SAFETY: per the function's contract.
    let options = unsafe { bytes(options, len) };
    let (code, text) = LIVE.with(|l| l.borrow().fit(options, &clock::now));
    set_out(text);
    code
}

/// `x` as the f64 of its shortest decimal form.
fn shortest(x: f32) -> f64 {
    x.to_string().parse().unwrap_or(f64::from(x))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Points on a shifted, stretched ellipsoid, as MotionCal's integer
    /// `Raw:` units, in the order of a board turned steadily from pole to
    /// pole (a generalised spiral, consecutive points about
    /// `3.6 / sqrt(n)` rad apart): the collector learns the noise from
    /// consecutive readings, so they come in a turning device's order.
    fn ellipsoid(n: usize) -> Vec<[f64; 3]> {
        let mut phi = 0.0f64;
        (0..n)
            .map(|i| {
                let z = 1.0 - 2.0 * (i as f64 + 0.5) / n as f64;
                let r = (1.0 - z * z).sqrt();
                phi += 3.6 / (n as f64).sqrt() / r;
                [
                    (120.0 + 400.0 * r * phi.cos()).round(),
                    (-80.0 + 460.0 * r * phi.sin()).round(),
                    (35.0 + 430.0 * z).round(),
                ]
            })
            .collect()
    }

    /// Each row as a MotionCal `Raw:` line into `live`.
    fn feed(live: &mut Live, rows: &[[f64; 3]]) {
        for r in rows {
            let line = format!("Raw:0,0,0,0,0,0,{},{},{}\r", r[0], r[1], r[2]);
            let _ = live.line(line.as_bytes());
        }
    }

    /// The collector's refusals of a progress document, all reasons.
    fn refused_total(p: &Value) -> u64 {
        p["refused"]
            .as_object()
            .map_or(0, |m| m.values().filter_map(Value::as_u64).sum())
    }

    fn csv(rows: &[[f64; 3]]) -> Vec<u8> {
        rows.iter()
            .map(|r| format!("{},{},{}\n", r[0], r[1], r[2]))
            .collect::<String>()
            .into_bytes()
    }

    #[test]
    fn a_file_fits_as_the_cli_fits_it() {
        let data = csv(&ellipsoid(400));
        let (code, text) = fit_json(&data, br#"{"name":"e.csv"}"#, &|| 0.0);
        assert_eq!(code, 0, "{text}");
        let doc: Value = serde_json::from_str(&text).unwrap();
        assert_eq!(doc["status"], "ok");
        let table = input::parse(&data, None, "e.csv").unwrap();
        let cli =
            mag_cal_cli::fit::fit(&table.samples, &Config::default(), Precision::F64).unwrap();
        assert_eq!(doc["fit"]["hard_iron"], json!(cli.hard_iron));
        assert_eq!(doc["fit"]["soft_iron"], json!(cli.soft_iron));
        assert_eq!(doc["norms"].as_array().unwrap().len(), 400);
        let packet = doc["packet"].as_array().unwrap();
        assert_eq!(packet.len(), packet::LEN);
        assert!(doc["snippets"]["c"]
            .as_str()
            .unwrap()
            .contains("magcal_apply"));
    }

    #[test]
    fn a_refusal_and_a_parse_error_say_why() {
        let flat: Vec<[f64; 3]> = ellipsoid(400)
            .into_iter()
            .map(|r| [r[0], r[1], 7.0])
            .collect();
        let (code, text) = fit_json(&csv(&flat), b"", &|| 0.0);
        let doc: Value = serde_json::from_str(&text).unwrap();
        assert_eq!(
            (code, doc["status"].as_str()),
            (3, Some("refused")),
            "{text}"
        );
        assert!(doc["message"].as_str().unwrap().contains("plane"), "{text}");
        assert_eq!(doc["raw"].as_array().unwrap().len(), 400);

        let (code, text) = fit_json(b"a,b,c,d\n1,2,3,4\n", b"", &|| 0.0);
        let doc: Value = serde_json::from_str(&text).unwrap();
        assert_eq!((code, doc["status"].as_str()), (2, Some("error")), "{text}");
        // The reader's advice names the page's columns box, not an option.
        let wide = "1,2,3,4,5,6,7,8,9\n2,3,4,5,6,7,8,9,1\n";
        for input in [&b"a,b,c,d\n1,2,3,4\n"[..], wide.as_bytes()] {
            let (code, text) = fit_json(input, b"", &|| 0.0);
            let doc: Value = serde_json::from_str(&text).unwrap();
            let msg = doc["message"].as_str().unwrap();
            assert_eq!(code, 2, "{text}");
            assert!(msg.contains("columns box") && !msg.contains("--"), "{msg}");
        }
        let (code, _) = fit_json(b"1,2,3\n", br#"{"precision":"f16"}"#, &|| 0.0);
        assert_eq!(code, 2);
    }

    /// `n` readings of a device lying still at `at`, with a count of noise
    /// (-1, 0, 0 or +1 per axis, from a fixed LCG seeded by `seed`).
    fn lying_still(at: [f64; 3], n: usize, seed: u32) -> Vec<[f64; 3]> {
        let mut state = seed;
        (0..n)
            .map(|_| {
                at.map(|v| {
                    state = state.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
                    v + [-1.0, 0.0, 0.0, 1.0][(state >> 30) as usize]
                })
            })
            .collect()
    }

    /// Still ends are a class of rows of their own, counted with the
    /// others and marked per row; a device that hardly moved is a refusal
    /// with its own cause and no other fit offered.
    #[test]
    fn still_rows_are_a_class_and_hardly_moving_a_refusal() {
        let turns = ellipsoid(400);
        let (first, last) = (turns[0], turns[399]);
        let rows = [
            lying_still(first, 500, 1),
            turns.clone(),
            lying_still(last, 800, 2),
        ]
        .concat();
        let (code, text) = fit_json(&csv(&rows), b"", &|| 0.0);
        assert_eq!(code, 0, "{text}");
        let doc: Value = serde_json::from_str(&text).unwrap();
        let fit = &doc["fit"];
        let dwell = fit["dwell"].as_u64().unwrap();
        assert!(dwell > 0, "{fit}");
        let count = |key: &str| fit[key].as_u64().unwrap();
        assert_eq!(
            count("samples_used")
                + count("samples_dropped")
                + dwell
                + count("screened")
                + count("rejected"),
            rows.len() as u64
        );
        let classes = doc["classes"].as_array().unwrap();
        let marked = classes.iter().filter(|c| *c == "dwell").count() as u64;
        assert_eq!(marked, dwell);
        // Every row marked lies in a still end.
        assert!(classes
            .iter()
            .enumerate()
            .all(|(i, c)| c != "dwell" || i <= 500 || i >= 899));

        let hardly = [
            lying_still(first, 500, 3),
            vec![turns[200]],
            lying_still(last, 500, 4),
        ]
        .concat();
        let (code, text) = fit_json(&csv(&hardly), b"", &|| 0.0);
        let doc: Value = serde_json::from_str(&text).unwrap();
        assert_eq!(
            (code, doc["status"].as_str()),
            (3, Some("refused")),
            "{text}"
        );
        let message = doc["message"].as_str().unwrap();
        assert!(
            message.starts_with("calibration refused: the device hardly moved: "),
            "{message}"
        );
        assert!(message.ends_with("turn the sensor through all orientations while recording"));
        assert!(doc["offer"].is_null(), "{text}");
    }

    /// A level turn about the sensor's -z axis: an ellipse in a plane.
    fn level_turn(n: usize) -> Vec<[f64; 3]> {
        (0..n)
            .map(|i| {
                let psi = i as f64 * 0.05;
                [
                    (40.0 + 330.0 * psi.cos()).round(),
                    (-25.0 - 300.0 * psi.sin()).round(),
                    (410.0 + (i % 3) as f64).round(),
                ]
            })
            .collect()
    }

    #[test]
    fn a_planar_refusal_offers_the_planar_fit_which_is_magcal_planar() {
        let data = csv(&level_turn(300));
        let (code, text) = fit_json(&data, br#"{"name":"turn.csv"}"#, &|| 0.0);
        let doc: Value = serde_json::from_str(&text).unwrap();
        assert_eq!((code, doc["offer"].as_str()), (3, Some("planar")), "{text}");
        let message = doc["message"].as_str().unwrap();
        assert!(message.contains("fit it as planar"), "{message}");
        assert!(!message.contains("magcal"), "{message}");

        let options = br#"{"name":"turn.csv","mode":"planar","up":"-z","align":"5:90"}"#;
        let (code, text) = fit_json(&data, options, &|| 0.0);
        assert_eq!(code, 0, "{text}");
        let doc: Value = serde_json::from_str(&text).unwrap();
        assert_eq!(
            (doc["mode"].as_str(), doc["fit"]["method"].as_str()),
            (Some("planar"), Some("planar"))
        );
        // What `magcal planar --up -z --align 5:90 --format json` prints.
        let file =
            std::env::temp_dir().join(format!("mag-cal-web-turn-{}.csv", std::process::id()));
        std::fs::write(&file, &data).unwrap();
        let args = PlanarArgs {
            file: file.clone(),
            up: AxisArg::MinusZ,
            align: Some((5, 90.0)),
            precision: Precision::F64,
            format: Format::Json,
            columns: None,
        };
        let mut out = Vec::new();
        let run = planar::run(&args, &mut out);
        std::fs::remove_file(&file).unwrap();
        run.unwrap();
        assert_eq!(doc["json"].as_str().map(str::as_bytes), Some(&out[..]));
        // Row 5 is at heading 90 deg; every row on the unit circle.
        let h5 = doc["headings"][5].as_f64().unwrap();
        assert!((h5 - 90.0).abs() < 1e-9, "{h5}");
        for n in doc["norms"].as_array().unwrap() {
            assert!((n.as_f64().unwrap() - 1.0).abs() < 0.02, "{n}");
        }
        assert!(doc["snippets"]["c"].is_null());
        assert!(doc["snippets"]["rust"]
            .as_str()
            .unwrap()
            .contains("PlanarCalibration::new("));
        assert!(doc["text"]
            .as_str()
            .unwrap()
            .starts_with("planar (heading-only) calibration of turn.csv"));

        // A three-dimensional recording fitted as planar: refused, and the
        // three-dimensional fit offered.
        let (code, text) = fit_json(&csv(&ellipsoid(400)), br#"{"mode":"planar"}"#, &|| 0.0);
        let doc: Value = serde_json::from_str(&text).unwrap();
        assert_eq!((code, doc["offer"].as_str()), (3, Some("3d")), "{text}");
        let (code, _) = fit_json(&data, br#"{"mode":"planar","up":"w"}"#, &|| 0.0);
        assert_eq!(code, 2);
    }

    /// A board turning level over the serial port: the 3-D fit refuses it
    /// as planar and offers the planar fit, which fits what the collector
    /// kept.
    #[test]
    fn a_live_level_turn_fits_as_planar() {
        let mut live = Live::default();
        feed(&mut live, &level_turn(600));
        let (code, text) = live.fit(b"", &|| 0.0);
        let doc: Value = serde_json::from_str(&text).unwrap();
        assert_eq!((code, doc["offer"].as_str()), (3, Some("planar")), "{text}");
        let (code, text) = live.fit(br#"{"mode":"planar"}"#, &|| 0.0);
        assert_eq!(code, 0, "{text}");
        let doc: Value = serde_json::from_str(&text).unwrap();
        let kept = live.progress_json()["samples"].as_u64().unwrap();
        assert_eq!(doc["norms"].as_array().map(Vec::len), Some(kept as usize));
        let centre = &doc["fit"]["centre"];
        assert!((centre[0].as_f64().unwrap() - 40.0).abs() < 2.0, "{centre}");
        assert!((centre[1].as_f64().unwrap() + 25.0).abs() < 2.0, "{centre}");
    }

    /// The exports as the page calls them: copy in, call, read out, free.
    #[test]
    fn the_exports_move_bytes_in_and_out() {
        let put = |bytes: &[u8]| {
            let ptr = mc_alloc(bytes.len());
            // SAFETY: `ptr` holds `bytes.len()` bytes from `mc_alloc`.
            unsafe { std::ptr::copy_nonoverlapping(bytes.as_ptr(), ptr, bytes.len()) };
            ptr
        };
        let out = || {
            // SAFETY: the output string, not changed until the next call.
            let bytes = unsafe { bytes(mc_out_ptr(), mc_out_len()) };
            serde_json::from_slice::<Value>(bytes).expect("JSON")
        };
        let data = csv(&ellipsoid(300));
        let options = br#"{"precision":"f32"}"#;
        let (d, o) = (put(&data), put(options));
        // SAFETY: both from `mc_alloc`, with their lengths.
        let code = unsafe { mc_fit(d, data.len(), o, options.len()) };
        assert_eq!((code, out()["fit"]["precision"].as_str()), (0, Some("f32")));
        // SAFETY: as allocated; an empty allocation too.
        unsafe {
            mc_free(d, data.len());
            mc_free(o, options.len());
            let empty = mc_alloc(0);
            assert_eq!(mc_fit(empty, 0, std::ptr::null(), 0), 2);
            mc_free(empty, 0);
        }
        assert_eq!(out()["status"], "error");

        mc_live_reset();
        let line = b"Raw:0,0,0,0,0,0,1,2,3";
        let l = put(line);
        // SAFETY: from `mc_alloc`, with its length.
        unsafe {
            mc_live_line(l, line.len());
            mc_free(l, line.len());
        }
        assert_eq!(out()["offer"], "accepted");
        // SAFETY: null options are the defaults.
        assert_eq!(unsafe { mc_live_fit(std::ptr::null(), 0) }, 3);
        assert_eq!(out()["status"], "refused");
    }

    /// The limits the page quotes are the core's.
    #[test]
    fn the_info_gives_the_limits_the_fits_judge_by() {
        use mag_cal_core::planar::PlanarThresholds;
        use mag_cal_core::quality::Thresholds;
        let limits = &info_json()["limits"];
        let f = |v: &Value| v.as_f64().map(|v| v as f32);
        let t = Thresholds::DEFAULT;
        let full = &limits["3d"];
        assert_eq!(f(&full["warn_fit_error"]), Some(t.warn_fit_error));
        assert_eq!(f(&full["refuse_fit_error"]), Some(t.refuse_fit_error));
        assert_eq!(f(&full["refuse_coverage"]), Some(t.refuse_coverage));
        assert_eq!(f(&full["refuse_flatness"]), Some(t.refuse_flatness));
        assert_eq!(f(&full["refuse_distortion"]), Some(t.refuse_distortion));
        assert_eq!(f(&full["refuse_lack_of_fit"]), Some(t.refuse_lack_of_fit));
        assert_eq!(
            f(&full["refuse_outlier_share"]),
            Some(t.refuse_outlier_share)
        );
        let p = PlanarThresholds::DEFAULT;
        let planar = &limits["planar"];
        assert_eq!(f(&planar["refuse_fit_error"]), Some(p.refuse_fit_error));
        assert_eq!(f(&planar["refuse_not_planar"]), Some(p.refuse_not_planar));
        assert_eq!(
            planar["min_sectors"].as_u64(),
            Some(u64::from(p.min_sectors))
        );
        assert_eq!(
            planar["sectors"].as_u64(),
            Some(u64::from(mag_cal_core::planar::SECTORS))
        );
    }

    /// Every reader's message that names `--columns`, built by the reader
    /// from an input that gives it: the page's sentence names the columns
    /// box and no option, offers no header to add, and keeps the rest of
    /// the CLI's sentence (its reason, and its example without the
    /// option).
    #[test]
    fn every_columns_advice_reads_in_the_page_terms() {
        let cases: [(&str, Option<&str>, &str); 10] = [
            (
                "Raw:0,0,0,0,0,0,1,2,3\n",
                Some("x,y,z"),
                "t.csv: MotionCal Raw: lines have no header: empty the columns box",
            ),
            (
                "1,2,3\n4,5,6\n",
                Some("a,b,c"),
                "t.csv: names in the columns box need a header line naming the columns, \
                 but line 1 is data; or fill it with their field numbers, e.g. 1,2,3",
            ),
            (
                "1,2,3,4,5\n2,3,4,5,6\n",
                None,
                "; fill the columns box with their field numbers (from 1), e.g. ",
            ),
            (
                "magx,mag_x,magy,magz\n1,2,3,4\n",
                None,
                "t.csv: 4 numeric columns and the header repeats a magnetometer axis \
                 (magx, mag_x, magy, magz); fill the columns box with the names of the \
                 three to use (columns: magx, mag_x, magy, magz)",
            ),
            (
                "a,b,c,d\n1,2,3,4\n",
                None,
                "; fill the columns box with the names of the three to use (columns: a, b, c, d)",
            ),
            (
                "mag_x,mag_y,mag_z,raw_mag_x,raw_mag_y,raw_mag_z\n1,2,3,4,5,6\n",
                None,
                "; fill the columns box with the names of the three to use (columns: ",
            ),
            (
                "X: 1900 Y: -12900 Z: 17400\nX: 19 Y: -129 Z: 174 uTesla\n",
                Some("x,y,z"),
                "t.csv: the values named 'x', 'y', 'z' come in 2 units (no unit, uTesla); \
                 fill the columns box with the names and their unit (e.g. \
                 x[uTesla],y[uTesla],z[uTesla])",
            ),
            (
                "X: 1 Y: 2 Z: 3 uT\nX: 1 Y: 2 Z: 3 gauss\n",
                None,
                "; fill the columns box with the labels of the one to use (e.g. \
                 x[uT],y[uT],z[uT])",
            ),
            (
                "Accel X: 1 Y: 2 Z: 3 m/s^2\nGyro X: 1 Y: 2 Z: 3 dps\n",
                None,
                "; fill the columns box with the three labels to use (e.g. \
                 accelx,accely,accelz) or their numbers in the line (e.g. 1,2,3)",
            ),
            (
                "Mag X: 1 Y: 2 Z: 3 uT\nmx = 1 my = 2 mz = 3 mG\n",
                None,
                "; fill the columns box with the labels of the one to use (e.g. \
                 magx,magy,magz)",
            ),
        ];
        for (text, columns, expected) in cases {
            let cli = input::parse(
                text.as_bytes(),
                columns.map(|c| parse_columns(c).unwrap()).as_ref(),
                "t.csv",
            )
            .unwrap_err();
            assert!(cli.to_string().contains("--columns"), "{cli}");
            let options = json!({ "name": "t.csv", "columns": columns.unwrap_or("") });
            let (code, doc) = fit_json(text.as_bytes(), options.to_string().as_bytes(), &|| 0.0);
            let doc: Value = serde_json::from_str(&doc).unwrap();
            let page = doc["message"].as_str().unwrap();
            assert_eq!(code, 2, "{page}");
            assert!(page.contains(expected), "{page}\n  expected {expected}");
            assert!(page.contains("columns box"), "{page}");
            assert!(
                !page.contains("--") && !page.contains("add a header"),
                "{page}"
            );
            // The reason before the advice is the CLI's (where it does
            // not name the option itself).
            let cli = cli.to_string();
            let reason = |m: &str| m.split(';').next().unwrap_or("").to_owned();
            if !reason(&cli).contains("--columns") {
                assert_eq!(reason(page), reason(&cli), "{page}");
            }
        }
        // The messages of the reader that name `--columns`, outside its
        // tests and comments: three in how a report names the columns,
        // and those above (the option's name passed to one of them). A
        // new one needs a case above and, when its phrase is new, a line
        // of COLUMNS_ADVICE.
        let named = |source: &str| {
            source
                .split("#[cfg(test)]")
                .next()
                .unwrap_or("")
                .lines()
                .filter(|l| !l.trim_start().starts_with("//") && l.contains("--columns"))
                .count()
        };
        assert_eq!(named(include_str!("../../mag-cal-cli/src/input.rs")), 10);
        assert_eq!(
            named(include_str!("../../mag-cal-cli/src/input/labelled.rs")),
            4
        );
    }

    /// The columns line of a fit by the columns box names the box.
    #[test]
    fn columns_picked_by_the_box_are_said_so() {
        let rows = csv(&ellipsoid(300));
        let wide: String = String::from_utf8(rows.clone())
            .unwrap()
            .lines()
            .map(|l| format!("0,{l},1\n"))
            .collect();
        let named = format!("t,mx,my,mz,q\n{wide}");
        for (text, columns, expected) in [
            (&wide, "2,3,4", "fields 2,3,4 (the columns box)"),
            (&named, "mx,my,mz", "mx,my,mz (the columns box)"),
            (&named, "2,3,4", "mx,my,mz (fields 2,3,4, the columns box)"),
        ] {
            let options = json!({ "columns": columns }).to_string();
            let (code, doc) = fit_json(text.as_bytes(), options.as_bytes(), &|| 0.0);
            let doc: Value = serde_json::from_str(&doc).unwrap();
            assert_eq!(
                (code, doc["columns"].as_str()),
                (0, Some(expected)),
                "{doc}"
            );
        }
    }

    #[test]
    fn the_info_names_every_method_default_first() {
        let info = info_json();
        let methods = info["methods"].as_array().unwrap();
        assert_eq!(methods[0], Config::default().method.name());
        assert_eq!(methods.len(), Method::ALL.len());
        let (bands, sectors) = (
            info["bands"].as_u64().unwrap(),
            info["sectors"].as_u64().unwrap(),
        );
        assert_eq!(Some(bands * sectors), info["cells"].as_u64());
    }

    #[test]
    fn a_live_stream_collects_and_fits() {
        let mut live = Live::default();
        let banner: Value =
            serde_json::from_str(&live.line(b"Adafruit sensor calibration")).unwrap();
        assert_eq!(banner["kind"], "skipped");
        let cut: Value = serde_json::from_str(&live.line(b"Raw:1,2,3,4,5,6,7")).unwrap();
        assert_eq!(cut["offer"], "not_finite");
        feed(&mut live, &ellipsoid(800));
        let p = live.progress_json();
        assert_eq!(p["ready"], true, "{p}");
        assert_eq!(
            (p["lines"].as_u64(), p["skipped"].as_u64()),
            (Some(801), Some(1))
        );
        assert_eq!(p["refused"]["not_finite"], 1, "{p}");
        let refused = refused_total(&p);
        assert_eq!(refused + p["samples"].as_u64().unwrap(), 801, "{p}");
        assert_eq!(
            (p["refused"]["restarted"].as_u64(), p["discarded"].as_u64()),
            (Some(0), Some(0))
        );
        let visited = p["visited"].as_array().unwrap();
        let seen = visited.iter().filter(|v| v.as_bool() == Some(true)).count();
        assert_eq!(Some(seen as u64), p["cells_visited"].as_u64());
        let (code, text) = live.fit(b"", &|| 0.0);
        assert_eq!(code, 0, "{text}");
        let doc: Value = serde_json::from_str(&text).unwrap();
        let b = doc["fit"]["hard_iron"][0].as_f64().unwrap();
        assert!((b - 120.0).abs() < 1.0, "{b}");
    }

    /// A board lying still when the collection starts adds one sample
    /// (its noise is not coverage), and the collection proceeds once the
    /// board turns, with no restart.
    #[test]
    fn a_board_lying_still_at_first_does_not_stall_the_collection() {
        let mut live = Live::default();
        let sphere = ellipsoid(800);
        let still = sphere[0];
        for k in 0..60 {
            // Noise of a few counts about one reading.
            let n = [
                (k * 7 % 5) as f64 - 2.0,
                (k * 3 % 7) as f64 - 3.0,
                (k % 3) as f64 - 1.0,
            ];
            let line = format!(
                "Raw:0,0,0,0,0,0,{},{},{}",
                still[0] + n[0],
                still[1] + n[1],
                still[2] + n[2]
            );
            let _ = live.line(line.as_bytes());
        }
        let p = live.progress_json();
        assert_eq!(p["samples"], 1, "{p}");
        assert_eq!(p["percent"], 0, "{p}");
        feed(&mut live, &sphere);
        let p = live.progress_json();
        assert_eq!(p["ready"], true, "{p}");
        assert_eq!(p["refused"]["restarted"], 0, "{p}");
        assert_eq!(p["discarded"], 0, "{p}");
        let (code, text) = live.fit(b"", &|| 0.0);
        assert_eq!(code, 0, "{text}");
    }

    /// A wild first reading would stall the collector; the core's
    /// collector starts over and then fills as usual.
    #[test]
    fn a_wild_first_reading_does_not_stall_the_collection() {
        let mut live = Live::default();
        let _ = live.line(b"Raw:0,0,0,0,0,0,0,0,32767");
        feed(&mut live, &ellipsoid(800));
        let p = live.progress_json();
        assert_eq!(p["ready"], true, "{p}");
        assert_eq!(p["refused"]["restarted"], 1, "{p}");
        let refused = refused_total(&p);
        let held = p["samples"].as_u64().unwrap() + p["discarded"].as_u64().unwrap();
        assert_eq!(refused + held, 801, "{p}");
        let (code, text) = live.fit(b"", &|| 0.0);
        assert_eq!(code, 0, "{text}");
    }
}
