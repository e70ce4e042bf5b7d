//! Build fingerprint: a hash of the sources every binary is built from, so
//! the launcher can tell whether the stage executables next to it were built
//! from the same code as itself (`cargo run` rebuilds only `beliefbus`).
//!
//! It lives in this crate because the launcher and the stages' `--build-id`
//! (`pipeline::stage_main::BUILD_ID`) are here, but it hashes the whole
//! workspace: every crate and the root package's sources and binaries go
//! into each executable.

use std::hash::Hasher;
use std::path::{Path, PathBuf};

fn files(dir: &Path, out: &mut Vec<PathBuf>) {
    let Ok(rd) = std::fs::read_dir(dir) else {
        return;
    };
    for e in rd.flatten() {
        let p = e.path();
        if p.is_dir() {
            files(&p, out);
        } else {
            out.push(p);
        }
    }
}

fn main() {
    // The workspace root: this crate is crates/beliefbus-runtime.
    let manifest = PathBuf::from(std::env::var("CARGO_MANIFEST_DIR").unwrap());
    let root = manifest.join("../..");
    let mut all = Vec::new();
    for d in ["src", "processes", "crates"] {
        files(&root.join(d), &mut all);
        println!("cargo:rerun-if-changed=../../{d}");
    }
    all.push(root.join("Cargo.toml"));
    println!("cargo:rerun-if-changed=../../Cargo.toml");
    all.sort();
    // FNV-1a over paths and contents (std's SipHash with fixed keys would do
    // too; FNV is simple and stable across Rust versions).
    let mut h = Fnv(0xcbf2_9ce4_8422_2325);
    for p in &all {
        h.write(
            p.strip_prefix(&root)
                .unwrap_or(p)
                .to_string_lossy()
                .as_bytes(),
        );
        h.write(&std::fs::read(p).unwrap_or_default());
    }
    println!("cargo:rustc-env=BELIEFBUS_BUILD_ID={:016x}", h.finish());
}

struct Fnv(u64);

impl Hasher for Fnv {
    fn finish(&self) -> u64 {
        self.0
    }
    fn write(&mut self, bytes: &[u8]) {
        for b in bytes {
            self.0 ^= *b as u64;
            self.0 = self.0.wrapping_mul(0x0100_0000_01b3);
        }
    }
}
