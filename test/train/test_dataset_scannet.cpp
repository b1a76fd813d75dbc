// The ScanNet layout: the fixture writer and the reader agree on every
// convention (world points from the read frames equal the written ones, the
// larger colour image resized to the depth's size), and broken files are
// named.
#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <string>
#include <vector>

#include "long3r/synth/cv/dataset_layouts.hpp"
#include "long3r/train/cv/datasets/dataset_io.hpp"
#include "support/cv_test_support.hpp"
#include "support/test_support.hpp"

namespace fs = std::filesystem;
using long3r::datasets::DatasetScan;
using long3r::synth::LayoutFrame;
using long3r::test::expect_error_naming;
using long3r::test::FramePrecision;
using long3r::test::open_layout;

TEST(DatasetScannet, RoundTrip) {
  const std::string root = long3r::test::scratch_dir("datasets/scannet");
  const std::vector<LayoutFrame> a = long3r::synth::render_layout_frames(31, 6, 48, 40);
  const std::vector<LayoutFrame> b = long3r::synth::render_layout_frames(32, 6, 48, 40);
  long3r::synth::write_scannet_sequence(root, "scene0000_00", a);
  long3r::synth::write_scannet_sequence(root, "scene0001_00", b);
  // Written again: the split list names it once.
  long3r::synth::write_scannet_sequence(root, "scene0001_00", b);
  // SimpleRecon's optional smaller colour copy is not a frame of its own.
  const fs::path data_a = fs::path(root) / "scans/scene0000_00/sensor_data";
  fs::copy_file(data_a / "frame-000000.color.jpg", data_a / "frame-000000.color.512.png");

  const DatasetScan scan = open_layout("scannet", root);
  EXPECT_TRUE(scan.skipped.empty()) << (scan.skipped.empty() ? "" : scan.skipped.front());
  ASSERT_EQ(scan.sequences.size(), 2u);
  EXPECT_EQ(scan.sequences[0]->name(), "scannet/scene0000_00");
  EXPECT_EQ(scan.sequences[1]->name(), "scannet/scene0001_00");
  // 16-bit millimetre depth; JPEG colour, written at twice the size and read
  // back at the depth's.
  for (std::size_t s = 0; s < 2; ++s) {
    ASSERT_EQ(scan.sequences[s]->size(), 6);
    long3r::test::expect_sequence_matches(
        *scan.sequences[s], s == 0 ? a : b,
        long3r::test::millimetre_depth_precision(FramePrecision::Colour::kMeanBgr));
  }
}

TEST(DatasetScannet, BrokenFilesAreNamed) {
  const std::string root = long3r::test::scratch_dir("datasets/scannet_broken");
  const fs::path r(root);
  long3r::synth::write_scannet_sequence(root, "scene_a",
                                        long3r::synth::render_layout_frames(41, 6, 48, 40));
  long3r::synth::write_scannet_sequence(root, "scene_b",
                                        long3r::synth::render_layout_frames(42, 6, 48, 40));
  // Listed, never written.
  std::ofstream(r / "splits" / "scannetv2_train.txt", std::ios::app) << "scene_gone\n";

  // scene_a: a frame's depth missing, another's pose truncated, a third's
  // pose -inf (as ScanNet's frames with lost tracking).
  const fs::path data = r / "scans" / "scene_a" / "sensor_data";
  const std::string depth = (data / "frame-000002.depth.png").string();
  const std::string pose = (data / "frame-000003.pose.txt").string();
  const std::string lost = (data / "frame-000004.pose.txt").string();
  long3r::test::delete_file(depth);
  long3r::test::truncate_file(pose, 10);
  std::ofstream(lost) << "-inf -inf -inf -inf\n-inf -inf -inf -inf\n"
                         "-inf -inf -inf -inf\n0 0 0 1\n";
  // scene_b: no depth intrinsics.
  const std::string k_b = (r / "scans" / "scene_b" / "intrinsic" / "intrinsic_depth.txt").string();
  long3r::test::delete_file(k_b);

  const DatasetScan scan = open_layout("scannet", root);
  ASSERT_EQ(scan.sequences.size(), 1u);
  ASSERT_EQ(scan.skipped.size(), 2u);
  EXPECT_NE(scan.skipped[0].find(k_b), std::string::npos) << scan.skipped[0];
  EXPECT_NE(scan.skipped[1].find((r / "scans" / "scene_gone").string()), std::string::npos)
      << scan.skipped[1];
  const long3r::RecordedSource* seq = long3r::test::find_sequence(scan, "scannet/scene_a");
  ASSERT_NE(seq, nullptr);
  EXPECT_EQ(seq->size(), 6);
  EXPECT_NO_THROW(seq->frame(1));
  expect_error_naming([&] { seq->frame(2); }, depth);
  expect_error_naming([&] { seq->frame(3); }, pose);
  expect_error_naming([&] { seq->frame(4); }, lost);

  // No split list: the dataset cannot be opened at all.
  expect_error_naming([&] { open_layout("scannet", root, "val"); }, "scannetv2_val.txt");
}
