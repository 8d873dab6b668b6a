#include "icars/planet/serializer.h"

#include <fmt/format.h>

#include <algorithm>
#include <cstring>
#include <limits>

#include "buffer_pool.h"

namespace icars::planet {

void Writer::raw_large(std::span<const std::byte> bytes) {
  const std::size_t needed = out_->size() + bytes.size();
  if (out_->capacity() < needed) {
    std::vector<std::byte> bigger = detail::take_buffer(needed);
    bigger.insert(bigger.end(), out_->begin(), out_->end());
    out_->swap(bigger);
    detail::give_buffer(std::move(bigger));
  }
  out_->insert(out_->end(), bytes.begin(), bytes.end());
}

void detail::recycle(Binary& value) { detail::give_buffer(std::move(value.bytes)); }

std::vector<std::byte> detail::copy_bytes(std::span<const std::byte> bytes) {
  if (bytes.size() < detail::kPooledBufferBytes) return {bytes.begin(), bytes.end()};
  std::vector<std::byte> copy = detail::take_buffer(bytes.size());
  copy.insert(copy.end(), bytes.begin(), bytes.end());
  return copy;
}

void Writer::length(std::size_t n) {
  if (n > std::numeric_limits<std::uint32_t>::max()) {
    throw Error(ErrorKind::bad_data, fmt::format("length {} does not fit the u32 length field", n));
  }
  u32(static_cast<std::uint32_t>(n));
}

std::size_t Reader::count(std::size_t min_item_size, const char* what) {
  const std::uint32_t n = u32();
  if (min_item_size != 0 && n > remaining() / min_item_size) {
    fail(fmt::format("{} length {} exceeds the {} bytes left in the message", what, n,
                     remaining()));
  }
  return n;
}

Reader::Reader(std::span<const std::vector<std::byte>> blocks) : blocks_(blocks) {
  for (const auto& b : blocks) size_ += b.size();
  if (!blocks_.empty()) bytes_ = blocks_.front();
}

void Reader::next_block() {
  base_ += bytes_.size();
  pos_ = 0;
  bytes_ = blocks_[++block_];
}

void Reader::copy_out(std::byte* to, std::size_t n) {
  while (n > 0) {
    while (pos_ == bytes_.size()) next_block();  // n <= remaining(): a block with bytes follows
    const std::size_t here = std::min(n, bytes_.size() - pos_);
    std::memcpy(to, bytes_.data() + pos_, here);
    to += here;
    pos_ += here;
    n -= here;
  }
}

const std::byte* Reader::take_across(std::size_t n, const char* what) {
  if (n > remaining()) underflow(n, what);
  while (pos_ == bytes_.size() && block_ + 1 < blocks_.size()) next_block();
  if (n <= bytes_.size() - pos_) {
    const std::byte* p = bytes_.data() + pos_;
    pos_ += n;
    return p;
  }
  auto& copy = kept_.emplace_back(n);
  copy_out(copy.data(), n);
  return copy.data();
}

std::vector<std::byte> Reader::copy(std::size_t n) {
  if (n > remaining()) underflow(n, "bytes");
  if (n <= bytes_.size() - pos_) return detail::copy_bytes(raw(n));
  std::vector<std::byte> out = detail::take_buffer(n);  // n is large: it straddles blocks
  out.reserve(n);
  while (out.size() < n) {  // appended block by block: nothing is written twice
    while (pos_ == bytes_.size()) next_block();
    const std::size_t here = std::min(n - out.size(), bytes_.size() - pos_);
    const auto from = bytes_.subspan(pos_, here);
    out.insert(out.end(), from.begin(), from.end());
    pos_ += here;
  }
  return out;
}

void Reader::copy_range(std::size_t start, std::size_t n, std::byte* to) const {
  std::size_t at = 0;  // where blocks_[i] starts
  for (const auto& b : blocks_) {
    if (n == 0) return;
    if (start < at + b.size()) {
      const std::size_t from = start - at;
      const std::size_t here = std::min(n, b.size() - from);
      std::memcpy(to, b.data() + from, here);
      to += here;
      start += here;
      n -= here;
    }
    at += b.size();
  }
}

std::span<const std::byte> Reader::kept(std::size_t start, std::size_t n) const {
  if (start >= base_ && start - base_ + n <= bytes_.size()) return bytes_.subspan(start - base_, n);
  auto& copy = kept_.emplace_back(n);
  copy_range(start, n, copy.data());
  return copy;
}

std::span<const std::byte> Reader::rest() const { return kept(position(), remaining()); }

std::span<const std::byte> Reader::span_from(std::size_t start) const {
  return kept(start, position() - start);
}

void Reader::fail(const std::string& what) const {
  throw Error(ErrorKind::bad_data, fmt::format("{} (at byte {})", what, position()));
}

void Reader::underflow(std::size_t n, const char* what) const {
  fail(fmt::format("truncated input: {} needs {} bytes, {} left", what, n, remaining()));
}

namespace {

void read_descriptor_into(Reader& r, std::size_t depth) {
  if (depth > kMaxTypeDepth) r.fail("type descriptor nested deeper than 32 levels");
  const auto code = static_cast<TypeCode>(r.u8());
  switch (code) {
    case TypeCode::void_type:
    case TypeCode::boolean:
    case TypeCode::byte:
    case TypeCode::short_int:
    case TypeCode::int32:
    case TypeCode::int64:
    case TypeCode::float32:
    case TypeCode::float64:
    case TypeCode::string:
    case TypeCode::binary:
    case TypeCode::stream:
    case TypeCode::event:
    case TypeCode::exception:
    case TypeCode::remote:
      return;
    case TypeCode::sequence: {
      const std::size_t element_at = r.position();
      read_descriptor_into(r, depth + 1);
      // Zero-size elements would let a short message claim billions of items.
      if (std::to_integer<std::uint8_t>(r.span_from(element_at)[0]) ==
          static_cast<std::uint8_t>(TypeCode::void_type)) {
        r.fail("sequence<void> is not a valid type");
      }
      return;
    }
    case TypeCode::enumeration:
    case TypeCode::valued:
      (void)r.str_view();
      return;
  }
  r.fail(fmt::format("unknown type code 0x{:02X}", static_cast<unsigned>(code)));
}

std::string describe_from(Reader& r) {
  const auto code = static_cast<TypeCode>(r.u8());
  switch (code) {
    case TypeCode::void_type:
      return "void";
    case TypeCode::boolean:
      return "bool";
    case TypeCode::byte:
      return "byte";
    case TypeCode::short_int:
      return "short";
    case TypeCode::int32:
      return "int";
    case TypeCode::int64:
      return "long";
    case TypeCode::float32:
      return "float";
    case TypeCode::float64:
      return "double";
    case TypeCode::string:
      return "string";
    case TypeCode::binary:
      return "binary";
    case TypeCode::stream:
      return "stream";
    case TypeCode::event:
      return "event";
    case TypeCode::exception:
      return "exception";
    case TypeCode::remote:
      return "remote";
    case TypeCode::sequence:
      return "sequence<" + describe_from(r) + ">";
    case TypeCode::enumeration:
      return "enum " + r.str();
    case TypeCode::valued:
      return "valued " + r.str();
  }
  return fmt::format("type 0x{:02X}", static_cast<unsigned>(code));
}

}  // namespace

std::span<const std::byte> read_descriptor(Reader& r) {
  const std::size_t start = r.position();
  read_descriptor_into(r, 0);
  return r.span_from(start);
}

std::string describe(std::span<const std::byte> descriptor) {
  try {
    Reader r(descriptor);
    return describe_from(r);
  } catch (const Error&) {
    return "malformed type";
  }
}

void skip_value(Reader& r, std::span<const std::byte> descriptor) {
  Reader d(descriptor);
  const auto code = static_cast<TypeCode>(d.u8());
  switch (code) {
    case TypeCode::void_type:
      return;
    case TypeCode::boolean:
    case TypeCode::byte:
      (void)r.raw(1);
      return;
    case TypeCode::short_int:
      (void)r.raw(2);
      return;
    case TypeCode::int32:
    case TypeCode::float32:
    case TypeCode::enumeration:
    case TypeCode::stream:
      (void)r.raw(4);
      return;
    case TypeCode::int64:
    case TypeCode::float64:
      (void)r.raw(8);
      return;
    case TypeCode::string:
    case TypeCode::binary:
      (void)r.raw(r.count(1, "string"));
      return;
    case TypeCode::remote:
      for (int i = 0; i < 3; ++i) (void)r.raw(r.count(1, "string"));
      return;
    case TypeCode::sequence: {
      if (++r.depth > kMaxTypeDepth) r.fail("values nested deeper than 32 levels");
      const auto element = d.rest();
      const std::size_t n = r.count(1, "sequence");
      for (std::size_t i = 0; i < n; ++i) skip_value(r, element);
      --r.depth;
      return;
    }
    case TypeCode::event:
    case TypeCode::exception: {
      (void)r.raw(r.count(1, "string"));
      if (code == TypeCode::exception) (void)r.raw(r.count(1, "string"));
      const std::size_t n = r.count(9, "property list");
      for (std::size_t i = 0; i < n; ++i) {
        (void)r.raw(r.count(1, "string"));
        (void)read_descriptor(r);
        (void)r.raw(r.count(1, "property value"));
      }
      return;
    }
    case TypeCode::valued:
      r.fail("cannot skip a valued " + describe(descriptor) + " without its definition");
  }
  r.fail(fmt::format("unknown type code 0x{:02X}", static_cast<unsigned>(code)));
}

}  // namespace icars::planet
