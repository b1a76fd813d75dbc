// Saved component states; see include/long3r/model/loading/state_dict.hpp.
#include "long3r/model/loading/state_dict.hpp"

#include "long3r/io/fnv1a.hpp"

#include <cstring>

#include <ATen/ATen.h>

#include <cmath>
#include <utility>

namespace long3r {

void put_int(StateDict& state, const std::string& key, int64_t value) {
  state[key] = at::scalar_tensor(value, at::kLong);
}

void put_real(StateDict& state, const std::string& key, double value) {
  state[key] = at::scalar_tensor(value, at::kDouble);
}

void put_state(StateDict& state, const std::string& prefix, const StateDict& part) {
  for (const auto& [key, t] : part) state[prefix + key] = t;
}

StateDict sub_state(const StateDict& state, const std::string& prefix) {
  StateDict part;
  for (auto it = state.lower_bound(prefix); it != state.end() && it->first.rfind(prefix, 0) == 0;
       ++it) {
    part[it->first.substr(prefix.size())] = it->second;
  }
  return part;
}

StateReader::StateReader(const StateDict& state, std::string what, std::string prefix)
    : state_(state), what_(std::move(what)), prefix_(std::move(prefix)) {}

StateReader StateReader::child(const std::string& prefix) const {
  return StateReader(state_, what_, prefix_ + prefix);
}

bool StateReader::has(const std::string& key) const {
  const auto it = state_.find(prefix_ + key);
  return it != state_.end() && it->second.defined();
}

void StateReader::fail(const std::string& key, const std::string& problem) const {
  throw StateError(what_ + ": " + prefix_ + key + ": " + problem);
}

const at::Tensor& StateReader::get(const std::string& key) const {
  if (!has(key)) fail(key, "missing");
  return state_.at(prefix_ + key);
}

int64_t StateReader::integer(const std::string& key) const {
  const at::Tensor& t = get(key);
  if (t.scalar_type() != at::kLong || t.dim() != 0) fail(key, "expected an int64 scalar");
  return t.item<int64_t>();
}

int64_t StateReader::integer(const std::string& key, int64_t min, int64_t max) const {
  const int64_t v = integer(key);
  if (v < min || v > max) {
    fail(key, std::to_string(v) + " is outside [" + std::to_string(min) + ", " +
                  std::to_string(max) + "]");
  }
  return v;
}

double StateReader::real(const std::string& key) const {
  const at::Tensor& t = get(key);
  if (t.scalar_type() != at::kDouble || t.dim() != 0) fail(key, "expected a float64 scalar");
  return t.item<double>();
}

at::Tensor StateReader::shaped(const std::string& key, std::initializer_list<int64_t> shape,
                               std::optional<at::ScalarType> exact, bool finite) const {
  const at::Tensor& t = get(key);
  const bool floating = !exact.has_value();
  if (floating ? !at::isFloatingType(t.scalar_type()) : t.scalar_type() != *exact) {
    fail(key, std::string("expected ") +
                  (floating ? std::string("a floating-point") : c10::toString(*exact)) +
                  " tensor, found " + c10::toString(t.scalar_type()));
  }
  bool ok = t.dim() == static_cast<int64_t>(shape.size());
  int64_t d = 0;
  for (const int64_t want : shape) {
    if (!ok) break;
    ok = want < 0 || t.size(d) == want;
    ++d;
  }
  if (!ok) {
    std::string want = "[";
    for (const int64_t s : shape) {
      want += (want.size() > 1 ? ", " : "") + (s < 0 ? std::string("*") : std::to_string(s));
    }
    fail(key, "shape " + c10::str(t.sizes()) + ", expected " + want + "]");
  }
  if (floating && finite && !at::isfinite(t).all().item<bool>()) {
    fail(key, "holds non-finite values");
  }
  return t;
}

at::Tensor StateReader::floating(const std::string& key, std::initializer_list<int64_t> shape,
                                 bool finite) const {
  return shaped(key, shape, std::nullopt, finite);
}

at::Tensor StateReader::int64(const std::string& key, std::initializer_list<int64_t> shape) const {
  return shaped(key, shape, at::kLong, false);
}

at::Tensor StateReader::uint8(const std::string& key, std::initializer_list<int64_t> shape) const {
  return shaped(key, shape, at::kByte, false);
}

namespace {

constexpr std::size_t kBlobSumBytes = 8;

std::uint64_t blob_sum(const char* data, std::size_t n) {
  Fnv1a f;
  f.add(data, n);
  return f.h;
}

}  // namespace

std::string StateReader::bytes(const std::string& key) const {
  const at::Tensor& t = get(key);
  if (t.scalar_type() != at::kByte || t.dim() != 1) {
    fail(key, "expected a 1-D uint8 tensor, found " + std::string(c10::toString(t.scalar_type())) +
                  " of shape " + c10::str(t.sizes()));
  }
  const at::Tensor c = t.contiguous();
  const auto* p = reinterpret_cast<const char*>(c.data_ptr<std::uint8_t>());
  const auto n = static_cast<std::size_t>(c.numel());
  if (n < kBlobSumBytes) fail(key, "too short for its check sum (damaged)");
  std::uint64_t stored = 0;
  for (std::size_t i = 0; i < kBlobSumBytes; ++i) {
    stored |= static_cast<std::uint64_t>(static_cast<unsigned char>(p[i])) << (8 * i);
  }
  if (blob_sum(p + kBlobSumBytes, n - kBlobSumBytes) != stored) {
    fail(key, "its check sum does not match its bytes (damaged)");
  }
  return std::string(p + kBlobSumBytes, n - kBlobSumBytes);
}

at::Tensor bytes_tensor(const std::string& bytes) {
  at::Tensor t = at::empty({static_cast<int64_t>(kBlobSumBytes + bytes.size())}, at::kByte);
  auto* p = t.data_ptr<std::uint8_t>();
  const std::uint64_t sum = blob_sum(bytes.data(), bytes.size());
  for (std::size_t i = 0; i < kBlobSumBytes; ++i) p[i] = static_cast<std::uint8_t>(sum >> (8 * i));
  if (!bytes.empty()) std::memcpy(p + kBlobSumBytes, bytes.data(), bytes.size());
  return t;
}

}  // namespace long3r
