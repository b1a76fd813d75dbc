// The Habitat layout (CroCo's generator): the fixture writer and the reader
// agree on every convention (world points from the read frames equal the
// written ones), and broken files are named.
#include <gtest/gtest.h>

#include <filesystem>
#include <stdexcept>
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

TEST(DatasetHabitat, RoundTrip) {
  const std::string root = long3r::test::scratch_dir("datasets/habitat");
  // Two groups of 5 views in each of two scenes of two datasets.
  const std::vector<LayoutFrame> a = long3r::synth::render_layout_frames(31, 10, 48, 40);
  const std::vector<LayoutFrame> b = long3r::synth::render_layout_frames(32, 10, 48, 40);
  long3r::synth::write_habitat_sequence(root, "gibson/scene_a", a);
  long3r::synth::write_habitat_sequence(root, "mp3d/scene_b", b);
  EXPECT_THROW(long3r::synth::write_habitat_sequence(
                   root, "mp3d/scene_c", long3r::synth::render_layout_frames(33, 7, 48, 40)),
               std::invalid_argument);

  const DatasetScan scan = open_layout("habitat", root);
  EXPECT_TRUE(scan.skipped.empty()) << (scan.skipped.empty() ? "" : scan.skipped.front());
  ASSERT_EQ(scan.sequences.size(), 4u);
  const char* names[] = {"gibson/scene_a/00000000", "gibson/scene_a/00000001",
                         "mp3d/scene_b/00000000", "mp3d/scene_b/00000001"};
  for (std::size_t s = 0; s < 4; ++s) {
    EXPECT_EQ(scan.sequences[s]->name(), std::string("habitat/") + names[s]);
    ASSERT_EQ(scan.sequences[s]->size(), 5);
    // Half-float EXR: 11 significant bits, within 1e-3 relative. Views 1-5
    // of group g are frames 5 g to 5 g + 4.
    long3r::test::expect_sequence_matches(*scan.sequences[s], s < 2 ? a : b,
                                          long3r::test::relative_depth_precision(1e-3),
                                          5 * (s % 2));
  }
  // No split file: every split is the whole folder.
  EXPECT_EQ(open_layout("habitat", root, "test").sequences.size(), 4u);
}

TEST(DatasetHabitat, BrokenFilesAreNamed) {
  const std::string root = long3r::test::scratch_dir("datasets/habitat_broken");
  const fs::path r(root);
  long3r::synth::write_habitat_sequence(root, "gibson/scene_a",
                                        long3r::synth::render_layout_frames(41, 10, 48, 40));

  // View 3 of group 0 without its depth, view 2 of group 1 with a truncated
  // camera file.
  const std::string depth = (r / "gibson" / "scene_a" / "00000000_3_depth.exr").string();
  const std::string params = (r / "gibson" / "scene_a" / "00000001_2_camera_params.json").string();
  long3r::test::delete_file(depth);
  long3r::test::truncate_file(params, 40);
  // View 4 of a third group without its camera file: that group is left out.
  long3r::synth::write_habitat_sequence(root, "gibson/scene_a",
                                        long3r::synth::render_layout_frames(42, 5, 48, 40));
  const std::string lost = (r / "gibson" / "scene_a" / "00000002_4_camera_params.json").string();
  long3r::test::delete_file(lost);

  const DatasetScan scan = open_layout("habitat", root);
  ASSERT_EQ(scan.sequences.size(), 2u);
  ASSERT_EQ(scan.skipped.size(), 1u);
  EXPECT_NE(scan.skipped[0].find(lost), std::string::npos) << scan.skipped[0];
  const long3r::RecordedSource* g0 =
      long3r::test::find_sequence(scan, "habitat/gibson/scene_a/00000000");
  const long3r::RecordedSource* g1 =
      long3r::test::find_sequence(scan, "habitat/gibson/scene_a/00000001");
  ASSERT_NE(g0, nullptr);
  ASSERT_NE(g1, nullptr);
  EXPECT_NO_THROW(g0->frame(1));
  expect_error_naming([&] { g0->frame(2); }, depth);
  expect_error_naming([&] { g1->frame(1); }, params);

  // No root: the dataset cannot be opened at all.
  const std::string none = (r / "nowhere").string();
  expect_error_naming([&] { open_layout("habitat", none); }, none);
}
