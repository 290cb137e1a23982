// torch.Tensor <-> at::Tensor for the extension, without a copy: the Python object and the
// Rust tensor share one TensorImpl (and so data, autograd history and version counter).
// Compiled for rtf-py alone, so the other crates' libtorch builds never link libtorch_python.
#include <torch/csrc/autograd/python_variable.h>

extern "C" {

// A new handle on `obj`'s tensor, or null where `obj` is not a torch.Tensor.
at::Tensor* rtf_py_tensor_unpack(PyObject* obj) {
  try {
    if (!THPVariable_Check(obj)) return nullptr;
    return new at::Tensor(THPVariable_Unpack(obj));
  } catch (...) {
    return nullptr;
  }
}

// A new reference to the torch.Tensor of `t` (the one Python already has, or a new one), or
// null with a Python error set.
PyObject* rtf_py_tensor_wrap(const at::Tensor* t) {
  try {
    return THPVariable_Wrap(*t);
  } catch (...) {
    PyErr_SetString(PyExc_RuntimeError, "rtf: a tensor could not be handed to Python");
    return nullptr;
  }
}

}
