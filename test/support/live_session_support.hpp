// LiveSession fixtures shared by the pipeline tests: a client that records
// what the session reports and answers from a generated sequence's ground
// truth, and a session over that sequence with a FakeModel.
#pragma once

#include <any>
#include <functional>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "long3r/pipeline/live_session.hpp"
#include "support/cv_test_support.hpp"

namespace long3r::test {

// Depth of frame k (z in its own camera) from the ground-truth pointmap.
inline cv::Mat gt_depth(const GtSequence& g, int k) {
  const Eigen::Isometry3f T_C_0 = g.T_0_k[static_cast<std::size_t>(k)].inverse().cast<float>();
  const cv::Mat& pts = g.pts_W0[static_cast<std::size_t>(k)];
  cv::Mat z(pts.size(), CV_32FC1);
  for (int i = 0; i < pts.rows * pts.cols; ++i) {
    const cv::Vec3f p = pts.at<cv::Vec3f>(i);
    z.at<float>(i) = (T_C_0 * Eigen::Vector3f(p[0], p[1], p[2])).z();
  }
  return z;
}

// Records what the session reports; tags are frame numbers.
struct Recorder : LiveSessionClient {
  const GtSequence* g = nullptr;
  std::vector<LiveResult> results;
  std::vector<LiveEvent> events;
  std::vector<std::string> log;  // results and new streams, in order
  std::function<std::optional<Eigen::Isometry3d>(int)> placer;
  double odometry_scale = 0.0;  // metres per ground-truth unit
  double depth_scale = 0.0;
  int depth_type = CV_32FC1;

  std::optional<Eigen::Isometry3d> place(const LiveFrame& f) override {
    return placer ? placer(std::any_cast<int>(f.tag)) : std::nullopt;
  }
  // The true camera pose, its translation times odometry_scale; none at frame 5.
  Eigen::Isometry3d odometry_camera_m(const std::any& tag) override {
    const int k = std::any_cast<int>(tag);
    if (k == 5) throw Unavailable("tf odometry", "odometry: none at frame 5");
    Eigen::Isometry3d T = g->T_0_k[static_cast<std::size_t>(k)];
    T.translation() *= odometry_scale;
    return T;
  }
  cv::Mat depth(const std::any& tag) override {
    const cv::Mat z = gt_depth(*g, std::any_cast<int>(tag)) * depth_scale;
    if (depth_type == CV_32FC1) return z;
    cv::Mat out;
    z.convertTo(out, depth_type, depth_type == CV_16UC1 ? 1000.0 : 1.0);
    return out;
  }
  void on_result(LiveResult& r) override {
    log.push_back("result " + std::to_string(std::any_cast<int>(r.tag)));
    results.push_back(r);
  }
  // Where W sits in the map frame of the maps of ended streams (none: not kept).
  std::optional<Eigen::Isometry3d> map_frame;
  std::optional<Eigen::Isometry3d> T_map_W() override { return map_frame; }
  void on_stream_ending(const Reconstruction& ending) override {
    ended_map_points.push_back(ending.map().size());
    ended_maps.push_back(ending.map().snapshot());
  }
  std::vector<MapSnapshot> ended_maps;  // in W of each stream that ended
  void on_new_stream(const std::string& why) override { log.push_back("new stream: " + why); }
  std::vector<std::size_t> ended_map_points;  // of each stream that ended
  void on_event(const LiveEvent& e) override { events.push_back(e); }

  const LiveEvent* event(const std::string& text) const {
    for (const LiveEvent& e : events) {
      if (e.message.find(text) != std::string::npos) return &e;
    }
    return nullptr;
  }
};

struct Session {
  GtSequence g;
  Recorder client;
  std::unique_ptr<LiveSession> session;
  // `recon` and `weights` (FakeModel::weights) for sessions of other
  // settings or models.
  explicit Session(int frames, LiveSessionConfig config = {}, bool calibrated = true,
                   const ReconstructionConfig& recon = gt_reconstruction_config(),
                   const std::string& weights = "fake-weights")
      : g(make_sequence(frames)) {
    client.g = &g;
    auto model = std::make_unique<FakeModel>(&g.pts_W0);
    model->weights = weights;
    session = std::make_unique<LiveSession>(std::move(model), recon, config, client);
    calibrated_ = calibrated;
  }
  // Frame k at stamp_s, arriving when the clock reads clock_s (default: the stamp).
  void push(int k, double stamp_s, double clock_s = -1.0,
            std::optional<CameraModel> camera = std::nullopt) {
    LiveFrame f;
    f.image = g.bgr[static_cast<std::size_t>(k)];
    f.encoding = "bgr8";
    f.stamp_s = stamp_s;
    f.clock_s = clock_s < 0.0 ? stamp_s : clock_s;
    f.camera = camera        ? camera
               : calibrated_ ? std::optional<CameraModel>(camera_model(g.seq.config.intrinsics))
                             : std::nullopt;
    f.tag = k;
    session->push(std::move(f));
  }
  std::vector<int> tags() const {
    std::vector<int> t;
    for (const LiveResult& r : client.results) t.push_back(std::any_cast<int>(r.tag));
    return t;
  }

 private:
  bool calibrated_ = true;
};

}  // namespace long3r::test
