// The pre-rendered frame cache: written by the generator scene by scene,
// read through a read-only memory mapping.
#include <ATen/ATen.h>
#include <fcntl.h>
#include <sys/mman.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cstdio>
#include <cstring>
#include <nlohmann/json.hpp>
#include <stdexcept>
#include <thread>
#include <vector>

#include "long3r/io/atomic_file.hpp"
#include "long3r/synth/generate.hpp"
#include "long3r/synth/render.hpp"
#include "long3r/train/frame_cache.hpp"

namespace long3r {

namespace {

constexpr const char* kMagic = "long3r frame cache\n";
constexpr int kFormat = 1;
constexpr std::size_t kHeaderBytes = 4096;
constexpr std::size_t kFramesAlign = 4096;
constexpr std::size_t kRecordAlign = 64;

std::size_t round_up(std::size_t n, std::size_t to) { return (n + to - 1) / to * to; }

// What the frames are a function of (besides the generator's code, which
// opening checks by rendering).
nlohmann::json cache_key(const SynthDataConfig& c, int render_size) {
  nlohmann::json k;
  k["format"] = kFormat;
  k["train_seed_begin"] = c.train_seed_begin;
  k["train_scenes"] = c.train_scenes;
  k["trajectory_frames"] = c.trajectory_frames;
  k["speed"] = c.speed;
  k["hfov_min_deg"] = c.hfov_min_deg;
  k["hfov_max_deg"] = c.hfov_max_deg;
  k["render_size"] = render_size;
  return k;
}

// Byte offsets of the parts of a cache of this shape.
struct Layout {
  std::size_t intrinsics, poses, frames, depth_bytes, record, total;
  Layout(int64_t scenes, int64_t frames_per_scene, int size) {
    const auto n_scenes = static_cast<std::size_t>(scenes);
    const auto n_frames = n_scenes * static_cast<std::size_t>(frames_per_scene);
    const auto pixels = static_cast<std::size_t>(size) * static_cast<std::size_t>(size);
    intrinsics = kHeaderBytes;
    poses = intrinsics + n_scenes * 4 * sizeof(double);
    frames = round_up(poses + n_frames * 16 * sizeof(double), kFramesAlign);
    depth_bytes = pixels * sizeof(float);
    record = round_up(depth_bytes + pixels * 3, kRecordAlign);
    total = frames + n_frames * record;
  }
};

// One scene's intrinsics and frame records, in file order.
struct RenderedScene {
  std::vector<double> intrinsics;
  std::string records;
};

RenderedScene render_scene(const SynthDataConfig& config, uint64_t seed, int size,
                           const Layout& layout) {
  const synth::Sequence seq = synth::generate_sequence(synth_scene_config(config, seed, size));
  const PinholeIntrinsics& k = seq.config.intrinsics;
  RenderedScene out;
  out.intrinsics = {k.fx, k.fy, k.cx, k.cy};
  out.records.assign(seq.poses.size() * layout.record, '\0');
  synth::RenderOptions ro;
  ro.threads = 1;  // scenes in parallel instead
  for (std::size_t i = 0; i < seq.poses.size(); ++i) {
    const synth::RenderedFrame r = synth::render_frame(seq.scene, seq.poses[i], k, ro);
    char* rec = out.records.data() + i * layout.record;
    std::memcpy(rec, r.depth.contiguous().data_ptr<float>(), layout.depth_bytes);
    std::memcpy(rec + layout.depth_bytes, r.bgr.contiguous().data_ptr<uint8_t>(),
                static_cast<std::size_t>(r.bgr.numel()));
  }
  return out;
}

[[noreturn]] void refuse(const std::string& path, const std::string& why) {
  throw FrameCacheError("frame cache " + path + ": " + why);
}

}  // namespace

std::string FrameCache::file_name(const SynthDataConfig& config, int render_size) {
  // FNV-1a of the key's text: the fields the frames depend on.
  uint64_t h = 14695981039346656037ull;
  for (const char c : cache_key(config, render_size).dump()) {
    h = (h ^ static_cast<unsigned char>(c)) * 1099511628211ull;
  }
  char hash[17];
  std::snprintf(hash, sizeof(hash), "%016llx", static_cast<unsigned long long>(h));
  return "synth_" + std::to_string(render_size) + "px_" + std::to_string(config.train_seed_begin) +
         "-" +
         std::to_string(config.train_seed_begin + static_cast<uint64_t>(config.train_scenes) - 1) +
         "x" + std::to_string(config.trajectory_frames) + "_" + std::string(hash, 8) + ".frames";
}

void FrameCache::write(const std::string& path, const SynthDataConfig& config, int render_size,
                       int threads, const std::function<void(int64_t, int64_t)>& progress) {
  if (render_size < 1 || config.train_scenes < 1 || config.trajectory_frames < 1) {
    throw std::invalid_argument(
        "FrameCache::write: need render_size, train_scenes and trajectory_frames >= 1");
  }
  threads = std::max(1, threads);
  const int64_t scenes = config.train_scenes;
  const Layout layout(scenes, config.trajectory_frames, render_size);
  // The tables come before the frames in the file: a first pass makes them
  // without rendering (generating a scene is cheap beside rendering it),
  // then the scenes' frames are rendered and appended in seed order.
  std::vector<double> intrinsics, poses;
  intrinsics.reserve(static_cast<std::size_t>(scenes) * 4);
  for (int64_t s = 0; s < scenes; ++s) {
    const synth::Sequence seq = synth::generate_sequence(synth_scene_config(
        config, config.train_seed_begin + static_cast<uint64_t>(s), render_size));
    const PinholeIntrinsics& k = seq.config.intrinsics;
    intrinsics.insert(intrinsics.end(), {k.fx, k.fy, k.cx, k.cy});
    for (const Eigen::Isometry3d& T_W_C : seq.poses) {
      const Eigen::Matrix<double, 4, 4, Eigen::RowMajor> T = T_W_C.matrix();
      poses.insert(poses.end(), T.data(), T.data() + 16);
    }
  }
  AtomicFile file(path);
  std::string header(kHeaderBytes, '\0');
  const std::string text = std::string(kMagic) + cache_key(config, render_size).dump() + "\n";
  if (text.size() > kHeaderBytes) throw std::logic_error("FrameCache: key longer than its block");
  std::memcpy(header.data(), text.data(), text.size());
  file.write(header);
  file.write(intrinsics.data(), intrinsics.size() * sizeof(double));
  file.write(poses.data(), poses.size() * sizeof(double));
  file.write(std::string(layout.frames - (layout.poses + poses.size() * sizeof(double)), '\0'));
  // Scenes rendered `threads` at a time, written in seed order.
  for (int64_t s0 = 0; s0 < scenes; s0 += threads) {
    const int64_t s1 = std::min<int64_t>(scenes, s0 + threads);
    std::vector<RenderedScene> rendered(static_cast<std::size_t>(s1 - s0));
    std::vector<std::exception_ptr> errors(rendered.size());
    std::vector<std::thread> workers;
    for (int64_t s = s0; s < s1; ++s) {
      const auto i = static_cast<std::size_t>(s - s0);
      workers.emplace_back([&, s, i] {
        try {
          rendered[i] = render_scene(config, config.train_seed_begin + static_cast<uint64_t>(s),
                                     render_size, layout);
        } catch (...) {
          errors[i] = std::current_exception();
        }
      });
    }
    for (std::thread& t : workers) t.join();
    for (std::size_t i = 0; i < rendered.size(); ++i) {
      if (errors[i]) std::rethrow_exception(errors[i]);
      // The tables of the first pass and the render's must agree.
      if (rendered[i].intrinsics.size() != 4 ||
          !std::equal(rendered[i].intrinsics.begin(), rendered[i].intrinsics.end(),
                      intrinsics.begin() + (s0 + static_cast<int64_t>(i)) * 4)) {
        throw std::logic_error("FrameCache::write: a scene changed between its two generations");
      }
      file.write(rendered[i].records);
      if (progress) progress(s0 + static_cast<int64_t>(i) + 1, scenes);
    }
  }
  file.commit();
}

FrameCache::FrameCache(const std::string& path, const SynthDataConfig& config, int render_size,
                       int verify_frames)
    : path_(path),
      seed_begin_(config.train_seed_begin),
      scenes_(config.train_scenes),
      frames_(config.trajectory_frames),
      size_(render_size) {
  const int fd = ::open(path.c_str(), O_RDONLY | O_CLOEXEC);
  if (fd < 0) refuse(path, std::string("cannot open: ") + std::strerror(errno));
  struct stat st {};
  if (::fstat(fd, &st) != 0) {
    const int err = errno;
    ::close(fd);
    refuse(path, std::string("cannot stat: ") + std::strerror(err));
  }
  bytes_ = static_cast<std::size_t>(st.st_size);
  if (bytes_ < kHeaderBytes) {
    ::close(fd);
    refuse(path, "shorter than its header (" + std::to_string(bytes_) + " bytes)");
  }
  void* m = ::mmap(nullptr, bytes_, PROT_READ, MAP_SHARED, fd, 0);
  const int map_err = errno;
  ::close(fd);  // the mapping keeps the file
  if (m == MAP_FAILED) refuse(path, std::string("cannot map: ") + std::strerror(map_err));
  map_ = static_cast<const unsigned char*>(m);
  try {
    const char* head = reinterpret_cast<const char*>(map_);
    const std::size_t magic = std::strlen(kMagic);
    if (std::memcmp(head, kMagic, magic) != 0) refuse(path, "not a frame cache (no header)");
    const char* end =
        static_cast<const char*>(std::memchr(head + magic, '\n', kHeaderBytes - magic));
    if (end == nullptr) refuse(path, "its key line is not terminated");
    nlohmann::json key;
    try {
      key = nlohmann::json::parse(head + magic, end);
    } catch (const nlohmann::json::exception& e) {
      refuse(path, std::string("its key is not JSON: ") + e.what());
    }
    const nlohmann::json want = cache_key(config, render_size);
    if (!key.contains("format") || key["format"] != kFormat) {
      refuse(path, "format " + (key.contains("format") ? key["format"].dump() : "?") +
                       ", this version reads format " + std::to_string(kFormat) +
                       " (write it again)");
    }
    for (const auto& [name, value] : want.items()) {
      if (!key.contains(name) || key[name] != value) {
        refuse(path, "made for " + name + " " + (key.contains(name) ? key[name].dump() : "?") +
                         ", the configuration has " + value.dump() + " (write it again)");
      }
    }
    const Layout layout(scenes_, frames_, size_);
    if (bytes_ != layout.total) {
      refuse(path, std::to_string(bytes_) + " bytes where its layout needs " +
                       std::to_string(layout.total) + " (cut short or grown)");
    }
    ::madvise(const_cast<unsigned char*>(map_), bytes_, MADV_RANDOM);
    // The frames must be the generator's own: scenes spread over the range.
    for (int v = 0; v < verify_frames && scenes_ > 0; ++v) {
      const int64_t s = verify_frames > 1 ? (scenes_ - 1) * v / (verify_frames - 1) : 0;
      const int64_t f = verify_frames > 1 ? (frames_ - 1) * v / (verify_frames - 1) : 0;
      const uint64_t seed = seed_begin_ + static_cast<uint64_t>(s);
      const synth::Sequence seq = synth::generate_sequence(synth_scene_config(config, seed, size_));
      synth::RenderOptions ro;
      ro.threads = 1;
      const synth::RenderedFrame r = synth::render_frame(
          seq.scene, seq.poses[static_cast<std::size_t>(f)], seq.config.intrinsics, ro);
      const RawFrame cached = frame(seed, f);
      const bool same = at::equal(cached.bgr, r.bgr) && at::equal(cached.depth, r.depth) &&
                        cached.T_W_C.matrix() == seq.poses[static_cast<std::size_t>(f)].matrix() &&
                        cached.intrinsics.fx == seq.config.intrinsics.fx &&
                        cached.intrinsics.cx == seq.config.intrinsics.cx;
      if (!same) {
        refuse(path, "frame " + std::to_string(f) + " of scene " + std::to_string(seed) +
                         " differs from the generator's (made by another version; write it "
                         "again)");
      }
    }
  } catch (...) {
    ::munmap(const_cast<unsigned char*>(map_), bytes_);
    map_ = nullptr;
    throw;
  }
}

FrameCache::~FrameCache() {
  if (map_ != nullptr) ::munmap(const_cast<unsigned char*>(map_), bytes_);
}

bool FrameCache::covers(uint64_t seed) const {
  return seed >= seed_begin_ && seed - seed_begin_ < static_cast<uint64_t>(scenes_);
}

RawFrame FrameCache::frame(uint64_t seed, int64_t index) const {
  if (!covers(seed) || index < 0 || index >= frames_) {
    throw std::out_of_range("frame cache " + path_ + ": no frame " + std::to_string(index) +
                            " of scene " + std::to_string(seed));
  }
  const Layout layout(scenes_, frames_, size_);
  const auto s = static_cast<std::size_t>(seed - seed_begin_);
  const std::size_t n = s * static_cast<std::size_t>(frames_) + static_cast<std::size_t>(index);
  double k[4];
  std::memcpy(k, map_ + layout.intrinsics + s * sizeof(k), sizeof(k));
  Eigen::Matrix<double, 4, 4, Eigen::RowMajor> T;
  std::memcpy(T.data(), map_ + layout.poses + n * 16 * sizeof(double), 16 * sizeof(double));
  const unsigned char* rec = map_ + layout.frames + n * layout.record;
  RawFrame f;
  // Copied out: the mapping is read-only and outlives no tensor.
  f.depth = at::from_blob(const_cast<unsigned char*>(rec), {size_, size_}, at::kFloat).clone();
  f.bgr = at::from_blob(const_cast<unsigned char*>(rec + layout.depth_bytes), {size_, size_, 3},
                        at::kByte)
              .clone();
  f.intrinsics.fx = k[0];
  f.intrinsics.fy = k[1];
  f.intrinsics.cx = k[2];
  f.intrinsics.cy = k[3];
  f.intrinsics.width = size_;
  f.intrinsics.height = size_;
  f.T_W_C.matrix() = T;
  return f;
}

}  // namespace long3r
