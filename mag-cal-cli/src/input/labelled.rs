//! Labelled values: lines that name their numbers, as Arduino sketches
//! print them.
//!
//! ```text
//! Mx 19 My -129 Mz 174
//! X: 12.30  Y: -4.50  Z: 6.70  uT
//! Mag X: 12.30    Y: -4.50    Z: 6.70 uTesla
//! ax=0.1 ay=0.2 az=9.8 gx=0 gy=0 gz=0 mx=19 my=-129 mz=174
//! Acc: 0.1 0.2 9.8 Gyro: 0 0 0 Mag: 19 -129 174
//! Scaled. Acc (mg) [ 1.0, 2.0, 3.0 ], Gyr (DPS) [ ... ], Mag (uT) [ 19.0, -12.9, 17.4 ], Tmp (C) [ 25.0 ]
//! {"mx": 19, "my": -129, "mz": 174}
//! ```
//!
//! A line is cut into words and numbers at white space and at `, ; : = [ ]
//! { } | " '`; `name(unit)` is the word `name` and the unit. Each number takes
//! its name from the words before it:
//!
//! - an axis word (`X`, `Mx`, `mag_x`, `Accel_X`: a name of letters, then
//!   `x`, `y` or `z`) names an axis of a sensor: the letters before the axis
//!   (`mag_x`), else the words before it (`Mag X`), else the sensor of the
//!   number before it on the line (`Y:` after `Mag X: 1`), else none (a
//!   bare `X`);
//! - other words (`Acc:`, `Mag (uT) [`) name a group of the numbers that
//!   follow without words between them; a group of three is that sensor's
//!   x, y, z;
//! - unit words (`uT`, `m/s^2`, `(mg)`, [`UNITS`]) are no names: after a
//!   number they are its unit, after a group's name the group's.
//!
//! `--columns` with three numbers picks the line's n-th numbers (from 1),
//! else it takes three names. A number's name is its sensor's and the axis
//! letter, compacted as header names are (lower case, without `_ - .` and
//! spaces):
//! `Mag X:` is `magx`, `Mx` is `mx`, `Mag (uT) [a, b, c]` is `magx, magy,
//! magz`, a bare `X:` is `x`; numbers without an axis are named by their
//! label (`Tmp (C) [ 25 ]` is `tmp`); a unit in brackets after a name
//! (`x[uT]`, `x (uT)`) must match too. An x, y, z of one sensor on one
//! line is a reading; its kind is its three names and unit.
//!
//! A line that holds the chosen values is a sample; one that holds some of
//! them (a serial line cut short) a non-finite row, which the fit drops and
//! counts; any other line (a banner, another sensor's line, the same labels
//! in another unit) is skipped and counted.
//!
//! Which reading is the magnetometer's, from the first
//! [`SNIFF_LINES`](super::SNIFF_LINES) lines: the one kind whose sensor
//! words name a magnetometer (the stems of [`mag_axis`](super::mag_axis):
//! `Mag`, `M`, `Magnetometer`, `mx`, ...; never a word containing `cal`)
//! or whose unit is a magnetic
//! field's ([`MAG_UNITS`]: `uT`, `gauss`, `mG`, ...); when no kind says so
//! and the lines hold a single kind, a bare `X: Y: Z:` without a unit, that
//! one. Anything else (no kind, several) is refused, listing the kinds found
//! and how to pick one with `--columns`.

use std::collections::{HashMap, HashSet};

use super::{excerpt, number, Accel, ColumnsUsed, Picked, Skipped, Table, ACCEL_NAMES, MAG_STEMS};
use crate::cli::Columns;
use crate::error::CliError;

/// Unit words (compared without case; `(...)` is a unit too): not names.
///
/// Only words that sketches print after a number; single letters that
/// sketches use as labels (`a`, `m`, `s`) are left out, except `g` and `c`
/// (`9.8 g`, `25 deg C`).
pub const UNITS: [&str; 41] = [
    "ut",
    "µt",
    "μt",
    "utesla",
    "microtesla",
    "nt",
    "nanotesla",
    "gauss",
    "ga",
    "mg",
    "milligauss",
    "mgauss",
    "g",
    "m/s^2",
    "m/s²",
    "m/s2",
    "m/s/s",
    "dps",
    "deg/s",
    "°/s",
    "rad/s",
    "rads/s",
    "radians/s",
    "degrees/s",
    "rpm",
    "deg",
    "degrees",
    "°",
    "c",
    "°c",
    "degc",
    "hz",
    "khz",
    "hpa",
    "pa",
    "kpa",
    "mbar",
    "%",
    "lux",
    "ms",
    "us",
];

/// Units of a magnetic field (compared without case, except `mG`:
/// milligauss, where `mg` is the milli-g of an accelerometer, as in
/// SparkFun's `Acc (mg)` and Kris Winer's MPU-9250 sketches, which print
/// `ax = ... mg` and `mx = ... mG`).
pub const MAG_UNITS: [&str; 11] = [
    "ut",
    "µt",
    "μt",
    "utesla",
    "microtesla",
    "nt",
    "nanotesla",
    "gauss",
    "ga",
    "milligauss",
    "mgauss",
];

/// Whether `word` is a unit ([`UNITS`], or in round brackets).
fn is_unit(word: &str) -> bool {
    (word.len() > 2 && word.starts_with('(') && word.ends_with(')'))
        || UNITS.iter().any(|u| u.eq_ignore_ascii_case(word))
}

/// Whether `unit` is a magnetic field's ([`MAG_UNITS`] or `mG`).
fn is_mag_unit(unit: &str) -> bool {
    unit == "mG" || MAG_UNITS.iter().any(|u| u.eq_ignore_ascii_case(unit))
}

/// A unit without its round brackets.
fn bare_unit(unit: &str) -> &str {
    unit.strip_prefix('(')
        .and_then(|u| u.strip_suffix(')'))
        .unwrap_or(unit)
}

/// A name compacted for comparison: lower case, without `_ - .` and spaces.
pub fn compact(name: &str) -> String {
    name.chars()
        .filter(|c| !matches!(c, '_' | '-' | '.' | ' '))
        .flat_map(char::to_lowercase)
        .collect()
}

/// One number of a labelled line, named.
#[derive(Clone, Debug, PartialEq)]
pub struct Value {
    /// The number.
    pub value: f64,
    /// The sensor, compacted (`mag`, `m`, `accel`; empty for a bare axis or
    /// no label).
    pub sensor: String,
    /// The axis (0, 1, 2 for x, y, z), if named or given by a group of three.
    pub axis: Option<usize>,
    /// The name `--columns` compares with (see the module docs); empty
    /// when the number has no label.
    pub name: String,
    /// The name as printed, for messages (`Mag X`, `Mx`, `Mag x`).
    pub display: String,
    /// Its unit, as printed without brackets: its own, or its reading's.
    pub unit: Option<String>,
    /// Whether its sensor words name a magnetometer.
    pub mag_words: bool,
    /// Whether its axis is its place in a group of three (`Acc: 1 2 3`),
    /// not an axis word.
    pub by_place: bool,
}

impl Value {
    /// The name and unit for a report: `Mag X (uT)`; `--columns` takes it.
    pub fn label(&self) -> String {
        match &self.unit {
            Some(unit) => format!("{} ({unit})", self.display),
            None => self.display.clone(),
        }
    }
}

/// Splits a line into words and numbers (see the module docs).
fn tokens(line: &str) -> Vec<&str> {
    let mut out = Vec::new();
    for token in line
        .split(|c: char| c.is_whitespace() || ",;:=[]{}|\"'".contains(c))
        .filter(|t| !t.is_empty())
    {
        // `Mag(uT)`: the name, then the unit.
        match token.find('(') {
            Some(open) if open > 0 && token.ends_with(')') => {
                out.push(&token[..open]);
                out.push(&token[open..]);
            }
            _ => out.push(token),
        }
    }
    out
}

/// `word` as an axis word: the letters before the axis, trimmed of `_ - .`,
/// and the axis.
fn axis_word(word: &str) -> Option<(&str, usize)> {
    let axis = match word.chars().last()?.to_ascii_lowercase() {
        'x' => 0,
        'y' => 1,
        'z' => 2,
        _ => return None,
    };
    let stem = word[..word.len() - 1].trim_end_matches(['_', '-', '.']);
    (stem.len() <= 16 && stem.chars().all(|c| c.is_ascii_alphabetic())).then_some((stem, axis))
}

/// Whether the sensor words name a raw magnetometer: one of them, compacted
/// and without a leading or trailing `raw`, is a `MAG_STEMS` stem other
/// than the empty one, and none contains `cal`.
fn names_magnetometer(words: &str) -> bool {
    let words: Vec<String> = words.split(' ').map(compact).collect();
    !words.iter().any(|w| w.contains("cal"))
        && words.iter().any(|w| {
            let w = w.strip_prefix("raw").unwrap_or(w);
            let w = w.strip_suffix("raw").unwrap_or(w);
            !w.is_empty() && MAG_STEMS.contains(&w)
        })
}

/// A number during [`values`]: its sensor (display, compact), axis and the
/// word that named the axis when it carried the sensor too (`Mx`).
struct Draft<'a> {
    value: f64,
    sensor: (String, String),
    axis: Option<usize>,
    word: Option<&'a str>,
    axis_text: &'a str,
    group: Option<usize>,
    unit: Option<&'a str>,
}

/// The sensor named by label words: as shown, and compacted. At most the
/// last [`SENSOR_WORDS`] words and [`SENSOR_CHARS`] characters: a label is
/// a word or two (`Mag`, `Accel`, `Mag raw`), and each number's name holds
/// its sensor's, so a hostile line of one long label and many numbers must
/// not make the names quadratic in its length.
fn sensor_of(words: &[&str]) -> (String, String) {
    let words = &words[words.len().saturating_sub(SENSOR_WORDS)..];
    let shown: String = words.join(" ").chars().take(SENSOR_CHARS).collect();
    let compacted = compact(&shown);
    (shown, compacted)
}

/// See [`sensor_of`].
const SENSOR_WORDS: usize = 3;

/// See [`sensor_of`].
const SENSOR_CHARS: usize = 40;

/// The numbers of a line, named (see the module docs).
pub fn values(line: &str) -> Vec<Value> {
    let mut drafts: Vec<Draft<'_>> = Vec::new();
    let mut run: Vec<&str> = Vec::new();
    // The sensor of the number before, for a bare axis after it.
    let mut sensor = (String::new(), String::new());
    // The open group: the index of its first number.
    let mut group: Option<usize> = None;
    for token in tokens(line) {
        let Some(value) = number(token) else {
            run.push(token);
            continue;
        };
        let lead = run.iter().take_while(|w| is_unit(w)).count();
        if let (Some(last), Some(unit)) = (drafts.last_mut(), run.first().filter(|_| lead > 0)) {
            last.unit.get_or_insert(unit);
        }
        let label = &run[lead..];
        let trail = label.iter().rev().take_while(|w| is_unit(w)).count();
        let (words, units) = label.split_at(label.len() - trail);
        // A word ending in '.' ends a sentence before the label
        // (`Scaled. Acc (mg) [`).
        let start = words[..words.len().saturating_sub(1)]
            .iter()
            .rposition(|w| w.ends_with('.'))
            .map_or(0, |i| i + 1);
        let words = &words[start..];
        let unit = units.first().copied();
        let mut draft = Draft {
            value,
            sensor: sensor.clone(),
            axis: None,
            word: None,
            axis_text: "",
            group: None,
            unit,
        };
        let axis = words
            .split_last()
            .and_then(|(&last, before)| Some((last, before, axis_word(last)?)));
        match axis {
            Some((last, before, (stem, axis))) => {
                if !stem.is_empty() {
                    let words: Vec<&str> = before.iter().chain([&stem]).copied().collect();
                    sensor = sensor_of(&words);
                    draft.word = Some(last);
                } else if !before.is_empty() {
                    sensor = sensor_of(before);
                }
                draft.sensor = sensor.clone();
                draft.axis = Some(axis);
                draft.axis_text = &last[last.len() - 1..];
                group = None;
            }
            None if !words.is_empty() => {
                sensor = sensor_of(words);
                draft.sensor = sensor.clone();
                group = Some(drafts.len());
                draft.group = group;
            }
            None => {
                draft.group = group;
                if group.is_none() {
                    // No label: no sensor.
                    draft.sensor = (String::new(), String::new());
                }
            }
        }
        drafts.push(draft);
        run.clear();
    }
    if let (Some(last), Some(&unit)) = (drafts.last_mut(), run.first()) {
        if is_unit(unit) {
            last.unit.get_or_insert(unit);
        }
    }
    name(drafts)
}

/// Names the drafts of a line: axes of groups of three, names, displays and
/// the unit of each reading (in time linear in the drafts: a hostile line
/// may hold a million numbers).
fn name(drafts: Vec<Draft<'_>>) -> Vec<Value> {
    // A group's members follow its first: their count, each one's place,
    // and the group's unit (its name's or its first member's with one).
    let mut size = vec![0usize; drafts.len()];
    let mut place = vec![0usize; drafts.len()];
    let mut group_unit: Vec<Option<&str>> = vec![None; drafts.len()];
    for (i, d) in drafts.iter().enumerate() {
        if let Some(g) = d.group {
            place[i] = size[g];
            size[g] += 1;
            if group_unit[g].is_none() {
                group_unit[g] = d.unit;
            }
        }
    }
    // A sensor's unit: the first among its numbers with an axis word.
    let mut sensor_unit: HashMap<&str, &str> = HashMap::new();
    for d in &drafts {
        if let (Some(_), None, Some(unit)) = (d.axis, d.group, d.unit) {
            sensor_unit.entry(d.sensor.1.as_str()).or_insert(unit);
        }
    }
    let xyz = ["x", "y", "z"];
    let mut values = Vec::with_capacity(drafts.len());
    for (i, d) in drafts.iter().enumerate() {
        let (display, compact_name) = (&d.sensor.0, &d.sensor.1);
        let (name, shown, axis, unit) = match (d.axis, d.group) {
            (Some(axis), _) => {
                let shown = match d.word {
                    Some(word) => word.to_owned(),
                    None if display.is_empty() => d.axis_text.to_owned(),
                    None => format!("{display} {}", d.axis_text),
                };
                let unit = sensor_unit.get(compact_name.as_str()).copied();
                (
                    format!("{compact_name}{}", xyz[axis]),
                    shown,
                    Some(axis),
                    unit,
                )
            }
            (None, Some(g)) => {
                let k = place[i];
                let unit = group_unit[g];
                match size[g] {
                    1 => (compact_name.clone(), display.clone(), None, unit),
                    3 => (
                        format!("{compact_name}{}", xyz[k]),
                        format!("{display} {}", xyz[k]),
                        Some(k),
                        unit,
                    ),
                    _ => (
                        format!("{compact_name}{}", k + 1),
                        format!("{display} {}", k + 1),
                        None,
                        unit,
                    ),
                }
            }
            (None, None) => (String::new(), String::new(), None, d.unit),
        };
        values.push(Value {
            value: d.value,
            sensor: compact_name.clone(),
            axis,
            name,
            display: shown,
            unit: unit.map(|u| bare_unit(u).to_owned()),
            mag_words: names_magnetometer(display),
            by_place: d.axis.is_none() && axis.is_some(),
        });
    }
    values
}

/// The readings of a line: per sensor with exactly one x, one y and one z,
/// their indices in `values`, in order of the x.
pub fn readings(values: &[Value]) -> Vec<[usize; 3]> {
    let mut axes: HashMap<&str, [Vec<usize>; 3]> = HashMap::new();
    for (i, v) in values.iter().enumerate() {
        if let Some(axis) = v.axis {
            axes.entry(v.sensor.as_str()).or_default()[axis].push(i);
        }
    }
    let mut out: Vec<[usize; 3]> = axes
        .values()
        .filter_map(
            |[x, y, z]| match (x.as_slice(), y.as_slice(), z.as_slice()) {
                ([x], [y], [z]) => Some([*x, *y, *z]),
                _ => None,
            },
        )
        .collect();
    out.sort_unstable();
    out
}

/// A kind of reading: its names, unit and whether it is the
/// magnetometer's by its words or unit.
#[derive(Clone, Debug, PartialEq, Eq, Hash)]
struct Kind {
    names: [String; 3],
    unit: Option<String>,
    labels: [String; 3],
    mag: bool,
    anonymous: bool,
}

impl Kind {
    fn of(values: &[Value], [x, y, z]: [usize; 3]) -> Self {
        let unit = values[x].unit.clone();
        Kind {
            names: [x, y, z].map(|i| values[i].name.clone()),
            labels: [x, y, z].map(|i| values[i].display.clone()),
            mag: values[x].mag_words || unit.as_deref().is_some_and(is_mag_unit),
            anonymous: values[x].sensor.is_empty(),
            unit,
        }
    }

    /// `Mag X, Mag Y, Mag Z (uT)`.
    fn describe(&self) -> String {
        let names = self
            .labels
            .iter()
            .map(|l| excerpt(l))
            .collect::<Vec<_>>()
            .join(", ");
        match &self.unit {
            Some(unit) => format!("{names} ({})", excerpt(unit)),
            None => names,
        }
    }

    /// The `--columns` value that picks this kind among `kinds`: its
    /// names, with its unit (`x[uT]`) when another kind has the same names.
    fn option(&self, kinds: &[&Kind]) -> String {
        let same_names = kinds
            .iter()
            .any(|k| k.names == self.names && k.unit != self.unit);
        let names = self.names.iter().map(|n| excerpt(n));
        match &self.unit {
            Some(unit) if same_names => names
                .map(|n| format!("{n}[{}]", excerpt(unit)))
                .collect::<Vec<_>>()
                .join(","),
            _ => names.collect::<Vec<_>>().join(","),
        }
    }

    fn pick(&self) -> Pick {
        Pick::Names(self.names.clone().map(|name| Want {
            name,
            unit: Some(self.unit.clone()),
        }))
    }
}

/// One value to find on a line: by name, and unit when given.
#[derive(Clone, Debug, PartialEq)]
struct Want {
    name: String,
    /// `None`: any unit; `Some(u)`: exactly `u` (`Some(None)`: none).
    unit: Option<Option<String>>,
}

impl Want {
    /// A `--columns` name: compacted, a trailing `(unit)` or `[unit]`
    /// names the unit.
    fn from_option(name: &str) -> Self {
        let trimmed = name.trim();
        let unit = trimmed
            .strip_suffix(')')
            .and_then(|t| t.rfind('(').map(|i| (i, &t[i + 1..])))
            .or_else(|| {
                trimmed
                    .strip_suffix(']')
                    .and_then(|t| t.rfind('[').map(|i| (i, &t[i + 1..])))
            });
        match unit {
            Some((i, unit)) => Want {
                name: compact(&trimmed[..i]),
                unit: Some(Some(unit.trim().to_owned())),
            },
            None => Want {
                name: compact(trimmed),
                unit: None,
            },
        }
    }

    fn matches(&self, value: &Value) -> bool {
        value.name == self.name
            && self
                .unit
                .as_ref()
                .is_none_or(|unit| match (unit, &value.unit) {
                    (None, None) => true,
                    (Some(a), Some(b)) => a.eq_ignore_ascii_case(b),
                    _ => false,
                })
    }
}

/// How the values are picked from a line.
#[derive(Clone, Debug, PartialEq)]
enum Pick {
    /// By name (and unit).
    Names([Want; 3]),
    /// The n-th numbers of the line, 1-based.
    Fields([usize; 3]),
}

/// What a line holds of the picked values.
enum Found {
    /// All three: their indices in the line's values.
    All([usize; 3]),
    /// Some of them, or too few numbers: why the line cannot be read.
    Partial(String),
    /// None of them (or another reading of the same names).
    Absent,
}

impl Pick {
    /// From `--columns`: numbers are field numbers, anything else names.
    fn from_columns(Columns(names): &Columns) -> Self {
        match names.each_ref().map(|n| super::field_number(n)) {
            [Some(a), Some(b), Some(c)] => Pick::Fields([a, b, c]),
            _ => Pick::Names(names.each_ref().map(|n| Want::from_option(n))),
        }
    }

    fn find(&self, values: &[Value]) -> Found {
        match self {
            Pick::Fields(fields) => {
                let needed = fields.iter().copied().max().unwrap_or(0);
                if values.len() >= needed {
                    Found::All(fields.map(|f| f - 1))
                } else if values.is_empty() {
                    Found::Absent
                } else {
                    Found::Partial(format!(
                        "{} numbers, expected at least {needed}",
                        values.len()
                    ))
                }
            }
            Pick::Names(wants) => {
                let full = wants
                    .each_ref()
                    .map(|w| values.iter().position(|v| w.matches(v)));
                if let [Some(x), Some(y), Some(z)] = full {
                    return Found::All([x, y, z]);
                }
                let named = wants
                    .each_ref()
                    .map(|w| values.iter().any(|v| v.name == w.name));
                match named {
                    [true, true, true] | [false, false, false] => Found::Absent,
                    _ => {
                        let missing: Vec<String> = wants
                            .iter()
                            .zip(named)
                            .filter(|(_, found)| !found)
                            .map(|(w, _)| format!("'{}'", excerpt(&w.name)))
                            .collect();
                        Found::Partial(format!("no value named {}", missing.join(", ")))
                    }
                }
            }
        }
    }
}

/// Whether `line` holds a labelled reading that makes the input a
/// labelled log: an x, y, z named by axis words, or a group of three named
/// by a sensor word (a magnetometer stem, or an accelerometer's or gyroscope's:
/// a CSV row such as `2024-01-01,1,2,3` or `NoFix,1,2,3` is no reading).
pub fn holds_reading(line: &str) -> bool {
    const OTHER_SENSORS: [&str; 7] = [
        "acc",
        "accel",
        "acceleration",
        "accelerometer",
        "gyr",
        "gyro",
        "gyroscope",
    ];
    let values = values(line);
    readings(&values).iter().any(|&[x, _, _]| {
        let v = &values[x];
        !v.by_place || v.mag_words || OTHER_SENSORS.contains(&v.sensor.as_str())
    })
}

/// Reads a labelled log (see the module docs): `lines` are its content
/// lines, `sniff` how many of the first decide which values to take.
pub fn read(
    lines: &[(usize, &str)],
    sniff: usize,
    columns: Option<&Columns>,
    accel: Accel<'_>,
    source_name: &str,
) -> Result<Table, CliError> {
    let head: Vec<Vec<Value>> = lines.iter().take(sniff).map(|(_, l)| values(l)).collect();
    let (pick, picked) = match columns {
        Some(columns) => {
            let pick = Pick::from_columns(columns);
            let picked = match &pick {
                Pick::Fields(fields) => Picked::Fields(*fields),
                Pick::Names(_) => Picked::Named,
            };
            (pick, picked)
        }
        None => (detect(&head, source_name)?, Picked::Labels),
    };
    // Names without a unit that the first lines give in several units (raw
    // counts and uT, say) would mix them: the unit must be named.
    if let Pick::Names(wants) = &pick {
        let mut units: Vec<Option<String>> = Vec::new();
        for values in &head {
            if let Found::All([x, _, _]) = pick.find(values) {
                if !units.contains(&values[x].unit) {
                    units.push(values[x].unit.clone());
                }
            }
        }
        if wants.iter().all(|w| w.unit.is_none()) && units.len() > 1 {
            let listed: Vec<String> = units
                .iter()
                .map(|u| u.as_deref().map_or("no unit".to_owned(), excerpt))
                .collect();
            let example = units.iter().flatten().next().map_or(String::new(), |u| {
                let names: Vec<String> = wants
                    .iter()
                    .map(|w| format!("{}[{}]", excerpt(&w.name), excerpt(u)))
                    .collect();
                format!(" (e.g. --columns {})", names.join(","))
            });
            return Err(CliError::Input(format!(
                "{source_name}: the values named {} come in {} units ({}); add the unit \
                 to each name{example}",
                wants
                    .iter()
                    .map(|w| format!("'{}'", excerpt(&w.name)))
                    .collect::<Vec<_>>()
                    .join(", "),
                units.len(),
                listed.join(", "),
            )));
        }
    }
    // The first line that holds the picked values names them, and decides
    // the accelerometer's.
    let first = lines
        .iter()
        .map(|(_, l)| values(l))
        .find_map(|v| match pick.find(&v) {
            Found::All(at) => Some((v, at)),
            _ => None,
        });
    let Some((first_values, first_at)) = first else {
        return Err(no_reading(&pick, &head, lines, source_name));
    };
    let accel_pick = match accel {
        Accel::None => None,
        Accel::Named(columns) => {
            let pick = Pick::from_columns(columns);
            if !matches!(pick.find(&first_values), Found::All(_)) {
                return Err(CliError::Input(format!(
                    "{source_name}: --accel-columns: the first line with the magnetometer's \
                     values has no values named so (it has: {})",
                    listing(&first_values)
                )));
            }
            Some(pick)
        }
        Accel::Detect => ACCEL_NAMES.iter().find_map(|names| {
            let pick = Pick::Names(names.map(|n| Want {
                name: compact(n),
                unit: None,
            }));
            match pick.find(&first_values) {
                Found::All(at) if at != first_at => Some(pick),
                _ => None,
            }
        }),
    };
    let names = first_at.map(|i| first_values[i].label());
    let columns = ColumnsUsed {
        names: names.iter().all(|n| !n.is_empty()).then_some(names),
        picked,
    };

    let mut samples = Vec::new();
    let mut accel_rows = accel_pick.as_ref().map(|_| Vec::new());
    let mut skipped = Skipped::default();
    let mut first_error = None;
    for &(line_no, line) in lines {
        let values = values(line);
        match pick.find(&values) {
            Found::All(at) => {
                samples.push(at.map(|i| values[i].value));
                if let (Some(rows), Some(pick)) = (accel_rows.as_mut(), accel_pick.as_ref()) {
                    rows.push(match pick.find(&values) {
                        Found::All(at) => at.map(|i| values[i].value),
                        _ => [f64::NAN; 3],
                    });
                }
            }
            Found::Partial(why) => {
                skipped.unreadable += 1;
                skipped.add(|| format!("line {line_no}: {why}"));
                first_error.get_or_insert(CliError::Parse {
                    line: line_no,
                    message: why,
                });
                samples.push([f64::NAN; 3]);
                if let Some(rows) = accel_rows.as_mut() {
                    rows.push([f64::NAN; 3]);
                }
            }
            Found::Absent => {
                skipped.no_reading += 1;
                skipped.add(|| format!("line {line_no}: '{}'", excerpt(line.trim())));
            }
        }
    }
    Ok(Table {
        samples,
        accel: accel_rows,
        columns,
        skipped,
    })
}

/// The magnetometer's kind among the readings of the first lines (see the
/// module docs), or the refusal that lists them.
fn detect(head: &[Vec<Value>], source_name: &str) -> Result<Pick, CliError> {
    let mut kinds: Vec<Kind> = Vec::new();
    let mut seen = HashSet::new();
    for values in head {
        for at in readings(values) {
            let kind = Kind::of(values, at);
            if seen.insert(kind.clone()) {
                kinds.push(kind);
            }
        }
    }
    let mags: Vec<&Kind> = kinds.iter().filter(|k| k.mag).collect();
    // At most this many kinds in a message.
    const LISTED: usize = 8;
    let list = |kinds: &[&Kind]| {
        let mut listed: Vec<String> = kinds.iter().take(LISTED).map(|k| k.describe()).collect();
        if kinds.len() > LISTED {
            listed.push(format!("... {} more", kinds.len() - LISTED));
        }
        listed.join("; ")
    };
    let all: Vec<&Kind> = kinds.iter().collect();
    match (mags.as_slice(), all.as_slice()) {
        ([one], _) => Ok(one.pick()),
        // (A unit that is not a field's says it is another sensor.)
        ([], [one]) if one.anonymous && one.unit.is_none() => Ok(one.pick()),
        ([], _) => Err(CliError::Input(format!(
            "{source_name}: labelled values, but none is the magnetometer's by its \
             label (Mag, M, mx, ...) or unit (uT, gauss, mG): found {}; pass \
             --columns with the three labels to use (e.g. --columns {}) or their \
             numbers in the line (e.g. --columns 1,2,3)",
            list(&all),
            all.first()
                .map_or(String::from("mx,my,mz"), |k| k.option(&all)),
        ))),
        (several, _) => Err(CliError::Input(format!(
            "{source_name}: labelled values with {} magnetometer readings: {}; pass \
             --columns with the labels of the one to use (e.g. --columns {})",
            several.len(),
            list(several),
            several[0].option(several),
        ))),
    }
}

/// The labelled values of a line, for a message: `Mx, My, Mz, t`.
fn listing(values: &[Value]) -> String {
    let names: Vec<String> = values
        .iter()
        .take(40)
        .map(|v| {
            if v.display.is_empty() {
                "(unlabelled)".to_owned()
            } else {
                excerpt(&v.label())
            }
        })
        .collect();
    names.join(", ")
}

/// The error when no line holds the picked values.
fn no_reading(
    pick: &Pick,
    head: &[Vec<Value>],
    lines: &[(usize, &str)],
    source_name: &str,
) -> CliError {
    let example = head
        .iter()
        .zip(lines)
        .find(|(v, _)| !readings(v).is_empty())
        .map(|(v, (line_no, _))| format!(" (line {line_no} has: {})", listing(v)))
        .unwrap_or_default();
    let what = match pick {
        Pick::Fields(f) => format!("{}, {} and {} numbers", f[0], f[1], f[2]),
        Pick::Names(w) => format!(
            "values named {}",
            w.iter()
                .map(|w| format!("'{}'", excerpt(&w.name)))
                .collect::<Vec<_>>()
                .join(", ")
        ),
    };
    CliError::Input(format!("{source_name}: no line holds {what}{example}"))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn names(line: &str) -> Vec<(String, Option<String>)> {
        values(line).into_iter().map(|v| (v.name, v.unit)).collect()
    }

    fn n(name: &str, unit: Option<&str>) -> (String, Option<String>) {
        (name.to_owned(), unit.map(str::to_owned))
    }

    #[test]
    fn numbers_are_named_by_the_words_before_them() {
        assert_eq!(
            names("Mx 19 My -129 Mz 174"),
            [n("mx", None), n("my", None), n("mz", None)]
        );
        assert_eq!(
            names("X: 12.30  Y: -4.50  Z: 6.70  uT"),
            [n("x", Some("uT")), n("y", Some("uT")), n("z", Some("uT"))]
        );
        assert_eq!(
            names("\t\tMag X: 12.30 \tY: -4.50 \tZ: 6.70 uTesla "),
            [
                n("magx", Some("uTesla")),
                n("magy", Some("uTesla")),
                n("magz", Some("uTesla"))
            ]
        );
        assert_eq!(
            names("Accel_X: 0.1 \tY: 0.2 \tZ: 9.8 m/s^2 Mag X: 1 Y: 2 Z: 3 uT"),
            [
                n("accelx", Some("m/s^2")),
                n("accely", Some("m/s^2")),
                n("accelz", Some("m/s^2")),
                n("magx", Some("uT")),
                n("magy", Some("uT")),
                n("magz", Some("uT")),
            ]
        );
        assert_eq!(
            names("Mag X: 0.12 gauss\tY: -0.34 gauss\tZ: 0.45 gauss"),
            [
                n("magx", Some("gauss")),
                n("magy", Some("gauss")),
                n("magz", Some("gauss"))
            ]
        );
        assert_eq!(
            names("t=5 mag_x=1.5, mag_y=2, mag_z=3"),
            [
                n("t", None),
                n("magx", None),
                n("magy", None),
                n("magz", None)
            ]
        );
        assert_eq!(
            names("Acc: 1 2 3 Gyro: 4 5 6 Mag: 7 8 9 Quat: 1 0 0 0"),
            [
                n("accx", None),
                n("accy", None),
                n("accz", None),
                n("gyrox", None),
                n("gyroy", None),
                n("gyroz", None),
                n("magx", None),
                n("magy", None),
                n("magz", None),
                n("quat1", None),
                n("quat2", None),
                n("quat3", None),
                n("quat4", None),
            ]
        );
        assert_eq!(
            names(
                "Scaled. Acc (mg) [ -00012.21,  00004.39,  01008.79 ], Gyr (DPS) [ -00000.11, \
                 00000.53, -00000.08 ], Mag (uT) [  00020.25, -00038.85, -00029.55 ], Tmp (C) \
                 [ 00029.03 ]"
            ),
            [
                n("accx", Some("mg")),
                n("accy", Some("mg")),
                n("accz", Some("mg")),
                n("gyrx", Some("DPS")),
                n("gyry", Some("DPS")),
                n("gyrz", Some("DPS")),
                n("magx", Some("uT")),
                n("magy", Some("uT")),
                n("magz", Some("uT")),
                n("tmp", Some("C")),
            ]
        );
        assert_eq!(
            names("Mag(uT): 1.00, 2.00, 3.00 | Acc(m/s²): 0.1, 0.2, 9.8"),
            [
                n("magx", Some("uT")),
                n("magy", Some("uT")),
                n("magz", Some("uT")),
                n("accx", Some("m/s²")),
                n("accy", Some("m/s²")),
                n("accz", Some("m/s²")),
            ]
        );
        assert_eq!(
            names(r#"{"mx": 19, "my": -129, "mz": 174}"#),
            [n("mx", None), n("my", None), n("mz", None)]
        );
        // A number without a label has no name.
        assert_eq!(names("1234 Mx 1"), [n("", None), n("mx", None)]);
    }

    #[test]
    fn values_show_as_printed() {
        let v = values("Mag X: 1 Y: 2 Z: 3 uT");
        let shown: Vec<String> = v.iter().map(Value::label).collect();
        assert_eq!(shown, ["Mag X (uT)", "Mag Y (uT)", "Mag Z (uT)"]);
        let v = values("Mx 19 My -129 Mz 174");
        let shown: Vec<String> = v.iter().map(Value::label).collect();
        assert_eq!(shown, ["Mx", "My", "Mz"]);
        let v = values("Mag (uT) [ 1, 2, 3 ]");
        let shown: Vec<String> = v.iter().map(Value::label).collect();
        assert_eq!(shown, ["Mag x (uT)", "Mag y (uT)", "Mag z (uT)"]);
    }

    #[test]
    fn readings_are_whole_triples_of_one_sensor() {
        let v = values("ax=1 ay=2 az=3 gx=4 gy=5 mx=7 my=8 mz=9");
        assert_eq!(readings(&v), [[0, 1, 2], [5, 6, 7]]);
        // An axis twice: no reading.
        let v = values("X: 1 Y: 2 Z: 3 X: 4 Y: 5 Z: 6");
        assert!(readings(&v).is_empty());
    }

    #[test]
    fn long_lines_take_linear_time() {
        // One group of 300 000 numbers, and one label of 100 000 words: in
        // quadratic time these took minutes; here a fraction of a second.
        let line = format!("Acc: {}", "1 ".repeat(300_000));
        let v = values(&line);
        assert_eq!(v.len(), 300_000);
        assert_eq!(
            (v[0].name.as_str(), v[299_999].name.as_str()),
            ("acc1", "acc300000")
        );
        let line = format!(
            "{} 1 2 3 {}",
            "Mag ".repeat(100_000),
            "t 1 ".repeat(100_000)
        );
        let v = values(&line);
        assert_eq!(v[0].display, "Mag Mag Mag x");
        assert_eq!(v.len(), 100_003);
        assert!(holds_reading(&line));
    }

    #[test]
    fn which_lines_make_a_labelled_log() {
        for line in [
            "Mx 19 My -129 Mz 174",
            "X: 12.30  Y: -4.50  Z: 6.70  uT",
            "Acc: 1 2 3",
            "Mag (uT) [ 1, 2, 3 ]",
            "mag,1,2,3",
        ] {
            assert!(holds_reading(line), "{line}");
        }
        for line in [
            "1,2,3",
            "mx,my,mz",
            "NoFix,0,1,2",
            "2024-01-01,1,2,3",
            "12:00:01,1,2,3",
            "Fs,50.00",
            "Temperature 25.5 deg C",
            "Raw:1,2,3,4,5,6,7,8,9",
        ] {
            assert!(!holds_reading(line), "{line}");
        }
    }
}
