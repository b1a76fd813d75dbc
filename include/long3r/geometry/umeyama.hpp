// Similarity transforms and their least-squares estimation from corresponding
// points (Umeyama, "Least-squares estimation of transformation parameters
// between two point patterns", IEEE PAMI 1991).
//
// A Sim3 maps a point p to s * R * p + t. Used to align an estimated
// trajectory or reconstruction (arbitrary frame and scale) to ground truth,
// and by any code that needs a rigid or similarity fit.
#pragma once

#include <Eigen/Core>
#include <Eigen/Geometry>

#include <vector>

namespace long3r {

struct Sim3 {
  double scale = 1.0;
  Eigen::Matrix3d rotation = Eigen::Matrix3d::Identity();
  Eigen::Vector3d translation = Eigen::Vector3d::Zero();

  Eigen::Vector3d operator*(const Eigen::Vector3d& p) const {
    return scale * (rotation * p) + translation;
  }
  // Composition: (a * b) * p == a * (b * p).
  Sim3 operator*(const Sim3& other) const;
  Sim3 inverse() const;
  Eigen::Matrix4d matrix() const;  // [[sR, t], [0, 1]]

  // Moves a camera pose T_W_C of the source frame into the target frame the
  // way trajectory evaluation does (evo's scale() then transform()): rotation
  // R * R_c, translation s * R * t_c + t. The result stays a rigid pose.
  Eigen::Isometry3d apply_to_pose(const Eigen::Isometry3d& pose) const;
};

// Sim(3) (with_scale) or SE(3) minimising sum_i ||dst_i - (s R src_i + t)||^2.
// src and dst are 3xN with column i corresponding. Scale follows Umeyama
// (variance of src in the denominator). Throws std::invalid_argument when the
// sizes differ, N < 3, or the points are degenerate (cross-covariance of rank
// < 2, e.g. all points on one line).
Sim3 umeyama_alignment(const Eigen::Matrix3Xd& src, const Eigen::Matrix3Xd& dst,
                       bool with_scale = true);

// umeyama_alignment of corresponding float points (pred[i] <-> gt[i]); also
// throws std::invalid_argument when the two differ in size.
Sim3 align_correspondences(const std::vector<Eigen::Vector3f>& pred,
                           const std::vector<Eigen::Vector3f>& gt, bool with_scale = true);

}  // namespace long3r
