// projected_matches (matches guided by a pose guess) on hand-made features:
// the radius, the distance bound, the ratio among the candidates and the
// one-to-one rule each decide a case.
#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <stdexcept>
#include <vector>

#include "long3r/tracking/feature_matching.hpp"

namespace long3r {
namespace {

// A 32-byte descriptor whose first `ones` bits are set.
cv::Mat descriptor(int ones) {
  cv::Mat d = cv::Mat::zeros(1, 32, CV_8UC1);
  for (int b = 0; b < ones; ++b) d.at<uchar>(0, b / 8) |= static_cast<uchar>(1u << (b % 8));
  return d;
}

cv::Mat stack(const std::vector<cv::Mat>& rows) {
  cv::Mat m;
  cv::vconcat(rows, m);
  return m;
}

constexpr float kNone = std::numeric_limits<float>::quiet_NaN();

TEST(ProjectedMatches, TakesTheClosestDescriptorWithinTheRadiusOnly) {
  // Query feature 0 sits 5 px from train 0's prediction with a near
  // descriptor; query 1 has train 0's very descriptor but lies 30 px off.
  const std::vector<cv::KeyPoint> keypoints{cv::KeyPoint(105.0f, 100.0f, 7.0f),
                                            cv::KeyPoint(130.0f, 100.0f, 7.0f)};
  const cv::Mat query = stack({descriptor(40), descriptor(0)});
  const cv::Mat train = descriptor(0);
  const auto m =
      projected_matches(keypoints, query, {cv::Point2f(100.0f, 100.0f)}, train, 8.0, 64, 0.9);
  ASSERT_EQ(m.size(), 1u);
  EXPECT_EQ(m[0].queryIdx, 0);
  EXPECT_EQ(m[0].trainIdx, 0);
  EXPECT_FLOAT_EQ(m[0].distance, 40.0f);
  // With the radius wide enough the identical descriptor wins.
  const auto wide =
      projected_matches(keypoints, query, {cv::Point2f(100.0f, 100.0f)}, train, 40.0, 64, 0.9);
  ASSERT_EQ(wide.size(), 1u);
  EXPECT_EQ(wide[0].queryIdx, 1);
}

TEST(ProjectedMatches, RefusesFarDescriptorsAmbiguityAndNoPrediction) {
  const std::vector<cv::KeyPoint> keypoints{cv::KeyPoint(10.0f, 10.0f, 7.0f),
                                            cv::KeyPoint(12.0f, 10.0f, 7.0f),
                                            cv::KeyPoint(200.0f, 200.0f, 7.0f)};
  // Query 0 and 1 are equally close to train 0 (ambiguous); query 2 is 100
  // bits from train 1 (beyond 64); train 2 has no prediction.
  const cv::Mat query = stack({descriptor(10), descriptor(10), descriptor(100)});
  const cv::Mat train = stack({descriptor(0), descriptor(0), descriptor(100)});
  const std::vector<cv::Point2f> predicted{cv::Point2f(11.0f, 10.0f), cv::Point2f(200.0f, 200.0f),
                                           cv::Point2f(kNone, kNone)};
  EXPECT_TRUE(projected_matches(keypoints, query, predicted, train, 8.0, 64, 0.9).empty());
  // Without the ratio bound the ambiguous one is taken.
  EXPECT_EQ(projected_matches(keypoints, query, predicted, train, 8.0, 64, 1.0).size(), 1u);
}

TEST(ProjectedMatches, EachQueryFeatureKeepsItsClosestTrainFeature) {
  const std::vector<cv::KeyPoint> keypoints{cv::KeyPoint(50.0f, 50.0f, 7.0f)};
  const cv::Mat query = descriptor(20);
  // Both train features predict the one query feature; train 1 is closer.
  const cv::Mat train = stack({descriptor(0), descriptor(16)});
  const auto m =
      projected_matches(keypoints, query, {cv::Point2f(48.0f, 50.0f), cv::Point2f(52.0f, 50.0f)},
                        train, 8.0, 64, 0.9);
  ASSERT_EQ(m.size(), 1u);
  EXPECT_EQ(m[0].trainIdx, 1);
  EXPECT_FLOAT_EQ(m[0].distance, 4.0f);
}

TEST(ProjectedMatches, PredictionsOutsideTheImageAndMismatchedInputs) {
  const std::vector<cv::KeyPoint> keypoints{cv::KeyPoint(0.0f, 0.0f, 7.0f),
                                            cv::KeyPoint(639.0f, 479.0f, 7.0f)};
  const cv::Mat query = stack({descriptor(0), descriptor(0)});
  const cv::Mat train = stack({descriptor(0), descriptor(0)});
  // Far outside, and just beyond the last cell but within the radius.
  const auto m = projected_matches(keypoints, query,
                                   {cv::Point2f(-1.0e6f, 3.0e7f), cv::Point2f(643.0f, 482.0f)},
                                   train, 8.0, 64, 0.9);
  ASSERT_EQ(m.size(), 1u);
  EXPECT_EQ(m[0].queryIdx, 1);
  EXPECT_EQ(m[0].trainIdx, 1);
  EXPECT_THROW(projected_matches(keypoints, query, {cv::Point2f(0.0f, 0.0f)}, train, 8.0, 64, 0.9),
               std::invalid_argument);
  EXPECT_TRUE(projected_matches(keypoints, query,
                                {cv::Point2f(0.0f, 0.0f), cv::Point2f(1.0f, 1.0f)}, train, 0.0, 64,
                                0.9)
                  .empty());
  // A tiny radius over features spread far apart keeps the grid small and
  // still finds the feature at the prediction.
  const std::vector<cv::KeyPoint> spread{cv::KeyPoint(0.0f, 0.0f, 7.0f),
                                         cv::KeyPoint(1.0e7f, 1.0e7f, 7.0f)};
  const auto tiny = projected_matches(
      spread, query, {cv::Point2f(0.0f, 0.0f), cv::Point2f(1.0e7f, 1.0e7f)}, train, 1e-3, 64, 0.9);
  EXPECT_EQ(tiny.size(), 2u);
}

}  // namespace
}  // namespace long3r
