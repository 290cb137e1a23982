// Embeds the libtorch rpath (shared body) and compiles csrc/ops.cpp against libtorch.
include!("../torch_cpp.rs");
mod rpath {
    include!("../torch_rpath.rs");
    pub fn embed() {
        main()
    }
}

fn main() {
    rpath::embed();
    libtorch_cpp("csrc/ops.cpp").compile("rtf_kernels_ops");
}
