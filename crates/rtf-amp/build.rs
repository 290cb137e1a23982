// Compiles the C++ shim over libtorch's autocast state (csrc/amp_shim.cpp).
include!("../torch_cpp.rs");

fn main() {
    libtorch_cpp("csrc/amp_shim.cpp").compile("rtf_amp_shim");
    println!(
        "cargo:rustc-link-arg=-Wl,-rpath,{}",
        libtorch_lib().display()
    );
}
