// C ABI over PyTorch's c10d process groups (TCPStore rendezvous, gloo on CPU, NCCL on CUDA),
// for rtf-dist's Rust side. Tensors arrive as `torch::Tensor*`, which is what tch's `C_tensor*`
// is in torch-sys's C++ (libtch/torch_api.h). Every entry point catches every C++ exception and
// returns it as a malloc'd message (NULL = success): nothing unwinds across the FFI boundary.

#include <atomic>
#include <chrono>
#include <cstdlib>
#include <cstring>
#include <exception>
#include <mutex>
#include <string>
#include <vector>

#include <torch/autograd.h>
#include <torch/torch.h>

#define USE_C10D_GLOO 1
#include <torch/csrc/distributed/c10d/Backend.hpp>
#include <torch/csrc/distributed/c10d/PrefixStore.hpp>
#include <torch/csrc/distributed/c10d/ProcessGroupGloo.hpp>
#include <torch/csrc/distributed/c10d/TCPStore.hpp>
#include <torch/csrc/distributed/c10d/Types.hpp>
#include <torch/csrc/distributed/c10d/Work.hpp>

#ifdef RTF_DIST_NCCL
#define USE_C10D_NCCL 1
#include <c10/cuda/CUDAFunctions.h>
#include <torch/csrc/distributed/c10d/ProcessGroupNCCL.hpp>
#endif

namespace {

struct Group {
  c10::intrusive_ptr<c10d::Store> store;
  c10::intrusive_ptr<c10d::Backend> backend;
  std::chrono::milliseconds timeout;
  // A collective that failed inside autograd's backward (which cannot return an error to
  // Rust): the first message, taken by `rtf_c10d_take_backward_error`. Once set, the
  // differentiable all-reduce stops communicating, so a dead peer costs one timeout, not one
  // per layer.
  std::atomic<bool> broken{false};
  std::mutex error_mutex;
  std::string backward_error;
};

char* message(const std::string& what) {
  return strdup(what.c_str());
}

template <typename F>
char* guarded(F&& body) {
  try {
    body();
    return nullptr;
  } catch (const c10::Error& e) {
    return message(e.what_without_backtrace());
  } catch (const std::exception& e) {
    return message(e.what());
  } catch (...) {
    return message("unknown C++ exception in the c10d shim");
  }
}

void finish(const c10::intrusive_ptr<c10d::Work>& work, std::chrono::milliseconds timeout) {
  // Work::wait throws when the collective failed (a peer died, the timeout passed).
  if (!work->wait(timeout)) {
    throw std::runtime_error("collective did not complete within the timeout");
  }
}

void allreduce_sum(Group* g, at::Tensor& t) {
  std::vector<at::Tensor> tensors{t};
  c10d::AllreduceOptions opts;
  opts.reduceOp = c10d::ReduceOp::SUM;
  opts.timeout = g->timeout;
  finish(g->backend->allreduce(tensors, opts), g->timeout);
}

// y = Σ_ranks x, differentiable: every rank's y depends on every rank's x, so the gradient of
// x is the sum over the ranks of the gradients of y (the backward is an all-reduce too). This is
// what synchronised BatchNorm's statistics need (torch.nn.SyncBatchNorm reduces them the same
// way, in its own backward).
struct AllReduceSum : public torch::autograd::Function<AllReduceSum> {
  static at::Tensor forward(torch::autograd::AutogradContext* ctx, at::Tensor x, int64_t group) {
    ctx->saved_data["group"] = group;
    auto g = reinterpret_cast<Group*>(group);
    auto y = x.contiguous().clone();
    if (g->broken.load()) {
      throw std::runtime_error("an earlier collective of this step failed");
    }
    try {
      allreduce_sum(g, y);
    } catch (...) {
      // The backward of the all-reduces already in the graph must not wait on the peers.
      g->broken.store(true);
      throw;
    }
    return y;
  }

  static torch::autograd::variable_list backward(
      torch::autograd::AutogradContext* ctx,
      torch::autograd::variable_list grads) {
    auto g = reinterpret_cast<Group*>(ctx->saved_data["group"].toInt());
    auto grad = grads[0].contiguous().clone();
    if (!g->broken.load()) {
      try {
        allreduce_sum(g, grad);
      } catch (const std::exception& e) {
        // Keep the local gradient; the step is abandoned once Rust reads the error.
        std::lock_guard<std::mutex> lock(g->error_mutex);
        if (!g->broken.exchange(true)) {
          g->backward_error = e.what();
        }
      }
    }
    return {grad, at::Tensor()};
  }
};

} // namespace

extern "C" {

char* rtf_c10d_new(
    const char* addr,
    uint16_t port,
    int rank,
    int world,
    int store_is_server,
    const char* prefix,
    int64_t timeout_ms,
    int nccl,
    int device_index,
    void** out) {
  return guarded([&] {
    *out = nullptr;
    auto timeout = std::chrono::milliseconds(timeout_ms);
    c10d::TCPStoreOptions opts;
    opts.port = port;
    opts.isServer = store_is_server != 0;
    opts.numWorkers = static_cast<std::size_t>(world);
    opts.waitWorkers = false;
    opts.timeout = timeout;
    opts.multiTenant = true;
    c10::intrusive_ptr<c10d::Store> tcp =
        c10::make_intrusive<c10d::TCPStore>(std::string(addr), opts);
    auto store = c10::make_intrusive<c10d::PrefixStore>(std::string(prefix), tcp);
    c10::intrusive_ptr<c10d::Backend> backend;
    if (nccl != 0) {
#ifdef RTF_DIST_NCCL
      c10::cuda::set_device(static_cast<c10::DeviceIndex>(device_index));
      auto options = c10d::ProcessGroupNCCL::Options::create();
      options->timeout = timeout;
      backend = c10::make_intrusive<c10d::ProcessGroupNCCL>(store, rank, world, options);
#else
      (void)device_index;
      throw std::runtime_error(
          "this build of rtf has no NCCL support (build rtf-dist with the `nccl` feature)");
#endif
    } else {
      // Devices as torch.distributed picks them: GLOO_SOCKET_IFNAME, else this host's name.
      auto options = c10d::ProcessGroupGloo::Options::create_default(timeout);
      backend = c10::make_intrusive<c10d::ProcessGroupGloo>(store, rank, world, options);
    }
    *out = new Group{store, backend, timeout};
  });
}

void rtf_c10d_free(void* group) {
  try {
    delete static_cast<Group*>(group);
  } catch (...) {
  }
}

void rtf_c10d_free_error(char* error) {
  free(error);
}

// In-place sum over all ranks of `tensor`.
char* rtf_c10d_allreduce_sum(void* group, torch::Tensor* tensor) {
  return guarded([&] {
    auto g = static_cast<Group*>(group);
    std::vector<at::Tensor> tensors{*tensor};
    c10d::AllreduceOptions opts;
    opts.reduceOp = c10d::ReduceOp::SUM;
    opts.timeout = g->timeout;
    finish(g->backend->allreduce(tensors, opts), g->timeout);
  });
}

// In-place broadcast of `root`'s `tensor`.
char* rtf_c10d_broadcast(void* group, torch::Tensor* tensor, int root) {
  return guarded([&] {
    auto g = static_cast<Group*>(group);
    std::vector<at::Tensor> tensors{*tensor};
    c10d::BroadcastOptions opts;
    opts.rootRank = root;
    opts.timeout = g->timeout;
    finish(g->backend->broadcast(tensors, opts), g->timeout);
  });
}

// `*out` = Σ_ranks `tensor` as a new tensor whose gradient is all-reduced in the backward.
char* rtf_c10d_allreduce_sum_autograd(void* group, torch::Tensor* tensor, torch::Tensor** out) {
  return guarded([&] {
    *out = nullptr;
    auto y = AllReduceSum::apply(*tensor, reinterpret_cast<int64_t>(group));
    *out = new torch::Tensor(y);
  });
}

// The first failure of a collective inside a backward pass since the last call (NULL: none).
char* rtf_c10d_take_backward_error(void* group) {
  auto g = static_cast<Group*>(group);
  std::lock_guard<std::mutex> lock(g->error_mutex);
  if (!g->broken.load() || g->backward_error.empty()) {
    return nullptr;
  }
  auto error = message(g->backward_error);
  g->backward_error.clear();
  return error;
}

char* rtf_c10d_barrier(void* group) {
  return guarded([&] {
    auto g = static_cast<Group*>(group);
    c10d::BarrierOptions opts;
    opts.timeout = g->timeout;
    finish(g->backend->barrier(opts), g->timeout);
  });
}

} // extern "C"
