// The extension finds libtorch in the torch package installed beside it
// (site-packages/rtf/_rtf.so -> site-packages/torch/lib), never at the build machine's path.
fn main() {
    println!("cargo:rustc-link-arg=-Wl,-rpath,$ORIGIN/../torch/lib");
}
