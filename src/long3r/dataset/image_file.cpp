#include "long3r/dataset/image_file.hpp"

#include <opencv2/imgcodecs.hpp>

#include <filesystem>
#include <stdexcept>

#include "long3r/io/atomic_file.hpp"

namespace long3r {

void write_image_atomically(const std::string& path, const cv::Mat& image,
                            const std::vector<int>& params) {
  const std::string ext = std::filesystem::path(path).extension().string();
  std::vector<unsigned char> bytes;
  bool ok = false;
  try {
    ok = !ext.empty() && cv::imencode(ext, image, bytes, params);
  } catch (const cv::Exception& e) {
    throw std::runtime_error("cannot encode '" + path + "': " + e.what());
  }
  if (!ok) throw std::runtime_error("cannot encode '" + path + "' as " + ext);
  AtomicFile file(path);
  file.write(bytes.data(), bytes.size());
  file.commit();
}

}  // namespace long3r
