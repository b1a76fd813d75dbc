// ORB features and their matches, as the keyframe tracker and the baseline
// scale take them (one detector, one matching rule).
#pragma once

#include <opencv2/core/mat.hpp>
#include <opencv2/features2d.hpp>

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

}  // namespace long3r
