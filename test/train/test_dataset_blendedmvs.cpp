// The BlendedMVS layout: the fixture writer and the reader agree on every
// convention (world points from the read frames equal the written ones), and
// broken files are named.
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
using long3r::test::open_layout;

TEST(DatasetBlendedmvs, RoundTrip) {
  const std::string root = long3r::test::scratch_dir("datasets/blendedmvs");
  const std::vector<LayoutFrame> a = long3r::synth::render_layout_frames(11, 6, 48, 40);
  const std::vector<LayoutFrame> b = long3r::synth::render_layout_frames(12, 6, 48, 40);
  long3r::synth::write_blendedmvs_sequence(root, "scene_a", a);
  long3r::synth::write_blendedmvs_sequence(root, "scene_b", b);
  // A masked copy beside an image is not a view of its own.
  fs::copy_file(fs::path(root) / "scene_a/blended_images/00000000.jpg",
                fs::path(root) / "scene_a/blended_images/00000000_masked.jpg");

  const DatasetScan scan = open_layout("blendedmvs", root);
  EXPECT_TRUE(scan.skipped.empty()) << (scan.skipped.empty() ? "" : scan.skipped.front());
  ASSERT_EQ(scan.sequences.size(), 2u);
  EXPECT_EQ(scan.sequences[0]->name(), "blendedmvs/scene_a");
  EXPECT_EQ(scan.sequences[1]->name(), "blendedmvs/scene_b");
  for (std::size_t s = 0; s < 2; ++s) {
    ASSERT_EQ(scan.sequences[s]->size(), 6);
    // PFM holds the float depth as written.
    long3r::test::expect_sequence_matches(*scan.sequences[s], s == 0 ? a : b,
                                          long3r::test::relative_depth_precision(1e-7));
  }
}

TEST(DatasetBlendedmvs, BrokenFilesAreNamed) {
  const std::string root = long3r::test::scratch_dir("datasets/blendedmvs_broken");
  const fs::path r(root);
  long3r::synth::write_blendedmvs_sequence(root, "scene_a",
                                           long3r::synth::render_layout_frames(21, 6, 48, 40));
  long3r::synth::write_blendedmvs_sequence(root, "scene_b",
                                           long3r::synth::render_layout_frames(22, 6, 48, 40));
  long3r::synth::write_blendedmvs_sequence(root, "scene_c",
                                           long3r::synth::render_layout_frames(23, 6, 48, 40));

  // A frame's depth missing, another's camera file truncated.
  const std::string depth = (r / "scene_a" / "rendered_depth_maps" / "00000002.pfm").string();
  const std::string cam = (r / "scene_a" / "cams" / "00000003_cam.txt").string();
  long3r::test::delete_file(depth);
  long3r::test::truncate_file(cam, 30);
  // scene_b's pair.txt malformed, scene_c's naming a view without an image.
  const std::string pairs_b = (r / "scene_b" / "cams" / "pair.txt").string();
  const std::string pairs_c = (r / "scene_c" / "cams" / "pair.txt").string();
  std::ofstream(pairs_b) << "6\n0\nthree 1 0.5\n";
  std::ofstream(pairs_c) << "1\n0\n1 99 0.5\n";

  const DatasetScan scan = open_layout("blendedmvs", root);
  ASSERT_EQ(scan.sequences.size(), 1u);
  ASSERT_EQ(scan.skipped.size(), 2u);
  EXPECT_NE(scan.skipped[0].find(pairs_b), std::string::npos) << scan.skipped[0];
  EXPECT_NE(scan.skipped[1].find(pairs_c), std::string::npos) << scan.skipped[1];
  const long3r::RecordedSource* seq = long3r::test::find_sequence(scan, "blendedmvs/scene_a");
  ASSERT_NE(seq, nullptr);
  EXPECT_NO_THROW(seq->frame(1));
  expect_error_naming([&] { seq->frame(2); }, depth);
  expect_error_naming([&] { seq->frame(3); }, cam);

  // No split list: the dataset cannot be opened at all.
  expect_error_naming([&] { open_layout("blendedmvs", root, "val"); }, "val_list.txt");
}

// The readers' one number parser (camera files, pair scores, timestamps).
TEST(DatasetIo, ParseFiniteTakesWholeFiniteTokensOnly) {
  double v = 0.0;
  EXPECT_TRUE(long3r::datasets::parse_finite("-1.5e3", &v));
  EXPECT_DOUBLE_EQ(v, -1500.0);
  EXPECT_TRUE(long3r::datasets::parse_finite("42", &v));
  EXPECT_DOUBLE_EQ(v, 42.0);
  for (const char* bad : {"", "1.5x", "three", "nan", "inf", "-inf", "1e999"}) {
    EXPECT_FALSE(long3r::datasets::parse_finite(bad, &v)) << "'" << bad << "'";
  }
}
