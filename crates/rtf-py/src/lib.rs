//! The Python extension `rtf._rtf` behind the package `rtf` (python/rtf/__init__.py, which
//! checks the torch version and imports torch before this module). Every entry point calls
//! the library function the corresponding `rtf` command calls; library errors become
//! `rtf.Error` subclasses (errors.rs) and the GIL is released while rtf computes.

mod arrays;
mod calibrate;
mod dataset;
mod errors;
mod evaluate;
mod loader;
mod methods;
mod network;
mod run;
mod tensor;
mod train;

use pyo3::prelude::*;

/// A caught panic's message (libtorch errors reach tch's infallible calls as panics).
pub(crate) fn panic_message(payload: &Box<dyn std::any::Any + Send>) -> String {
    payload
        .downcast_ref::<String>()
        .cloned()
        .or_else(|| payload.downcast_ref::<&str>().map(|s| s.to_string()))
        .unwrap_or_else(|| "panic without a message".into())
}

/// Keeps freed memory in the process for reuse (rtf_kernels::allocator: glibc serves no block
/// by `mmap` and trims no heap), as the `rtf` binary keeps it with mimalloc: a network that
/// allocates the same activations every pass then does not page-fault them in again. Called by
/// `import rtf` unless `RTF_RETAIN_FREED_MEMORY=0`. Process-wide; returns whether it applied.
#[pyfunction]
fn retain_freed_memory() -> bool {
    rtf_kernels::allocator::retain_freed_memory()
}

#[pymodule]
fn _rtf(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    errors::register(m)?;
    m.add_class::<network::PyNetwork>()?;
    m.add_class::<dataset::PyDataset>()?;
    m.add_class::<dataset::PySplit>()?;
    m.add_class::<dataset::PyFrame>()?;
    m.add_class::<loader::PyLoader>()?;
    m.add_class::<loader::PyEpoch>()?;
    m.add_function(wrap_pyfunction!(network::load_network, m)?)?;
    m.add_function(wrap_pyfunction!(network::models, m)?)?;
    m.add_function(wrap_pyfunction!(dataset::open_dataset, m)?)?;
    m.add_function(wrap_pyfunction!(evaluate::evaluate_json, m)?)?;
    m.add_function(wrap_pyfunction!(calibrate::calibrate_yaml, m)?)?;
    m.add_function(wrap_pyfunction!(run::read_run, m)?)?;
    m.add_function(wrap_pyfunction!(train::train, m)?)?;
    m.add_function(wrap_pyfunction!(train::train_options, m)?)?;
    m.add_function(wrap_pyfunction!(retain_freed_memory, m)?)?;
    Ok(())
}
