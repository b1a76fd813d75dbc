#include "long3r/pipeline/keyframe_state.hpp"

#include <ATen/ATen.h>

#include <cmath>
#include <cstring>

#include "long3r/mapping/state_geometry.hpp"

namespace long3r {

namespace {

constexpr int64_t kVersion = 1;
constexpr int64_t kDescriptorBytes = 32;  // ORB
constexpr double kUnitTolerance = 1e-3;   // float32 rays

}  // namespace

void put_keyframes(StateDict& out, const std::string& prefix,
                   const std::deque<KeptKeyframe>& keyframes) {
  const int64_t k = static_cast<int64_t>(keyframes.size());
  int64_t n = 0;
  for (const KeptKeyframe& kf : keyframes) n += static_cast<int64_t>(kf.pixels.size());
  at::Tensor offsets = at::empty({k + 1}, at::kLong);
  at::Tensor poses = at::empty({k, 4, 4}, at::kDouble);
  at::Tensor pixels = at::empty({n, 2}, at::kFloat);
  at::Tensor bearings = at::empty({n, 3}, at::kFloat);
  at::Tensor points = at::empty({n, 3}, at::kFloat);
  at::Tensor descriptors = at::empty({n, kDescriptorBytes}, at::kByte);
  int64_t* o = offsets.data_ptr<int64_t>();
  float* px = pixels.data_ptr<float>();
  float* b = bearings.data_ptr<float>();
  float* p = points.data_ptr<float>();
  uint8_t* d = descriptors.data_ptr<uint8_t>();
  int64_t at_feature = 0;
  for (int64_t i = 0; i < k; ++i) {
    const KeptKeyframe& kf = keyframes[static_cast<std::size_t>(i)];
    o[i] = at_feature;
    poses[i].copy_(pose_to_tensor(kf.T_W_K));
    for (std::size_t j = 0; j < kf.pixels.size(); ++j, ++at_feature) {
      px[2 * at_feature] = kf.pixels[j].x;
      px[2 * at_feature + 1] = kf.pixels[j].y;
      for (int c = 0; c < 3; ++c) {
        b[3 * at_feature + c] = static_cast<float>(kf.bearings[j][c]);
        p[3 * at_feature + c] =
            kf.points[j] ? static_cast<float>((*kf.points[j])[c]) : std::nanf("");
      }
      std::memcpy(d + kDescriptorBytes * at_feature,
                  kf.descriptors.ptr<uint8_t>(static_cast<int>(j)), kDescriptorBytes);
    }
  }
  o[k] = at_feature;
  put_int(out, prefix + "version", kVersion);
  out[prefix + "offsets"] = offsets;
  out[prefix + "T_W_K"] = poses;
  out[prefix + "pixels"] = pixels;
  out[prefix + "bearings"] = bearings;
  out[prefix + "points"] = points;
  out[prefix + "descriptors"] = descriptors;
}

std::vector<KeptKeyframe> read_keyframes(const StateReader& r) {
  const int64_t version = r.integer("version");
  if (version != kVersion) {
    r.fail("version", "keyframes of layout version " + std::to_string(version) +
                          "; this build reads version " + std::to_string(kVersion));
  }
  const at::Tensor offsets = r.int64("offsets", {-1}).contiguous();
  const int64_t k = offsets.size(0) - 1;
  if (k < 0) r.fail("offsets", "empty (it holds the keyframes' bounds)");
  const int64_t* o = offsets.data_ptr<int64_t>();
  if (o[0] != 0) r.fail("offsets", "does not start at 0");
  for (int64_t i = 0; i < k; ++i) {
    if (o[i + 1] < o[i]) r.fail("offsets", "decreases at " + std::to_string(i + 1));
  }
  const int64_t n = o[k];
  const at::Tensor poses = r.floating("T_W_K", {k, 4, 4});
  const at::Tensor pixels = r.floating("pixels", {n, 2}).to(at::kFloat).contiguous();
  const at::Tensor bearings = r.floating("bearings", {n, 3}).to(at::kFloat).contiguous();
  const at::Tensor points =
      r.floating("points", {n, 3}, /*finite=*/false).to(at::kFloat).contiguous();
  const at::Tensor descriptors = r.uint8("descriptors", {n, kDescriptorBytes}).contiguous();
  const float* px = pixels.data_ptr<float>();
  const float* b = bearings.data_ptr<float>();
  const float* p = points.data_ptr<float>();
  const uint8_t* d = descriptors.data_ptr<uint8_t>();

  std::vector<KeptKeyframe> out(static_cast<std::size_t>(k));
  for (int64_t i = 0; i < k; ++i) {
    KeptKeyframe& kf = out[static_cast<std::size_t>(i)];
    const std::optional<Eigen::Isometry3d> T = pose_from_tensor(poses[i]);
    if (!T) r.fail("T_W_K", "keyframe " + std::to_string(i) + ": not a rigid transform");
    kf.T_W_K = *T;
    const int64_t begin = o[i], count = o[i + 1] - o[i];
    kf.descriptors = cv::Mat(static_cast<int>(count), kDescriptorBytes, CV_8UC1);
    if (count > 0) {
      std::memcpy(kf.descriptors.data, d + kDescriptorBytes * begin,
                  static_cast<std::size_t>(kDescriptorBytes * count));
    }
    for (int64_t j = begin; j < begin + count; ++j) {
      kf.pixels.emplace_back(px[2 * j], px[2 * j + 1]);
      const Eigen::Vector3d ray(b[3 * j], b[3 * j + 1], b[3 * j + 2]);
      if (std::abs(ray.norm() - 1.0) > kUnitTolerance) {
        r.fail("bearings", "feature " + std::to_string(j) + ": not a unit ray");
      }
      kf.bearings.push_back(ray.normalized());
      const Eigen::Vector3d X(p[3 * j], p[3 * j + 1], p[3 * j + 2]);
      const int finite = std::isfinite(X.x()) + std::isfinite(X.y()) + std::isfinite(X.z());
      if (finite == 3 && X.z() > 0.0) {
        kf.points.emplace_back(X);
      } else if (finite == 0) {
        kf.points.emplace_back(std::nullopt);
      } else {
        r.fail("points", "feature " + std::to_string(j) +
                             ": neither a point in front of the camera nor none (NaN)");
      }
    }
    kf.median_depth = median_depth(kf.points);
  }
  return out;
}

}  // namespace long3r
