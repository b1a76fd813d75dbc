#include "long3r/tracking/feature_matching.hpp"

namespace long3r {

cv::Ptr<cv::ORB> make_orb(int max_features, int fast_threshold, int pyramid_levels) {
  return cv::ORB::create(max_features, 1.2f, pyramid_levels, 31, 0, 2, cv::ORB::HARRIS_SCORE, 31,
                         fast_threshold);
}

std::vector<cv::DMatch> ratio_matches(const cv::Mat& query, const cv::Mat& train, double ratio) {
  std::vector<cv::DMatch> out;
  if (query.empty() || train.empty()) return out;
  std::vector<std::vector<cv::DMatch>> knn;
  cv::BFMatcher(cv::NORM_HAMMING).knnMatch(query, train, knn, 2);
  std::vector<cv::DMatch> best(static_cast<std::size_t>(train.rows));
  std::vector<bool> found(static_cast<std::size_t>(train.rows), false);
  for (const auto& m : knn) {
    if (m.empty()) continue;
    if (m.size() == 2 && m[0].distance > ratio * m[1].distance) continue;
    const auto k = static_cast<std::size_t>(m[0].trainIdx);
    if (!found[k] || m[0].distance < best[k].distance) {
      best[k] = m[0];
      found[k] = true;
    }
  }
  for (std::size_t k = 0; k < best.size(); ++k) {
    if (found[k]) out.push_back(best[k]);
  }
  return out;
}

}  // namespace long3r
