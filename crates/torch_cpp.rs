// Shared build-script helper for the crates that compile C++ against libtorch (rtf-models'
// ops, rtf-amp's autocast shim, rtf-dist's c10d shim): a `cc` build over the headers of the
// libtorch torch-sys links (it hands its lib directory over as DEP_TCH_LIBTORCH_LIB), with the
// flags torch-sys uses for its own shim: C++17 and the libstdc++ ABI of the library.

/// The libtorch `lib/` directory torch-sys links.
fn libtorch_lib() -> std::path::PathBuf {
    std::path::PathBuf::from(
        std::env::var("DEP_TCH_LIBTORCH_LIB")
            .expect("torch-sys did not report its libtorch directory (DEP_TCH_LIBTORCH_LIB)"),
    )
}

/// A C++17 build of `source` against libtorch's headers, rebuilt when it or the ABI changes.
fn libtorch_cpp(source: &str) -> cc::Build {
    println!("cargo:rerun-if-changed={source}");
    println!("cargo:rerun-if-env-changed=LIBTORCH_CXX11_ABI");
    let include = libtorch_lib()
        .parent()
        .expect("libtorch lib directory has a parent")
        .join("include");
    let abi = std::env::var("LIBTORCH_CXX11_ABI").unwrap_or_else(|_| "1".to_owned());
    let mut build = cc::Build::new();
    build
        .cpp(true)
        .file(source)
        .include(include)
        .flag("-std=c++17")
        .flag(format!("-D_GLIBCXX_USE_CXX11_ABI={abi}"))
        .warnings(false);
    build
}
