include!("../../crates/torch_rpath.rs");
