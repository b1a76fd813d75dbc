// The voxel map's index: voxel key -> position in its dense voxel storage.
//
// An open-addressing hash table (linear probing, at most half full,
// backward-shift deletion) in one flat array of (key, position) slots, so a
// lookup touches one cache line where std::unordered_map follows a bucket and
// then a node: fusing a frame into a large map is bound by these lookups
// (docs/performance.md, "The voxel map beside PCL"). Keys use at most 63 bits
// (VoxelMap packs 3 x 21), the all-ones key marks an empty slot.
#pragma once

#include <cstddef>
#include <cstdint>
#include <utility>
#include <vector>

namespace long3r {

class VoxelKeyIndex {
 public:
  static constexpr std::uint64_t kNoKey = ~std::uint64_t{0};

  // The position stored for key, or nullptr. Valid until the next change.
  const std::uint32_t* find(std::uint64_t key) const;
  // Inserts (key, pos) unless key is present; returns the stored position
  // and whether it was inserted. key must not be kNoKey
  // (std::invalid_argument).
  std::pair<std::uint32_t, bool> try_emplace(std::uint64_t key, std::uint32_t pos);
  // Sets the position of a key that is present (std::out_of_range otherwise).
  void assign(std::uint64_t key, std::uint32_t pos);
  // Removes key if present; returns whether it was.
  bool erase(std::uint64_t key);
  void clear();
  // Room for n keys without growing.
  void reserve(std::size_t n);
  std::size_t size() const { return size_; }

 private:
  struct Slot {
    std::uint64_t key;
    std::uint32_t pos;
  };
  std::size_t home(std::uint64_t key) const;
  std::size_t slot_of(std::uint64_t key) const;  // its slot, or the empty one ending its probe
  void rehash(std::size_t slots);

  std::vector<Slot> slots_;  // empty, or a power of two
  std::size_t size_ = 0;
};

}  // namespace long3r
