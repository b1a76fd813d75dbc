#include "long3r/tracking/feature_matching.hpp"

#include <opencv2/core.hpp>

#include <algorithm>
#include <cmath>
#include <limits>
#include <stdexcept>

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

std::vector<cv::DMatch> projected_matches(const std::vector<cv::KeyPoint>& query_keypoints,
                                          const cv::Mat& query,
                                          const std::vector<cv::Point2f>& predicted,
                                          const cv::Mat& train, double radius_px, int max_distance,
                                          double ratio) {
  if (static_cast<std::size_t>(query.rows) != query_keypoints.size() ||
      static_cast<std::size_t>(train.rows) != predicted.size() ||
      (!query.empty() && !train.empty() && query.cols != train.cols)) {
    throw std::invalid_argument("projected_matches: descriptors and pixels of different lengths");
  }
  std::vector<cv::DMatch> out;
  if (query.empty() || train.empty() || !(radius_px > 0.0)) return out;
  // The query features in square cells at least the radius wide (and no
  // more than 512 of them across): a prediction's candidates lie in its
  // cell's 3 x 3 block.
  float x_min = std::numeric_limits<float>::max(), y_min = x_min;
  float x_max = std::numeric_limits<float>::lowest(), y_max = x_max;
  for (const cv::KeyPoint& k : query_keypoints) {
    x_min = std::min(x_min, k.pt.x);
    y_min = std::min(y_min, k.pt.y);
    x_max = std::max(x_max, k.pt.x);
    y_max = std::max(y_max, k.pt.y);
  }
  const double cell =
      std::max(radius_px, static_cast<double>(std::max(x_max - x_min, y_max - y_min)) / 512.0);
  const int cols = static_cast<int>((x_max - x_min) / cell) + 1;
  const int rows = static_cast<int>((y_max - y_min) / cell) + 1;
  std::vector<std::vector<int>> grid(static_cast<std::size_t>(cols) * rows);
  for (std::size_t i = 0; i < query_keypoints.size(); ++i) {
    const int cx = static_cast<int>((query_keypoints[i].pt.x - x_min) / cell);
    const int cy = static_cast<int>((query_keypoints[i].pt.y - y_min) / cell);
    grid[static_cast<std::size_t>(cy) * cols + cx].push_back(static_cast<int>(i));
  }
  const double r2 = radius_px * radius_px;
  // For each query feature its closest train feature so far (trainIdx -1: none).
  std::vector<cv::DMatch> best(query_keypoints.size(), cv::DMatch(-1, -1, 0.0f));
  for (int t = 0; t < train.rows; ++t) {
    const cv::Point2f& p = predicted[static_cast<std::size_t>(t)];
    if (!std::isfinite(p.x) || !std::isfinite(p.y)) continue;
    const double fx = std::floor((p.x - x_min) / cell), fy = std::floor((p.y - y_min) / cell);
    if (fx < -1.0 || fy < -1.0 || fx > cols || fy > rows) continue;  // no cell within reach
    const int cx = static_cast<int>(fx), cy = static_cast<int>(fy);
    int first = -1;
    double d1 = std::numeric_limits<double>::max(), d2 = d1;
    for (int y = std::max(0, cy - 1); y <= std::min(rows - 1, cy + 1); ++y) {
      for (int x = std::max(0, cx - 1); x <= std::min(cols - 1, cx + 1); ++x) {
        for (int q : grid[static_cast<std::size_t>(y) * cols + x]) {
          const cv::Point2f d = query_keypoints[static_cast<std::size_t>(q)].pt - p;
          if (static_cast<double>(d.x) * d.x + static_cast<double>(d.y) * d.y > r2) continue;
          const double h = cv::norm(query.row(q), train.row(t), cv::NORM_HAMMING);
          if (h < d1) {
            d2 = d1;
            d1 = h;
            first = q;
          } else if (h < d2) {
            d2 = h;
          }
        }
      }
    }
    if (first < 0 || d1 > max_distance ||
        (d2 < std::numeric_limits<double>::max() && d1 > ratio * d2)) {
      continue;
    }
    cv::DMatch& b = best[static_cast<std::size_t>(first)];
    if (b.trainIdx < 0 || d1 < b.distance) b = cv::DMatch(first, t, static_cast<float>(d1));
  }
  for (const cv::DMatch& m : best) {
    if (m.trainIdx >= 0) out.push_back(m);
  }
  std::sort(out.begin(), out.end(),
            [](const cv::DMatch& a, const cv::DMatch& b) { return a.trainIdx < b.trainIdx; });
  return out;
}

}  // namespace long3r
