// The TUM-layout sequence writer.
#include <nlohmann/json.hpp>
#include <opencv2/imgcodecs.hpp>

#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <optional>
#include <sstream>
#include <stdexcept>

#include "long3r/dataset/image_file.hpp"
#include "long3r/dataset/tum_dataset.hpp"
#include "long3r/io/atomic_file.hpp"
#include "long3r/synth/cv/sensor_image.hpp"
#include "long3r/synth/cv/tum_writer.hpp"

namespace long3r::synth {

namespace {

std::string stamp_name(double t) {
  char buf[64];
  std::snprintf(buf, sizeof(buf), "%.6f", t);
  return buf;
}

nlohmann::json scene_json(const Sequence& seq) {
  using nlohmann::json;
  const SequenceConfig& c = seq.config;
  auto vec = [](const auto& v) { return json::array({v.x(), v.y(), v.z()}); };
  static const char* kPattern[] = {"noise",   "tiles", "bricks", "checker",
                                   "stripes", "dots",  "wood",   "marble"};
  static const char* kShape[] = {"box", "cylinder", "sphere"};
  json j;
  j["generator"] = "long3r_synth";
  j["seed"] = c.seed;
  j["frames"] = c.trajectory.frames;
  j["fps"] = c.fps;
  j["trajectory"] = {{"type", to_string(c.trajectory.type)},
                     {"speed_m_per_frame", c.trajectory.speed},
                     {"max_yaw_rate_deg", c.trajectory.max_yaw_rate_deg},
                     {"clearance_m", c.trajectory.clearance},
                     {"height_range_m", {c.trajectory.min_height, c.trajectory.max_height}},
                     {"pitch_deg", c.trajectory.pitch_deg},
                     {"roll_deg", c.trajectory.roll_deg}};
  const PinholeIntrinsics& k = c.intrinsics;
  j["intrinsics"] = {{"fx", k.fx}, {"fy", k.fy},       {"cx", k.cx},
                     {"cy", k.cy}, {"width", k.width}, {"height", k.height}};
  // Sections of the optional effects only when used: default files stay as they were.
  if (c.trajectory.type == TrajectoryType::kRobot) {
    const CameraMount& m = c.trajectory.mount;
    j["trajectory"]["mount"] = {
        {"x_m", m.x}, {"y_m", m.y}, {"z_m", m.z}, {"pitch_deg", m.pitch_deg}};
  }
  if (c.distortion.any()) {
    j["distortion"] = {{"model", "plumb_bob"}, {"D", c.distortion.coefficients()}};
  }
  if (c.sensor.any()) {
    const SensorConfig& s = c.sensor;
    j["sensor"] = {
        {"read_noise", s.read_noise},         {"shot_noise", s.shot_noise},
        {"exposure_drift", s.exposure_drift}, {"exposure_step_prob", s.exposure_step_prob},
        {"exposure_step", s.exposure_step},   {"mono", s.mono}};
  }
  j["depth_factor"] = kTumDepthFactor;
  j["world_frame"] = "z up; room spans [0, room_size]";
  j["room_size"] = vec(seq.scene.room_size);
  j["room_material"] = json::array();
  for (int m : seq.scene.room_material) j["room_material"].push_back(m);
  j["shapes"] = json::array();
  for (const Shape& s : seq.scene.shapes) {
    j["shapes"].push_back({{"type", kShape[static_cast<int>(s.type)]},
                           {"label", s.label},
                           {"center", vec(s.center)},
                           {"half_size", vec(s.half_size)},
                           {"yaw", s.yaw},
                           {"material", s.material}});
  }
  j["materials"] = json::array();
  for (const Material& m : seq.scene.materials) {
    j["materials"].push_back({{"pattern", kPattern[static_cast<int>(m.pattern)]},
                              {"base", vec(m.base)},
                              {"accent", vec(m.accent)},
                              {"pattern_scale", m.pattern_scale},
                              {"pattern_angle", m.pattern_angle},
                              {"noise_scale", m.noise_scale},
                              {"noise_amount", m.noise_amount},
                              {"cell_variation", m.cell_variation},
                              {"seed", m.seed}});
  }
  j["lights"] = {{"ambient", seq.scene.ambient},
                 {"directional", seq.scene.directional},
                 {"direction", vec(seq.scene.light_direction)},
                 {"point", vec(seq.scene.point_light)},
                 {"point_intensity", seq.scene.point_intensity}};
  return j;
}

}  // namespace

WriteStats write_tum_sequence(const Sequence& seq, const std::string& dir,
                              const RenderOptions& options,
                              const std::function<void(int, int)>& progress, int image_every) {
  namespace fs = std::filesystem;
  using clock = std::chrono::steady_clock;
  if (seq.stamps.size() != seq.poses.size()) {
    throw std::invalid_argument("write_tum_sequence: stamps and poses differ in size");
  }
  if (image_every < 1) {
    throw std::invalid_argument("write_tum_sequence: image_every must be >= 1, got " +
                                std::to_string(image_every));
  }
  const fs::path root(dir);
  fs::create_directories(root / "rgb");
  fs::create_directories(root / "depth");

  if (!seq.base_poses.empty() && seq.base_poses.size() != seq.poses.size()) {
    throw std::invalid_argument("write_tum_sequence: base poses and poses differ in size");
  }
  if (!seq.exposure.empty() && seq.exposure.size() != seq.poses.size()) {
    throw std::invalid_argument("write_tum_sequence: exposure gains and poses differ in size");
  }
  const PinholeIntrinsics& k = seq.config.intrinsics;
  const LensDistortion& lens = seq.config.distortion;
  const SensorConfig& sensor = seq.config.sensor;
  std::optional<LensRays> rays;
  if (lens.any()) {
    rays.emplace(k, lens, options.supersample);
    write_camera_calibration((root / "calibration.txt").string(),
                             CameraCalibration{k, "plumb_bob", lens.coefficients()});
  } else {
    write_calibration_file((root / "calibration.txt").string(), k);
  }
  write_file_atomically((root / "scene.json").string(), scene_json(seq).dump(1) + "\n");
  PoseTrajectory gt;
  gt.stamps = seq.stamps;
  gt.poses = seq.poses;
  write_tum_trajectory((root / "groundtruth.txt").string(), gt,
                       "ground truth T_W_C (camera optical frame: x right, y down, z forward)");
  if (!seq.base_poses.empty()) {
    gt.poses = seq.base_poses;
    write_tum_trajectory((root / "base_groundtruth.txt").string(), gt,
                         "ground truth T_W_B (base_link: x forward, y left, z up; on the floor)");
    write_pose_file((root / "camera_mount.txt").string(),
                    seq.config.trajectory.mount.base_to_optical(),
                    "T_B_C: the camera optical frame (x right, y down, z forward) in base_link");
  }
  if (sensor.exposure()) {
    std::string text = "# exposure gain on the linear radiance\n# timestamp gain\n";
    for (size_t i = 0; i < seq.stamps.size(); ++i) {
      char gain[32];
      std::snprintf(gain, sizeof(gain), " %.9g\n", seq.exposure[i]);
      text += stamp_name(seq.stamps[i]) + gain;
    }
    write_file_atomically((root / "exposure.txt").string(), text);
  }

  // The lists are written last, so that they only ever name images on disk.
  std::ostringstream rgb_list, depth_list;
  rgb_list << "# color images\n# file: long3r_synth\n# timestamp filename\n";
  depth_list << "# depth maps (uint16, metres * " << kTumDepthFactor
             << ")\n# file: long3r_synth\n# timestamp filename\n";

  const std::vector<int> png_params = {cv::IMWRITE_PNG_COMPRESSION, 1};
  WriteStats stats;
  const int n = static_cast<int>(seq.poses.size());
  const int images = (n + image_every - 1) / image_every;
  cv::Mat depth16(k.height, k.width, CV_16UC1);
  for (int i = 0; i < n; i += image_every) {
    const auto t0 = clock::now();
    RenderOptions frame_options = options;
    if (!seq.exposure.empty()) frame_options.gain = static_cast<float>(seq.exposure[i]);
    const RenderedFrame f = rays ? render_frame(seq.scene, seq.poses[i], *rays, frame_options)
                                 : render_frame(seq.scene, seq.poses[i], k, frame_options);
    const cv::Mat image = apply_sensor(bgr_image(f), sensor, seq.config.seed, i);
    const auto t1 = clock::now();
    for (int v = 0; v < k.height; ++v) {
      const float* z = f.depth.data_ptr<float>() + static_cast<int64_t>(k.width) * v;
      uint16_t* d = depth16.ptr<uint16_t>(v);
      for (int u = 0; u < k.width; ++u) {
        const double q = std::round(z[u] * kTumDepthFactor);
        d[u] = (q > 0.0 && q <= 65535.0) ? static_cast<uint16_t>(q) : 0;
      }
    }
    const std::string name = stamp_name(seq.stamps[i]) + ".png";
    write_image_atomically((root / "rgb" / name).string(), image, png_params);
    write_image_atomically((root / "depth" / name).string(), depth16, png_params);
    rgb_list << stamp_name(seq.stamps[i]) << " rgb/" << name << "\n";
    depth_list << stamp_name(seq.stamps[i]) << " depth/" << name << "\n";
    const auto t2 = clock::now();
    stats.render_seconds += std::chrono::duration<double>(t1 - t0).count();
    stats.write_seconds += std::chrono::duration<double>(t2 - t1).count();
    ++stats.frames;
    if (progress) progress(stats.frames, images);
  }
  write_file_atomically((root / "rgb.txt").string(), rgb_list.str());
  write_file_atomically((root / "depth.txt").string(), depth_list.str());
  return stats;
}

}  // namespace long3r::synth
