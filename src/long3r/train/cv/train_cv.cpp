// The trainer's OpenCV side: TUM folders as training data, the loss-curve
// picture, and the extensions that hand them and the full validation metrics
// (model_eval.cpp) to the trainer.
#include "long3r/train/cv/train_cv.hpp"

#include <ATen/ATen.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>
#include <stdexcept>

#include "long3r/dataset/image_file.hpp"
#include "long3r/dataset/tum_dataset.hpp"
#include "long3r/eval/eval.hpp"
#include "long3r/train/cv/datasets/dataset_io.hpp"

namespace long3r {

namespace {

class TumTrainingSource : public RecordedSource {
 public:
  explicit TumTrainingSource(TumDataset dataset) : ds_(std::move(dataset)) {}
  int64_t size() const override { return static_cast<int64_t>(ds_.size()); }
  RawFrame frame(int64_t index) const override {
    const std::size_t i = static_cast<std::size_t>(index);
    RawFrame f;
    f.bgr = datasets::tensor_of_mat(ds_.load_rgb(i), at::kByte);
    f.depth = datasets::tensor_of_mat(ds_.load_depth(i), at::kFloat);
    f.intrinsics = *ds_.calibration();
    f.T_W_C = *ds_.frame(i).pose;
    return f;
  }
  std::string name() const override { return ds_.root(); }

 private:
  TumDataset ds_;
};

}  // namespace

std::unique_ptr<RecordedSource> open_tum_training_source(const std::string& dir) {
  TumDatasetOptions opt;
  opt.require_depth = true;
  opt.require_pose = true;
  TumDataset ds = TumDataset::open(dir, opt);
  if (!ds.calibration()) throw std::runtime_error(dir + ": training needs calibration.txt");
  if (ds.size() < 2) throw std::runtime_error(dir + ": fewer than 2 frames with depth and pose");
  return std::make_unique<TumTrainingSource>(std::move(ds));
}

cv::Mat plot_training_curves(const std::vector<LogRow>& rows, int width, int height) {
  PlotSeries raw{"train loss", {}, {}, cv::Scalar(200, 200, 200), 1};
  PlotSeries smooth{"train loss (EMA 0.95)", {}, {}, cv::Scalar(180, 80, 0), 2};
  PlotSeries val{"validation loss", {}, {}, cv::Scalar(0, 0, 220), 2};
  double ema = std::numeric_limits<double>::quiet_NaN();
  double lo = std::numeric_limits<double>::infinity();
  for (const LogRow& r : rows) {
    lo = std::min({lo, r.loss, r.val ? r.val->loss : lo});
  }
  // The loss can go negative (the -alpha log conf term), so it is plotted
  // with an offset that keeps log-y usable and says so in the title.
  const double offset = std::isfinite(lo) && lo <= 0.0 ? -lo + 1e-2 : 0.0;
  for (const LogRow& r : rows) {
    if (!std::isfinite(r.loss)) continue;
    ema = std::isfinite(ema) ? 0.95 * ema + 0.05 * r.loss : r.loss;
    raw.x.push_back(static_cast<double>(r.step));
    raw.y.push_back(r.loss + offset);
    smooth.x.push_back(static_cast<double>(r.step));
    smooth.y.push_back(ema + offset);
    if (r.val) {
      val.x.push_back(static_cast<double>(r.step));
      val.y.push_back(r.val->loss + offset);
    }
  }
  std::string title = "LONG3R training loss";
  if (offset > 0.0) {
    char text[32];
    std::snprintf(text, sizeof(text), "%.8g", offset);
    title += std::string(" (+") + text + ")";
  }
  return plot_line_chart({raw, smooth, val}, title, "step", true, width, height);
}

TrainerExtensions opencv_trainer_extensions() {
  TrainerExtensions e;
  e.score = full_validation_scorer;
  e.open_recorded = open_tum_training_source;
  e.open_dataset = datasets::open_dataset;
  e.write_plot = [](const std::vector<LogRow>& rows, const std::string& path) {
    write_image_atomically(path, plot_training_curves(rows));
  };
  return e;
}

}  // namespace long3r
