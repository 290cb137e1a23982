// Compiles the C++ shim over libtorch's autocast state (csrc/amp_shim.cpp) against the headers
// of the libtorch torch-sys links (it hands its lib directory over as DEP_TCH_LIBTORCH_LIB), with
// the flags torch-sys uses for its own shim: C++17 and the libstdc++ ABI of the library.
fn main() {
    println!("cargo:rerun-if-changed=csrc/amp_shim.cpp");
    println!("cargo:rerun-if-env-changed=LIBTORCH_CXX11_ABI");
    let lib = std::env::var("DEP_TCH_LIBTORCH_LIB")
        .expect("torch-sys did not report its libtorch directory (DEP_TCH_LIBTORCH_LIB)");
    let root = std::path::Path::new(&lib)
        .parent()
        .expect("libtorch lib directory has a parent")
        .to_path_buf();
    let abi = std::env::var("LIBTORCH_CXX11_ABI").unwrap_or_else(|_| "1".to_owned());
    cc::Build::new()
        .cpp(true)
        .file("csrc/amp_shim.cpp")
        .include(root.join("include"))
        .flag("-std=c++17")
        .flag(format!("-D_GLIBCXX_USE_CXX11_ABI={abi}"))
        .warnings(false)
        .compile("rtf_amp_shim");
    println!("cargo:rustc-link-arg=-Wl,-rpath,{lib}");
}
