// Plain driver for a libFuzzer entry point, so that the fuzz target runs as an
// ordinary test under any compiler: feeds every file of a corpus folder to
// LLVMFuzzerTestOneInput, then a fixed number of deterministic mutations of
// them (bit flips, truncations, edits of the 8-byte length field, byte
// insertions/deletions, splices). A failure aborts (trap, sanitizer) or
// escapes as an exception; the offending input is written to
// replay_failure.bin in the working folder.
//
// usage: replay_main CORPUS_DIR [ITERATIONS=3000] [SEED=1]
#include <dirent.h>

#include <algorithm>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <exception>
#include <fstream>
#include <iostream>
#include <memory>
#include <random>
#include <sstream>
#include <string>
#include <vector>

#include "long3r/io/safetensors_header.hpp"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, std::size_t size);

namespace {

using Bytes = std::vector<uint8_t>;

std::vector<std::string> list_files(const std::string& dir) {
  std::vector<std::string> out;
  DIR* d = ::opendir(dir.c_str());
  if (d == nullptr) return out;
  while (dirent* e = ::readdir(d)) {
    const std::string n = e->d_name;
    if (n != "." && n != ".." && n[0] != '.') out.push_back(dir + "/" + n);
  }
  ::closedir(d);
  std::sort(out.begin(), out.end());  // deterministic order
  return out;
}

Bytes read_file(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  return Bytes((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
}

void save_failure(const Bytes& b) {
  std::ofstream out("replay_failure.bin", std::ios::binary);
  out.write(reinterpret_cast<const char*>(b.data()), static_cast<std::streamsize>(b.size()));
}

// Runs one input; exceptions escaping the entry point are failures.
bool run_one(const Bytes& b, const std::string& what) {
  // A copy of exactly b.size() bytes so that reads past the end are caught by
  // sanitizers when they are enabled.
  std::unique_ptr<uint8_t[]> buf(new uint8_t[b.empty() ? 1 : b.size()]);
  std::copy(b.begin(), b.end(), buf.get());
  try {
    LLVMFuzzerTestOneInput(buf.get(), b.size());
  } catch (const std::exception& e) {
    std::cerr << "FAIL on " << what << ": uncaught exception: " << e.what() << "\n";
    save_failure(b);
    return false;
  } catch (...) {
    std::cerr << "FAIL on " << what << ": uncaught non-std exception\n";
    save_failure(b);
    return false;
  }
  return true;
}

void set_le64(Bytes& b, uint64_t n) {
  if (b.size() < 8) b.resize(8, 0);
  long3r::encode_header_length(n, b.data());
}

uint64_t get_le64(const Bytes& b) {
  return b.size() >= 8 ? long3r::decode_header_length(b.data()) : 0;
}

Bytes mutate(const std::vector<Bytes>& corpus, std::mt19937_64& rng, std::string* what) {
  const auto pick = [&](std::size_t n) { return static_cast<std::size_t>(rng() % (n ? n : 1)); };
  Bytes b = corpus[pick(corpus.size())];
  static const char kInteresting[] = "{}[]\",:-0123456789e.\\u \x00\xff\x80";
  const int kind = static_cast<int>(rng() % 8);
  std::ostringstream w;
  switch (kind) {
    case 0: {  // bit flips
      const int flips = 1 + static_cast<int>(rng() % 4);
      for (int i = 0; i < flips && !b.empty(); ++i) b[pick(b.size())] ^= 1u << (rng() % 8);
      w << flips << " bit flips";
      break;
    }
    case 1: {  // truncation
      const std::size_t cut = pick(b.size() + 1);
      b.resize(cut);
      w << "truncated to " << cut;
      break;
    }
    case 2: {  // length field edits
      const uint64_t n = get_le64(b);
      const uint64_t choices[] = {0,
                                  n + 1,
                                  n - 1,
                                  n + 8,
                                  b.size() >= 8 ? b.size() - 8 : 0,
                                  b.size(),
                                  UINT64_MAX,
                                  UINT64_MAX - 7,
                                  uint64_t{1} << 63,
                                  (uint64_t{100} << 20) + 1,
                                  rng()};
      const uint64_t v = choices[pick(sizeof(choices) / sizeof(choices[0]))];
      set_le64(b, v);
      w << "length field set to " << v;
      break;
    }
    case 3: {  // overwrite with a syntactically interesting byte
      const int k = 1 + static_cast<int>(rng() % 3);
      for (int i = 0; i < k && !b.empty(); ++i) {
        b[pick(b.size())] = static_cast<uint8_t>(kInteresting[pick(sizeof(kInteresting) - 1)]);
      }
      w << k << " byte overwrites";
      break;
    }
    case 4: {  // insertion
      const std::size_t at = pick(b.size() + 1);
      const std::size_t len = 1 + pick(8);
      Bytes ins;
      for (std::size_t i = 0; i < len; ++i) {
        ins.push_back(static_cast<uint8_t>(kInteresting[pick(sizeof(kInteresting) - 1)]));
      }
      b.insert(b.begin() + static_cast<std::ptrdiff_t>(at), ins.begin(), ins.end());
      w << "inserted " << len << " bytes at " << at;
      break;
    }
    case 5: {  // deletion
      if (b.empty()) break;
      const std::size_t at = pick(b.size());
      const std::size_t len = std::min(b.size() - at, 1 + pick(16));
      b.erase(b.begin() + static_cast<std::ptrdiff_t>(at),
              b.begin() + static_cast<std::ptrdiff_t>(at + len));
      w << "deleted " << len << " bytes at " << at;
      break;
    }
    case 6: {  // splice with another corpus file
      const Bytes& o = corpus[pick(corpus.size())];
      const std::size_t a = pick(b.size() + 1), c = pick(o.size() + 1);
      b.resize(a);
      b.insert(b.end(), o.begin() + static_cast<std::ptrdiff_t>(c), o.end());
      w << "spliced at " << a;
      break;
    }
    default: {  // decimal digit edits (shapes, offsets)
      std::vector<std::size_t> digits;
      for (std::size_t i = 0; i < b.size(); ++i) {
        if (b[i] >= '0' && b[i] <= '9') digits.push_back(i);
      }
      if (!digits.empty()) {
        const std::size_t at = digits[pick(digits.size())];
        b[at] = static_cast<uint8_t>('0' + rng() % 10);
        if (rng() % 2) b.insert(b.begin() + static_cast<std::ptrdiff_t>(at), '9');
      }
      w << "digit edit";
      break;
    }
  }
  *what = w.str();
  return b;
}

}  // namespace

int main(int argc, char** argv) {
  if (argc < 2) {
    std::cerr << "usage: " << argv[0] << " CORPUS_DIR [ITERATIONS=3000] [SEED=1]\n";
    return 2;
  }
  const std::string dir = argv[1];
  const long iterations = argc > 2 ? std::atol(argv[2]) : 3000;
  const uint64_t seed = argc > 3 ? std::strtoull(argv[3], nullptr, 10) : 1;

  std::vector<Bytes> corpus;
  for (const std::string& f : list_files(dir)) {
    corpus.push_back(read_file(f));
    if (!run_one(corpus.back(), f)) return 1;
  }
  if (corpus.empty()) {
    std::cerr << "no corpus files in " << dir << "\n";
    return 1;
  }
  std::mt19937_64 rng(seed);
  for (long i = 0; i < iterations; ++i) {
    std::string what;
    const Bytes b = mutate(corpus, rng, &what);
    if (!run_one(b, "mutation " + std::to_string(i) + " (" + what + ")")) return 1;
  }
  std::cout << "replayed " << corpus.size() << " corpus files and " << iterations
            << " mutations (seed " << seed << ") without failure\n";
  return 0;
}
