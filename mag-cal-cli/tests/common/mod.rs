//! What the end-to-end tests of `magcal` share: running the binary, the
//! real recordings read in place, scratch files.
// Each test file uses a part of this module.
#![allow(dead_code)]

use std::io::Write;
use std::path::PathBuf;
use std::process::{Command, Stdio};

use serde_json::Value;

/// The shared folder of real recordings, beside the repository root.
pub const REAL: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/../../shared/data/real/");

/// A finished run of the binary.
pub struct Run {
    pub code: i32,
    pub stdout: String,
    pub stderr: String,
}

impl Run {
    /// Asserts a failure with `code` and exactly one `magcal: ` line on
    /// stderr containing `reason`.
    pub fn fails_with(&self, code: i32, reason: &str) {
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
    pub fn json(&self) -> Value {
        assert_eq!(self.code, 0, "stderr: {}", self.stderr);
        self.any_json()
    }

    /// The stdout as one JSON object, whatever the exit code.
    pub fn any_json(&self) -> Value {
        assert_eq!(self.stdout.lines().count(), 1, "one line: {}", self.stdout);
        serde_json::from_str(&self.stdout).expect("stdout is JSON")
    }
}

/// Runs `magcal` with `args` and no input on stdin.
pub fn magcal(args: &[&str]) -> Run {
    magcal_in(args, None)
}

/// Runs `magcal` with `args`, feeding `stdin` (empty when `None`).
pub fn magcal_in(args: &[&str], stdin: Option<&[u8]>) -> Run {
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
pub fn real(name: &str) -> String {
    let path = format!("{REAL}{name}");
    assert!(PathBuf::from(&path).is_file(), "missing test data {path}");
    path
}

/// Writes `contents` to a fresh file in Cargo's scratch directory.
pub fn temp_file(name: &str, contents: impl AsRef<[u8]>) -> String {
    let path = PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join(name);
    std::fs::write(&path, contents).expect("scratch file written");
    path.display().to_string()
}

/// Reads the `x,y,z` rows of a header-less CSV.
pub fn read_xyz(path: &str) -> Vec<[f64; 3]> {
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

/// A JSON array of three numbers.
pub fn vec3(v: &Value) -> [f64; 3] {
    let a = v.as_array().expect("array");
    assert_eq!(a.len(), 3);
    [0, 1, 2].map(|i| a[i].as_f64().expect("number"))
}

/// `n` readings of a device lying still at `r`: each axis plus `-step`,
/// 0, 0 or `+step`, from a fixed LCG whose `state` goes on from call to
/// call (a sensor's noise of about a count).
pub fn still_rows(r: [f64; 3], n: usize, step: f64, state: &mut u32) -> Vec<[f64; 3]> {
    (0..n)
        .map(|_| {
            r.map(|v| {
                *state = state.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
                v + [-step, 0.0, 0.0, step][(*state >> 30) as usize]
            })
        })
        .collect()
}
