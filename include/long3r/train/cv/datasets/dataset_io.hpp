// The public training datasets in the preprocessed layouts that the official
// DUSt3R / Spann3R preparation writes and reads (docs/training.md,
// "Datasets"): the pieces every layout reader shares, and the readers. A
// reader turns a dataset's files into sequences (RecordedSource): frames of
// colour, z-depth (metres, or the dataset's own unit where it has no metric
// one), pinhole intrinsics at the image's pixels (OpenCV convention: the
// first pixel's centre at (0, 0)) and the camera-to-world pose T_W_C in
// OpenCV camera axes (x right, y down, z forward).
#pragma once

#include <Eigen/Geometry>
#include <nlohmann/json.hpp>
#include <opencv2/core.hpp>

#include <cstdint>
#include <functional>
#include <map>
#include <memory>
#include <stdexcept>
#include <string>
#include <vector>

#include "long3r/train/train_config.hpp"
#include "long3r/train/train_data.hpp"

namespace long3r::datasets {

// A missing, truncated or inconsistent file, named in the message. Thrown
// by a sequence's frame(): the sampler skips that sample, counts it and
// draws another; while a dataset is opened, that sequence is left out and
// listed in DatasetScan::skipped.
using DatasetError = RecordedFrameError;

// 8-bit colour as BGR (grey is expanded); DatasetError when missing or
// undecodable.
cv::Mat read_color(const std::string& path);
// A depth image as CV_32F: a 16-bit PNG times `scale` (0.001 for
// millimetres), or a float image (EXR, half or full; PFM) times `scale`.
// Non-finite and negative values become 0 (invalid).
cv::Mat read_depth(const std::string& path, double scale);
// A PFM image (one channel), top row first (the file stores the bottom row
// first).
cv::Mat read_pfm(const std::string& path);
// `rows` x `cols` numbers separated by white space, the rest of the file
// ignored.
Eigen::MatrixXd read_matrix_text(const std::string& path, int rows, int cols);
nlohmann::json read_json(const std::string& path);
// The lines of a text file, trimmed, empty ones left out.
std::vector<std::string> read_lines(const std::string& path);
// `token` whole as a finite number: false for an empty, partial ("1.5x"),
// infinite or NaN token.
bool parse_finite(const std::string& token, double* value);

// numpy arrays (.npy; .npz as numpy.savez writes them, entries stored
// uncompressed) of floating-point or integer values, as doubles.
struct NpyArray {
  std::vector<int64_t> shape;
  std::vector<double> values;  // C order
};
NpyArray read_npy(const std::string& path);
std::map<std::string, NpyArray> read_npz(const std::string& path);
// An entry of an npz as a matrix of that size; DatasetError naming the file
// and key when it is absent or of another shape.
Eigen::MatrixXd npz_matrix(const std::map<std::string, NpyArray>& npz, const std::string& key,
                           int rows, int cols, const std::string& path);

// Intrinsics from a 3 x 3 K of an image of width x height: no skew, positive
// focal lengths, or DatasetError naming `what`.
PinholeIntrinsics intrinsics_from_k(const Eigen::Matrix3d& k, int width, int height,
                                    const std::string& what);
// A 4 x 4 rigid transform: finite, last row 0 0 0 1, a rotation to within
// 1e-3 (then made exactly orthonormal); DatasetError naming `what` otherwise.
Eigen::Isometry3d rigid_from_matrix(const Eigen::Matrix4d& m, const std::string& what);
// A cv::Mat's pixels as a tensor of that type that owns them ([H, W] or
// [H, W, C]).
at::Tensor tensor_of_mat(const cv::Mat& m, at::ScalarType type);
// The frame of these images; the colour image is resized (area) to the
// depth's size when `resize_color` and they differ (ScanNet's colour is
// larger than its depth), DatasetError otherwise.
RawFrame make_frame(const cv::Mat& bgr, const cv::Mat& depth, const PinholeIntrinsics& k,
                    const Eigen::Isometry3d& T_W_C, const std::string& what,
                    bool resize_color = false);

// A sequence whose frames are loaded when asked for.
class FrameListSource : public RecordedSource {
 public:
  FrameListSource(std::string name, int64_t size, std::function<RawFrame(int64_t)> load)
      : name_(std::move(name)), size_(size), load_(std::move(load)) {}
  int64_t size() const override { return size_; }
  RawFrame frame(int64_t index) const override { return load_(index); }
  std::string name() const override { return name_; }

 private:
  std::string name_;
  int64_t size_;
  std::function<RawFrame(int64_t)> load_;
};

using DatasetScan = OpenedDataset;

// The layout readers (src/long3r/train/cv/datasets/<layout>.cpp). Each throws
// DatasetError when the dataset's own index (its split list, its root) is
// missing; a sequence with a missing or broken index file is left out and
// listed in `skipped`. Frames are read when a sample needs them.
DatasetScan open_scannet(const DatasetSource& source);
DatasetScan open_scannetpp(const DatasetSource& source);
DatasetScan open_arkitscenes(const DatasetSource& source);
DatasetScan open_co3d(const DatasetSource& source);
DatasetScan open_blendedmvs(const DatasetSource& source);
DatasetScan open_habitat(const DatasetSource& source);
// By source.layout (kDatasetLayouts).
DatasetScan open_dataset(const DatasetSource& source);

}  // namespace long3r::datasets
