//! The contamination study (design document section 14,
//! `host_tests::contamination`): for each configuration of [`configs`] and
//! each precision, every contamination kind at every fraction, the clean
//! runs and the degenerate inputs, both unit systems (i16 counts, f64 uT)
//! and both coverages (sphere, +-30 deg band), as markdown tables on
//! stdout.
//!
//! ```sh
//! cargo run --release -p host-tests --bin contamination-table -- [RUNS]
//! ```
//!
//! Options: `RUNS` or `--runs N` (runs per cell, default 64);
//! `--precision f32|f64|both` (default both); `--fractions 0.01,0.1` and
//! `--kinds spike,rail,...` (a subset of the grid); `--by-setting` (after
//! each pooled table, one per units x coverage); `--threads N` (default:
//! one per core; the results do not depend on it); `--write [FILE]`: also
//! put the tables into FILE (default the workspace's `docs/results.md`)
//! between `<!-- contamination:start -->` and `<!-- contamination:end -->`,
//! replacing what was there, or appended when the markers are missing.
//! Progress goes to stderr. Every run has its own fixed seed, so everything
//! but the timings is reproducible bit for bit.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::time::Instant;

use host_tests::contamination::{
    percent, render_setting_table, render_table, run_study, totals, Grid, Kind, Precision,
    BAND_DEG, FIELD_COUNTS, FIELD_UT, NOISE_REL, RATIO_FLOOR, SECTION, SIZES, WRONG_LIMIT,
};
use mag_cal_core::{calibrate, Config, Method};

/// The configurations of the tables, with their labels. A new one (e.g.
/// the robust configuration) is one more line.
fn configs() -> Vec<(&'static str, Config)> {
    let plain = Config {
        robust: false,
        ..Config::default()
    };
    vec![
        ("robust ADC2 (`Config::default()`)", Config::default()),
        (
            "robust iterated ADC2 (`Method::Adc2Iterated`)",
            Config {
                method: Method::Adc2Iterated,
                ..Config::default()
            },
        ),
        // LS alone is not judged by its lack of fit (its algebraic residual
        // is biased by region): its plain attempt is judged clean by the
        // tails of an artificial-data pass and by its lack of shape
        // (`CLEAN_SHAPE`), its fit error about the rows' mean radius.
        (
            "robust LS9 alone (`Method::Ls`)",
            Config {
                method: Method::Ls,
                ..Config::default()
            },
        ),
        ("plain ADC2 (`robust: false`)", plain),
        (
            "plain iterated ADC2 (`robust: false`)",
            Config {
                method: Method::Adc2Iterated,
                ..plain
            },
        ),
    ]
}

struct Options {
    runs: usize,
    precisions: Vec<Precision>,
    fractions: Option<Vec<f64>>,
    kinds: Option<Vec<Kind>>,
    threads: Option<usize>,
    by_setting: bool,
    write: Option<PathBuf>,
}

const USAGE: &str = "usage: contamination-table [RUNS] [--runs N] [--precision f32|f64|both] \
                     [--fractions F,F,..] [--kinds K,K,..] [--by-setting] [--threads N] \
                     [--write [FILE]]";

fn default_results() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .parent()
        .expect("host-tests lives in the workspace")
        .join("docs")
        .join("results.md")
}

fn options() -> Result<Options, String> {
    let mut o = Options {
        runs: 64,
        precisions: Precision::ALL.to_vec(),
        fractions: None,
        kinds: None,
        threads: None,
        by_setting: false,
        write: None,
    };
    let args: Vec<String> = std::env::args().skip(1).collect();
    let mut i = 0;
    let runs = |v: Option<&String>| {
        v.and_then(|v| v.parse().ok())
            .filter(|&n: &usize| n >= 1)
            .ok_or("the runs per cell must be a number >= 1")
    };
    while i < args.len() {
        let a = args[i].as_str();
        let value = args.get(i + 1);
        i += 1;
        match a {
            "--runs" => {
                o.runs = runs(value)?;
                i += 1;
            }
            "--precision" => {
                o.precisions = match value.map(String::as_str) {
                    Some("f32") => vec![Precision::F32],
                    Some("f64") => vec![Precision::F64],
                    Some("both") => Precision::ALL.to_vec(),
                    _ => return Err("--precision needs f32, f64 or both".into()),
                };
                i += 1;
            }
            "--fractions" => {
                let v = value.ok_or("--fractions needs a list")?;
                let f: Result<Vec<f64>, _> = v.split(',').map(str::parse).collect();
                o.fractions = Some(
                    f.ok()
                        .filter(|f| f.iter().all(|x| (0.0..=1.0).contains(x)))
                        .ok_or("--fractions needs numbers in [0, 1], e.g. 0.01,0.1")?,
                );
                i += 1;
            }
            "--kinds" => {
                let v = value.ok_or("--kinds needs a list")?;
                let k: Option<Vec<Kind>> = v.split(',').map(Kind::from_name).collect();
                let names: Vec<&str> = Kind::ALL.iter().map(|k| k.name()).collect();
                o.kinds = Some(k.ok_or(format!("--kinds takes {}", names.join(",")))?);
                i += 1;
            }
            "--threads" => {
                o.threads = Some(runs(value).map_err(|_| "--threads needs a number >= 1")?);
                i += 1;
            }
            "--write" => match value.filter(|v| !v.starts_with("--")) {
                Some(v) if v.parse::<usize>().is_err() => {
                    o.write = Some(PathBuf::from(v));
                    i += 1;
                }
                _ => o.write = Some(default_results()),
            },
            "--by-setting" => o.by_setting = true,
            "-h" | "--help" => return Err(USAGE.into()),
            other => match other.parse() {
                Ok(n) if n >= 1 => o.runs = n,
                _ => return Err(format!("unknown argument {other:?}\n{USAGE}")),
            },
        }
    }
    Ok(o)
}

fn main() -> ExitCode {
    let opts = match options() {
        Ok(o) => o,
        Err(e) => {
            eprintln!("{e}");
            return ExitCode::from(2);
        }
    };
    let mut grid = Grid::full(opts.runs);
    if let Some(f) = &opts.fractions {
        grid.fractions = f.clone();
    }
    if let Some(k) = &opts.kinds {
        grid.kinds = k.clone();
    }
    if let Some(t) = opts.threads {
        grid.threads = t;
    }
    let start = Instant::now();
    let mut tables = String::new();
    let mut summary = String::new();
    for (label, config) in configs() {
        for &p in &opts.precisions {
            eprintln!(
                "[{:6.1} s] {label}, {}: {} fits",
                start.elapsed().as_secs_f64(),
                p.name(),
                grid.fits()
            );
            let study = run_study(&config, p, &grid);
            let (runs, accepted, wrong) = totals(&study);
            let _ = writeln!(
                summary,
                "| {label} | {} | {runs} | {:.1} | {wrong} ({:.1} %) | {:.1} |",
                p.name(),
                100.0 * accepted as f64 / runs as f64,
                100.0 * wrong as f64 / runs as f64,
                study.seconds
            );
            tables.push_str(&render_table(&study, label));
            tables.push('\n');
            if opts.by_setting {
                for &u in &grid.units {
                    for &c in &grid.coverages {
                        tables.push_str(&render_setting_table(&study, label, u, c));
                        tables.push('\n');
                    }
                }
            }
        }
    }
    let elapsed = start.elapsed().as_secs_f64();
    eprintln!("[{elapsed:6.1} s] done");

    // The command as run, less the output option.
    let mut args: Vec<String> = std::env::args().skip(1).collect();
    if let Some(w) = args.iter().position(|a| a == "--write") {
        let with_file = args
            .get(w + 1)
            .is_some_and(|v| !v.starts_with("--") && v.parse::<usize>().is_err());
        args.drain(w..w + 1 + usize::from(with_file));
    }
    tables.push_str(&real_recordings());
    let doc = render(&grid, &args.join(" "), &summary, &tables, elapsed);
    print!("{doc}");
    if let Some(path) = &opts.write {
        let old = match std::fs::read_to_string(path) {
            Ok(s) => s,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => String::new(),
            Err(e) => {
                eprintln!("reading {}: {e}", path.display());
                return ExitCode::from(2);
            }
        };
        if let Err(e) = std::fs::write(path, host_tests::sections::splice(&old, SECTION, &doc)) {
            eprintln!("writing {}: {e}", path.display());
            return ExitCode::from(2);
        }
        eprintln!("wrote the section into {}", path.display());
    }
    ExitCode::SUCCESS
}

/// The columns `cols` of every row of a recording in which they are numbers
/// (other fields may be text, as in `imu_gnss_1252.csv`).
fn read_fields(name: &str, cols: [usize; 3]) -> Vec<[f64; 3]> {
    let path = host_tests::real::path(name);
    let text = std::fs::read_to_string(&path).unwrap_or_else(|e| {
        panic!(
            "cannot read {} ({e}): is ../shared beside the repo?",
            path.display()
        )
    });
    text.lines()
        .filter_map(|line| {
            let fields: Vec<&str> = line
                .split(|c: char| c == ',' || c.is_whitespace())
                .filter(|f| !f.is_empty())
                .collect();
            let get = |k: usize| fields.get(k)?.parse::<f64>().ok();
            Some([get(cols[0])?, get(cols[1])?, get(cols[2])?])
        })
        .collect()
}

/// The real recordings of `shared/data/real/` with plain ADC2 and the
/// robust ADC2 and iterated ADC2: what each leaves out, and its figures.
fn real_recordings() -> String {
    let files: [(&str, [usize; 3]); 5] = [
        ("icm20948_mag_300.csv", [0, 1, 2]),
        ("mag3_raw_541.csv", [0, 1, 2]),
        ("magcal_25598.txt", [0, 1, 2]),
        ("imu_gnss_1252.csv", [6, 7, 8]),
        ("planar_243.txt", [0, 1, 2]),
    ];
    let plain = Config {
        robust: false,
        ..Config::default()
    };
    let iterated = Config {
        method: Method::Adc2Iterated,
        ..Config::default()
    };
    let mut s = String::new();
    let _ = writeln!(
        s,
        "### Real recordings (`shared/data/real/`, f64)

Rows left out by each configuration, the fit error and lack of fit (both in units of \
the field), the radial RMS over the rows used, and the hard iron's distance from the plain \
fit's (in units of the field). Magneto 1.4 rejects 10 of the 300 rows of \
`icm20948_mag_300.csv` (2 sigma after its Li-Griffiths fit).

| recording | configuration | used | dropped (rule) | screened | rejected | fit error | lack of fit | radial RMS | robust passes | \\|b - b_plain\\| |
|---|---|---:|---|---:|---:|---:|---:|---:|---:|---:|"
    );
    for (name, cols) in files {
        let y = read_fields(name, cols);
        let base = calibrate::<f64, _>(&y, &plain).ok();
        for (label, cfg) in [
            ("plain ADC2", plain),
            ("robust ADC2", Config::default()),
            ("robust iterated ADC2", iterated),
        ] {
            match calibrate::<f64, _>(&y, &cfg) {
                Ok(fit) => {
                    let r = fit.report;
                    let d = r.drops;
                    let rules: Vec<String> = [
                        ("non_finite", d.non_finite),
                        ("overflow", d.overflow),
                        ("zero", d.zero),
                        ("rails", d.rails),
                        ("repeated", d.repeated),
                        ("clipped", d.clipped),
                    ]
                    .iter()
                    .filter(|(_, n)| *n > 0)
                    .map(|(k, n)| format!("{n} {k}"))
                    .collect();
                    let db = base.as_ref().map_or(f64::NAN, |b| {
                        (fit.calibration.hard_iron_vector() - b.calibration.hard_iron_vector())
                            .norm()
                            / b.calibration.field_strength()
                    });
                    let _ = writeln!(
                        s,
                        "| `{name}` | {label} | {} | {} | {} | {} | {:.4} | {:.4} | {:.4} | {} | {:.1e} |",
                        r.samples_used,
                        if rules.is_empty() { "0".to_string() } else { rules.join(", ") },
                        r.screened,
                        r.rejected,
                        r.quality.fit_error,
                        r.quality.lack_of_fit,
                        r.radial_rms,
                        r.robust_passes,
                        db
                    );
                }
                Err(e) => {
                    let _ = writeln!(s, "| `{name}` | {label} | refused: {e} | | | | | | | | |");
                }
            }
        }
    }
    s.push('\n');
    s
}

fn render(grid: &Grid, args: &str, summary: &str, tables: &str, elapsed: f64) -> String {
    let mut s = String::new();
    let fractions: Vec<String> = grid.fractions.iter().map(|&f| percent(f)).collect();
    let kinds: Vec<&str> = grid.kinds.iter().map(|k| k.name()).collect();
    let _ = writeln!(s, "## Contaminated and degenerate data\n");
    let _ = writeln!(
        s,
        "Written by `cargo run --release -p host-tests --bin contamination-table{}{args}` \
         (source: `host-tests/src/bin/contamination-table.rs` and \
         `host-tests/src/contamination.rs`; design document section 14). \
         {} runs a cell; {} worker threads; the whole binary took {elapsed:.0} s. \
         Every run has its own fixed seed: everything but the timings is reproducible.\n",
        if args.is_empty() { "" } else { " -- " },
        grid.runs,
        grid.threads
    );
    let _ = writeln!(
        s,
        "Data: clean runs `y = T h + b + e` in integer counts (`T = {FIELD_COUNTS} x` a random \
         distortion, field 415 counts, `b` up to 300 counts an axis, fed as `[i16; 3]`) and in \
         uT (`T = {FIELD_UT} x` a random distortion, field 52 uT, `b` up to 40 uT, fed as \
         `[f64; 3]`), noise {:.0} % of the field per axis, n = {} and {} in turn, directions \
         uniform on the sphere or on a +-{BAND_DEG} deg band, ordered along a path (a Hilbert \
         curve on the equal-area map) so that a contiguous stretch is a patch of directions. \
         Kinds: {}; fractions {} of the rows. Degenerate inputs (a stationary device, a filled \
         ball, a cube) must be refused.\n",
        100.0 * NOISE_REL,
        SIZES[0],
        SIZES[1],
        kinds.join(", "),
        fractions.join(", "),
    );
    let _ = writeln!(
        s,
        "Metrics: `e_M = |M_hat - M|_F / |M|_F` (`M = W^T W`), `e_b = |b_hat - b| / rho`. \
         The ratio of a run is its error over the error of the same configuration, precision \
         and sample type on the clean rows of the same run (denominator at least \
         {RATIO_FLOOR:e}); the medians are over the accepted runs. Silently wrong: accepted \
         with `e_M` or `e_b` above {WRONG_LIMIT} (every accepted degenerate input), in % of \
         the runs; in brackets the % of the runs that were silently wrong yet carried a \
         warning (any `Warning`). Refusals: the `Error` variant, and warnings of the accepted runs \
         (`Warning::name`), in % of the runs. A row of \
         a configuration's first table pools both unit systems and both coverages.\n"
    );
    let _ = writeln!(
        s,
        "| configuration | precision | contaminated and degenerate runs | accepted % | silently wrong | seconds |\n\
         |---|---|---|---|---|---|\n{summary}"
    );
    s.push_str(tables);
    s
}
