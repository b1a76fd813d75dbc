// Poses and camera intrinsics in saved states (sessions; state_dict.hpp),
// for the maps here and the pipeline above them: a pose is a [4, 4] float64
// tensor, intrinsics a [6] float64 one (fx, fy, cx, cy, width, height).
#pragma once

#include <ATen/core/Tensor.h>
#include <Eigen/Geometry>

#include <optional>
#include <string>

#include "long3r/geometry/pinhole_intrinsics.hpp"
#include "long3r/model/loading/state_dict.hpp"

namespace long3r {

at::Tensor pose_to_tensor(const Eigen::Isometry3d& T);
// nullopt unless the tensor is [4, 4], finite and a rigid transform
// (orthonormal rotation with det 1 to 1e-6, last row 0 0 0 1).
std::optional<Eigen::Isometry3d> pose_from_tensor(const at::Tensor& t);
// The pose under `key`; StateError naming it unless it is one.
Eigen::Isometry3d read_pose(const StateReader& r, const std::string& key);

at::Tensor intrinsics_to_tensor(const PinholeIntrinsics& k);
// The intrinsics under `key`; StateError naming it unless they are valid.
PinholeIntrinsics read_intrinsics(const StateReader& r, const std::string& key);

}  // namespace long3r
