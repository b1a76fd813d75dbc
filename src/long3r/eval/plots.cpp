// Evaluation plots drawn with OpenCV: trajectory top view, error maps.
#include <opencv2/imgproc.hpp>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <optional>

#include "long3r/eval/eval.hpp"

namespace long3r {

namespace {

// Orthonormal basis (right, forward) of the plane orthogonal to `up`, so that
// looking down along -up, right is screen x and forward is screen up.
void plane_basis(const Eigen::Vector3d& up_in, Eigen::Vector3d* right, Eigen::Vector3d* forward) {
  const Eigen::Vector3d up = up_in.normalized();
  Eigen::Vector3d seed = Eigen::Vector3d::UnitX();
  if (std::abs(up.dot(seed)) > 0.9) seed = Eigen::Vector3d::UnitY();
  *right = (seed - up * up.dot(seed)).normalized();
  *forward = up.cross(*right);
}

struct View {
  double min_x = 0, min_y = 0, scale = 1;
  int x0 = 0, y0 = 0, w = 0, h = 0;  // drawing area in the image
  cv::Point to_px(const Eigen::Vector2d& p) const {
    return cv::Point(x0 + static_cast<int>(std::lround((p.x() - min_x) * scale)),
                     y0 + h - static_cast<int>(std::lround((p.y() - min_y) * scale)));
  }
};

View fit_view(const std::vector<Eigen::Vector2d>& pts, int x0, int y0, int w, int h) {
  View v;
  v.x0 = x0;
  v.y0 = y0;
  v.w = w;
  v.h = h;
  if (pts.empty()) return v;
  Eigen::Vector2d lo = pts[0], hi = pts[0];
  for (const auto& p : pts) {
    lo = lo.cwiseMin(p);
    hi = hi.cwiseMax(p);
  }
  const Eigen::Vector2d span = (hi - lo).cwiseMax(1e-6);
  v.scale = std::min(w / span.x(), h / span.y());
  // Centre the content.
  v.min_x = lo.x() - 0.5 * (w / v.scale - span.x());
  v.min_y = lo.y() - 0.5 * (h / v.scale - span.y());
  return v;
}

double nice_length(double target) {
  const double p = std::pow(10.0, std::floor(std::log10(target)));
  for (double m : {5.0, 2.0, 1.0}) {
    if (m * p <= target) return m * p;
  }
  return p;
}

void draw_scale_bar(cv::Mat& img, const View& v, int x, int y) {
  const double len = nice_length(0.25 * v.w / v.scale);
  const int px = static_cast<int>(std::lround(len * v.scale));
  cv::line(img, {x, y}, {x + px, y}, cv::Scalar(0, 0, 0), 2);
  cv::line(img, {x, y - 5}, {x, y + 5}, cv::Scalar(0, 0, 0), 2);
  cv::line(img, {x + px, y - 5}, {x + px, y + 5}, cv::Scalar(0, 0, 0), 2);
  char buf[64];
  if (len >= 1.0)
    std::snprintf(buf, sizeof(buf), "%g m", len);
  else
    std::snprintf(buf, sizeof(buf), "%g cm", len * 100.0);
  cv::putText(img, buf, {x, y - 10}, cv::FONT_HERSHEY_SIMPLEX, 0.5, cv::Scalar(0, 0, 0), 1,
              cv::LINE_AA);
}

}  // namespace

Eigen::Vector3d estimate_up_axis(const std::vector<Eigen::Isometry3d>& poses) {
  Eigen::Vector3d sum = Eigen::Vector3d::Zero();
  for (const auto& p : poses) sum -= p.linear().col(1);
  if (sum.norm() < 1e-9) return Eigen::Vector3d::UnitZ();
  return sum.normalized();
}

cv::Mat plot_trajectory_top_view(const std::vector<Eigen::Vector3d>& ref,
                                 const std::vector<Eigen::Vector3d>& est, const Eigen::Vector3d& up,
                                 const std::string& title, int size) {
  Eigen::Vector3d right, forward;
  plane_basis(up, &right, &forward);
  auto project = [&](const std::vector<Eigen::Vector3d>& in) {
    std::vector<Eigen::Vector2d> out;
    for (const auto& p : in) out.emplace_back(p.dot(right), p.dot(forward));
    return out;
  };
  const auto r2 = project(ref), e2 = project(est);
  std::vector<Eigen::Vector2d> all = r2;
  all.insert(all.end(), e2.begin(), e2.end());
  cv::Mat img(size, size, CV_8UC3, cv::Scalar(255, 255, 255));
  const int margin = size / 12, top = size / 10;
  const View v = fit_view(all, margin, top, size - 2 * margin, size - top - 2 * margin);

  const size_t n = std::min(r2.size(), e2.size());
  for (size_t i = 0; i < n; ++i) {
    cv::line(img, v.to_px(r2[i]), v.to_px(e2[i]), cv::Scalar(200, 200, 200), 1, cv::LINE_AA);
  }
  auto polyline = [&](const std::vector<Eigen::Vector2d>& p, const cv::Scalar& c) {
    for (size_t i = 1; i < p.size(); ++i)
      cv::line(img, v.to_px(p[i - 1]), v.to_px(p[i]), c, 2, cv::LINE_AA);
    if (!p.empty()) cv::circle(img, v.to_px(p.front()), 5, c, 2, cv::LINE_AA);
  };
  const cv::Scalar green(40, 160, 40), red(40, 40, 220);
  polyline(r2, green);
  polyline(e2, red);

  cv::putText(img, title, {margin, top / 2}, cv::FONT_HERSHEY_SIMPLEX, 0.6, cv::Scalar(0, 0, 0), 1,
              cv::LINE_AA);
  const int ly = top / 2 + 22;
  cv::line(img, {margin, ly}, {margin + 30, ly}, green, 2);
  cv::putText(img, "ground truth", {margin + 36, ly + 5}, cv::FONT_HERSHEY_SIMPLEX, 0.5, green, 1,
              cv::LINE_AA);
  cv::line(img, {margin + 170, ly}, {margin + 200, ly}, red, 2);
  cv::putText(img, "estimate (aligned)", {margin + 206, ly + 5}, cv::FONT_HERSHEY_SIMPLEX, 0.5, red,
              1, cv::LINE_AA);
  draw_scale_bar(img, v, margin, size - margin / 2);
  return img;
}

cv::Mat plot_error_top_view(const std::vector<Eigen::Vector3f>& pred,
                            const std::vector<float>& pred_errors,
                            const std::vector<Eigen::Vector3f>& gt,
                            const std::vector<float>& gt_errors, const Eigen::Vector3d& up,
                            double max_error, int panel) {
  if (pred.size() != pred_errors.size() || gt.size() != gt_errors.size()) {
    throw std::invalid_argument("plot_error_top_view: points and errors differ in size");
  }
  if (!(max_error > 0.0)) max_error = 0.1;
  Eigen::Vector3d right, forward;
  plane_basis(up, &right, &forward);
  const Eigen::Vector3f rf = right.cast<float>(), ff = forward.cast<float>();
  std::vector<Eigen::Vector2d> all;
  all.reserve(pred.size() + gt.size());
  for (const auto& p : gt) all.emplace_back(p.dot(rf), p.dot(ff));
  for (const auto& p : pred) all.emplace_back(p.dot(rf), p.dot(ff));

  const int title_h = 40, bar_w = 70;
  cv::Mat img(panel + title_h, 2 * panel + bar_w, CV_8UC3, cv::Scalar(255, 255, 255));
  const int pad = 10;
  const View base = fit_view(all, pad, title_h + pad, panel - 2 * pad, panel - 2 * pad);

  auto draw_panel = [&](const std::vector<Eigen::Vector3f>& pts, const std::vector<float>& err,
                        int x_offset, const std::string& title) {
    View v = base;
    v.x0 += x_offset;
    cv::Mat sum(img.rows, img.cols, CV_32F, cv::Scalar(0)),
        cnt(img.rows, img.cols, CV_32F, cv::Scalar(0));
    for (size_t i = 0; i < pts.size(); ++i) {
      const cv::Point px = v.to_px(Eigen::Vector2d(pts[i].dot(rf), pts[i].dot(ff)));
      if (px.x < 0 || px.y < 0 || px.x >= img.cols || px.y >= img.rows) continue;
      sum.at<float>(px) += err[i];
      cnt.at<float>(px) += 1.0f;
    }
    cv::Mat level(img.rows, img.cols, CV_8U, cv::Scalar(0));
    for (int y = 0; y < img.rows; ++y) {
      for (int x = 0; x < img.cols; ++x) {
        const float c = cnt.at<float>(y, x);
        if (c > 0) {
          const double e = sum.at<float>(y, x) / c;
          level.at<uint8_t>(y, x) =
              static_cast<uint8_t>(std::lround(255.0 * std::min(1.0, e / max_error)));
        }
      }
    }
    cv::Mat colour;
    cv::applyColorMap(level, colour, cv::COLORMAP_TURBO);
    colour.copyTo(img, cnt > 0);
    cv::putText(img, title, {x_offset + pad, 26}, cv::FONT_HERSHEY_SIMPLEX, 0.55,
                cv::Scalar(0, 0, 0), 1, cv::LINE_AA);
  };
  draw_panel(pred, pred_errors, 0, "accuracy: prediction -> GT");
  draw_panel(gt, gt_errors, panel, "completion: GT -> prediction");
  cv::line(img, {panel, title_h}, {panel, img.rows}, cv::Scalar(180, 180, 180), 1);

  // Colour bar.
  const int bx = 2 * panel + 10, by0 = title_h + 20, by1 = img.rows - 30;
  for (int y = by0; y <= by1; ++y) {
    cv::Mat one(1, 1, CV_8U, cv::Scalar(std::lround(255.0 * (by1 - y) / (by1 - by0))));
    cv::Mat c;
    cv::applyColorMap(one, c, cv::COLORMAP_TURBO);
    cv::line(img, {bx, y}, {bx + 15, y}, cv::Scalar(c.at<cv::Vec3b>(0, 0)), 1);
  }
  char buf[32];
  std::snprintf(buf, sizeof(buf), ">=%.0fcm", max_error * 100.0);
  cv::putText(img, buf, {bx - 5, by0 - 6}, cv::FONT_HERSHEY_SIMPLEX, 0.4, cv::Scalar(0, 0, 0), 1,
              cv::LINE_AA);
  cv::putText(img, "0", {bx + 3, by1 + 16}, cv::FONT_HERSHEY_SIMPLEX, 0.4, cv::Scalar(0, 0, 0), 1,
              cv::LINE_AA);
  draw_scale_bar(img, base, pad + 10, img.rows - 12);
  return img;
}

cv::Mat plot_line_chart(const std::vector<PlotSeries>& series, const std::string& title,
                        const std::string& x_label, bool log_y, int width, int height) {
  cv::Mat img(height, width, CV_8UC3, cv::Scalar(255, 255, 255));
  const int left = 80, right = 20, top = 40, bottom = 50;
  const int pw = width - left - right, ph = height - top - bottom;
  auto value = [&](double y) { return log_y ? std::log10(y) : y; };
  auto usable = [&](double x, double y) {
    return std::isfinite(x) && std::isfinite(y) && (!log_y || y > 0.0);
  };
  double x_lo = HUGE_VAL, x_hi = -HUGE_VAL, y_lo = HUGE_VAL, y_hi = -HUGE_VAL;
  for (const PlotSeries& s : series) {
    for (std::size_t i = 0; i < std::min(s.x.size(), s.y.size()); ++i) {
      if (!usable(s.x[i], s.y[i])) continue;
      x_lo = std::min(x_lo, s.x[i]);
      x_hi = std::max(x_hi, s.x[i]);
      y_lo = std::min(y_lo, value(s.y[i]));
      y_hi = std::max(y_hi, value(s.y[i]));
    }
  }
  cv::putText(img, title, {left, 25}, cv::FONT_HERSHEY_SIMPLEX, 0.6, cv::Scalar(0, 0, 0), 1,
              cv::LINE_AA);
  cv::rectangle(img, {left, top}, {left + pw, top + ph}, cv::Scalar(0, 0, 0), 1);
  if (!(x_lo <= x_hi)) return img;  // nothing to draw
  if (x_hi - x_lo < 1e-12) x_hi = x_lo + 1.0;
  if (y_hi - y_lo < 1e-12) {
    y_lo -= 0.5;
    y_hi += 0.5;
  }
  const double y_pad = 0.05 * (y_hi - y_lo);
  y_lo -= y_pad;
  y_hi += y_pad;
  auto to_px = [&](double x, double y) {
    return cv::Point(left + static_cast<int>(std::lround((x - x_lo) / (x_hi - x_lo) * pw)),
                     top + ph - static_cast<int>(std::lround((y - y_lo) / (y_hi - y_lo) * ph)));
  };
  char buf[64];
  for (int t = 0; t <= 5; ++t) {  // ticks and grid
    const double fx = x_lo + (x_hi - x_lo) * t / 5.0, fy = y_lo + (y_hi - y_lo) * t / 5.0;
    const cv::Point px = to_px(fx, y_lo), py = to_px(x_lo, fy);
    cv::line(img, {px.x, top}, {px.x, top + ph}, cv::Scalar(225, 225, 225), 1);
    cv::line(img, {left, py.y}, {left + pw, py.y}, cv::Scalar(225, 225, 225), 1);
    std::snprintf(buf, sizeof(buf), "%g", std::round(fx * 100.0) / 100.0);
    cv::putText(img, buf, {px.x - 15, top + ph + 18}, cv::FONT_HERSHEY_SIMPLEX, 0.4,
                cv::Scalar(0, 0, 0), 1, cv::LINE_AA);
    std::snprintf(buf, sizeof(buf), "%.3g", log_y ? std::pow(10.0, fy) : fy);
    cv::putText(img, buf, {5, py.y + 4}, cv::FONT_HERSHEY_SIMPLEX, 0.4, cv::Scalar(0, 0, 0), 1,
                cv::LINE_AA);
  }
  cv::putText(img, x_label + (log_y ? "   (log y)" : ""), {left + pw / 2 - 30, height - 10},
              cv::FONT_HERSHEY_SIMPLEX, 0.5, cv::Scalar(0, 0, 0), 1, cv::LINE_AA);
  int legend_y = top + 18;
  for (const PlotSeries& s : series) {
    std::optional<cv::Point> prev;
    std::size_t points = 0;
    for (std::size_t i = 0; i < std::min(s.x.size(), s.y.size()); ++i) {
      if (!usable(s.x[i], s.y[i])) continue;
      const cv::Point p = to_px(s.x[i], value(s.y[i]));
      if (prev) cv::line(img, *prev, p, s.colour, s.thickness, cv::LINE_AA);
      prev = p;
      ++points;
    }
    if (points == 1) cv::circle(img, *prev, 3, s.colour, cv::FILLED, cv::LINE_AA);
    cv::line(img, {left + pw - 170, legend_y - 4}, {left + pw - 145, legend_y - 4}, s.colour, 2);
    cv::putText(img, s.label, {left + pw - 140, legend_y}, cv::FONT_HERSHEY_SIMPLEX, 0.45,
                cv::Scalar(0, 0, 0), 1, cv::LINE_AA);
    legend_y += 18;
  }
  return img;
}

}  // namespace long3r
