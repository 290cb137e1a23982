//! Compiles the c10d shim against the libtorch headers torch-sys builds with (its
//! `DEP_TCH_LIBTORCH_LIB`, and the same C++ ABI flag), and embeds the libtorch rpath like the
//! workspace's other crates that link libtorch.
use std::path::PathBuf;
include!("../torch_cpp.rs");

fn main() {
    println!("cargo:rerun-if-changed=shim");
    println!("cargo:rerun-if-env-changed=RTF_DIST_CUDA_INCLUDE");
    println!("cargo:rerun-if-env-changed=RTF_DIST_NCCL_INCLUDE");
    let lib = libtorch_lib();
    let include = lib.parent().expect("libtorch root").join("include");
    let mut build = libtorch_cpp("shim/c10d_shim.cpp");
    build
        .pic(true)
        .include("shim/gloo_decl")
        .include(include.join("torch/csrc/api/include"))
        .flag("-DGLOG_USE_GLOG_EXPORT");
    if std::env::var_os("CARGO_FEATURE_NCCL").is_some() {
        // ProcessGroupNCCL.hpp needs a CUDA toolkit's headers (the runtime wheels lack nvcc's
        // `crt/` and CCCL's `nv/`): RTF_DIST_CUDA_INCLUDE, else /usr/local/cuda/include. NCCL's
        // header comes from the venv's nvidia-nccl wheel beside torch, or RTF_DIST_NCCL_INCLUDE.
        let cuda = std::env::var("RTF_DIST_CUDA_INCLUDE")
            .map(PathBuf::from)
            .unwrap_or_else(|_| PathBuf::from("/usr/local/cuda/include"));
        let nccl = std::env::var("RTF_DIST_NCCL_INCLUDE")
            .map(PathBuf::from)
            .unwrap_or_else(|_| lib.join("../../nvidia/nccl/include"));
        if !cuda.join("crt/host_config.h").exists() {
            panic!(
                "the `nccl` feature needs a CUDA toolkit's headers: {} has no crt/host_config.h \
                 (set RTF_DIST_CUDA_INCLUDE)",
                cuda.display()
            );
        }
        build
            .define("RTF_DIST_NCCL", "1")
            .include(cuda)
            .include(nccl);
        println!("cargo:rustc-link-lib=torch_cuda");
    }
    build.compile("rtf_c10d");
    println!("cargo:rustc-link-search=native={}", lib.display());
    println!("cargo:rustc-link-lib=torch_cpu");
    println!("cargo:rustc-link-lib=c10");
    println!("cargo:rustc-link-arg=-Wl,-rpath,{}", lib.display());
}
