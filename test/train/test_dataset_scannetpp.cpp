// The ScanNet++ layout: the fixture writer and the reader agree on every
// convention (world points from the read frames equal the written ones, the
// poses stored in OpenGL camera axes), and broken files are named.
#include <gtest/gtest.h>

#include <algorithm>
#include <filesystem>
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

namespace {

fs::path dslr_of(const std::string& root, const std::string& scene) {
  return fs::path(root) / "data" / scene / "dslr";
}

void write_json(const fs::path& path, const nlohmann::json& j) {
  long3r::test::write_file(path.string(), j.dump(2) + "\n");
}

}  // namespace

TEST(DatasetScannetpp, RoundTrip) {
  const std::string root = long3r::test::scratch_dir("datasets/scannetpp");
  const std::vector<LayoutFrame> a = long3r::synth::render_layout_frames(51, 6, 48, 40);
  const std::vector<LayoutFrame> b = long3r::synth::render_layout_frames(52, 6, 48, 40);
  long3r::synth::write_scannetpp_sequence(root, "0a5c013435", a);
  long3r::synth::write_scannetpp_sequence(root, "1ada7a0617", b);
  // The frames come sorted by name whatever the lists' order; a test image
  // (in transforms, not in "train") is not one of them.
  const fs::path lists = dslr_of(root, "0a5c013435") / "train_test_lists.json";
  nlohmann::json l = long3r::datasets::read_json(lists.string());
  std::reverse(l["train"].begin(), l["train"].end());
  l["test"].push_back(l["train"][0]);
  l["train"].erase(0);
  write_json(lists, l);

  const DatasetScan scan = open_layout("scannetpp", root);
  EXPECT_TRUE(scan.skipped.empty()) << (scan.skipped.empty() ? "" : scan.skipped.front());
  ASSERT_EQ(scan.sequences.size(), 2u);
  EXPECT_EQ(scan.sequences[0]->name(), "scannetpp/0a5c013435");
  EXPECT_EQ(scan.sequences[1]->name(), "scannetpp/1ada7a0617");
  // Sequence a lost its last frame to "test".
  ASSERT_EQ(scan.sequences[0]->size(), 5);
  ASSERT_EQ(scan.sequences[1]->size(), 6);
  // 16-bit millimetre depth, JPEG colour.
  for (std::size_t s = 0; s < 2; ++s) {
    long3r::test::expect_sequence_matches(
        *scan.sequences[s], s == 0 ? a : b,
        long3r::test::millimetre_depth_precision(FramePrecision::Colour::kMeanBgr));
  }
  // With every frame in "train": 6 frames.
  long3r::synth::write_scannetpp_sequence(root, "0a5c013435", a);
  EXPECT_EQ(open_layout("scannetpp", root).sequences.at(0)->size(), 6);
}

TEST(DatasetScannetpp, BrokenFilesAreNamed) {
  const std::string root = long3r::test::scratch_dir("datasets/scannetpp_broken");
  long3r::synth::write_scannetpp_sequence(root, "scene_a",
                                          long3r::synth::render_layout_frames(61, 6, 48, 40));
  long3r::synth::write_scannetpp_sequence(root, "scene_b",
                                          long3r::synth::render_layout_frames(62, 6, 48, 40));
  long3r::synth::write_scannetpp_sequence(root, "scene_c",
                                          long3r::synth::render_layout_frames(63, 6, 48, 40));

  // scene_a: a frame's depth missing, another's pose not a rigid transform.
  const fs::path dslr_a = dslr_of(root, "scene_a");
  const std::string depth = (dslr_a / "undistorted_depths" / "DSC00002.png").string();
  const std::string tf_a = (dslr_a / "nerfstudio" / "transforms_undistorted.json").string();
  long3r::test::delete_file(depth);
  nlohmann::json tf = long3r::datasets::read_json(tf_a);
  ASSERT_EQ(tf["frames"][3]["file_path"], "DSC00003.JPG");
  for (int r = 0; r < 3; ++r) tf["frames"][3]["transform_matrix"][r][0] = 2.0;
  write_json(tf_a, tf);
  // scene_b: its transforms truncated; scene_c: a train image without a
  // frame in the transforms.
  const std::string tf_b =
      (dslr_of(root, "scene_b") / "nerfstudio" / "transforms_undistorted.json").string();
  long3r::test::truncate_file(tf_b, fs::file_size(tf_b) / 2);
  const std::string lists_c = (dslr_of(root, "scene_c") / "train_test_lists.json").string();
  nlohmann::json l = long3r::datasets::read_json(lists_c);
  l["train"].push_back("DSC09999.JPG");
  write_json(lists_c, l);

  const DatasetScan scan = open_layout("scannetpp", root);
  ASSERT_EQ(scan.sequences.size(), 1u);
  ASSERT_EQ(scan.skipped.size(), 2u);
  EXPECT_NE(scan.skipped[0].find(tf_b), std::string::npos) << scan.skipped[0];
  EXPECT_NE(scan.skipped[1].find(lists_c), std::string::npos) << scan.skipped[1];
  const long3r::RecordedSource* seq = long3r::test::find_sequence(scan, "scannetpp/scene_a");
  ASSERT_NE(seq, nullptr);
  EXPECT_EQ(seq->size(), 6);
  EXPECT_NO_THROW(seq->frame(1));
  expect_error_naming([&] { seq->frame(2); }, depth);
  expect_error_naming([&] { seq->frame(3); }, tf_a);

  // No split list: the dataset cannot be opened at all.
  expect_error_naming([&] { open_layout("scannetpp", root, "val"); }, "nvs_sem_val.txt");
}
