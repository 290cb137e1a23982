// Operators the networks need that tch 0.26 does not offer:
// - ATen operators tch binds without a parameter the networks need. tch generates its bindings
//   with defaulted scalars dropped, so `Tensor::leaky_relu` has the slope fixed at 0.01; MFNet
//   uses 0.1. Calling ATen here goes through the dispatcher, autograd included, so the result is
//   differentiable exactly like `torch.nn.functional.leaky_relu(x, slope, inplace)`.
// - A bf16 convolution for CPUs without bf16 arithmetic (below, `Bf16EmulatedConvolution`).
// - oneDNN weight packing for the inference path's convolutions (`rtf_pack_conv_weight`).
// - ATen's fused SGD update (one pass over parameter, gradient and momentum buffer), which tch
//   does not bind (list arguments).
// Tensors arrive as `at::Tensor*`, which is what tch's `C_tensor*` is. Every C++ exception is
// caught and returned as a malloc'd message (NULL = success).

#include <ATen/ATen.h>
#include <ATen/Parallel.h>
#include <ATen/record_function.h>
#include <c10/core/impl/LocalDispatchKeySet.h>
#include <torch/csrc/autograd/custom_function.h>

#include <cstdint>
#include <cstdlib>
#include <cstring>
#include <algorithm>
#include <exception>
#include <map>
#include <mutex>
#include <sstream>
#include <string>
#include <tuple>
#include <vector>

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


// ---- Winograd F(4x4, 3x3) (Lavin & Gray 2016) for inference and fp32 training (winograd.rs) --
// A 3x3 convolution (stride 1, padding 1) of an NHWC map (float, or bf16 converted on the way
// in and out, the arithmetic in float), 4x4 output tiles: each 6x6
// input tile d becomes V = Bt d B (36 values per channel), the channels are summed by 36 matrix
// products M[xi] = V[xi] U[xi] (U = G g Gt, made once in Rust), and each tile's outputs are
// At M A. Tiles go in chunks that keep V and M in cache; the transforms are loops over the
// channels, which the compiler vectorises (a copy per instruction set, picked at run time).
// `GCC ivdep` lets it: their rows arrive as arrays of pointers, which it must otherwise assume
// may overlap, and it left the loops scalar (64 channels at 120x160: 7.5 -> 4.9 ms a layer,
// examples/winograd_layers.rs). No caller overlaps a read row with a written one, except
// wino43_finish in place (in == out), which reads each element before writing it.

// Scratch rows of C floats: out[r] = Bt · in (6 rows) for r in 0..6.
#define RTF_WINO_CLONES __attribute__((target_clones("avx512f", "avx2", "default")))

RTF_WINO_CLONES
void wino43_bt(const float* const in[6], float* const out[6], int64_t c_count) {
#pragma GCC ivdep
  for (int64_t c = 0; c < c_count; ++c) {
    float d0 = in[0][c], d1 = in[1][c], d2 = in[2][c], d3 = in[3][c], d4 = in[4][c],
          d5 = in[5][c];
    out[0][c] = 4.f * d0 - 5.f * d2 + d4;
    out[1][c] = -4.f * d1 - 4.f * d2 + d3 + d4;
    out[2][c] = 4.f * d1 - 4.f * d2 - d3 + d4;
    out[3][c] = -2.f * d1 - d2 + 2.f * d3 + d4;
    out[4][c] = 2.f * d1 - d2 - 2.f * d3 + d4;
    out[5][c] = 4.f * d1 - 5.f * d3 + d5;
  }
}

// out[r] = At · in (6 rows -> 4) for r in 0..4.
RTF_WINO_CLONES
void wino43_at(const float* const in[6], float* const out[4], int64_t c_count) {
#pragma GCC ivdep
  for (int64_t c = 0; c < c_count; ++c) {
    float m0 = in[0][c], m1 = in[1][c], m2 = in[2][c], m3 = in[3][c], m4 = in[4][c],
          m5 = in[5][c];
    out[0][c] = m0 + m1 + m2 + m3 + m4;
    out[1][c] = m1 - m2 + 2.f * (m3 - m4);
    out[2][c] = m1 + m2 + 4.f * (m3 + m4);
    out[3][c] = m1 - m2 + 8.f * (m3 - m4) + m5;
  }
}

// out[r] = A · in (4 rows -> 6; A = Atᵀ) for r in 0..6: the output transform's transpose,
// which carries an output gradient's 4x4 tile into the 6x6 transformed domain.
RTF_WINO_CLONES
void wino43_a(const float* const in[4], float* const out[6], int64_t c_count) {
#pragma GCC ivdep
  for (int64_t c = 0; c < c_count; ++c) {
    float g0 = in[0][c], g1 = in[1][c], g2 = in[2][c], g3 = in[3][c];
    out[0][c] = g0;
    out[1][c] = g0 + g1 + g2 + g3;
    out[2][c] = g0 - g1 + g2 - g3;
    out[3][c] = g0 + 2.f * g1 + 4.f * g2 + 8.f * g3;
    out[4][c] = g0 - 2.f * g1 + 4.f * g2 - 8.f * g3;
    out[5][c] = g3;
  }
}

// out = act(in + bias (+ residual)), c_count floats.
RTF_WINO_CLONES
void wino43_finish(const float* in, const float* bias, const float* residual, bool relu,
                   float* out, int64_t c_count) {
#pragma GCC ivdep
  for (int64_t c = 0; c < c_count; ++c) {
    float v = in[c] + (bias != nullptr ? bias[c] : 0.f) + (residual != nullptr ? residual[c] : 0.f);
    out[c] = relu ? (v > 0.f ? v : 0.f) : v;
  }
}

// bf16 <-> float for maps stored in bf16 (the bf16 inference path on CPUs where fp32 Winograd
// beats oneDNN's bf16 kernels, winograd.rs): a bf16 is the top half of a float, and the way back
// rounds to nearest even, as c10::BFloat16 does (NaN stays a quiet NaN).
RTF_WINO_CLONES
void bf16_to_float(const uint16_t* in, float* out, int64_t count) {
  for (int64_t i = 0; i < count; ++i) {
    uint32_t bits = uint32_t(in[i]) << 16;
    std::memcpy(out + i, &bits, sizeof bits);
  }
}

RTF_WINO_CLONES
void float_to_bf16(const float* in, uint16_t* out, int64_t count) {
  for (int64_t i = 0; i < count; ++i) {
    uint32_t bits;
    std::memcpy(&bits, in + i, sizeof bits);
    uint32_t rounded = (bits + 0x7fffu + ((bits >> 16) & 1u)) >> 16;
    out[i] = in[i] != in[i] ? uint16_t(0x7fc0) : uint16_t(rounded);
  }
}

// An NHWC map of float or bf16 values.
struct NhwcMap {
  const void* data;
  bool bf16;
  // Pixel p's C values as floats: the map's own where float, else converted into `scratch`.
  const float* pixel(int64_t p, int64_t c, float* scratch) const {
    if (!bf16) return static_cast<const float*>(data) + p * c;
    bf16_to_float(static_cast<const uint16_t*>(data) + p * c, scratch, c);
    return scratch;
  }
};

struct Wino43Map {
  NhwcMap x;  // [N, H, W, C]
  int64_t n, h, w, c, k, tiles_h, tiles_w;
};

// V[xi, t, :] for the chunk's tiles [t0, t1) (tile t = (n, i, j) in row-major order).
void wino43_input(const Wino43Map& m, const float* zeros, int64_t t0, int64_t t1, float* v) {
  int64_t chunk = t1 - t0;
  at::parallel_for(t0, t1, 1, [&](int64_t begin, int64_t end) {
    std::vector<float> scratch(36 * m.c);
    std::vector<float> pixels(m.x.bf16 ? 36 * m.c : 0);  // the tile's pixels, where bf16
    for (int64_t t = begin; t < end; ++t) {
      int64_t n = t / (m.tiles_h * m.tiles_w), r = t % (m.tiles_h * m.tiles_w);
      int64_t y0 = 4 * (r / m.tiles_w) - 1, x0 = 4 * (r % m.tiles_w) - 1;
      // Rows: tmp[a][col] = Bt · d[:, col], per column of the tile.
      for (int col = 0; col < 6; ++col) {
        const float* in[6];
        float* out[6];
        for (int row = 0; row < 6; ++row) {
          int64_t y = y0 + row, x = x0 + col;
          bool inside = y >= 0 && y < m.h && x >= 0 && x < m.w;
          float* own = m.x.bf16 ? pixels.data() + (row * 6 + col) * m.c : nullptr;
          in[row] = inside ? m.x.pixel((n * m.h + y) * m.w + x, m.c, own) : zeros;
          out[row] = scratch.data() + (row * 6 + col) * m.c;
        }
        wino43_bt(in, out, m.c);
      }
      // Columns: V[a * 6 + b] = (tmp[a] · B)[b].
      for (int a = 0; a < 6; ++a) {
        const float* in[6];
        float* out[6];
        for (int b = 0; b < 6; ++b) {
          in[b] = scratch.data() + (a * 6 + b) * m.c;
          out[b] = v + ((a * 6 + b) * chunk + (t - t0)) * m.c;
        }
        wino43_bt(in, out, m.c);
      }
    }
  });
}

// Where a chunk's outputs go: act(At M A + bias (+ residual)) into NHWC `y`, float or bf16
// (the residual in the output's type).
struct Wino43Out {
  const float* bias;
  NhwcMap residual;  // data null: none
  bool relu;
  void* y;
  bool bf16;
};

// Writes output pixel p from its K accumulated values `acc` (float scratch of K, overwritten).
void wino43_store(const Wino43Out& o, int64_t p, int64_t k, float* acc, float* scratch) {
  const float* res = o.residual.data != nullptr ? o.residual.pixel(p, k, scratch) : nullptr;
  if (!o.bf16) {
    wino43_finish(acc, o.bias, res, o.relu, static_cast<float*>(o.y) + p * k, k);
    return;
  }
  wino43_finish(acc, o.bias, res, o.relu, acc, k);
  float_to_bf16(acc, static_cast<uint16_t*>(o.y) + p * k, k);
}

// The chunk's outputs from M[xi, t, :].
void wino43_output(const Wino43Map& m, const float* mm, int64_t t0, int64_t t1,
                   const Wino43Out& o) {
  int64_t chunk = t1 - t0;
  at::parallel_for(t0, t1, 1, [&](int64_t begin, int64_t end) {
    std::vector<float> scratch(24 * m.k + 16 * m.k + m.k);
    float* rows = scratch.data();             // [4][6][K]
    float* tile = scratch.data() + 24 * m.k;  // [4][4][K]
    float* residual = tile + 16 * m.k;        // [K], a bf16 residual's pixel
    for (int64_t t = begin; t < end; ++t) {
      int64_t n = t / (m.tiles_h * m.tiles_w), r = t % (m.tiles_h * m.tiles_w);
      int64_t y0 = 4 * (r / m.tiles_w), x0 = 4 * (r % m.tiles_w);
      for (int b = 0; b < 6; ++b) {
        const float* in[6];
        float* out[4];
        for (int a = 0; a < 6; ++a) in[a] = mm + ((a * 6 + b) * chunk + (t - t0)) * m.k;
        for (int a = 0; a < 4; ++a) out[a] = rows + (a * 6 + b) * m.k;
        wino43_at(in, out, m.k);
      }
      for (int a = 0; a < 4; ++a) {
        const float* in[6];
        float* out[4];
        for (int b = 0; b < 6; ++b) in[b] = rows + (a * 6 + b) * m.k;
        for (int b = 0; b < 4; ++b) out[b] = tile + (a * 4 + b) * m.k;
        wino43_at(in, out, m.k);
      }
      for (int a = 0; a < 4 && y0 + a < m.h; ++a) {
        for (int b = 0; b < 4 && x0 + b < m.w; ++b) {
          int64_t p = (n * m.h + y0 + a) * m.w + x0 + b;
          wino43_store(o, p, m.k, tile + (a * 4 + b) * m.k, residual);
        }
      }
    }
  });
}

// act(conv3x3(x) + bias (+ residual)) with U [36, C, K] (float); x, residual channels-last
// [N, C|K, H, W], both float or both bf16 (the sums in float either way); the output in x's type.
at::Tensor wino43_conv(const at::Tensor& x_in, const at::Tensor& u, const at::Tensor* bias,
                       const at::Tensor* residual_in, bool relu) {
  at::NoGradGuard no_grad;
  bool bf16 = x_in.scalar_type() == at::kBFloat16;
  TORCH_CHECK((bf16 || x_in.scalar_type() == at::kFloat) && u.scalar_type() == at::kFloat,
              "winograd F(4x4, 3x3): float32 or bf16 maps, float32 U");
  TORCH_CHECK(u.dim() == 3 && u.size(0) == 36 && u.size(1) == x_in.size(1),
              "winograd F(4x4, 3x3): expected U [36, C, K]");
  TORCH_CHECK(bias == nullptr || bias->scalar_type() == at::kFloat,
              "winograd F(4x4, 3x3): float32 bias");
  TORCH_CHECK(residual_in == nullptr || residual_in->scalar_type() == x_in.scalar_type(),
              "winograd F(4x4, 3x3): the residual in the input's type");
  at::Tensor x = x_in.permute({0, 2, 3, 1}).contiguous();
  at::Tensor u_c = u.contiguous();
  Wino43Map m{{x.data_ptr(), bf16}, x.size(0), x.size(1), x.size(2), x.size(3), u.size(2), 0, 0};
  m.tiles_h = (m.h + 3) / 4;
  m.tiles_w = (m.w + 3) / 4;
  at::Tensor b = bias != nullptr ? bias->contiguous() : at::Tensor();
  at::Tensor res = residual_in != nullptr ? residual_in->permute({0, 2, 3, 1}).contiguous() : at::Tensor();
  at::Tensor y = at::empty({m.n, m.h, m.w, m.k}, x.options());
  at::TensorOptions f32 = x.options().dtype(at::kFloat);
  at::Tensor zeros = at::zeros({m.c}, f32);
  Wino43Out o{b.defined() ? b.data_ptr<float>() : nullptr,
              {res.defined() ? res.data_ptr() : nullptr, bf16}, relu, y.data_ptr(), bf16};
  int64_t tiles = m.n * m.tiles_h * m.tiles_w;
  // V and M of a chunk within ~8 MB each.
  int64_t per_chunk = std::max<int64_t>(16, (8 << 20) / (36 * 4 * std::max(m.c, m.k)));
  at::Tensor v = at::empty({36, std::min(per_chunk, tiles), m.c}, f32);
  at::Tensor mm = at::empty({36, std::min(per_chunk, tiles), m.k}, f32);
  for (int64_t t0 = 0; t0 < tiles; t0 += per_chunk) {
    int64_t t1 = std::min(tiles, t0 + per_chunk), chunk = t1 - t0;
    at::Tensor vc = v.narrow(1, 0, chunk), mc = mm.narrow(1, 0, chunk);
    if (chunk != v.size(1)) {
      vc = at::empty({36, chunk, m.c}, f32);
      mc = at::empty({36, chunk, m.k}, f32);
    }
    wino43_input(m, zeros.data_ptr<float>(), t0, t1, vc.data_ptr<float>());
    at::bmm_out(mc, vc, u_c);
    wino43_output(m, mc.data_ptr<float>(), t0, t1, o);
  }
  return y.permute({0, 3, 1, 2});
}

// Mg[xi, t, :] = (A gy Aᵀ)[xi] for the chunk's tiles [t0, t1) of the float NHWC output
// gradient `gy` (tiles as in wino43_input, with the output's 4x4 grid; zero past the map).
void wino43_grad_tiles(const Wino43Map& m, const float* gy, const float* zeros, int64_t t0,
                       int64_t t1, float* mg) {
  int64_t chunk = t1 - t0;
  at::parallel_for(t0, t1, 1, [&](int64_t begin, int64_t end) {
    std::vector<float> scratch(24 * m.k);  // [6][4][K]
    for (int64_t t = begin; t < end; ++t) {
      int64_t n = t / (m.tiles_h * m.tiles_w), r = t % (m.tiles_h * m.tiles_w);
      int64_t y0 = 4 * (r / m.tiles_w), x0 = 4 * (r % m.tiles_w);
      for (int b = 0; b < 4; ++b) {
        const float* in[4];
        float* out[6];
        for (int a = 0; a < 4; ++a) {
          int64_t y = y0 + a, x = x0 + b;
          in[a] = y < m.h && x < m.w ? gy + ((n * m.h + y) * m.w + x) * m.k : zeros;
        }
        for (int xi = 0; xi < 6; ++xi) out[xi] = scratch.data() + (xi * 4 + b) * m.k;
        wino43_a(in, out, m.k);
      }
      for (int xi = 0; xi < 6; ++xi) {
        const float* in[4];
        float* out[6];
        for (int b = 0; b < 4; ++b) in[b] = scratch.data() + (xi * 4 + b) * m.k;
        for (int eta = 0; eta < 6; ++eta) out[eta] = mg + ((xi * 6 + eta) * chunk + (t - t0)) * m.k;
        wino43_a(in, out, m.k);
      }
    }
  });
}

// The weight gradient [K, C, 3, 3] of a 3x3 convolution (stride 1, padding 1) of float maps,
// from its input x [N, C, H, W] and output gradient gy [N, K, H, W], in F(4x4, 3x3): the
// forward pass is Y = At (U ⊙ V) A per tile with U = G w Gt, so dU[xi] = Σ_t V[xi, t]ᵀ Mg[xi, t]
// (36 products over the tiles, chunked as in wino43_conv) and dw = Gt dU G.
at::Tensor wino43_weight_grad(const at::Tensor& x_in, const at::Tensor& gy_in,
                              const at::Tensor& g) {
  at::NoGradGuard no_grad;
  at::Tensor x = x_in.permute({0, 2, 3, 1}).contiguous();
  at::Tensor gy = gy_in.permute({0, 2, 3, 1}).contiguous();
  Wino43Map m{{x.data_ptr(), false}, x.size(0), x.size(1), x.size(2), x.size(3), gy.size(3), 0, 0};
  m.tiles_h = (m.h + 3) / 4;
  m.tiles_w = (m.w + 3) / 4;
  at::TensorOptions f32 = x.options();
  at::Tensor zeros = at::zeros({std::max(m.c, m.k)}, f32);
  at::Tensor du = at::zeros({36, m.c, m.k}, f32);
  int64_t tiles = m.n * m.tiles_h * m.tiles_w;
  int64_t per_chunk = std::max<int64_t>(16, (8 << 20) / (36 * 4 * std::max(m.c, m.k)));
  for (int64_t t0 = 0; t0 < tiles; t0 += per_chunk) {
    int64_t t1 = std::min(tiles, t0 + per_chunk), chunk = t1 - t0;
    at::Tensor v = at::empty({36, chunk, m.c}, f32), mg = at::empty({36, chunk, m.k}, f32);
    wino43_input(m, zeros.data_ptr<float>(), t0, t1, v.data_ptr<float>());
    wino43_grad_tiles(m, gy.data_ptr<float>(), zeros.data_ptr<float>(), t0, t1,
                      mg.data_ptr<float>());
    du.baddbmm_(v.transpose(1, 2), mg);
  }
  return at::einsum("ai,abck,bj->kcij", {g, du.view({6, 6, m.c, m.k}), g});
}

// U = G w Gt per channel pair: [K, C, 3, 3] -> [36, C, K] (winograd.rs `weight_transform`, with
// its G for F(4x4, 3x3) passed in as `g` [6, 3]).
at::Tensor wino43_weight(const at::Tensor& w, const at::Tensor& g) {
  return at::einsum("ai,kcij,bj->abck", {g, w.to(at::kFloat), g})
      .reshape({36, w.size(1), w.size(0)})
      .contiguous();
}

// A 3x3 convolution (stride 1, padding 1, no bias, float32) for training, all three passes in
// F(4x4, 3x3): the forward pass, and the input's gradient, a 3x3 convolution of the output's
// gradient with the weight flipped and its channel axes swapped, both by wino43_conv; the
// weight's gradient by wino43_weight_grad. `g` is the form's G [6, 3]; the transformed weights
// are made from `w` in each pass, not kept.
struct Winograd43Convolution : public torch::autograd::Function<Winograd43Convolution> {
  static at::Tensor forward(AutogradContext* ctx, const at::Tensor& x, const at::Tensor& w,
                            const at::Tensor& g) {
    ctx->save_for_backward({x, w, g});
    return wino43_conv(x, wino43_weight(w, g), nullptr, nullptr, false);
  }

  static variable_list backward(AutogradContext* ctx, variable_list grads) {
    auto saved = ctx->get_saved_variables();
    const at::Tensor &x = saved[0], &w = saved[1], &g = saved[2];
    at::Tensor gx, gw;
    if (ctx->needs_input_grad(0)) {
      // [K, C, 3, 3] -> [C, K, 3, 3], taps reversed
      at::Tensor w_back = w.flip({2, 3}).transpose(0, 1);
      gx = wino43_conv(grads[0], wino43_weight(w_back, g), nullptr, nullptr, false);
    }
    if (ctx->needs_input_grad(1)) {
      gw = wino43_weight_grad(x, grads[0], g);
    }
    return {gx, gw, at::Tensor()};
  }
};
// The operator counter (`rtf_op_counter_start` / `_stop`): every ATen operator and autograd
// node the dispatcher and the engine record (RecordFunction, the events torch.profiler
// counts), by name: how many in all, and how many at the outermost level (not called from
// another recorded one on the same thread).
struct OpCount {
  int64_t all = 0;
  int64_t outermost = 0;
};
std::mutex op_counts_mutex;
std::map<std::string, OpCount> op_counts;
thread_local int op_depth = 0;

std::unique_ptr<at::ObserverContext> count_op_start(const at::RecordFunction& fn) {
  {
    std::lock_guard<std::mutex> lock(op_counts_mutex);
    OpCount& count = op_counts[fn.name()];
    count.all += 1;
    count.outermost += op_depth == 0 ? 1 : 0;
  }
  op_depth += 1;
  return nullptr;
}

void count_op_end(const at::RecordFunction&, at::ObserverContext*) {
  op_depth -= 1;
}

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

// One SGD step of each of the `n` `params` (PyTorch's rules, no dampening or Nesterov) in ATen's
// fused kernel, all in one call (on CUDA a multi-tensor kernel: a few launches for the lot,
// not one per tensor): g = grad + weight_decay·param; buf = g on the first step, else
// momentum·buf + g; param -= lr·buf. Each `bufs[i]` is shaped like `params[i]`; with momentum 0
// `bufs` is not read (may be null). All on one device, of one type.
char* rtf_fused_sgd(at::Tensor** params, at::Tensor** grads, at::Tensor** bufs, int64_t n,
                    double weight_decay, double momentum, double lr, int is_first_step) {
  try {
    at::NoGradGuard no_grad;
    std::vector<at::Tensor> param_list, grad_list, buf_list;
    for (int64_t i = 0; i < n; ++i) {
      param_list.push_back(*params[i]);
      grad_list.push_back(*grads[i]);
      if (momentum != 0.0) {
        buf_list.push_back(*bufs[i]);
      }
    }
    at::_fused_sgd_(param_list, grad_list, buf_list, weight_decay, momentum, lr,
                    /*dampening=*/0.0, /*nesterov=*/false, /*maximize=*/false, is_first_step != 0);
    return nullptr;
  } catch (const std::exception& e) {
    return strdup(e.what());
  } catch (...) {
    return strdup("unknown C++ exception in rtf_fused_sgd");
  }
}

// One AdamW step of each of the `n` `params` (PyTorch's `torch.optim.AdamW(fused=True)`, no
// amsgrad) in ATen's fused kernel, all in one call (on CUDA a multi-tensor kernel): each step
// count in `steps` (a one-element float tensor on the parameter's device) goes up by one, then
// p *= 1 - lr·weight_decay; m = lerp(m, g, 1 - beta1); v = beta2·v + (1 - beta2)·g²;
// p -= lr / (1 - beta1^t) · m / (sqrt(v) / sqrt(1 - beta2^t) + eps). `exp_avgs[i]` and
// `exp_avg_sqs[i]` are shaped and laid out like `params[i]`. All on one device, of one type.
char* rtf_fused_adamw(at::Tensor** params, at::Tensor** grads, at::Tensor** exp_avgs,
                      at::Tensor** exp_avg_sqs, at::Tensor** steps, int64_t n, double lr,
                      double beta1, double beta2, double weight_decay, double eps) {
  try {
    at::NoGradGuard no_grad;
    std::vector<at::Tensor> param_list, grad_list, m_list, v_list, step_list;
    for (int64_t i = 0; i < n; ++i) {
      param_list.push_back(*params[i]);
      grad_list.push_back(*grads[i]);
      m_list.push_back(*exp_avgs[i]);
      v_list.push_back(*exp_avg_sqs[i]);
      step_list.push_back(*steps[i]);
    }
    at::_foreach_add_(step_list, 1);
    at::_fused_adamw_(param_list, grad_list, m_list, v_list, /*max_exp_avg_sqs=*/{}, step_list, lr,
                      beta1, beta2, weight_decay, eps, /*amsgrad=*/false, /*maximize=*/false);
    return nullptr;
  } catch (const std::exception& e) {
    return strdup(e.what());
  } catch (...) {
    return strdup("unknown C++ exception in rtf_fused_adamw");
  }
}

// Zeroes the gradients of the `n` `params`, as PyTorch's `Optimizer.zero_grad(set_to_none=False)`
// does: a gradient with a history is detached, one without stops requiring grad, then one
// `_foreach_zero_` per device and type (on CUDA a few launches for the lot, not one per tensor).
// Parameters without a gradient are left alone.
char* rtf_zero_grads(at::Tensor** params, int64_t n) {
  try {
    std::map<std::tuple<int, int, int>, std::vector<at::Tensor>> groups;
    for (int64_t i = 0; i < n; ++i) {
      at::Tensor& grad = params[i]->mutable_grad();
      if (!grad.defined()) {
        continue;
      }
      if (grad.grad_fn()) {
        grad.detach_();
      } else {
        grad.requires_grad_(false);
      }
      auto key = std::make_tuple(static_cast<int>(grad.device().type()),
                                 static_cast<int>(grad.device().index()),
                                 static_cast<int>(grad.scalar_type()));
      groups[key].push_back(grad);
    }
    for (auto& [key, grads] : groups) {
      at::_foreach_zero_(grads);
    }
    return nullptr;
  } catch (const std::exception& e) {
    return strdup(e.what());
  } catch (...) {
    return strdup("unknown C++ exception in rtf_zero_grads");
  }
}

// `*out` = the convolution weight `w` (float or bf16, dense) reordered once into the blocked
// layout oneDNN's convolution kernels read, as an MKLDNN tensor: a `_convolution_pointwise`
// given it skips the reorder it otherwise makes of a dense weight on every call. No input size
// is given, so oneDNN assumes one; for k×k kernels with k > 1 its layout is the one the kernels
// pick at every size measured (docs/src/models.md), for 1×1 kernels it is not (callers keep
// those dense). Geometry arrays hold (H, W) pairs.
char* rtf_pack_conv_weight(at::Tensor* w, const int64_t* padding, const int64_t* stride,
                           const int64_t* dilation, int64_t groups, at::Tensor** out) {
  try {
    *out = nullptr;
    at::NoGradGuard no_grad;
    at::Tensor mkldnn = w->contiguous().to_mkldnn();
    at::Tensor packed = at::mkldnn_reorder_conv2d_weight(
        mkldnn, {padding[0], padding[1]}, {stride[0], stride[1]}, {dilation[0], dilation[1]},
        groups, std::nullopt);
    *out = new at::Tensor(std::move(packed));
    return nullptr;
  } catch (const std::exception& e) {
    return strdup(e.what());
  } catch (...) {
    return strdup("unknown C++ exception in rtf_pack_conv_weight");
  }
}

// `*out` = act(conv3x3(x) + b (+ residual)) by Winograd F(4x4, 3x3) with the transformed weight
// `u` [36, C, K] (see wino43_conv); b and residual may be NULL; relu != 0 applies a ReLU.
char* rtf_winograd43_conv(at::Tensor* x, at::Tensor* u, at::Tensor* b, at::Tensor* residual,
                          int relu, at::Tensor** out) {
  try {
    *out = nullptr;
    *out = new at::Tensor(wino43_conv(*x, *u, b, residual, relu != 0));
    return nullptr;
  } catch (const std::exception& e) {
    return strdup(e.what());
  } catch (...) {
    return strdup("unknown C++ exception in rtf_winograd43_conv");
  }
}

// `*out` = conv3x3(x, w) (stride 1, padding 1, no bias) for training, differentiable, by
// Winograd F(4x4, 3x3) (see Winograd43Convolution); `g` is the form's G [6, 3].
char* rtf_winograd43_train_conv(at::Tensor* x, at::Tensor* w, at::Tensor* g, at::Tensor** out) {
  try {
    *out = nullptr;
    *out = new at::Tensor(Winograd43Convolution::apply(*x, *w, *g));
    return nullptr;
  } catch (const std::exception& e) {
    return strdup(e.what());
  } catch (...) {
    return strdup("unknown C++ exception in rtf_winograd43_train_conv");
  }
}

// How many hold `t`: `*handles`, the `at::Tensor` handles on its TensorImpl (a shallow copy,
// or an op that returns its input unchanged, adds one); `*storage_users`, the TensorImpls on
// its storage (a view adds one); 0 for a tensor without storage. What the fast path's release
// of the plain weights compares before and after folding (fast.rs).
char* rtf_tensor_holders(at::Tensor* t, int64_t* handles, int64_t* storage_users) {
  try {
    *handles = static_cast<int64_t>(t->use_count());
    *storage_users = t->has_storage() ? static_cast<int64_t>(t->storage().use_count()) : 0;
    return nullptr;
  } catch (const std::exception& e) {
    return strdup(e.what());
  } catch (...) {
    return strdup("unknown C++ exception in rtf_tensor_holders");
  }
}

// Starts counting the operators this thread runs (see OpCount; the autograd engine carries the
// callback to the threads that run a backward for it), from zero; `*handle` is for
// `rtf_op_counter_stop`, on the same thread.
char* rtf_op_counter_start(uint64_t* handle) {
  try {
    {
      std::lock_guard<std::mutex> lock(op_counts_mutex);
      op_counts.clear();
    }
    *handle = at::addThreadLocalCallback(
        at::RecordFunctionCallback(count_op_start, count_op_end)
            .scopes({at::RecordScope::FUNCTION, at::RecordScope::BACKWARD_FUNCTION}));
    return nullptr;
  } catch (const std::exception& e) {
    return strdup(e.what());
  } catch (...) {
    return strdup("unknown C++ exception in rtf_op_counter_start");
  }
}

// Stops counting; `*table` = one malloc'd line per operator, "name\tall\toutermost\n"
// (freed with rtf_ops_free_error).
char* rtf_op_counter_stop(uint64_t handle, char** table) {
  try {
    *table = nullptr;
    at::removeCallback(handle);
    std::ostringstream out;
    std::lock_guard<std::mutex> lock(op_counts_mutex);
    for (const auto& [name, count] : op_counts) {
      out << name << '\t' << count.all << '\t' << count.outermost << '\n';
    }
    op_counts.clear();
    *table = strdup(out.str().c_str());
    return nullptr;
  } catch (const std::exception& e) {
    return strdup(e.what());
  } catch (...) {
    return strdup("unknown C++ exception in rtf_op_counter_stop");
  }
}

void rtf_ops_free_error(char* error) {
  free(error);
}

}  // extern "C"
