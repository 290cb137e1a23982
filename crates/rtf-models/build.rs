// Embeds the libtorch rpath in the crate's tests (shared body; the C++ shim is rtf-kernels').
include!("../torch_rpath.rs");
