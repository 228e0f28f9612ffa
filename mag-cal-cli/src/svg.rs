//! `magcal fit --plot`: a hand-written SVG of the samples before and after
//! calibration.
//!
//! Four panels (each a `<g class="panel">`): the raw samples shifted by the
//! hard iron, `y - b` (blue), and the calibrated samples the fit used, in
//! sensor units, `rho W (y - b)` (orange), projected on the XY, XZ and YZ
//! planes with the circle of radius `rho`, all at one scale; and the
//! paper's Fig. 2, the per-sample norms `|y - b| / rho` and `|W (y - b)|`
//! against the sample index with the unit line. Rows the fit did not use
//! are red crosses at their calibrated position: `x` rejected by their
//! residual, `+` screened out (drawn on the frame when they lie beyond it);
//! rows set aside as still periods (a device lying still: no outliers) are
//! green rings at their calibrated position. Rows dropped by the rules
//! (non-finite, overflowing, glitches) are not drawn; the subtitle counts
//! every class. Long inputs are thinned to one used sample in k, more than
//! [`MAX_CROSSES`] outliers to one in j, and as many still rows to one in
//! m (the subtitle says so). The output
//! depends on the inputs only (no timestamps), and every coordinate is
//! finite.

use std::fmt::Write as _;

use mag_cal_core::{Calibration, SampleClass};

use crate::output::sig;

/// What the title names.
pub struct PlotTitle<'a> {
    /// Input file name.
    pub source: &'a str,
    /// Method name.
    pub method: &'a str,
    /// LS variant name.
    pub ls: &'a str,
    /// Radial RMS of the fit.
    pub radial_rms: f64,
    /// Fit error of the fit.
    pub fit_error: f64,
    /// The residual beyond which rows were rejected, if any.
    pub residual_limit: Option<f64>,
    /// Outlier handling was on.
    pub robust: bool,
}

const WIDTH: f64 = 1200.0;
const HEIGHT: f64 = 820.0;
const RAW: &str = "#1f77b4";
const CAL: &str = "#ff7f0e";
const OUT: &str = "#d62728";
/// Rows set aside as still periods.
const STILL: &str = "#2ca02c";
const REF: &str = "#333";
/// Most points drawn per series; longer inputs are thinned by a stride.
const MAX_POINTS: usize = 3000;
/// Most outliers (screened and rejected rows) drawn as crosses; more are
/// thinned by a stride of their own (crosses weigh more than dots, and a
/// few hundred show where the outliers lie).
const MAX_CROSSES: usize = 300;

/// Text styles: attributes of a `<text>` element.
const TITLE: &str = r#"text-anchor="middle" font-size="18" font-weight="bold""#;
const SUBTITLE: &str = r#"text-anchor="middle" font-size="13""#;
const PANEL: &str = r#"font-size="14" font-weight="bold""#;
const CENTRED: &str = r#"text-anchor="middle""#;
const TICK_X: &str = r#"text-anchor="middle" font-size="11""#;
const TICK_Y: &str = r#"text-anchor="end" font-size="11""#;

/// A drawn sample: input row, `y - b`, `rho W (y - b)`, what the fit did
/// with it (used, still, screened or rejected).
type Drawn = (usize, [f64; 3], [f64; 3], SampleClass);

/// A rectangle of the canvas mapping data ranges onto it (y up).
struct Area {
    left: f64,
    top: f64,
    width: f64,
    height: f64,
    x: (f64, f64),
    y: (f64, f64),
}

impl Area {
    fn px(&self, x: f64) -> f64 {
        self.left + (x - self.x.0) / (self.x.1 - self.x.0) * self.width
    }
    fn py(&self, y: f64) -> f64 {
        self.top + (self.y.1 - y) / (self.y.1 - self.y.0) * self.height
    }
    /// A finite canvas point, clamped near the area (the clip path hides
    /// what lies outside).
    fn point(&self, x: f64, y: f64) -> Option<(f64, f64)> {
        let (px, py, pad) = (self.px(x), self.py(y), self.width.max(self.height));
        (px.is_finite() && py.is_finite()).then(|| {
            (
                px.clamp(self.left - pad, self.left + self.width + pad),
                py.clamp(self.top - pad, self.top + self.height + pad),
            )
        })
    }
    /// A finite canvas point inside the area: beyond it, on its frame.
    fn inside(&self, x: f64, y: f64) -> Option<(f64, f64)> {
        let (px, py) = (self.px(x), self.py(y));
        let clamp = |v: f64, lo: f64, len: f64| {
            // NaN (no position along this axis) is left out.
            (!v.is_nan()).then(|| v.clamp(lo, lo + len))
        };
        Some((
            clamp(px, self.left, self.width)?,
            clamp(py, self.top, self.height)?,
        ))
    }
}

/// Rows of each class, counted from the classes.
#[derive(Default)]
struct Counts {
    used: usize,
    dropped: usize,
    dwell: usize,
    screened: usize,
    rejected: usize,
}

impl Counts {
    fn of(classes: &[SampleClass]) -> Self {
        let mut c = Counts::default();
        for class in classes {
            match class {
                SampleClass::Used => c.used += 1,
                SampleClass::Dropped(_) => c.dropped += 1,
                SampleClass::Dwell => c.dwell += 1,
                SampleClass::Screened => c.screened += 1,
                SampleClass::Rejected => c.rejected += 1,
            }
        }
        c
    }
}

/// The SVG document for `samples` calibrated by `cal`; `classes` says what
/// the fit did with each row (a row without a class counts as dropped).
pub fn plot(
    samples: &[[f64; 3]],
    classes: &[SampleClass],
    cal: &Calibration<f64>,
    title: &PlotTitle<'_>,
) -> String {
    let (rho, b) = (cal.field_strength(), cal.hard_iron_vector());
    let counts = Counts::of(&classes[..classes.len().min(samples.len())]);
    let counts = Counts {
        dropped: counts.dropped + samples.len().saturating_sub(classes.len()),
        ..counts
    };
    let stride = counts.used.div_ceil(MAX_POINTS).max(1);
    let cross_stride = (counts.screened + counts.rejected)
        .div_ceil(MAX_CROSSES)
        .max(1);
    let still_stride = counts.dwell.div_ceil(MAX_CROSSES).max(1);
    let rows = || samples.iter().zip(classes).enumerate();
    let used = rows()
        .filter(|(_, (_, c))| **c == SampleClass::Used)
        .step_by(stride);
    let outliers = rows()
        .filter(|(_, (_, c))| matches!(c, SampleClass::Screened | SampleClass::Rejected))
        .step_by(cross_stride);
    let still = rows()
        .filter(|(_, (_, c))| **c == SampleClass::Dwell)
        .step_by(still_stride);
    let mut drawn: Vec<Drawn> = used
        .chain(outliers)
        .chain(still)
        .map(|(i, (y, class))| {
            let c = cal.apply_scaled_vector(*y);
            (
                i,
                [y[0] - b.x, y[1] - b.y, y[2] - b.z],
                [c.x, c.y, c.z],
                *class,
            )
        })
        .collect();
    drawn.sort_by_key(|d| d.0);

    let mut s = format!(
        r#"<svg xmlns="http://www.w3.org/2000/svg" width="{WIDTH}" height="{HEIGHT}" viewBox="0 0 {WIDTH} {HEIGHT}" font-family="DejaVu Sans, Arial, sans-serif" font-size="12">
<rect width="100%" height="100%" fill="white"/>
"#
    );
    let mut heading = format!(
        "magcal fit: {} \u{2014} method {} (LS {}), radial RMS {}, fit error {}",
        title.source,
        title.method,
        title.ls,
        sig(title.radial_rms, 3),
        sig(title.fit_error, 3)
    );
    if !title.robust {
        heading.push_str(", --plain");
    }
    text(&mut s, WIDTH / 2.0, 30.0, TITLE, &heading);
    let mut sub = format!(
        "{} rows: {} used, {} dropped, {} still, {} screened, {} rejected; \
         field strength \u{3c1} = {}, hard iron b = [{}, {}, {}]",
        samples.len(),
        counts.used,
        counts.dropped,
        counts.dwell,
        counts.screened,
        counts.rejected,
        sig(rho, 4),
        sig(b.x, 4),
        sig(b.y, 4),
        sig(b.z, 4)
    );
    if stride > 1 {
        let _ = write!(sub, "; 1 in {stride} used rows drawn");
    }
    if cross_stride > 1 {
        let _ = write!(sub, ", 1 in {cross_stride} outliers");
    }
    if still_stride > 1 {
        let _ = write!(sub, ", 1 in {still_stride} still rows");
    }
    text(&mut s, WIDTH / 2.0, 52.0, SUBTITLE, &sub);
    let rejected = match title.residual_limit {
        Some(limit) => format!(
            "rejected ({}): |W (y \u{2212} b)| off 1 by > {}",
            counts.rejected,
            sig(limit, 3)
        ),
        None => format!("rejected ({})", counts.rejected),
    };
    let screened = format!(
        "screened out ({}; beyond the frame: on its edge)",
        counts.screened
    );
    let mut entries = vec![
        (RAW, Mark::Dot, "raw \u{2212} b".to_owned()),
        (
            CAL,
            Mark::Dot,
            "calibrated \u{3c1} W (raw \u{2212} b)".to_owned(),
        ),
    ];
    if counts.rejected > 0 {
        entries.push((OUT, Mark::Cross, rejected));
    }
    if counts.screened > 0 {
        entries.push((OUT, Mark::Plus, screened));
    }
    if counts.dwell > 0 {
        let still = format!("still, set aside ({})", counts.dwell);
        entries.push((STILL, Mark::Ring, still));
    }
    entries.push((REF, Mark::Dash, "circle of radius \u{3c1}".to_owned()));
    legend(
        &mut s,
        WIDTH / 2.0 - legend_width(&entries) / 2.0,
        78.0,
        &entries,
    );

    // One symmetric range for the three projections: equal aspect, equal
    // scale, from the rows used; outliers beyond it (and anything beyond
    // 3 rho) sit on the frame or are clipped.
    let reach = drawn
        .iter()
        .filter(|d| d.3 == SampleClass::Used)
        .flat_map(|(_, r, c, _)| r.iter().chain(c).map(|v| v.abs()))
        .fold(rho, f64::max)
        .min(3.0 * rho);
    let half = nice_ceiling(reach * 1.04);
    for (k, (i, j)) in [(0, 1), (0, 2), (1, 2)].into_iter().enumerate() {
        let area = Area {
            left: 75.0 + 400.0 * k as f64,
            top: 120.0,
            width: 300.0,
            height: 300.0,
            x: (-half, half),
            y: (-half, half),
        };
        projection(&mut s, &area, &drawn, (i, j), rho);
    }
    norms(&mut s, &drawn, samples.len(), rho);
    s.push_str("</svg>\n");
    s
}

/// One projection panel: axes `i` (across) and `j` (up).
fn projection(s: &mut String, area: &Area, drawn: &[Drawn], (i, j): (usize, usize), rho: f64) {
    let axis = ["x", "y", "z"];
    let name = format!("{}{}", axis[i], axis[j]);
    open_panel(s, &name, area, &format!("{} plane", name.to_uppercase()));
    let unit = |n: usize| format!("{} (sensor units)", axis[n]);
    axes(s, area, &unit(i), &unit(j));
    let _ = writeln!(s, r#"<g clip-path="url(#clip-{name})">"#);
    for (colour, calibrated) in [(RAW, false), (CAL, true)] {
        let points = drawn
            .iter()
            .filter(|d| !calibrated || d.3 == SampleClass::Used)
            .filter_map(|(_, r, c, _)| {
                let v = if calibrated { c } else { r };
                area.point(v[i], v[j])
            });
        path(s, colour, true, points);
    }
    let (cx, cy, r) = (area.px(0.0), area.py(0.0), area.px(rho) - area.px(0.0));
    if r.is_finite() && cx.is_finite() && cy.is_finite() {
        let _ = writeln!(
            s,
            r#"<circle cx="{cx:.1}" cy="{cy:.1}" r="{r:.1}" fill="none" stroke="{REF}" stroke-width="1.2" stroke-dasharray="6 4"/>"#
        );
    }
    s.push_str("</g>\n");
    // Outside the clip: an outlier beyond the frame sits on it.
    crosses(s, drawn, |(_, _, c, _)| area.inside(c[i], c[j]));
    rings(s, drawn, |(_, _, c, _)| area.inside(c[i], c[j]));
    s.push_str("</g>\n");
}

/// The rows of `drawn` the fit did not use, as red crosses at `place`:
/// `x` rejected, `+` screened.
fn crosses(s: &mut String, drawn: &[Drawn], place: impl Fn(&Drawn) -> Option<(f64, f64)>) {
    for (class, mark) in [
        (SampleClass::Rejected, Mark::Cross),
        (SampleClass::Screened, Mark::Plus),
    ] {
        let points: Vec<(f64, f64)> = drawn
            .iter()
            .filter(|d| d.3 == class)
            .filter_map(&place)
            .collect();
        if points.is_empty() {
            continue;
        }
        let _ = write!(
            s,
            r#"<path class="{}" fill="none" stroke="{OUT}" stroke-width="1.6" stroke-linecap="round" d=""#,
            if class == SampleClass::Rejected {
                "rejected"
            } else {
                "screened"
            }
        );
        for (x, y) in points {
            let _ = match mark {
                Mark::Cross => write!(s, "M{:.1} {:.1}l8 8m0 -8l-8 8", x - 4.0, y - 4.0),
                _ => write!(s, "M{:.1} {y:.1}h10M{x:.1} {:.1}v10", x - 5.0, y - 5.0),
            };
        }
        s.push_str("\"/>\n");
    }
}

/// The rows of `drawn` set aside as still periods, as green rings at
/// `place`.
fn rings(s: &mut String, drawn: &[Drawn], place: impl Fn(&Drawn) -> Option<(f64, f64)>) {
    let points: Vec<(f64, f64)> = drawn
        .iter()
        .filter(|d| d.3 == SampleClass::Dwell)
        .filter_map(place)
        .collect();
    if points.is_empty() {
        return;
    }
    let _ = write!(
        s,
        r#"<path class="dwell" fill="none" stroke="{STILL}" stroke-width="1.2" d=""#
    );
    for (x, y) in points {
        let _ = write!(s, "M{:.1} {y:.1}{RING}", x - 3.5);
    }
    s.push_str("\"/>\n");
}

/// A ring of radius 3.5 from its leftmost point (path commands).
const RING: &str = "a3.5 3.5 0 1 0 7 0a3.5 3.5 0 1 0 -7 0";

/// The paper's Fig. 2: norms against the sample index, with the unit line.
fn norms(s: &mut String, drawn: &[Drawn], rows: usize, rho: f64) {
    let norm = |v: [f64; 3]| v[0].hypot(v[1]).hypot(v[2]) / rho;
    let norms: Vec<(usize, f64, f64, SampleClass)> = drawn
        .iter()
        .map(|&(i, r, c, class)| (i, norm(r), norm(c), class))
        .filter(|(_, r, c, _)| r.is_finite() && c.is_finite())
        .collect();
    // The range of the rows used and of the rejected and still rows'
    // calibrated norms (screened rows may lie far off: they sit on the
    // frame).
    let (lo, hi) = norms
        .iter()
        .flat_map(|&(_, r, c, class)| match class {
            SampleClass::Used => [Some(r), Some(c)],
            SampleClass::Rejected | SampleClass::Dwell => [Some(c), None],
            _ => [None, None],
        })
        .flatten()
        .fold((1.0f64, 1.0f64), |(lo, hi), v| (lo.min(v), hi.max(v)));
    let pad = 0.06 * (hi - lo).max(0.02);
    let area = Area {
        left: 75.0,
        top: 530.0,
        width: 1095.0,
        height: 220.0,
        x: (0.0, rows.saturating_sub(1).max(1) as f64),
        y: ((lo - pad).max(0.0), (hi + pad).min(3.0)),
    };
    open_panel(s, "norm", &area, "Norm per sample (paper's Fig. 2)");
    let entries = [
        (RAW, Mark::Line, "raw |y \u{2212} b| / \u{3c1}".to_owned()),
        (
            CAL,
            Mark::Line,
            "calibrated |W (y \u{2212} b)|, rows used".to_owned(),
        ),
        (REF, Mark::Dash, "1".to_owned()),
    ];
    let width = legend_width(&entries);
    legend(s, area.left + area.width - width, area.top - 12.0, &entries);
    axes(s, &area, "sample index", "norm");
    let (y, x0, x1) = (area.py(1.0), area.left, area.left + area.width);
    let _ = writeln!(
        s,
        r#"<g clip-path="url(#clip-norm)">
<line x1="{x0:.1}" y1="{y:.1}" x2="{x1:.1}" y2="{y:.1}" stroke="{REF}" stroke-width="1.2" stroke-dasharray="6 4"/>"#
    );
    for (colour, calibrated) in [(RAW, false), (CAL, true)] {
        let points = norms
            .iter()
            .filter(|n| !calibrated || n.3 == SampleClass::Used)
            .filter_map(|&(i, r, c, _)| area.point(i as f64, if calibrated { c } else { r }));
        path(s, colour, false, points);
    }
    s.push_str("</g>\n");
    let calibrated_norm = |&(i, _, c, _): &Drawn| area.inside(i as f64, norm(c));
    crosses(s, drawn, calibrated_norm);
    rings(s, drawn, calibrated_norm);
    s.push_str("</g>\n");
}

/// Opens a panel group: clip path, frame and title (closed by the caller).
fn open_panel(s: &mut String, name: &str, a: &Area, title: &str) {
    let (l, t, w, h) = (a.left, a.top, a.width, a.height);
    let _ = writeln!(
        s,
        r##"<g class="panel" id="panel-{name}">
<clipPath id="clip-{name}"><rect x="{l}" y="{t}" width="{w}" height="{h}"/></clipPath>
<rect x="{l}" y="{t}" width="{w}" height="{h}" fill="#fafafa" stroke="#999"/>"##
    );
    text(s, l, t - 12.0, PANEL, title);
}

/// Grid lines, tick labels and axis labels of an area.
fn axes(s: &mut String, a: &Area, x_label: &str, y_label: &str) {
    let (top, bottom, left, right) = (a.top, a.top + a.height, a.left, a.left + a.width);
    let grid = r##"stroke="#e3e3e3""##;
    for (v, step) in ticks(a.x) {
        let x = a.px(v);
        let _ = writeln!(
            s,
            r#"<line x1="{x:.1}" y1="{top:.1}" x2="{x:.1}" y2="{bottom:.1}" {grid}/>"#
        );
        text(s, x, bottom + 16.0, TICK_X, &tick_label(v, step));
    }
    for (v, step) in ticks(a.y) {
        let y = a.py(v);
        let _ = writeln!(
            s,
            r#"<line x1="{left:.1}" y1="{y:.1}" x2="{right:.1}" y2="{y:.1}" {grid}/>"#
        );
        text(s, left - 6.0, y + 4.0, TICK_Y, &tick_label(v, step));
    }
    text(s, left + a.width / 2.0, bottom + 36.0, CENTRED, x_label);
    let (x, y) = (left - 52.0, top + a.height / 2.0);
    let rotated = format!(r#"{CENTRED} transform="rotate(-90 {x:.1} {y:.1})""#);
    text(s, x, y, &rotated, y_label);
}

/// Points as round dots (zero-length segments with round caps) or as a
/// line through them.
fn path(s: &mut String, colour: &str, dots: bool, points: impl Iterator<Item = (f64, f64)>) {
    let style = if dots {
        r#"stroke-opacity="0.6" stroke-width="3.2" stroke-linecap="round""#
    } else {
        r#"stroke-width="1.3" stroke-linejoin="round""#
    };
    let _ = write!(s, r#"<path fill="none" stroke="{colour}" {style} d=""#);
    for (k, (x, y)) in points.enumerate() {
        let command = if dots || k == 0 { 'M' } else { 'L' };
        let _ = write!(s, "{command}{x:.1} {y:.1}{}", if dots { "h0" } else { "" });
    }
    s.push_str("\"/>\n");
}

/// How a legend entry is marked.
enum Mark {
    Dot,
    Line,
    Dash,
    /// `x`, a rejected row.
    Cross,
    /// `+`, a screened row.
    Plus,
    /// `o`, a row set aside as a still period's.
    Ring,
}

/// A legend entry: colour, mark, label.
type Entry = (&'static str, Mark, String);

/// About 6.6 px per character at 12 px.
const CHAR_WIDTH: f64 = 6.6;

/// The width [`legend`] takes for `entries`.
fn legend_width(entries: &[Entry]) -> f64 {
    entries
        .iter()
        .map(|(_, _, label)| 50.0 + CHAR_WIDTH * label.chars().count() as f64)
        .sum::<f64>()
        - 22.0
}

/// A row of legend entries starting at `x`.
fn legend(s: &mut String, mut x: f64, y: f64, entries: &[Entry]) {
    for (colour, mark, label) in entries {
        let (cy, end) = (y - 4.0, x + 22.0);
        let dash = if matches!(mark, Mark::Dash) {
            r#" stroke-dasharray="5 3""#
        } else {
            ""
        };
        let (mx, my) = (x + 11.0, cy);
        let _ = match mark {
            Mark::Dot => writeln!(
                s,
                r#"<circle cx="{:.1}" cy="{cy:.1}" r="4" fill="{colour}"/>"#,
                x + 9.0
            ),
            Mark::Line | Mark::Dash => writeln!(
                s,
                r#"<line x1="{x:.1}" y1="{cy:.1}" x2="{end:.1}" y2="{cy:.1}" stroke="{colour}" stroke-width="2"{dash}/>"#
            ),
            Mark::Cross => writeln!(
                s,
                r#"<path fill="none" stroke="{colour}" stroke-width="1.6" stroke-linecap="round" d="M{:.1} {:.1}l8 8m0 -8l-8 8"/>"#,
                mx - 4.0,
                my - 4.0
            ),
            Mark::Plus => writeln!(
                s,
                r#"<path fill="none" stroke="{colour}" stroke-width="1.6" stroke-linecap="round" d="M{:.1} {my:.1}h10M{mx:.1} {:.1}v10"/>"#,
                mx - 5.0,
                my - 5.0
            ),
            Mark::Ring => writeln!(
                s,
                r#"<path fill="none" stroke="{colour}" stroke-width="1.2" d="M{:.1} {my:.1}{RING}"/>"#,
                mx - 3.5
            ),
        };
        text(s, x + 28.0, y, "", label);
        x += 50.0 + CHAR_WIDTH * label.chars().count() as f64;
    }
}

/// A `<text>` at `(x, y)` with `style` attributes, its body escaped.
fn text(s: &mut String, x: f64, y: f64, style: &str, body: &str) {
    let body = escape(body);
    let _ = writeln!(s, r#"<text x="{x:.1}" y="{y:.1}" {style}>{body}</text>"#);
}

/// Text for XML: markup characters as entities, characters XML 1.0 does not
/// allow (controls) as U+FFFD.
pub fn escape(text: &str) -> String {
    let mut out = String::with_capacity(text.len());
    for c in text.chars() {
        match c {
            '&' => out.push_str("&amp;"),
            '<' => out.push_str("&lt;"),
            '>' => out.push_str("&gt;"),
            '"' => out.push_str("&quot;"),
            '\'' => out.push_str("&apos;"),
            '\t' | '\n' | '\r' => out.push(' '),
            c if c.is_control() || c == '\u{fffe}' || c == '\u{ffff}' => out.push('\u{fffd}'),
            c => out.push(c),
        }
    }
    out
}

/// The smallest "nice" step (1, 2 or 5 times a power of ten) that cuts
/// `span` into at most 8 intervals.
fn nice_step(span: f64) -> f64 {
    let raw = span / 8.0;
    let power = 10f64.powf(raw.log10().floor());
    let m = raw / power;
    let nice = [1.0, 2.0, 5.0].into_iter().find(|&n| m <= n * (1.0 + 1e-9));
    power * nice.unwrap_or(10.0)
}

/// `value` rounded up to a multiple of half a nice step.
fn nice_ceiling(value: f64) -> f64 {
    let step = nice_step(value) / 2.0;
    let up = (value / step).ceil() * step;
    if up.is_finite() && up > 0.0 {
        up
    } else {
        1.0
    }
}

/// Tick values inside `range`, each with the step.
fn ticks(range: (f64, f64)) -> Vec<(f64, f64)> {
    let step = nice_step(range.1 - range.0);
    if !(step.is_finite() && step > 0.0) {
        return Vec::new();
    }
    let (first, last) = (
        (range.0 / step).ceil() as i64,
        (range.1 / step).floor() as i64,
    );
    (first..=last.min(first + 20))
        .map(|k| (k as f64 * step, step))
        .collect()
}

/// A tick label with as many decimals as the step needs.
fn tick_label(value: f64, step: f64) -> String {
    let value = value + 0.0; // no "-0"
    if value != 0.0 && (value.abs() >= 1e6 || step < 1e-4) {
        return format!("{value:.1e}");
    }
    let decimals = (-step.log10().floor()).max(0.0) as usize;
    format!("{value:.decimals$}")
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Matrix3, Vector3};

    #[test]
    fn nice_numbers() {
        assert_eq!((nice_step(10.0), nice_step(0.37)), (2.0, 0.05));
        assert_eq!(nice_ceiling(437.0), 450.0);
        assert_eq!(tick_label(-0.0, 0.5), "0.0");
        assert_eq!(tick_label(250.0, 50.0), "250");
        assert_eq!(tick_label(0.05, 0.05), "0.05");
        assert_eq!(ticks((-1.0, 1.0)).len(), 5);
    }

    #[test]
    fn escapes_markup_and_controls() {
        let escaped = escape("a<b>&\"'\u{1}\n");
        assert_eq!(escaped, "a&lt;b&gt;&amp;&quot;&apos;\u{fffd} ");
    }

    #[test]
    fn four_finite_panels() {
        let b = Vector3::new(10.0, -5.0, 2.0);
        let cal = Calibration::from_nalgebra(b, Matrix3::identity() * 0.02).expect("valid");
        let mut samples: Vec<[f64; 3]> = (0..50)
            .map(|i| {
                let a = f64::from(i) * 0.4;
                [50.0 * a.cos(), 50.0 * a.sin(), 40.0 * (a * 0.3).sin()]
            })
            .collect();
        samples.extend([[f64::NAN, 0.0, 0.0], [1e300, 0.0, 0.0], [80.0, 0.0, 0.0]]);
        let mut classes = vec![SampleClass::Used; 50];
        classes.extend([
            SampleClass::Dropped(mag_cal_core::Rule::NonFinite),
            SampleClass::Screened,
            SampleClass::Rejected,
        ]);
        // A still period at the end: one reading, set aside 3 times.
        samples.extend([[60.0, 0.0, 0.0]; 3]);
        classes.extend([SampleClass::Dwell; 3]);
        let title = PlotTitle {
            source: "<a&b>.csv",
            method: "adc2",
            ls: "ls9",
            radial_rms: 0.01,
            fit_error: 0.012,
            residual_limit: Some(0.05),
            robust: true,
        };
        let svg = plot(&samples, &classes, &cal, &title);
        assert!(svg.starts_with("<svg") && svg.trim_end().ends_with("</svg>"));
        assert_eq!(svg.matches("<g class=\"panel\"").count(), 4);
        assert_eq!(svg.matches("<g").count(), svg.matches("</g>").count());
        assert!(svg.contains("&lt;a&amp;b&gt;.csv"));
        assert!(!svg.contains("NaN") && !svg.contains("inf"), "{svg}");
        assert!(
            svg.contains("56 rows: 50 used, 1 dropped, 3 still, 1 screened, 1 rejected;"),
            "{svg}"
        );
        assert!(svg.contains("rejected (1): |W (y \u{2212} b)| off 1 by &gt; 0.0500"));
        assert!(svg.contains("screened out (1; beyond the frame: on its edge)"));
        assert!(svg.contains(">still, set aside (3)</text>"), "{svg}");
        // One cross per outlier in each of the four panels, and one ring
        // per still row.
        assert_eq!(svg.matches("<path class=\"rejected\"").count(), 4);
        assert_eq!(svg.matches("<path class=\"screened\"").count(), 4);
        let rings: Vec<&str> = svg
            .split("<path class=\"dwell\"")
            .skip(1)
            .map(|p| p.split("/>").next().unwrap_or_default())
            .collect();
        assert_eq!(rings.len(), 4, "{svg}");
        assert!(
            rings.iter().all(|p| p.matches(RING).count() == 3),
            "{rings:?}"
        );
        assert_eq!(svg, plot(&samples, &classes, &cal, &title), "deterministic");

        // A clean plain fit: no crosses, no cross legend.
        let used = vec![SampleClass::Used; 50];
        let plain = PlotTitle {
            robust: false,
            residual_limit: None,
            ..title
        };
        let svg = plot(&samples[..50], &used, &cal, &plain);
        assert!(!svg.contains("rejected (") && !svg.contains("screened out"));
        assert!(!svg.contains("still, set aside") && !svg.contains("class=\"dwell\""));
        assert!(svg.contains("--plain") && svg.contains("50 rows: 50 used, 0 dropped"));
    }
}
