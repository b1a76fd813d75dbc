#include "long3r_ros/output_units.hpp"

#include <utility>
#include <vector>

namespace long3r_ros {

std::string OutputUnits::held() const {
  const std::vector<std::pair<bool, const char*>> outputs{
      {poses_held, "TF, ~pose, ~odometry, ~pose_with_covariance, ~path"},
      {depth_held, "~depth"},
      {frame_cloud_held, "~frame_cloud"},
      {map_held, "~map, ~grid"}};
  std::string text;
  for (const auto& [held, names] : outputs) {
    if (!held) continue;
    text += (text.empty() ? "" : ", ") + std::string(names);
  }
  return text;
}

OutputUnits outputUnits(long3r::ScaleSource source, bool scale_metric, bool pose_from_odometry,
                        bool publish_unscaled) {
  OutputUnits u;
  if (publish_unscaled) return u;
  if (source == long3r::ScaleSource::kNone) {
    u.depth_held = true;  // REP-118: 32FC1 depth is metres
    return u;
  }
  if (scale_metric) return u;
  u.depth_held = u.frame_cloud_held = u.map_held = true;
  u.poses_held = !pose_from_odometry;
  return u;
}

std::string describeUnits(long3r::ScaleSource source, bool scale_metric, bool publish_unscaled) {
  if (source == long3r::ScaleSource::kNone) {
    return std::string("model units (scale_source none") +
           (publish_unscaled ? "; ~depth too, publish_unscaled)" : "; ~depth not published)");
  }
  if (scale_metric) return "metres";
  return publish_unscaled ? "model units until the metric scale is known (publish_unscaled)"
                          : "none yet: outputs in metres held until the metric scale is known";
}

}  // namespace long3r_ros
