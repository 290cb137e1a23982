//! Per-thread settings that a call sets for the work inside it (the Winograd forms training
//! steps may take; lazy initialisation), below every module that reads them.

use std::cell::Cell;
use std::thread::LocalKey;

/// Runs `f` with this thread's `setting` set to `value`, restoring the previous value after.
pub(crate) fn with<V: Copy, T>(
    setting: &'static LocalKey<Cell<V>>,
    value: V,
    f: impl FnOnce() -> T,
) -> T {
    let previous = setting.with(|c| c.replace(value));
    let out = f();
    setting.with(|c| c.set(previous));
    out
}
