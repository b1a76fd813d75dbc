// The Co3D layout: generated sequences written as DUSt3R's preprocessed
// Co3D-v2 (npz cameras, depth relative to each frame's maximum, object masks)
// read back with their depth, intrinsics and poses, the background masked,
// and broken files named.
#include <gtest/gtest.h>

#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>

#include <cstdio>
#include <filesystem>
#include <string>
#include <utility>
#include <vector>

#include "long3r/synth/cv/dataset_layouts.hpp"
#include "long3r/train/cv/datasets/dataset_io.hpp"
#include "support/cv_test_support.hpp"
#include "support/test_support.hpp"

namespace fs = std::filesystem;
using long3r::test::expect_error_naming;

namespace {

long3r::DatasetSource co3d_source(const std::string& root, bool mask_background = true) {
  long3r::DatasetSource s = long3r::test::layout_source("co3d", root);
  s.mask_background = mask_background;
  return s;
}

// The writer's file stem of frame i (Co3D numbers frames from 1).
std::string stem(int i) {
  char text[32];
  std::snprintf(text, sizeof(text), "frame%06d", i + 1);
  return text;
}

// A read frame against the written one, whose depth is valid only where
// `mask` (empty: everywhere) is foreground. Depth is stored in 65535 steps
// of the frame's largest depth (half a step of error); intrinsics and pose
// as float32 (1e-6 relative is well within); colour as JPEG, compared in
// grey levels, since its colour is stored at half resolution, which on these
// small noisy images costs several levels per channel.
void expect_same_frame(const long3r::RawFrame& got, const long3r::synth::LayoutFrame& want,
                       const cv::Mat& mask) {
  double maximum_depth = 0.0;
  cv::minMaxLoc(want.depth_m, nullptr, &maximum_depth);
  long3r::test::FramePrecision p;
  p.depth_abs_m = 0.5 * maximum_depth / 65535.0 + 1e-6 * maximum_depth;
  p.colour = long3r::test::FramePrecision::Colour::kMeanGrey;
  long3r::synth::LayoutFrame foreground = want;
  if (!mask.empty()) {
    foreground.depth_m = want.depth_m.clone();
    foreground.depth_m.setTo(0.0f, mask <= 25);
  }
  long3r::test::expect_frame_matches(got, foreground, p);
}

}  // namespace

TEST(DatasetCo3d, RoundTrip) {
  const std::string root = long3r::test::scratch_dir("datasets/co3d/round_trip");
  const auto a = long3r::synth::render_layout_frames(31, 6, 48, 40);
  const auto b = long3r::synth::render_layout_frames(32, 6, 48, 40);
  long3r::synth::write_co3d_sequence(root, "apple/110_13051_23361", a);
  long3r::synth::write_co3d_sequence(root, "teddybear/34_1403_4393", b);

  const long3r::datasets::DatasetScan scan = long3r::datasets::open_dataset(co3d_source(root));
  ASSERT_EQ(scan.sequences.size(), 2u);
  EXPECT_TRUE(scan.skipped.empty()) << scan.skipped.front();
  for (const auto& [name, frames] :
       {std::pair{"apple/110_13051_23361", &a}, std::pair{"teddybear/34_1403_4393", &b}}) {
    const long3r::RecordedSource* seq =
        long3r::test::find_sequence(scan, std::string("co3d/") + name);
    ASSERT_NE(seq, nullptr) << name;
    ASSERT_EQ(seq->size(), 6);
    for (int i = 0; i < 6; ++i) {
      SCOPED_TRACE(std::string(name) + " frame " + std::to_string(i));
      // The fixture's mask leaves out a band: the reader must drop its depth.
      const std::string mask_path = root + "/" + name + "/masks/" + stem(i) + ".png";
      const cv::Mat mask = cv::imread(mask_path, cv::IMREAD_UNCHANGED);
      ASSERT_EQ(mask.type(), CV_8UC1) << mask_path;
      const int background = mask.rows * mask.cols - cv::countNonZero(mask);
      EXPECT_GT(background, 0);
      EXPECT_LT(background, mask.rows * mask.cols / 4);
      expect_same_frame(seq->frame(i), (*frames)[static_cast<std::size_t>(i)], mask);
    }
  }

  // Without mask_background, the depth is kept everywhere.
  const long3r::datasets::DatasetScan unmasked =
      long3r::datasets::open_co3d(co3d_source(root, false));
  const long3r::RecordedSource* seq =
      long3r::test::find_sequence(unmasked, "co3d/apple/110_13051_23361");
  ASSERT_NE(seq, nullptr);
  for (int i = 0; i < 6; ++i) {
    SCOPED_TRACE("unmasked frame " + std::to_string(i));
    expect_same_frame(seq->frame(i), a[static_cast<std::size_t>(i)], cv::Mat());
  }
}

TEST(DatasetCo3d, BrokenFilesAreNamed) {
  const std::string root = long3r::test::scratch_dir("datasets/co3d/broken");
  const std::string list = root + "/selected_seqs_train.json";
  expect_error_naming([&] { long3r::datasets::open_co3d(co3d_source(root)); }, list);

  long3r::synth::write_co3d_sequence(root, "apple/seq_a",
                                     long3r::synth::render_layout_frames(41, 4, 48, 40));
  long3r::synth::write_co3d_sequence(root, "apple/seq_b",
                                     long3r::synth::render_layout_frames(42, 4, 48, 40));
  const std::string a = root + "/apple/seq_a";
  // Frame 1's depth truncated, frame 2's cameras gone, frame 3's mask gone.
  const std::string depth = a + "/depths/" + stem(1) + ".jpg.geometric.png";
  long3r::test::truncate_file(depth, 40);
  const std::string meta = a + "/images/" + stem(2) + ".npz";
  long3r::test::delete_file(meta);
  const std::string mask = a + "/masks/" + stem(3) + ".png";
  long3r::test::delete_file(mask);
  // seq_b has lost its images folder: left out, named.
  const std::string b_images = root + "/apple/seq_b/images";
  ASSERT_GT(fs::remove_all(b_images), 0u);

  const long3r::datasets::DatasetScan scan = long3r::datasets::open_co3d(co3d_source(root));
  ASSERT_EQ(scan.sequences.size(), 1u);
  EXPECT_EQ(scan.sequences[0]->name(), "co3d/apple/seq_a");
  ASSERT_EQ(scan.skipped.size(), 1u);
  EXPECT_NE(scan.skipped[0].find(b_images), std::string::npos) << scan.skipped[0];

  const long3r::RecordedSource& seq = *scan.sequences[0];
  ASSERT_EQ(seq.size(), 4);
  EXPECT_NO_THROW(seq.frame(0));
  expect_error_naming([&] { seq.frame(1); }, depth);
  expect_error_naming([&] { seq.frame(2); }, meta);
  expect_error_naming([&] { seq.frame(3); }, mask);
  // The mask is only read to mask the background.
  const long3r::datasets::DatasetScan unmasked =
      long3r::datasets::open_co3d(co3d_source(root, false));
  ASSERT_EQ(unmasked.sequences.size(), 1u);
  EXPECT_NO_THROW(unmasked.sequences[0]->frame(3));

  // A sequence's entry in the split list that is not a list of frame
  // numbers: that sequence is left out, named with the list.
  long3r::test::write_file(list, R"({"apple": {"seq_a": [1, 2, 3, 4], "seq_b": "frames"}})");
  const long3r::datasets::DatasetScan listed = long3r::datasets::open_co3d(co3d_source(root));
  EXPECT_EQ(listed.sequences.size(), 1u);
  ASSERT_EQ(listed.skipped.size(), 1u);
  EXPECT_NE(listed.skipped[0].find(list), std::string::npos) << listed.skipped[0];
  EXPECT_NE(listed.skipped[0].find("seq_b"), std::string::npos) << listed.skipped[0];
}
