//! Puts the repository's one `memory.x` on the linker search path, where
//! `cortex-m-rt`'s `link.x` picks it up, and passes the linker script (as
//! firmware-example's build.rs does, without defmt).
//!
//! `NO_PANIC_CHECK_FLASH_KB=N` replaces the flash length by `N` KiB (same
//! origin, same RAM): an `opt-level = 3` build of every monomorphisation
//! does not fit the nRF52833's 512 KiB, and the check is about what the
//! optimiser leaves, not about the size.

use std::{env, fs, path::PathBuf};

fn main() {
    let out = PathBuf::from(env::var_os("OUT_DIR").expect("OUT_DIR is set by cargo"));
    let memory_x = PathBuf::from(env::var_os("CARGO_MANIFEST_DIR").expect("set by cargo"))
        .join("..")
        .join("memory.x");
    let text = fs::read_to_string(&memory_x)
        .unwrap_or_else(|e| panic!("reading {}: {e}", memory_x.display()));
    let text = match env::var("NO_PANIC_CHECK_FLASH_KB") {
        Ok(kb) => {
            let kb: u32 = kb.parse().expect("NO_PANIC_CHECK_FLASH_KB is a number");
            let line = text
                .lines()
                .find(|l| l.trim_start().starts_with("FLASH"))
                .expect("memory.x has a FLASH line");
            let start = line.find("LENGTH").expect("FLASH line has a LENGTH");
            text.replace(line, &format!("{}LENGTH = {kb}K", &line[..start]))
        }
        Err(_) => text,
    };
    fs::write(out.join("memory.x"), text).expect("writing memory.x");
    println!("cargo:rustc-link-search={}", out.display());
    println!("cargo:rerun-if-changed={}", memory_x.display());
    println!("cargo:rerun-if-changed=build.rs");
    println!("cargo:rerun-if-env-changed=NO_PANIC_CHECK_FLASH_KB");
    for arg in ["--nmagic", "-Tlink.x"] {
        println!("cargo:rustc-link-arg-bins={arg}");
    }
}
