// The voxel map's flat hash index against std::unordered_map.
#include <gtest/gtest.h>

#include <cstdint>
#include <random>
#include <stdexcept>
#include <unordered_map>
#include <vector>

#include "long3r/mapping/voxel_key_index.hpp"

namespace long3r {
namespace {

void expect_same(const VoxelKeyIndex& index,
                 const std::unordered_map<std::uint64_t, std::uint32_t>& ref,
                 const std::vector<std::uint64_t>& keys) {
  ASSERT_EQ(index.size(), ref.size());
  for (std::uint64_t key : keys) {
    const std::uint32_t* pos = index.find(key);
    const auto it = ref.find(key);
    if (it == ref.end()) {
      EXPECT_EQ(pos, nullptr) << key;
    } else {
      ASSERT_NE(pos, nullptr) << key;
      EXPECT_EQ(*pos, it->second) << key;
    }
  }
}

// Random inserts, reassignments and erases over a small key pool (so that
// probe runs are long and erases shift entries across them and across the
// table's end), through several growths.
TEST(VoxelKeyIndex, MatchesUnorderedMapUnderRandomOperations) {
  std::mt19937_64 rng(7);
  std::vector<std::uint64_t> pool;
  for (int i = 0; i < 3000; ++i) pool.push_back(rng() >> 1);  // 63-bit keys
  // Neighbouring voxels: keys differing in the low bits only.
  for (std::uint64_t k = 0; k < 500; ++k) pool.push_back((std::uint64_t{1} << 42) + k);
  VoxelKeyIndex index;
  std::unordered_map<std::uint64_t, std::uint32_t> ref;
  std::uniform_int_distribution<std::size_t> pick(0, pool.size() - 1);
  for (int step = 0; step < 40000; ++step) {
    const std::uint64_t key = pool[pick(rng)];
    const int op = static_cast<int>(rng() % 10);
    const auto pos = static_cast<std::uint32_t>(rng() % 100000);
    if (op < 5) {
      const auto [stored, inserted] = index.try_emplace(key, pos);
      const auto [it, ref_inserted] = ref.try_emplace(key, pos);
      ASSERT_EQ(inserted, ref_inserted);
      ASSERT_EQ(stored, it->second);
    } else if (op < 7) {
      if (ref.count(key)) {
        index.assign(key, pos);
        ref[key] = pos;
      } else {
        EXPECT_THROW(index.assign(key, pos), std::out_of_range);
      }
    } else {
      ASSERT_EQ(index.erase(key), ref.erase(key) == 1);
    }
    if (step % 4000 == 0) expect_same(index, ref, pool);
  }
  expect_same(index, ref, pool);
  // Erase everything: every lookup then misses.
  for (std::uint64_t key : pool) {
    index.erase(key);
    ref.erase(key);
  }
  expect_same(index, ref, pool);
  EXPECT_EQ(index.size(), 0u);
}

TEST(VoxelKeyIndex, ReserveClearAndTheEmptyKey) {
  VoxelKeyIndex index;
  EXPECT_EQ(index.find(5), nullptr);
  EXPECT_FALSE(index.erase(5));
  index.reserve(10000);
  for (std::uint32_t i = 0; i < 10000; ++i) EXPECT_TRUE(index.try_emplace(3 * i, i).second);
  EXPECT_EQ(index.size(), 10000u);
  EXPECT_EQ(*index.find(3 * 777), 777u);
  EXPECT_FALSE(index.try_emplace(3 * 777, 1).second);
  EXPECT_EQ(*index.find(3 * 777), 777u);
  EXPECT_THROW(index.try_emplace(VoxelKeyIndex::kNoKey, 0), std::invalid_argument);
  EXPECT_EQ(index.find(VoxelKeyIndex::kNoKey), nullptr);
  index.clear();
  EXPECT_EQ(index.size(), 0u);
  EXPECT_EQ(index.find(3 * 777), nullptr);
  EXPECT_TRUE(index.try_emplace(3 * 777, 2).second);
}

}  // namespace
}  // namespace long3r
