// The extension finds libtorch in the torch package installed beside it
// (site-packages/rtf/_rtf.so -> site-packages/torch/lib), never at the build machine's path;
// csrc/python_tensor.cpp (torch.Tensor <-> at::Tensor) is compiled against libtorch's and the
// target Python's headers and links libtorch_python, which the Python process has loaded.
include!("../torch_cpp.rs");

/// The target interpreter's C headers (maturin sets PYO3_PYTHON).
fn python_include() -> std::path::PathBuf {
    println!("cargo:rerun-if-env-changed=PYO3_PYTHON");
    let python = std::env::var("PYO3_PYTHON").unwrap_or_else(|_| "python3".to_owned());
    let out = std::process::Command::new(&python)
        .args([
            "-c",
            "import sysconfig; print(sysconfig.get_paths()['include'])",
        ])
        .output()
        .unwrap_or_else(|e| panic!("cannot run {python} for its include directory: {e}"));
    assert!(
        out.status.success(),
        "{python} failed to name its include directory"
    );
    std::path::PathBuf::from(String::from_utf8_lossy(&out.stdout).trim())
}

fn main() {
    println!("cargo:rustc-link-arg=-Wl,-rpath,$ORIGIN/../torch/lib");
    let api = libtorch_lib()
        .parent()
        .expect("libtorch lib directory has a parent")
        .join("include/torch/csrc/api/include");
    libtorch_cpp("csrc/python_tensor.cpp")
        .include(api)
        .include(python_include())
        .compile("rtf_py_tensor");
    println!("cargo:rustc-link-lib=torch_python");
    println!(
        "cargo:rustc-link-search=native={}",
        libtorch_lib().display()
    );
}
