//! Free space on the disk that holds `target/`, printed between the suite's passes. A fresh
//! clone's suite needs room for the release build, `.venv` (PyTorch) and the smoke
//! reproduction's largest cell: RTFNet-152 writes a checkpoint with its momentum (2 GB), the
//! best and the final weights (1 GB each) before xtask removes them. A CI machine once ran out
//! of disk in that cell; the line before each pass tells how close a machine is.

use std::ffi::CString;
use std::os::unix::ffi::OsStrExt;
use std::path::Path;

/// What the smoke reproduction's largest cell holds on disk at its peak, in bytes.
pub const SMOKE_PEAK: u64 = 4_500_000_000;

/// Bytes available to this user on the file system holding `path`, or `None` where it cannot
/// be read.
pub fn free_bytes(path: &Path) -> Option<u64> {
    let c_path = CString::new(path.as_os_str().as_bytes()).ok()?;
    // SAFETY: `c_path` is a NUL-terminated string that outlives the call, and `stat` is a
    // plain-data struct that statvfs fills in; it is read only when the call succeeded.
    let stat = unsafe {
        let mut stat: libc::statvfs = std::mem::zeroed();
        if libc::statvfs(c_path.as_ptr(), &mut stat) != 0 {
            return None;
        }
        stat
    };
    Some(stat.f_bavail.saturating_mul(stat.f_frsize))
}

/// Prints the free space under `root` before the pass named `pass`, with a warning when less
/// than `needs` bytes are free.
pub fn note(root: &Path, pass: &str, needs: u64) {
    let Some(free) = free_bytes(root) else {
        return;
    };
    println!(
        "xtask test: {:.1} GB free on the disk of {} before {pass}",
        free as f64 / 1e9,
        root.display()
    );
    if free < needs {
        println!(
            "xtask test: warning: {pass} may need about {:.1} GB; with {:.1} GB free it can \
             fail with `No space left on device`",
            needs as f64 / 1e9,
            free as f64 / 1e9
        );
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn free_space_is_read_for_a_folder_and_not_for_a_missing_one() {
        let dir = tempfile::tempdir().unwrap();
        assert!(free_bytes(dir.path()).is_some_and(|b| b > 0));
        assert_eq!(free_bytes(&dir.path().join("missing")), None);
    }
}
