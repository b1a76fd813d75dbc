// Autocast (mixed precision: matmuls and convolutions in a lower precision,
// the rest float32) switched for a scope; the previous state comes back at
// its end. AutocastOn is what the trainer's mixed precision runs the forward
// pass under; AutocastOff is how the model keeps parts of it in float32.
#pragma once

#include <ATen/autocast_mode.h>
#include <c10/core/DeviceType.h>
#include <c10/core/ScalarType.h>

namespace long3r {

class AutocastOn {
 public:
  // `device`: autocast of the CPU or of CUDA; `dtype`: at::kBFloat16 (or
  // at::kHalf on CUDA).
  AutocastOn(c10::DeviceType device, at::ScalarType dtype) : cuda_(device == c10::kCUDA) {
    if (cuda_) {
      prev_enabled_ = at::autocast::is_enabled();
      prev_dtype_ = at::autocast::get_autocast_gpu_dtype();
      at::autocast::set_enabled(true);
      at::autocast::set_autocast_gpu_dtype(dtype);
    } else {
      prev_enabled_ = at::autocast::is_cpu_enabled();
      prev_dtype_ = at::autocast::get_autocast_cpu_dtype();
      at::autocast::set_cpu_enabled(true);
      at::autocast::set_autocast_cpu_dtype(dtype);
    }
    at::autocast::increment_nesting();
  }
  ~AutocastOn() {
    // The cast weights are cached for the outermost scope only.
    if (at::autocast::decrement_nesting() == 0) at::autocast::clear_cache();
    if (cuda_) {
      at::autocast::set_enabled(prev_enabled_);
      at::autocast::set_autocast_gpu_dtype(prev_dtype_);
    } else {
      at::autocast::set_cpu_enabled(prev_enabled_);
      at::autocast::set_autocast_cpu_dtype(prev_dtype_);
    }
  }
  AutocastOn(const AutocastOn&) = delete;
  AutocastOn& operator=(const AutocastOn&) = delete;

 private:
  bool cuda_;
  bool prev_enabled_ = false;
  at::ScalarType prev_dtype_ = at::kFloat;
};

class AutocastOff {
 public:
  AutocastOff() : gpu_(at::autocast::is_enabled()), cpu_(at::autocast::is_cpu_enabled()) {
    at::autocast::set_enabled(false);
    at::autocast::set_cpu_enabled(false);
  }
  ~AutocastOff() {
    at::autocast::set_enabled(gpu_);
    at::autocast::set_cpu_enabled(cpu_);
  }
  AutocastOff(const AutocastOff&) = delete;
  AutocastOff& operator=(const AutocastOff&) = delete;
  // Whether autocast was on (CPU or CUDA) when the scope began.
  bool was_on() const { return gpu_ || cpu_; }

 private:
  bool gpu_, cpu_;
};

}  // namespace long3r
