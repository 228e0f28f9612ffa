//! Host benchmarks of every calibration method (criterion).
//!
//! `cargo bench -p benches` times one whole `calibrate::<T, [i16; 3]>` call
//! (raw samples to validated result: every pass and check) for each method
//! (`ls` is LS9 alone; every other method starts from LS9), at
//! n = 100, 1000, 10 000 and 100 000 samples, in `f32` and `f64`, then
//! prints a summary computed from this run's criterion estimates (medians):
//! the time per call and per sample, the same-run ratios ADC2/LS,
//! subMLE/ADC2, iterated/ADC2 and ADC1/ADC2 at each n, and how the time
//! grows with n (the ratio of successive n is 10 for a linear cost).
//! Criterion runs the benchmarks one after another, so load from other
//! processes during one of them skews a ratio; the summary therefore adds
//! each cell's minimum over the samples, and an interleaved check follows:
//! the methods alternate round after round (500 rounds at n = 100 down to
//! 15 at n = 100 000) and each keeps its fastest single call, so load hits
//! all alike. The host budget line
//! (`BUDGET host ... adc2/ls=<r> (at most 2): met|MISSED`) comes from that
//! check.
//!
//! The samples are simulated `[i16; 3]` counts of a full sphere, seeded:
//! field directions uniform on the sphere, the firmware example's sensor
//! (`firmware-example/src/sim.rs`): a 320-count field, soft iron
//! `V diag(0.8, 1.0, 1.25) V^T`, hard iron (180, -95, 240) counts, 2.5
//! counts of Gaussian noise per axis, rounded to counts.
//!
//! Criterion's arguments work as usual, e.g. `cargo bench -p benches --
//! f32/adc2` runs a subset (the summary then shows the rest as `-`). A full
//! run takes about two minutes: ten samples per benchmark, short warm-up
//! and measurement times, flat sampling for the large n.

use std::collections::BTreeMap;
use std::hint::black_box;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant, SystemTime};

use criterion::{BenchmarkId, Criterion, SamplingMode, Throughput};
use host_tests::sim::Rng; // SplitMix64, the generator of the firmware's simulator too
use mag_cal_core::{calibrate, Config, LsVariant, Method, Real};

/// Sample counts.
const NS: [usize; 4] = [100, 1_000, 10_000, 100_000];
/// Methods, in the order of the summary.
const METHODS: [Method; 5] = [
    Method::Ls,
    Method::Adc2,
    Method::Adc1,
    Method::Adc2Iterated,
    Method::SubMle,
];
/// Seed of the simulated samples.
const SEED: u64 = 0x6d61_672d_6361_6c21;

type Mat3 = [[f64; 3]; 3];

fn mat_mul(a: &Mat3, b: &Mat3) -> Mat3 {
    let mut c = [[0.0; 3]; 3];
    for (i, row) in c.iter_mut().enumerate() {
        for (j, v) in row.iter_mut().enumerate() {
            *v = (0..3).map(|k| a[i][k] * b[k][j]).sum();
        }
    }
    c
}

/// `R_z R_y R_x`, degrees.
fn rotation_zyx(deg: [f64; 3]) -> Mat3 {
    let [(sz, cz), (sy, cy), (sx, cx)] = deg.map(|d| d.to_radians().sin_cos());
    let rz = [[cz, -sz, 0.0], [sz, cz, 0.0], [0.0, 0.0, 1.0]];
    let ry = [[cy, 0.0, sy], [0.0, 1.0, 0.0], [-sy, 0.0, cy]];
    let rx = [[1.0, 0.0, 0.0], [0.0, cx, -sx], [0.0, sx, cx]];
    mat_mul(&rz, &mat_mul(&ry, &rx))
}

/// `n` simulated raw samples covering the full sphere.
fn samples(n: usize) -> Vec<[i16; 3]> {
    let field = 320.0;
    let v = rotation_zyx([35.0, -20.0, 50.0]);
    let s = [0.8, 1.0, 1.25];
    let mut t = [[0.0; 3]; 3];
    for (i, row) in t.iter_mut().enumerate() {
        for (j, x) in row.iter_mut().enumerate() {
            *x = field * (0..3).map(|k| v[i][k] * s[k] * v[j][k]).sum::<f64>();
        }
    }
    let b = [180.0, -95.0, 240.0];
    let noise = 2.5;
    let mut rng = Rng(SEED ^ n as u64);
    (0..n)
        .map(|_| {
            let h = loop {
                let h = [rng.normal(), rng.normal(), rng.normal()];
                let r = (h[0] * h[0] + h[1] * h[1] + h[2] * h[2]).sqrt();
                if r > 1e-9 {
                    break h.map(|c| c / r);
                }
            };
            std::array::from_fn(|i| {
                let y = t[i][0] * h[0] + t[i][1] * h[1] + t[i][2] * h[2] + b[i];
                (y + noise * rng.normal()).round() as i16
            })
        })
        .collect()
}

fn config(method: Method) -> Config {
    Config {
        method,
        ls: LsVariant::Ls9,
        ..Config::default()
    }
}

/// One group per precision: `<precision>/<method>/<n>`.
fn bench_precision<T: Real>(c: &mut Criterion, precision: &str, data: &[(usize, Vec<[i16; 3]>)]) {
    let mut group = c.benchmark_group(precision);
    group.sample_size(10);
    for (n, samples) in data {
        let n = *n;
        // Every method must succeed on the data, else the figure is a
        // refusal's cost.
        for method in METHODS {
            if let Err(e) = calibrate::<T, _>(samples, &config(method)) {
                panic!(
                    "{precision} {} n={n}: calibration failed: {e}",
                    method.name()
                );
            }
        }
        group.throughput(Throughput::Elements(n as u64));
        if n >= 10_000 {
            // One call per sample (up to ~0.5 s): flat sampling keeps the
            // run short.
            group.sampling_mode(SamplingMode::Flat);
            group.warm_up_time(Duration::from_millis(500));
            group.measurement_time(Duration::from_secs(2));
        } else {
            group.sampling_mode(SamplingMode::Auto);
            group.warm_up_time(Duration::from_millis(500));
            group.measurement_time(Duration::from_secs(1));
        }
        for method in METHODS {
            let cfg = config(method);
            group.bench_with_input(
                BenchmarkId::new(method.name(), n),
                samples.as_slice(),
                |b, s| b.iter(|| calibrate::<T, _>(black_box(s), black_box(&cfg))),
            );
        }
    }
    group.finish();
}

/// Criterion's output directory, as criterion finds it (without running
/// `cargo metadata`: this workspace's `target/` unless overridden).
fn output_directory() -> PathBuf {
    if let Some(home) = std::env::var_os("CRITERION_HOME") {
        return PathBuf::from(home);
    }
    let target = std::env::var_os("CARGO_TARGET_DIR")
        .map(PathBuf::from)
        .unwrap_or_else(|| Path::new(env!("CARGO_MANIFEST_DIR")).join("../target"));
    target.join("criterion")
}

/// Median and minimum time (ns) per call of `<precision>/<method>/<n>`,
/// from criterion's files of this run (written after `start`): the median
/// from `estimates.json`, the minimum over the samples from `sample.json`
/// (each sample's total time over its iterations). The minimum is the
/// figure least disturbed by other load on the machine.
fn times_ns(
    dir: &Path,
    precision: &str,
    method: &str,
    n: usize,
    start: SystemTime,
) -> Option<(f64, f64)> {
    let new = dir
        .join(precision)
        .join(method)
        .join(n.to_string())
        .join("new");
    let read = |name: &str| -> Option<serde_json::Value> {
        let file = new.join(name);
        let modified = std::fs::metadata(&file).ok()?.modified().ok()?;
        if modified < start {
            return None; // from an earlier run
        }
        serde_json::from_str(&std::fs::read_to_string(&file).ok()?).ok()
    };
    let median = read("estimates.json")?["median"]["point_estimate"].as_f64()?;
    let sample = read("sample.json")?;
    let iters = sample["iters"].as_array()?;
    let times = sample["times"].as_array()?;
    let min = iters
        .iter()
        .zip(times)
        .filter_map(|(i, t)| Some(t.as_f64()? / i.as_f64()?))
        .fold(f64::INFINITY, f64::min);
    Some((median, if min.is_finite() { min } else { median }))
}

fn human(ns: f64) -> String {
    if ns >= 1e9 {
        format!("{:.3} s", ns / 1e9)
    } else if ns >= 1e6 {
        format!("{:.3} ms", ns / 1e6)
    } else if ns >= 1e3 {
        format!("{:.2} us", ns / 1e3)
    } else {
        format!("{ns:.0} ns")
    }
}

fn ratio(a: Option<f64>, b: Option<f64>) -> String {
    match (a, b) {
        (Some(a), Some(b)) if b > 0.0 => format!("{:.2}", a / b),
        _ => "-".into(),
    }
}

/// `median (min)` of a ratio.
fn ratio2(a: Option<(f64, f64)>, b: Option<(f64, f64)>) -> String {
    format!(
        "{} ({})",
        ratio(a.map(|x| x.0), b.map(|x| x.0)),
        ratio(a.map(|x| x.1), b.map(|x| x.1))
    )
}

/// The table of same-run ratios (ADC2/LS, subMLE/ADC2, iterated/ADC2,
/// ADC1/ADC2) per n, from the times `get` returns, formatted by `fmt`.
fn ratio_table<V: Copy>(
    get: impl Fn(Method, usize) -> Option<V>,
    fmt: impl Fn(Option<V>, Option<V>) -> String,
) {
    println!("| n | adc2/ls | submle/adc2 | adc2-iter/adc2 | adc1/adc2 |");
    println!("|---|---|---|---|---|");
    for n in NS {
        let adc2 = get(Method::Adc2, n);
        println!(
            "| {n} | {} | {} | {} | {} |",
            fmt(adc2, get(Method::Ls, n)),
            fmt(get(Method::SubMle, n), adc2),
            fmt(get(Method::Adc2Iterated, n), adc2),
            fmt(get(Method::Adc1, n), adc2),
        );
    }
}

/// The summary of this run, from criterion's files.
fn summary(start: SystemTime) {
    let dir = output_directory();
    let mut t: BTreeMap<(&str, &str, usize), (f64, f64)> = BTreeMap::new();
    for precision in ["f32", "f64"] {
        for method in METHODS {
            for n in NS {
                if let Some(v) = times_ns(&dir, precision, method.name(), n, start) {
                    t.insert((precision, method.name(), n), v);
                }
            }
        }
    }
    let get = |p: &str, m: Method, n: usize| t.get(&(p, m.name(), n)).copied();
    println!(
        "\n==== summary of this run (criterion files in {}) ====",
        dir.display()
    );
    println!("cells: median over the samples (minimum over the samples)");
    for precision in ["f32", "f64"] {
        println!("\n{precision}: time per call; per sample, median");
        print!("| method |");
        for n in NS {
            print!(" n = {n} |");
        }
        println!();
        println!("|---|{}", "---|".repeat(NS.len()));
        for method in METHODS {
            print!("| {} |", method.name());
            for n in NS {
                match get(precision, method, n) {
                    Some((med, min)) => print!(
                        " {} ({}); {:.1} ns |",
                        human(med),
                        human(min),
                        med / n as f64
                    ),
                    None => print!(" - |"),
                }
            }
            println!();
        }
        println!("\n{precision}: same-run ratios, median (min)");
        ratio_table(|m, n| get(precision, m, n), ratio2);
        println!("\n{precision}: growth with n, t(10 n) / t(n), median (min); 10 = linear");
        print!("| method |");
        for w in NS.windows(2) {
            print!(" {} -> {} |", w[0], w[1]);
        }
        println!();
        println!("|---|{}", "---|".repeat(NS.len() - 1));
        for method in METHODS {
            print!("| {} |", method.name());
            for w in NS.windows(2) {
                print!(
                    " {} |",
                    ratio2(get(precision, method, w[1]), get(precision, method, w[0]))
                );
            }
            println!();
        }
    }
}

/// Best time (ns) of one call of every method at every n, measured
/// interleaved: round after round, each method once, keeping each method's
/// fastest call. Load from other processes then hits all methods alike, and
/// a single call is short enough to run unpreempted in some round, where
/// criterion's consecutive benchmarks can see different load.
fn interleaved<T: Real>(data: &[(usize, Vec<[i16; 3]>)]) -> BTreeMap<(&'static str, usize), f64> {
    let mut best = BTreeMap::new();
    for (n, samples) in data {
        let n = *n;
        let rounds = match n {
            0..=100 => 500,
            101..=1_000 => 200,
            1_001..=10_000 => 60,
            _ => 15,
        };
        for _ in 0..rounds {
            for method in METHODS {
                let cfg = config(method);
                let t0 = Instant::now();
                let _ = black_box(calibrate::<T, _>(black_box(samples), black_box(&cfg)));
                let ns = t0.elapsed().as_nanos() as f64;
                let e = best.entry((method.name(), n)).or_insert(f64::INFINITY);
                if ns < *e {
                    *e = ns;
                }
            }
        }
    }
    best
}

/// The interleaved check: best times, same-run ratios, growth, and the
/// host budget.
fn interleaved_summary(data: &[(usize, Vec<[i16; 3]>)]) {
    println!(
        "\n==== interleaved check (fastest single call of 15-500 rounds, methods alternating) ===="
    );
    for precision in ["f32", "f64"] {
        let best = if precision == "f32" {
            interleaved::<f32>(data)
        } else {
            interleaved::<f64>(data)
        };
        let get = |m: Method, n: usize| best.get(&(m.name(), n)).copied();
        println!("\n{precision}: best time per call; per sample");
        print!("| method |");
        for n in NS {
            print!(" n = {n} |");
        }
        println!();
        println!("|---|{}", "---|".repeat(NS.len()));
        for method in METHODS {
            print!("| {} |", method.name());
            for n in NS {
                match get(method, n) {
                    Some(ns) => print!(" {}; {:.1} ns |", human(ns), ns / n as f64),
                    None => print!(" - |"),
                }
            }
            println!();
        }
        println!("\n{precision}: ratios of the best times");
        ratio_table(get, ratio);
        println!("\n{precision}: growth of the best times, t(10 n) / t(n); 10 = linear");
        print!("| method |");
        for w in NS.windows(2) {
            print!(" {} -> {} |", w[0], w[1]);
        }
        println!();
        println!("|---|{}", "---|".repeat(NS.len() - 1));
        for method in METHODS {
            print!("| {} |", method.name());
            for w in NS.windows(2) {
                print!(" {} |", ratio(get(method, w[1]), get(method, w[0])));
            }
            println!();
        }
        println!();
        for n in NS {
            if let (Some(a), Some(l)) = (get(Method::Adc2, n), get(Method::Ls, n)) {
                println!(
                    "BUDGET host {precision} n={n} adc2/ls={:.2} (at most 2): {}",
                    a / l,
                    if a <= 2.0 * l { "met" } else { "MISSED" }
                );
            }
        }
    }
}

fn main() {
    let start = SystemTime::now();
    // `cargo bench -- --list` / `--test`: criterion's quick modes, no summary.
    let quick = std::env::args().any(|a| a == "--list" || a == "--test");
    let data: Vec<(usize, Vec<[i16; 3]>)> = NS.iter().map(|&n| (n, samples(n))).collect();
    let mut c = Criterion::default().configure_from_args();
    bench_precision::<f32>(&mut c, "f32", &data);
    bench_precision::<f64>(&mut c, "f64", &data);
    c.final_summary();
    if !quick {
        summary(start);
        interleaved_summary(&data);
    }
}
