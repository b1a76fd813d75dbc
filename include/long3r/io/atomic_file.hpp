// Atomic file replacement, used for every file the project writes (maps,
// checkpoints, trajectories, metrics, plots): the data goes to a temporary
// file beside the target (same directory, so the same file system), which is
// flushed, fsync'ed and renamed over the target, and then the directory is
// fsync'ed. A reader, or the file system after a crash, sees either the old
// file or the complete new one, never part of one. On any error the temporary
// is removed, the target is untouched and AtomicWriteError says what failed
// and names the target.
#pragma once

#include <cstddef>
#include <stdexcept>
#include <string>
#include <string_view>

namespace long3r {

// "cannot write '<path>': <step>: <strerror>", e.g. "... write failed: File
// too large".
class AtomicWriteError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

// One file being written. Nothing is visible at `path` until commit(); a
// destroyed, uncommitted AtomicFile removes its temporary (so an exception
// thrown while the data is produced leaves no trace).
class AtomicFile {
 public:
  // Creates the temporary ".<name>.tmp-XXXXXX" (mode 0644) beside `path`.
  explicit AtomicFile(const std::string& path);
  ~AtomicFile();
  AtomicFile(const AtomicFile&) = delete;
  AtomicFile& operator=(const AtomicFile&) = delete;

  // Buffered; a failed write removes the temporary and throws.
  void write(const void* data, std::size_t size);
  void write(std::string_view text) { write(text.data(), text.size()); }

  // Flushes, fsyncs and closes the temporary, renames it over `path` and
  // fsyncs the directory. At most once; no write() after it.
  void commit();

  const std::string& path() const { return path_; }

 private:
  void drain(const char* data, std::size_t size);
  [[noreturn]] void fail(const std::string& step, int err);

  std::string path_, dir_, tmp_;
  int fd_ = -1;
  std::string buffer_;
};

// The whole file at once.
void write_file_atomically(const std::string& path, std::string_view contents);

// fsyncs a directory, making renames in it durable (e.g. after renaming a
// completed folder into place). Best effort: see atomic_file.cpp.
void sync_directory(const std::string& dir);

}  // namespace long3r
