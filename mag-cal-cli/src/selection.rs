//! Which rows a fit used, as the JSON of `fit --format json` carries it and
//! `apply --flags` reads it back: the drop counts by rule, the core's
//! [`Selection`] in JSON form, and the names of the row classes.
//!
//! The JSON form (`selection` object):
//!
//! ```json
//! {"glitch_rules": true,
//!  "clip_levels": [[null, 512], [null, null], [-480, null]],
//!  "screen": {"centre": [x, y, z], "radius": r},
//!  "residual_limit": 0.094,
//!  "runs": [[120, 245]],
//!  "dwell": [[5, 600], [905, 2100]]}
//! ```
//!
//! `screen` and `residual_limit` are `null` when the fit did not screen or
//! weight its rows (a clean plain fit, or `--plain`). `runs` lists the
//! spans of rows `[start, end)` rejected beside runs of rejected rows
//! ([`mag_cal_core::runs`]); `dwell` the spans of rows set aside as still
//! periods, a device lying still beyond the first rows of each
//! ([`mag_cal_core::Dwell`], class `dwell`: not outliers). A selection
//! written without either has none. With `glitch_rules` false, everything
//! else `null` and no spans it is [`Selection::ALL`]: every finite row
//! used.

use mag_cal_core::{
    runs::RUNS, Calibration, Drops, Dwell, Real, Rule, Runs, Sample, SampleClass, Selection,
};
use serde::ser::SerializeMap;
use serde::{Serialize, Serializer};
use serde_json::Value;

/// The rows dropped by each rule, serialised as a JSON object keyed by
/// [`Rule::name`] (every rule present, zeros included).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct DropCounts(pub Drops);

impl DropCounts {
    /// `(rule, rows)` for every rule, in [`Rule::ALL`] order.
    pub fn by_rule(&self) -> impl Iterator<Item = (Rule, usize)> + '_ {
        Rule::ALL.into_iter().map(|r| (r, self.0.by(r)))
    }
}

impl Serialize for DropCounts {
    fn serialize<S: Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
        let mut map = serializer.serialize_map(Some(Rule::ALL.len()))?;
        for (rule, n) in self.by_rule() {
            map.serialize_entry(rule.name(), &n)?;
        }
        map.end()
    }
}

/// The screening ball of a fit: rows farther than `radius` from `centre`
/// (sensor units) were screened out.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct Screen {
    /// Centre, sensor units.
    pub centre: [f64; 3],
    /// Radius, sensor units.
    pub radius: f64,
}

/// The core's [`Selection`] widened to `f64`: the `selection` object of the
/// fit JSON.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct SelectionJson {
    /// The zero, rails, repetition and clip rules were applied.
    pub glitch_rules: bool,
    /// Per axis the low and high clip level (`null`: none).
    pub clip_levels: [[Option<f64>; 2]; 3],
    /// The screening ball, if the fit screened.
    pub screen: Option<Screen>,
    /// Rows whose `||W (y - b)| - 1|` exceeds this were rejected.
    pub residual_limit: Option<f64>,
    /// Rows in these spans, beside runs of rejected rows, were rejected.
    #[serde(serialize_with = "spans")]
    pub runs: Runs,
    /// Rows in these spans `(start, end)`, still periods beyond their first
    /// rows, were set aside before any fit (disjoint, in the core's order:
    /// [`Dwell::spans`]).
    #[serde(serialize_with = "pairs")]
    pub dwell: Vec<(usize, usize)>,
}

/// The spans of `runs` as `[[start, end], ...]`.
pub(crate) fn spans<S: Serializer>(runs: &Runs, serializer: S) -> Result<S::Ok, S::Error> {
    pairs(runs.spans(), serializer)
}

/// Spans `(start, end)` as `[[start, end], ...]`.
fn pairs<S: Serializer>(spans: &[(usize, usize)], serializer: S) -> Result<S::Ok, S::Error> {
    serializer.collect_seq(spans.iter().map(|&(s, e)| [s, e]))
}

impl SelectionJson {
    /// Every finite row used ([`Selection::ALL`]).
    pub const ALL: Self = Self {
        glitch_rules: false,
        clip_levels: [[None; 2]; 3],
        screen: None,
        residual_limit: None,
        runs: Runs::NONE,
        dwell: Vec::new(),
    };

    /// The core's selection, widened to `f64` (exactly).
    pub fn from_core<T: Real>(s: &Selection<T>) -> Self {
        Self {
            glitch_rules: s.glitch_rules,
            clip_levels: s.clip_levels.map(|axis| axis.map(|l| l.map(T::to_f64))),
            screen: s.screen.map(|(centre, radius)| Screen {
                centre: centre.map(T::to_f64),
                radius: radius.to_f64(),
            }),
            residual_limit: s.residual_limit.map(T::to_f64),
            runs: s.runs,
            dwell: s.dwell.spans().to_vec(),
        }
    }

    /// The core's selection in precision `T` (exact for values that came
    /// from `T`) but for its still periods: the core builds a [`Dwell`]
    /// only in a fit, so they are [`Dwell::NONE`] here and [`Self::classify`]
    /// marks their rows.
    pub fn to_core<T: Real>(&self) -> Selection<T> {
        Selection {
            glitch_rules: self.glitch_rules,
            clip_levels: self.clip_levels.map(|axis| axis.map(|l| l.map(T::lit))),
            screen: self
                .screen
                .map(|s| (s.centre.map(T::lit), T::lit(s.radius))),
            residual_limit: self.residual_limit.map(T::lit),
            runs: self.runs,
            dwell: Dwell::NONE,
        }
    }

    /// What the fit did with each row of `samples`, calibrated by `cal` in
    /// precision `T`: the core's [`Selection::classify`] of
    /// [`Self::to_core`], with the rows of the still periods that no drop
    /// rule removed marked [`SampleClass::Dwell`], as the core marks them
    /// (a drop rule first, then a still period, then the screening, the
    /// runs and the residual).
    pub fn classify<T: Real, S: Sample>(
        &self,
        cal: &Calibration<T>,
        samples: &[S],
    ) -> Vec<SampleClass> {
        let still = |i: usize| self.dwell.iter().any(|&(s, e)| s <= i && i < e);
        self.to_core::<T>()
            .classify(cal, samples)
            .enumerate()
            .map(|(i, class)| match class {
                SampleClass::Dropped(_) => class,
                _ if still(i) => SampleClass::Dwell,
                _ => class,
            })
            .collect()
    }

    /// Reads the `selection` object of a fit JSON; the error names the
    /// offending field (`selection.screen.radius must be ...`).
    pub fn from_json(v: &Value) -> Result<Self, String> {
        let obj = v
            .as_object()
            .ok_or("'selection' must be an object".to_owned())?;
        let get = |key: &str| {
            obj.get(key)
                .ok_or(format!("missing field 'selection.{key}'"))
        };
        let glitch_rules = get("glitch_rules")?
            .as_bool()
            .ok_or("'selection.glitch_rules' must be true or false".to_owned())?;
        let level = |v: &Value| -> Option<Option<f64>> {
            match v {
                Value::Null => Some(None),
                v => v.as_f64().map(Some),
            }
        };
        let pair = |v: &Value| -> Option<[Option<f64>; 2]> {
            let a = v.as_array().filter(|a| a.len() == 2)?;
            Some([level(&a[0])?, level(&a[1])?])
        };
        let clip_levels = get("clip_levels")?
            .as_array()
            .filter(|a| a.len() == 3)
            .and_then(|a| Some([pair(&a[0])?, pair(&a[1])?, pair(&a[2])?]))
            .ok_or(
                "'selection.clip_levels' must be 3 pairs [low, high] of numbers or null".to_owned(),
            )?;
        let screen = match get("screen")? {
            Value::Null => None,
            v => {
                let bad = || {
                    "'selection.screen' must be null or {\"centre\": [x, y, z], \"radius\": r} \
                     with a positive radius"
                        .to_owned()
                };
                let centre = v
                    .get("centre")
                    .and_then(Value::as_array)
                    .filter(|a| a.len() == 3)
                    .and_then(|a| Some([a[0].as_f64()?, a[1].as_f64()?, a[2].as_f64()?]))
                    .ok_or_else(bad)?;
                let radius = v
                    .get("radius")
                    .and_then(Value::as_f64)
                    .filter(|r| *r >= 0.0)
                    .ok_or_else(bad)?;
                Some(Screen { centre, radius })
            }
        };
        let residual_limit = match get("residual_limit")? {
            Value::Null => None,
            v => Some(v.as_f64().filter(|l| *l >= 0.0).ok_or(
                "'selection.residual_limit' must be null or a non-negative number".to_owned(),
            )?),
        };
        let span = |v: &Value| -> Option<(usize, usize)> {
            let a = v.as_array().filter(|a| a.len() == 2)?;
            let end = |v: &Value| v.as_u64().and_then(|x| usize::try_from(x).ok());
            Some((end(&a[0])?, end(&a[1])?))
        };
        let runs = match obj.get("runs") {
            None => Runs::NONE,
            Some(v) => v
                .as_array()
                .and_then(|a| a.iter().map(span).collect::<Option<Vec<_>>>())
                .and_then(|spans| Runs::from_spans(&spans))
                .ok_or(format!(
                    "'selection.runs' must be at most {RUNS} pairs [start, end] of row \
                         indices, each non-empty, ascending and apart"
                ))?,
        };
        let dwell = match obj.get("dwell") {
            None => Vec::new(),
            Some(v) => v
                .as_array()
                .and_then(|a| a.iter().map(span).collect::<Option<Vec<_>>>())
                .filter(|spans| disjoint(spans))
                .ok_or(
                    "'selection.dwell' must be pairs [start, end] of row indices, each \
                     non-empty, not overlapping"
                        .to_owned(),
                )?,
        };
        Ok(Self {
            glitch_rules,
            clip_levels,
            screen,
            residual_limit,
            runs,
            dwell,
        })
    }
}

/// Whether `spans` are each non-empty and none overlaps another.
fn disjoint(spans: &[(usize, usize)]) -> bool {
    let mut sorted = spans.to_vec();
    sorted.sort_unstable();
    sorted.iter().all(|&(s, e)| s < e) && sorted.windows(2).all(|w| w[0].1 <= w[1].0)
}

/// The name of a row class in `apply --flags`: `used`, `dropped:<rule>`
/// (the rule's [`Rule::name`]), `dwell` (a still period's row set aside),
/// `screened`, `rejected`.
pub fn class_name(class: SampleClass) -> String {
    match class {
        SampleClass::Used => "used".into(),
        SampleClass::Dropped(rule) => format!("dropped:{}", rule.name()),
        SampleClass::Screened => "screened".into(),
        SampleClass::Rejected => "rejected".into(),
        SampleClass::Dwell => "dwell".into(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn drops_serialise_by_rule_name() {
        let mut drops = Drops::default();
        drops.non_finite = 1;
        drops.repeated = 4;
        let v = serde_json::to_value(DropCounts(drops)).expect("serialises");
        assert_eq!(
            v,
            serde_json::json!({"non_finite": 1, "overflow": 0, "zero": 0, "rails": 0,
                               "repeated": 4, "clipped": 0})
        );
        let names: Vec<&str> = Rule::ALL.iter().map(|r| r.name()).collect();
        assert_eq!(
            names,
            [
                "non_finite",
                "overflow",
                "zero",
                "rails",
                "repeated",
                "clipped"
            ]
        );
    }

    #[test]
    fn selection_round_trips_through_json_exactly() {
        let core = Selection::<f32> {
            glitch_rules: true,
            clip_levels: [[None, Some(512.0)], [None, None], [Some(-480.25), None]],
            screen: Some(([1.5, -2.0, 0.1], 812.3)),
            residual_limit: Some(0.0946),
            runs: Runs::from_spans(&[(3, 40), (500, 531)]).expect("valid spans"),
            dwell: mag_cal_core::Dwell::NONE,
        };
        let json = SelectionJson::from_core(&core);
        let text = serde_json::to_string(&json).expect("serialises");
        let back = SelectionJson::from_json(&serde_json::from_str(&text).expect("json"))
            .expect("reads back");
        assert_eq!(back, json);
        assert_eq!(back.to_core::<f32>(), core);
        assert_eq!(SelectionJson::ALL.to_core::<f64>(), Selection::<f64>::ALL);
        let plain = serde_json::to_value(SelectionJson::ALL).expect("serialises");
        assert_eq!(
            plain,
            serde_json::json!({"glitch_rules": false,
                               "clip_levels": [[null, null], [null, null], [null, null]],
                               "screen": null, "residual_limit": null, "runs": [],
                               "dwell": []})
        );
        // A selection written before runs and still periods were found
        // reads as none.
        let old = r#"{"glitch_rules":true,"clip_levels":[[null,1],[null,null],[2,null]],"screen":null,"residual_limit":0.1}"#;
        let old =
            SelectionJson::from_json(&serde_json::from_str(old).expect("json")).expect("reads");
        assert!(old.runs.is_empty() && old.dwell.is_empty());
        // Still periods, not in order (as the core keeps them).
        let still = SelectionJson {
            dwell: vec![(900, 2100), (5, 600)],
            ..json
        };
        let text = serde_json::to_string(&still).expect("serialises");
        assert!(text.ends_with(r#""dwell":[[900,2100],[5,600]]}"#), "{text}");
        let back = SelectionJson::from_json(&serde_json::from_str(&text).expect("json"))
            .expect("reads back");
        assert_eq!(back, still);
    }

    /// The rows of a still period are `dwell` unless a drop rule removed
    /// them; the others keep their class.
    #[test]
    fn still_rows_are_classified_after_the_drop_rules() {
        let mut samples: Vec<[f64; 3]> = (0..12)
            .map(|i| {
                let a = f64::from(i) * 0.5;
                [a.cos(), a.sin(), 0.1 * a]
            })
            .collect();
        samples[4] = [f64::NAN, 0.0, 0.0];
        let identity = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
        let cal = Calibration::<f64>::new([0.0; 3], identity).expect("a calibration");
        let selection = SelectionJson {
            dwell: vec![(3, 6), (10, 12)],
            ..SelectionJson::ALL
        };
        let classes = selection.classify(&cal, &samples);
        let expected: Vec<SampleClass> = (0..12)
            .map(|i| match i {
                4 => SampleClass::Dropped(Rule::NonFinite),
                3 | 5 | 10 | 11 => SampleClass::Dwell,
                _ => SampleClass::Used,
            })
            .collect();
        assert_eq!(classes, expected);
        // Without still periods: the core's classes.
        let core: Vec<SampleClass> = Selection::<f64>::ALL.classify(&cal, &samples).collect();
        assert_eq!(SelectionJson::ALL.classify(&cal, &samples), core);
    }

    #[test]
    fn bad_selections_name_the_field() {
        let ok = r#"{"glitch_rules":true,"clip_levels":[[null,1],[null,null],[2,null]],"screen":{"centre":[0,0,0],"radius":5},"residual_limit":0.1}"#;
        assert!(SelectionJson::from_json(&serde_json::from_str(ok).expect("json")).is_ok());
        for (text, reason) in [
            ("[]", "'selection' must be an object"),
            ("{}", "missing field 'selection.glitch_rules'"),
            (
                r#"{"glitch_rules":1,"clip_levels":[],"screen":null,"residual_limit":null}"#,
                "glitch_rules' must be",
            ),
            (
                r#"{"glitch_rules":true,"clip_levels":[[1,2],[3,4]],"screen":null,"residual_limit":null}"#,
                "clip_levels' must be",
            ),
            (
                r#"{"glitch_rules":true,"clip_levels":[[1,2],[3,4],[5,"6"]],"screen":null,"residual_limit":null}"#,
                "clip_levels' must be",
            ),
            (
                r#"{"glitch_rules":true,"clip_levels":[[1,2],[3,4],[5,6]],"screen":{"centre":[0,0]},"residual_limit":null}"#,
                "'selection.screen' must be",
            ),
            (
                r#"{"glitch_rules":true,"clip_levels":[[1,2],[3,4],[5,6]],"screen":{"centre":[0,0,0],"radius":-1},"residual_limit":null}"#,
                "'selection.screen' must be",
            ),
            (
                r#"{"glitch_rules":true,"clip_levels":[[1,2],[3,4],[5,6]],"screen":null,"residual_limit":"0.1"}"#,
                "residual_limit' must be",
            ),
            (
                r#"{"glitch_rules":true,"clip_levels":[[1,2],[3,4],[5,6]],"screen":null}"#,
                "missing field 'selection.residual_limit'",
            ),
            (
                r#"{"glitch_rules":true,"clip_levels":[[1,2],[3,4],[5,6]],"screen":null,"residual_limit":null,"runs":[[5,9],[8,12]]}"#,
                "'selection.runs' must be",
            ),
            (
                r#"{"glitch_rules":true,"clip_levels":[[1,2],[3,4],[5,6]],"screen":null,"residual_limit":null,"runs":[[5,-9]]}"#,
                "'selection.runs' must be",
            ),
            (
                r#"{"glitch_rules":true,"clip_levels":[[1,2],[3,4],[5,6]],"screen":null,"residual_limit":null,"dwell":[[900,2100],[5,901]]}"#,
                "'selection.dwell' must be",
            ),
            (
                r#"{"glitch_rules":true,"clip_levels":[[1,2],[3,4],[5,6]],"screen":null,"residual_limit":null,"dwell":[[7,7]]}"#,
                "'selection.dwell' must be",
            ),
            (
                r#"{"glitch_rules":true,"clip_levels":[[1,2],[3,4],[5,6]],"screen":null,"residual_limit":null,"dwell":{"a":1}}"#,
                "'selection.dwell' must be",
            ),
        ] {
            let err = SelectionJson::from_json(&serde_json::from_str(text).expect("json"))
                .expect_err(text);
            assert!(err.contains(reason), "{text}: {err}");
        }
    }

    #[test]
    fn class_names() {
        assert_eq!(class_name(SampleClass::Used), "used");
        assert_eq!(class_name(SampleClass::Screened), "screened");
        assert_eq!(class_name(SampleClass::Rejected), "rejected");
        assert_eq!(class_name(SampleClass::Dwell), "dwell");
        assert_eq!(
            class_name(SampleClass::Dropped(Rule::NonFinite)),
            "dropped:non_finite"
        );
    }
}
