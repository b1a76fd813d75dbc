// The ARKitScenes layout: generated videos written as Spann3R's raw
// low-resolution ARKitScenes folders read back with their depth, intrinsics
// and poses, and broken files named.
#include <gtest/gtest.h>

#include <cstdio>
#include <filesystem>
#include <string>
#include <utility>
#include <vector>

#include "long3r/synth/cv/dataset_layouts.hpp"
#include "long3r/train/cv/datasets/dataset_io.hpp"
#include "support/cv_test_support.hpp"
#include "support/test_support.hpp"

using long3r::test::expect_error_naming;
using long3r::test::open_layout;

namespace {

// The writer's file stem of frame i: timestamps 1000.000 + 0.1 i.
std::string stem(const std::string& video, int i) {
  char ts[32];
  std::snprintf(ts, sizeof(ts), "%.3f", 1000.0 + 0.1 * i);
  return video + "_" + ts;
}

}  // namespace

TEST(DatasetArkitscenes, RoundTrip) {
  const std::string root = long3r::test::scratch_dir("datasets/arkitscenes/round_trip");
  const auto a = long3r::synth::render_layout_frames(11, 6, 48, 40);
  const auto b = long3r::synth::render_layout_frames(12, 6, 48, 40);
  long3r::synth::write_arkitscenes_sequence(root, "41069021", a);
  long3r::synth::write_arkitscenes_sequence(root, "41069022", b);

  const long3r::datasets::DatasetScan scan = open_layout("arkitscenes", root);
  ASSERT_EQ(scan.sequences.size(), 2u);
  EXPECT_TRUE(scan.skipped.empty()) << scan.skipped.front();
  for (const auto& [video, frames] : {std::pair{"41069021", &a}, std::pair{"41069022", &b}}) {
    const long3r::RecordedSource* seq =
        long3r::test::find_sequence(scan, std::string("arkitscenes/") + video);
    ASSERT_NE(seq, nullptr) << video;
    ASSERT_EQ(seq->size(), 6);
    // uint16 millimetre depth, lossless PNG colour, intrinsics and pose from
    // full-precision text.
    long3r::test::expect_sequence_matches(*seq, *frames,
                                          long3r::test::millimetre_depth_precision(
                                              long3r::test::FramePrecision::Colour::kExact, 1e-6));
  }
}

TEST(DatasetArkitscenes, BrokenFilesAreNamed) {
  const std::string root = long3r::test::scratch_dir("datasets/arkitscenes/broken");
  const std::string split = root + "/raw/Training";
  EXPECT_THROW(open_layout("arkitscenes", root), long3r::RecordedFrameError);

  long3r::synth::write_arkitscenes_sequence(root, "41069021",
                                            long3r::synth::render_layout_frames(21, 4, 48, 40));
  long3r::synth::write_arkitscenes_sequence(root, "41069022",
                                            long3r::synth::render_layout_frames(22, 4, 48, 40));
  // Frame 1's depth truncated, frame 2's intrinsics gone: those frames are
  // unreadable, named, and the others still read.
  const std::string depth = split + "/41069021/lowres_depth/" + stem("41069021", 1) + ".png";
  long3r::test::truncate_file(depth, 40);
  const std::string pincam =
      split + "/41069021/lowres_wide_intrinsics/" + stem("41069021", 2) + ".pincam";
  long3r::test::delete_file(pincam);
  // The other video's trajectory is corrupt: it is left out, named.
  const std::string traj = split + "/41069022/lowres_wide.traj";
  long3r::test::write_file(traj, "1000.000 0.1 0.2 x 1 2 3\n");

  const long3r::datasets::DatasetScan scan = open_layout("arkitscenes", root);
  ASSERT_EQ(scan.sequences.size(), 1u);
  EXPECT_EQ(scan.sequences[0]->name(), "arkitscenes/41069021");
  ASSERT_EQ(scan.skipped.size(), 1u);
  EXPECT_NE(scan.skipped[0].find(traj), std::string::npos) << scan.skipped[0];

  const long3r::RecordedSource& seq = *scan.sequences[0];
  ASSERT_EQ(seq.size(), 4);
  EXPECT_NO_THROW(seq.frame(0));
  EXPECT_NO_THROW(seq.frame(3));
  expect_error_naming([&] { seq.frame(1); }, depth);
  expect_error_naming([&] { seq.frame(2); }, pincam);

  // Without its trajectory file, a video is left out too.
  long3r::test::delete_file(traj);
  const long3r::datasets::DatasetScan again = open_layout("arkitscenes", root);
  EXPECT_EQ(again.sequences.size(), 1u);
  ASSERT_EQ(again.skipped.size(), 1u);
  EXPECT_NE(again.skipped[0].find(traj), std::string::npos) << again.skipped[0];
}
