#include "support/cv_test_support.hpp"

#include <cmath>

namespace long3r::test {

cv::Mat pointmap_from_depth(const PinholeIntrinsics& k, const Eigen::Isometry3d& T,
                            const std::function<double(int u, int v)>& depth) {
  cv::Mat pts(k.height, k.width, CV_32FC3, cv::Scalar::all(NAN));
  for (int v = 0; v < k.height; ++v) {
    for (int u = 0; u < k.width; ++u) {
      const double d = depth(u, v);
      if (!(d > 0.0)) continue;
      const Eigen::Vector3d X = T * k.backproject(u, v, d);
      pts.at<cv::Vec3f>(v, u) = cv::Vec3f(static_cast<float>(X.x()), static_cast<float>(X.y()),
                                          static_cast<float>(X.z()));
    }
  }
  return pts;
}

}  // namespace long3r::test
