#include "long3r/geometry/umeyama.hpp"

#include <Eigen/SVD>

#include <limits>
#include <stdexcept>

namespace long3r {

Sim3 Sim3::operator*(const Sim3& other) const {
  Sim3 out;
  out.scale = scale * other.scale;
  out.rotation = rotation * other.rotation;
  out.translation = scale * (rotation * other.translation) + translation;
  return out;
}

Sim3 Sim3::inverse() const {
  Sim3 out;
  out.scale = 1.0 / scale;
  out.rotation = rotation.transpose();
  out.translation = -(out.scale * (out.rotation * translation));
  return out;
}

Eigen::Matrix4d Sim3::matrix() const {
  Eigen::Matrix4d m = Eigen::Matrix4d::Identity();
  m.topLeftCorner<3, 3>() = scale * rotation;
  m.topRightCorner<3, 1>() = translation;
  return m;
}

Eigen::Isometry3d Sim3::apply_to_pose(const Eigen::Isometry3d& pose) const {
  Eigen::Isometry3d out = Eigen::Isometry3d::Identity();
  out.linear() = rotation * pose.linear();
  out.translation() = scale * (rotation * pose.translation()) + translation;
  return out;
}

Sim3 umeyama_alignment(const Eigen::Matrix3Xd& src, const Eigen::Matrix3Xd& dst, bool with_scale) {
  if (src.cols() != dst.cols()) {
    throw std::invalid_argument("umeyama_alignment: src and dst differ in size");
  }
  const Eigen::Index n = src.cols();
  if (n < 3) throw std::invalid_argument("umeyama_alignment: needs at least 3 points");

  const Eigen::Vector3d mean_src = src.rowwise().mean();
  const Eigen::Vector3d mean_dst = dst.rowwise().mean();
  const Eigen::Matrix3Xd src_c = src.colwise() - mean_src;
  const Eigen::Matrix3Xd dst_c = dst.colwise() - mean_dst;

  const double var_src = src_c.squaredNorm() / static_cast<double>(n);
  const Eigen::Matrix3d cov = dst_c * src_c.transpose() / static_cast<double>(n);

  Eigen::JacobiSVD<Eigen::Matrix3d> svd(cov, Eigen::ComputeFullU | Eigen::ComputeFullV);
  const Eigen::Vector3d d = svd.singularValues();
  // Rank < 2 leaves the rotation about the remaining axis undetermined.
  const double eps = std::numeric_limits<double>::epsilon() * std::max(1.0, d(0));
  if (!(d(1) > eps)) {
    throw std::invalid_argument("umeyama_alignment: degenerate point configuration");
  }

  Eigen::Vector3d s_diag(1.0, 1.0, 1.0);
  // Reflection guard: keep det(R) = +1.
  if (svd.matrixU().determinant() * svd.matrixV().determinant() < 0.0) s_diag(2) = -1.0;

  Sim3 out;
  out.rotation = svd.matrixU() * s_diag.asDiagonal() * svd.matrixV().transpose();
  if (with_scale) {
    if (!(var_src > 0.0)) throw std::invalid_argument("umeyama_alignment: zero source variance");
    out.scale = d.dot(s_diag) / var_src;
  }
  out.translation = mean_dst - out.scale * (out.rotation * mean_src);
  return out;
}

Sim3 align_correspondences(const std::vector<Eigen::Vector3f>& pred,
                           const std::vector<Eigen::Vector3f>& gt, bool with_scale) {
  if (pred.size() != gt.size()) {
    throw std::invalid_argument("align_correspondences: clouds differ in size");
  }
  Eigen::Matrix3Xd src(3, pred.size()), dst(3, gt.size());
  for (size_t i = 0; i < pred.size(); ++i) {
    src.col(i) = pred[i].cast<double>();
    dst.col(i) = gt[i].cast<double>();
  }
  return umeyama_alignment(src, dst, with_scale);
}

}  // namespace long3r
