#include "long3r_ros/params.hpp"

#include <sstream>

namespace long3r_ros {

namespace {

// Reads `name` if set. A value of the wrong XML-RPC type is an error rather
// than a silent fallback to the default.
template <typename T>
void read(const ros::NodeHandle& pnh, const std::string& name, T& value) {
  if (!pnh.hasParam(name)) return;
  if (!pnh.getParam(name, value)) {
    throw ParamError("parameter " + pnh.resolveName(name) + " has the wrong type");
  }
}

// Integers given as whole doubles (e.g. 2.0) are accepted; others are not.
void read(const ros::NodeHandle& pnh, const std::string& name, double& value) {
  if (!pnh.hasParam(name)) return;
  int as_int = 0;
  if (pnh.getParam(name, value)) return;
  if (pnh.getParam(name, as_int)) {
    value = as_int;
    return;
  }
  throw ParamError("parameter " + pnh.resolveName(name) + " must be a number");
}

void require(bool ok, const ros::NodeHandle& pnh, const std::string& name,
             const std::string& what) {
  if (!ok) throw ParamError("parameter " + pnh.resolveName(name) + " " + what);
}

}  // namespace

NodeletConfig readNodeletConfig(const ros::NodeHandle& pnh) {
  NodeletConfig c;
  read(pnh, "model_path", c.model_path);
  read(pnh, "world_frame", c.world_frame);
  read(pnh, "camera_frame", c.camera_frame);
  read(pnh, "publish_tf", c.publish_tf);
  read(pnh, "use_camera_info", c.use_camera_info);
  read(pnh, "image_transport", c.image_transport);
  read(pnh, "queue_size", c.queue_size);
  read(pnh, "flush_after_s", c.flush_after_s);
  read(pnh, "map_publish_period_s", c.map_publish_period_s);

  require(!c.world_frame.empty(), pnh, "world_frame", "must not be empty");
  require(c.world_frame != c.camera_frame, pnh, "camera_frame", "must differ from world_frame");
  require(!c.image_transport.empty(), pnh, "image_transport", "must not be empty");
  require(c.queue_size >= 1 && c.queue_size <= 1000, pnh, "queue_size", "must be in [1, 1000]");
  require(c.flush_after_s > 0.0, pnh, "flush_after_s", "must be > 0");
  require(c.map_publish_period_s > 0.0, pnh, "map_publish_period_s", "must be > 0");
  return c;
}

long3r::ThreadConfig readThreadConfig(const ros::NodeHandle& pnh) {
  long3r::ThreadConfig c;
  read(pnh, "torch_threads", c.torch_threads);
  read(pnh, "openblas_threads", c.openblas_threads);
  require(c.torch_threads >= 0 && c.torch_threads <= 256, pnh, "torch_threads",
          "must be in [0, 256] (0 = all cores)");
  require(c.openblas_threads >= 0 && c.openblas_threads <= 256, pnh, "openblas_threads",
          "must be in [0, 256] (0 = leave as the environment set it)");
  return c;
}

long3r::ReconstructionConfig readReconstructionConfig(const ros::NodeHandle& pnh) {
  long3r::ReconstructionConfig c;
  read(pnh, "model_width", c.preprocess.width);
  read(pnh, "model_height", c.preprocess.height);
  double conf = c.conf_threshold;
  read(pnh, "conf_threshold", conf);
  read(pnh, "voxel_size_m", c.map.voxel_size_m);
  int max_points = static_cast<int>(c.map.max_points);
  read(pnh, "max_map_points", max_points);
  read(pnh, "pnp_reprojection_error_px", c.pnp.reprojection_error_px);
  read(pnh, "pnp_min_inliers", c.pnp.min_inliers);
  read(pnh, "pnp_iterations", c.pnp.iterations);
  read(pnh, "pnp_max_correspondences", c.pnp.max_correspondences);

  auto multiple_of_16 = [](int v) { return v >= 16 && v <= 4096 && v % 16 == 0; };
  require(multiple_of_16(c.preprocess.width), pnh, "model_width",
          "must be a multiple of 16 in [16, 4096]");
  require(multiple_of_16(c.preprocess.height), pnh, "model_height",
          "must be a multiple of 16 in [16, 4096]");
  require(conf >= 1.0, pnh, "conf_threshold", "must be >= 1 (the model's confidence starts at 1)");
  require(c.map.voxel_size_m > 0.0, pnh, "voxel_size_m", "must be > 0");
  require(max_points >= 1, pnh, "max_map_points", "must be >= 1");
  require(c.pnp.reprojection_error_px > 0.0, pnh, "pnp_reprojection_error_px", "must be > 0");
  require(c.pnp.min_inliers >= 4, pnh, "pnp_min_inliers", "must be >= 4");
  require(c.pnp.iterations >= 1, pnh, "pnp_iterations", "must be >= 1");
  require(c.pnp.max_correspondences >= c.pnp.min_inliers, pnh, "pnp_max_correspondences",
          "must be >= pnp_min_inliers");
  c.conf_threshold = static_cast<float>(conf);
  c.map.conf_threshold = c.conf_threshold;
  c.pnp.conf_threshold = c.conf_threshold;
  c.map.max_points = static_cast<std::size_t>(max_points);
  return c;
}

std::string describe(const NodeletConfig& c) {
  std::ostringstream s;
  s << "model_path: " << (c.model_path.empty() ? "(package default)" : c.model_path)
    << "\nworld_frame: " << c.world_frame
    << "\ncamera_frame: " << (c.camera_frame.empty() ? "(from image header)" : c.camera_frame)
    << "\npublish_tf: " << std::boolalpha << c.publish_tf
    << "\nuse_camera_info: " << c.use_camera_info << "\nimage_transport: " << c.image_transport
    << "\nqueue_size: " << c.queue_size << "\nflush_after_s: " << c.flush_after_s
    << "\nmap_publish_period_s: " << c.map_publish_period_s;
  return s.str();
}

std::string describe(const long3r::ThreadConfig& c) {
  std::ostringstream s;
  s << "torch_threads: " << c.torch_threads << (c.torch_threads == 0 ? " (all cores)" : "")
    << "\nopenblas_threads: " << c.openblas_threads
    << (c.openblas_threads == 0 ? " (from environment)" : "");
  return s.str();
}

std::string describe(const long3r::ReconstructionConfig& c) {
  std::ostringstream s;
  s << "model_width: " << c.preprocess.width << "\nmodel_height: " << c.preprocess.height
    << "\nconf_threshold: " << c.conf_threshold << "\nvoxel_size_m: " << c.map.voxel_size_m
    << "\nmax_map_points: " << c.map.max_points
    << "\npnp_reprojection_error_px: " << c.pnp.reprojection_error_px
    << "\npnp_min_inliers: " << c.pnp.min_inliers << "\npnp_iterations: " << c.pnp.iterations
    << "\npnp_max_correspondences: " << c.pnp.max_correspondences;
  return s.str();
}

}  // namespace long3r_ros
