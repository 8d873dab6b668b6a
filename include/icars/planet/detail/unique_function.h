// A move-only std::function (std::move_only_function is C++23). Private: not part of the API.
#pragma once

#include <memory>
#include <utility>

namespace icars::planet::detail {

template <class Signature>
class UniqueFunction;

template <class R, class... A>
class UniqueFunction<R(A...)> {
 public:
  UniqueFunction() = default;
  template <class F>
  UniqueFunction(F f) : impl_(std::make_unique<Impl<F>>(std::move(f))) {}  // NOLINT: implicit

  explicit operator bool() const { return impl_ != nullptr; }
  R operator()(A... args) { return impl_->call(std::forward<A>(args)...); }

 private:
  struct Base {
    virtual ~Base() = default;
    virtual R call(A... args) = 0;
  };
  template <class F>
  struct Impl final : Base {
    explicit Impl(F fn) : f(std::move(fn)) {}
    R call(A... args) override { return f(std::forward<A>(args)...); }
    F f;
  };
  std::unique_ptr<Base> impl_;
};

}  // namespace icars::planet::detail
