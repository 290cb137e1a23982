// Operators the networks need that tch 0.26 does not offer:
// - ATen operators tch binds without a parameter the networks need. tch generates its bindings
//   with defaulted scalars dropped, so `Tensor::leaky_relu` has the slope fixed at 0.01; MFNet
//   uses 0.1. Calling ATen here goes through the dispatcher, autograd included, so the result is
//   differentiable exactly like `torch.nn.functional.leaky_relu(x, slope, inplace)`.
// - A bf16 convolution for CPUs without bf16 arithmetic (below, `Bf16EmulatedConvolution`).
// - ATen's fused SGD update (one pass over parameter, gradient and momentum buffer), which tch
//   does not bind (list arguments).
// Tensors arrive as `at::Tensor*`, which is what tch's `C_tensor*` is. Every C++ exception is
// caught and returned as a malloc'd message (NULL = success).

#include <ATen/ATen.h>
#include <c10/core/impl/LocalDispatchKeySet.h>
#include <torch/csrc/autograd/custom_function.h>

#include <cstdlib>
#include <cstring>
#include <exception>

namespace {

using torch::autograd::AutogradContext;
using torch::autograd::variable_list;

struct Geometry {
  std::vector<int64_t> stride, padding, dilation, output_padding;
  bool transposed;
  int64_t groups;
};

// The value `t` takes as a bf16 tensor, back in `kind` (a gradient of a bf16 operand, as the
// cast out of an autocast region hands it on).
at::Tensor through_bf16(const at::Tensor& t, at::ScalarType kind) {
  return t.defined() ? t.to(at::kBFloat16).to(kind) : t;
}

// A convolution with bf16 semantics computed by fp32 kernels, for CPUs without bf16 arithmetic
// (AVX2): there libtorch has no fast bf16 convolution (oneDNN refuses bf16 without avx512_bf16
// or AMX) and autocast's bf16 convolutions fall to generic kernels, a training step ~10x slower
// than fp32 (docs/src/benchmarks.md).
//
// The numbers are those of a native bf16 kernel: the operands are rounded to bf16 (autocast's
// casts); a product of two bf16 values is exact in fp32 (8 + 8 significand bits) and native
// kernels accumulate in fp32 too, so only the order of the sums differs; the output, and the
// gradients of the bf16 operands, are rounded to bf16, then handed to the inputs' own types as
// autocast's casts do (fp32 master weights get bf16-rounded gradients). The operands saved for
// the backward pass are the bf16 ones (autocast's activation memory).
struct Bf16EmulatedConvolution : public torch::autograd::Function<Bf16EmulatedConvolution> {
  static at::Tensor forward(AutogradContext* ctx, const at::Tensor& x, const at::Tensor& w,
                            const at::Tensor& b, std::vector<int64_t> stride,
                            std::vector<int64_t> padding, std::vector<int64_t> dilation,
                            std::vector<int64_t> output_padding, bool transposed,
                            int64_t groups, bool has_bias) {
    // The fp32 kernels below must not be cast back to bf16 by an enclosing autocast region.
    c10::impl::ExcludeDispatchKeyGuard no_autocast(c10::DispatchKey::AutocastCPU);
    at::Tensor xb = x.to(at::kBFloat16);
    at::Tensor wb = w.to(at::kBFloat16);
    at::Tensor bias = has_bias ? through_bf16(b, at::kFloat) : at::Tensor();
    ctx->save_for_backward({xb, wb});
    ctx->saved_data["x_kind"] = static_cast<int64_t>(x.scalar_type());
    ctx->saved_data["w_kind"] = static_cast<int64_t>(w.scalar_type());
    ctx->saved_data["b_kind"] = static_cast<int64_t>(b.scalar_type());
    ctx->saved_data["bias_size"] = has_bias ? b.size(0) : int64_t{-1};
    ctx->saved_data["stride"] = stride;
    ctx->saved_data["padding"] = padding;
    ctx->saved_data["dilation"] = dilation;
    ctx->saved_data["output_padding"] = output_padding;
    ctx->saved_data["transposed"] = transposed;
    ctx->saved_data["groups"] = groups;
    at::Tensor y = at::convolution(xb.to(at::kFloat), wb.to(at::kFloat), bias, stride, padding,
                                   dilation, transposed, output_padding, groups);
    return y.to(at::kBFloat16);
  }

  static variable_list backward(AutogradContext* ctx, variable_list grads) {
    c10::impl::ExcludeDispatchKeyGuard no_autocast(c10::DispatchKey::AutocastCPU);
    auto saved = ctx->get_saved_variables();
    auto& d = ctx->saved_data;
    auto kind = [&](const char* key) { return static_cast<at::ScalarType>(d[key].toInt()); };
    int64_t bias_size = d["bias_size"].toInt();
    std::array<bool, 3> mask{ctx->needs_input_grad(0), ctx->needs_input_grad(1),
                             bias_size >= 0 && ctx->needs_input_grad(2)};
    std::vector<int64_t> bias_sizes{bias_size};
    auto stride = d["stride"].toIntVector();
    auto padding = d["padding"].toIntVector();
    auto dilation = d["dilation"].toIntVector();
    auto output_padding = d["output_padding"].toIntVector();
    // The incoming gradient is that of a bf16 output.
    at::Tensor gy = through_bf16(grads[0], at::kFloat);
    auto [gx, gw, gb] = at::convolution_backward(
        gy, saved[0].to(at::kFloat), saved[1].to(at::kFloat),
        bias_size >= 0 ? at::OptionalIntArrayRef(bias_sizes) : at::OptionalIntArrayRef(),
        stride, padding, dilation, d["transposed"].toBool(), output_padding,
        d["groups"].toInt(), mask);
    return {through_bf16(gx, kind("x_kind")), through_bf16(gw, kind("w_kind")),
            through_bf16(gb, kind("b_kind")), at::Tensor(), at::Tensor(), at::Tensor(),
            at::Tensor(), at::Tensor(), at::Tensor(), at::Tensor()};
  }
};

}  // namespace

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

// `*out` = the bf16 convolution of x and w (+ b), emulated (see Bf16EmulatedConvolution); b may
// be NULL. Geometry arrays hold (H, W) pairs.
char* rtf_bf16_emulated_convolution(at::Tensor* x, at::Tensor* w, at::Tensor* b,
                                    const int64_t* stride, const int64_t* padding,
                                    const int64_t* dilation, int transposed,
                                    const int64_t* output_padding, int64_t groups,
                                    at::Tensor** out) {
  try {
    *out = nullptr;
    Geometry g{{stride[0], stride[1]},
               {padding[0], padding[1]},
               {dilation[0], dilation[1]},
               {output_padding[0], output_padding[1]},
               transposed != 0,
               groups};
    // A custom autograd function takes no undefined tensor: without a bias, an unused
    // placeholder stands in (has_bias false).
    at::Tensor bias = b != nullptr ? *b : at::zeros({1}, w->options().requires_grad(false));
    at::Tensor y = Bf16EmulatedConvolution::apply(*x, *w, bias, g.stride, g.padding, g.dilation,
                                                  g.output_padding, g.transposed, g.groups,
                                                  b != nullptr);
    *out = new at::Tensor(std::move(y));
    return nullptr;
  } catch (const std::exception& e) {
    return strdup(e.what());
  } catch (...) {
    return strdup("unknown C++ exception in rtf_bf16_emulated_convolution");
  }
}

// One SGD step of `param` (PyTorch's rules, no dampening or Nesterov) in one fused pass:
// g = grad + weight_decay·param; buf = g on the first step, else momentum·buf + g;
// param -= lr·buf. `buf` must be shaped like `param`; with momentum 0 it is left alone.
char* rtf_fused_sgd(at::Tensor* param, at::Tensor* grad, at::Tensor* buf, double weight_decay,
                    double momentum, double lr, int is_first_step) {
  try {
    at::NoGradGuard no_grad;
    std::vector<at::Tensor> params{*param}, grads{*grad}, bufs;
    if (momentum != 0.0) {
      bufs.push_back(*buf);
    }
    at::_fused_sgd_(params, grads, bufs, weight_decay, momentum, lr, /*dampening=*/0.0,
                    /*nesterov=*/false, /*maximize=*/false, is_first_step != 0);
    return nullptr;
  } catch (const std::exception& e) {
    return strdup(e.what());
  } catch (...) {
    return strdup("unknown C++ exception in rtf_fused_sgd");
  }
}

void rtf_ops_free_error(char* error) {
  free(error);
}

}  // extern "C"
