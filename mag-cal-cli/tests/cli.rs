//! End-to-end tests of the `magcal` binary: real recordings, exit codes,
//! error messages, and hostile input.

use std::io::Write;
use std::path::PathBuf;
use std::process::{Command, Stdio};

use serde_json::Value;

/// The shared folder of real recordings, beside the repository root.
const REAL: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/../../shared/data/real/");

/// Magneto 1.4's hard iron on `icm20948_mag_300.csv` (after it rejected 10
/// outliers), from `icm20948_mag_300.magneto14.lis`.
const MAGNETO_B: [f64; 3] = [-156.70, -52.79, -141.07];

/// A finished run of the binary.
struct Run {
    code: i32,
    stdout: String,
    stderr: String,
}

impl Run {
    /// Asserts a failure with `code` and exactly one `magcal: ` line on
    /// stderr containing `reason`.
    fn fails_with(&self, code: i32, reason: &str) {
        assert_eq!(self.code, code, "stderr: {}", self.stderr);
        assert_eq!(self.stderr.lines().count(), 1, "stderr: {:?}", self.stderr);
        assert!(
            self.stderr.starts_with("magcal: "),
            "stderr: {}",
            self.stderr
        );
        assert!(self.stderr.contains(reason), "stderr: {}", self.stderr);
        assert!(self.stdout.is_empty(), "stdout: {}", self.stdout);
    }

    /// The stdout as the JSON report, after checking success.
    fn json(&self) -> Value {
        assert_eq!(self.code, 0, "stderr: {}", self.stderr);
        assert_eq!(self.stdout.lines().count(), 1, "one line: {}", self.stdout);
        serde_json::from_str(&self.stdout).expect("stdout is JSON")
    }
}

/// Runs `magcal` with `args`, feeding `stdin` (empty when `None`).
fn magcal(args: &[&str], stdin: Option<&[u8]>) -> Run {
    let mut child = Command::new(env!("CARGO_BIN_EXE_magcal"))
        .args(args)
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("binary starts");
    let input = stdin.unwrap_or_default().to_vec();
    let mut pipe = child.stdin.take().expect("stdin piped");
    // The child may exit before reading everything; a broken pipe is fine.
    let writer = std::thread::spawn(move || {
        let _ = pipe.write_all(&input);
    });
    let out = child.wait_with_output().expect("binary runs");
    writer.join().expect("writer thread");
    Run {
        code: out.status.code().expect("exited, not killed by a signal"),
        stdout: String::from_utf8_lossy(&out.stdout).into_owned(),
        stderr: String::from_utf8_lossy(&out.stderr).into_owned(),
    }
}

/// Path of a real recording.
fn real(name: &str) -> String {
    let path = format!("{REAL}{name}");
    assert!(PathBuf::from(&path).is_file(), "missing test data {path}");
    path
}

/// Writes `bytes` to a fresh file in Cargo's scratch directory.
fn temp_file(name: &str, bytes: &[u8]) -> String {
    let path = PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join(name);
    std::fs::write(&path, bytes).expect("scratch file written");
    path.display().to_string()
}

/// Reads `x,y,z` rows of a header-less CSV.
fn read_xyz(path: &str) -> Vec<[f64; 3]> {
    std::fs::read_to_string(path)
        .expect("readable")
        .lines()
        .filter(|l| !l.trim().is_empty())
        .map(|l| {
            let v: Vec<f64> = l
                .split(',')
                .map(|f| f.trim().parse().expect("number"))
                .collect();
            [v[0], v[1], v[2]]
        })
        .collect()
}

fn vec3(v: &Value) -> [f64; 3] {
    let a = v.as_array().expect("array");
    assert_eq!(a.len(), 3);
    [0, 1, 2].map(|i| a[i].as_f64().expect("number"))
}

fn mat3(v: &Value) -> [[f64; 3]; 3] {
    let rows = v.as_array().expect("array of rows");
    assert_eq!(rows.len(), 3);
    [0, 1, 2].map(|i| vec3(&rows[i]))
}

#[test]
fn json_on_icm20948_agrees_with_magneto() {
    let path = real("icm20948_mag_300.csv");
    let v = magcal(&["fit", &path, "--format", "json"], None).json();

    for key in [
        "method",
        "ls",
        "precision",
        "samples_used",
        "samples_dropped",
        "hard_iron",
        "soft_iron",
        "field_strength",
        "iterations",
        "timing_us",
        "quality",
    ] {
        assert!(v.get(key).is_some(), "missing {key} in {v}");
    }
    assert_eq!(v["method"], "adc2");
    assert_eq!(v["ls"], "ls9");
    assert_eq!(v["precision"], "f64");
    assert_eq!(v["samples_used"], 300);
    assert_eq!(v["samples_dropped"], 0);
    assert!(v["iterations"].as_u64().is_some_and(|n| n > 0));
    assert!(v["timing_us"].as_f64().is_some_and(|t| t > 0.0 && t < 5e6));
    let rms = v["quality"]["radial_rms"].as_f64().expect("radial_rms");
    let spread = v["quality"]["norm_spread"].as_f64().expect("norm_spread");
    assert!(rms > 0.0 && rms < 0.1 && spread > 0.0 && spread < 0.1);
    let rho = v["field_strength"].as_f64().expect("field_strength");
    assert!(rho > 200.0 && rho < 500.0, "{rho}");

    let b = vec3(&v["hard_iron"]);
    for (got, want) in b.iter().zip(MAGNETO_B) {
        assert!(
            (got - want).abs() < 15.0,
            "hard iron {b:?} vs Magneto {MAGNETO_B:?}"
        );
    }
    let w = mat3(&v["soft_iron"]);
    for (i, row) in w.iter().enumerate() {
        for (j, value) in row.iter().enumerate() {
            assert!(
                (value - w[j][i]).abs() <= 1e-12 * w[i][i].abs(),
                "W not symmetric: {w:?}"
            );
        }
    }

    // W (y - b) lies on the unit sphere on average.
    let samples = read_xyz(&path);
    let norms: Vec<f64> = samples
        .iter()
        .map(|y| {
            let d = [y[0] - b[0], y[1] - b[1], y[2] - b[2]];
            let u = w.map(|r| r[0] * d[0] + r[1] * d[1] + r[2] * d[2]);
            (u[0] * u[0] + u[1] * u[1] + u[2] * u[2]).sqrt()
        })
        .collect();
    let mean = norms.iter().sum::<f64>() / norms.len() as f64;
    assert!((mean - 1.0).abs() < 0.01, "mean |W (y - b)| = {mean}");
}

#[test]
fn columns_pick_named_fields() {
    let path = real("imu_gnss_1252.csv");
    let v = magcal(
        &[
            "fit",
            &path,
            "--columns",
            "magx,magy,magz",
            "--format",
            "json",
        ],
        None,
    )
    .json();
    assert_eq!(v["samples_used"], 1252);
    // Raw counts of a few hundred: the accelerometer columns would give a
    // field strength near 9.8.
    let rho = v["field_strength"].as_f64().expect("field_strength");
    assert!(rho > 100.0, "{rho}");
    assert!(v["quality"]["radial_rms"].as_f64().is_some_and(|r| r < 0.1));

    let r = magcal(&["fit", &path, "--columns", "magx,magy,nope"], None);
    r.fails_with(2, "no column named 'nope'");
}

#[test]
fn stdin_and_text_format() {
    let bytes = std::fs::read(real("icm20948_mag_300.csv")).expect("readable");
    let text = magcal(&["fit", "-"], Some(&bytes));
    assert_eq!(text.code, 0, "{}", text.stderr);
    assert!(text.stderr.is_empty());
    for needle in [
        "<stdin>",
        "adc2",
        "ls9",
        "f64",
        "300 used",
        "radial RMS",
        "norm spread",
    ] {
        assert!(
            text.stdout.contains(needle),
            "{needle} missing in\n{}",
            text.stdout
        );
    }
    assert!(text.stdout.contains("calibrated = W (raw - b)"));

    // The hard-iron line of the text report holds the JSON's numbers.
    let v = magcal(&["fit", "-", "--format", "json"], Some(&bytes)).json();
    let b = vec3(&v["hard_iron"]);
    let mut lines = text.stdout.lines();
    lines.by_ref().find(|l| l.starts_with("hard iron b"));
    let row: Vec<f64> = lines
        .next()
        .expect("row after the heading")
        .trim_matches(|c: char| c == ' ' || c == '[' || c == ']')
        .split_whitespace()
        .map(|f| f.parse().expect("number"))
        .collect();
    assert_eq!(row.len(), 3);
    for (shown, exact) in row.iter().zip(b) {
        assert!((shown - exact).abs() < 1e-3, "{row:?} vs {b:?}");
    }
}

#[test]
fn non_finite_rows_are_dropped_and_counted() {
    let mut bytes = b"# x,y,z\nnan,1,2\n".to_vec();
    bytes.extend(std::fs::read(real("icm20948_mag_300.csv")).expect("readable"));
    bytes.extend_from_slice(b"1e400,0,0\n-inf,0,0\n");
    let v = magcal(&["fit", "-", "--format", "json"], Some(&bytes)).json();
    assert_eq!(
        (v["samples_used"].as_u64(), v["samples_dropped"].as_u64()),
        (Some(300), Some(3))
    );
}

#[test]
fn methods_and_ls_variants() {
    let path = real("icm20948_mag_300.csv");
    for (method, ls) in [
        ("ls", "ls9"),
        ("ls", "svd10"),
        ("ls", "lg10"),
        ("adc2", "lg10"),
    ] {
        let v = magcal(
            &[
                "fit", &path, "--method", method, "--ls", ls, "--format", "json",
            ],
            None,
        )
        .json();
        assert_eq!(
            (v["method"].as_str(), v["ls"].as_str()),
            (Some(method), Some(ls))
        );
        if method == "ls" {
            assert_eq!(v["iterations"], 0);
        }
        let b = vec3(&v["hard_iron"]);
        for (got, want) in b.iter().zip(MAGNETO_B) {
            assert!((got - want).abs() < 15.0, "{method}/{ls}: {b:?}");
        }
    }
}

#[test]
fn f32_agrees_with_f64_on_large_offsets() {
    let path = real("mag3_raw_541.csv");
    let fit = |precision: &str| {
        let v = magcal(
            &["fit", &path, "--precision", precision, "--format", "json"],
            None,
        )
        .json();
        assert_eq!(v["precision"], precision);
        vec3(&v["hard_iron"])
    };
    let (b32, b64) = (fit("f32"), fit("f64"));
    assert!(
        b64.iter().all(|v| v.abs() > 5e3),
        "offset near 1e4: {b64:?}"
    );
    for (single, double) in b32.iter().zip(b64) {
        assert!(
            (single - double).abs() <= 1e-3 * double.abs(),
            "{b32:?} vs {b64:?}"
        );
    }
}

#[test]
fn help_and_version() {
    for flag in ["--help", "-h"] {
        let r = magcal(&[flag], None);
        assert_eq!(r.code, 0);
        for needle in [
            "fit",
            "--method",
            "--ls",
            "--precision",
            "--format",
            "--columns",
            "Exit status",
        ] {
            assert!(
                r.stdout.contains(needle),
                "{needle} missing in\n{}",
                r.stdout
            );
        }
    }
    let r = magcal(&["fit", "--help"], None);
    assert_eq!(r.code, 0);
    assert!(r.stdout.contains("lg10") && r.stdout.contains("'-' for stdin"));
    let r = magcal(&["--version"], None);
    assert_eq!(r.code, 0);
    assert_eq!(
        r.stdout.trim(),
        format!("magcal {}", env!("CARGO_PKG_VERSION"))
    );
}

#[test]
fn usage_and_input_errors_exit_2() {
    // Usage errors: clap's message, first line names the reason.
    for args in [
        &["fit", "x.csv", "--bogus"][..],
        &["fit", "x.csv", "--method", "magic"],
        &["fit", "x.csv", "--columns", "a,b"],
        &["fit"],
        &["frobnicate"],
        &[],
    ] {
        let r = magcal(args, None);
        assert_eq!(r.code, 2, "{args:?}: {}", r.stderr);
        let first = r.stderr.lines().next().unwrap_or_default();
        assert!(!first.trim().is_empty(), "{args:?}: stderr {:?}", r.stderr);
        assert!(r.stdout.is_empty());
    }
    let r = magcal(&["fit", "x.csv", "--method", "magic"], None);
    assert!(r
        .stderr
        .starts_with("error: invalid value 'magic' for '--method"));

    // Our own errors: exactly one line.
    magcal(&["fit", "/nonexistent/dir/foo.csv"], None).fails_with(
        2,
        "cannot read /nonexistent/dir/foo.csv: No such file or directory",
    );
    magcal(&["fit", env!("CARGO_MANIFEST_DIR")], None).fails_with(2, "cannot read");
    let bad = temp_file("bad_line.csv", b"x,y,z\n1,2,3\n\n4,abc,6\n7,8,9\n");
    magcal(&["fit", &bad], None).fails_with(2, "line 4: 'abc' is not a number");
    magcal(&["fit", "-"], Some(b"1 2 3\n4 5\n"))
        .fails_with(2, "line 2: expected at least 3 fields");
    magcal(&["fit", "-", "--columns", "a,b,c"], Some(b"1,2,3\n"))
        .fails_with(2, "--columns needs a header");
    magcal(&["fit", "-"], Some(b"")).fails_with(2, "no data rows");
}

#[test]
fn refusals_exit_3() {
    let equal = "5,5,5\n".repeat(50);
    magcal(&["fit", "-"], Some(equal.as_bytes()))
        .fails_with(3, "calibration refused: all samples are equal");

    let five = temp_file(
        "five.csv",
        b"-231,29,161\n-233,35,167\n-228,38,172\n-240,38,176\n-234,32,173\n",
    );
    magcal(&["fit", &five], None)
        .fails_with(3, "calibration refused: too few usable samples: 5 finite");

    // A planar circle determines no ellipsoid.
    let circle: String = (0..100)
        .map(|i| {
            let a = f64::from(i) * 0.0628;
            format!("{},{},7\n", 300.0 + 40.0 * a.cos(), -20.0 + 40.0 * a.sin())
        })
        .collect();
    for method in ["adc2", "ls"] {
        magcal(&["fit", "-", "--method", method], Some(circle.as_bytes()))
            .fails_with(3, "calibration refused: ");
    }
}

/// A small deterministic generator (xorshift64*) for hostile inputs.
struct Rng(u64);

impl Rng {
    fn next(&mut self) -> u64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        self.0.wrapping_mul(0x2545_f491_4f6c_dd1d)
    }

    fn bytes(&mut self, n: usize, alphabet: &[u8]) -> Vec<u8> {
        (0..n)
            .map(|_| {
                let r = self.next();
                if alphabet.is_empty() {
                    r.to_le_bytes()[7]
                } else {
                    alphabet[usize::try_from(r % alphabet.len() as u64).unwrap_or(0)]
                }
            })
            .collect()
    }
}

#[test]
fn hostile_input_never_panics() {
    let mut rng = Rng(0x9e37_79b9_7f4a_7c15);
    let mut inputs: Vec<(String, Vec<u8>)> = vec![
        ("empty".into(), Vec::new()),
        ("blank lines".into(), b"\n\n  \n\r\n".to_vec()),
        ("one column".into(), "1\n2\n3\n".repeat(10).into_bytes()),
        (
            "huge row repeated".into(),
            "1e300,1e300,1e300\n".repeat(40).into_bytes(),
        ),
        (
            "1e400".into(),
            "1e400,1e400,1e400\n".repeat(40).into_bytes(),
        ),
        (
            "huge varied".into(),
            (0..40)
                .map(|i| format!("{i}e300,-{i}e301,1e{}\n", 290 + i % 18))
                .collect::<String>()
                .into_bytes(),
        ),
        (
            "tiny varied".into(),
            (0..40)
                .map(|i| format!("{i}e-320,{}e-321,1e-310\n", i % 7))
                .collect::<String>()
                .into_bytes(),
        ),
        (
            "mixed column counts".into(),
            b"1,2,3\n4,5\n6,7,8,9\n".to_vec(),
        ),
        ("header only".into(), b"x,y,z\n".to_vec()),
        (
            "invalid utf-8".into(),
            b"x,y,z\n1,2,3\n\xff\xfe,2,3\n".to_vec(),
        ),
        ("nul bytes".into(), b"1,2,3\n\0\0\0\n".to_vec()),
        ("all nan".into(), "nan,nan,nan\n".repeat(30).into_bytes()),
        (
            "long field".into(),
            [b"1,2,".as_slice(), &[b'9'; 100_000], b"\n"].concat(),
        ),
    ];
    for i in 0..4 {
        inputs.push((format!("random bytes {i}"), rng.bytes(2000, &[])));
        inputs.push((
            format!("random numeric text {i}"),
            rng.bytes(
                3000,
                b"0123456789012345678901234567890123456789,,,,  \n\n\n\n.-e",
            ),
        ));
    }
    for (name, bytes) in &inputs {
        for precision in ["f64", "f32"] {
            let r = magcal(
                &["fit", "-", "--precision", precision, "--format", "json"],
                Some(bytes),
            );
            assert!(
                matches!(r.code, 0 | 2 | 3),
                "{name} ({precision}): exit {} {}",
                r.code,
                r.stderr
            );
            if r.code == 0 {
                r.json();
            } else {
                assert_eq!(r.stderr.lines().count(), 1, "{name}: {:?}", r.stderr);
                assert!(r.stderr.starts_with("magcal: "), "{name}: {}", r.stderr);
            }
        }
    }
    // The same through a file path.
    let path = temp_file("garbage.bin", &rng.bytes(5000, &[]));
    let r = magcal(&["fit", &path], None);
    assert_eq!(r.code, 2, "{}", r.stderr);
}
