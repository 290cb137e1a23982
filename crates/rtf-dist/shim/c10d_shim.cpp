// C ABI over PyTorch's c10d process groups (TCPStore rendezvous, gloo on CPU, NCCL on CUDA),
// for rtf-dist's Rust side. Tensors arrive as `torch::Tensor*`, which is what tch's `C_tensor*`
// is in torch-sys's C++ (libtch/torch_api.h). Every entry point catches every C++ exception and
// returns it as a malloc'd message (NULL = success): nothing unwinds across the FFI boundary.

#include <chrono>
#include <cstdlib>
#include <cstring>
#include <exception>
#include <string>
#include <vector>

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

char* rtf_c10d_barrier(void* group) {
  return guarded([&] {
    auto g = static_cast<Group*>(group);
    c10d::BarrierOptions opts;
    opts.timeout = g->timeout;
    finish(g->backend->barrier(opts), g->timeout);
  });
}

} // extern "C"
