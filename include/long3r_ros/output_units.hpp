// OutputUnits: which of the node's outputs go out while their lengths are
// not metres. LONG3R reconstructs up to a scale: with a scale source set,
// lengths are in model units until the scale is known, and a consumer that
// reads metres (move_base on ~grid, robot_localization on ~odometry, voxblox
// on ~depth, anything on TF) must not get them. So, by default, while the
// scale is pending every output that carries metres is held: ~depth,
// ~frame_cloud, ~map and ~grid, and the poses (TF, ~pose, ~odometry,
// ~pose_with_covariance, ~path) unless the odometry placed them (metric by
// itself). ~pointmap always goes out: it says `metric` and `scale` itself.
// With scale_source none the user chose model units: everything goes out,
// said so in the diagnostics, except ~depth, which REP-118 defines in metres.
// publish_unscaled: true sends every held output in model units meanwhile.
#pragma once

#include <string>

#include "long3r/pipeline/metric_scale.hpp"

namespace long3r_ros {

struct OutputUnits {
  bool depth_held = false;        // ~depth
  bool frame_cloud_held = false;  // ~frame_cloud
  bool map_held = false;          // ~map, ~grid
  bool poses_held = false;        // TF, ~pose, ~odometry, ~pose_with_covariance, ~path

  bool anyHeld() const { return depth_held || frame_cloud_held || map_held || poses_held; }
  // "~depth, ~frame_cloud, ..." of the held outputs; "" when none.
  std::string held() const;
};

// `pose_from_odometry`: the poses are the odometry's (metric whatever the
// model's scale); `scale_metric`: the scale in use is metres per model unit.
OutputUnits outputUnits(long3r::ScaleSource source, bool scale_metric, bool pose_from_odometry,
                        bool publish_unscaled);

// For the diagnostics: "metres", "model units (scale_source none)", ...
std::string describeUnits(long3r::ScaleSource source, bool scale_metric, bool publish_unscaled);

}  // namespace long3r_ros
