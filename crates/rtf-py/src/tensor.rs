//! `torch.Tensor` in and out without a copy (csrc/python_tensor.cpp): the Python object and
//! the `tch::Tensor` share one libtorch tensor, with its autograd history.

use pyo3::exceptions::{PyRuntimeError, PyTypeError};
use pyo3::prelude::*;

extern "C" {
    fn rtf_py_tensor_unpack(obj: *mut pyo3::ffi::PyObject) -> *mut torch_sys::C_tensor;
    fn rtf_py_tensor_wrap(t: *const torch_sys::C_tensor) -> *mut pyo3::ffi::PyObject;
}

/// A tensor passed to or from Python.
pub struct PyTensor(pub tch::Tensor);

impl std::ops::Deref for PyTensor {
    type Target = tch::Tensor;
    fn deref(&self) -> &tch::Tensor {
        &self.0
    }
}

impl<'py> FromPyObject<'py> for PyTensor {
    fn extract_bound(ob: &Bound<'py, PyAny>) -> PyResult<Self> {
        // SAFETY: `ob` is a live object while the GIL is held; the shim returns a new
        // heap-allocated at::Tensor (owned by the tch::Tensor from here) or null.
        let ptr = unsafe { rtf_py_tensor_unpack(ob.as_ptr()) };
        if ptr.is_null() {
            let type_ = ob.get_type();
            return Err(PyTypeError::new_err(format!(
                "expected a torch.Tensor, got {type_}"
            )));
        }
        // SAFETY: a valid, uniquely owned at::Tensor* from the shim.
        Ok(PyTensor(unsafe { tch::Tensor::from_ptr(ptr) }))
    }
}

impl<'py> IntoPyObject<'py> for PyTensor {
    type Target = PyAny;
    type Output = Bound<'py, PyAny>;
    type Error = PyErr;

    fn into_pyobject(self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        // SAFETY: `as_ptr` is a live at::Tensor* for the call (the shim copies the handle);
        // the GIL is held, as THPVariable_Wrap requires; a non-null result is a new reference.
        unsafe {
            let obj = rtf_py_tensor_wrap(self.0.as_ptr());
            if obj.is_null() {
                return Err(PyErr::take(py).unwrap_or_else(|| {
                    PyRuntimeError::new_err("rtf: a tensor could not be handed to Python")
                }));
            }
            Ok(Bound::from_owned_ptr(py, obj))
        }
    }
}
