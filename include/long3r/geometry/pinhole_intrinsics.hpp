// Pinhole camera intrinsics in pixels, OpenCV/TUM convention: integer pixel
// coordinates are pixel centres, (0,0) is the centre of the top-left pixel,
// and a camera-frame point (x right, y down, z forward) projects to
// u = fx * x / z + cx, v = fy * y / z + cy.
#pragma once

#include <Eigen/Core>

#include <cmath>

namespace long3r {

struct PinholeIntrinsics {
  double fx = 0.0, fy = 0.0, cx = 0.0, cy = 0.0;
  int width = 0, height = 0;  // 0 when unknown

  Eigen::Matrix3d matrix() const {
    Eigen::Matrix3d k;
    k << fx, 0.0, cx, 0.0, fy, cy, 0.0, 0.0, 1.0;
    return k;
  }
  // Camera-frame point at z-depth `depth` seen at pixel (u, v).
  Eigen::Vector3d backproject(double u, double v, double depth) const {
    return {(u - cx) / fx * depth, (v - cy) / fy * depth, depth};
  }
  // Pixel of a camera-frame point (z must be > 0).
  Eigen::Vector2d project(const Eigen::Vector3d& p) const {
    return {fx * p.x() / p.z() + cx, fy * p.y() / p.z() + cy};
  }
  bool valid() const { return fx > 0.0 && fy > 0.0; }

  // Square-pixel intrinsics for a horizontal field of view, principal point
  // at the image centre ((w-1)/2, (h-1)/2).
  static PinholeIntrinsics from_hfov(int width, int height, double hfov_deg) {
    PinholeIntrinsics k;
    k.width = width;
    k.height = height;
    k.fx = k.fy = 0.5 * width / std::tan(0.5 * hfov_deg * M_PI / 180.0);
    k.cx = 0.5 * (width - 1);
    k.cy = 0.5 * (height - 1);
    return k;
  }
};

}  // namespace long3r
