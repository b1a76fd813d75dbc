#include "long3r/io/atomic_file.hpp"

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>
#include <filesystem>

namespace long3r {

namespace {
constexpr std::size_t kBufferBytes = 1 << 20;
}  // namespace

AtomicFile::AtomicFile(const std::string& path) : path_(path) {
  const std::filesystem::path target(path);
  std::filesystem::path dir = target.parent_path();
  if (dir.empty()) dir = ".";
  dir_ = dir.string();
  // The random suffix keeps concurrent writers of one target apart; the
  // leading dot hides the temporary from globs such as *.ply.
  tmp_ = (dir / ("." + target.filename().string() + ".tmp-XXXXXX")).string();
  fd_ = ::mkostemp(tmp_.data(), O_CLOEXEC);
  if (fd_ < 0) {
    tmp_.clear();
    fail("cannot create a temporary file in '" + dir_ + "'", errno);
  }
  // mkstemp creates 0600; outputs are ordinary shareable files.
  if (::fchmod(fd_, 0644) != 0) fail("fchmod", errno);
  buffer_.reserve(kBufferBytes);
}

AtomicFile::~AtomicFile() {
  if (fd_ >= 0) ::close(fd_);
  if (!tmp_.empty()) ::unlink(tmp_.c_str());
}

void AtomicFile::fail(const std::string& step, int err) {
  if (fd_ >= 0) ::close(fd_);
  fd_ = -1;
  if (!tmp_.empty()) ::unlink(tmp_.c_str());
  tmp_.clear();
  throw AtomicWriteError("cannot write '" + path_ + "': " + step + ": " + std::strerror(err));
}

void AtomicFile::drain(const char* data, std::size_t size) {
  while (size > 0) {
    const ssize_t n = ::write(fd_, data, size);
    if (n < 0) {
      if (errno == EINTR) continue;
      fail("write failed", errno);
    }
    data += n;
    size -= static_cast<std::size_t>(n);
  }
}

void AtomicFile::write(const void* data, std::size_t size) {
  if (fd_ < 0) throw std::logic_error("AtomicFile::write after commit or failure: " + path_);
  const char* p = static_cast<const char*>(data);
  if (buffer_.size() + size > kBufferBytes) {
    drain(buffer_.data(), buffer_.size());
    buffer_.clear();
  }
  if (size > kBufferBytes) {
    drain(p, size);  // large blocks (tensors) go straight through
  } else {
    buffer_.append(p, size);
  }
}

void AtomicFile::commit() {
  if (fd_ < 0) throw std::logic_error("AtomicFile::commit twice or after failure: " + path_);
  drain(buffer_.data(), buffer_.size());
  buffer_.clear();
  if (::fsync(fd_) != 0) fail("fsync", errno);
  const int fd = fd_;
  fd_ = -1;
  if (::close(fd) != 0) fail("close", errno);
  if (::rename(tmp_.c_str(), path_.c_str()) != 0) {
    fail("rename of the temporary file failed", errno);
  }
  tmp_.clear();
  sync_directory(dir_);
}

void write_file_atomically(const std::string& path, std::string_view contents) {
  AtomicFile file(path);
  file.write(contents);
  file.commit();
}

void sync_directory(const std::string& dir) {
  // Errors are not reported: by now the new file is complete and in place,
  // and a directory the process may not open for reading can still be
  // written to.
  const int fd = ::open(dir.c_str(), O_RDONLY | O_DIRECTORY | O_CLOEXEC);
  if (fd < 0) return;
  ::fsync(fd);
  ::close(fd);
}

}  // namespace long3r
