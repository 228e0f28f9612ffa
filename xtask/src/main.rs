//! Project automation, run as `cargo xtask <command>` (alias in
//! `.cargo/config.toml`).
//!
//! | command | what |
//! |---|---|
//! | `setup` | install what a fresh machine lacks: the thumb, RISC-V and wasm targets (rustup), `qemu-system-arm`, `gcc-arm-none-eabi`, `libnewlib-arm-none-eabi`, `chromium`, and `nodejs` with `npm` when npm is missing (apt), `defmt-print`, `flip-link` and `cbindgen` (cargo install) |
//! | `qemu` | setup, then build and run the firmware on the emulated Cortex-M4F (the main job) |
//! | `qemu-faults` | setup, then the same run with sensor faults injected (`--features qemu,faults`) |
//! | `test` | setup, then every test: host tests, the core's examples, the packaged core's own tests (extracted from `cargo package`), the on-target tests under QEMU, the board build, the QEMU run, the fault run, the page's browser tests (`web-test`) and the no-panic link proof (`no-panic-check/check.sh`) |
//! | `header` | regenerate the C header `mag-cal-ffi/include/mag_cal.h` with cbindgen |
//! | `c` | setup, then the C API's tests: the header is current, the C program agrees with `magcal fit` on the host (gcc) and on the emulated Cortex-M4F (arm-none-eabi-gcc, QEMU), the README's C example compiles as it stands and runs, and the README's C footprint figures hold (`c-footprint`) |
//! | `c-footprint` | setup, then flash and stack of one `magcal_calibrate_i16` call on the Cortex-M4F, with the library the README's target command builds (`FOOTPRINT-C` lines), checked against the README's figures (within 5 %) |
//! | `package` | `cargo package -p mag-cal-core`, then the packaged crate's own tests in an extracted copy |
//! | `ablation` | the robust path's mechanisms left out one at a time, then the set the rule prunes: the contamination study's robust ADC2 f32 cells, the flash of LS9 + ADC2 and the bench's instructions for each (needs what `bench` needs: run `setup` once); see `docs/robustness.md`, "Ablation" |
//! | `bench` | setup, then the benchmarks under QEMU (`firmware-example/bench.sh`): `BENCH` instruction counts on the Cortex-M4F and `FOOTPRINT` lines (Cortex-M4F, and LS9 + ADC2 on the Cortex-M0+), then `c-footprint`; `--verify` also checks the counts against QEMU's exec log, `--host` also runs the criterion benchmarks (`cargo bench -p benches`); see `docs/benchmarks.md` |
//! | `web` | setup, then build the calibration page (`mag-cal-web`: the wasm, `npm ci`, the page assembled in `target/web`) and serve it on `http://127.0.0.1:8080/` (or the port given) |
//! | `web-test` | setup, then build the page and run its browser tests (`mag-cal-web/tests`, Playwright driving Debian's `chromium`) |
//!
//! Each step prints what it runs; the first failing step ends the run with
//! its exit status.

use std::path::{Path, PathBuf};
use std::process::{exit, Command};

mod ablation;

/// `defmt-print` version installed when missing (matches the `defmt` 1.0
/// wire format the firmware emits).
const DEFMT_PRINT_VERSION: &str = "1.2.0";

/// `flip-link` version installed when missing: the firmware's linker
/// (`firmware-example/.cargo/config.toml`), which puts the stack below the
/// static data so that an overflow faults instead of corrupting them.
const FLIP_LINK_VERSION: &str = "0.1.12";

/// `cbindgen` version that generates the C header (a newer one may format
/// it differently: the header check compares its output byte for byte).
const CBINDGEN_VERSION: &str = "0.29.4";

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let result = match args.first().map(String::as_str) {
        Some("setup") => setup(),
        Some("qemu") => setup().and_then(|()| qemu_demo()),
        Some("qemu-faults") => setup().and_then(|()| qemu_faults()),
        Some("test") => setup().and_then(|()| test_all()),
        Some("package") => package_check(),
        Some("header") => header(true),
        Some("c") => setup().and_then(|()| c_checks()),
        Some("c-footprint") => setup().and_then(|()| c_footprint_checked()),
        Some("bench") => setup().and_then(|()| bench(&args[1..])),
        Some("ablation") => ablation::ablation(&args[1..]),
        Some("web") => setup().and_then(|()| web(&args[1..])),
        Some("web-test") => setup().and_then(|()| web_tests()),
        _ => {
            eprintln!("usage: cargo xtask <setup|qemu|qemu-faults|test|package|header|c|c-footprint|bench [--verify] [--host]|ablation [--runs N] [--set A,B] [--no-firmware] [--reuse] [NAMES]|web [PORT]|web-test>");
            exit(2);
        }
    };
    if let Err(e) = result {
        eprintln!("xtask: {e}");
        exit(1);
    }
}

fn root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .parent()
        .expect("xtask lives in the workspace")
        .to_path_buf()
}

fn firmware_dir() -> PathBuf {
    root().join("firmware-example")
}

/// Runs a command in `dir`, failing with its description on a non-zero exit.
fn run(dir: &Path, program: &str, args: &[&str]) -> Result<(), String> {
    run_with(dir, program, args, &[])
}

/// [`run`] with environment variables set for the command.
fn run_with(dir: &Path, program: &str, args: &[&str], envs: &[(&str, &str)]) -> Result<(), String> {
    println!("\n==> ({}) {program} {}", dir.display(), args.join(" "));
    let status = Command::new(program)
        .args(args)
        .current_dir(dir)
        // The firmware is a workspace of its own: do not leak this cargo's
        // per-invocation settings into it.
        .env_remove("CARGO_TARGET_DIR")
        .env_remove("CARGO_BUILD_TARGET")
        .envs(envs.iter().copied())
        .status()
        .map_err(|e| format!("cannot start {program}: {e}"))?;
    if status.success() {
        Ok(())
    } else {
        Err(format!("`{program} {}` failed ({status})", args.join(" ")))
    }
}

fn on_path(program: &str) -> bool {
    Command::new("sh")
        .args(["-c", &format!("command -v {program} >/dev/null 2>&1")])
        .status()
        .is_ok_and(|s| s.success())
}

fn is_root() -> bool {
    Command::new("id")
        .arg("-u")
        .output()
        .is_ok_and(|o| o.stdout.trim_ascii() == b"0")
}

/// Installs what is missing; idempotent and quiet when nothing is.
fn setup() -> Result<(), String> {
    let root = root();
    // Reads rust-toolchain.toml: the pinned channel, the thumb, RISC-V and
    // wasm targets, clippy and rustfmt.
    run(&root, "rustup", &["toolchain", "install"])?;
    // A toolchain of that channel installed earlier without the target
    // (seen: `toolchain install` then leaves it out); a no-op when present.
    run(
        &root,
        "rustup",
        &[
            "target",
            "add",
            "thumbv7em-none-eabihf",
            "thumbv6m-none-eabi",
            "riscv32imc-unknown-none-elf",
            "wasm32-unknown-unknown",
        ],
    )?;
    // Debian packages: QEMU's ARM system emulator, and the Arm GNU
    // toolchain with newlib for the C API's Cortex-M4F build.
    let mut packages = Vec::new();
    if !on_path("qemu-system-arm") {
        packages.push("qemu-system-arm");
    }
    if !on_path("arm-none-eabi-gcc") {
        packages.extend(["gcc-arm-none-eabi", "libnewlib-arm-none-eabi"]);
    }
    // The page's browser tests: Debian's Chromium (never a downloaded
    // browser), and Node.js with npm for playwright-core and three.js.
    if !Path::new(CHROMIUM).exists() {
        packages.push("chromium");
    }
    if !on_path("npm") {
        packages.extend(["nodejs", "npm"]);
    }
    if !packages.is_empty() {
        if !on_path("apt-get") {
            return Err(format!(
                "{} missing and apt-get is not available: install them",
                packages.join(", ")
            ));
        }
        // No prompts: CI has no standard input. `sudo` drops the
        // environment, so the frontend is passed as its argument.
        let prefix: &[&str] = if is_root() {
            &["env", "DEBIAN_FRONTEND=noninteractive"]
        } else {
            &["sudo", "DEBIAN_FRONTEND=noninteractive"]
        };
        let apt = |args: &[&str]| {
            let mut full: Vec<&str> = prefix.to_vec();
            full.push("apt-get");
            full.extend_from_slice(args);
            run(&root, full[0], &full[1..])
        };
        apt(&["update", "-qq"])?;
        let mut install = vec!["install", "-y", "-qq"];
        install.extend(&packages);
        apt(&install)?;
    }
    for (tool, version) in [
        ("defmt-print", DEFMT_PRINT_VERSION),
        ("flip-link", FLIP_LINK_VERSION),
        ("cbindgen", CBINDGEN_VERSION),
    ] {
        if !on_path(tool) {
            run(
                &root,
                "cargo",
                &["install", tool, "--locked", "--version", version],
            )?;
        }
    }
    Ok(())
}

/// Builds and runs one firmware binary on QEMU (its runner ends with the
/// firmware's semihosting exit status).
fn run_on_qemu(bin: &str) -> Result<(), String> {
    run_on_qemu_with(bin, "qemu")
}

/// [`run_on_qemu`] with the given feature list (which must include `qemu`).
fn run_on_qemu_with(bin: &str, features: &str) -> Result<(), String> {
    run(
        &firmware_dir(),
        "cargo",
        &[
            "run",
            "--release",
            "--locked",
            "--no-default-features",
            "--features",
            features,
            "--bin",
            bin,
        ],
    )
}

/// The main job: the firmware on the emulated board, against the simulated
/// sensor; exits non-zero when the calibration misses its bounds.
fn qemu_demo() -> Result<(), String> {
    run_on_qemu("firmware-example")
}

/// The firmware against a faulty simulated sensor (NACK bursts, stuck
/// output, saturation, a passing magnet): ends with the line `faults: ..`
/// and the `calibrated: ..` line, and exits non-zero when a fault class was
/// not seen or not handled, a faulty sample was used, or the calibration
/// misses the clean run's bounds.
fn qemu_faults() -> Result<(), String> {
    run_on_qemu_with("firmware-example", "qemu,faults")
}

/// Every test: host, on-target under QEMU, the board build, the QEMU demo,
/// the fault run.
fn test_all() -> Result<(), String> {
    run(&root(), "cargo", &["test", "--workspace", "--locked"])?;
    // A build with one optional method: the others are refused by name.
    run(
        &root(),
        "cargo",
        &[
            "test",
            "--locked",
            "-p",
            "mag-cal-core",
            "--no-default-features",
            "--features",
            "adc1",
            "--test",
            "fit",
            "--",
            "a_method_left_out",
        ],
    )?;
    examples()?;
    package_check()?;
    c_checks()?;
    run_on_qemu("ontarget")?;
    // The board example to copy, on the emulated board.
    run_on_qemu("compass")?;
    // Calibration in the background from ordinary use, with a hard-iron
    // jump (exits non-zero out of its bounds).
    run_on_qemu("background")?;
    let fw = firmware_dir();
    run(&fw, "cargo", &["build", "--release", "--locked"])?;
    qemu_demo()?;
    qemu_faults()?;
    // The calibration page in headless Chromium.
    web_tests()?;
    // The link proof that no panic path is reachable from the core's API
    // (docs/robustness.md).
    let proof = root().join("no-panic-check").join("check.sh");
    let proof = proof.to_str().ok_or("check.sh: path is not UTF-8")?;
    run(&root(), "bash", &[proof, "--no-list"])
}

/// Debian's Chromium, which the page's tests drive.
const CHROMIUM: &str = "/usr/bin/chromium";

/// Builds the page into `target/web`: the wasm (profile `web`), three.js
/// from `npm ci`, and the page's own files. Returns that folder.
fn web_build() -> Result<PathBuf, String> {
    let root = root();
    let web = root.join("mag-cal-web");
    run(&web, "npm", &["ci", "--no-audit", "--no-fund"])?;
    run(
        &root,
        "cargo",
        &[
            "build",
            "-p",
            "mag-cal-web",
            "--target",
            "wasm32-unknown-unknown",
            "--profile",
            "web",
            "--locked",
        ],
    )?;
    let out = root.join("target").join("web");
    let _ = std::fs::remove_dir_all(&out);
    let three = web.join("node_modules").join("three");
    let copies = [
        (
            root.join("target/wasm32-unknown-unknown/web/mag_cal_web.wasm"),
            out.join("mag_cal_web.wasm"),
        ),
        (
            three.join("build/three.module.js"),
            out.join("vendor/three.module.js"),
        ),
        (
            three.join("build/three.core.js"),
            out.join("vendor/three.core.js"),
        ),
        (
            three.join("examples/jsm/controls/OrbitControls.js"),
            out.join("vendor/addons/controls/OrbitControls.js"),
        ),
        (three.join("LICENSE"), out.join("vendor/THREE-LICENSE")),
    ];
    let www = std::fs::read_dir(web.join("www")).map_err(|e| format!("mag-cal-web/www: {e}"))?;
    let pages = www
        .filter_map(Result::ok)
        .map(|e| (e.path(), out.join(e.file_name())));
    for (from, to) in copies.into_iter().chain(pages) {
        if let Some(dir) = to.parent() {
            std::fs::create_dir_all(dir).map_err(|e| format!("{}: {e}", dir.display()))?;
        }
        std::fs::copy(&from, &to).map_err(|e| format!("{}: {e}", from.display()))?;
    }
    println!("page built in {}", out.display());
    Ok(out)
}

/// Builds the page and serves it (until Ctrl-C).
fn web(args: &[String]) -> Result<(), String> {
    let out = web_build()?;
    let port = args.first().map_or("8080", String::as_str);
    let serve = root().join("mag-cal-web").join("serve.mjs");
    run(&root(), "node", &[path_str(&serve)?, path_str(&out)?, port])
}

/// The page's browser tests: headless Debian Chromium driven by
/// playwright-core against the page served on localhost, with `magcal` as
/// the reference for the numbers.
fn web_tests() -> Result<(), String> {
    let out = web_build()?;
    let root = root();
    run(&root, "cargo", &["build", "-p", "mag-cal-cli", "--locked"])?;
    let magcal = root.join("target").join("debug").join("magcal");
    let shared = root.join("..").join("shared").join("data").join("real");
    let shots = root.join("target").join("web-screenshots");
    run_with(
        &root.join("mag-cal-web"),
        "node",
        &["--test", "--test-concurrency=1", "tests/"],
        &[
            ("WEB_ROOT", path_str(&out)?),
            ("MAGCAL", path_str(&magcal)?),
            ("REAL_DATA", path_str(&shared)?),
            ("CHROMIUM", CHROMIUM),
            ("SCREENSHOTS", path_str(&shots)?),
        ],
    )
}

/// The core's examples, as a user runs them (the log is a shared real
/// recording).
fn examples() -> Result<(), String> {
    let root = root();
    let log = root.join("../shared/data/real/icm20948_mag_300.csv");
    let example = |name: &str, args: &[&str]| {
        let mut all = vec!["run", "--locked", "-p", "mag-cal-core", "--example", name];
        if !args.is_empty() {
            all.push("--");
            all.extend_from_slice(args);
        }
        run(&root, "cargo", &all)
    };
    example("calibrate_log", &[path_str(&log)?])?;
    example("heading", &[])?;
    example("persist", &[])
}

/// The C header of `mag-cal-ffi`, generated by cbindgen: written to
/// `mag-cal-ffi/include/mag_cal.h` (`write`), or compared with it (a stale
/// header fails).
fn header(write: bool) -> Result<(), String> {
    let root = root();
    let ffi = root.join("mag-cal-ffi");
    let committed = ffi.join("include").join("mag_cal.h");
    let generated = root.join("target").join("c").join("mag_cal.h");
    std::fs::create_dir_all(root.join("target").join("c")).map_err(|e| e.to_string())?;
    let out = if write { &committed } else { &generated };
    run(
        &ffi,
        "cbindgen",
        &[
            "--quiet",
            "--config",
            "cbindgen.toml",
            "--crate",
            "mag-cal-ffi",
            "--output",
            path_str(out)?,
        ],
    )?;
    if write {
        return Ok(());
    }
    let read = |p: &Path| std::fs::read(p).map_err(|e| format!("{}: {e}", p.display()));
    if read(&committed)? != read(&generated)? {
        return Err(format!(
            "{} is stale: regenerate it with `cargo xtask header` (compare {})",
            committed.display(),
            generated.display()
        ));
    }
    println!("the C header is current");
    Ok(())
}

/// Runs a command and returns its standard output.
fn output(dir: &Path, program: &str, args: &[&str]) -> Result<Vec<u8>, String> {
    println!("\n==> ({}) {program} {}", dir.display(), args.join(" "));
    let out = Command::new(program)
        .args(args)
        .current_dir(dir)
        .output()
        .map_err(|e| format!("cannot start {program}: {e}"))?;
    if out.status.success() {
        Ok(out.stdout)
    } else {
        Err(format!(
            "`{program} {}` failed ({}): {}",
            args.join(" "),
            out.status,
            String::from_utf8_lossy(&out.stderr)
        ))
    }
}

/// The C API: the header is current; `mag-cal-ffi/c/calibrate.c` built
/// with gcc against the host static library and with arm-none-eabi-gcc
/// against the Cortex-M4F one (run under QEMU, semihosting) calibrates a
/// shared recording and agrees with `magcal fit --format json` on it, in
/// `f64` and `f32` (the program checks and exits non-zero otherwise).
fn c_tests() -> Result<(), String> {
    header(false)?;
    let root = root();
    let c_dir = root.join("target").join("c");
    let log = root.join("../shared/data/real/icm20948_mag_300.csv");
    let log = path_str(&log)?;
    run(
        &root,
        "cargo",
        &["build", "--release", "--locked", "-p", "mag-cal-cli"],
    )?;
    // The C libraries (the crate is an rlib by its manifest).
    ffi_libraries("staticlib,cdylib", &["--release"])?;
    let magcal = root.join("target/release/magcal");
    for precision in ["f64", "f32"] {
        let json = output(
            &root,
            path_str(&magcal)?,
            &["fit", log, "--format", "json", "--precision", precision],
        )?;
        let file = c_dir.join(format!("expected-{precision}.json"));
        std::fs::write(&file, json).map_err(|e| format!("{}: {e}", file.display()))?;
    }
    let include = format!("-I{}", path_str(&root.join("mag-cal-ffi/include"))?);
    let source = root.join("mag-cal-ffi/c/calibrate.c");
    let warnings = ["-std=c99", "-Wall", "-Wextra", "-Werror", "-O2"];

    // Host: gcc, the static library and the libraries Rust's std needs
    // (`cargo rustc -- --print native-static-libs`).
    let host_bin = c_dir.join("calibrate");
    let mut args: Vec<&str> = warnings.to_vec();
    let host_lib = root.join("target/release/libmag_cal_ffi.a");
    args.extend([include.as_str(), path_str(&source)?, path_str(&host_lib)?]);
    args.extend([
        "-lgcc_s",
        "-lutil",
        "-lrt",
        "-lpthread",
        "-lm",
        "-ldl",
        "-lc",
    ]);
    args.extend(["-o", path_str(&host_bin)?]);
    run(&root, "gcc", &args)?;
    for precision in ["f64", "f32"] {
        let expected = c_dir.join(format!("expected-{precision}.json"));
        run(
            &root,
            path_str(&host_bin)?,
            &[log, precision, path_str(&expected)?],
        )?;
    }

    // Cortex-M4F: the static library for thumbv7em, newlib with
    // semihosting (the log and the JSON are read from the host), QEMU.
    ffi_libraries(
        "staticlib",
        &["--release", "--target", "thumbv7em-none-eabihf"],
    )?;
    let m4_lib = root.join("target/thumbv7em-none-eabihf/release/libmag_cal_ffi.a");
    let m4_bin = c_dir.join("calibrate-m4.elf");
    let cortex = root.join("mag-cal-ffi/c/cortex-m");
    let mut args: Vec<&str> = warnings.to_vec();
    args.extend(M4_CFLAGS);
    let (script, startup) = (cortex.join("link.ld"), cortex.join("startup.c"));
    args.extend([
        "-T",
        path_str(&script)?,
        include.as_str(),
        path_str(&startup)?,
    ]);
    args.extend([
        path_str(&source)?,
        path_str(&m4_lib)?,
        "-lm",
        "-o",
        path_str(&m4_bin)?,
    ]);
    run(&root, "arm-none-eabi-gcc", &args)?;
    for precision in ["f32", "f64"] {
        let expected = c_dir.join(format!("expected-{precision}.json"));
        let semihosting = format!(
            "enable=on,target=native,arg=calibrate,arg={log},arg={precision},arg={}",
            path_str(&expected)?
        );
        run(
            &root,
            "timeout",
            &qemu_args("300", &semihosting, path_str(&m4_bin)?),
        )?;
    }
    Ok(())
}

/// arm-none-eabi-gcc's options for the C programs on the Cortex-M4F: the
/// core and its FPU, newlib with semihosting, unused sections dropped.
const M4_CFLAGS: [&str; 7] = [
    "-mcpu=cortex-m4",
    "-mthumb",
    "-mfloat-abi=hard",
    "-mfpu=fpv4-sp-d16",
    "--specs=rdimon.specs",
    "-Wl,--gc-sections",
    "-Wl,--no-warn-execstack",
];

/// The C libraries of `mag-cal-ffi` (an rlib by its manifest):
/// `cargo rustc --locked -p mag-cal-ffi --crate-type TYPES` with `args`
/// (profile, target, features).
fn ffi_libraries(types: &str, args: &[&str]) -> Result<(), String> {
    let mut cargo = vec![
        "rustc",
        "--locked",
        "-p",
        "mag-cal-ffi",
        "--crate-type",
        types,
    ];
    cargo.extend(args);
    run(&root(), "cargo", &cargo)
}

/// The arguments of `timeout` that run `elf` on QEMU's mps2-an386 (a
/// Cortex-M4F) for at most `seconds`, with `semihosting` as its
/// `-semihosting-config` (the program's arguments, files and exit status).
fn qemu_args<'a>(seconds: &'a str, semihosting: &'a str, elf: &'a str) -> [&'a str; 15] {
    [
        seconds,
        "qemu-system-arm",
        "-cpu",
        "cortex-m4",
        "-machine",
        "mps2-an386",
        "-nographic",
        "-monitor",
        "none",
        "-serial",
        "none",
        "-semihosting-config",
        semihosting,
        "-kernel",
        elf,
    ]
}

/// Every check of the C API (`cargo xtask c`): [`c_tests`], the README's
/// example ([`readme_c_example`]) and its footprint figures
/// ([`c_footprint_checked`]).
fn c_checks() -> Result<(), String> {
    c_tests()?;
    readme_c_example()?;
    c_footprint_checked()
}

/// The README's "From C" section: from its heading to the next heading
/// (outside code blocks).
fn readme_from_c() -> Result<String, String> {
    let path = root().join("README.md");
    let text = std::fs::read_to_string(&path).map_err(|e| format!("{}: {e}", path.display()))?;
    let mut section = String::new();
    let (mut inside, mut fenced) = (false, false);
    for line in text.lines() {
        if line.starts_with("```") {
            fenced = !fenced;
        }
        if !fenced && line.starts_with('#') {
            if inside {
                break;
            }
            inside = line == "### From C";
        }
        if inside {
            section.push_str(line);
            section.push('\n');
        }
    }
    if section.is_empty() {
        return Err("README.md: no `### From C` section".into());
    }
    Ok(section)
}

/// The contents of the code blocks fenced as ```` ```lang ```` in `text`.
fn fenced_blocks(text: &str, lang: &str) -> Vec<String> {
    let mut blocks = Vec::new();
    // The block being read: whether it is one of `lang`, and its lines.
    let mut open: Option<(bool, String)> = None;
    for line in text.lines() {
        match (open.take(), line.strip_prefix("```")) {
            (None, Some(info)) => open = Some((info.trim() == lang, String::new())),
            (Some((wanted, body)), Some(_)) => {
                if wanted {
                    blocks.push(body);
                }
            }
            (Some((wanted, mut body)), None) => {
                body.push_str(line);
                body.push('\n');
                open = Some((wanted, body));
            }
            (None, None) => {}
        }
    }
    blocks
}

/// A build command of the README's "From C" section: `cargo` and its
/// arguments, and the library it gives (the `# -> PATH` line after it).
struct LibraryCommand {
    args: Vec<String>,
    library: PathBuf,
}

/// The README's two library commands (its ```` ```sh ```` block in "From
/// C"): for the target (the one with `--target`) and for the host.
fn readme_library_commands() -> Result<(LibraryCommand, LibraryCommand), String> {
    let section = readme_from_c()?;
    let blocks = fenced_blocks(&section, "sh");
    let [block] = blocks.as_slice() else {
        return Err(format!(
            "README.md, From C: {} sh blocks, not one",
            blocks.len()
        ));
    };
    let mut commands = Vec::new();
    let mut lines = block.lines().map(str::trim).peekable();
    while let Some(line) = lines.next() {
        let Some(rest) = line.strip_prefix("cargo ") else {
            continue;
        };
        let library = lines
            .next_if(|l| l.starts_with("# -> "))
            .map(|l| root().join(&l["# -> ".len()..]))
            .ok_or_else(|| format!("README.md, From C: no `# -> LIBRARY` line after `{line}`"))?;
        let args = rest.split_whitespace().map(str::to_owned).collect();
        commands.push(LibraryCommand { args, library });
    }
    let found = commands.len();
    let (target, host): (Vec<_>, Vec<_>) = commands
        .into_iter()
        .partition(|c| c.args.iter().any(|a| a == "--target"));
    match (<[_; 1]>::try_from(target), <[_; 1]>::try_from(host)) {
        (Ok([target]), Ok([host])) => Ok((target, host)),
        _ => Err(format!(
            "README.md, From C: the sh block needs two `cargo` commands, one with `--target` (the target) and one without (the host); found {found}"
        )),
    }
}

/// Runs a README library command (with `--locked` and `extra` arguments
/// added) and returns the library it gives.
fn build_readme_library(command: &LibraryCommand, extra: &[&str]) -> Result<PathBuf, String> {
    let mut args: Vec<&str> = command.args.iter().map(String::as_str).collect();
    args.push("--locked");
    args.extend(extra);
    run(&root(), "cargo", &args)?;
    if !command.library.is_file() {
        return Err(format!(
            "the README's `cargo {}` gave no {}",
            command.args.join(" "),
            command.library.display()
        ));
    }
    Ok(command.library.clone())
}

/// The README's C example, as it stands (its one ```` ```c ```` block in
/// "From C"): compiled with `gcc -std=c99 -Wall -Wextra -Werror -pedantic
/// -c`, linked with the host library of the README's host command and the
/// simulated driver `mag-cal-ffi/c/readme_sensor.c`, and run: it must
/// calibrate and print the heading of its last reading within 1 deg of the
/// true one (which the driver prints at exit).
fn readme_c_example() -> Result<(), String> {
    let root = root();
    let c_dir = root.join("target").join("c");
    std::fs::create_dir_all(&c_dir).map_err(|e| e.to_string())?;
    let blocks = fenced_blocks(&readme_from_c()?, "c");
    let [example] = blocks.as_slice() else {
        return Err(format!(
            "README.md, From C: {} c blocks, not one",
            blocks.len()
        ));
    };
    let source = c_dir.join("readme_example.c");
    std::fs::write(&source, example).map_err(|e| format!("{}: {e}", source.display()))?;
    let include = format!("-I{}", path_str(&root.join("mag-cal-ffi/include"))?);
    let object = c_dir.join("readme_example.o");
    let strict = ["-std=c99", "-Wall", "-Wextra", "-Werror", "-pedantic"];
    let mut args = strict.to_vec();
    args.extend([
        include.as_str(),
        "-c",
        path_str(&source)?,
        "-o",
        path_str(&object)?,
    ]);
    run(&root, "gcc", &args)?;

    let (_, host) = readme_library_commands()?;
    let library = build_readme_library(&host, &[])?;
    let sensor = root.join("mag-cal-ffi/c/readme_sensor.c");
    let program = c_dir.join("readme_example");
    let mut args = strict.to_vec();
    args.extend([
        "-O2",
        path_str(&object)?,
        path_str(&sensor)?,
        path_str(&library)?,
        "-lm",
        "-Wl,--gc-sections",
        "-o",
        path_str(&program)?,
    ]);
    run(&root, "gcc", &args)?;
    let out = output(&root, "timeout", &["60", path_str(&program)?])?;
    let out = String::from_utf8_lossy(&out);
    print!("{out}");
    let degrees = |line: &str| -> Option<f64> {
        let (_, rest) = line.rsplit_once("heading ")?;
        rest.strip_suffix(" deg")?.trim().parse().ok()
    };
    let truth = out.lines().find_map(|l| degrees(l.strip_prefix("true ")?));
    let shown = out
        .lines()
        .filter(|l| !l.starts_with("true "))
        .find_map(degrees);
    let (Some(truth), Some(shown)) = (truth, shown) else {
        return Err(format!("the README's C example printed no heading: {out}"));
    };
    let error = (shown - truth + 540.0).rem_euclid(360.0) - 180.0;
    if error.abs() > 1.0 {
        return Err(format!(
            "the README's C example: heading {shown} deg, true {truth} deg ({error:+.1} deg)"
        ));
    }
    println!("the README's C example: heading {shown} deg, true {truth} deg ({error:+.1} deg)");
    Ok(())
}

/// Footprint of the C API on the Cortex-M4F, of the library the README's
/// target command builds (`mag-cal-ffi/c/cortex-m/footprint.c`): flash of
/// the program with one `magcal_calibrate_i16` call over the same program
/// without it (Berkeley `text`), and the stack high-water mark of the call
/// (n = 1000, `float`) over the baseline's, for the library with every
/// method (the README's command) and with LS9 + ADC2 alone (the same
/// command with `--no-default-features --features panic-handler`).
/// Prints `FOOTPRINT-C <build> flash=<bytes> stack=<bytes>` and returns
/// the figures of `all-methods`, then `ls9+adc2`.
fn c_footprint() -> Result<[Footprint; 2], String> {
    let root = root();
    let c_dir = root.join("target").join("c");
    std::fs::create_dir_all(&c_dir).map_err(|e| e.to_string())?;
    let (target, _) = readme_library_commands()?;
    let cortex = root.join("mag-cal-ffi/c/cortex-m");
    let include = format!("-I{}", path_str(&root.join("mag-cal-ffi/include"))?);
    let (script, startup, source) = (
        cortex.join("link.ld"),
        cortex.join("startup.c"),
        cortex.join("footprint.c"),
    );
    // The program with (or without, `baseline`) the call, linked against
    // `lib`: its flash and stack.
    let measure = |name: &str, lib: &Path, baseline: bool| -> Result<Footprint, String> {
        let elf = c_dir.join(format!("footprint-{name}.elf"));
        let mut args = vec![
            "-std=c99",
            "-Wall",
            "-Wextra",
            "-Werror",
            "-Os",
            "-ffunction-sections",
            "-fdata-sections",
        ];
        args.extend(M4_CFLAGS);
        args.extend([
            "-T",
            path_str(&script)?,
            include.as_str(),
            path_str(&startup)?,
            path_str(&source)?,
            path_str(lib)?,
            "-lm",
            "-o",
            path_str(&elf)?,
        ]);
        if baseline {
            args.push("-DBASELINE");
        }
        run(&root, "arm-none-eabi-gcc", &args)?;
        // Berkeley `text`: code and read-only data (this link script puts
        // .rodata into .text).
        let size = output(&root, "arm-none-eabi-size", &[path_str(&elf)?])?;
        let size = String::from_utf8_lossy(&size);
        let flash: u64 = size
            .lines()
            .nth(1)
            .and_then(|l| l.split_whitespace().next())
            .and_then(|t| t.parse().ok())
            .ok_or("arm-none-eabi-size: no text column")?;
        let log = output(
            &root,
            "timeout",
            &qemu_args("120", "enable=on,target=native", path_str(&elf)?),
        )?;
        let log = String::from_utf8_lossy(&log);
        let stack: u64 = log
            .split_whitespace()
            .find_map(|w| w.strip_prefix("stack="))
            .and_then(|v| v.parse().ok())
            .ok_or_else(|| format!("footprint.c printed no stack figure: {log}"))?;
        Ok(Footprint { flash, stack })
    };
    // LS9 + ADC2 first, so that the library left in place is the one the
    // README's command gives.
    let lib = build_readme_library(
        &target,
        &["--no-default-features", "--features", "panic-handler"],
    )?;
    let ls9 = measure("ls9+adc2", &lib, false)?;
    let lib = build_readme_library(&target, &[])?;
    let base = measure("baseline", &lib, true)?;
    let every = measure("all-methods", &lib, false)?;
    let over = |f: Footprint| Footprint {
        flash: f.flash.saturating_sub(base.flash),
        stack: f.stack.saturating_sub(base.stack),
    };
    let figures = [over(every), over(ls9)];
    for (name, f) in ["all-methods", "ls9+adc2"].iter().zip(&figures) {
        println!("FOOTPRINT-C {name} flash={} stack={}", f.flash, f.stack);
    }
    Ok(figures)
}

/// Flash and stack of one `magcal_calibrate_i16` call, bytes.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Footprint {
    flash: u64,
    stack: u64,
}

/// The README's footprint figures (its "From C" section): the first four
/// `N B of flash` / `N B of stack` (digits grouped by spaces), in this
/// order: flash and stack of the default build, then of LS9 + ADC2 alone.
fn readme_footprint() -> Result<[Footprint; 2], String> {
    footprint_figures(&readme_from_c()?)
}

/// [`readme_footprint`] of the text `section`.
fn footprint_figures(section: &str) -> Result<[Footprint; 2], String> {
    let text = section.split_whitespace().collect::<Vec<_>>().join(" ");
    let mut figures = Vec::new();
    for (at, _) in text.match_indices(" B of ") {
        let rest = &text[at + " B of ".len()..];
        let kind = &rest[..rest
            .find(|c: char| !c.is_ascii_alphabetic())
            .unwrap_or(rest.len())];
        if kind != "flash" && kind != "stack" {
            continue;
        }
        // The number before: digits in groups separated by single spaces.
        let digits: String = text[..at]
            .rsplit(' ')
            .take_while(|w| !w.is_empty() && w.bytes().all(|b| b.is_ascii_digit()))
            .collect::<Vec<_>>()
            .into_iter()
            .rev()
            .collect();
        let value: u64 = digits
            .parse()
            .map_err(|_| format!("README.md, From C: no number before `B of {kind}`"))?;
        figures.push((kind.to_owned(), value));
    }
    match figures.as_slice() {
        [(a, fa), (b, sa), (c, fb), (d, sb), ..]
            if [a, b, c, d] == ["flash", "stack", "flash", "stack"] =>
        {
            Ok([
                Footprint { flash: *fa, stack: *sa },
                Footprint { flash: *fb, stack: *sb },
            ])
        }
        _ => Err(format!(
            "README.md, From C: expected `N B of flash ... N B of stack` for the default build, then for LS9 + ADC2; found {figures:?}"
        )),
    }
}

/// [`c_footprint`], then the README's figures against it: each within
/// 5 % of the measured one, or the run fails.
fn c_footprint_checked() -> Result<(), String> {
    let measured = c_footprint()?;
    let stated = readme_footprint()?;
    let mut wrong = Vec::new();
    for ((name, m), s) in ["all-methods", "ls9+adc2"].iter().zip(measured).zip(stated) {
        for (what, m, s) in [("flash", m.flash, s.flash), ("stack", m.stack, s.stack)] {
            let off = (m as f64 - s as f64) / s as f64 * 100.0;
            let line = format!("{name} {what}: README {s} B, measured {m} B ({off:+.1} %)");
            println!("{line}");
            if off.abs() > 5.0 {
                wrong.push(line);
            }
        }
    }
    if !wrong.is_empty() {
        return Err(format!(
            "the README's C footprint (From C) is more than 5 % off; state the measured figures: {}",
            wrong.join("; ")
        ));
    }
    println!("the README's C footprint figures hold (within 5 %)");
    Ok(())
}

/// The value of the first `key = "value"` line after the line `section` of
/// the TOML file `path` (enough for this repository's manifests).
fn toml_value(path: &Path, section: &str, key: &str) -> Result<String, String> {
    let text = std::fs::read_to_string(path).map_err(|e| format!("{}: {e}", path.display()))?;
    let prefix = format!("{key} = \"");
    text.lines()
        .skip_while(|l| l.trim() != section)
        .find_map(|l| l.trim().strip_prefix(prefix.as_str())?.strip_suffix('"'))
        .map(str::to_owned)
        .ok_or_else(|| format!("{}: no {key} in {section}", path.display()))
}

/// The core as a user gets it from the registry: `cargo package` (which
/// also builds the packaged crate), then the crate's own tests, doctests
/// included, in a copy extracted outside this workspace (so nothing of the
/// repository is in reach), with the lock file the package carries and
/// the pinned toolchain.
fn package_check() -> Result<(), String> {
    let root = root();
    run(
        &root,
        "cargo",
        &["package", "-p", "mag-cal-core", "--locked", "--allow-dirty"],
    )?;
    let version = toml_value(&root.join("Cargo.toml"), "[workspace.package]", "version")?;
    let toolchain = toml_value(&root.join("rust-toolchain.toml"), "[toolchain]", "channel")?;
    let name = format!("mag-cal-core-{version}");
    let archive = root
        .join("target")
        .join("package")
        .join(format!("{name}.crate"));
    let dir = std::env::temp_dir().join("mag-cal-package-check");
    // A stale copy from an earlier run must not be tested.
    if dir.exists() {
        std::fs::remove_dir_all(&dir).map_err(|e| format!("{}: {e}", dir.display()))?;
    }
    std::fs::create_dir_all(&dir).map_err(|e| format!("{}: {e}", dir.display()))?;
    let (archive, extract) = (path_str(&archive)?, path_str(&dir)?);
    run(&root, "tar", &["-xzf", archive, "-C", extract])?;
    let target = root.join("target").join("package-check");
    let envs = [
        ("RUSTUP_TOOLCHAIN", toolchain.as_str()),
        ("CARGO_TARGET_DIR", path_str(&target)?),
    ];
    let crate_dir = dir.join(&name);
    // The extracted files carry the archive's times, older than the last
    // run's build: cargo would take that build as current and run the
    // doctests (compiled anew) against the earlier library.
    run_with(&crate_dir, "cargo", &["clean", "-p", "mag-cal-core"], &envs)?;
    run_with(&crate_dir, "cargo", &["test", "--locked"], &envs)?;
    // The host features too (`defmt` needs a target with a logger).
    run_with(
        &crate_dir,
        "cargo",
        &["test", "--locked", "--features", "serde,nalgebra"],
        &envs,
    )
}

fn path_str(p: &Path) -> Result<&str, String> {
    p.to_str()
        .ok_or_else(|| format!("{}: path is not UTF-8", p.display()))
}

/// The benchmarks: instruction counts and footprint on the emulated
/// Cortex-M4F (`firmware-example/bench.sh`, which prints the `BENCH` and
/// `FOOTPRINT` lines), and with `--host` the criterion benchmarks.
fn bench(args: &[String]) -> Result<(), String> {
    let mut verify = false;
    let mut host = false;
    for arg in args {
        match arg.as_str() {
            "--verify" => verify = true,
            "--host" => host = true,
            other => {
                return Err(format!(
                    "bench: unknown argument `{other}` (--verify, --host)"
                ))
            }
        }
    }
    let script = firmware_dir().join("bench.sh");
    let script = script.to_str().ok_or("bench.sh: path is not UTF-8")?;
    let mut bench_args = vec![script, "all"];
    if verify {
        bench_args.push("--verify");
    }
    run(&firmware_dir(), "bash", &bench_args)?;
    c_footprint_checked()?;
    if host {
        run(&root(), "cargo", &["bench", "--locked", "-p", "benches"])?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_footprint_figures_are_read_from_the_sentence() {
        let text = "one call adds 68 536 B of flash to a C program and needs\n4 144 B of stack. \
                    LS9 + ADC2 alone: 49 752 B of flash and 4 128 B of stack (`cargo xtask`).";
        assert_eq!(
            footprint_figures(text),
            Ok([
                Footprint {
                    flash: 68_536,
                    stack: 4_144
                },
                Footprint {
                    flash: 49_752,
                    stack: 4_128
                },
            ])
        );
        // A figure missing or out of order is an error, not a guess.
        assert!(footprint_figures("adds 68 536 B of flash and 49 752 B of flash").is_err());
        assert!(
            footprint_figures("adds B of flash, 4 B of stack, 5 B of flash, 6 B of stack").is_err()
        );
    }

    #[test]
    fn code_blocks_are_found_by_language() {
        let text = "x\n```sh\ncargo a\n# -> t\n```\n```c\nint x;\n```\n```sh\nb\n```\n";
        assert_eq!(fenced_blocks(text, "sh"), ["cargo a\n# -> t\n", "b\n"]);
        assert_eq!(fenced_blocks(text, "c"), ["int x;\n"]);
    }
}
