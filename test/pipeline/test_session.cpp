// Sessions without ROS (pipeline/session.hpp, LiveSession::save / load): a
// saved and loaded stream continues exactly as the uninterrupted one would
// after a pause (poses, map voxels bit for bit, path), whatever the stamps
// of the frames that follow; every damaged, foreign or mismatched file is
// refused by name with the running stream untouched; a failed save leaves
// the old file. A model that returns the generator's ground truth makes
// every figure exact.
#include <ATen/ATen.h>
#include <gtest/gtest.h>

#include <any>
#include <cstdio>
#include <fstream>
#include <functional>
#include <random>
#include <string>
#include <vector>

#include "long3r/io/safetensors_header.hpp"
#include "long3r/model/loading/safetensors.hpp"
#include "long3r/pipeline/live_session.hpp"
#include "long3r/pipeline/session.hpp"
#include "support/cv_test_support.hpp"
#include "support/live_session_support.hpp"
#include "support/test_support.hpp"

namespace long3r {
namespace {

using test::Session;

constexpr int kFrames = 10;
constexpr int kSplit = 5;  // frames 0..4 before the save, 5..9 after

std::string session_path(const std::string& dir) {
  return test::scratch_dir("session/" + dir) + "/map.l3s";
}

void expect_same_map(const VoxelMap& a, const VoxelMap& b) {
  const std::vector<VoxelRecord> ra = a.records(), rb = b.records();
  ASSERT_EQ(ra.size(), rb.size());
  for (std::size_t i = 0; i < ra.size(); ++i) {
    ASSERT_EQ(ra[i].index, rb[i].index) << "voxel " << i;
    ASSERT_EQ(ra[i].mean, rb[i].mean) << "voxel " << i;
    ASSERT_EQ(ra[i].color, rb[i].color) << "voxel " << i;
    ASSERT_EQ(ra[i].hits, rb[i].hits) << "voxel " << i;
    ASSERT_EQ(ra[i].last_seen, rb[i].last_seen) << "voxel " << i;
  }
}

void expect_same_path(const Reconstruction& a, const Reconstruction& b) {
  const auto pa = a.trajectory(), pb = b.trajectory();
  ASSERT_EQ(pa.size(), pb.size());
  for (std::size_t i = 0; i < pa.size(); ++i) {
    EXPECT_EQ(pa[i].first, pb[i].first);
    EXPECT_TRUE(pa[i].second.isApprox(pb[i].second, 0.0)) << "pose " << i;
  }
}

// Results of frames from..to-1 in `s` (by tag).
std::vector<const LiveResult*> results_of(const Session& s, int from, int to) {
  std::vector<const LiveResult*> out;
  for (const LiveResult& r : s.client.results) {
    const int k = std::any_cast<int>(r.tag);
    if (k >= from && k < to) out.push_back(&r);
  }
  return out;
}

// What must not change when a load is refused.
struct Fingerprint {
  int64_t frames;
  std::size_t map_points, poses;
  double scale;
  explicit Fingerprint(const Session& s)
      : frames(s.session->reconstruction().frames_pushed()),
        map_points(s.session->reconstruction().map().size()),
        poses(s.session->reconstruction().trajectory().size()),
        scale(s.session->reconstruction().scale()) {}
  bool operator==(const Fingerprint& o) const {
    return frames == o.frames && map_points == o.map_points && poses == o.poses && scale == o.scale;
  }
};

// A session of frames 0..kSplit-1 saved to `path`.
void save_first_part(const std::string& path) {
  Session a(kFrames);
  for (int k = 0; k < kSplit; ++k) a.push(k, 10.0 + 0.1 * k);
  a.session->save(path);
}

std::string error_of(const std::function<void()>& f) {
  try {
    f();
  } catch (const SessionError& e) {
    return e.what();
  }
  return "(no SessionError)";
}

TEST(Session, ALoadedSessionContinuesExactlyAsTheStreamAfterAPause) {
  // The reference: one run with a pause (flush) where the other saves.
  Session ref(kFrames);
  for (int k = 0; k < kFrames; ++k) {
    if (k == kSplit) ref.session->flush();
    ref.push(k, 10.0 + 0.1 * k);
  }
  ref.session->flush();

  const std::string path = session_path("exact");
  Session before(kFrames);
  for (int k = 0; k < kSplit; ++k) before.push(k, 10.0 + 0.1 * k);
  before.session->save(path);
  ASSERT_EQ(before.tags(), (std::vector<int>{0, 1, 2, 3, 4}));  // save delivered frame 4

  const std::map<std::string, std::string> meta = read_session_metadata(path);
  EXPECT_EQ(meta.at("format"), "long3r_session");
  EXPECT_EQ(meta.at("model.variant"), "fake");
  EXPECT_EQ(meta.at("frames"), std::to_string(kSplit));
  EXPECT_EQ(meta.at("map_points"), std::to_string(before.session->reconstruction().map().size()));

  Session after(kFrames);  // another process: a fresh model of the same identity
  after.session->load(path);
  EXPECT_EQ(after.client.log,
            (std::vector<std::string>{"new stream: session loaded from " + path}));
  EXPECT_EQ(after.session->reconstruction().frames_pushed(), kSplit);
  expect_same_map(after.session->reconstruction().map(), before.session->reconstruction().map());
  for (int k = kSplit; k < kFrames; ++k) after.push(k, 10.0 + 0.1 * k);
  after.session->flush();

  const auto got = results_of(after, kSplit, kFrames), want = results_of(ref, kSplit, kFrames);
  ASSERT_EQ(got.size(), want.size());
  for (std::size_t i = 0; i < got.size(); ++i) {
    EXPECT_EQ(got[i]->frame.frame_index, want[i]->frame.frame_index);
    EXPECT_TRUE(got[i]->frame.pose.ok());
    EXPECT_TRUE(got[i]->frame.pose.T_W_C.isApprox(want[i]->frame.pose.T_W_C, 0.0));
  }
  expect_same_map(after.session->reconstruction().map(), ref.session->reconstruction().map());
  expect_same_path(after.session->reconstruction(), ref.session->reconstruction());
}

TEST(Session, FramesAfterALoadContinueWhateverTheirStamps) {
  const std::string path = session_path("stamps");
  save_first_part(path);
  Session s(kFrames);
  s.session->load(path);
  const std::size_t saved_points = s.session->reconstruction().map().size();
  // A replay another day: stamps far behind the saved ones. Not a jump back
  // in time (which would start a new stream): the file's stream goes on.
  for (int k = kSplit; k < kFrames; ++k) s.push(k, 1.0 + 0.1 * k);
  s.session->flush();
  EXPECT_EQ(s.client.log.front(), "new stream: session loaded from " + path);
  EXPECT_EQ(s.client.log.size(), 1u + (kFrames - kSplit));  // no other new stream
  EXPECT_EQ(s.session->status().streams, 2u);
  EXPECT_GE(s.session->reconstruction().map().size(), saved_points);
  EXPECT_EQ(s.session->reconstruction().trajectory().size(), static_cast<std::size_t>(kFrames));
  for (const LiveResult* r : results_of(s, kSplit, kFrames)) {
    EXPECT_EQ(r->frame.frame_index, std::any_cast<int>(r->tag));  // frame indices go on
    EXPECT_TRUE(r->frame.pose.ok());
  }
}

TEST(Session, AMetricScaleIsKeptAndANonMetricOneFollowsThisRunsSource) {
  const std::string path = session_path("scale");
  LiveSessionConfig fixed;
  fixed.scale.source = ScaleSource::kFixed;
  fixed.scale.fixed_scale = 2.0;
  {
    Session a(kFrames, fixed);
    for (int k = 0; k < kSplit; ++k) a.push(k, 10.0 + 0.1 * k);
    a.session->save(path);
  }
  Session b(kFrames);  // scale source none: the saved metric scale stays
  b.session->load(path);
  EXPECT_EQ(b.session->reconstruction().scale(), 2.0);
  EXPECT_TRUE(b.session->status().scale_metric);

  const std::string plain = session_path("scale_plain");
  save_first_part(plain);  // model units
  Session c(kFrames, fixed);
  c.session->load(plain);
  EXPECT_EQ(c.session->reconstruction().scale(), 2.0);  // this run's fixed scale, applied
  Session ref(kFrames, fixed);
  for (int k = 0; k < kSplit; ++k) ref.push(k, 10.0 + 0.1 * k);
  ref.session->flush();
  const auto rp = ref.session->reconstruction().trajectory();
  const auto cp = c.session->reconstruction().trajectory();
  ASSERT_EQ(rp.size(), cp.size());
  for (std::size_t i = 0; i < rp.size(); ++i) {
    EXPECT_TRUE(cp[i].second.isApprox(rp[i].second, 1e-9));
  }
}

TEST(Session, DamagedForeignOrMismatchedFilesAreRefusedAndTheStreamIsUntouched) {
  const std::string dir = test::scratch_dir("session/refused");
  const std::string good = dir + "/good.l3s";
  save_first_part(good);
  const std::string bytes = test::read_file(good);

  // The running session: frames of its own, to be kept through every refusal.
  Session s(kFrames);
  for (int k = 0; k < 3; ++k) s.push(k, 50.0 + 0.1 * k);
  const Fingerprint before(s);

  auto refused = [&](const std::string& name, const std::string& content,
                     const std::string& expect) {
    const std::string path = dir + "/" + name;
    test::write_file(path, content);
    const std::string e = error_of([&] { s.session->load(path); });
    EXPECT_NE(e.find(expect), std::string::npos) << name << ": " << e;
    EXPECT_TRUE(Fingerprint(s) == before) << name;
  };
  refused("truncated.l3s", bytes.substr(0, bytes.size() / 2), "truncated.l3s");
  refused("empty.l3s", "", "empty.l3s");
  refused("garbage.l3s", std::string(4096, '\x5a'), "garbage.l3s");
  std::string flipped = bytes;
  flipped[12] = '\x01';  // inside the JSON header
  refused("flipped.l3s", flipped, "flipped.l3s");
  EXPECT_NE(error_of([&] { s.session->load(dir + "/missing.l3s"); }).find("missing.l3s"),
            std::string::npos);

  // A safetensors file that is not a session (a model checkpoint).
  const std::string ckpt = dir + "/checkpoint.safetensors";
  save_safetensors(ckpt, {{"w", at::ones({2})}}, {{"config", "{}"}});
  EXPECT_NE(error_of([&] { s.session->load(ckpt); }).find("not a long3r session file"),
            std::string::npos);

  // Sessions of another model or configuration, named.
  const TensorFile file = load_safetensors(good);
  auto with_metadata = [&](const std::string& name, const std::string& key,
                           const std::string& value) {
    std::map<std::string, std::string> meta = file.metadata;
    meta[key] = value;
    const std::string path = dir + "/" + name;
    save_safetensors(path, file.tensors, meta);
    return path;
  };
  auto expect_refused = [&](const std::string& path, const std::string& expect) {
    const std::string e = error_of([&] { s.session->load(path); });
    EXPECT_NE(e.find(expect), std::string::npos) << e;
    EXPECT_TRUE(Fingerprint(s) == before) << path;
  };
  expect_refused(with_metadata("weights.l3s", "model.weights", "0123456789abcdef"),
                 "other weights (fingerprint 0123456789abcdef, this model's fake-weights)");
  expect_refused(with_metadata("variant.l3s", "model.variant", "spann3r"),
                 "a spann3r model, this one is fake");
  expect_refused(with_metadata("config.l3s", "model.config", "{\"fake\": 2}"),
                 "fake: 2 in the file, 1 here");
  expect_refused(with_metadata("size.l3s", "input_width", "512"),
                 "a model input size of 512x64, this one 64x64");
  expect_refused(with_metadata("version.l3s", "format_version", "7"),
                 "session format version 7, this build reads 1 to 2");
  {
    // Version 1 (before the keyframes were kept) is read.
    Session older(kFrames);
    older.session->load(with_metadata("version1.l3s", "format_version", "1"));
    EXPECT_EQ(older.session->reconstruction().frames_pushed(), kSplit);
  }
  {
    ReconstructionConfig coarse = test::gt_reconstruction_config();
    coarse.map.voxel_size_m *= 2.0;
    Session other(kFrames, {}, true, coarse);
    EXPECT_NE(error_of([&] { other.session->load(good); }).find("a map voxel size of"),
              std::string::npos);
  }

  // Damaged contents behind a valid header: named by entry.
  auto with_tensor = [&](const std::string& name, const std::string& key, const at::Tensor& t) {
    std::map<std::string, at::Tensor> tensors = file.tensors;
    if (t.defined()) {
      tensors[key] = t;
    } else {
      tensors.erase(key);
    }
    const std::string path = dir + "/" + name;
    save_safetensors(path, tensors, file.metadata);
    return path;
  };
  const at::Tensor mean = file.tensors.at("reconstruction.map.mean");
  expect_refused(with_tensor("mean.l3s", "reconstruction.map.mean", mean + 1000.0),
                 "mean position outside its voxel");
  expect_refused(with_tensor("nan.l3s", "reconstruction.map.mean", mean * NAN),
                 "saved reconstruction: map.mean: holds non-finite values");
  expect_refused(with_tensor("no_path.l3s", "reconstruction.trajectory.T_W_C", at::Tensor()),
                 "saved reconstruction: trajectory.T_W_C: missing");
  expect_refused(with_tensor("not_rigid.l3s", "reconstruction.trajectory.T_W_C",
                             file.tensors.at("reconstruction.trajectory.T_W_C") * 2.0),
                 "not a rigid transform");
  expect_refused(with_tensor("frames.l3s", "reconstruction.model.frames",
                             at::scalar_tensor(int64_t{3}, at::kLong)),
                 "the model's stream has 3 frames, the reconstruction 5");
  expect_refused(
      with_tensor("scale.l3s", "live.scale.applied", at::scalar_tensor(-1.0, at::kDouble)),
      "live.scale.applied: must be positive and finite");

  // After all that, the stream goes on as if nothing had happened.
  for (int k = 3; k < kFrames; ++k) s.push(k, 50.0 + 0.1 * k);
  s.session->flush();
  EXPECT_EQ(s.tags(), (std::vector<int>{0, 1, 2, 3, 4, 5, 6, 7, 8, 9}));
  EXPECT_EQ(s.session->status().streams, 1u);
}

// The session reader fuzzed as the safetensors header is (test/fuzz), over
// the whole load: seeded mutations of a valid file (bytes flipped in the
// header and in the tensor data, truncations, insertions, deletions) are
// each refused with a SessionError, the running stream untouched, or load
// into a session that then takes frames and saves again. Nothing else may
// escape.
TEST(Session, MutatedFilesAreRefusedOrLoadIntoAWorkingSession) {
  const std::string dir = test::scratch_dir("session/mutated");
  const std::string good = dir + "/good.l3s";
  save_first_part(good);
  const std::string bytes = test::read_file(good);
  const std::size_t header_end = 8 + static_cast<std::size_t>(decode_header_length(
                                         reinterpret_cast<const std::uint8_t*>(bytes.data())));
  ASSERT_LT(header_end, bytes.size());

  Session s(kFrames);
  for (int k = 0; k < 3; ++k) s.push(k, 50.0 + 0.1 * k);
  const std::string running = dir + "/running.l3s";  // to go back to after a load
  s.session->save(running);
  const Fingerprint before(s);
  std::mt19937_64 rng(20261203);
  auto pick = [&rng](std::size_t from, std::size_t to) {  // in [from, to)
    return from + static_cast<std::size_t>(rng() % (to - from));
  };
  constexpr int kMutations = 600;
  int refused = 0, loaded = 0;
  for (int i = 0; i < kMutations; ++i) {
    std::string m = bytes;
    switch (i % 6) {
      case 0:  // bits in the JSON header
        m[pick(8, header_end)] ^= static_cast<char>(1u << (rng() % 8));
        break;
      case 1:  // bytes in the tensor data (values, counts, poses)
      case 2:
        for (int n = 0; n < 1 + static_cast<int>(rng() % 4); ++n) {
          m[pick(header_end, m.size())] = static_cast<char>(rng());
        }
        break;
      case 3:  // truncated
        m.resize(pick(0, m.size()));
        break;
      case 4:  // a byte inserted
        m.insert(pick(0, m.size()), 1, static_cast<char>(rng()));
        break;
      case 5:  // a run deleted
        m.erase(pick(0, m.size()), 1 + rng() % 64);
        break;
    }
    const std::string path = dir + "/mutated.l3s";
    test::write_file(path, m);
    try {
      s.session->load(path);
    } catch (const SessionError&) {
      ++refused;
      ASSERT_TRUE(Fingerprint(s) == before) << "mutation " << i;
      continue;
    } catch (const std::exception& e) {
      test::write_file(dir + "/failure.l3s", m);
      FAIL() << "mutation " << i << " (kept in failure.l3s) escaped as: " << e.what();
    }
    ++loaded;  // a change the format cannot tell (a colour, a stamp): it must work
    const int64_t frames = s.session->reconstruction().frames_pushed();
    s.push(kSplit, 60.0);
    s.session->flush();
    EXPECT_EQ(s.session->reconstruction().frames_pushed(), frames + 1) << "mutation " << i;
    s.session->save(dir + "/resaved.l3s");
    s.session->load(running);  // back to the running stream for the next mutation
    ASSERT_TRUE(Fingerprint(s) == before);
  }
  RecordProperty("refused", refused);
  RecordProperty("loaded", loaded);
  std::printf("%d mutated sessions: %d refused, %d loaded and continued\n", kMutations, refused,
              loaded);
  EXPECT_GT(refused, kMutations / 2);
}

TEST(Session, AFailedSaveLeavesTheOldFileAndAModelWithoutIdentityCannotSave) {
  const std::string dir = test::scratch_dir("session/save_fails");
  const std::string path = dir + "/map.l3s";
  save_first_part(path);
  const std::string old = test::read_file(path);

  Session s(kFrames);
  for (int k = 0; k < kFrames; ++k) s.push(k, 10.0 + 0.1 * k);
  {
    test::FileSizeLimit limit(old.size() / 2);  // a disk that fills up mid-write
    EXPECT_NE(error_of([&] { s.session->save(path); }).find("session not saved"),
              std::string::npos);
  }
  EXPECT_EQ(test::read_file(path), old);
  EXPECT_EQ(test::folder_entries(dir), (std::vector<std::string>{"map.l3s"}));  // no temporary
  EXPECT_NE(error_of([&] {
              s.session->save(dir + "/no/such/folder/map.l3s");
            }).find("No such file or directory"),
            std::string::npos);

  Session anonymous(kFrames, {}, true, test::gt_reconstruction_config(), /*weights=*/"");
  anonymous.push(0, 1.0);
  anonymous.push(1, 1.1);
  EXPECT_NE(error_of([&] {
              anonymous.session->save(dir + "/anon.l3s");
            }).find("weights were not loaded from a checkpoint"),
            std::string::npos);
  EXPECT_EQ(test::folder_entries(dir), (std::vector<std::string>{"map.l3s"}));
}

// A new stream never wipes the map: the ended stream's map stays where the
// client's map frame has it, sessions keep it, only reset() clears it.
TEST(Session, MapsOfEndedStreamsAreKeptInTheMapFrameSavedAndClearedByReset) {
  Session s(kFrames);
  Eigen::Isometry3d T_map_W0 = Eigen::Isometry3d::Identity();
  T_map_W0.translation() = Eigen::Vector3d(3.0, -1.0, 0.5);
  s.client.map_frame = T_map_W0;
  for (int k = 0; k < 4; ++k) s.push(k, 10.0 + 0.1 * k);
  s.push(4, 2.0);  // time jumps back: a new stream
  s.push(5, 2.1);
  s.session->flush();
  ASSERT_EQ(s.session->status().streams, 2u);
  ASSERT_EQ(s.client.ended_maps.size(), 1u);
  const MapSnapshot& old_W = s.client.ended_maps[0];
  const VoxelMap& ended = s.session->ended_maps();
  ASSERT_GT(ended.size(), 0u);
  EXPECT_LE(ended.size(), old_W.points.size());  // re-binned after the move, never more
  EXPECT_NE(s.client.event("the ending stream's " + std::to_string(old_W.points.size()) +
                           " map points stay in the map"),
            nullptr)
      << "last event: " << (s.client.events.empty() ? "" : s.client.events.back().message);
  // Its points moved into the map frame: the centroids agree.
  auto centroid = [](const std::vector<Eigen::Vector3f>& points) {
    Eigen::Vector3d c = Eigen::Vector3d::Zero();
    for (const Eigen::Vector3f& p : points) c += p.cast<double>();
    return Eigen::Vector3d(c / static_cast<double>(points.size()));
  };
  const double voxel_m = s.session->reconstruction().config().map.voxel_size_m;
  EXPECT_LT((centroid(ended.snapshot().points) - T_map_W0 * centroid(old_W.points)).norm(),
            voxel_m);
  // The whole map: the current stream's, placed by its own T_map_W, and the ended one's.
  Eigen::Isometry3d T_map_W1 = Eigen::Isometry3d::Identity();
  T_map_W1.translation() = Eigen::Vector3d(-2.0, 0.0, 0.0);
  const MapSnapshot whole = s.session->map_snapshot(T_map_W1);
  const MapSnapshot current = s.session->reconstruction().map().snapshot();
  ASSERT_EQ(whole.points.size(), current.points.size() + ended.size());
  ASSERT_EQ(whole.colors.size(), whole.points.size());
  EXPECT_TRUE(whole.points[0].isApprox((T_map_W1.cast<float>() * current.points[0]), 1e-6f));
  const std::uint64_t revision = s.session->map_revision();

  // Saved and loaded exactly, with the current stream.
  const std::string path = session_path("ended_maps");
  s.session->save(path);
  Session loaded(kFrames);
  loaded.session->load(path);
  expect_same_map(loaded.session->ended_maps(), ended);
  expect_same_map(loaded.session->reconstruction().map(), s.session->reconstruction().map());

  // Files that kept them with the node's own state ("client.archive.") load them too.
  StateDict file = read_session(path, loaded.session->identity());
  StateDict earlier;
  for (const auto& [key, value] : file) {
    earlier[key.rfind("ended_maps.", 0) == 0 ? "client.archive." + key.substr(11) : key] = value;
  }
  const std::string earlier_path = session_path("ended_maps_earlier");
  write_session(earlier_path, loaded.session->identity(), earlier, {});
  Session reloaded(kFrames);
  reloaded.session->load(earlier_path);
  expect_same_map(reloaded.session->ended_maps(), ended);

  // A damaged kept map refuses the whole file; the running session is untouched.
  file["ended_maps.hits"] = at::zeros_like(file.at("ended_maps.hits"));
  const std::string damaged = session_path("ended_maps_damaged");
  write_session(damaged, loaded.session->identity(), file, {});
  Session other(kFrames);
  for (int k = 0; k < 2; ++k) other.push(k, 10.0 + 0.1 * k);
  const Fingerprint before(other);
  const std::string error = error_of([&] { other.session->load(damaged); });
  EXPECT_NE(error.find("ended_maps.hits"), std::string::npos) << error;
  EXPECT_TRUE(Fingerprint(other) == before);
  EXPECT_TRUE(other.session->ended_maps().empty());

  // reset() clears them, with the current stream.
  s.session->reset("reset requested");
  EXPECT_TRUE(s.session->ended_maps().empty());
  EXPECT_EQ(s.client.ended_maps.size(), 2u);  // the client still hears of the ending
  EXPECT_NE(s.session->map_revision(), revision);
  EXPECT_TRUE(s.session->map_snapshot(T_map_W1).points.empty());
}

}  // namespace
}  // namespace long3r
