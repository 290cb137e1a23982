// ATen operators tch 0.26 binds without a parameter the networks need. tch generates its
// bindings with defaulted scalars dropped, so `Tensor::leaky_relu` has the slope fixed at 0.01;
// MFNet uses 0.1. Calling ATen here goes through the dispatcher, autograd included, so the
// result is differentiable exactly like `torch.nn.functional.leaky_relu(x, slope, inplace)`.
// Tensors arrive as `at::Tensor*`, which is what tch's `C_tensor*` is. Every C++ exception is
// caught and returned as a malloc'd message (NULL = success).

#include <ATen/ATen.h>

#include <cstdlib>
#include <cstring>
#include <exception>

extern "C" {

// `*out` = leaky_relu(x, slope); with `in_place`, x itself is overwritten (and returned).
char* rtf_leaky_relu(at::Tensor* x, double slope, int in_place, at::Tensor** out) {
  try {
    *out = nullptr;
    at::Tensor y = in_place != 0 ? at::leaky_relu_(*x, slope) : at::leaky_relu(*x, slope);
    *out = new at::Tensor(std::move(y));
    return nullptr;
  } catch (const std::exception& e) {
    return strdup(e.what());
  } catch (...) {
    return strdup("unknown C++ exception in rtf_leaky_relu");
  }
}

void rtf_ops_free_error(char* error) {
  free(error);
}

}  // extern "C"
