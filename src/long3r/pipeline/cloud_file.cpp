// Atomic .ply / .pcd writers for coloured point clouds (see voxel_map.hpp).
#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cctype>
#include <cerrno>
#include <cinttypes>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <stdexcept>
#include <string>

#include "long3r/pipeline/voxel_map.hpp"

namespace long3r {

namespace {

enum class CloudFormat { kPly, kPcd };

CloudFormat format_of(const std::string& path) {
  std::string ext = std::filesystem::path(path).extension().string();
  for (char& c : ext) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
  if (ext == ".ply") return CloudFormat::kPly;
  if (ext == ".pcd") return CloudFormat::kPcd;
  throw std::invalid_argument("save_colored_cloud: unknown file extension '" + ext + "' in '" +
                              path + "' (use .ply or .pcd)");
}

// Buffered writer on a file descriptor that remembers the first error.
class FdWriter {
 public:
  explicit FdWriter(int fd) : fd_(fd) { buffer_.reserve(kCapacity); }
  void write(const void* data, std::size_t n) {
    const char* p = static_cast<const char*>(data);
    if (buffer_.size() + n > kCapacity) flush();
    if (n > kCapacity) {
      drain(p, n);
    } else {
      buffer_.append(p, n);
    }
  }
  void write(const std::string& s) { write(s.data(), s.size()); }
  void flush() {
    drain(buffer_.data(), buffer_.size());
    buffer_.clear();
  }
  int error() const { return error_; }

 private:
  static constexpr std::size_t kCapacity = 1 << 20;
  void drain(const char* p, std::size_t n) {
    while (n > 0 && error_ == 0) {
      const ssize_t w = ::write(fd_, p, n);
      if (w < 0) {
        if (errno == EINTR) continue;
        error_ = errno;
        return;
      }
      p += w;
      n -= static_cast<std::size_t>(w);
    }
  }
  int fd_;
  int error_ = 0;
  std::string buffer_;
};

void put_le32(unsigned char* out, std::uint32_t bits) {
  for (int i = 0; i < 4; ++i) out[i] = static_cast<unsigned char>((bits >> (8 * i)) & 0xffu);
}
std::uint32_t float_bits(float f) {
  std::uint32_t bits;
  std::memcpy(&bits, &f, sizeof(bits));
  return bits;
}
std::uint32_t pack_rgb(const Rgb8& c) {
  return (static_cast<std::uint32_t>(c[0]) << 16) | (static_cast<std::uint32_t>(c[1]) << 8) |
         static_cast<std::uint32_t>(c[2]);
}

void write_ply(FdWriter& w, const std::vector<Eigen::Vector3f>& points,
               const std::vector<Rgb8>& colors, bool ascii) {
  w.write(std::string("ply\nformat ") + (ascii ? "ascii" : "binary_little_endian") +
          " 1.0\ncomment long3r map\nelement vertex " + std::to_string(points.size()) +
          "\nproperty float x\nproperty float y\nproperty float z\n"
          "property uchar red\nproperty uchar green\nproperty uchar blue\nend_header\n");
  char line[128];
  unsigned char rec[15];
  for (std::size_t i = 0; i < points.size(); ++i) {
    const Eigen::Vector3f& p = points[i];
    const Rgb8& c = colors[i];
    if (ascii) {
      // %.9g round-trips a float exactly.
      const int n = std::snprintf(line, sizeof(line), "%.9g %.9g %.9g %u %u %u\n", p.x(), p.y(),
                                  p.z(), unsigned{c[0]}, unsigned{c[1]}, unsigned{c[2]});
      w.write(line, static_cast<std::size_t>(n));
    } else {
      for (int a = 0; a < 3; ++a) put_le32(rec + 4 * a, float_bits(p[a]));
      rec[12] = c[0];
      rec[13] = c[1];
      rec[14] = c[2];
      w.write(rec, sizeof(rec));
    }
  }
}

void write_pcd(FdWriter& w, const std::vector<Eigen::Vector3f>& points,
               const std::vector<Rgb8>& colors, bool ascii) {
  const std::string n = std::to_string(points.size());
  w.write(
      "# .PCD v0.7 - Point Cloud Data file format\nVERSION 0.7\nFIELDS x y z rgb\n"
      "SIZE 4 4 4 4\nTYPE F F F U\nCOUNT 1 1 1 1\nWIDTH " +
      n + "\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS " + n + "\nDATA " +
      (ascii ? "ascii" : "binary") + "\n");
  char line[128];
  unsigned char rec[16];
  for (std::size_t i = 0; i < points.size(); ++i) {
    const Eigen::Vector3f& p = points[i];
    const std::uint32_t rgb = pack_rgb(colors[i]);
    if (ascii) {
      const int len = std::snprintf(line, sizeof(line), "%.9g %.9g %.9g %" PRIu32 "\n", p.x(),
                                    p.y(), p.z(), rgb);
      w.write(line, static_cast<std::size_t>(len));
    } else {
      for (int a = 0; a < 3; ++a) put_le32(rec + 4 * a, float_bits(p[a]));
      put_le32(rec + 12, rgb);
      w.write(rec, sizeof(rec));
    }
  }
}

[[noreturn]] void fail(const std::string& path, const std::string& what, int err) {
  throw std::runtime_error("save_colored_cloud: cannot write '" + path + "': " + what + ": " +
                           std::strerror(err));
}

}  // namespace

void save_colored_cloud(const std::string& path, const std::vector<Eigen::Vector3f>& points,
                        const std::vector<Rgb8>& colors, const MapSaveOptions& options) {
  if (points.size() != colors.size()) {
    throw std::invalid_argument("save_colored_cloud: points and colors differ in length");
  }
  const CloudFormat format = format_of(path);

  // The temporary sits beside the target so that rename() is atomic (same
  // file system); the random suffix keeps concurrent writers apart.
  const std::filesystem::path target(path);
  std::filesystem::path dir = target.parent_path();
  if (dir.empty()) dir = ".";
  std::string tmp = (dir / ("." + target.filename().string() + ".tmp-XXXXXX")).string();
  const int fd = ::mkostemp(tmp.data(), O_CLOEXEC);
  if (fd < 0) fail(path, "cannot create a temporary file in '" + dir.string() + "'", errno);

  auto abandon = [&](const std::string& what, int err) {
    ::close(fd);
    ::unlink(tmp.c_str());
    fail(path, what, err);
  };
  // mkstemp creates 0600; a map is an ordinary shareable file.
  if (::fchmod(fd, 0644) != 0) abandon("fchmod", errno);

  FdWriter w(fd);
  if (format == CloudFormat::kPly) {
    write_ply(w, points, colors, options.ascii);
  } else {
    write_pcd(w, points, colors, options.ascii);
  }
  w.flush();
  if (w.error() != 0) abandon("write failed", w.error());
  if (::fsync(fd) != 0) abandon("fsync", errno);
  if (::close(fd) != 0) {
    const int err = errno;
    ::unlink(tmp.c_str());
    fail(path, "close", err);
  }
  if (::rename(tmp.c_str(), path.c_str()) != 0) {
    const int err = errno;
    ::unlink(tmp.c_str());
    fail(path, "rename of the temporary file failed", err);
  }
  // Make the rename itself durable; the file is already complete either way.
  const int dir_fd = ::open(dir.c_str(), O_RDONLY | O_DIRECTORY | O_CLOEXEC);
  if (dir_fd >= 0) {
    ::fsync(dir_fd);
    ::close(dir_fd);
  }
}

}  // namespace long3r
