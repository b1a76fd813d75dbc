// Evaluation metrics of the paper (LONG3R, experiments section):
//
// Reconstruction (as Spann3R's evaluation defines them), on point clouds in
// metres after aligning the prediction to the ground truth:
//   accuracy     for each predicted point, distance to the nearest GT point;
//                mean and median
//   completion   for each GT point, distance to the nearest predicted point;
//                mean and median
//   normal consistency  |n_pred . n_gt| for the same nearest-neighbour pairs
//                (pred->GT: "accuracy" direction, GT->pred: "completion"
//                direction), mean and median; normals by PCA over the k = 30
//                nearest neighbours (Open3D's estimate_normals default); the
//                overall NC is the average of the two directions
//   completion ratio  fraction of GT points with a prediction within 5 cm
//
// Trajectory (as evo computes them: evo_ape / evo_rpe with --align
// --correct_scale), on TUM trajectories associated by timestamp:
//   ATE          RMSE of ||t_est_aligned - t_gt|| after Sim(3) Umeyama
//                alignment of the estimated positions to the GT positions
//   RPE trans    ||trans(E_i)||, E_i = (Q_i^-1 Q_j)^-1 (P_i^-1 P_j) over the
//                pairs (i, j = i + delta), delta = 1 frame by default
//   RPE rot      rotation angle of E_i in degrees
// Statistics (rmse, mean, median, std, min, max, sse) follow numpy / evo.
#pragma once

#include <Eigen/Geometry>
#include <opencv2/core.hpp>

#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "long3r/dataset/tum_dataset.hpp"
#include "long3r/geometry/pinhole_intrinsics.hpp"
#include "long3r/geometry/umeyama.hpp"

namespace long3r {

// ------------------------------------------------------------- statistics

struct ErrorStatistics {
  double rmse = 0, mean = 0, median = 0, std = 0, min = 0, max = 0, sse = 0;
  size_t count = 0;
};
// numpy conventions: median averages the middle pair, std has ddof = 0.
// All zeros for an empty input.
ErrorStatistics error_statistics(const std::vector<double>& errors);

// ------------------------------------------------------------- point clouds
// (files: long3r/geometry/cv/point_cloud_io.hpp)

// Centroid of the points in each voxel (cubes of `voxel` metres), in order of
// first occurrence. voxel <= 0 returns the input.
std::vector<Eigen::Vector3f> voxel_downsample(const std::vector<Eigen::Vector3f>& points,
                                              double voxel);

// World points of a depth map (CV_32FC1 metres) with T_W_C; every
// `pixel_step`-th pixel in both directions, depths in (min_depth, max_depth].
std::vector<Eigen::Vector3f> backproject_depth(const cv::Mat& depth, const PinholeIntrinsics& k,
                                               const Eigen::Isometry3d& T_W_C, int pixel_step = 1,
                                               double min_depth = 1e-3, double max_depth = 1e9);

struct GroundTruthCloudOptions {
  int frame_step = 10;  // every n-th frame with depth and pose (Spann3R uses keyframes)
  int pixel_step = 1;
  double min_depth = 1e-3, max_depth = 1e9;
};
// GT cloud of a TUM-layout dataset from depth + ground-truth poses.
// Throws std::runtime_error when no frame has both.
std::vector<Eigen::Vector3f> ground_truth_cloud(const TumDataset& dataset,
                                                const PinholeIntrinsics& intrinsics,
                                                const GroundTruthCloudOptions& options = {});

// ------------------------------------------------------------- reconstruction

// Unit normals by PCA over the k nearest neighbours (the point included);
// arbitrary sign. Points with fewer than 3 neighbours get (0, 0, 0).
std::vector<Eigen::Vector3f> estimate_normals(const std::vector<Eigen::Vector3f>& points,
                                              int k = 30, int threads = 2);

struct IcpOptions {
  double max_correspondence_distance = 0.1;  // metres (Spann3R uses 0.1)
  int max_iterations = 30;                   // Open3D's default
  double relative_fitness = 1e-6;            // stop when both change less than this
  double relative_rmse = 1e-6;
  bool estimate_scale = false;  // rigid by default; true: Sim(3) per iteration
  int threads = 2;
};
struct IcpResult {
  Sim3 transform;        // source -> target, including the initial guess
  double fitness = 0.0;  // fraction of source points with a correspondence
  double inlier_rmse = 0.0;
  int iterations = 0;
};
// Point-to-point ICP from `initial`. Throws std::invalid_argument on empty clouds.
IcpResult icp_point_to_point(const std::vector<Eigen::Vector3f>& source,
                             const std::vector<Eigen::Vector3f>& target, const Sim3& initial,
                             const IcpOptions& options = {});

struct ReconstructionMetricsOptions {
  int normal_neighbours = 30;
  double completion_ratio_threshold = 0.05;  // metres
  bool normals = true;                       // skip normal consistency (and its cost) when false
  bool keep_errors = true;                   // fill the per-point error vectors
  int threads = 2;
};
struct ReconstructionMetrics {
  double accuracy_mean = 0, accuracy_median = 0;
  double completion_mean = 0, completion_median = 0;
  double nc_accuracy_mean = 0, nc_accuracy_median = 0;      // pred -> GT pairs
  double nc_completion_mean = 0, nc_completion_median = 0;  // GT -> pred pairs
  double nc_mean = 0, nc_median = 0;                        // averages of the two directions
  double completion_ratio = 0;
  size_t num_pred = 0, num_gt = 0;
  std::vector<float> accuracy_errors;    // per predicted point (keep_errors)
  std::vector<float> completion_errors;  // per GT point (keep_errors)
};
// Metrics of an already aligned prediction. Throws std::invalid_argument on
// empty clouds.
ReconstructionMetrics reconstruction_metrics(const std::vector<Eigen::Vector3f>& pred,
                                             const std::vector<Eigen::Vector3f>& gt,
                                             const ReconstructionMetricsOptions& options = {});

struct ReconstructionEvalOptions {
  Sim3 initial;     // applied to the prediction first (e.g. the trajectory alignment)
  bool icp = true;  // then refined by ICP (default: rigid, 0.1 m, as Spann3R)
  IcpOptions icp_options;
  ReconstructionMetricsOptions metrics;
};
struct ReconstructionEvalResult {
  Sim3 alignment;  // pred -> GT, the one the metrics use
  std::optional<IcpResult> icp;
  ReconstructionMetrics metrics;
  std::vector<Eigen::Vector3f> pred_aligned;
};
ReconstructionEvalResult evaluate_reconstruction(const std::vector<Eigen::Vector3f>& pred,
                                                 const std::vector<Eigen::Vector3f>& gt,
                                                 const ReconstructionEvalOptions& options = {});

// ------------------------------------------------------------- trajectories

// evo's matching (sync.associate_trajectories): for each stamp of the shorter
// trajectory (the estimate when equally long) the first closest stamp of the
// other, kept when |dt| <= max_diff; `offset` is added to the estimate's
// stamps. Returns (ref index, est index) pairs in the shorter one's order.
std::vector<std::pair<int, int>> associate_trajectories(const PoseTrajectory& ref,
                                                        const PoseTrajectory& est,
                                                        double max_diff = 0.01,
                                                        double offset = 0.0);

// ||t_est_i - t_ref_i|| for associated (and aligned) poses.
std::vector<double> ate_translation_errors(const std::vector<Eigen::Isometry3d>& ref,
                                           const std::vector<Eigen::Isometry3d>& est);

struct RpeErrors {
  std::vector<std::pair<int, int>> pairs;
  std::vector<double> translation;   // same unit as the poses
  std::vector<double> rotation_deg;  // degrees
};
// Pairs as evo's frame delta: consecutive (0, d), (d, 2d), ... or, with
// all_pairs, (i, i + d) for every i. Throws std::invalid_argument if delta < 1
// or no pair exists.
RpeErrors rpe_errors(const std::vector<Eigen::Isometry3d>& ref,
                     const std::vector<Eigen::Isometry3d>& est, int delta = 1,
                     bool all_pairs = false);

struct TrajectoryEvalOptions {
  double max_diff = 0.01;  // association, seconds (evo's default)
  double offset = 0.0;     // added to the estimate's stamps
  bool align = true;
  bool correct_scale = true;  // Sim(3); false: SE(3)
  int rpe_delta = 1;          // frames
  bool rpe_all_pairs = false;
};
struct TrajectoryMetrics {
  size_t matched = 0;
  Sim3 alignment;  // est -> ref (identity without align)
  ErrorStatistics ate, rpe_translation, rpe_rotation_deg;
  std::vector<double> stamps;          // reference stamps of the matches
  std::vector<Eigen::Isometry3d> ref;  // matched reference poses
  std::vector<Eigen::Isometry3d> est_aligned;
  std::vector<double> ate_errors;
  RpeErrors rpe;
};
// Throws std::invalid_argument when fewer than 3 poses match (or as rpe_errors).
TrajectoryMetrics evaluate_trajectory(const PoseTrajectory& ref, const PoseTrajectory& est,
                                      const TrajectoryEvalOptions& options = {});

// ------------------------------------------------------------- plots

// "Up" of a camera trajectory: minus the mean camera y axis (image down),
// normalised; +z if undefined. Top views look down along it.
Eigen::Vector3d estimate_up_axis(const std::vector<Eigen::Isometry3d>& poses);

// Top view (orthographic, along -up) of the reference (green) and the aligned
// estimate (red), with error segments between matched positions, a scale bar
// and `title`.
cv::Mat plot_trajectory_top_view(const std::vector<Eigen::Vector3d>& ref,
                                 const std::vector<Eigen::Vector3d>& est, const Eigen::Vector3d& up,
                                 const std::string& title, int size = 800);

// Two top-view panels: predicted points coloured by accuracy error and GT
// points coloured by completion error (mean error per cell, colour map
// saturating at max_error metres), with colour bars.
cv::Mat plot_error_top_view(const std::vector<Eigen::Vector3f>& pred,
                            const std::vector<float>& pred_errors,
                            const std::vector<Eigen::Vector3f>& gt,
                            const std::vector<float>& gt_errors, const Eigen::Vector3d& up,
                            double max_error, int panel_size = 600);

// One curve of plot_line_chart; colour in OpenCV BGR.
struct PlotSeries {
  std::string label;
  std::vector<double> x, y;  // same length; non-finite points are skipped
  cv::Scalar colour{0, 0, 0};
  int thickness = 1;
};
// Line chart with axes, ticks, a legend and `title`; log_y plots log10(y)
// (non-positive values skipped). Empty series give an empty frame.
cv::Mat plot_line_chart(const std::vector<PlotSeries>& series, const std::string& title,
                        const std::string& x_label, bool log_y, int width = 900, int height = 560);

}  // namespace long3r
