// long3r_synth: renders a procedural indoor sequence with exact ground truth
// into a TUM RGB-D style folder (see include/long3r/synth/synth.hpp, docs/evaluation.md).
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <iostream>
#include <string>

#include "long3r/synth/synth.hpp"

namespace {

void usage() {
  std::puts(
      "usage: long3r_synth --out DIR [options]\n"
      "  --seed N            scene and path seed (default 1)\n"
      "  --frames N          number of frames (default 300)\n"
      "  --trajectory T      walk | orbit | pan (default walk)\n"
      "  --speed M           metres per frame (default 0.02; peak speed for pan)\n"
      "  --yaw-rate DEG      max turn per frame for walk/pan (default 1.5)\n"
      "  --width W --height H   image size (default 224 x 224)\n"
      "  --hfov DEG          horizontal field of view (default 70); or:\n"
      "  --fx F --fy F --cx C --cy C   explicit intrinsics (pixels)\n"
      "  --fps F             frame rate for timestamps (default 30)\n"
      "  --clearance M       min camera distance to any surface (default 0.5)\n"
      "  --objects MIN MAX   furniture count range (default 10 18)\n"
      "  --threads N         render threads (default 2)\n"
      "  --supersample N     N x N colour rays per pixel (default 1)\n"
      "  --quiet             no progress output");
}

}  // namespace

int main(int argc, char** argv) {
  using namespace long3r::synth;
  SequenceConfig cfg;
  RenderOptions ropt;
  std::string out;
  int width = 224, height = 224;
  double hfov = 70.0, fx = 0, fy = 0, cx = -1, cy = -1;
  bool quiet = false;
  try {
    for (int i = 1; i < argc; ++i) {
      const std::string a = argv[i];
      auto next = [&]() -> std::string {
        if (i + 1 >= argc) throw std::invalid_argument("missing value after " + a);
        return argv[++i];
      };
      if (a == "--out")
        out = next();
      else if (a == "--seed")
        cfg.seed = std::stoull(next());
      else if (a == "--frames")
        cfg.trajectory.frames = std::stoi(next());
      else if (a == "--trajectory")
        cfg.trajectory.type = trajectory_type_from_string(next());
      else if (a == "--speed")
        cfg.trajectory.speed = std::stod(next());
      else if (a == "--yaw-rate")
        cfg.trajectory.max_yaw_rate_deg = std::stod(next());
      else if (a == "--width")
        width = std::stoi(next());
      else if (a == "--height")
        height = std::stoi(next());
      else if (a == "--hfov")
        hfov = std::stod(next());
      else if (a == "--fx")
        fx = std::stod(next());
      else if (a == "--fy")
        fy = std::stod(next());
      else if (a == "--cx")
        cx = std::stod(next());
      else if (a == "--cy")
        cy = std::stod(next());
      else if (a == "--fps")
        cfg.fps = std::stod(next());
      else if (a == "--clearance")
        cfg.trajectory.clearance = std::stod(next());
      else if (a == "--objects") {
        cfg.scene.min_objects = std::stoi(next());
        cfg.scene.max_objects = std::stoi(next());
      } else if (a == "--threads")
        ropt.threads = std::stoi(next());
      else if (a == "--supersample")
        ropt.supersample = std::stoi(next());
      else if (a == "--quiet")
        quiet = true;
      else if (a == "-h" || a == "--help") {
        usage();
        return 0;
      } else {
        throw std::invalid_argument("unknown option " + a);
      }
    }
    if (out.empty()) throw std::invalid_argument("--out is required");
    if (width < 1 || height < 1) throw std::invalid_argument("bad image size");
    cfg.intrinsics = long3r::PinholeIntrinsics::from_hfov(width, height, hfov);
    if (fx > 0) cfg.intrinsics.fx = fx;
    if (fy > 0)
      cfg.intrinsics.fy = fy;
    else if (fx > 0)
      cfg.intrinsics.fy = fx;
    if (cx >= 0) cfg.intrinsics.cx = cx;
    if (cy >= 0) cfg.intrinsics.cy = cy;
    if (ropt.supersample < 1 || ropt.threads < 1) throw std::invalid_argument("bad render options");
  } catch (const std::exception& e) {
    std::fprintf(stderr, "long3r_synth: %s\n", e.what());
    usage();
    return 2;
  }

  try {
    const auto t0 = std::chrono::steady_clock::now();
    const Sequence seq = generate_sequence(cfg);
    const auto t1 = std::chrono::steady_clock::now();
    if (!quiet) {
      std::printf("room %.2f x %.2f x %.2f m, %zu shapes, %s path of %d frames\n",
                  seq.scene.room_size.x(), seq.scene.room_size.y(), seq.scene.room_size.z(),
                  seq.scene.shapes.size(), to_string(cfg.trajectory.type), cfg.trajectory.frames);
    }
    const WriteStats st = write_tum_sequence(seq, out, ropt, [&](int i, int n) {
      if (!quiet && (i % 50 == 0 || i == n)) {
        std::printf("\rframe %d / %d", i, n);
        std::fflush(stdout);
      }
    });
    const auto t2 = std::chrono::steady_clock::now();
    const double gen = std::chrono::duration<double>(t1 - t0).count();
    const double total = std::chrono::duration<double>(t2 - t0).count();
    if (!quiet) std::printf("\n");
    std::printf(
        "wrote %d frames %dx%d to %s in %.2f s (scene+path %.2f s, render %.2f s, png+io %.2f s; "
        "%.1f frames/s)\n",
        st.frames, cfg.intrinsics.width, cfg.intrinsics.height, out.c_str(), total, gen,
        st.render_seconds, st.write_seconds, st.frames / std::max(total, 1e-9));
  } catch (const std::exception& e) {
    std::fprintf(stderr, "long3r_synth: %s\n", e.what());
    return 1;
  }
  return 0;
}
