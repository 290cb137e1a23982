// Embeds the libtorch rpath (shared body) and compiles csrc/ops.cpp against the headers of the
// libtorch torch-sys links, with its C++17 and libstdc++ ABI flags (as rtf-amp's shim).
mod rpath {
    include!("../torch_rpath.rs");
    pub fn embed() {
        main()
    }
}

fn main() {
    rpath::embed();
    println!("cargo:rerun-if-changed=csrc/ops.cpp");
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
        .file("csrc/ops.cpp")
        .include(root.join("include"))
        .flag("-std=c++17")
        .flag(format!("-D_GLIBCXX_USE_CXX11_ABI={abi}"))
        .warnings(false)
        .compile("rtf_models_ops");
}
