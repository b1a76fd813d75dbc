// Poses and intrinsics in saved states; see
// include/long3r/mapping/state_geometry.hpp.
#include "long3r/mapping/state_geometry.hpp"

#include <ATen/ATen.h>

#include <cmath>
#include <vector>

namespace long3r {

at::Tensor pose_to_tensor(const Eigen::Isometry3d& T) {
  at::Tensor t = at::empty({4, 4}, at::kDouble);
  Eigen::Map<Eigen::Matrix<double, 4, 4, Eigen::RowMajor>>(t.data_ptr<double>()) = T.matrix();
  return t;
}

std::optional<Eigen::Isometry3d> pose_from_tensor(const at::Tensor& t) {
  if (!t.defined() || t.dim() != 2 || t.size(0) != 4 || t.size(1) != 4 ||
      !at::isFloatingType(t.scalar_type())) {
    return std::nullopt;
  }
  const at::Tensor c = t.to(at::kDouble).contiguous();
  const Eigen::Matrix4d m =
      Eigen::Map<const Eigen::Matrix<double, 4, 4, Eigen::RowMajor>>(c.data_ptr<double>());
  const Eigen::Matrix3d R = m.topLeftCorner<3, 3>();
  if (!m.allFinite() || (R * R.transpose() - Eigen::Matrix3d::Identity()).norm() > 1e-6 ||
      std::abs(R.determinant() - 1.0) > 1e-6 ||
      m.row(3) != Eigen::RowVector4d(0.0, 0.0, 0.0, 1.0)) {
    return std::nullopt;
  }
  Eigen::Isometry3d T;
  T.matrix() = m;
  return T;
}

Eigen::Isometry3d read_pose(const StateReader& r, const std::string& key) {
  const std::optional<Eigen::Isometry3d> T = pose_from_tensor(r.floating(key, {4, 4}));
  if (!T) r.fail(key, "not a rigid transform");
  return *T;
}

at::Tensor intrinsics_to_tensor(const PinholeIntrinsics& k) {
  return at::tensor(std::vector<double>{k.fx, k.fy, k.cx, k.cy, double(k.width), double(k.height)},
                    at::kDouble);
}

PinholeIntrinsics read_intrinsics(const StateReader& r, const std::string& key) {
  const at::Tensor t = r.floating(key, {6}).to(at::kDouble).contiguous();
  const double* v = t.data_ptr<double>();
  PinholeIntrinsics k;
  k.fx = v[0];
  k.fy = v[1];
  k.cx = v[2];
  k.cy = v[3];
  k.width = static_cast<int>(v[4]);
  k.height = static_cast<int>(v[5]);
  if (!k.valid() || v[4] < 0 || v[5] < 0 || v[4] > 1e5 || v[5] > 1e5) {
    r.fail(key, "not valid intrinsics");
  }
  return k;
}

}  // namespace long3r
