//! Gives the integration tests (tests/it, a target of this package) the repository's root as
//! `CLIPMAP_ROOT`: they read the examples, fixtures and docs there, and run the tools in it.

fn main() {
    let manifest =
        std::path::PathBuf::from(std::env::var_os("CARGO_MANIFEST_DIR").expect("cargo sets CARGO_MANIFEST_DIR"));
    let root = manifest.parent().and_then(|apps| apps.parent()).expect("the package lives in apps/clipmap-tools");
    println!("cargo:rustc-env=CLIPMAP_ROOT={}", root.display());
    println!("cargo:rerun-if-changed=build.rs");
}
