//! The prebuilt ISPC kernels of `intel_tex_2` (block compression, src/source/bc.rs) name the C++
//! runtime's exception personality: link libstdc++ so that every binary and test finds it.

fn main() {
    println!("cargo:rustc-link-lib=stdc++");
    println!("cargo:rerun-if-changed=build.rs");
}
