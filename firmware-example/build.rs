//! Puts the repository's one `memory.x` (nRF52833; the same map boots on
//! QEMU's mps2-an386) on the linker search path, where `cortex-m-rt`'s
//! `link.x` picks it up, and passes the linker scripts.

use std::{env, fs, path::PathBuf};

fn main() {
    let out = PathBuf::from(env::var_os("OUT_DIR").expect("OUT_DIR is set by cargo"));
    let memory_x = PathBuf::from(env::var_os("CARGO_MANIFEST_DIR").expect("set by cargo"))
        .join("..")
        .join("memory.x");
    fs::copy(&memory_x, out.join("memory.x"))
        .unwrap_or_else(|e| panic!("copying {}: {e}", memory_x.display()));
    println!("cargo:rustc-link-search={}", out.display());
    println!("cargo:rerun-if-changed={}", memory_x.display());
    println!("cargo:rerun-if-changed=build.rs");

    // `--nmagic`: sections need not be page-aligned in flash (knurling
    // app-template); `-Tlink.x`: cortex-m-rt's script, which includes
    // memory.x; `-Tdefmt.x`: defmt's interned strings.
    for arg in ["--nmagic", "-Tlink.x", "-Tdefmt.x"] {
        println!("cargo:rustc-link-arg-bins={arg}");
    }
}
