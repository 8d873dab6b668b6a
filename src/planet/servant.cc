#include "icars/planet/servant.h"

#include <fmt/format.h>

#include <mutex>
#include <stdexcept>

namespace icars::planet {

namespace detail {

void fail_argument(Reader& r, std::string_view method, std::size_t index,
                   std::span<const std::byte> expected, std::span<const std::byte> actual) {
  r.fail(fmt::format("argument {} of '{}': expected {}, got {}", index, method,
                     describe(expected), describe(actual)));
}

void fail_arity(Reader& r, std::string_view method, std::size_t expected, std::size_t actual) {
  r.fail(fmt::format("'{}' takes {} argument{}, got {}", method, expected,
                     expected == 1 ? "" : "s", actual));
}

}  // namespace detail

std::optional<Servant::AsyncResult> Servant::dispatch(std::string_view method, Reader& args,
                                                      Writer* result, const Current& current) {
  auto it = methods_.find(method);
  if (it == methods_.end()) {
    throw Error(ErrorKind::unimplemented,
                fmt::format("servant at '{}' ({}) has no method '{}'", current.path, type_id_,
                            method));
  }
  return it->second(args, result, current);
}

void ObjectAdapter::add(const std::string& path, std::shared_ptr<Servant> servant) {
  if (path.empty() || path.front() != '/') {
    throw std::invalid_argument(fmt::format("servant path '{}' must start with '/'", path));
  }
  if (!servant) throw std::invalid_argument("null servant for path " + path);
  std::unique_lock lock(mutex_);
  if (!servants_.emplace(path, std::move(servant)).second) {
    throw std::invalid_argument(fmt::format("a servant is already registered at '{}'", path));
  }
}

bool ObjectAdapter::remove(std::string_view path) {
  std::unique_lock lock(mutex_);
  auto it = servants_.find(path);
  if (it == servants_.end()) return false;
  servants_.erase(it);
  return true;
}

std::shared_ptr<Servant> ObjectAdapter::find(std::string_view path) const {
  std::shared_lock lock(mutex_);
  auto it = servants_.find(path);
  return it == servants_.end() ? nullptr : it->second;
}

std::vector<std::string> ObjectAdapter::paths() const {
  std::shared_lock lock(mutex_);
  std::vector<std::string> out;
  for (const auto& [path, s] : servants_) out.push_back(path);
  return out;
}

}  // namespace icars::planet
