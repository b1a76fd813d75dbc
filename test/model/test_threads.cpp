// Thread settings: which OpenBLAS build torch loaded (read independently from
// the process's mapped libraries), the automatic OpenBLAS thread count that
// follows from it, explicit counts, and the command-line options.
#include <ATen/Parallel.h>
#include <dlfcn.h>
#include <gtest/gtest.h>

#include <fstream>
#include <set>
#include <string>
#include <vector>

#include "long3r/config/cli_options.hpp"
#include "long3r/model/runtime/threads.hpp"
#include "support/test_support.hpp"

namespace {

using long3r::BlasThreading;
using long3r::ThreadConfig;

// The OpenBLAS builds mapped into this process, from their paths
// (/usr/lib/x86_64-linux-gnu/openblas-openmp/libblas.so.3 and the like).
std::set<std::string> mapped_openblas() {
  std::ifstream maps("/proc/self/maps");
  std::set<std::string> builds;
  std::string line;
  while (std::getline(maps, line)) {
    for (const char* build : {"openblas-openmp", "openblas-pthread", "openblas-serial"}) {
      if (line.find(build) != std::string::npos) builds.insert(build);
    }
  }
  return builds;
}

int openblas_threads_now() {
  const auto get = reinterpret_cast<int (*)()>(dlsym(RTLD_DEFAULT, "openblas_get_num_threads"));
  return get != nullptr ? get() : -1;
}

TEST(Threads, ReportsTheOpenblasBuildTorchLoaded) {
  const std::set<std::string> mapped = mapped_openblas();
  if (mapped.empty()) GTEST_SKIP() << "no Debian OpenBLAS build mapped (another BLAS)";
  // libtorch links libblas.so.3, liblapack.so.3 and libopenblas.so.0, three
  // alternatives: when they point at different builds two OpenBLAS pools run
  // side by side (scripts/install_deps.sh selects all three).
  ASSERT_EQ(mapped.size(), 1u) << "more than one OpenBLAS build loaded: " << *mapped.begin()
                               << " and " << *mapped.rbegin();
  const BlasThreading loaded = long3r::loaded_blas_threading();
  if (*mapped.begin() == "openblas-openmp") {
    EXPECT_EQ(loaded, BlasThreading::kOpenmp);
  } else if (*mapped.begin() == "openblas-pthread") {
    EXPECT_EQ(loaded, BlasThreading::kPthread);
  } else {
    EXPECT_EQ(loaded, BlasThreading::kSequential);
  }
}

TEST(Threads, AutomaticOpenblasThreadsFollowTheBuild) {
  ThreadConfig c;
  EXPECT_EQ(c.openblas_threads, ThreadConfig::kOpenblasThreadsAuto);
  c.torch_threads = 2;
  const long3r::ThreadState s = long3r::apply_thread_config(c);
  EXPECT_EQ(s.torch_threads, 2);
  EXPECT_EQ(at::get_num_threads(), 2);
  switch (s.blas) {
    case BlasThreading::kOpenmp:
      // Shares torch's pool: every float32 GEMM on torch's threads.
      EXPECT_EQ(s.openblas_threads, 2);
      EXPECT_EQ(openblas_threads_now(), 2);
      break;
    case BlasThreading::kPthread:
      // Its own busy-waiting pool would fight torch's: one thread.
      EXPECT_EQ(s.openblas_threads, 1);
      EXPECT_EQ(openblas_threads_now(), 1);
      break;
    default:
      EXPECT_EQ(s.openblas_threads, 0);
  }
  EXPECT_NE(long3r::describe(s).find("2 torch thread(s)"), std::string::npos)
      << long3r::describe(s);
}

TEST(Threads, ExplicitAndEnvironmentCounts) {
  if (long3r::loaded_blas_threading() != BlasThreading::kOpenmp &&
      long3r::loaded_blas_threading() != BlasThreading::kPthread) {
    GTEST_SKIP() << "no threaded OpenBLAS loaded";
  }
  ThreadConfig c;
  c.torch_threads = 1;
  c.openblas_threads = 3;
  EXPECT_EQ(long3r::apply_thread_config(c).openblas_threads, 3);
  EXPECT_EQ(openblas_threads_now(), 3);
  // 0 leaves what is set (here: the 3 above) alone.
  c.openblas_threads = 0;
  const long3r::ThreadState s = long3r::apply_thread_config(c);
  EXPECT_EQ(s.openblas_threads, 0);
  EXPECT_EQ(openblas_threads_now(), 3);
  EXPECT_NE(long3r::describe(s).find("from the environment"), std::string::npos);
  c.openblas_threads = ThreadConfig::kOpenblasThreadsAuto;
  long3r::apply_thread_config(c);
}

ThreadConfig parsed(std::vector<std::string> words) {
  ThreadConfig c;
  long3r::CliOptions cli("prog");
  long3r::add_thread_options(cli, &c);
  const long3r::test::Argv a(std::move(words));
  cli.parse(a.argc(), a.argv());
  return c;
}

// glibc keeps freed memory for reuse unless told otherwise; the start-up line says so.
TEST(Threads, FreedMemoryIsReusedByDefault) {
  ThreadConfig c;
  c.torch_threads = 1;
  const long3r::ThreadState state = long3r::apply_thread_config(c);
#if defined(__GLIBC__)
  EXPECT_TRUE(state.reuse_freed_memory);
  EXPECT_NE(long3r::describe(state).find("freed memory reused"), std::string::npos)
      << long3r::describe(state);
#endif
  c.reuse_freed_memory = false;
  const long3r::ThreadState left = long3r::apply_thread_config(c);
  EXPECT_FALSE(left.reuse_freed_memory);
  EXPECT_EQ(long3r::describe(left).find("freed memory"), std::string::npos);
}

TEST(Threads, CommandLineOptions) {
  EXPECT_EQ(parsed({}).openblas_threads, ThreadConfig::kOpenblasThreadsAuto);
  EXPECT_EQ(parsed({}).torch_threads, 0);
  EXPECT_EQ(parsed({"--openblas-threads", "auto"}).openblas_threads,
            ThreadConfig::kOpenblasThreadsAuto);
  EXPECT_EQ(parsed({"--openblas-threads", "0"}).openblas_threads, 0);
  EXPECT_EQ(parsed({"--openblas-threads", "4", "--threads", "3"}).openblas_threads, 4);
  EXPECT_EQ(parsed({"--threads", "3"}).torch_threads, 3);
  EXPECT_TRUE(parsed({}).reuse_freed_memory);
  EXPECT_FALSE(parsed({"--return-freed-memory"}).reuse_freed_memory);
  for (const std::vector<std::string>& bad :
       {std::vector<std::string>{"--openblas-threads", "-1"},
        std::vector<std::string>{"--openblas-threads", "many"},
        std::vector<std::string>{"--threads", "-2"}}) {
    try {
      parsed(bad);
      ADD_FAILURE() << "accepted " << bad[0] << " " << bad[1];
    } catch (const long3r::UsageError& e) {
      EXPECT_NE(std::string(e.what()).find(bad[0]), std::string::npos) << e.what();
    }
  }
}

}  // namespace
