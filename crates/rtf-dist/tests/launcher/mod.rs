//! What the torchrun tests of rtf-dist, rtf-train and rtf-cli share (included by path from
//! the other crates' tests): the launcher and a free loopback port for its rendezvous.

use std::path::{Path, PathBuf};

/// The venv's torchrun (`cargo xtask setup` creates it), or RTF_TORCHRUN. Every crate lives in
/// `crates/<name>`, so the venv is two folders above the manifest.
pub fn torchrun() -> Option<PathBuf> {
    if let Some(p) = std::env::var_os("RTF_TORCHRUN") {
        return Some(PathBuf::from(p));
    }
    let p = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../.venv/bin/torchrun");
    p.exists().then_some(p)
}

/// A loopback port free at the time of asking (torchrun's `--master-port`).
pub fn free_port() -> u16 {
    std::net::TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port()
}
