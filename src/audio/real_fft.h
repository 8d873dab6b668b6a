// A real-to-complex FFT of one size and its inverse (FFTW, single precision), for the audio
// layer's own code (direction, acoustics). Private: not installed.
#pragma once

#include <fftw3.h>

#include <complex>
#include <cstddef>
#include <mutex>
#include <new>
#include <span>

namespace icars::audio::detail {

// FFTW's planner keeps global state and is not thread-safe (only fftwf_execute is): every plan
// of the process is made and destroyed under this one lock.
inline std::mutex& fftw_planner_mutex() {
  static std::mutex mutex;
  return mutex;
}

class RealFft {
 public:
  explicit RealFft(std::size_t n) : n_(n) {
    time_ = static_cast<float*>(fftwf_malloc(sizeof(float) * n_));
    spectrum_ = static_cast<fftwf_complex*>(fftwf_malloc(sizeof(fftwf_complex) * bins()));
    if (time_ == nullptr || spectrum_ == nullptr) {
      release();
      throw std::bad_alloc();
    }
    std::lock_guard lock(fftw_planner_mutex());
    const int size = static_cast<int>(n_);
    forward_ = fftwf_plan_dft_r2c_1d(size, time_, spectrum_, FFTW_ESTIMATE);
    inverse_ = fftwf_plan_dft_c2r_1d(size, spectrum_, time_, FFTW_ESTIMATE);
  }
  ~RealFft() { release(); }
  RealFft(const RealFft&) = delete;
  RealFft& operator=(const RealFft&) = delete;

  std::size_t size() const { return n_; }
  std::size_t bins() const { return n_ / 2 + 1; }

  // `in` (at most size() values, zero-padded to size()) → bins() complex values.
  void forward(std::span<const float> in, std::span<std::complex<float>> out) {
    std::size_t i = 0;
    for (; i < in.size() && i < n_; ++i) time_[i] = in[i];
    for (; i < n_; ++i) time_[i] = 0.0f;
    fftwf_execute(forward_);
    const auto* s = reinterpret_cast<const std::complex<float>*>(spectrum_);
    for (std::size_t k = 0; k < bins() && k < out.size(); ++k) out[k] = s[k];
  }

  // bins() complex values → size() real values, unnormalised (n times the true inverse).
  void inverse(std::span<const std::complex<float>> in, std::span<float> out) {
    auto* s = reinterpret_cast<std::complex<float>*>(spectrum_);
    for (std::size_t k = 0; k < bins(); ++k) s[k] = k < in.size() ? in[k] : 0.0f;
    fftwf_execute(inverse_);  // destroys spectrum_, which is ours
    for (std::size_t i = 0; i < n_ && i < out.size(); ++i) out[i] = time_[i];
  }

 private:
  void release() {
    {
      std::lock_guard lock(fftw_planner_mutex());
      if (forward_ != nullptr) fftwf_destroy_plan(forward_);
      if (inverse_ != nullptr) fftwf_destroy_plan(inverse_);
    }
    fftwf_free(time_);
    fftwf_free(spectrum_);
  }

  std::size_t n_;
  float* time_ = nullptr;
  fftwf_complex* spectrum_ = nullptr;
  fftwf_plan forward_ = nullptr;
  fftwf_plan inverse_ = nullptr;
};

// The smallest power of two at least n.
inline std::size_t fft_size_for(std::size_t n) {
  std::size_t size = 1;
  while (size < n) size *= 2;
  return size;
}

}  // namespace icars::audio::detail
