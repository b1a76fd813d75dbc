// A component's saved state as named tensors (a state dict): how a model's
// stream and its memory go into a session file (pipeline/session.hpp) and
// come back. Integers and reals are 0-dim int64 / float64 tensors, so the
// whole state is one safetensors map.
//
// StateReader reads a saved state strictly: every accessor checks presence,
// dtype and shape and throws StateError "<what>: <key>: <problem>", so a
// component validates a whole state before it replaces its own (a refused
// state changes nothing).
#pragma once

#include <ATen/core/Tensor.h>

#include <cstdint>
#include <initializer_list>
#include <map>
#include <optional>
#include <stdexcept>
#include <string>

namespace long3r {

using StateDict = std::map<std::string, at::Tensor>;

class StateError : public std::invalid_argument {
 public:
  using std::invalid_argument::invalid_argument;
};

void put_int(StateDict& state, const std::string& key, int64_t value);
void put_real(StateDict& state, const std::string& key, double value);
// A part's state nested under `prefix` ("memory."), and taken back out.
void put_state(StateDict& state, const std::string& prefix, const StateDict& part);
StateDict sub_state(const StateDict& state, const std::string& prefix);

// A blob as a 1-D uint8 tensor, for StateReader::bytes(): its FNV-1a (8
// bytes, little endian) and then its bytes. The check sum lets the reader
// refuse a damaged blob before the library that wrote it parses it (which
// may not be safe against damage: OctoMap's reader is not).
at::Tensor bytes_tensor(const std::string& bytes);

class StateReader {
 public:
  // `what` names the state in messages ("session model state").
  StateReader(const StateDict& state, std::string what, std::string prefix = "");

  StateReader child(const std::string& prefix) const;
  bool has(const std::string& key) const;
  int64_t integer(const std::string& key) const;
  // integer() within [min, max].
  int64_t integer(const std::string& key, int64_t min, int64_t max) const;
  double real(const std::string& key) const;
  // A floating-point tensor of the given shape (-1: any size), finite unless
  // `finite` is false. Returned as stored (CPU); the caller converts it to its
  // device and dtype.
  at::Tensor floating(const std::string& key, std::initializer_list<int64_t> shape,
                      bool finite = true) const;
  // An int64 tensor of the given shape (-1: any size).
  at::Tensor int64(const std::string& key, std::initializer_list<int64_t> shape) const;
  // A uint8 tensor of the given shape (an image's colours).
  at::Tensor uint8(const std::string& key, std::initializer_list<int64_t> shape) const;
  // The bytes of a 1-D uint8 tensor (a blob another library wrote: an
  // OctoMap file), as bytes_tensor() stored them; a blob whose check sum does
  // not match is refused (StateError naming the key).
  std::string bytes(const std::string& key) const;

  [[noreturn]] void fail(const std::string& key, const std::string& problem) const;

 private:
  const at::Tensor& get(const std::string& key) const;
  // Of dtype `exact`, or of any floating-point dtype without it.
  at::Tensor shaped(const std::string& key, std::initializer_list<int64_t> shape,
                    std::optional<at::ScalarType> exact, bool finite) const;

  const StateDict& state_;
  std::string what_, prefix_;
};

}  // namespace long3r
