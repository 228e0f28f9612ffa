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
//!  "dwell": [{"centre": [x, y, z], "radius": r}]}
//! ```
//!
//! `screen` and `residual_limit` are `null` when the fit did not screen or
//! weight its rows (a clean plain fit, or `--plain`). `runs` lists the
//! spans of rows `[start, end)` rejected beside runs of rejected rows
//! ([`mag_cal_core::runs`]); `dwell` the balls (sensor units, at most
//! [`DWELL_BALLS`]) of the still periods: a row the drop rules keep that
//! lies in one was set aside ([`mag_cal_core::Dwell`], class `dwell`: not
//! outliers). A selection written without either has none. With `glitch_rules` false, everything
//! else `null` and no spans it is [`Selection::ALL`]: every finite row
//! used.

use mag_cal_core::{
    runs::RUNS, Calibration, Drops, Dwell, Real, Rule, Runs, Sample, SampleClass, Selection,
};
use serde::ser::SerializeMap;
use serde::{Serialize, Serializer};
use serde_json::Value;

/// At most this many still periods a fit sets aside (the core's
/// `DWELL_SPANS`, which it does not export).
pub const DWELL_BALLS: usize = 3;

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

/// A ball in sensor units: the screening ball of a fit (rows farther than
/// `radius` from `centre` were screened out) or a still period's (rows the
/// drop rules keep within `radius` of `centre` were set aside).
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
    /// Rows the drop rules keep within these balls, still periods, were
    /// set aside before any fit (in the core's order: [`Dwell::balls`]).
    pub dwell: Vec<Screen>,
}

/// The spans of `runs` as `[[start, end], ...]`.
pub(crate) fn spans<S: Serializer>(runs: &Runs, serializer: S) -> Result<S::Ok, S::Error> {
    serializer.collect_seq(runs.spans().iter().map(|&(s, e)| [s, e]))
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
            dwell: s
                .dwell
                .balls()
                .map(|(centre, radius)| Screen {
                    centre: centre.map(T::to_f64),
                    radius: radius.to_f64(),
                })
                .collect(),
        }
    }

    /// The core's selection in precision `T` (exact for values that came
    /// from `T`) but for its still periods: the core builds a [`Dwell`]
    /// only in a fit (no public constructor), so they are [`Dwell::NONE`]
    /// here and [`Self::classify`] marks their rows.
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
    /// [`Self::to_core`], with the rows that no drop rule removed and that
    /// lie in a still period's ball marked [`SampleClass::Dwell`], as the
    /// core marks them (a drop rule first, then a still period, then the
    /// screening, the runs and the residual).
    ///
    /// A ball's test is the core's, in `T`: the squared distance summed
    /// axis by axis against the squared radius. The radius is the core's
    /// square root of its squared radius, squared again here: a row within
    /// rounding of the surface could fall the other side.
    pub fn classify<T: Real, S: Sample>(
        &self,
        cal: &Calibration<T>,
        samples: &[S],
    ) -> Vec<SampleClass> {
        let balls: Vec<([T; 3], T)> = self
            .dwell
            .iter()
            .map(|b| {
                let r = T::lit(b.radius);
                (b.centre.map(T::lit), r * r)
            })
            .collect();
        let still = |s: &S| {
            let y = s.xyz::<T>();
            balls.iter().any(|&(c, radius_sq)| {
                let d = [y[0] - c[0], y[1] - c[1], y[2] - c[2]];
                d[0] * d[0] + d[1] * d[1] + d[2] * d[2] <= radius_sq
            })
        };
        self.to_core::<T>()
            .classify(cal, samples)
            .zip(samples)
            .map(|(class, s)| match class {
                SampleClass::Dropped(_) => class,
                _ if still(s) => SampleClass::Dwell,
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
            v => Some(
                ball(v).ok_or(
                    "'selection.screen' must be null or {\"centre\": [x, y, z], \"radius\": r} \
                 with a positive radius"
                        .to_owned(),
                )?,
            ),
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
                .filter(|a| a.len() <= DWELL_BALLS)
                .and_then(|a| a.iter().map(ball).collect::<Option<Vec<_>>>())
                .ok_or(format!(
                    "'selection.dwell' must be at most {DWELL_BALLS} balls \
                     {{\"centre\": [x, y, z], \"radius\": r}} with a positive radius"
                ))?,
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

/// A ball `{"centre": [x, y, z], "radius": r}`, `r` not negative.
fn ball(v: &Value) -> Option<Screen> {
    let centre = v
        .get("centre")
        .and_then(Value::as_array)
        .filter(|a| a.len() == 3)
        .and_then(|a| Some([a[0].as_f64()?, a[1].as_f64()?, a[2].as_f64()?]))?;
    let radius = v
        .get("radius")
        .and_then(Value::as_f64)
        .filter(|r| *r >= 0.0)?;
    Some(Screen { centre, radius })
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
        // Still periods: balls, in the core's order.
        let still = SelectionJson {
            dwell: vec![
                Screen {
                    centre: [30.5, -2.0, 11.0],
                    radius: 1.25,
                },
                Screen {
                    centre: [-4.0, 8.0, 0.5],
                    radius: 0.75,
                },
            ],
            ..json
        };
        let text = serde_json::to_string(&still).expect("serialises");
        assert!(
            text.ends_with(
                r#""dwell":[{"centre":[30.5,-2.0,11.0],"radius":1.25},{"centre":[-4.0,8.0,0.5],"radius":0.75}]}"#
            ),
            "{text}"
        );
        let back = SelectionJson::from_json(&serde_json::from_str(&text).expect("json"))
            .expect("reads back");
        assert_eq!(back, still);
    }

    /// The rows in a still period's ball are `dwell` unless a drop rule
    /// removed them, before the screening; the others keep their class.
    #[test]
    fn still_rows_are_classified_after_the_drop_rules() {
        let mut samples: Vec<[f64; 3]> = (0..12)
            .map(|i| {
                let a = f64::from(i) * 0.5;
                [a.cos(), a.sin(), 0.1 * a]
            })
            .collect();
        // Rows 3 and 10 lie in a ball, row 4 repeats row 3 (dropped),
        // row 11 lies at the ball's surface (in), row 7 just outside.
        samples[4] = samples[3];
        samples[10] = [5.0, 0.0, 0.0];
        samples[11] = [5.5, 0.0, 0.0];
        samples[7] = [5.0, 0.0, -0.75];
        let identity = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
        let cal = Calibration::<f64>::new([0.0; 3], identity).expect("a calibration");
        let selection = SelectionJson {
            glitch_rules: true,
            // Rows beyond 2 of the origin were screened: the still rows
            // at 5 are `dwell`, as the core checks the still periods first.
            screen: Some(Screen {
                centre: [0.0; 3],
                radius: 2.0,
            }),
            dwell: vec![
                Screen {
                    centre: samples[3],
                    radius: 0.25,
                },
                Screen {
                    centre: [5.0, 0.0, 0.0],
                    radius: 0.5,
                },
            ],
            ..SelectionJson::ALL
        };
        let classes = selection.classify(&cal, &samples);
        let expected: Vec<SampleClass> = (0..12)
            .map(|i| match i {
                4 => SampleClass::Dropped(Rule::Repeated),
                3 | 10 | 11 => SampleClass::Dwell,
                7 => SampleClass::Screened,
                _ => SampleClass::Used,
            })
            .collect();
        assert_eq!(classes, expected);
        // Without still periods: the core's classes.
        let core: Vec<SampleClass> = Selection::<f64>::ALL.classify(&cal, &samples).collect();
        assert_eq!(SelectionJson::ALL.classify(&cal, &samples), core);
    }

    /// A fit of turns between two still ends: the still periods written to
    /// JSON and read back mark exactly the rows the core's own
    /// [`Selection::classify`] marks, in both precisions.
    #[test]
    fn still_balls_read_back_mark_the_cores_rows() {
        fn check<T: Real>(rows: &[[f64; 3]]) {
            let fit = mag_cal_core::calibrate::<T, _>(rows, &mag_cal_core::Config::default())
                .expect("a fit");
            let sel = &fit.report.selection;
            assert!(fit.report.dwell > 0 && !sel.dwell.is_empty());
            let core: Vec<SampleClass> = sel.classify(&fit.calibration, rows).collect();
            let text = serde_json::to_string(&SelectionJson::from_core(sel)).expect("serialises");
            let back = SelectionJson::from_json(&serde_json::from_str(&text).expect("json"))
                .expect("reads back");
            assert_eq!(back.dwell.len(), sel.dwell.balls().count());
            let cli = back.classify(&fit.calibration, rows);
            assert_eq!(cli, core);
            let dwell = cli.iter().filter(|c| **c == SampleClass::Dwell).count();
            assert_eq!(dwell, fit.report.dwell);
        }
        // 400 turns on an ellipsoid (offset, unequal axes), 500 rows lying
        // still before and 800 after, noise of a count (fixed LCG).
        let turns: Vec<[f64; 3]> = (0..400)
            .map(|i| {
                let z = 1.0 - 2.0 * (f64::from(i) + 0.5) / 400.0;
                let (r, phi) = ((1.0 - z * z).sqrt(), f64::from(i) * 2.399_963);
                [
                    300.0 * r * phi.cos() + 40.0,
                    260.0 * r * phi.sin() - 25.0,
                    330.0 * z + 12.0,
                ]
            })
            .collect();
        let mut state = 7u32;
        let mut still = |at: [f64; 3], n: usize| -> Vec<[f64; 3]> {
            (0..n)
                .map(|_| {
                    at.map(|v| {
                        state = state.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
                        v.round() + [-1.0, 0.0, 0.0, 1.0][(state >> 30) as usize]
                    })
                })
                .collect()
        };
        let rows = [still(turns[0], 500), turns.clone(), still(turns[399], 800)].concat();
        check::<f32>(&rows);
        check::<f64>(&rows);
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
            // Row spans, as a branch before the balls wrote them.
            (
                r#"{"glitch_rules":true,"clip_levels":[[1,2],[3,4],[5,6]],"screen":null,"residual_limit":null,"dwell":[[900,2100],[5,901]]}"#,
                "'selection.dwell' must be",
            ),
            (
                r#"{"glitch_rules":true,"clip_levels":[[1,2],[3,4],[5,6]],"screen":null,"residual_limit":null,"dwell":[{"centre":[0,0,0],"radius":-1}]}"#,
                "'selection.dwell' must be",
            ),
            (
                r#"{"glitch_rules":true,"clip_levels":[[1,2],[3,4],[5,6]],"screen":null,"residual_limit":null,"dwell":[{"centre":[0,0,0],"radius":1},{"centre":[0,0,0],"radius":1},{"centre":[0,0,0],"radius":1},{"centre":[0,0,0],"radius":1}]}"#,
                "'selection.dwell' must be at most 3 balls",
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
