// AtomicFile / write_file_atomically: the target is either the old file or
// the complete new one, and no temporary is ever left behind.
#include <gtest/gtest.h>
#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <functional>
#include <string>
#include <vector>

#include "long3r/io/atomic_file.hpp"
#include "support/test_support.hpp"

namespace long3r {
namespace {

namespace fs = std::filesystem;

fs::path test_dir() {
  const auto* info = ::testing::UnitTest::GetInstance()->current_test_info();
  return test::scratch_dir(std::string("atomic_file/") + info->name());
}

std::vector<std::string> entries(const fs::path& dir) { return test::folder_entries(dir.string()); }
std::string read_all(const fs::path& p) { return test::read_file(p.string()); }

std::string message_of(const std::function<void()>& f) {
  try {
    f();
  } catch (const AtomicWriteError& e) {
    return e.what();
  }
  ADD_FAILURE() << "no AtomicWriteError";
  return {};
}

TEST(AtomicFile, WritesAndReplaces) {
  const fs::path dir = test_dir();
  const fs::path target = dir / "out.txt";
  write_file_atomically(target.string(), "first\n");
  EXPECT_EQ(read_all(target), "first\n");
  // Streaming writes, one larger than the buffer (written straight through).
  const std::string big(3 << 20, 'x');
  {
    AtomicFile f(target.string());
    f.write("head ");
    f.write(big.data(), big.size());
    f.write(std::string_view(" tail"));
    EXPECT_EQ(read_all(target), "first\n");  // nothing visible before commit
    f.commit();
  }
  EXPECT_EQ(read_all(target), "head " + big + " tail");
  EXPECT_EQ(entries(dir), std::vector<std::string>{"out.txt"});
  EXPECT_EQ(fs::status(target).permissions() & fs::perms::others_read, fs::perms::others_read);
  // A relative path (no directory part) resolves against the working directory.
  const fs::path cwd = fs::current_path();
  fs::current_path(dir);
  write_file_atomically("rel.txt", "");
  fs::current_path(cwd);
  EXPECT_EQ(entries(dir), (std::vector<std::string>{"out.txt", "rel.txt"}));
  fs::remove_all(dir);
}

TEST(AtomicFile, UncommittedLeavesTargetAndNoTemporary) {
  const fs::path dir = test_dir();
  const fs::path target = dir / "keep.txt";
  { std::ofstream(target) << "old"; }
  try {
    AtomicFile f(target.string());
    f.write("partial new content");
    throw std::runtime_error("producer failed");
  } catch (const std::runtime_error&) {
  }
  EXPECT_EQ(read_all(target), "old");
  EXPECT_EQ(entries(dir), std::vector<std::string>{"keep.txt"});
  fs::remove_all(dir);
}

// A directory where no file can be created (as root, who ignores permission
// bits, one in /proc): the error names the target, the old file stays.
TEST(AtomicFile, UnwritableDirectory) {
  if (::geteuid() != 0) {
    const fs::path dir = test_dir();
    const fs::path target = dir / "a.json";
    { std::ofstream(target) << "old"; }
    fs::permissions(dir, fs::perms::owner_read | fs::perms::owner_exec);
    const std::string what = message_of([&] { write_file_atomically(target.string(), "new"); });
    fs::permissions(dir, fs::perms::owner_all);
    EXPECT_NE(what.find(target.string()), std::string::npos) << what;
    EXPECT_NE(what.find("temporary"), std::string::npos) << what;
    EXPECT_EQ(read_all(target), "old");
    EXPECT_EQ(entries(dir), std::vector<std::string>{"a.json"});
    fs::remove_all(dir);
  } else {
    const std::string what =
        message_of([] { write_file_atomically("/proc/self/long3r_atomic.json", "new"); });
    EXPECT_NE(what.find("/proc/self/long3r_atomic.json"), std::string::npos) << what;
    EXPECT_NE(what.find("temporary"), std::string::npos) << what;
  }
}

TEST(AtomicFile, MissingDirectory) {
  const fs::path missing = fs::temp_directory_path() / "long3r_no_such_dir" / "x" / "a.csv";
  const std::string what = message_of([&] { write_file_atomically(missing.string(), "x"); });
  EXPECT_NE(what.find(missing.string()), std::string::npos) << what;
  EXPECT_NE(what.find("No such file or directory"), std::string::npos) << what;
  EXPECT_FALSE(fs::exists(missing.parent_path()));
}

// The disk fills up mid-write (RLIMIT_FSIZE makes write() fail with EFBIG).
TEST(AtomicFile, FailedWriteLeavesTargetAndNoTemporary) {
  const fs::path dir = test_dir();
  const fs::path target = dir / "big.bin";
  { std::ofstream(target) << "old"; }
  std::string what;
  {
    const test::FileSizeLimit limit(4096);
    what = message_of([&] { write_file_atomically(target.string(), std::string(1 << 16, 'y')); });
  }
  EXPECT_NE(what.find("write failed"), std::string::npos) << what;
  EXPECT_NE(what.find(target.string()), std::string::npos) << what;
  EXPECT_EQ(read_all(target), "old");
  EXPECT_EQ(entries(dir), std::vector<std::string>{"big.bin"});
  fs::remove_all(dir);
}

// rename() over a non-empty directory fails after the data was written.
TEST(AtomicFile, FailedRenameLeavesTargetAndNoTemporary) {
  const fs::path dir = test_dir();
  fs::create_directory(dir / "t");
  { std::ofstream(dir / "t" / "keep") << "x"; }
  const std::string what = message_of([&] { write_file_atomically((dir / "t").string(), "new"); });
  EXPECT_NE(what.find("rename"), std::string::npos) << what;
  EXPECT_EQ(entries(dir), std::vector<std::string>{"t"});
  EXPECT_EQ(entries(dir / "t"), std::vector<std::string>{"keep"});
  fs::remove_all(dir);
}

}  // namespace
}  // namespace long3r
