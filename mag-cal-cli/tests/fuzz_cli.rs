//! Seeded fuzzing of the `magcal` binary: no file makes it panic (exit
//! 101) or die by a signal, and every failure is one line on stderr.
//!
//! Each case is built from `(seed, index)` alone: an input file (random
//! bytes; numbers with random separators, quoting and line ends; headers;
//! huge, tiny and non-finite values; mixed column counts; very long lines;
//! CRLF and lone CR; a UTF-8 BOM; UTF-16 with and without BOM; valid
//! ellipsoid data with corruption; labelled values of one or several
//! sensors, as sketches print them), and a valid command line:
//! `magcal fit` (every method and LS variant, both precisions, json and
//! text, sometimes `--columns`, `--noise-std`, `--plot`, `--plain`) or
//! `magcal apply` (a valid calibration or a corrupt one, sometimes
//! `--columns`, `--accel-columns`, `--window`, `--scaled`, `--flags`),
//! reading the file by path or from stdin.
//!
//! Checked per run: the process exits (no signal) with 0, 2 or 3 (`apply`:
//! 0 or 2), never 101; on 2 or 3 stderr is exactly one line starting with
//! `magcal: `; on 0 stderr is empty (or, for `fit --format json` and
//! `apply`, the line `magcal: note: columns ...` naming the columns found
//! in the header, the line `magcal: note: input: ...` naming the lines
//! that were no samples, and for `apply --flags` the note that the
//! calibration has no `selection`) and stdout is well formed: one JSON object with
//! finite numbers whose row counts agree (drops by rule add up to
//! `samples_dropped`, the outlier share is the screened and rejected rows'
//! share, `--plain` screens and rejects nothing) and whose `selection` is
//! well formed (still rows counted have their spans); a text report with its `samples` line; or CSV with its
//! header, and with `--flags` a `used` flag matching each row's class.
//!
//! Environment:
//! - `MAGCAL_FUZZ_CLI_CASES`: runs (default 1000, a few seconds);
//! - `MAGCAL_FUZZ_SEED`: the seed (default `0x6d61_6763_616c_0002`);
//! - `MAGCAL_FUZZ_THREADS`: parallel runs (default: available cores);
//! - `MAGCAL_FUZZ_CASE`: run only this case, print its command line and
//!   keep its input file (to replay a failure).
//!
//! The long run (see docs/robustness.md):
//! `MAGCAL_FUZZ_CLI_CASES=20000 cargo test --release -p mag-cal-cli --test fuzz_cli -- --nocapture`

use std::io::Write;
use std::path::PathBuf;
use std::process::{Command, Stdio};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Mutex;
use std::time::Instant;

use serde_json::Value;

const DEFAULT_SEED: u64 = 0x6d61_6763_616c_0002;

/// The host tests' SplitMix64 (`host_tests::sim::Rng`), with the draws
/// the file generator needs.
struct Rng(host_tests::sim::Rng);

impl std::ops::Deref for Rng {
    type Target = host_tests::sim::Rng;
    fn deref(&self) -> &host_tests::sim::Rng {
        &self.0
    }
}

impl std::ops::DerefMut for Rng {
    fn deref_mut(&mut self) -> &mut host_tests::sim::Rng {
        &mut self.0
    }
}

impl Rng {
    /// The generator of case `index` under `seed`.
    fn for_case(seed: u64, index: u64) -> Self {
        Rng(host_tests::sim::Rng::for_case(seed, index))
    }

    fn pick<'a, T>(&mut self, items: &'a [T]) -> &'a T {
        &items[self.index(items.len())]
    }

    fn bytes(&mut self, n: usize) -> Vec<u8> {
        (0..n).map(|_| self.next_u64() as u8).collect()
    }

    /// A number as a logger (or an adversary) might write it.
    fn number(&mut self) -> String {
        match self.below(14) {
            0 => self.pick(&NON_FINITE).to_string(),
            1 => format!("{:e}", f64::from_bits(self.next_u64())),
            2 => format!("{}", f64::from_bits(self.next_u64())),
            3 => format!("{}", f32::from_bits(self.next_u64() as u32)),
            4 => self.pick(&EXTREME).to_string(),
            5 => format!("{}", self.next_u64() as i64),
            6 => format!("{}", self.next_u64() as i16),
            7 => {
                // Odd but parseable or not: leading '+', '.5', '5.', '1e+3',
                // '0x10', '1_000', ' 1 ', '1,5', '−1' (U+2212), digits only.
                let odd = [
                    "+3",
                    ".5",
                    "5.",
                    "1e+3",
                    "1E-3",
                    "0x10",
                    "1_000",
                    " 1 ",
                    "1,5",
                    "\u{2212}1",
                    "00012",
                    "1e",
                    "e5",
                    "-",
                    "+",
                    ".",
                    "",
                    "--1",
                    "1..2",
                    "١٢٣",
                ];
                self.pick(&odd).to_string()
            }
            8 => format!("\"{}\"", self.plain()),
            9 => "9".repeat(1 + self.index(400)),
            _ => self.plain(),
        }
    }

    fn plain(&mut self) -> String {
        let v = (self.unit() - 0.5) * 2000.0;
        if self.chance(0.5) {
            format!("{v:.3}")
        } else {
            format!("{}", v.round() as i64)
        }
    }

    fn separator(&mut self) -> &'static str {
        SEPARATORS[self.index(SEPARATORS.len())]
    }

    fn line_end(&mut self) -> &'static str {
        LINE_ENDS[self.index(LINE_ENDS.len())]
    }
}

const SEPARATORS: [&str; 10] = [",", ";", " ", "\t", "  ", ", ", " ;", "\t\t", "|", ",,"];

const LINE_ENDS: [&str; 7] = ["\n", "\n", "\n", "\r\n", "\r", "\n\n", "\r\r\n"];

const NON_FINITE: [&str; 14] = [
    "nan",
    "NaN",
    "-nan",
    "inf",
    "-inf",
    "+inf",
    "Infinity",
    "-Infinity",
    "INF",
    "1e400",
    "-1e400",
    "1e99999",
    "nan(123)",
    "NAN",
];

const EXTREME: [&str; 16] = [
    "1e308",
    "-1.7976931348623157e308",
    "1.7976931348623157e308",
    "5e-324",
    "1e-320",
    "2.2250738585072014e-308",
    "3.4028235e38",
    "3.5e38",
    "1e38",
    "1e-45",
    "1.17549435e-38",
    "-0",
    "0",
    "1e30",
    "123456789012345678901234567890",
    "0.000000000000000000000000000000000000000000001",
];

const HEADER_NAMES: [&str; 24] = [
    "x", "y", "z", "X", "Y", "Z", "magx", "magy", "magz", "mx", "my", "mz", "ax", "ay", "az",
    "accx", "accy", "accz", "acc_x", "acc_y", "acc_z", "time", "", "\"x\"",
];

/// The header of [`ellipsoid_rows`]: without it, six numeric columns are
/// refused (no header to find the magnetometer columns in).
const ELLIPSOID_HEADER: &str = "x,y,z,ax,ay,az";

/// An ellipsoid sample set as CSV rows (so that some runs succeed): x, y,
/// z, then an accelerometer's ax, ay, az ([`ELLIPSOID_HEADER`]).
fn ellipsoid_rows(rng: &mut Rng, n: usize) -> Vec<String> {
    let c = [
        (rng.unit() - 0.5) * 2000.0,
        (rng.unit() - 0.5) * 2000.0,
        (rng.unit() - 0.5) * 2000.0,
    ];
    let r = [
        50.0 + rng.unit() * 400.0,
        50.0 + rng.unit() * 400.0,
        50.0 + rng.unit() * 400.0,
    ];
    (0..n)
        .map(|i| {
            let z = 1.0 - 2.0 * (i as f64 + 0.5) / n as f64;
            let (s, phi) = ((1.0 - z * z).sqrt(), i as f64 * 2.399_963);
            let v = [
                c[0] + r[0] * s * phi.cos() + rng.unit(),
                c[1] + r[1] * s * phi.sin() + rng.unit(),
                c[2] + r[2] * z + rng.unit(),
            ];
            let a = [rng.unit() - 0.5, rng.unit() - 0.5, -9.8 + rng.unit()];
            format!(
                "{:.3},{:.3},{:.3},{:.3},{:.3},{:.3}",
                v[0], v[1], v[2], a[0], a[1], a[2]
            )
        })
        .collect()
}

/// An input file of one of many shapes, and its name.
fn input_file(rng: &mut Rng) -> (&'static str, Vec<u8>) {
    let kind = rng.below(12);
    let rows = match rng.below(4) {
        0 => rng.index(12),
        1 | 2 => 10 + rng.index(200),
        _ => 200 + rng.index(2000),
    };
    let mut text = String::new();
    let name = match kind {
        // Random bytes.
        0 => {
            let n = rng.index(5000);
            return ("random bytes", rng.bytes(n));
        }
        // Numbers with random separators, per row or per field.
        1 | 2 => {
            let per_field = rng.chance(0.3);
            let sep = rng.separator();
            for _ in 0..rows {
                let fields = 1 + rng.index(6);
                for f in 0..fields {
                    if f > 0 {
                        text.push_str(if per_field { rng.separator() } else { sep });
                    }
                    text.push_str(&rng.number());
                }
                text.push_str(rng.line_end());
            }
            "random numbers"
        }
        // A header (sometimes several, sometimes with accelerometer names),
        // then numbers or ellipsoid rows.
        3 | 4 => {
            let sep = *rng.pick(&[",", ";", "\t", " "]);
            let n = 3 + rng.index(5);
            let names: Vec<&str> = if rng.chance(0.5) {
                ["x", "y", "z", "ax", "ay", "az", "t", "q"][..n].to_vec()
            } else {
                (0..n).map(|_| *rng.pick(&HEADER_NAMES)).collect()
            };
            for _ in 0..1 + rng.index(2) {
                text.push_str(&names.join(sep));
                text.push('\n');
            }
            if rng.chance(0.5) {
                for row in ellipsoid_rows(rng, rows) {
                    text.push_str(&row.replace(',', sep));
                    text.push_str(rng.line_end());
                }
            } else {
                for _ in 0..rows {
                    let fields: Vec<String> = (0..n).map(|_| rng.number()).collect();
                    text.push_str(&fields.join(sep));
                    text.push('\n');
                }
            }
            "header"
        }
        // Valid data with corruption: special values, a bad row, comments.
        5 | 6 => {
            // Mostly with the header; without it the six columns are refused.
            if rng.chance(0.8) {
                text.push_str(ELLIPSOID_HEADER);
                text.push_str(rng.line_end());
            }
            for row in ellipsoid_rows(rng, rows.max(12)) {
                let row = if rng.chance(0.05) {
                    let mut f: Vec<String> = row.split(',').map(str::to_owned).collect();
                    let i = rng.index(f.len());
                    f[i] = rng.number();
                    f.join(",")
                } else {
                    row
                };
                if rng.chance(0.02) {
                    text.push_str("# a comment, 1, 2, 3\n");
                }
                text.push_str(&row);
                text.push_str(rng.line_end());
            }
            "corrupted data"
        }
        // Huge, tiny and non-finite values only.
        7 => {
            for _ in 0..rows {
                let f: Vec<&str> = (0..3)
                    .map(|_| {
                        if rng.chance(0.5) {
                            *rng.pick(&EXTREME)
                        } else {
                            *rng.pick(&NON_FINITE)
                        }
                    })
                    .collect();
                text.push_str(&f.join(","));
                text.push('\n');
            }
            "extreme values"
        }
        // Mixed column counts and empty fields.
        8 => {
            for _ in 0..rows {
                let n = rng.index(8);
                let f: Vec<String> = (0..n)
                    .map(|_| {
                        if rng.chance(0.2) {
                            String::new()
                        } else {
                            rng.plain()
                        }
                    })
                    .collect();
                text.push_str(&f.join(","));
                text.push('\n');
            }
            "mixed columns"
        }
        // Very long lines.
        9 => {
            for _ in 0..1 + rng.index(3) {
                let len = 10_000 + rng.index(1_000_000);
                match rng.below(3) {
                    0 => text.push_str(&"1,".repeat(len / 2)),
                    1 => text.push_str(&"9".repeat(len)),
                    _ => text.push_str(&" ".repeat(len)),
                }
                text.push('\n');
            }
            for row in ellipsoid_rows(rng, 20) {
                text.push_str(&row);
                text.push('\n');
            }
            "long lines"
        }
        // Labelled values, as sketches print them: one or several sensors,
        // one line or one line each, units or none, some lines cut short,
        // garbled or of another sensor, sometimes with a banner.
        10 => {
            const LABELS: [[&str; 3]; 8] = [
                ["Mx ", " My ", " Mz "],
                ["X: ", "  Y: ", "  Z: "],
                ["Mag X: ", " \tY: ", " \tZ: "],
                ["mag_x=", ", mag_y=", ", mag_z="],
                ["Mag: ", " ", " "],
                ["Mag (uT) [ ", ", ", " ]"],
                ["Accel X: ", " Y: ", " Z: "],
                ["ax=", " ay=", " az="],
            ];
            const UNITS: [&str; 7] = ["", " uT", " uTesla", " gauss", " mG", " m/s^2", " mg"];
            if rng.chance(0.3) {
                text.push_str("Adafruit test!\nSensor found\nrate set to: 100 Hz\n");
            }
            let sensors: Vec<([&str; 3], &str)> = (0..1 + rng.index(3))
                .map(|_| (*rng.pick(&LABELS), *rng.pick(&UNITS)))
                .collect();
            let one_line = rng.chance(0.5);
            for row in ellipsoid_rows(rng, rows.max(12)) {
                let v: Vec<&str> = row.split(',').collect();
                for (k, (labels, unit)) in sensors.iter().enumerate() {
                    let at = if k == 0 { 0 } else { 3 };
                    let mut line = format!(
                        "{}{}{}{}{}{}{unit}",
                        labels[0],
                        v[at],
                        labels[1],
                        v[at + 1],
                        labels[2],
                        v[at + 2]
                    );
                    if rng.chance(0.03) {
                        let cut = rng.index(line.len());
                        line = line.chars().take(cut).collect();
                    } else if rng.chance(0.02) {
                        line = line.replace(v[at], &rng.number());
                    }
                    text.push_str(&line);
                    text.push_str(if one_line { " " } else { rng.line_end() });
                }
                if one_line {
                    text.push_str(rng.line_end());
                }
            }
            "labelled values"
        }
        // Valid data in another encoding or with a BOM.
        _ => {
            let rows = ellipsoid_rows(rng, rows.max(12));
            let body = format!("x,y,z\r\n{}\r\n", rows.join("\r\n"));
            let bytes = match rng.below(5) {
                0 => [&[0xef, 0xbb, 0xbf][..], body.as_bytes()].concat(),
                1 => [&[0xff, 0xfe][..], &utf16(&body, false)].concat(),
                2 => [&[0xfe, 0xff][..], &utf16(&body, true)].concat(),
                3 => utf16(&body, false),
                // A BOM in the middle.
                _ => format!("1,2,3\n\u{feff}{body}").into_bytes(),
            };
            return ("encoding", bytes);
        }
    };
    (name, text.into_bytes())
}

fn utf16(text: &str, big_endian: bool) -> Vec<u8> {
    text.encode_utf16()
        .flat_map(|u| {
            if big_endian {
                u.to_be_bytes()
            } else {
                u.to_le_bytes()
            }
        })
        .collect()
}

/// A calibration file: valid, or corrupt in one of many ways.
fn calibration_file(rng: &mut Rng, valid: &[u8]) -> Vec<u8> {
    let valid_text = String::from_utf8_lossy(valid).into_owned();
    match rng.below(8) {
        0 | 1 => valid.to_vec(),
        2 => {
            let n = rng.index(400);
            rng.bytes(n)
        }
        // Truncated.
        3 => valid[..rng.index(valid.len().max(1))].to_vec(),
        // One byte changed.
        4 => {
            let mut v = valid.to_vec();
            if !v.is_empty() {
                let i = rng.index(v.len());
                v[i] = rng.next_u64() as u8;
            }
            v
        }
        // A number replaced by an extreme or non-number.
        5 => {
            let bad = *rng.pick(&[
                "1e999", "-1e999", "null", "\"1\"", "[]", "{}", "0", "1e-320", "1e308", "true",
                "-0",
            ]);
            let digits: Vec<usize> = valid_text
                .char_indices()
                .filter(|(_, c)| c.is_ascii_digit())
                .map(|(i, _)| i)
                .collect();
            if digits.is_empty() {
                return valid.to_vec();
            }
            let i = digits[rng.index(digits.len())];
            let mut s = valid_text.clone();
            s.replace_range(i..i + 1, bad);
            s.into_bytes()
        }
        // Hand-made objects.
        6 => {
            let objects = [
                r#"{"hard_iron":[0,0,0],"soft_iron":[[0,0,0],[0,0,0],[0,0,0]]}"#,
                r#"{"hard_iron":[1e308,1e308,1e308],"soft_iron":[[1e-308,0,0],[0,1e-308,0],[0,0,1e-308]]}"#,
                r#"{"hard_iron":[0,0,0],"soft_iron":[[1e300,0,0],[0,1e300,0],[0,0,1e300]]}"#,
                r#"{"hard_iron":[0,0,0],"soft_iron":[[1,1,1],[1,1,1],[1,1,1]]}"#,
                r#"{"hard_iron":[0,0],"soft_iron":[[1,0,0],[0,1,0],[0,0,1]]}"#,
                r#"{"hard_iron":[0,0,0],"soft_iron":[[1,0,0],[0,1,0],[0,0,1],[0,0,0]]}"#,
                r#"{"hard_iron":[0,0,0],"soft_iron":[[-1,0,0],[0,-1,0],[0,0,-1]]}"#,
                r#"{"hard_iron":"x","soft_iron":1}"#,
                r#"[{"hard_iron":[0,0,0]}]"#,
                r#"{"hard_iron":[0,0,0],"soft_iron":[[1,0,0],[0,1,0],[0,0,1]],"hard_iron":[1,2,3]}"#,
                "{}",
                "",
                "null",
            ];
            rng.pick(&objects).as_bytes().to_vec()
        }
        // Deep nesting (a recursion-limit probe).
        _ => {
            let depth = 1 + rng.index(100_000);
            ["[".repeat(depth), "]".repeat(depth)].concat().into_bytes()
        }
    }
}

/// A command line for case `index`, writing its files under `dir`; the
/// input and whether it goes through stdin.
struct Run {
    args: Vec<String>,
    stdin: Option<Vec<u8>>,
    apply: bool,
    json: bool,
    /// `fit --plain`.
    plain: bool,
    /// `apply --flags`.
    flags: bool,
    description: String,
}

fn build_run(rng: &mut Rng, dir: &std::path::Path, valid_cal: &[u8]) -> Run {
    let (kind, bytes) = input_file(rng);
    let input = dir.join("input");
    let via_stdin = rng.chance(0.25);
    std::fs::write(&input, &bytes).expect("write input");
    let file_arg = if via_stdin {
        "-".to_string()
    } else {
        input.display().to_string()
    };
    let columns = |rng: &mut Rng| -> String {
        let names: Vec<&str> = (0..3)
            .map(|_| {
                *rng.pick(&[
                    "x", "y", "z", "ax", "ay", "az", "magx", "q", "X", "1", "3", "7", "9", "40",
                ])
            })
            .collect();
        names.join(",")
    };
    let apply = rng.chance(0.3);
    let (mut json, mut plain, mut flags) = (false, false, false);
    let mut args: Vec<String> = Vec::new();
    if apply {
        let cal = dir.join("cal.json");
        std::fs::write(&cal, calibration_file(rng, valid_cal)).expect("write cal");
        args.extend(["apply".into(), cal.display().to_string(), file_arg]);
        if rng.chance(0.3) {
            args.extend(["--columns".into(), columns(rng)]);
        }
        if rng.chance(0.3) {
            args.extend(["--accel-columns".into(), columns(rng)]);
        }
        if rng.chance(0.3) {
            args.extend(["--window".into(), (1 + rng.index(128)).to_string()]);
        }
        if rng.chance(0.3) {
            args.push("--scaled".into());
        }
        flags = rng.chance(0.4);
        if flags {
            args.push("--flags".into());
        }
    } else {
        let method = *rng.pick(&["ls", "submle", "adc1", "adc2", "adc2-iter"]);
        let ls = *rng.pick(&["ls9", "svd10", "lg10"]);
        let precision = *rng.pick(&["f32", "f64"]);
        json = rng.chance(0.5);
        args.extend([
            "fit".into(),
            file_arg,
            "--method".into(),
            method.into(),
            "--ls".into(),
            ls.into(),
            "--precision".into(),
            precision.into(),
            "--format".into(),
            if json { "json" } else { "text" }.into(),
        ]);
        if rng.chance(0.15) {
            args.extend(["--columns".into(), columns(rng)]);
        }
        if rng.chance(0.1) {
            let s = *rng.pick(&["0.5,0.5,0.5", "1e-100,1,1", "1e100,1e100,1e100", "3,2,1"]);
            args.extend(["--noise-std".into(), s.into()]);
        }
        if rng.chance(0.1) {
            args.extend(["--plot".into(), dir.join("plot.svg").display().to_string()]);
        }
        plain = rng.chance(0.2);
        if plain {
            args.push("--plain".into());
        }
    }
    let description = format!(
        "{kind} input ({} bytes), via stdin: {via_stdin}",
        bytes.len()
    );
    Run {
        args,
        stdin: via_stdin.then_some(bytes),
        apply,
        json,
        plain,
        flags,
        description,
    }
}

/// Runs `magcal` and checks the contract; returns the exit code, or what
/// is wrong.
fn run_and_check(run: &Run) -> Result<i32, String> {
    let mut child = Command::new(env!("CARGO_BIN_EXE_magcal"))
        .args(&run.args)
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .map_err(|e| format!("spawn: {e}"))?;
    let input = run.stdin.clone().unwrap_or_default();
    let mut pipe = child.stdin.take().ok_or("no stdin")?;
    let writer = std::thread::spawn(move || {
        let _ = pipe.write_all(&input);
    });
    let out = child.wait_with_output().map_err(|e| format!("wait: {e}"))?;
    let _ = writer.join();
    let stdout = String::from_utf8_lossy(&out.stdout);
    let stderr = String::from_utf8_lossy(&out.stderr);
    let Some(code) = out.status.code() else {
        return Err(format!(
            "killed by a signal: {:?}; stderr: {stderr}",
            out.status
        ));
    };
    let allowed: &[i32] = if run.apply { &[0, 2] } else { &[0, 2, 3] };
    if code == 101 || !allowed.contains(&code) {
        return Err(format!("exit {code}; stderr: {stderr}"));
    }
    if code != 0 {
        if stderr.lines().count() != 1 || !stderr.starts_with("magcal: ") {
            return Err(format!("exit {code} with stderr {stderr:?}"));
        }
        return Ok(code);
    }
    // The notes a success may print, in this order, each at most once.
    let mut notes = stderr.lines().peekable();
    if run.apply || run.json {
        notes.next_if(|l| l.starts_with("magcal: note: columns "));
        notes.next_if(|l| l.starts_with("magcal: note: input: "));
    }
    if run.flags {
        notes.next_if(|l| {
            l.starts_with("magcal: note: ")
                && l.ends_with(" has no 'selection' (written before outlier handling): --flags marks every finite row used")
        });
    }
    if notes.next().is_some() || !(stderr.is_empty() || stderr.ends_with('\n')) {
        return Err(format!("exit 0 with stderr {stderr:?}"));
    }
    if run.apply {
        if !stdout.starts_with("x,y,z") {
            return Err(format!(
                "apply: stdout {:?}",
                &stdout[..stdout.len().min(200)]
            ));
        }
        if run.flags {
            check_flags(&stdout)?;
        }
    } else if run.json {
        let v: Value = serde_json::from_str(&stdout).map_err(|e| format!("json: {e}: {stdout}"))?;
        let finite = |v: &Value| v.as_f64().is_some_and(f64::is_finite);
        let b = v["hard_iron"].as_array().ok_or("no hard_iron")?;
        let w = v["soft_iron"].as_array().ok_or("no soft_iron")?;
        if b.len() != 3
            || !b.iter().all(finite)
            || w.len() != 3
            || !w.iter().all(|r| {
                r.as_array()
                    .is_some_and(|r| r.len() == 3 && r.iter().all(finite))
            })
            || !finite(&v["field_strength"])
            || !v["field_strength"].as_f64().is_some_and(|r| r > 0.0)
        {
            return Err(format!("json without finite parameters: {stdout}"));
        }
        check_counts(&v, run.plain).map_err(|e| format!("{e}: {stdout}"))?;
    } else if !stdout.contains("\n  samples       ") || !stdout.contains(" used of ") {
        return Err(format!("text without its samples line: {stdout:?}"));
    }
    Ok(code)
}

/// The row counts, figures and selection of a fit JSON agree.
fn check_counts(v: &Value, plain: bool) -> Result<(), String> {
    let count = |key: &str| v[key].as_u64().ok_or(format!("no count {key}"));
    let [used, dropped, dwell, screened, rejected] = [
        count("samples_used")?,
        count("samples_dropped")?,
        count("dwell")?,
        count("screened")?,
        count("rejected")?,
    ];
    let drops = v["drops"].as_object().ok_or("no drops object")?;
    let rules = [
        "non_finite",
        "overflow",
        "zero",
        "rails",
        "repeated",
        "clipped",
    ];
    let mut by_rule = 0;
    for rule in rules {
        by_rule += drops
            .get(rule)
            .and_then(Value::as_u64)
            .ok_or(format!("no drops.{rule}"))?;
    }
    if drops.len() != rules.len() || by_rule != dropped {
        return Err(format!("drops {drops:?} vs samples_dropped {dropped}"));
    }
    if v["robust"].as_bool() != Some(!plain) || v["robust_passes"].as_u64().is_none() {
        return Err("robust / robust_passes".into());
    }
    let q = &v["quality"];
    let figure = |key: &str| {
        q[key]
            .as_f64()
            .filter(|x| x.is_finite() && *x >= 0.0)
            .ok_or(format!("quality.{key} not a finite non-negative number"))
    };
    let (_, _, share) = (
        figure("fit_error")?,
        figure("lack_of_fit")?,
        figure("outlier_share")?,
    );
    let kept = used + screened + rejected;
    if kept > 0 && (share - (screened + rejected) as f64 / kept as f64).abs() > 1e-6 {
        return Err(format!("outlier_share {share} vs counts"));
    }
    let s = &v["selection"];
    let glitch_rules = s["glitch_rules"]
        .as_bool()
        .ok_or("selection.glitch_rules")?;
    let levels = s["clip_levels"]
        .as_array()
        .filter(|a| {
            a.len() == 3
                && a.iter().all(|p| {
                    p.as_array().is_some_and(|p| {
                        p.len() == 2 && p.iter().all(|l| l.is_null() || l.is_f64() || l.is_i64())
                    })
                })
        })
        .ok_or("selection.clip_levels")?;
    let screen = &s["screen"];
    let screen_ok = screen.is_null()
        || (screen["centre"].as_array().is_some_and(|c| c.len() == 3)
            && screen["radius"].as_f64().is_some_and(|r| r >= 0.0));
    // At most 3 balls (centre, non-negative radius).
    let balls_ok = s["dwell"].as_array().is_some_and(|balls| {
        balls.len() <= 3
            && balls.iter().all(|b| {
                b["centre"]
                    .as_array()
                    .is_some_and(|c| c.len() == 3 && c.iter().all(|x| x.as_f64().is_some()))
                    && b["radius"].as_f64().is_some_and(|r| r >= 0.0)
            })
    });
    if !balls_ok || (dwell > 0 && s["dwell"].as_array().is_some_and(Vec::is_empty)) {
        return Err("selection.dwell vs dwell".into());
    }
    let limit = &s["residual_limit"];
    if !screen_ok || !(limit.is_null() || limit.as_f64().is_some_and(|l| l >= 0.0)) {
        return Err("selection.screen / residual_limit".into());
    }
    if plain
        && (screened + rejected > 0
            || glitch_rules
            || !screen.is_null()
            || !limit.is_null()
            || levels
                .iter()
                .filter_map(Value::as_array)
                .flatten()
                .any(|l| !l.is_null()))
    {
        return Err("--plain screened, rejected or applied glitch rules".into());
    }
    Ok(())
}

/// The `used` and `class` columns of `apply --flags` agree on every row.
fn check_flags(stdout: &str) -> Result<(), String> {
    let mut lines = stdout.lines();
    let header = lines.next().unwrap_or_default();
    if !header.ends_with(",used,class") {
        return Err(format!("--flags header {header:?}"));
    }
    let width = header.split(',').count();
    for line in lines {
        let fields: Vec<&str> = line.split(',').collect();
        let ok = fields.len() == width
            && match fields[width - 2..] {
                ["1", "used"] => true,
                ["0", "screened" | "rejected" | "dwell"] => true,
                ["0", class] => class.strip_prefix("dropped:").is_some_and(|rule| {
                    [
                        "non_finite",
                        "overflow",
                        "zero",
                        "rails",
                        "repeated",
                        "clipped",
                    ]
                    .contains(&rule)
                }),
                _ => false,
            };
        if !ok {
            return Err(format!("--flags row {line:?}"));
        }
    }
    Ok(())
}

fn env_u64(name: &str) -> Option<u64> {
    let v = std::env::var(name).ok()?;
    let v = v.trim().replace('_', "");
    let parsed = match v.strip_prefix("0x") {
        Some(hex) => u64::from_str_radix(hex, 16),
        None => v.parse(),
    };
    Some(parsed.unwrap_or_else(|_| panic!("{name}={v} is not a number")))
}

/// A valid calibration file: `magcal fit --format json` on clean data,
/// its wall time replaced by a constant (the corrupt variants cut and
/// change bytes at positions drawn from the case: a time of another length
/// would shift them, and the outcomes would vary from run to run).
fn valid_calibration(dir: &std::path::Path) -> Vec<u8> {
    let mut rng = Rng(host_tests::sim::Rng(7));
    let rows = ellipsoid_rows(&mut rng, 300);
    let data = dir.join("clean.csv");
    let text = format!("{ELLIPSOID_HEADER}\n{}", rows.join("\n"));
    std::fs::write(&data, text).expect("write clean data");
    let out = Command::new(env!("CARGO_BIN_EXE_magcal"))
        .args(["fit", &data.display().to_string(), "--format", "json"])
        .output()
        .expect("magcal runs");
    assert_eq!(
        out.status.code(),
        Some(0),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let text = String::from_utf8(out.stdout).expect("JSON is UTF-8");
    let key = "\"timing_us\":";
    let start = text.find(key).expect("timing_us") + key.len();
    let end = start + text[start..].find(',').expect("a field after timing_us");
    format!("{}100.0{}", &text[..start], &text[end..]).into_bytes()
}

#[test]
fn fuzz_cli() {
    let seed = env_u64("MAGCAL_FUZZ_SEED").unwrap_or(DEFAULT_SEED);
    let replay = env_u64("MAGCAL_FUZZ_CASE");
    let (first, cases) = match replay {
        Some(i) => (i, 1),
        None => (0, env_u64("MAGCAL_FUZZ_CLI_CASES").unwrap_or(1000)),
    };
    let threads = env_u64("MAGCAL_FUZZ_THREADS")
        .map(|t| t.max(1) as usize)
        .unwrap_or_else(|| std::thread::available_parallelism().map_or(1, |n| n.get()));
    let root = PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join(format!("fuzz_cli_{seed:x}"));
    std::fs::create_dir_all(&root).expect("scratch directory");
    let valid_cal = valid_calibration(&root);

    let next = AtomicU64::new(first);
    let exits = Mutex::new([0u64; 3]); // runs that passed, by exit 0, 2, 3
    let failures: Mutex<Vec<(u64, String)>> = Mutex::new(Vec::new());
    let start = Instant::now();
    std::thread::scope(|scope| {
        for worker in 0..threads {
            let (next, exits, failures, root, valid_cal) =
                (&next, &exits, &failures, &root, &valid_cal);
            scope.spawn(move || {
                let dir = root.join(format!("w{worker}"));
                std::fs::create_dir_all(&dir).expect("worker directory");
                loop {
                    let i = next.fetch_add(1, Ordering::Relaxed);
                    if i >= first + cases {
                        break;
                    }
                    if cases >= 5000 && i > first && (i - first) % 1000 == 0 {
                        eprintln!(
                            "fuzz_cli: {} runs, {:.0} s",
                            i - first,
                            start.elapsed().as_secs_f64()
                        );
                    }
                    let mut rng = Rng::for_case(seed, i);
                    let run = build_run(&mut rng, &dir, valid_cal);
                    if replay.is_some() {
                        eprintln!(
                            "case {i}: {}\n  magcal {}\n  input kept in {}",
                            run.description,
                            run.args.join(" "),
                            dir.display()
                        );
                    }
                    match run_and_check(&run) {
                        Ok(code) => {
                            let slot = match code {
                                0 => 0,
                                2 => 1,
                                _ => 2,
                            };
                            exits.lock().unwrap()[slot] += 1;
                        }
                        Err(msg) => failures.lock().unwrap().push((
                            i,
                            format!(
                                "{} | magcal {} | {msg}",
                                run.description,
                                run.args.join(" ")
                            ),
                        )),
                    }
                }
            });
        }
    });
    let elapsed = start.elapsed().as_secs_f64();
    let [ok, usage, refused] = exits.into_inner().unwrap();
    eprintln!(
        "fuzz_cli: {cases} runs from case {first}, seed {seed:#x}, {threads} threads, \
         {elapsed:.1} s; exit 0: {ok}, exit 2: {usage}, exit 3: {refused}"
    );
    let mut failures = failures.into_inner().unwrap();
    failures.sort();
    if !failures.is_empty() {
        for (i, msg) in failures.iter().take(20) {
            let msg: String = msg.chars().take(600).collect();
            eprintln!("  case {i}: {msg}");
        }
        panic!(
            "fuzz_cli: {} of {cases} runs failed (seed {seed:#x}); replay one with \
             MAGCAL_FUZZ_SEED={seed:#x} MAGCAL_FUZZ_CASE=<index>",
            failures.len()
        );
    }
}
