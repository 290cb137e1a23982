// C entry points over libtorch's thread-local autocast state, for every device type: tch 0.26
// exposes only the CUDA one (at_autocast_set_enabled drives at::autocast::set_enabled).
//
// The declarations are those of ATen/autocast_mode.h (libtorch 2.x); the header itself pulls in
// all of ATen, so they are restated here. A changed signature fails at link time (the mangled
// names carry the parameter types).
//
// Every function catches C++ exceptions and reports them as a non-zero status (never lets one
// cross into Rust).
#include <c10/core/DeviceType.h>
#include <c10/core/ScalarType.h>
#include <c10/macros/Export.h>

#include <exception>

namespace at::autocast {
TORCH_API bool is_autocast_enabled(c10::DeviceType device_type);
TORCH_API void set_autocast_enabled(c10::DeviceType device_type, bool enabled);
TORCH_API c10::ScalarType get_autocast_dtype(c10::DeviceType device_type);
TORCH_API void set_autocast_dtype(c10::DeviceType device_type, c10::ScalarType dtype);
TORCH_API void clear_cache();
TORCH_API int increment_nesting();
TORCH_API int decrement_nesting();
}  // namespace at::autocast

extern "C" {

// The state of `device_type`'s autocast: *enabled (0/1) and *dtype (a c10::ScalarType code).
int rtf_amp_get(int device_type, int* enabled, int* dtype) {
  try {
    auto device = static_cast<c10::DeviceType>(device_type);
    *enabled = at::autocast::is_autocast_enabled(device) ? 1 : 0;
    *dtype = static_cast<int>(at::autocast::get_autocast_dtype(device));
    return 0;
  } catch (...) {
    return 1;
  }
}

// Sets `device_type`'s autocast state (the value torch.autocast sets on entry and restores on
// exit).
int rtf_amp_set(int device_type, int enabled, int dtype) {
  try {
    auto device = static_cast<c10::DeviceType>(device_type);
    at::autocast::set_autocast_dtype(device, static_cast<c10::ScalarType>(dtype));
    at::autocast::set_autocast_enabled(device, enabled != 0);
    return 0;
  } catch (...) {
    return 1;
  }
}

// Entering an autocast region: one level deeper.
int rtf_amp_enter() {
  try {
    at::autocast::increment_nesting();
    return 0;
  } catch (...) {
    return 1;
  }
}

// Leaving one: the cache of casted weights is dropped when the outermost region ends (as
// torch.autocast.__exit__ does).
int rtf_amp_exit() {
  try {
    if (at::autocast::decrement_nesting() == 0) {
      at::autocast::clear_cache();
    }
    return 0;
  } catch (...) {
    return 1;
  }
}

}  // extern "C"
