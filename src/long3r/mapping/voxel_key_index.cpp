#include "long3r/mapping/voxel_key_index.hpp"

#include <stdexcept>

namespace long3r {

std::size_t VoxelKeyIndex::home(std::uint64_t key) const {
  // splitmix64's finaliser: neighbouring voxels' keys differ in few bits.
  key ^= key >> 30;
  key *= 0xbf58476d1ce4e5b9ULL;
  key ^= key >> 27;
  key *= 0x94d049bb133111ebULL;
  key ^= key >> 31;
  return static_cast<std::size_t>(key) & (slots_.size() - 1);
}

std::size_t VoxelKeyIndex::slot_of(std::uint64_t key) const {
  const std::size_t mask = slots_.size() - 1;
  std::size_t i = home(key);
  while (slots_[i].key != key && slots_[i].key != kNoKey) i = (i + 1) & mask;
  return i;
}

const std::uint32_t* VoxelKeyIndex::find(std::uint64_t key) const {
  if (slots_.empty() || key == kNoKey) return nullptr;
  const Slot& s = slots_[slot_of(key)];
  return s.key == key ? &s.pos : nullptr;
}

std::pair<std::uint32_t, bool> VoxelKeyIndex::try_emplace(std::uint64_t key, std::uint32_t pos) {
  if (key == kNoKey) throw std::invalid_argument("VoxelKeyIndex: the key reserved for empty slots");
  if (2 * (size_ + 1) > slots_.size()) rehash(slots_.empty() ? 1024 : 2 * slots_.size());
  Slot& s = slots_[slot_of(key)];
  if (s.key == key) return {s.pos, false};
  s = Slot{key, pos};
  ++size_;
  return {pos, true};
}

void VoxelKeyIndex::assign(std::uint64_t key, std::uint32_t pos) {
  if (slots_.empty() || key == kNoKey) throw std::out_of_range("VoxelKeyIndex: no such key");
  Slot& s = slots_[slot_of(key)];
  if (s.key != key) throw std::out_of_range("VoxelKeyIndex: no such key");
  s.pos = pos;
}

bool VoxelKeyIndex::erase(std::uint64_t key) {
  if (slots_.empty() || key == kNoKey) return false;
  const std::size_t mask = slots_.size() - 1;
  std::size_t hole = slot_of(key);
  if (slots_[hole].key != key) return false;
  // Backward shift: move up every later entry of the probe run whose home
  // does not lie cyclically in (hole, j], so no lookup meets a gap.
  for (std::size_t j = (hole + 1) & mask; slots_[j].key != kNoKey; j = (j + 1) & mask) {
    const std::size_t h = home(slots_[j].key);
    const bool stays = hole < j ? (h > hole && h <= j) : (h > hole || h <= j);
    if (!stays) {
      slots_[hole] = slots_[j];
      hole = j;
    }
  }
  slots_[hole].key = kNoKey;
  --size_;
  return true;
}

void VoxelKeyIndex::clear() {
  slots_.clear();
  slots_.shrink_to_fit();
  size_ = 0;
}

void VoxelKeyIndex::reserve(std::size_t n) {
  std::size_t slots = slots_.empty() ? 1024 : slots_.size();
  while (slots < 2 * n) slots *= 2;
  if (slots != slots_.size()) rehash(slots);
}

void VoxelKeyIndex::rehash(std::size_t slots) {
  std::vector<Slot> old;
  old.swap(slots_);
  slots_.assign(slots, Slot{kNoKey, 0});
  for (const Slot& s : old) {
    if (s.key != kNoKey) slots_[slot_of(s.key)] = s;
  }
}

}  // namespace long3r
