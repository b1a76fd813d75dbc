// ORB features and their matches, as the keyframe tracker and the baseline
// scale take them (one detector, one matching rule).
#pragma once

#include <opencv2/core/mat.hpp>
#include <opencv2/features2d.hpp>

#include <opencv2/core/types.hpp>

#include <vector>

namespace long3r {

// OpenCV's ORB defaults but the FAST threshold (theirs: 20, which finds too
// few corners on smooth surfaces; docs/model_card.md, "Poses from keyframes")
// and the pyramid's levels (theirs: 8, the tracker's default).
cv::Ptr<cv::ORB> make_orb(int max_features, int fast_threshold, int pyramid_levels);

// Matches of `query` descriptors to `train` ones by Hamming distance: Lowe's
// ratio test of the best against the second best, then for each train
// feature only its closest query feature. queryIdx / trainIdx index them;
// ordered by trainIdx.
std::vector<cv::DMatch> ratio_matches(const cv::Mat& query, const cv::Mat& train, double ratio);

// Matches guided by a pose guess (ORB-SLAM's search by projection): each
// train feature has a predicted pixel in the query image (not finite: none)
// and takes, of the query features within radius_px of it, the one closest
// by Hamming distance, if that is at most max_distance and below `ratio` of
// the second closest there; then each query feature keeps only its closest
// train feature. queryIdx / trainIdx index them; ordered by trainIdx.
std::vector<cv::DMatch> projected_matches(const std::vector<cv::KeyPoint>& query_keypoints,
                                          const cv::Mat& query,
                                          const std::vector<cv::Point2f>& predicted,
                                          const cv::Mat& train, double radius_px, int max_distance,
                                          double ratio);

}  // namespace long3r
