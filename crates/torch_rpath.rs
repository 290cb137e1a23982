// Shared build script body for crates whose binaries or tests link libtorch: tch only sets an
// rpath for its own targets, so each such crate embeds the libtorch directory itself
// (torch-sys hands it over as DEP_TCH_LIBTORCH_LIB because we depend on torch-sys directly).
fn main() {
    if let Ok(lib) = std::env::var("DEP_TCH_LIBTORCH_LIB") {
        println!("cargo:rustc-link-arg=-Wl,-rpath,{lib}");
        // Keep libtorch_cuda linked even though no symbol of it is referenced directly.
        println!("cargo:rustc-link-arg=-Wl,--no-as-needed");
        println!("cargo:rustc-link-arg=-ltorch");
    }
}
